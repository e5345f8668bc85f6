//! The navigation integrator: RK4 on (attitude quaternion, rate, velocity, position).

use nalgebra::{UnitQuaternion, Vector3};

use super::drift::DriftSample;
use super::lanes::{L, LANES, LaneSolve, LaneState};
use super::plan::{Plan, PlanStep};
use super::source::OutputSource;
use super::state::NavState;
use super::trajectory::{Trajectory, TruthState};
use crate::sensor::params::Compensator;

/// Navigates from the trajectory's initial state with fixed steps of `step_s` (shortened to land
/// exactly on each horizon and on each of the trajectory's breakpoints: [`Plan`]), compensating
/// the outputs with `compensator`, and returns the drift at each horizon (sorted ascending).
pub fn navigate(
    trajectory: &Trajectory,
    source: &mut dyn OutputSource,
    compensator: &Compensator,
    gravity_i_m_s2: &Vector3<f64>,
    step_s: f64,
    horizons_s: &[f64],
) -> Vec<DriftSample> {
    let plan = Plan::new(trajectory, step_s, horizons_s);
    let truths: Vec<TruthState> = plan.records.iter().map(|&(_, h)| trajectory.truth(h)).collect();
    let mut fill = |_: usize, step: &PlanStep, outputs: &mut [Vec<f64>; 3]| {
        source.begin_step(step.t_s, step.h_s);
        for (t_s, out) in step.stage_times_s().into_iter().zip(outputs.iter_mut()) {
            source.outputs(t_s, out);
        }
    };
    navigate_together(&plan, &trajectory.truth(0.0), &truths, &mut fill, &[compensator], gravity_i_m_s2)
        .pop()
        .unwrap_or_default()
}

/// Raw outputs at a step's start, midpoint and end.
pub type StageOutputs = [Vec<f64>; 3];

/// Fills the raw outputs of step `i` (index, step, outputs).
pub type StepFill<'a> = dyn FnMut(usize, &PlanStep, &mut StageOutputs) + 'a;

/// Navigates several compensations of the same outputs in lockstep along `plan`: each step's raw
/// outputs at its three distinct times (start, midpoint for RK4's stages 2 and 3, end) come from
/// `fill(step index, step, outputs)` once and serve every compensation. Returns, per
/// compensation, the drift at each of `plan.records` against `record_truths`; a navigation whose
/// state stops being finite reports infinite errors from then on.
pub fn navigate_together(
    plan: &Plan,
    initial: &TruthState,
    record_truths: &[TruthState],
    fill: &mut StepFill<'_>,
    compensators: &[&Compensator],
    gravity_i_m_s2: &Vector3<f64>,
) -> Vec<Vec<DriftSample>> {
    let mut groups = [NavGroup { fill, compensators: compensators.to_vec() }];
    navigate_groups(&Route { plan, initial, record_truths, gravity_i_m_s2 }, &mut groups).pop().unwrap_or_default()
}

/// What every navigation of a lockstep shares: the steps, the initial state, the true state at
/// each of `plan.records`, and gravity in inertial axes.
#[derive(Debug, Clone, Copy)]
pub struct Route<'a> {
    pub plan: &'a Plan,
    pub initial: &'a TruthState,
    pub record_truths: &'a [TruthState],
    pub gravity_i_m_s2: &'a Vector3<f64>,
}

/// One source of outputs (a trial's array) and the compensations that navigate it.
pub struct NavGroup<'f, 'c> {
    pub fill: &'f mut StepFill<'c>,
    pub compensators: Vec<&'f Compensator>,
}

/// [`navigate_together`] for several groups at once (several trials along the same plan, each
/// with its own outputs): every compensation of every group goes in lockstep, [`LANES`] to a
/// packed number. Returns per group, per compensation, the drift at each record. Each
/// compensation's numbers are those it gets navigated alone.
pub fn navigate_groups(route: &Route<'_>, groups: &mut [NavGroup<'_, '_>]) -> Vec<Vec<Vec<DriftSample>>> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, the only feature the copy is compiled for.
        return unsafe { navigate_groups_avx(route, groups) };
    }
    navigate_groups_any(route, groups)
}

/// [`navigate_groups_any`] compiled for AVX: the four lanes in one instruction. Same
/// instructions otherwise (no fused multiply-add), so the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn navigate_groups_avx(route: &Route<'_>, groups: &mut [NavGroup<'_, '_>]) -> Vec<Vec<Vec<DriftSample>>> {
    navigate_groups_any(route, groups)
}

