//! The branch of the gyroscope-free rate at each sample of a clocked rotation phase, chosen on a
//! path over the samples.
//!
//! Without the timing term the outputs do not change when the rate changes sign, and on a thin
//! array (the MIMU4444 board: 18.9 mm across, 2 mm through) a rate reflected through the plane of
//! the sensing points, re-solved so that it takes its own angular acceleration, fits almost as
//! well: the in-plane block of `[alpha x] + w w^T - |w|^2 I` fixes `w_x`, `w_y` and `|w_z|`, and
//! the sign of `w_z` against them rests on the thin lever. A sample's own solve cannot tell the
//! four apart, and the sign by continuity alone (`motion::orient_run`, the trapezoid of the
//! angular acceleration over a 16 ms step) flips whole runs where the clocks' timing error spoils
//! the angular acceleration. On the six real recordings 3.0-6.5% of the samples had the wrong
//! sign and 8.9-10.8% the wrong reflection, and they carried 92-95% of the rate's squared error
//! against the gyroscopes (`results/mimu4444/EXPECTATIONS.md` (at)-(aw)).
//!
//! Here every sample has four branches, each solved by least squares (`motion::solve`) on the
//! outputs corrected to the mean instant by the calibration's clocks: the fitted motion `m`
//! re-solved from itself, its rate negated, the reflection through the plane re-solved from the
//! reflected rate, and that one negated (all four alike, so that none wins by what it was fitted
//! to: the fit's own motion was fitted to Huber's shifted outputs). The path over them
//! minimises, by the Viterbi recursion,
//!
//! ```text
//! sum_i c_i(b_i) / 2  +  sum_(i, i-1 in a run) |w_i - w_(i-1) - (alpha_i + alpha_(i-1)) dt / 2|^2 / (2 s^2)
//! ```
//!
//! with `c_i(b)` the branch's misfit under the timing model (the sample's jerk and angular jerk
//! refitted, `timing::ClockProblem`): the centripetal term's derivative `D r` is odd in the rate
//! and not symmetric under the reflection, so it votes, weakly per sample (a median misfit
//! difference of 0.5-0.9 between the signs) but summed over a run. `s^2` is a third of the mean
//! over the steps of the smallest mismatch among the branch pairs: the carried rate's error per
//! axis, from the data. There is no transition cost across a gap between runs.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::clock::SampleClock;
use super::data::DynamicData;
use super::model::{SampleMotion, Sensor};
use super::motion::{SampleData, solve};
use super::timing::ClockProblem;

/// Branches a sample's rate has: the fitted, its negative, the plane's reflection, its negative.
pub const BRANCHES: usize = 4;

/// The unit normal of the plane the sensing points lie closest to (the eigenvector of their
/// scatter about their mean with the smallest eigenvalue).
pub fn thinnest_direction(sensors: &[Sensor]) -> Vector3<f64> {
    let n = sensors.len().max(1) as f64;
    let mean: Vector3<f64> = sensors.iter().map(|s| s.position_m).sum::<Vector3<f64>>() / n;
    let scatter: Matrix3<f64> = sensors
        .iter()
        .map(|s| {
            let d = s.position_m - mean;
            d * d.transpose()
        })
        .sum();
    let eig = scatter.symmetric_eigen();
    eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned()
}

/// Every sample's four branches (see the module docs), each solved on `fitted` (the outputs
/// corrected to the mean instant) by the same least squares: the fitted motion re-solved from
/// itself and the reflection from the reflected rate. (The fit's own motion may have been fitted
/// to other outputs, Huber's shifted ones: scored beside a least-squares re-solve it would lose
/// for that alone.)
pub fn branches(
    sensors: &[Sensor],
    fitted: &DynamicData,
    motion: &[SampleMotion],
    weights: &[f64],
) -> Vec<[SampleMotion; BRANCHES]> {
    let normal = thinnest_direction(sensors);
    let n = sensors.len();
    motion
        .par_iter()
        .enumerate()
        .map(|(i, m)| {
            let negated = |m: &SampleMotion| SampleMotion { omega_rad_s: -m.omega_rad_s, ..*m };
            let w = m.omega_rad_s;
            let start = SampleMotion { omega_rad_s: w - normal * (2.0 * w.dot(&normal)), ..*m };
            let outputs: Vec<f64> = (0..n).map(|j| fitted.outputs[(i, j)]).collect();
            let data = SampleData { outputs: &outputs, used: &fitted.used[i * n..(i + 1) * n], weights };
            let (fitted_branch, _) = solve(sensors, &data, *m, false);
            let (reflected, _) = solve(sensors, &data, start, false);
            [fitted_branch, negated(&fitted_branch), reflected, negated(&reflected)]
        })
        .collect()
}

