//! Held-out prediction: a calibration of one recording applied to another recording of the same
//! array, with only what must differ between recordings refitted there (the pose directions of
//! the static intervals and the motion of every dynamic sample). The residuals against the
//! noise say whether the calibration carries over.

use nalgebra::Vector3;

use super::calibrate::{
    CalibrateError, CalibrateSettings, Calibration, bias_drift_taken_out, gyroscope_clocks, prepare_dynamic,
    static_data,
};
use super::data::{DynamicData, StaticData};
use super::model::{SampleMotion, SensorSet, sensors};
use super::recording::Recording;
use super::segment::{DetectorSettings, segment};
use super::timing::ClockProblem;
use super::track;
use crate::array::Array;
use crate::array::wiring::RecordingArray;
use crate::sensor::misalignment::tilt_basis;

/// Residuals of a held-out recording.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOut {
    pub static_intervals: usize,
    /// RMS over intervals and accelerometers of the static mean's residual, m/s^2.
    pub static_residual_rms_m_s2: f64,
    /// RMS of the static mean's noise, `sigma_j / sqrt(n_p)`, m/s^2.
    pub static_noise_rms_m_s2: f64,
    /// `sum (r / (sigma_j / sqrt(n_p)))^2 / (N P - 2 P)`.
    pub static_chi2_dof: f64,
    pub dynamic_samples: usize,
    /// RMS of the dynamic residuals, m/s^2, against the per-sample static noise RMS.
    pub dynamic_residual_rms_m_s2: f64,
    pub dynamic_noise_rms_m_s2: f64,
    /// The rotation-phase chi^2/dof with the motion tracked there ([`super::misfit`]: the same
    /// metric as `calibrate`'s); NaN without a rotation phase.
    pub dynamic_chi2_dof: f64,
    /// Whether the recording's own bias drift in time was taken out before the prediction
    /// ([`predict_held_out`]).
    pub bias_drift_removed: bool,
    /// Where the array file declares sample clocks ([`predict_held_out`]): the share of the
    /// rotation phase's weighted misfit that the timing model removes with the recording's own
    /// gyroscopes' clocks, each sample's motion refitted with it
    /// (`timing::ClockProblem::share_removed_motion_refitted`). A recording's clocks are its
    /// own (their phases and common rate differ between recordings), so the misfit above is the
    /// prediction without them; what this share leaves bounds what the calibration does not carry
    /// over (it holds the recording's own unmodelled misfit too, and the timing model's six
    /// unknowns a sample remove about 0.4 of a misfit without any clock). `None` without declared
    /// clocks, and where the recording has no rotation phase, no gyroscope in every package, or
    /// clocks its gyroscopes do not resolve.
    pub own_clocks_share_removed: Option<f64>,
}

/// What a held-out recording refits besides the motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refit {
    /// The pose directions only (the calibration carries over whole).
    Pose,
    /// The pose directions and every accelerometer's bias (a turn-on bias: the bias differs
    /// between recordings).
    PoseAndBias,
    /// The pose directions, and every accelerometer's bias and scale factor.
    PoseBiasAndScale,
}

/// Predicts `rec` with `params` (see the module docs), refitting the pose directions.
pub fn predict(
    array: &Array,
    params: &SensorSet,
    rec: &Recording,
    detector: &DetectorSettings,
    gravity_m_s2: f64,
) -> Result<HeldOut, super::recording::RecordingError> {
    predict_refitting(array, params, rec, detector, gravity_m_s2, Refit::Pose)
}

/// Whether `rec` can be predicted: it segments, and no output of a static interval is at its range.
/// The commands check their held-out recordings so before any fit, so that a bad one is refused
/// at once rather than after the calibration.
pub fn check_predictable(rec: &Recording, detector: &DetectorSettings) -> Result<(), super::recording::RecordingError> {
    let seg = segment(rec, detector)?;
    static_data(rec, &seg.static_intervals)
        .map(|_| ())
        .map_err(|problem| super::recording::RecordingError::Unusable { path: rec.path.clone(), problem })
}

/// Predicts `rec` as `cal` was fitted: its parameters, the motion of every sample tracked with
/// its per-accelerometer weights and (with `--use-gyro`) the rate from the gyroscopes; refitting
/// what `refit` says. The held-out predictions of `calibrate` and `diagnose` are these, so that
/// their rotation-phase chi^2/dof is the fitting recording's metric measured alike.
pub fn predict_as_fitted(
    array: &Array,
    cal: &super::calibrate::Calibration,
    rec: &Recording,
    detector: &DetectorSettings,
    gravity_m_s2: f64,
    refit: Refit,
) -> Result<(HeldOut, HeldOutState), super::recording::RecordingError> {
    let dynamic_w = cal.fit.dynamic_weights();
    predict_with_state(array, &cal.fit.params, rec, detector, gravity_m_s2, refit, Some(&dynamic_w), cal.use_gyro)
}

