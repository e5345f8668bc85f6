//! Drift metrics: how far a navigated state is from the truth.

use nalgebra::UnitQuaternion;

use super::navigator::NavState;
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

/// Drift of one compensation at one horizon.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftRow {
    /// Which parameters compensated the outputs (e.g. "nominal", "true").
    pub compensation: String,
    pub sample: DriftSample,
}

/// What the compared navigations share: the array and its true parameters, the trajectory, and
/// the noise (one realisation from `noise_seed`, the same for every compensation).
pub struct DriftSetup<'a> {
    pub array: &'a crate::array::Array,
    pub truth: &'a crate::sensor::ArrayParams,
    pub trajectory: &'a super::Trajectory,
    pub noise: crate::sensor::NoiseSpec,
    pub noise_seed: u64,
    pub gravity_m_s2: f64,
    pub step_s: f64,
}

/// Navigates the outputs of an array with true parameters along a trajectory, once per
/// compensation, and returns the drift at every horizon.
pub fn drift_study(
    setup: &DriftSetup<'_>,
    compensations: &[(&str, &crate::sensor::ArrayParams)],
    horizons_s: &[f64],
) -> Result<Vec<DriftRow>, crate::array::RankError> {
    use rand::SeedableRng;
    let gravity_i = nalgebra::Vector3::new(0.0, 0.0, -setup.gravity_m_s2);
    let mut rows = Vec::new();
    for (name, params) in compensations {
        let compensator = crate::sensor::Compensator::new(setup.array, params)?;
        let mut source = crate::sensor::SimulatedArray::new(setup.array, setup.truth, setup.trajectory, gravity_i);
        if !setup.noise.is_zero() {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(setup.noise_seed);
            let generator =
                crate::sensor::NoiseGenerator::new(&setup.noise, setup.array.len(), 1.0 / setup.step_s, &mut rng);
            source = source.with_noise(generator, rng, setup.noise.quantization_m_s2);
        }
        let samples =
            super::navigate(setup.trajectory, &mut source, &compensator, &gravity_i, setup.step_s, horizons_s);
        rows.extend(samples.into_iter().map(|sample| DriftRow { compensation: (*name).to_string(), sample }));
    }
    Ok(rows)
}