/// Each branch's misfit under the timing model at `clocks`, on the outputs as read (`raw`).
pub fn timing_costs(
    sensors: &[Sensor],
    raw: &DynamicData,
    candidates: &[[SampleMotion; BRANCHES]],
    weights: &[f64],
    package_of: &[usize],
    clocks: &[Option<SampleClock>],
) -> Vec<[f64; BRANCHES]> {
    let mut costs = vec![[0.0; BRANCHES]; candidates.len()];
    for b in 0..BRANCHES {
        let motion: Vec<SampleMotion> = candidates.iter().map(|c| c[b]).collect();
        let problem = ClockProblem::new(sensors, raw, &motion, weights, package_of);
        for (row, c) in costs.iter_mut().zip(problem.sample_costs(clocks)) {
            row[b] = c;
        }
    }
    costs
}

/// The branch of every sample on the path of least cost (module docs): `t_s` the samples'
/// times, `run_starts` where each run of consecutive samples starts, `costs` each branch's misfit
/// (a chi^2). `None` where the branches carry no continuity to weigh (no step inside a run, or
/// every step matched exactly).
pub fn path(
    t_s: &[f64],
    run_starts: &[usize],
    candidates: &[[SampleMotion; BRANCHES]],
    costs: &[[f64; BRANCHES]],
) -> Option<Vec<usize>> {
    let n = candidates.len();
    if n == 0 || costs.len() != n || t_s.len() != n {
        return None;
    }
    let mut starts = vec![false; n];
    for &s in run_starts {
        if s < n {
            starts[s] = true;
        }
    }
    starts[0] = true;
    let mismatch = |k: usize, a: usize, b: usize| -> f64 {
        let (p, c) = (&candidates[k - 1][a], &candidates[k][b]);
        let carried = (p.alpha_rad_s2 + c.alpha_rad_s2) * (0.5 * (t_s[k] - t_s[k - 1]));
        (c.omega_rad_s - p.omega_rad_s - carried).norm_squared()
    };
    let (mut sum, mut steps) = (0.0, 0usize);
    for k in (1..n).filter(|&k| !starts[k]) {
        let smallest =
            (0..BRANCHES * BRANCHES).map(|ab| mismatch(k, ab / BRANCHES, ab % BRANCHES)).fold(f64::INFINITY, f64::min);
        sum += smallest;
        steps += 1;
    }
    let s2 = sum / steps.max(1) as f64 / 3.0;
    if steps == 0 || !(s2.is_finite() && s2 > 0.0) {
        return None;
    }
    let mut score: [f64; BRANCHES] = std::array::from_fn(|b| 0.5 * costs[0][b]);
    let mut back = vec![[0usize; BRANCHES]; n];
    for k in 1..n {
        let mut next = [0.0; BRANCHES];
        for b in 0..BRANCHES {
            let (mut best, mut from) = (f64::INFINITY, 0);
            for (a, s) in score.iter().enumerate() {
                let step = if starts[k] { 0.0 } else { mismatch(k, a, b) / (2.0 * s2) };
                if s + step < best {
                    (best, from) = (s + step, a);
                }
            }
            next[b] = best + 0.5 * costs[k][b];
            back[k][b] = from;
        }
        score = next;
    }
    let mut chosen = vec![0usize; n];
    // A score that is not a number (a branch whose misfit is not) is never the least.
    let key = |b: usize| if score[b].is_nan() { f64::INFINITY } else { score[b] };
    chosen[n - 1] = (0..BRANCHES).min_by(|a, b| key(*a).total_cmp(&key(*b)))?;
    for k in (1..n).rev() {
        chosen[k - 1] = back[k][chosen[k]];
    }
    Some(chosen)
}