/// A held-out recording predicted as `gfcal calibrate --held-out` predicts it: as `cal` was
/// fitted, the pose directions refitted, and with its own bias drift in time taken out first
/// where the calibration took the fitting recording's out (`settings.remove_bias_drift`): the
/// drift is each recording's own, as its turn-on bias is, and `gfcal diagnose
/// --remove-bias-drift` treats its held-out recordings so. A recording whose drift cannot be
/// fitted (too few poses) is predicted as it is (`bias_drift_removed` false).
pub fn predict_held_out(
    array: &RecordingArray,
    cal: &Calibration,
    rec: &Recording,
    settings: &CalibrateSettings,
) -> Result<HeldOut, CalibrateError> {
    let as_fitted = |rec: &Recording| {
        let (mut held, state) =
            predict_as_fitted(&array.array, cal, rec, &settings.detector, settings.fit.gravity_m_s2, Refit::Pose)?;
        held.own_clocks_share_removed = own_clocks_share_removed(array, cal, rec, &state, settings);
        Ok::<HeldOut, CalibrateError>(held)
    };
    if !settings.remove_bias_drift {
        return as_fitted(rec);
    }
    let (corrected, drift) = bias_drift_taken_out(rec, array, settings)?;
    let mut held = as_fitted(&corrected)?;
    held.bias_drift_removed = drift.is_ok();
    Ok(held)
}

/// [`HeldOut::own_clocks_share_removed`] of `rec` predicted as `state` (with `cal`'s weights):
/// its packages' clocks from its own gyroscopes (`calibrate::gyroscope_clocks`, as `gfcal
/// diagnose` scores its held-out recordings' own clocks).
fn own_clocks_share_removed(
    array: &RecordingArray,
    cal: &Calibration,
    rec: &Recording,
    state: &HeldOutState,
    settings: &CalibrateSettings,
) -> Option<f64> {
    if !array.has_sample_clocks() {
        return None;
    }
    let d = state.dynamic.as_ref().filter(|d| d.samples() > 0 && d.samples() == state.motion.len())?;
    let clocks = gyroscope_clocks(rec, array, settings).ok()?;
    let weights = cal.fit.dynamic_weights();
    let package_of = array.package_indices();
    let sens = sensors(&array.array, &state.params);
    let problem = ClockProblem::new(&sens, d, &state.motion, &weights, &package_of);
    let rate_given = d.reference_rate_rad_s.is_some();
    let (share, _) = problem.share_removed_motion_refitted(&sens, &state.motion, rate_given, &clocks, &[]);
    share.is_finite().then_some(share)
}

/// Predicts `rec` with `params`, refitting what `refit` says.
pub fn predict_refitting(
    array: &Array,
    params: &SensorSet,
    rec: &Recording,
    detector: &DetectorSettings,
    gravity_m_s2: f64,
    refit: Refit,
) -> Result<HeldOut, super::recording::RecordingError> {
    predict_with_state(array, params, rec, detector, gravity_m_s2, refit, None, false).map(|(h, _)| h)
}

/// The state of a held-out recording at the carried-over (and refitted) parameters: what a
/// linearised test of further effects needs.
#[derive(Debug, Clone)]
pub struct HeldOutState {
    /// The carried-over parameters with the refitted ones replaced.
    pub params: SensorSet,
    pub stat: StaticData,
    /// Middle time of each static interval, s.
    pub static_t_s: Vec<f64>,
    pub up: Vec<Vector3<f64>>,
    pub dynamic: Option<DynamicData>,
    pub motion: Vec<SampleMotion>,
    /// The recording's middle time, s.
    pub t_mid_s: f64,
}

