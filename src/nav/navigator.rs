//! The navigation integrator: RK4 on (attitude quaternion, rate, velocity, position).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::drift::DriftSample;
use super::plan::{Plan, PlanStep};
use super::trajectory::{InitialState, Trajectory, TruthState};
use crate::sensor::params::Compensator;

/// Navigated state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavState {
    pub q_b_i: UnitQuaternion<f64>,
    pub omega_b_rad_s: Vector3<f64>,
    pub v_i_m_s: Vector3<f64>,
    pub r_i_m: Vector3<f64>,
}

impl From<InitialState> for NavState {
    fn from(s: InitialState) -> Self {
        Self { q_b_i: s.q_b_i, omega_b_rad_s: s.omega_b_rad_s, v_i_m_s: s.v_i_m_s, r_i_m: s.r_i_m }
    }
}

/// Unnormalised state and derivative, for the RK4 stages.
#[derive(Clone, Copy)]
struct Raw {
    q: Quaternion<f64>,
    w: Vector3<f64>,
    v: Vector3<f64>,
    r: Vector3<f64>,
}

impl Raw {
    fn axpy(&self, h: f64, d: &Raw) -> Raw {
        Raw { q: self.q + d.q * h, w: self.w + d.w * h, v: self.v + d.v * h, r: self.r + d.r * h }
    }
}

/// A source of array outputs along the trajectory: `outputs(t, out)` fills the raw outputs at
/// time `t`; `begin_step(t, h)` is called before each step (a noisy source draws its noise there,
/// held over the step).
pub trait OutputSource {
    fn begin_step(&mut self, _t_s: f64, _h_s: f64) {}
    fn outputs(&mut self, t_s: f64, out: &mut [f64]);
}

/// Navigates from the trajectory's initial state with fixed steps of `step_s` (shortened to land
/// exactly on each horizon and on each of the trajectory's breakpoints: [`Plan`]), compensating
/// the outputs with `compensator`, and returns the drift at each horizon (sorted ascending).
pub fn navigate(
    trajectory: &Trajectory,
    source: &mut dyn OutputSource,
    compensator: &mut Compensator,
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
    navigate_together(&plan, &trajectory.truth(0.0), &truths, &mut fill, &mut [compensator], gravity_i_m_s2)
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
    compensators: &mut [&mut Compensator],
    gravity_i_m_s2: &Vector3<f64>,
) -> Vec<Vec<DriftSample>> {
    let n = compensators.first().map_or(0, |c| c.mechanization().len());
    let mut outputs = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let start = Raw { q: *initial.q_b_i.quaternion(), w: initial.omega_b_rad_s, v: initial.v_i_m_s, r: initial.r_i_m };
    let m = compensators.len();
    let mut states = vec![start; m];
    let mut active = vec![true; m];
    let mut drift: Vec<Vec<DriftSample>> = vec![Vec::with_capacity(plan.records.len()); m];
    let mut next_record = 0;
    let record_due =
        |done: usize, next_record: &mut usize, states: &[Raw], active: &[bool], drift: &mut [Vec<DriftSample>]| {
            while *next_record < plan.records.len() && plan.records[*next_record].0 == done {
                let horizon = plan.records[*next_record].1;
                for c in (0..m).filter(|&c| active[c]) {
                    let x = &states[c];
                    let nav = NavState {
                        q_b_i: UnitQuaternion::new_normalize(x.q),
                        omega_b_rad_s: x.w,
                        v_i_m_s: x.v,
                        r_i_m: x.r,
                    };
                    drift[c].push(DriftSample::new(horizon, &nav, &record_truths[*next_record]));
                }
                *next_record += 1;
            }
        };
    for (i, step) in plan.steps.iter().enumerate() {
        record_due(i, &mut next_record, &states, &active, &mut drift);
        if !active.iter().any(|&a| a) {
            break;
        }
        fill(i, step, &mut outputs);
        let h = step.h_s;
        for c in 0..m {
            if !active[c] {
                continue;
            }
            let comp = &mut *compensators[c];
            let x = states[c];
            let k1 = derivative(&x, &outputs[0], comp, gravity_i_m_s2);
            let k2 = derivative(&x.axpy(0.5 * h, &k1), &outputs[1], comp, gravity_i_m_s2);
            let k3 = derivative(&x.axpy(0.5 * h, &k2), &outputs[1], comp, gravity_i_m_s2);
            let k4 = derivative(&x.axpy(h, &k3), &outputs[2], comp, gravity_i_m_s2);
            let mut y = Raw {
                q: x.q + (k1.q + k2.q * 2.0 + k3.q * 2.0 + k4.q) * (h / 6.0),
                w: x.w + (k1.w + k2.w * 2.0 + k3.w * 2.0 + k4.w) * (h / 6.0),
                v: x.v + (k1.v + k2.v * 2.0 + k3.v * 2.0 + k4.v) * (h / 6.0),
                r: x.r + (k1.r + k2.r * 2.0 + k3.r * 2.0 + k4.r) * (h / 6.0),
            };
            y.q = y.q.normalize();
            // The rate equation is quadratic in omega (centripetal terms): with large enough
            // errors it blows up in finite time. A diverged navigation reports infinite errors.
            if y.w.iter().chain(y.v.iter()).chain(y.r.iter()).all(|v| v.is_finite()) && y.q.norm().is_finite() {
                states[c] = y;
            } else {
                active[c] = false;
                drift[c].extend(plan.records[next_record..].iter().map(|&(_, h)| DriftSample::diverged(h)));
            }
        }
    }
    record_due(plan.steps.len(), &mut next_record, &states, &active, &mut drift);
    drift
}

/// The state's derivative with the outputs `outputs` compensated by `compensator`.
///
/// Written out in scalars on the unnormalised quaternion `q = (s, u)` (the RK4 stages leave it
/// slightly off unit length): a vector rotates as `R(q) v = ((s^2 - u.u) v + 2 (u.v) u + 2 s u x v)
/// / |q|^2`, so no square root and no normalised copy are needed.
#[inline]
fn derivative(x: &Raw, outputs: &[f64], compensator: &mut Compensator, gravity_i_m_s2: &Vector3<f64>) -> Raw {
    let s = x.q.w;
    let u = Vector3::new(x.q.i, x.q.j, x.q.k);
    let inv_n2 = 1.0 / (s * s + u.norm_squared());
    let ss_uu = s * s - u.norm_squared();
    // Gravity in body axes: R(q)^T g_i (the conjugate's rotation: u -> -u).
    let g = gravity_i_m_s2;
    let gravity_b = (g * ss_uu + u * (2.0 * u.dot(g)) - u.cross(g) * (2.0 * s)) * inv_n2;
    let acc = compensator.rigid_accel(outputs, &x.w, &gravity_b);
    let a = &acc.accel_b_m_s2;
    let accel_i = (a * ss_uu + u * (2.0 * u.dot(a)) + u.cross(a) * (2.0 * s)) * inv_n2;
    Raw { q: x.q * Quaternion::from_imag(x.w) * 0.5, w: acc.alpha_b_rad_s2, v: accel_i, r: x.v }
}