/// The motion of every sample on the path (module docs): `raw` the rotation phase's outputs as
/// read, `fitted` the outputs corrected to the mean instant by the calibration's clocks, `motion`
/// the fit's. `None` where the path has nothing to weigh (no step inside a run, or no spread of
/// the steps' mismatches) or the data do not match the motion.
#[allow(clippy::too_many_arguments)]
pub fn on_path(
    sensors: &[Sensor],
    raw: &DynamicData,
    fitted: &DynamicData,
    motion: &[SampleMotion],
    weights: &[f64],
    package_of: &[usize],
    clocks: &[Option<SampleClock>],
) -> Option<Vec<SampleMotion>> {
    if motion.len() != raw.samples() || motion.len() != fitted.samples() {
        return None;
    }
    let candidates = branches(sensors, fitted, motion, weights);
    let costs = timing_costs(sensors, raw, &candidates, weights, package_of, clocks);
    let chosen = path(&raw.t_s, &raw.run_starts, &candidates, &costs)?;
    Some(candidates.iter().zip(&chosen).map(|(c, &b)| c[b]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion(w: Vector3<f64>, alpha: Vector3<f64>) -> SampleMotion {
        SampleMotion { f_m_s2: Vector3::zeros(), alpha_rad_s2: alpha, omega_rad_s: w }
    }

    /// A smooth rate (closed form) and its exact derivative at `t`.
    fn truth(t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let w = Vector3::new(20.0 * (3.0 * t).sin(), 15.0 * (2.0 * t).cos(), 10.0 * (5.0 * t).sin());
        let a = Vector3::new(60.0 * (3.0 * t).cos(), -30.0 * (2.0 * t).sin(), 50.0 * (5.0 * t).cos());
        (w, a)
    }

    /// Every sample's four branches with the truth in a slot that moves from sample to sample:
    /// the negative keeps the angular acceleration, the reflection through `z = 0` keeps it too
    /// (a reflected rate re-solved keeps the angular acceleration the tangential terms see), and
    /// the negated reflection. Returns the branches and the truth's slot.
    fn shuffled(n: usize, dt: f64) -> (Vec<f64>, Vec<[SampleMotion; BRANCHES]>, Vec<usize>) {
        let mut t_s = Vec::new();
        let (mut cands, mut slots) = (Vec::new(), Vec::new());
        for i in 0..n {
            let t = i as f64 * dt;
            let (w, a) = truth(t);
            let r = Vector3::new(w[0], w[1], -w[2]);
            let four = [motion(w, a), motion(-w, a), motion(r, a), motion(-r, a)];
            let slot = (i * 7 + i / 3) % BRANCHES;
            // The truth into `slot`, the others after it in turn.
            cands.push(std::array::from_fn(|b| four[(b + BRANCHES - slot) % BRANCHES]));
            slots.push(slot);
            t_s.push(t);
        }
        (t_s, cands, slots)
    }

    #[test]
    fn continuity_alone_finds_a_smooth_rate_among_its_branches() {
        let (t_s, cands, slots) = shuffled(400, 0.016);
        let costs = vec![[0.0; BRANCHES]; cands.len()];
        let chosen = path(&t_s, &[0], &cands, &costs).expect("steps to weigh");
        assert_eq!(chosen, slots);
    }

    #[test]
    fn the_evidence_decides_where_continuity_cannot() {
        // Two runs: the second starts at sample 200 with no step to the first. Within each run
        // the negated chain `(-w, -alpha)` is as smooth as the truth, so only the misfit can
        // choose: it favours the truth by 1 (a chi^2) at every sample.
        let (t_s, cands, slots) = shuffled(400, 0.016);
        let negated: Vec<[SampleMotion; BRANCHES]> = cands
            .iter()
            .zip(&slots)
            .map(|(c, &s)| {
                let mut c = *c;
                let t = c[s];
                let o = (s + 1) % BRANCHES;
                c[o] = motion(-t.omega_rad_s, -t.alpha_rad_s2);
                c
            })
            .collect();
        let costs: Vec<[f64; BRANCHES]> =
            slots.iter().map(|&s| std::array::from_fn(|b| if b == s { 0.0 } else { 1.0 })).collect();
        let chosen = path(&t_s, &[0, 200], &negated, &costs).expect("steps to weigh");
        assert_eq!(chosen, slots);
        // With the misfit favouring the negated chain instead, the path takes it throughout.
        let other: Vec<usize> = slots.iter().map(|&s| (s + 1) % BRANCHES).collect();
        let costs: Vec<[f64; BRANCHES]> =
            other.iter().map(|&s| std::array::from_fn(|b| if b == s { 0.0 } else { 1.0 })).collect();
        assert_eq!(path(&t_s, &[0, 200], &negated, &costs).expect("steps"), other);
    }

    #[test]
    fn a_path_with_no_step_to_weigh_is_refused() {
        let (t_s, cands, _) = shuffled(5, 0.016);
        let costs = vec![[0.0; BRANCHES]; cands.len()];
        assert!(path(&t_s, &[0, 1, 2, 3, 4], &cands, &costs).is_none());
        assert!(path(&[], &[0], &[], &[]).is_none());
    }

    #[test]
    fn the_thinnest_direction_of_a_board_is_its_normal() {
        let mut sensors = Vec::new();
        for (x, y, z) in [(1.0, 1.0, 1.0), (1.0, 1.0, -1.0), (-1.0, 1.0, 1.0), (-1.0, 1.0, -1.0)] {
            for (sx, sy) in [(1.0, 1.0), (1.0, -1.0)] {
                let p = Vector3::new(9.45 * x * sx, 9.45 * y * sy, z) * 1e-3;
                let axis = Vector3::x();
                sensors.push(Sensor { k: 1.0, b_m_s2: 0.0, axis, daxis: [Vector3::y(), Vector3::z()], position_m: p });
            }
        }
        let n = thinnest_direction(&sensors);
        assert!((n.z.abs() - 1.0).abs() < 1e-12, "{n}");
    }
}