/// As [`predict_refitting`], and the state. The dynamic motion is tracked with the weights
/// `dynamic_w` (per accelerometer) when given, else with the static noise's; with `use_gyro`, the
/// rate is the reference gyroscopes' (bias from the static intervals) and a sample where one clips
/// is left out, as in `calibrate --use-gyro`.
#[allow(clippy::too_many_arguments)]
pub fn predict_with_state(
    array: &Array,
    params: &SensorSet,
    rec: &Recording,
    detector: &DetectorSettings,
    gravity_m_s2: f64,
    refit: Refit,
    dynamic_w: Option<&[f64]>,
    use_gyro: bool,
) -> Result<(HeldOut, HeldOutState), super::recording::RecordingError> {
    let seg = segment(rec, detector)?;
    let stat = static_data(rec, &seg.static_intervals)
        .map_err(|problem| super::recording::RecordingError::Unusable { path: rec.path.clone(), problem })?;
    let n = array.len();
    let mut params = params.clone();
    let poses = stat.means.nrows();
    let total: f64 = stat.counts.iter().map(|&c| c as f64).sum();
    if refit != Refit::Pose && poses > 0 {
        // Alternately the poses given the sensors and the sensors given the poses: each
        // accelerometer's bias (and with `PoseBiasAndScale` its scale factor) by count-weighted
        // least squares of its interval means on its input `a . u g`.
        for _ in 0..500 {
            let sens = sensors(array, &params);
            let ups: Vec<Vector3<f64>> = (0..poses).map(|p| solve_pose(&sens, &stat, p, gravity_m_s2)).collect();
            let mut largest = 0.0f64;
            for (j, s) in sens.iter().enumerate() {
                let w = |p: usize| stat.counts[p] as f64;
                let x = |p: usize| s.axis.dot(&(ups[p] * gravity_m_s2));
                let y = |p: usize| stat.means[(p, j)];
                let mx = (0..poses).map(|p| w(p) * x(p)).sum::<f64>() / total;
                let my = (0..poses).map(|p| w(p) * y(p)).sum::<f64>() / total;
                let sxx: f64 = (0..poses).map(|p| w(p) * (x(p) - mx).powi(2)).sum();
                let k = if refit == Refit::PoseBiasAndScale && sxx > 0.0 {
                    (0..poses).map(|p| w(p) * (x(p) - mx) * (y(p) - my)).sum::<f64>() / sxx
                } else {
                    s.k
                };
                let b = my / k - mx;
                largest = largest.max((b - params.bias_m_s2[j]).abs()).max((k - params.scale_factor[j]).abs());
                params.bias_m_s2[j] = b;
                params.scale_factor[j] = k;
            }
            if largest < 1e-13 {
                break;
            }
        }
    }
    let sens = sensors(array, &params);
    let mut ss = 0.0;
    let mut noise = 0.0;
    let mut chi2 = 0.0;
    let up: Vec<Vector3<f64>> = (0..poses).map(|p| solve_pose(&sens, &stat, p, gravity_m_s2)).collect();
    for (p, &u) in up.iter().enumerate() {
        for (j, s) in sens.iter().enumerate() {
            let r = stat.means[(p, j)] - s.output(&(u * gravity_m_s2));
            let sd = stat.sigma[j] / (stat.counts[p] as f64).sqrt();
            ss += r * r;
            noise += sd * sd;
            chi2 += (r / sd).powi(2);
        }
    }
    let count = (poses * n) as f64;
    // The refitted parameters (their values are the state's `params`).
    let refitted = match refit {
        _ if poses == 0 => 0,
        Refit::Pose => 0,
        Refit::PoseAndBias => n,
        Refit::PoseBiasAndScale => 2 * n,
    };
    let fitted = 2.0 * poses as f64 + refitted as f64;
    let prepared = if use_gyro {
        prepare_dynamic(rec, &seg, true, super::gyro_check::gyro_bias(rec, &seg))
    } else {
        prepare_dynamic(rec, &seg, false, None)
    };
    let static_w: Vec<f64> = stat.sigma.iter().map(|s| 1.0 / (s * s)).collect();
    let weights = dynamic_w.unwrap_or(&static_w);
    let mut prepared = prepared;
    let mut motion = match prepared.data.as_ref() {
        Some(d) => track::from_scratch(array, d, weights, &params),
        None => Vec::new(),
    };
    // With the accelerometers lagging the gyroscopes, the rate refined to first order from the
    // tracked angular acceleration and the motion tracked again (as `calibrate` refits).
    if let (Some(d), Some(b)) = (prepared.data.as_mut(), super::gyro_check::gyro_bias(rec, &seg))
        && use_gyro
        && rec.accelerometer_lag_s != 0.0
        && motion.len() == prepared.index.len()
    {
        let chi2 = |d: &DynamicData, motion: &[SampleMotion]| {
            let (rms, _) = super::misfit::residual_rms(array, &params, d, motion);
            super::misfit::chi2_dof(d, &rms, &stat.sigma)
        };
        let behind = DynamicData {
            reference_rate_rad_s: Some(super::lag::rates_behind(rec, &prepared.index, &b, &motion)),
            ..d.clone()
        };
        let again = track::from_scratch(array, &behind, weights, &params);
        // kept where it fits better, as `calibrate` keeps its refit
        if chi2(&behind, &again) < chi2(d, &motion) {
            *d = behind;
            motion = again;
        }
    }
    let (dyn_rms, dyn_noise, dyn_samples) = match prepared.data.as_ref() {
        Some(d) => dynamic_residual(array, &params, d, &motion, &stat.sigma),
        None => (f64::NAN, f64::NAN, 0),
    };
    let dyn_chi2_dof = match prepared.data.as_ref() {
        Some(d) if d.samples() > 0 => {
            let (rms, _) = super::misfit::residual_rms(array, &params, d, &motion);
            super::misfit::chi2_dof(d, &rms, &stat.sigma)
        }
        _ => f64::NAN,
    };
    let static_t_s = seg.static_intervals.iter().map(|iv| rec.t_s[(iv.start + iv.end) / 2]).collect();
    let t_mid_s = match (rec.t_s.first(), rec.t_s.last()) {
        (Some(a), Some(b)) => 0.5 * (a + b),
        _ => 0.0,
    };
    let held = HeldOut {
        static_intervals: poses,
        static_residual_rms_m_s2: (ss / count).sqrt(),
        static_noise_rms_m_s2: (noise / count).sqrt(),
        static_chi2_dof: chi2 / (count - fitted).max(1.0),
        dynamic_samples: dyn_samples,
        dynamic_residual_rms_m_s2: dyn_rms,
        dynamic_noise_rms_m_s2: dyn_noise,
        dynamic_chi2_dof: dyn_chi2_dof,
        bias_drift_removed: false,
        own_clocks_share_removed: None,
    };
    let state = HeldOutState { params, stat, static_t_s, up, dynamic: prepared.data, motion, t_mid_s };
    Ok((held, state))
}

