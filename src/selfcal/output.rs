//! The JSON of `gfcal calibrate` (SI units; keys fixed by the interface).
//!
//! `parameters: [{accelerometer, name, value, sigma, unit}]` (tilt-form misalignment, so
//! `scale_factor` is the gain along the true unit axis and `bias` is input-referred; `dx, dy, dz`
//! are location errors, true minus nominal position; `sigma` is null for a parameter the recording
//! cannot identify), `poses: [{start_s, end_s, up_x, up_y, up_z}]`, `static: {intervals,
//! chi2_dof, residual_rms_m_s2}`, `dynamic: {samples, clipped, residual_rms_m_s2}`, `gyro_check:
//! {samples, rms_rad_s, relative}` (when reference gyroscopes are given), and further keys that
//! say how the result was obtained.

use serde_json::{Value, json};

use super::calibrate::Calibration;
use super::model::{NAMES, PER_ACCEL, UNITS};
use super::recording::{Recording, RecordingArray};

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
                "value": fit.params.get(j, p),
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
        "poses": poses,
        "static": {
            "intervals": cal.segmentation.static_intervals.len(),
            "chi2_dof": num(fit.static_chi2_dof),
            "residual_rms_m_s2": num(fit.static_residual_rms_m_s2),
            "variance_factor": num(fit.static_variance_factor),
            "noise_sigma_m_s2": cal.static_data.sigma,
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
            "expected_null_directions": fit.gauge.count(),
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
            "by_rate": g.by_rate.iter().map(|(lo, hi, c, d, r)| json!({
                "low_rad_s": lo, "high_rad_s": num(*hi), "samples": c, "rms_rad_s": num(*d), "relative": num(*r)
            })).collect::<Vec<_>>(),
        });
    }
    if let Some(b) = cal.gyro_bias_rad_s {
        out["gyro_bias_rad_s"] = json!([b.x, b.y, b.z]);
    }
    out
}
