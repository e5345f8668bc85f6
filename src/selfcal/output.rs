//! The JSON of `gfcal calibrate` (SI units; keys fixed by the interface).
//!
//! `parameters: [{accelerometer, name, value, sigma, unit}]` (tilt-form misalignment, so
//! `scale_factor` is the gain along the true unit axis and `bias` is input-referred; `dx, dy, dz`
//! are location errors, true minus nominal position; `sigma` is null for a parameter the recording
//! cannot identify), `poses: [{start_s, end_s, up_x, up_y, up_z}]`, `static: {intervals,
//! chi2_dof, residual_rms_m_s2, tension}` (`tension: {chi2_dof_static_only, move_rms_sigma,
//! largest: {accelerometer, name, move_sigma}, pull_chi2, pull_dof, pull_p_value}` with a
//! rotation phase, else null:
//! `selfcal::tension`; `bias_drift: {t_mid_s, chi2_dof, chi2_dof_without, test_chi2, test_dof,
//! p_value, drifts, move_rms_sigma and sigma_over_printed: {scale_factor, bias, tilt_u, tilt_w}
//! (the refit's values less this calibration's in its printed sigmas, RMS; its sigmas over the
//! printed, median), rates:
//! [{accelerometer, rate_m_s2_per_s, rate_sigma_m_s2_per_s}], parameters: [{accelerometer, name,
//! value, sigma, unit}]}` with at least 6 poses, else null: `selfcal::static_drift`;
//! `bias_drift_removed`: the same for the drift taken out before the calibration (`gfcal
//! calibrate`'s default; null with `--keep-bias-drift`), and `bias_drift_note`: why it was not), `dynamic: {samples, clipped, residual_rms_m_s2}`, `gyro_check:
//! {samples, rms_rad_s, relative}` (when reference gyroscopes are given), and further keys that
//! say how the result was obtained. A parameter the recording cannot identify (a location without
//! a rotation phase, or one with a share in a combination the Fisher information cannot see beyond
//! the gauge) has `value` and `sigma` null and is named in `unidentified`; the combinations are in
//! `unseen_combinations: [{combination, components: [{parameter, weight}]}]` and what would make
//! them identifiable in `to_identify` (a list of sentences). With `--held-out`, `held_out:
//! [{recording, static_intervals, static_residual_rms_m_s2, static_noise_rms_m_s2, static_chi2_dof,
//! dynamic_samples, dynamic_residual_rms_m_s2, dynamic_noise_rms_m_s2, dynamic_chi2_dof,
//! bias_drift_removed, own_clocks_share_removed}]` (`selfcal::predict::HeldOut`; the last null
//! without declared sample clocks, and where the held-out recording has no rotation phase, no
//! gyroscope in every package, or clocks its gyroscopes do not resolve).

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use super::calibrate::Calibration;
use super::model::{NAMES, PER_ACCEL, UNITS};
use super::predict::HeldOut;
use super::recording::Recording;
use crate::array::wiring::RecordingArray;

