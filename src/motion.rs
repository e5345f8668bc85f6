//! Rigid-body motion: the specific force at any body point.
//!
//! `f(r) = a_o + alpha x r + omega x (omega x r) - g_b` (body axes), where `a_o` is the inertial
//! acceleration of the body origin, `alpha` and `omega` the angular acceleration and rate, and
//! `g_b` the gravity vector (pointing down) in body axes. At rest `f = g * up`.

use nalgebra::{UnitQuaternion, Vector3};

/// Instantaneous motion of the body, everything in body axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidMotion {
    /// Inertial acceleration of the body origin, m/s^2.
    pub accel_b_m_s2: Vector3<f64>,
    /// Angular acceleration, rad/s^2.
    pub alpha_b_rad_s2: Vector3<f64>,
    /// Angular rate, rad/s.
    pub omega_b_rad_s: Vector3<f64>,
    /// Gravity vector (down), m/s^2.
    pub gravity_b_m_s2: Vector3<f64>,
}

impl RigidMotion {
    /// At rest with `up_b` (any non-zero vector, normalised here) pointing up, gravity `g_m_s2`.
    pub fn at_rest(up_b: &Vector3<f64>, g_m_s2: f64) -> Self {
        Self {
            accel_b_m_s2: Vector3::zeros(),
            alpha_b_rad_s2: Vector3::zeros(),
            omega_b_rad_s: Vector3::zeros(),
            gravity_b_m_s2: -up_b.normalize() * g_m_s2,
        }
    }

    /// Spinning at constant rate `omega_b_rad_s` about an axis through the body origin, with
    /// `up_b` pointing up (Hung & Lee 2006, Section 4, eq. 12).
    pub fn spinning(omega_b_rad_s: &Vector3<f64>, up_b: &Vector3<f64>, g_m_s2: f64) -> Self {
        Self { omega_b_rad_s: *omega_b_rad_s, ..Self::at_rest(up_b, g_m_s2) }
    }

    /// Motion from an inertial description: attitude `q_b_i` (body to inertial), inertial
    /// acceleration of the origin, body rate and angular acceleration, inertial gravity.
    pub fn from_inertial(
        q_b_i: &UnitQuaternion<f64>,
        accel_i_m_s2: &Vector3<f64>,
        omega_b_rad_s: &Vector3<f64>,
        alpha_b_rad_s2: &Vector3<f64>,
        gravity_i_m_s2: &Vector3<f64>,
    ) -> Self {
        let q_i_b = q_b_i.inverse();
        Self {
            accel_b_m_s2: q_i_b * accel_i_m_s2,
            alpha_b_rad_s2: *alpha_b_rad_s2,
            omega_b_rad_s: *omega_b_rad_s,
            gravity_b_m_s2: q_i_b * gravity_i_m_s2,
        }
    }

    /// Specific force at body point `r_b_m`, m/s^2.
    pub fn specific_force_m_s2(&self, r_b_m: &Vector3<f64>) -> Vector3<f64> {
        let w = &self.omega_b_rad_s;
        self.accel_b_m_s2 + self.alpha_b_rad_s2.cross(r_b_m) + w.cross(&w.cross(r_b_m)) - self.gravity_b_m_s2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_rest_the_specific_force_is_g_up_everywhere() {
        let up = Vector3::new(1.0, -2.0, 2.0);
        let m = RigidMotion::at_rest(&up, 9.8);
        for r in [Vector3::zeros(), Vector3::new(0.1, 0.2, -0.3)] {
            let f = m.specific_force_m_s2(&r);
            assert!((f - up / 3.0 * 9.8).norm() < 1e-14, "{f}");
        }
    }

    #[test]
    fn spinning_adds_the_centripetal_term_toward_the_axis() {
        // Spin about z at 2 rad/s: a point at x = 0.5 m feels -w^2 x = -2 m/s^2 along x.
        let m = RigidMotion::spinning(&Vector3::new(0.0, 0.0, 2.0), &Vector3::z(), 9.8);
        let f = m.specific_force_m_s2(&Vector3::new(0.5, 0.0, 0.0));
        assert!((f - Vector3::new(-2.0, 0.0, 9.8)).norm() < 1e-14, "{f}");
    }
}
