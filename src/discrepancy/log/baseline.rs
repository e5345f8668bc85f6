//! The baseline fit of a calibration log, and where and how much it disagrees with the
//! measurements.
//!
//! The noise level is estimated within steps (pooled sample variance of each output about its
//! step mean, input-referred), independently of the model. Step means are whitened by it:
//! `z_sj = (mean_sj - model_sj) / (k_j sigma / sqrt(n_s))`, and the gap is
//! `chi^2 / dof = sum z^2 / (S N - p)`, which is about 1 when the model explains the means and
//! grows with an unmodelled effect.

use super::data::CalibrationLog;
use crate::array::Array;
use crate::calib::estimate::CalibError;
use crate::calib::joint::{Start, estimate};
use crate::calib::params::{Form, Layout, PER_ACCEL};
use crate::calib::{Estimate, Measurements};
use crate::sensor::ArrayParams;
use crate::stats::chi2_sf;

/// The baseline model fitted to a log, and its disagreement with it.
#[derive(Debug, Clone)]
pub struct BaselineFit {
    pub estimate: Estimate,
    /// Per-sample noise estimated within steps, input-referred, m/s^2.
    pub noise_sigma_m_s2: f64,
    /// Whitened residual of each step mean: `[step][accelerometer]`.
    pub whitened: Vec<Vec<f64>>,
    pub chi2: f64,
    pub dof: usize,
    /// Probability of a chi-square at least this large if the model were right.
    pub p_value: f64,
}

impl BaselineFit {
    pub fn chi2_per_dof(&self) -> f64 {
        self.chi2 / self.dof as f64
    }
}

/// Why a log cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DiagnoseError {
    #[error(
        "the log has {steps} steps; the baseline fit needs at least {needed} (7 parameters per accelerometer and one degree of freedom for the test)"
    )]
    TooShort { steps: usize, needed: usize },
    #[error("the log's steps do not make a schedule: {0}")]
    Schedule(#[from] crate::calib::ScheduleError),
    #[error(transparent)]
    Calib(#[from] CalibError),
    #[error(
        "the log has no within-step scatter to estimate the noise from (every step has one sample, or the outputs are constant)"
    )]
    NoNoise,
}

/// Pooled within-step noise, input-referred with scale factors `k`.
pub fn within_step_sigma(meas: &Measurements, k: &[f64]) -> Option<f64> {
    let (mut ss, mut dof) = (0.0, 0usize);
    for s in &meas.steps {
        if s.samples < 2 {
            continue;
        }
        for (j, v) in s.within_ss.iter().enumerate() {
            ss += v / (k[j] * k[j]);
            dof += s.samples - 1;
        }
    }
    (dof > 0 && ss > 0.0).then(|| (ss / dof as f64).sqrt())
}

/// Fits the baseline model (bias, scale factor, misalignment, location of each accelerometer)
/// to a log and measures the gap. `nominal` gives the starting scale factors.
pub fn fit_baseline(
    log: &CalibrationLog,
    array: &Array,
    nominal: &ArrayParams,
    form: Form,
    g_m_s2: f64,
) -> Result<BaselineFit, DiagnoseError> {
    let needed = PER_ACCEL + 1;
    if log.steps.len() < needed {
        return Err(DiagnoseError::TooShort { steps: log.steps.len(), needed });
    }
    let schedule = log.schedule()?;
    let meas = log.measurements();
    let layout = Layout::new(array, form).map_err(CalibError::from)?;
    let estimate = estimate(&layout, &schedule, &meas, nominal, Start::Linear, g_m_s2)?;
    let k: Vec<f64> = estimate.params.sensors.iter().map(|s| s.scale_factor).collect();
    let sigma = within_step_sigma(&meas, &k).ok_or(DiagnoseError::NoNoise)?;
    let n = array.len();
    let mut out = vec![0.0; n];
    let mut whitened = Vec::with_capacity(schedule.len());
    let mut chi2 = 0.0;
    for (step, m) in schedule.steps().iter().zip(&meas.steps) {
        layout.step_model(&estimate.x, step, g_m_s2, &mut out, None);
        let z: Vec<f64> =
            (0..n).map(|j| (m.mean[j] - out[j]) / (k[j].abs() * sigma / (m.samples as f64).sqrt())).collect();
        chi2 += z.iter().map(|v| v * v).sum::<f64>();
        whitened.push(z);
    }
    let dof = schedule.len() * n - layout.len();
    let p_value = chi2_sf(chi2, dof as f64).unwrap_or(f64::NAN);
    Ok(BaselineFit { estimate, noise_sigma_m_s2: sigma, whitened, chi2, dof, p_value })
}
