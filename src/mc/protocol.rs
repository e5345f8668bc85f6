//! A `gfcal run` cell on the hand-held protocol of a real array (`selfcal`): poses placed by hand
//! in random directions, then a smooth random rotation phase, calibrated with no rate table and
//! (unless `use_gyro`) no gyroscope. Replaces `[schedule]` in a run config:
//!
//! ```toml
//! [protocol]
//! poses = 20                  # static poses placed by hand (random directions)
//! pose_s = 22.0               # still time per pose
//! transition_s = 3.0          # carrying the board between poses
//! dynamic_s = 100.0           # the rotation phase
//! rate_rms_rad_s = 25.0       # RMS angular rate of the rotation phase
//! accel_rms_m_s2 = 30.0       # RMS acceleration of the origin in the rotation phase
//! sample_rate_hz = 62.5
//! use_gyro = false            # true: the rate from the reference gyroscopes of the array file
//! gyro_noise_sigma_rad_s = 0.01
//! ```
//!
//! The array is an array file (`[array] file = ...`; its ranges clip the simulated outputs), the
//! form is `tilt` (the parameters of `gfcal calibrate`), and `[noise]` gives the white noise of
//! one sample at the protocol's rate. Each trial draws its errors from `[errors]`, moves them onto
//! the gauge (`selfcal::simulate::project_to_gauge`), simulates a recording, calibrates it with
//! `selfcal::calibrate`, and records the Cramer-Rao bound at its truth on the samples the
//! calibration used.

use nalgebra::DVector;
use rand::Rng;
use serde::Deserialize;

use crate::calib::params::Layout;
use crate::calib::{Estimate, FitStatus};
use crate::config::{Bad, positive};
use crate::selfcal::calibrate::{CalibrateSettings, calibrate};
use crate::selfcal::model::{PER_ACCEL, SensorSet};
use crate::selfcal::recording::RecordingArray;
use crate::selfcal::simulate::{Protocol, bound_at_truth, project_to_gauge, simulate};

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProtocolSection {
    pub poses: usize,
    pub pose_s: f64,
    pub transition_s: f64,
    pub dynamic_s: f64,
    pub rate_rms_rad_s: f64,
    pub accel_rms_m_s2: f64,
    pub sample_rate_hz: f64,
    #[serde(default)]
    pub use_gyro: bool,
    pub gyro_noise_sigma_rad_s: Option<f64>,
}

/// A checked protocol with its recording array.
#[derive(Debug, Clone)]
pub struct ProtocolCell {
    pub protocol: Protocol,
    pub array: RecordingArray,
    pub use_gyro: bool,
}

impl ProtocolSection {
    /// Checks the section; `noise_sigma_m_s2` is the white noise of one sample at its rate.
    pub fn resolve(
        &self,
        array: RecordingArray,
        noise_sigma_m_s2: f64,
        gravity_m_s2: f64,
    ) -> Result<ProtocolCell, Bad> {
        if self.poses < 4 {
            return Err(Bad::new(
                "protocol.poses",
                format!("a calibration needs at least 4 poses, got {}", self.poses),
            ));
        }
        let rate = positive("protocol.sample_rate_hz", self.sample_rate_hz)?;
        let pose_s = positive("protocol.pose_s", self.pose_s)?;
        // The segmentation keeps still runs of 5 s and trims 1 s from each end.
        if pose_s < 7.0 {
            return Err(Bad::new(
                "protocol.pose_s",
                format!(
                    "poses of {pose_s} s are too short: still runs of at least 7 s are found and trimmed (5 s + 2 x 1 s)"
                ),
            ));
        }
        let dynamic_s = positive("protocol.dynamic_s", self.dynamic_s)?;
        if dynamic_s < 10.0 {
            return Err(Bad::new(
                "protocol.dynamic_s",
                format!("a rotation phase of {dynamic_s} s is shorter than the 10 s the segmentation needs"),
            ));
        }
        if self.use_gyro && array.gyroscopes.is_empty() {
            return Err(Bad::new(
                "protocol.use_gyro",
                format!("the array file {} lists no reference gyroscopes", array.path.display()),
            ));
        }
        if noise_sigma_m_s2.is_nan() || noise_sigma_m_s2 <= 0.0 {
            return Err(Bad::new(
                "noise",
                "a protocol run needs white noise (the bound and the segmentation scale with it)",
            ));
        }
        let n = array.array.len();
        let gyro = match self.gyro_noise_sigma_rad_s {
            Some(v) => positive("protocol.gyro_noise_sigma_rad_s", v)?,
            None => 0.01,
        };
        Ok(ProtocolCell {
            protocol: Protocol {
                poses: self.poses,
                pose_s,
                transition_s: positive("protocol.transition_s", self.transition_s)?,
                dynamic_s,
                rate_rms_rad_s: positive("protocol.rate_rms_rad_s", self.rate_rms_rad_s)?,
                accel_rms_m_s2: positive("protocol.accel_rms_m_s2", self.accel_rms_m_s2)?,
                motion_band_hz: crate::selfcal::simulate::MOTION_BAND_HZ,
                sample_rate_hz: rate,
                noise_sigma_m_s2: vec![noise_sigma_m_s2; n],
                gyro_noise_sigma_rad_s: gyro,
                gravity_m_s2,
            },
            array,
            use_gyro: self.use_gyro,
        })
    }
}

