//! Diagnosis of real recordings (free hand-held calibrations, `gfcal calibrate`'s input): the
//! baseline model's gap on the recording it is fitted to and on held-out recordings of the same
//! array, for the static and the dynamic phase, and the per-recording effects that close part of
//! it.
//!
//! **The gap.** Static phase: chi-square per degree of freedom of the interval means against the
//! pooled within-interval noise, with the pose directions (and whatever a named per-recording
//! effect says) refitted; on the fitting recording, the fit's own chi-square per degree of freedom.
//! Dynamic phase: `(residual RMS / static noise RMS)^2` of every unclipped output, with the motion
//! of every sample tracked with the model's parameters, on the fitting and the held-out
//! recordings alike; about 1 for a model that explains the rotation phase as well as the noise. A
//! gap above [`GAP_ABOVE_NOISE`] is more than the noise.
//!
//! **Held-out scoring.** The calibration of the fitting recording is applied to each held-out
//! recording with only what must differ between recordings refitted there: the pose directions,
//! the motion, and the parameters of the per-recording effects under test. An effect is named
//! only if it lowers the static gap on *every* held-out recording and its refitted parameters
//! differ from the fitting recording's on every one by a chi-square test at the familywise level
//! `alpha` (Bonferroni over the held-out recordings; the changes' covariance carries the fitting
//! recording's whole uncertainty: see [`super::recorded_change`]).
//!
//! **Effects tried so far:** `bias_turn_on`, a bias that differs between recordings (each
//! accelerometer's bias refitted on the held-out recording's static intervals), then, on top of
//! it, `scale_factor_turn_on` (the scale factors refitted as well). The rest of the
//! library (sensing point per axis, sampling delays, input-dependent scale factors, cross-axis
//! sensitivity, warm-up drift, the gyroscopes' own errors) is not yet tried on recordings: what
//! is left of the gap is reported as unexplained.

use std::path::PathBuf;

use nalgebra::DMatrix;

use super::diagnose::Explanation;
use super::recorded_blocks::{Nuisance, RecordingState, accumulate_recording, refitted_columns};
use super::recorded_change::change_test;
use super::recorded_effect::{Layout, RecordedEffect};
use super::recorded_sensing::{SensingPoint, sensing_points};
use super::recorded_trial::{HeldOutNormal, RankTest, try_effects};
use crate::selfcal::calibrate::{CalibrateError, CalibrateSettings, Calibration, calibrate, prepare_dynamic};
use crate::selfcal::model::PER_ACCEL;
use crate::selfcal::predict::{HeldOut, HeldOutState, Refit, predict_refitting, predict_with_state};
use crate::selfcal::recording::{Recording, RecordingArray, RecordingError};

/// The gap of one recording, static and dynamic phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Chi-square per degree of freedom of the static interval means.
    pub static_chi2_dof: f64,
    /// `(dynamic residual RMS / static noise RMS)^2`; `None` without a rotation phase.
    pub dynamic: Option<f64>,
}

/// A held-out recording's gap before and after the named effects.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutScore {
    pub recording: PathBuf,
    pub before: Gap,
    pub after: Gap,
    /// The held-out recording's own bias minus the fitting recording's, per accelerometer, m/s^2,
    /// and its sigma.
    pub bias_change_m_s2: Vec<f64>,
    pub bias_change_sigma_m_s2: Vec<f64>,
    /// The held-out recording's own scale factor minus the fitting recording's, and its sigma
    /// (refitted with the biases).
    pub scale_factor_change: Vec<f64>,
    pub scale_factor_change_sigma: Vec<f64>,
    /// The p-values of "no change" of the biases and of the scale factors (Wald tests on the
    /// changes' whole covariance, [`super::recorded_change`]).
    pub bias_change_p_value: f64,
    pub scale_factor_change_p_value: f64,
    /// The gap after each named effect, in the order they were added.
    pub after_each: Vec<(String, Gap)>,
}

/// One effect named on recordings.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedFinding {
    pub name: String,
    /// What the values are (for a per-recording effect: the RMS over the held-out recordings of
    /// the change from the fitting recording).
    pub what: String,
    /// `None`: every accelerometer (the values are per accelerometer), or a package's or a shared
    /// effect.
    pub accelerometer: Option<usize>,
    /// The package (IMU, 0-based) of a per-package effect.
    pub package: Option<usize>,
    pub value: Vec<f64>,
    pub sigma: Vec<f64>,
    pub unit: String,
    /// The largest p-value over the held-out recordings of the effect's test (it must pass on
    /// every one).
    pub p_value_largest: f64,
}

