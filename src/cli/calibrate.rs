//! The binary's real-hardware command (`gfcal calibrate`): read the array file and the
//! recording, calibrate, print, and write the JSON and the report.
//! (Part of the `gfcal` binary, not the library.)

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::error::InputError;
use gfcal::config::array::load_recording_array;
use gfcal::selfcal::calibrate::{CalibrateError, CalibrateSettings, Calibration, calibrate as run_calibration};
use gfcal::selfcal::fit::{FitError, FitSettings};
use gfcal::selfcal::model::PER_ACCEL;
use gfcal::selfcal::predict::{HeldOut, check_predictable, predict_held_out};
use gfcal::selfcal::recording::{Recording, RecordingError};
use gfcal::selfcal::segment::DetectorSettings;

pub struct CalibrateArgs<'a> {
    pub recording: &'a Path,
    pub array: &'a Path,
    pub json: Option<&'a Path>,
    pub report: Option<&'a Path>,
    pub use_gyro: bool,
    pub plain_least_squares: bool,
    pub remove_bias_drift: bool,
    pub held_out: &'a [PathBuf],
    pub gravity_m_s2: f64,
    pub detector: DetectorSettings,
}

/// A bias drift check's test in words (`selfcal::static_drift`).
pub(crate) fn drift_test(d: &gfcal::selfcal::static_drift::StaticDrift) -> String {
    format!(
        "median {:.2e} m/s^2/s, test chi2 {:.1} on {} dof (p = {:.1e}); static chi2/dof {:.2} with it, {:.2} without",
        gfcal::stats::median(&d.rate_m_s2_per_s),
        d.test_chi2,
        d.test_dof,
        d.p_value,
        d.chi2_dof,
        d.chi2_dof_without
    )
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

/// A calibration's failure: a singular fit is a failure while running (exit 1); anything else is
/// the recording's (exit 2), and too few static intervals come with what the segmentation found.
pub(crate) fn calibrate_error(
    e: CalibrateError,
    rec: &Recording,
    array: &gfcal::array::wiring::RecordingArray,
    detector: &DetectorSettings,
) -> anyhow::Error {
    match e {
        CalibrateError::Fit { source: FitError::Singular(_), .. } => anyhow::anyhow!("{e}"),
        CalibrateError::Fit { source: FitError::TooFewPoses { found, needed, with_dynamic }, path } => {
            let why =
                gfcal::selfcal::segment::too_few_poses(rec, detector, &array.time_column, found, needed, with_dynamic);
            InputError::Other(format!("{}: {why}", path.display())).into()
        }
        other => InputError::Other(other.to_string()).into(),
    }
}

fn recording_error(e: RecordingError) -> anyhow::Error {
    InputError::Other(e.to_string()).into()
}

pub fn calibrate(a: CalibrateArgs) -> anyhow::Result<()> {
    check_settings(&a)?;
    let array = load_recording_array(a.array).map_err(InputError::Config)?;
    let rec = Recording::read(a.recording, &array).map_err(recording_error)?;
    // Held-out recordings are read and checked before any work, so a bad one stops the run at once.
    let mut held = Vec::new();
    for path in a.held_out {
        let other = Recording::read(path, &array)
            .map_err(|e| InputError::Other(format!("held-out recording for {}: {e}", a.recording.display())))?;
        rec.same_array_as(&other).map_err(recording_error)?;
        check_predictable(&other, &a.detector)
            .map_err(|e| InputError::Other(format!("held-out recording for {}: {e}", a.recording.display())))?;
        held.push(other);
    }
    let settings = CalibrateSettings {
        detector: a.detector,
        fit: FitSettings { gravity_m_s2: a.gravity_m_s2, ..FitSettings::default() },
        use_gyro: a.use_gyro,
        plain_least_squares: a.plain_least_squares,
        remove_bias_drift: a.remove_bias_drift,
    };
    let started_utc = humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string();
    let started = std::time::Instant::now();
    let cal =
        run_calibration(&rec, &array, &settings).map_err(|e| calibrate_error(e, &rec, &array, &settings.detector))?;
    let elapsed_s = started.elapsed().as_secs_f64();
    // The solver's trace, for whoever debugs it (the library reports it; the binary prints).
    if std::env::var_os("GFCAL_DEBUG").is_some() {
        for t in &cal.fit.trace {
            eprintln!("it {} lambda {:.1e} cost {:.6e} trial {:.6e}", t.iteration, t.lambda, t.cost, t.trial_cost);
        }
        eprintln!("smallest scaled eigenvalues {:?}", cal.fit.smallest_scaled_eigenvalues);
    }
    let mut held_results = Vec::new();
    for other in &held {
        let h = predict_held_out(&array, &cal, other, &settings)
            .map_err(|e| calibrate_error(e, other, &array, &settings.detector))?;
        held_results.push((other.path.clone(), h));
    }
    print!("{}", summary_text(&cal, &rec, elapsed_s, &held_results, a.detector.min_dynamic_s));
    let json = gfcal::selfcal::output::to_json_with(&cal, &rec, &array, &held_results, elapsed_s, &started_utc);
    let text = match a.json {
        Some(_) => serde_json::to_string_pretty(&json).context("cannot format the JSON")?,
        None => String::new(),
    };
    let html = match a.report {
        Some(_) => gfcal::report::calibration::render_page(&cal, &rec, &array, &held_results),
        None => String::new(),
    };
    let mut files: Vec<(&Path, &[u8])> = Vec::new();
    files.extend(a.json.map(|p| (p, text.as_bytes())));
    files.extend(a.report.map(|p| (p, html.as_bytes())));
    super::outputs::write_all(&files)
}

fn summary_text(
    cal: &Calibration,
    rec: &Recording,
    elapsed_s: f64,
    held: &[(PathBuf, HeldOut)],
    min_dynamic_s: f64,
) -> String {
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
        "rate from {}; fit {} in {} iterations, {:.2} s; Fisher null directions {} (gauge {}{})",
        if cal.use_gyro { "the reference gyroscopes" } else { "the accelerometers (gyroscope-free)" },
        if fit.converged { "converged" } else { "did NOT converge" },
        fit.iterations,
        elapsed_s,
        fit.null_directions,
        fit.gauge.null_count(),
        match fit.gauge.count() - fit.gauge.null_count() {
            0 => String::new(),
            k => format!("; and {k} directions of the axis groups' translations, seen only through the tilts, fixed"),
        }
    );
    let _ = writeln!(
        s,
        "static: chi2/dof {:.2}, residual RMS {:.3e} m/s^2; dynamic: {} outputs clipped and left out, {} samples dropped, residual RMS {:.3e} m/s^2, rotation-phase chi2/dof {:.1}",
        fit.static_chi2_dof,
        fit.static_residual_rms_m_s2,
        cal.clipped_outputs,
        cal.dropped_samples,
        rms(&fit.dynamic_residual_rms_m_s2),
        fit.dynamic_chi2_dof
    );
    if let Some(t) = &cal.static_tension {
        let _ = writeln!(
            s,
            "static phase refitted alone (poses held): chi2/dof {:.2} (as fitted {:.2}); the biases, scale factors and tilts move by {:.2} printed sigmas RMS{}; the joint fit's pull on them chi2 {:.1} on {} dof (p = {:.1e}){}",
            t.chi2_dof_static_only,
            fit.static_chi2_dof,
            t.move_rms_sigma,
            t.largest.map_or(String::new(), |(j, p, v)| format!(
                ", most accelerometer {} {} ({v:+.2})",
                j + 1,
                gfcal::selfcal::model::NAMES[p]
            )),
            t.pull_chi2,
            t.pull_dof,
            t.pull_p_value,
            if t.pulls() {
                ": the rotation phase pulls them from what the static poses say, beyond its noise"
            } else {
                ""
            }
        );
    }
    if let Some(d) = &cal.removed_bias_drift {
        let _ = writeln!(
            s,
            "bias drift in time taken out before the calibration (fitted to the static phase alone; --keep-bias-drift leaves it in): {}",
            drift_test(d)
        );
    }
    if let Some(note) = &cal.bias_drift_note {
        let _ = writeln!(s, "{note}");
    }
    if let Some(d) = &cal.static_drift {
        let printed = |j, p| fit.sigma(j, p);
        let over = gfcal::selfcal::static_drift::sigma_over_printed(d, &printed);
        let moves = gfcal::selfcal::static_drift::moves_in_printed_sigmas(d, &fit.params, &printed);
        let _ = writeln!(
            s,
            "static phase refitted with a bias drift in time (poses held): {}{}; with it scale factor, bias, tilt_u and tilt_w move by {:.1}, {:.1}, {:.1}, {:.1} printed sigmas RMS, their sigmas {:.1}, {:.1}, {:.1}, {:.1} times the printed (median)",
            drift_test(d),
            if d.drifts() { ": the biases drift in time, which the joint fit leaves out" } else { "" },
            moves[0],
            moves[1],
            moves[2],
            moves[3],
            over[0],
            over[1],
            over[2],
            over[3]
        );
    }
    if let Some(c) = &cal.clocks {
        let _ = writeln!(
            s,
            "sample clocks (started from {}; {} refits): dynamic residual RMS {:.3} -> {:.3} m/s^2",
            c.start, c.iterations, c.residual_rms_before_m_s2, c.residual_rms_after_m_s2
        );
        let null_max = c.null_shares_removed.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let _ = writeln!(
            s,
            "  the timing model removes {:.1}% of the rotation phase's misfit; with the clocks read at {} shifted times (the null) at most {:.1}% (rank p = {:.2})",
            100.0 * c.share_removed,
            c.null_shares_removed.len(),
            100.0 * null_max,
            c.null_p_value()
        );
        for (p, (clock, sigma)) in c.clocks.iter().zip(&c.sigma).enumerate() {
            if let (Some(clock), Some(sigma)) = (clock, sigma) {
                let _ = writeln!(
                    s,
                    "  package {:>2}: rate offset {:>9.2} +- {:.2} ppm, drift {:>7.3} +- {:.3} ppm/s, phase {:.4} +- {:.4} ms at {:.2} s",
                    p + 1,
                    clock.rate_offset * 1e6,
                    sigma[0] * 1e6,
                    clock.drift_per_s * 1e6,
                    sigma[1] * 1e6,
                    clock.phase_s * 1e3,
                    sigma[2] * 1e3,
                    clock.t_ref_s
                );
            }
        }
    }
    if let Some(note) = &cal.clock_note {
        let _ = writeln!(s, "sample clocks declared but not fitted: {note}");
    }
    if !fit.locations_identified {
        // Why there is no rotation phase, in the segmentation's facts: no moving run long enough (the
        // longest's length, rounded down, so that it never reads as the limit), or rotation runs
        // without a usable sample.
        let seg = &cal.segmentation;
        let why = if !seg.dynamic_intervals.is_empty() {
            format!(
                " (the segmentation's {} rotation run(s) have no sample with enough unclipped outputs)",
                seg.dynamic_intervals.len()
            )
        } else if !seg.from_step_column && seg.short_moving_runs > 0 {
            format!(
                " (no moving run lasts --min-dynamic-s {} s; the longest lasts {:.1} s)",
                min_dynamic_s,
                (seg.longest_moving_s * 10.0).floor() / 10.0
            )
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "no dynamic phase{why}: the locations (dx, dy, dz of every accelerometer) are not identifiable from static poses and are left at nominal"
        );
    }
    if !fit.unseen.is_empty() {
        let names = gfcal::selfcal::geometry::unseen_names(&fit.unseen_parameters, rec.accelerometers());
        let _ = writeln!(
            s,
            "NOT IDENTIFIABLE: the recording cannot see {} parameter combination(s) beyond the gauge (Fisher null directions {}, gauge {}); their {} parameters are unidentified (no value, no sigma) and the rest are calibrated. The unseen combinations (weights of each parameter scaled by its own information):",
            fit.unseen.len(),
            fit.null_directions,
            fit.gauge.null_count(),
            names.len()
        );
        for c in &fit.unseen {
            let _ = writeln!(s, "  {}", gfcal::selfcal::unseen::describe(c, rec.accelerometers()));
        }
        let _ = writeln!(s, "unidentified: {}", names.join(", "));
    }
    if !cal.to_identify.is_empty() {
        let _ = writeln!(s, "to make them identifiable:");
        for r in &cal.to_identify {
            let _ = writeln!(s, "  - {r}");
        }
    }
    let _ = writeln!(
        s,
        "{:>5} {:>21} {:>21} {:>21} {:>21} {:>21} {:>21} {:>21}",
        "accel", "scale_factor (1)", "bias (m/s^2)", "tilt_u (rad)", "tilt_w (rad)", "dx (m)", "dy (m)", "dz (m)"
    );
    for j in 0..rec.accelerometers() {
        let mut line = format!("{:>5}", j + 1);
        for p in 0..PER_ACCEL {
            if fit.identified(j, p) || !fit.unseen_parameters[PER_ACCEL * j + p] {
                let _ = write!(line, " {:>10.3e} +-{:>8.1e}", fit.params.get(j, p), fit.sigma(j, p));
            } else {
                let _ = write!(line, " {:>21}", "unidentified");
            }
        }
        let _ = writeln!(s, "{line}");
    }
    if let Some(g) = &cal.gyro_check {
        let _ = writeln!(
            s,
            "gyroscope-free rate{} against the gyroscopes ({} unclipped samples): RMS difference {:.3} rad/s of {:.2} rad/s RMS ({:.1}%); after the best frame rotation ({:.2e} rad) {:.3} rad/s; median magnitude ratio {:.4}",
            cal.samples_on_another_branch()
                .map(|n| format!(
                    " (on the path over its branches: {n} samples moved by more than 3 sigmas from the fit's sign or plane reflection)"
                ))
                .unwrap_or_default(),
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
            gfcal::selfcal::gyro_check::LAG_SEARCH_S * 1e3,
            g.rms_at_lag_rad_s
        );
    }
    for (p, h) in held {
        let _ = writeln!(
            s,
            "held out {}{}: static residual RMS {:.3e} m/s^2 (noise {:.3e}, chi2/dof {:.1}); dynamic residual RMS {:.3e} m/s^2 (noise {:.3e}, rotation-phase chi2/dof {:.1})",
            p.display(),
            if h.bias_drift_removed { " (its own bias drift taken out)" } else { "" },
            h.static_residual_rms_m_s2,
            h.static_noise_rms_m_s2,
            h.static_chi2_dof,
            h.dynamic_residual_rms_m_s2,
            h.dynamic_noise_rms_m_s2,
            h.dynamic_chi2_dof
        );
        if let Some(share) = h.own_clocks_share_removed {
            let _ = writeln!(
                s,
                "  its own gyroscopes' clocks (a recording's clocks are its own) remove {:.1}% of that rotation-phase misfit (each sample's motion refitted with the timing model; about 40% of a misfit without clocks goes so by chance); what they leave bounds what this calibration does not carry over",
                100.0 * share
            );
        }
    }
    let _ = writeln!(s, "assessment:");
    for v in gfcal::selfcal::output::verdicts(cal, held) {
        let _ = writeln!(s, "  {}: {}", v.kind, v.reason);
    }
    s
}

fn rms(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() { f64::NAN } else { (f.iter().map(|x| x * x).sum::<f64>() / f.len() as f64).sqrt() }
}
