//! The navigation integrator: RK4 on (attitude quaternion, rate, velocity, position).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::drift::DriftSample;
use super::trajectory::{InitialState, Trajectory};
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
/// exactly on each horizon and on each of the trajectory's breakpoints), compensating the outputs with `compensator`, and returns the drift
/// at each horizon (sorted ascending).
pub fn navigate(
    trajectory: &Trajectory,
    source: &mut dyn OutputSource,
    compensator: &mut Compensator,
    gravity_i_m_s2: &Vector3<f64>,
    step_s: f64,
    horizons_s: &[f64],
) -> Vec<DriftSample> {
    assert!(step_s > 0.0, "step must be positive");
    let n = compensator.mechanization().len();
    let mut outputs = vec![0.0; n];
    let start = NavState::from({
        let t = trajectory.truth(0.0);
        InitialState { q_b_i: t.q_b_i, omega_b_rad_s: t.omega_b_rad_s, v_i_m_s: t.v_i_m_s, r_i_m: t.r_i_m }
    });
    let mut x = Raw { q: *start.q_b_i.quaternion(), w: start.omega_b_rad_s, v: start.v_i_m_s, r: start.r_i_m };
    let mut t_s = 0.0;
    let mut drift = Vec::with_capacity(horizons_s.len());
    let mut deriv = |t: f64, x: &Raw, source: &mut dyn OutputSource, outputs: &mut [f64]| -> Raw {
        source.outputs(t, outputs);
        let q = UnitQuaternion::new_normalize(x.q);
        let gravity_b = q.inverse_transform_vector(gravity_i_m_s2);
        let acc = compensator.rigid_accel(outputs, &x.w, &gravity_b);
        Raw {
            q: x.q * Quaternion::from_imag(x.w) * 0.5,
            w: acc.alpha_b_rad_s2,
            v: q.transform_vector(&acc.accel_b_m_s2),
            r: x.v,
        }
    };
    let mut stops: Vec<(f64, bool)> = horizons_s.iter().map(|&h| (h, true)).collect();
    let last_s = horizons_s.iter().copied().fold(0.0, f64::max);
    stops.extend(trajectory.breakpoints_s().into_iter().filter(|&b| b < last_s).map(|b| (b, false)));
    stops.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
    for &(horizon, record) in &stops {
        loop {
            let remaining = horizon - t_s;
            if remaining <= 1e-9 * step_s {
                t_s = horizon;
                break;
            }
            // Take a full step unless the horizon falls within it (or just past it).
            let h = if remaining < step_s * (1.0 + 1e-9) { remaining } else { step_s };
            source.begin_step(t_s, h);
            let k1 = deriv(t_s, &x, source, &mut outputs);
            let k2 = deriv(t_s + 0.5 * h, &x.axpy(0.5 * h, &k1), source, &mut outputs);
            let k3 = deriv(t_s + 0.5 * h, &x.axpy(0.5 * h, &k2), source, &mut outputs);
            let k4 = deriv(t_s + h, &x.axpy(h, &k3), source, &mut outputs);
            x = Raw {
                q: x.q + (k1.q + k2.q * 2.0 + k3.q * 2.0 + k4.q) * (h / 6.0),
                w: x.w + (k1.w + k2.w * 2.0 + k3.w * 2.0 + k4.w) * (h / 6.0),
                v: x.v + (k1.v + k2.v * 2.0 + k3.v * 2.0 + k4.v) * (h / 6.0),
                r: x.r + (k1.r + k2.r * 2.0 + k3.r * 2.0 + k4.r) * (h / 6.0),
            };
            x.q = x.q.normalize();
            t_s = if h == step_s { t_s + h } else { horizon };
            // The rate equation is quadratic in omega (centripetal terms): with large enough
            // errors it blows up in finite time. A diverged navigation reports infinite errors.
            if !(x.w.iter().chain(x.v.iter()).chain(x.r.iter()).all(|v| v.is_finite()) && x.q.norm().is_finite()) {
                for &(h, record) in stops.iter().filter(|(h, _)| *h >= horizon) {
                    if record {
                        drift.push(DriftSample::diverged(h));
                    }
                }
                return drift;
            }
        }
        if record {
            let nav =
                NavState { q_b_i: UnitQuaternion::new_normalize(x.q), omega_b_rad_s: x.w, v_i_m_s: x.v, r_i_m: x.r };
            drift.push(DriftSample::new(horizon, &nav, &trajectory.truth(horizon)));
        }
    }
    drift
}
