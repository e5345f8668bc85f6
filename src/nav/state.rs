//! The navigated state: attitude, body rate, inertial velocity and position.

use nalgebra::{UnitQuaternion, Vector3};

use super::trajectory::InitialState;

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
