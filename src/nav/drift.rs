//! Drift metrics: how far a navigated state is from the truth.

use nalgebra::UnitQuaternion;

use super::state::NavState;
use super::trajectory::TruthState;

/// Navigation error at one horizon.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftSample {
    pub horizon_s: f64,
    /// |omega_nav - omega_true|, rad/s.
    pub rate_err_rad_s: f64,
    /// Rotation angle of `q_true^-1 q_nav`, rad.
    pub attitude_err_rad: f64,
    /// |v_nav - v_true|, m/s.
    pub velocity_err_m_s: f64,
    /// |r_nav - r_true|, m.
    pub position_err_m: f64,
}

impl DriftSample {
    /// A navigation that diverged before `horizon_s` (its state stopped being finite).
    pub fn diverged(horizon_s: f64) -> Self {
        Self {
            horizon_s,
            rate_err_rad_s: f64::INFINITY,
            attitude_err_rad: f64::INFINITY,
            velocity_err_m_s: f64::INFINITY,
            position_err_m: f64::INFINITY,
        }
    }

    pub fn new(horizon_s: f64, nav: &NavState, truth: &TruthState) -> Self {
        Self {
            horizon_s,
            rate_err_rad_s: (nav.omega_b_rad_s - truth.omega_b_rad_s).norm(),
            attitude_err_rad: attitude_error_rad(&truth.q_b_i, &nav.q_b_i),
            velocity_err_m_s: (nav.v_i_m_s - truth.v_i_m_s).norm(),
            position_err_m: (nav.r_i_m - truth.r_i_m).norm(),
        }
    }
}

/// Angle of the rotation between two attitudes, in [0, pi], computed as
/// `2 atan2(|vec(dq)|, |scalar(dq)|)`: accurate for tiny angles, unlike `acos` of a trace.
pub fn attitude_error_rad(q_true: &UnitQuaternion<f64>, q_nav: &UnitQuaternion<f64>) -> f64 {
    let dq = q_true.inverse() * q_nav;
    2.0 * dq.imag().norm().atan2(dq.scalar().abs())
}