/// Moves a sampled truth (tilt-form layout vector) onto the gauge the calibration estimates in.
pub fn truth_in_gauge(cell: &ProtocolCell, x: &DVector<f64>) -> DVector<f64> {
    let mut t = SensorSet::from_vector(x.as_slice());
    project_to_gauge(&cell.array.array, &mut t);
    DVector::from_vec(t.to_vector())
}

/// Simulates and calibrates one recording; the estimate (tilt form) and the Cramer-Rao sigma of
/// every parameter at the truth (NaN where the calibration failed).
pub fn calibrate_one<R: Rng + ?Sized>(
    cell: &ProtocolCell,
    layout: &Layout,
    x_true: &DVector<f64>,
    rng: &mut R,
) -> (Result<Estimate, String>, Vec<f64>) {
    let p = layout.len();
    let truth = SensorSet::from_vector(x_true.as_slice());
    let sim = match simulate(&cell.array, &truth, &cell.protocol, rng) {
        Ok(s) => s,
        Err(e) => return (Err(format!("simulation: {e}")), vec![f64::NAN; p]),
    };
    let settings = CalibrateSettings { use_gyro: cell.use_gyro, ..CalibrateSettings::default() };
    let cal = match calibrate(&sim.recording, &cell.array, &settings) {
        Ok(c) => c,
        Err(e) => return (Err(format!("calibration: {e}")), vec![f64::NAN; p]),
    };
    let sigma = &cell.protocol.noise_sigma_m_s2;
    let g = cell.protocol.gravity_m_s2;
    let crb: Vec<f64> = match bound_at_truth(&cell.array, &sim, &cal, &truth, sigma, g, cell.use_gyro) {
        Ok((cov, _)) => (0..p).map(|i| cov[(i, i)].max(0.0).sqrt()).collect(),
        Err(_) => vec![f64::NAN; p],
    };
    let fit = &cal.fit;
    let x = DVector::from_vec(fit.params.to_vector());
    let covariance = fit.covariance.view((0, 0), (p, p)).clone_owned();
    let residual = fit.dynamic_residual_rms_m_s2.iter().copied().fold(0.0_f64, |a, b| a.max(b));
    let status = FitStatus {
        converged: fit.converged,
        iterations: fit.iterations,
        cost: f64::NAN,
        condition_number: f64::NAN,
        message: format!(
            "{} poses found; static chi2/dof {:.3}, dynamic chi2/dof {:.3}",
            cal.segmentation.static_intervals.len(),
            fit.static_chi2_dof,
            fit.dynamic_chi2_dof
        ),
    };
    debug_assert_eq!(p, PER_ACCEL * cell.array.array.len());
    let estimate = Estimate {
        form: layout.form(),
        params: layout.unpack(&x),
        x,
        covariance,
        residual_sigma_m_s2: residual,
        status,
    };
    (Ok(estimate), crb)
}