/// A gap (static or dynamic) above this is more than the noise.
pub const GAP_ABOVE_NOISE: f64 = 2.0;

/// A whole diagnosis of recordings.
#[derive(Debug, Clone)]
pub struct RecordedDiagnosis {
    pub calibration: Calibration,
    /// The fitting recording's gap (the per-recording effects are fitted there already, so it is
    /// the same after).
    pub fitting: Gap,
    pub held_out: Vec<HeldOutScore>,
    pub findings: Vec<RecordedFinding>,
    /// The fitting recording's gap after each named effect of the library (linearised).
    pub fitting_after_each: Vec<(String, Gap)>,
    /// Effects tried and not named, with why.
    pub not_named: Vec<(String, String)>,
    /// The rank test of every effect of the library tried.
    pub ranks: Vec<RankTest>,
    /// The sensing points of the axes of each package.
    pub sensing_points: Vec<SensingPoint>,
    pub alpha: f64,
}

impl RecordedDiagnosis {
    /// Whether the named effects explain the gap (to the noise) on the held-out recordings and on
    /// the fitting one, part of it, or nothing was named.
    pub fn explanation(&self) -> Explanation {
        // Above the noise: a residual variance more than twice the noise's, in either phase. (A
        // held-out gap exceeds 1 by the fitting recording's own parameter uncertainty even for a
        // right model, so a chi-square test at the noise alone would always reject it.) Fixed before
        // any recording was diagnosed.
        let above = |g: &Gap| g.static_chi2_dof > GAP_ABOVE_NOISE || g.dynamic.is_some_and(|d| d > GAP_ABOVE_NOISE);
        let fitting = self.fitting_after_each.last().map_or(self.fitting, |(_, g)| *g);
        let remains = above(&fitting) || self.held_out.iter().any(|h| above(&h.after));
        match (self.findings.is_empty(), remains) {
            (true, false) => Explanation::NothingToExplain,
            (true, true) => Explanation::Unexplained,
            (false, true) => Explanation::Partial,
            (false, false) => Explanation::Complete,
        }
    }
}