#[inline(always)]
fn navigate_groups_any(route: &Route<'_>, groups: &mut [NavGroup<'_, '_>]) -> Vec<Vec<Vec<DriftSample>>> {
    let Route { plan, initial, record_truths, gravity_i_m_s2 } = *route;
    // Every compensation, with its group.
    let compensators: Vec<(usize, &Compensator)> =
        groups.iter().enumerate().flat_map(|(g, group)| group.compensators.iter().map(move |c| (g, *c))).collect();
    let m = compensators.len();
    let n = compensators.first().map_or(0, |(_, c)| c.mechanization().len());
    if compensators.iter().any(|(_, c)| c.mechanization().len() != n) {
        // Arrays of different sizes cannot share lanes: each group alone.
        return groups.iter_mut().flat_map(|g| navigate_groups(route, std::slice::from_mut(g))).collect();
    }
    let mut outputs = vec![[vec![0.0; n], vec![0.0; n], vec![0.0; n]]; groups.len()];
    // Compensations go [`LANES`] at a time; the last lanes of an incomplete set repeat its last
    // compensation and are not read.
    let lanes: Vec<[usize; LANES]> =
        (0..m).step_by(LANES).map(|c| std::array::from_fn(|l| (c + l).min(m - 1))).collect();
    let distinct = |set: &[usize; LANES], l: usize| l == 0 || set[l] != set[l - 1];
    let solves: Vec<LaneSolve> = lanes.iter().map(|set| LaneSolve::new(set.map(|c| compensators[c].1))).collect();
    let mut start = LaneState::default();
    for l in 0..LANES {
        start.set_lane(l, initial.q_b_i.quaternion(), &initial.omega_b_rad_s, &initial.v_i_m_s, &initial.r_i_m);
    }
    let mut states = vec![start; lanes.len()];
    let mut active = vec![true; m];
    let mut drift: Vec<Vec<DriftSample>> = vec![Vec::with_capacity(plan.records.len()); m];
    let mut next_record = 0;
    let record_due = |done: usize,
                      next_record: &mut usize,
                      states: &[LaneState],
                      active: &[bool],
                      drift: &mut [Vec<DriftSample>]| {
        while *next_record < plan.records.len() && plan.records[*next_record].0 == done {
            let horizon = plan.records[*next_record].1;
            for c in (0..m).filter(|&c| active[c]) {
                let (q, w, v, r) = states[c / LANES].lane(c % LANES);
                let nav = NavState { q_b_i: UnitQuaternion::new_normalize(q), omega_b_rad_s: w, v_i_m_s: v, r_i_m: r };
                drift[c].push(DriftSample::new(horizon, &nav, &record_truths[*next_record]));
            }
            *next_record += 1;
        }
    };
    // Each set's readings at the step's three distinct times: they do not depend on the state,
    // so they are computed once per time and off the stages' chain of dependencies.
    let mut readings = vec![[vec![L::default(); n], vec![L::default(); n], vec![L::default(); n]]; lanes.len()];
    for (i, step) in plan.steps.iter().enumerate() {
        record_due(i, &mut next_record, &states, &active, &mut drift);
        if !active.iter().any(|&a| a) {
            break;
        }
        for (g, group) in groups.iter_mut().enumerate() {
            if compensators.iter().zip(&active).any(|((cg, _), a)| *cg == g && *a) {
                (group.fill)(i, step, &mut outputs[g]);
            }
        }
        for (p, set) in lanes.iter().enumerate() {
            if !set.iter().any(|&c| active[c]) {
                continue;
            }
            for (t, m) in readings[p].iter_mut().enumerate() {
                solves[p].readings(set.map(|c| outputs[compensators[c].0][t].as_slice()), m);
            }
            let y = solves[p].step(&states[p], &readings[p], step.h_s, gravity_i_m_s2);
            // The rate equation is quadratic in omega (centripetal terms): with large enough
            // errors it blows up in finite time. A diverged navigation reports infinite errors
            // from then on; its lane keeps its last finite state and is no longer read.
            let finite = y.finite();
            if (0..LANES).filter(|&l| distinct(set, l)).all(|l| active[set[l]] && finite[l]) {
                states[p] = y;
                continue;
            }
            for l in (0..LANES).filter(|&l| distinct(set, l)) {
                let c = set[l];
                if active[c] && finite[l] {
                    let (q, w, v, r) = y.lane(l);
                    states[p].set_lane(l, &q, &w, &v, &r);
                } else if active[c] {
                    active[c] = false;
                    drift[c].extend(plan.records[next_record..].iter().map(|&(_, h)| DriftSample::diverged(h)));
                }
            }
        }
    }
    record_due(plan.steps.len(), &mut next_record, &states, &active, &mut drift);
    let mut drift = drift.into_iter();
    groups.iter().map(|g| drift.by_ref().take(g.compensators.len()).collect()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::Array;
    use crate::nav::SimulatedArray;
    use crate::nav::{MotionGrid, Trajectory};
    use crate::sensor::ArrayParams;
    use crate::sensor::params::random_params;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    type Navigated = Vec<Vec<Vec<DriftSample>>>;

    /// Navigates `trials` (true parameters, compensations) as groups in lockstep, with the
    /// dispatching entry (`avx`) or the portable copy.
    fn run(grid: &MotionGrid, cube: &Array, trials: &[(ArrayParams, Vec<Compensator>)], avx: bool) -> Navigated {
        let g = Vector3::new(0.0, 0.0, -9.80665);
        let trajectory = Trajectory::paper_manoeuvre(4.0);
        let mut sources: Vec<_> =
            trials.iter().map(|(truth, _)| SimulatedArray::<ChaCha8Rng>::new(cube, truth, &trajectory, g)).collect();
        let mut fills: Vec<Box<StepFill<'_>>> = sources
            .iter_mut()
            .map(|s| {
                Box::new(move |i: usize, step: &PlanStep, out: &mut StageOutputs| {
                    s.fill_step(&grid.motions[i], step.t_s, step.h_s, out)
                }) as Box<StepFill<'_>>
            })
            .collect();
        let mut groups: Vec<NavGroup<'_, '_>> = fills
            .iter_mut()
            .zip(trials)
            .map(|(fill, (_, comps))| NavGroup { fill: fill.as_mut(), compensators: comps.iter().collect() })
            .collect();
        let route =
            Route { plan: &grid.plan, initial: &grid.initial, record_truths: &grid.record_truths, gravity_i_m_s2: &g };
        if avx { navigate_groups(&route, &mut groups) } else { navigate_groups_any(&route, &mut groups) }
    }

    /// Three trials in lockstep (seven compensations: two sets of four lanes, the last padded),
    /// one of them diverging, give each compensation the bits it gets navigated alone; and the
    /// AVX copy (where the processor has AVX) the bits of the portable one.
    #[test]
    fn lockstep_and_avx_give_each_compensation_the_bits_it_gets_alone() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let cube = Array::cube(0.1).expect("cube");
        let g = Vector3::new(0.0, 0.0, -9.80665);
        let grid = MotionGrid::new(&Trajectory::paper_manoeuvre(4.0), &g, 0.01, &[1.0, 2.0, 4.0]);
        let trials: Vec<(ArrayParams, Vec<Compensator>)> = [2, 3, 2]
            .iter()
            .map(|&k| {
                let truth = random_params(&cube, &mut rng);
                let mut comps: Vec<Compensator> = (0..k)
                    .map(|_| Compensator::new(&cube, &random_params(&cube, &mut rng)).expect("full rank"))
                    .collect();
                if k == 3 {
                    // Locations 5 cm off, unevenly: the centripetal terms no longer cancel in
                    // the angular acceleration, and the rate equation blows up.
                    let mut short = ArrayParams::nominal(&cube);
                    for (j, s) in short.sensors.iter_mut().enumerate() {
                        s.location_error_m = Vector3::new(0.05, -0.03, 0.04) * (j as f64 - 2.5);
                    }
                    comps[1] = Compensator::new(&cube, &short).expect("full rank");
                }
                (truth, comps)
            })
            .collect();
        let together = run(&grid, &cube, &trials, false);
        let diverged = together.iter().flatten().filter(|d| d.last().is_some_and(|s| s.rate_err_rad_s.is_infinite()));
        assert_eq!(diverged.count(), 1, "the short-armed compensation diverges, the others do not");
        for (t, (truth, comps)) in trials.iter().enumerate() {
            for (c, comp) in comps.iter().enumerate() {
                let alone = run(&grid, &cube, &[(truth.clone(), vec![comp.clone()])], false);
                assert_eq!(alone[0][0], together[t][c], "trial {t}, compensation {c}");
            }
        }
        assert_eq!(run(&grid, &cube, &trials, true), together);
    }
}
