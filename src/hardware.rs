//! The binary's real-hardware command (`gfcal calibrate`): read the array file and the
//! recording, calibrate, print, and write the JSON and the report.
//! (Part of the `gfcal` binary, not the library.)

use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::InputError;
use gfcal::config::array::load_recording_array;
use gfcal::selfcal::calibrate::{CalibrateError, CalibrateSettings, Calibration, calibrate as run_calibration};
use gfcal::selfcal::fit::{FitError, FitSettings};
use gfcal::selfcal::model::PER_ACCEL;
use gfcal::selfcal::predict::{HeldOut, predict};
use gfcal::selfcal::recording::{Recording, RecordingError};
use gfcal::selfcal::segment::DetectorSettings;

pub struct CalibrateArgs<'a> {
    pub recording: &'a Path,
    pub array: &'a Path,
    pub json: Option<&'a Path>,
    pub report: Option<&'a Path>,
    pub use_gyro: bool,
    pub held_out: &'a [PathBuf],
    pub gravity_m_s2: f64,
    pub detector: DetectorSettings,
}

fn check_settings(a: &CalibrateArgs) -> Result<(), InputError> {
    let d = &a.detector;
    let checks = [
        ("--gravity-m-s2", a.gravity_m_s2),
        ("--window-s", d.window_s),
        ("--still-threshold", d.threshold),
        ("--min-static-s", d.min_static_s),
        ("--min-dynamic-s", d.min_dynamic_s),
    ];
    for (flag, v) in checks {
        if !(v.is_finite() && v > 0.0) {
            return Err(InputError::Other(format!("{flag}: must be a positive number, got {v}")));
        }
    }
    if !(d.trim_s.is_finite() && d.trim_s >= 0.0) {
        return Err(InputError::Other(format!("--trim-s: must be zero or positive, got {}", d.trim_s)));
    }
    Ok(())
}

fn recording_error(e: RecordingError) -> anyhow::Error {
    InputError::Other(e.to_string()).into()
}