/// The up direction of static interval `p` given the sensors: Gauss-Newton on two tangent angles.
pub fn solve_pose(
    sens: &[super::model::Sensor],
    stat: &super::data::StaticData,
    p: usize,
    gravity_m_s2: f64,
) -> Vector3<f64> {
    let normal: nalgebra::Matrix3<f64> = sens.iter().map(|s| s.axis * s.axis.transpose()).sum();
    let b: Vector3<f64> = sens.iter().enumerate().map(|(j, s)| s.axis * (stat.means[(p, j)] / s.k - s.b_m_s2)).sum();
    let mut u = normal.try_inverse().map(|m| m * b).unwrap_or_else(Vector3::z).normalize();
    for _ in 0..20 {
        let (e1, e2) = tilt_basis(&u);
        let mut h = nalgebra::Matrix2::zeros();
        let mut g = nalgebra::Vector2::zeros();
        for (j, s) in sens.iter().enumerate() {
            let w = stat.counts[p] as f64 / stat.sigma[j].powi(2);
            let r = stat.means[(p, j)] - s.output(&(u * gravity_m_s2));
            let d = nalgebra::Vector2::new(s.k * gravity_m_s2 * s.axis.dot(&e1), s.k * gravity_m_s2 * s.axis.dot(&e2));
            h += d * d.transpose() * w;
            g += d * (w * r);
        }
        let Some(step) = h.try_inverse().map(|hi| hi * g) else { break };
        u = (u + e1 * step[0] + e2 * step[1]).normalize();
        if step.norm() < 1e-12 {
            break;
        }
    }
    u
}

fn dynamic_residual(
    array: &Array,
    params: &SensorSet,
    d: &DynamicData,
    motion: &[SampleMotion],
    sigma: &[f64],
) -> (f64, f64, usize) {
    let sens = sensors(array, params);
    let n = array.len();
    let mut ss = 0.0;
    let mut noise = 0.0;
    let mut count = 0.0;
    for (i, m) in motion.iter().enumerate() {
        for (j, s) in sens.iter().enumerate() {
            if d.used[i * n + j] {
                ss += (d.outputs[(i, j)] - s.output(&m.specific_force_m_s2(&s.position_m))).powi(2);
                noise += sigma[j] * sigma[j];
                count += 1.0;
            }
        }
    }
    ((ss / count).sqrt(), (noise / count).sqrt(), d.samples())
}