/// Why recordings cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordedError {
    #[error(transparent)]
    Calibrate(#[from] CalibrateError),
    #[error(transparent)]
    Recording(#[from] RecordingError),
}

/// Diagnoses `fitting` with the `held_out` recordings of the same array (see the module docs).
pub fn diagnose_recordings(
    fitting: &Recording,
    array: &RecordingArray,
    held_out: &[Recording],
    settings: &CalibrateSettings,
    alpha: f64,
) -> Result<RecordedDiagnosis, RecordedError> {
    for other in held_out {
        fitting.same_array_as(other)?;
    }
    let calibration = calibrate(fitting, array, settings)?;
    let fit = &calibration.fit;
    let n = array.array.len();
    let g = settings.fit.gravity_m_s2;
    // The fitting recording's static gap is the fit's own (its degrees of freedom count every
    // fitted parameter); its dynamic gap is measured as on a held-out recording (the motion
    // tracked again with the fitted parameters), so that the two are the same quantity.
    let own = predict_refitting(&array.array, &fit.params, fitting, &settings.detector, g, Refit::Pose)?;
    let fitting_gap = Gap {
        static_chi2_dof: fit.static_chi2_dof,
        dynamic: (!fit.motion.is_empty()).then(|| own.dynamic_chi2_dof()).filter(|v| v.is_finite()),
    };
    let mut scores = Vec::with_capacity(held_out.len());
    let mut scaled_gaps = Vec::with_capacity(held_out.len());
    for other in held_out {
        let before = predict_refitting(&array.array, &fit.params, other, &settings.detector, g, Refit::Pose)?;
        let refitted = |refit: Refit| {
            predict_with_state(&array.array, &fit.params, other, &settings.detector, g, refit, None, false)
        };
        let (after, after_state) = refitted(Refit::PoseAndBias)?;
        let (scaled, scaled_state) = refitted(Refit::PoseBiasAndScale)?;
        let gap = |h: &HeldOut| Gap { static_chi2_dof: h.static_chi2_dof, dynamic: finite(h.dynamic_chi2_dof()) };
        let (gap_before, gap_after) = (gap(&before), gap(&after));
        scaled_gaps.push(gap(&scaled));
        let bias = refitted_columns(Nuisance::Bias, n);
        let bias_test = change_test(
            &static_normal(&array.array, &after_state, g, &bias),
            &bias,
            &bias,
            (0..n).map(|j| after_state.params.bias_m_s2[j] - fit.params.bias_m_s2[j]).collect(),
            &fit.covariance,
        );
        let both = refitted_columns(Nuisance::BiasAndScale, n);
        let scale: Vec<usize> = (0..n).map(|j| PER_ACCEL * j).collect();
        let scale_test = change_test(
            &static_normal(&array.array, &scaled_state, g, &both),
            &both,
            &scale,
            (0..n).map(|j| scaled_state.params.scale_factor[j] - fit.params.scale_factor[j]).collect(),
            &fit.covariance,
        );
        scores.push(HeldOutScore {
            recording: other.path.clone(),
            before: gap_before,
            after: gap_after,
            bias_change_m_s2: bias_test.change,
            bias_change_sigma_m_s2: bias_test.sigma,
            scale_factor_change: scale_test.change,
            scale_factor_change_sigma: scale_test.sigma,
            bias_change_p_value: bias_test.p_value,
            scale_factor_change_p_value: scale_test.p_value,
            after_each: Vec::new(),
        });
    }
    let mut findings = Vec::new();
    let mut not_named = Vec::new();
    let level = alpha / held_out.len().max(1) as f64;
    let largest = scores.iter().map(|s| s.bias_change_p_value).fold(0.0f64, f64::max);
    let lowers_every_gap = scores.iter().all(|s| s.after.static_chi2_dof < s.before.static_chi2_dof);
    if held_out.is_empty() {
        not_named.push(("bias_turn_on".into(), "needs held-out recordings (--held-out)".into()));
    } else if lowers_every_gap && largest < level {
        // The RMS over held-out recordings of each accelerometer's bias change, and the RMS of its sigma.
        let rms = |f: &dyn Fn(&HeldOutScore) -> f64| {
            (scores.iter().map(|s| f(s).powi(2)).sum::<f64>() / scores.len() as f64).sqrt()
        };
        findings.push(RecordedFinding {
            name: "bias_turn_on".into(),
            what: "RMS over the held-out recordings of the bias change from the fitting recording".into(),
            accelerometer: None,
            package: None,
            value: (0..n).map(|j| rms(&|s: &HeldOutScore| s.bias_change_m_s2[j])).collect(),
            sigma: (0..n).map(|j| rms(&|s: &HeldOutScore| s.bias_change_sigma_m_s2[j])).collect(),
            unit: "m/s^2".into(),
            p_value_largest: largest,
        });
    } else {
        not_named.push((
            "bias_turn_on".into(),
            format!(
                "does not lower the gap on every held-out recording at the familywise level {alpha} (largest p = {largest:.2e})"
            ),
        ));
    }
    let rms = |scores: &[HeldOutScore], f: &dyn Fn(&HeldOutScore) -> f64| {
        (scores.iter().map(|s| f(s).powi(2)).sum::<f64>() / scores.len().max(1) as f64).sqrt()
    };
    if findings.iter().any(|f| f.name == "bias_turn_on") {
        for s in &mut scores {
            s.after_each.push(("bias_turn_on".into(), s.after));
        }
        // Then the scale factor per recording, on top of the bias (nested: tried only after it).
        let largest = scores.iter().map(|s| s.scale_factor_change_p_value).fold(0.0f64, f64::max);
        let lowers = scores.iter().zip(&scaled_gaps).all(|(s, g)| g.static_chi2_dof < s.after.static_chi2_dof);
        if lowers && largest < level {
            findings.push(RecordedFinding {
                name: "scale_factor_turn_on".into(),
                what: "RMS over the held-out recordings of the scale-factor change from the fitting recording".into(),
                accelerometer: None,
                package: None,
                value: (0..n).map(|j| rms(&scores, &|s: &HeldOutScore| s.scale_factor_change[j])).collect(),
                sigma: (0..n).map(|j| rms(&scores, &|s: &HeldOutScore| s.scale_factor_change_sigma[j])).collect(),
                unit: "1".into(),
                p_value_largest: largest,
            });
            for (s, g) in scores.iter_mut().zip(&scaled_gaps) {
                s.after = *g;
                s.after_each.push(("scale_factor_turn_on".into(), *g));
            }
        } else {
            not_named.push((
                "scale_factor_turn_on".into(),
                format!(
                    "does not lower the gap on every held-out recording at the familywise level {alpha} on top of bias_turn_on (largest p = {largest:.2e})"
                ),
            ));
        }
    } else {
        for s in &mut scores {
            s.after = s.before;
        }
    }
    // Then the library, on top of the turn-on effects named.
    let named = |name: &str| findings.iter().any(|f| f.name == name);
    let (refit, nuisance_b) = if named("scale_factor_turn_on") {
        (Refit::PoseBiasAndScale, Nuisance::BiasAndScale)
    } else if named("bias_turn_on") {
        (Refit::PoseAndBias, Nuisance::Bias)
    } else {
        (Refit::Pose, Nuisance::Nothing)
    };
    let effects: Vec<RecordedEffect> =
        RecordedEffect::ALL.into_iter().filter(|e| settings.use_gyro || !e.needs_reference_rate()).collect();
    let layout = Layout::new(&array.array);
    let dynamic_w: Vec<f64> = fit.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect();
    let prepared = prepare_dynamic(fitting, &calibration.segmentation, settings.use_gyro, calibration.gyro_bias_rad_s);
    let static_t_s: Vec<f64> =
        calibration.segmentation.static_intervals.iter().map(|iv| fitting.t_s[(iv.start + iv.end) / 2]).collect();
    let state_a = RecordingState {
        array: &array.array,
        params: &fit.params,
        stat: &calibration.static_data,
        static_t_s: &static_t_s,
        up: &fit.up,
        static_variance_factor: fit.static_variance_factor,
        dynamic: prepared.data.as_ref(),
        motion: &fit.motion,
        dynamic_w: &dynamic_w,
        gravity_m_s2: g,
        t_mid_s: middle(&fitting.t_s),
    };
    let normal_a = accumulate_recording(&state_a, Nuisance::Baseline, None, &effects);
    let sensing = sensing_points(&normal_a.total(), &layout, &fit.params);
    let mut held = Vec::with_capacity(held_out.len());
    for (other, score) in held_out.iter().zip(&scores) {
        let (_, st) = predict_with_state(
            &array.array,
            &fit.params,
            other,
            &settings.detector,
            g,
            refit,
            Some(&dynamic_w),
            settings.use_gyro,
        )?;
        let state = held_state(&array.array, &st, g, &dynamic_w);
        // The baseline's layout, so that the fitting recording's change of every parameter with an
        // effect is carried over; only the turn-on parameters named are refitted here.
        let refit_b = refitted_columns(nuisance_b, array.array.len());
        held.push(HeldOutNormal {
            normal: accumulate_recording(&state, Nuisance::Baseline, Some(refit_b), &effects),
            gap: score.after,
        });
    }
    let trial = try_effects(&normal_a, fitting_gap, &held, &effects, &layout, alpha);
    for (s, each) in scores.iter_mut().zip(trial.held_out_after_each) {
        if let Some((_, g)) = each.last() {
            s.after = *g;
        }
        s.after_each.extend(each);
    }
    findings.extend(trial.findings);
    not_named.extend(trial.not_named);
    Ok(RecordedDiagnosis {
        calibration,
        fitting: fitting_gap,
        held_out: scores,
        findings,
        fitting_after_each: trial.fitting_after_each,
        not_named,
        ranks: trial.ranks,
        sensing_points: sensing,
        alpha,
    })
}

fn middle(t_s: &[f64]) -> f64 {
    match (t_s.first(), t_s.last()) {
        (Some(a), Some(b)) => 0.5 * (a + b),
        _ => 0.0,
    }
}

/// A held-out recording's state for `accumulate_recording` (its static means carry no variance
/// factor: their noise is measured on the recording itself).
fn held_state<'a>(
    array: &'a crate::array::Array,
    state: &'a HeldOutState,
    g: f64,
    dynamic_w: &'a [f64],
) -> RecordingState<'a> {
    RecordingState {
        array,
        params: &state.params,
        stat: &state.stat,
        static_t_s: &state.static_t_s,
        up: &state.up,
        static_variance_factor: 1.0,
        dynamic: state.dynamic.as_ref(),
        motion: &state.motion,
        dynamic_w,
        gravity_m_s2: g,
        t_mid_s: state.t_mid_s,
    }
}

/// The static normal matrix of a held-out recording at its refitted state, in the baseline's
/// layout with the pose angles eliminated (what the turn-on test needs).
fn static_normal(array: &crate::array::Array, state: &HeldOutState, g: f64, refit: &[usize]) -> DMatrix<f64> {
    let statics = RecordingState { dynamic: None, motion: &[], ..held_state(array, state, g, &[]) };
    accumulate_recording(&statics, Nuisance::Baseline, Some(refit.to_vec()), &[]).statics.normal
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}