pub fn calibrate(a: CalibrateArgs) -> anyhow::Result<()> {
    check_settings(&a)?;
    let array = load_recording_array(a.array).map_err(InputError::Config)?;
    let rec = Recording::read(a.recording, &array).map_err(recording_error)?;
    // Held-out recordings are read before any work, so a bad one stops the run at once.
    let mut held = Vec::new();
    for path in a.held_out {
        let other = Recording::read(path, &array)
            .map_err(|e| InputError::Other(format!("held-out recording for {}: {e}", a.recording.display())))?;
        rec.same_array_as(&other).map_err(recording_error)?;
        held.push(other);
    }
    let settings = CalibrateSettings {
        detector: a.detector,
        fit: FitSettings { gravity_m_s2: a.gravity_m_s2, ..FitSettings::default() },
        use_gyro: a.use_gyro,
    };
    let started = std::time::Instant::now();
    let cal = run_calibration(&rec, &array, &settings).map_err(|e| -> anyhow::Error {
        match e {
            CalibrateError::Fit { source: FitError::Singular(_), .. } => anyhow::anyhow!("{e}"),
            other => InputError::Other(other.to_string()).into(),
        }
    })?;
    let elapsed_s = started.elapsed().as_secs_f64();
    let mut held_results = Vec::new();
    for other in &held {
        let h = predict(&array.array, &cal.fit.params, other, &settings.detector, a.gravity_m_s2)
            .map_err(recording_error)?;
        held_results.push((other.path.clone(), h));
    }
    print!("{}", summary_text(&cal, &rec, elapsed_s, &held_results));
    let mut json = gfcal::selfcal::output::to_json(&cal, &rec, &array);
    json["held_out"] = serde_json::Value::Array(held_results.iter().map(|(p, h)| held_json(p, h)).collect());
    json["elapsed_s"] = serde_json::json!(elapsed_s);
    if let Some(path) = a.json {
        let text = serde_json::to_string_pretty(&json).context("cannot format the JSON")?;
        gfcal::io::write_atomic(path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = a.report {
        let html = gfcal::report::calibration::render_page(&cal, &rec, &array, &held_results);
        gfcal::io::write_atomic(path, html.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn held_json(path: &Path, h: &HeldOut) -> serde_json::Value {
    let num = |v: f64| if v.is_finite() { serde_json::json!(v) } else { serde_json::Value::Null };
    serde_json::json!({
        "recording": path.display().to_string(),
        "static_intervals": h.static_intervals,
        "static_residual_rms_m_s2": num(h.static_residual_rms_m_s2),
        "static_noise_rms_m_s2": num(h.static_noise_rms_m_s2),
        "static_chi2_dof": num(h.static_chi2_dof),
        "dynamic_samples": h.dynamic_samples,
        "dynamic_residual_rms_m_s2": num(h.dynamic_residual_rms_m_s2),
        "dynamic_noise_rms_m_s2": num(h.dynamic_noise_rms_m_s2),
    })
}

fn summary_text(cal: &Calibration, rec: &Recording, elapsed_s: f64, held: &[(PathBuf, HeldOut)]) -> String {
    use std::fmt::Write;
    let fit = &cal.fit;
    let seg = &cal.segmentation;
    let t = &rec.t_s;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: {} samples, {:.1} s; {} static interval(s), {} dynamic run(s) ({} samples){}",
        rec.path.display(),
        rec.samples(),
        t[t.len() - 1] - t[0],
        seg.static_intervals.len(),
        seg.dynamic_intervals.len(),
        cal.dynamic_index.len(),
        if seg.from_step_column { " from the `step` column" } else { "" }
    );
    for (k, iv) in seg.static_intervals.iter().enumerate() {
        let _ = writeln!(
            s,
            "  static {:>2}: {:>8.2} - {:>8.2} s ({:.1} s)",
            k + 1,
            t[iv.start],
            t[iv.end - 1],
            t[iv.end - 1] - t[iv.start]
        );
    }
    for iv in &seg.dynamic_intervals {
        let _ = writeln!(
            s,
            "  dynamic:   {:>8.2} - {:>8.2} s ({:.1} s)",
            t[iv.start],
            t[iv.end - 1],
            t[iv.end - 1] - t[iv.start]
        );
    }
    let _ = writeln!(
        s,
        "rate from {}; fit {} in {} iterations, {:.2} s; Fisher null directions {} (gauge {})",
        if cal.use_gyro { "the reference gyroscopes" } else { "the accelerometers (gyroscope-free)" },
        if fit.converged { "converged" } else { "did NOT converge" },
        fit.iterations,
        elapsed_s,
        fit.null_directions,
        fit.gauge.count()
    );
    let _ = writeln!(
        s,
        "static: chi2/dof {:.2}, residual RMS {:.3e} m/s^2; dynamic: {} outputs clipped and left out, {} samples dropped, residual RMS {:.3e} m/s^2, chi2/dof {:.1}",
        fit.static_chi2_dof,
        fit.static_residual_rms_m_s2,
        cal.clipped_outputs,
        cal.dropped_samples,
        rms(&fit.dynamic_residual_rms_m_s2),
        fit.dynamic_chi2_dof
    );
    if !fit.locations_identified {
        let _ = writeln!(
            s,
            "no dynamic phase: the locations (dx, dy, dz of every accelerometer) are not identifiable from static poses and are left at nominal"
        );
    }
    let _ = writeln!(
        s,
        "{:>5} {:>21} {:>21} {:>21} {:>21} {:>21} {:>21} {:>21}",
        "accel", "scale_factor (1)", "bias (m/s^2)", "tilt_u (rad)", "tilt_w (rad)", "dx (m)", "dy (m)", "dz (m)"
    );
    for j in 0..rec.accelerometers() {
        let mut line = format!("{:>5}", j + 1);
        for p in 0..PER_ACCEL {
            let _ = write!(line, " {:>10.3e} +-{:>8.1e}", fit.params.get(j, p), fit.sigma(j, p));
        }
        let _ = writeln!(s, "{line}");
    }
    if let Some(g) = &cal.gyro_check {
        let _ = writeln!(
            s,
            "gyroscope-free rate against the gyroscopes ({} unclipped samples): RMS difference {:.3} rad/s of {:.2} rad/s RMS ({:.1}%); after the best frame rotation ({:.2e} rad) {:.3} rad/s; median magnitude ratio {:.4}",
            g.samples,
            g.rms_rad_s,
            g.rms_reference_rad_s,
            100.0 * g.relative,
            g.frame_rotation_rad,
            g.aligned_rms_rad_s,
            g.median_magnitude_ratio
        );
        let _ = writeln!(
            s,
            "  with the gyroscopes delayed by the accelerometers' best lag ({:.1} ms, searched over +-{:.0} ms): RMS difference {:.3} rad/s",
            g.accelerometer_lag_s * 1e3,
            gfcal::selfcal::calibrate::LAG_SEARCH_S * 1e3,
            g.rms_at_lag_rad_s
        );
    }
    for (p, h) in held {
        let _ = writeln!(
            s,
            "held out {}: static residual RMS {:.3e} m/s^2 (noise {:.3e}, chi2/dof {:.1}); dynamic residual RMS {:.3e} m/s^2 (noise {:.3e})",
            p.display(),
            h.static_residual_rms_m_s2,
            h.static_noise_rms_m_s2,
            h.static_chi2_dof,
            h.dynamic_residual_rms_m_s2,
            h.dynamic_noise_rms_m_s2
        );
    }
    s
}

fn rms(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() { f64::NAN } else { (f.iter().map(|x| x * x).sum::<f64>() / f.len() as f64).sqrt() }
}