fn num(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

/// The calibration as JSON.
pub fn to_json(cal: &Calibration, rec: &Recording, array: &RecordingArray) -> Value {
    let fit = &cal.fit;
    let n = rec.accelerometers();
    let mut parameters = Vec::new();
    let mut unidentified = Vec::new();
    for j in 0..n {
        for p in 0..PER_ACCEL {
            let sigma = fit.sigma(j, p);
            let identified = sigma.is_finite();
            if !identified {
                unidentified.push(format!("a{}.{}", j + 1, NAMES[p]));
            }
            parameters.push(json!({
                "accelerometer": j + 1,
                "name": NAMES[p],
                "value": if identified { json!(fit.params.get(j, p)) } else { Value::Null },
                "sigma": num(sigma),
                "unit": UNITS[p],
            }));
        }
    }
    let t = &rec.t_s;
    let poses: Vec<Value> = cal
        .segmentation
        .static_intervals
        .iter()
        .zip(&fit.up)
        .map(|(iv, u)| json!({"start_s": t[iv.start], "end_s": t[iv.end - 1], "up_x": u.x, "up_y": u.y, "up_z": u.z}))
        .collect();
    let interval = |iv: &super::segment::Interval| json!({"start_s": t[iv.start], "end_s": t[iv.end - 1], "length_s": t[iv.end - 1] - t[iv.start], "samples": iv.len()});
    let dyn_rms = {
        let v: Vec<f64> = fit.dynamic_residual_rms_m_s2.iter().copied().filter(|v| v.is_finite()).collect();
        if v.is_empty() { f64::NAN } else { (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt() }
    };
    let mut out = json!({
        "recording": rec.path.display().to_string(),
        "array": array.path.display().to_string(),
        "rate_source": if cal.use_gyro { "reference gyroscopes (--use-gyro)" } else { "accelerometers (gyroscope-free)" },
        "parameters": parameters,
        "unidentified": unidentified,
        "unseen_combinations": fit.unseen.iter().map(|c| json!({
            "combination": super::unseen::describe(c, n),
            "components": c.components.iter().map(|(i, w)| json!({"parameter": super::unseen::name(*i, n), "weight": w})).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "to_identify": cal.to_identify,
        "poses": poses,
        "static": {
            "intervals": cal.segmentation.static_intervals.len(),
            "chi2_dof": num(fit.static_chi2_dof),
            "residual_rms_m_s2": num(fit.static_residual_rms_m_s2),
            "variance_factor": num(fit.static_variance_factor),
            "noise_sigma_m_s2": cal.static_data.sigma,
            "tension": cal.static_tension.as_ref().map(|t| json!({
                "chi2_dof_static_only": num(t.chi2_dof_static_only),
                "move_rms_sigma": num(t.move_rms_sigma),
                "largest": t.largest.map(|(j, p, v)| json!({"accelerometer": j + 1, "name": NAMES[p], "move_sigma": num(v)})),
                "pull_chi2": num(t.pull_chi2),
                "pull_dof": t.pull_dof,
                "pull_p_value": num(t.pull_p_value),
            })),
            "bias_drift": cal.static_drift.as_ref().map(|d| bias_drift_json(d, cal)),
            "bias_drift_removed": cal.removed_bias_drift.as_ref().map(|d| bias_drift_json(d, cal)),
            "bias_drift_note": cal.bias_drift_note,
        },
        "dynamic": {
            "samples": cal.dynamic_index.len(),
            "clipped": cal.clipped_outputs,
            "dropped_samples": cal.dropped_samples,
            "residual_rms_m_s2": num(dyn_rms),
            "chi2_dof": num(fit.dynamic_chi2_dof),
            "residual_rms_by_accelerometer_m_s2": fit.dynamic_residual_rms_m_s2.iter().map(|v| num(*v)).collect::<Vec<_>>(),
        },
        "segmentation": {
            "from_step_column": cal.segmentation.from_step_column,
            "static_intervals": cal.segmentation.static_intervals.iter().map(interval).collect::<Vec<_>>(),
            "dynamic_intervals": cal.segmentation.dynamic_intervals.iter().map(interval).collect::<Vec<_>>(),
            "short_moving_runs_left_out": cal.segmentation.short_moving_runs,
        },
        "gauge": {
            "null_directions": fit.null_directions,
            "expected_null_directions": fit.gauge.null_count(),
            "unseen_beyond_gauge": fit.unseen.len(),
            "conditions": fit.gauge.describe(),
        },
        "fit": {"iterations": fit.iterations, "converged": fit.converged},
    });
    if let Some(g) = &cal.gyro_check {
        out["gyro_check"] = json!({
            "samples": g.samples,
            "rms_rad_s": num(g.rms_rad_s),
            "relative": num(g.relative),
            "rms_reference_rad_s": num(g.rms_reference_rad_s),
            "aligned_rms_rad_s": num(g.aligned_rms_rad_s),
            "frame_rotation_rad": num(g.frame_rotation_rad),
            "median_magnitude_ratio": num(g.median_magnitude_ratio),
            "accelerometer_lag_s": num(g.accelerometer_lag_s),
            "rms_at_lag_rad_s": num(g.rms_at_lag_rad_s),
            "rate_on_path": cal.motion_on_path.is_some(),
            "samples_on_another_branch": cal.samples_on_another_branch(),
            "by_rate": g.by_rate.iter().map(|(lo, hi, c, d, r)| json!({
                "low_rad_s": lo, "high_rad_s": num(*hi), "samples": c, "rms_rad_s": num(*d), "relative": num(*r)
            })).collect::<Vec<_>>(),
        });
    }
    if let Some(b) = cal.gyro_bias_rad_s {
        out["gyro_bias_rad_s"] = json!([b.x, b.y, b.z]);
    }
    if let Some(c) = &cal.clocks {
        out["sample_clocks"] = sample_clocks_json(c, array);
        out["sample_clock_model"] = json!({
            "started_from": c.start,
            "iterations": c.iterations,
            "dynamic_residual_rms_before_m_s2": num(c.residual_rms_before_m_s2),
            "dynamic_residual_rms_after_m_s2": num(c.residual_rms_after_m_s2),
            "gauge": SAMPLE_CLOCK_GAUGE,
            "timing_unknowns_per_sample": super::timing::TIMING_UNKNOWNS_PER_SAMPLE,
            "share_removed": num(c.share_removed),
            "null_shares_removed": c.null_shares_removed.iter().map(|v| num(*v)).collect::<Vec<_>>(),
            "null_p_value": num(c.null_p_value()),
            "common_sigma": {
                "rate_offset_ppm": num(c.common_sigma[0] * 1e6),
                "drift_ppm_per_s": num(c.common_sigma[1] * 1e6),
                "phase_s": num(c.common_sigma[2]),
            },
            "sigma_check": {
                "method": SAMPLE_CLOCK_SIGMA_CHECK,
                "birge_ratio": num(c.sigma_check.birge_ratio),
                "inflation": num(c.sigma_check.inflation),
                "half_difference_rms_ppm": num(c.sigma_check.half_difference_rms * 1e6),
            },
            "robust": c.huber.as_ref().map(|h| json!({
                "method": ROBUST_ROTATION_PHASE,
                "clip_m_s2": num(h.clip_m_s2),
                "robust_scale_m_s2": num(h.robust_scale_m_s2),
                "clipped_share": num(h.clipped_share),
                "iterations": h.iterations,
            })),
        });
    }
    if let Some(note) = &cal.clock_note {
        out["sample_clock_note"] = json!(note);
    }
    out
}

/// How the clocks' sigmas are checked, as the JSON states it.
pub const SAMPLE_CLOCK_SIGMA_CHECK: &str = "the relative part's linearised sigmas are checked on the two halves of the rotation phase, each half's optimum as linearised at the final clocks (one Gauss-Newton step, the timing motion and the wraps held; birge_ratio null where a half cannot fix its clocks): the RMS of the halves' relative rate-offset difference over its sigma (the Birge ratio, 1 when the sigmas are right) multiplies every linearised sigma where it exceeds 1, and no relative sigma is put below the spread of the gyroscopes' half-phase clocks (per package); the common part's sigma is the spread of the gyroscopes' half-phase clocks over the root of the number of packages";

/// How a clocked rotation phase is fitted, as the JSON states it (`selfcal::huber`).
pub const ROBUST_ROTATION_PHASE: &str = "Huber's M-estimator after the least-squares iterations: each rotation-phase output's residual after the clocks clipped at clip_m_s2 (2 robust scales, 1.4826 times the median absolute residual) by pseudo-observations, every sample kept in its run; the covariance a sandwich over blocks of samples whose bread weighs each output by the chance that its residual falls within the clip under its accelerometer's static noise; residual_rms_m_s2 and chi2_dof are of the outputs as measured";

/// The gauge of the clock model, as the JSON states it.
pub const SAMPLE_CLOCK_GAUGE: &str = "a change common to every package's clock (phase, rate, drift) moves every sample's age alike and the per-sample motion absorbs it: the accelerometers' linearised model sees the clocks relative to their mean only (3 null directions), so the common part is taken from the gyroscopes' sawtooth (a rising sawtooth with a 1 ms wrap fixes it) and only the relative part is fitted to the accelerometers; without gyroscopes, the mirror age -> period - age (every rate offset's sign flipped) fits as well, so the gyroscopes' sawtooth picks the branch";

/// `static.bias_drift` (`selfcal::static_drift`): the test, each accelerometer's drift rate, the
/// static parameters refitted with it (as `parameters`), and their sigmas over the printed ones of
/// `cal` (median over the accelerometers, per parameter). `gfcal diagnose --remove-bias-drift`
/// writes the drift it took out so too.
pub fn bias_drift_json(d: &super::static_drift::StaticDrift, cal: &Calibration) -> Value {
    let n = d.rate_m_s2_per_s.len();
    let printed = |j, p| cal.fit.sigma(j, p);
    let over_printed = super::static_drift::sigma_over_printed(d, &printed);
    let moves = super::static_drift::moves_in_printed_sigmas(d, &cal.fit.params, &printed);
    json!({
        "t_mid_s": d.t_mid_s,
        "chi2_dof": num(d.chi2_dof),
        "chi2_dof_without": num(d.chi2_dof_without),
        "test_chi2": num(d.test_chi2),
        "test_dof": d.test_dof,
        "p_value": num(d.p_value),
        "drifts": d.drifts(),
        "move_rms_sigma": (0..4).map(|p| (NAMES[p].to_string(), num(moves[p]))).collect::<serde_json::Map<_, _>>(),
        "sigma_over_printed": (0..4).map(|p| (NAMES[p].to_string(), num(over_printed[p]))).collect::<serde_json::Map<_, _>>(),
        "rates": (0..n).map(|j| json!({
            "accelerometer": j + 1,
            "rate_m_s2_per_s": num(d.rate_m_s2_per_s[j]),
            "rate_sigma_m_s2_per_s": num(d.rate_sigma_m_s2_per_s[j]),
        })).collect::<Vec<_>>(),
        "parameters": (0..n).flat_map(|j| (0..4).map(move |p| (j, p))).map(|(j, p)| json!({
            "accelerometer": j + 1,
            "name": NAMES[p],
            "value": num(if d.sigma[j][p].is_finite() { d.params.get(j, p) } else { f64::NAN }),
            "sigma": num(d.sigma[j][p]),
            "unit": UNITS[p],
        })).collect::<Vec<_>>(),
    })
}

/// `sample_clocks`: per package (1-based, in the order the array file names them) its clock's
/// rate offset `(f / f0 - 1) 1e6` in the recording's time base (positive: the package runs fast),
/// drift and phase (the age of its sample at `phase_time_s`), with sigmas.
fn sample_clocks_json(c: &super::timing::ClockEstimate, array: &RecordingArray) -> Value {
    let rows: Vec<Value> = c
        .clocks
        .iter()
        .zip(&c.sigma)
        .enumerate()
        .filter_map(|(p, (clock, sigma))| {
            let (clock, sigma) = (clock.as_ref()?, sigma.as_ref()?);
            let gyro = c.gyroscope_clocks.as_ref().and_then(|g| g[p]);
            Some(json!({
                "package": p + 1,
                "name": array.packages.get(p).map(|q| q.name.clone()),
                "nominal_hz": clock.nominal_hz,
                "rate_offset_ppm": clock.rate_offset * 1e6,
                "rate_offset_sigma_ppm": num(sigma[0] * 1e6),
                "drift_ppm_per_s": clock.drift_per_s * 1e6,
                "drift_sigma_ppm_per_s": num(sigma[1] * 1e6),
                "phase_s": clock.phase_s,
                "phase_sigma_s": num(sigma[2]),
                "phase_time_s": clock.t_ref_s,
                "gyroscope_rate_offset_ppm": gyro.map(|g| g.rate_offset * 1e6),
            }))
        })
        .collect();
    Value::Array(rows)
}

/// [`to_json`] with the held-out recordings' predictions (`held_out`), the time the
/// calibration took (`elapsed_s`), the verdict on what to trust (`assessment: [{kind,
/// trustworthy, reason}]`, `selfcal::assessment`) and provenance as `run.json` has it
/// (`gfcal_version`, `git_commit`, `started`, `finished`: RFC 3339, UTC), as `gfcal calibrate
/// --json` writes it.
pub fn to_json_with(
    cal: &Calibration,
    rec: &Recording,
    array: &RecordingArray,
    held: &[(PathBuf, HeldOut)],
    elapsed_s: f64,
    started: &str,
) -> Value {
    let mut json = to_json(cal, rec, array);
    json["held_out"] = Value::Array(held.iter().map(|(p, h)| held_out_json(p, h)).collect());
    json["elapsed_s"] = serde_json::json!(elapsed_s);
    json["assessment"] = assessment_json(cal, held);
    json["gfcal_version"] = json!(env!("CARGO_PKG_VERSION"));
    json["git_commit"] = json!(env!("GFCAL_GIT_COMMIT"));
    json["started"] = json!(started);
    json["finished"] = json!(humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string());
    json
}

/// The verdicts of `selfcal::assessment` for `cal` and its held-out recordings.
pub fn verdicts(cal: &Calibration, held: &[(PathBuf, HeldOut)]) -> Vec<super::assessment::Verdict> {
    let held_chi2: Vec<f64> = held.iter().map(|(_, h)| h.static_chi2_dof).collect();
    super::assessment::assess(cal, &held_chi2)
}

fn assessment_json(cal: &Calibration, held: &[(PathBuf, HeldOut)]) -> Value {
    Value::Array(
        verdicts(cal, held)
            .iter()
            .map(|v| json!({"kind": v.kind, "trustworthy": v.trustworthy, "reason": v.reason}))
            .collect(),
    )
}

/// A held-out recording's prediction as JSON.
pub fn held_out_json(path: &Path, h: &HeldOut) -> Value {
    json!({
        "recording": path.display().to_string(),
        "static_intervals": h.static_intervals,
        "static_residual_rms_m_s2": num(h.static_residual_rms_m_s2),
        "static_noise_rms_m_s2": num(h.static_noise_rms_m_s2),
        "static_chi2_dof": num(h.static_chi2_dof),
        "dynamic_samples": h.dynamic_samples,
        "dynamic_residual_rms_m_s2": num(h.dynamic_residual_rms_m_s2),
        "dynamic_noise_rms_m_s2": num(h.dynamic_noise_rms_m_s2),
        "dynamic_chi2_dof": num(h.dynamic_chi2_dof),
        "bias_drift_removed": h.bias_drift_removed,
        "own_clocks_share_removed": h.own_clocks_share_removed.map(num),
    })
}
