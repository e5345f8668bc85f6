//! The drift study of `gfcal drift`: one array with true parameters navigated along a trajectory
//! once per compensation, and its table as CSV.

use super::drift::DriftSample;

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
        let mut source = super::source::SimulatedArray::new(setup.array, setup.truth, setup.trajectory, gravity_i);
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

/// The drift table as CSV: one row per compensation and horizon.
pub fn drift_csv(rows: &[DriftRow]) -> String {
    let mut s =
        String::from("compensation,horizon_s,rate_err_rad_s,attitude_err_rad,velocity_err_m_s,position_err_m\n");
    for r in rows {
        let d = &r.sample;
        s.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e}\n",
            r.compensation, d.horizon_s, d.rate_err_rad_s, d.attitude_err_rad, d.velocity_err_m_s, d.position_err_m
        ));
    }
    s
}
