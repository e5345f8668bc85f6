//! `gfcal simulate-log`, `gfcal diagnose` (of logs and of recordings) and `gfcal inject`: read the
//! inputs, call the library, print the text and write the files the flags name.

use std::path::Path;

use super::error::InputError;

pub fn simulate_log(config: &Path, out: &Path) -> anyhow::Result<()> {
    use gfcal::config::simulate_log::SimulateLogConfig;
    use gfcal::discrepancy::log::LogSimulation;
    let cfg = SimulateLogConfig::load(config)
        .map_err(|e| super::check::input_error(e, config, super::check::ConfigKind::SimulateLog))?;
    let sim = LogSimulation {
        array: &cfg.array,
        truth: &cfg.errors.truth,
        schedule: &cfg.schedule,
        noise: cfg.noise,
        effects: &cfg.effects,
        temperature: cfg.temperature,
        g_m_s2: cfg.gravity_m_s2,
    };
    sim.check().map_err(|e| InputError::Other(format!("{}: key `effects`: {e}", config.display())))?;
    let log = sim.run(&mut gfcal::rng::trial_rng(cfg.seed, 0));
    log.write(out)?;
    let samples: usize = log.steps.iter().map(|s| s.samples()).sum();
    let effects: Vec<&str> = cfg.effects.iter().map(|e| e.effect.name()).collect();
    eprintln!(
        "wrote {}: {} steps, {samples} samples of {} outputs{}; effects hidden: {}",
        out.display(),
        log.steps.len(),
        log.n,
        if log.has_temperature() { ", with temp_c" } else { "" },
        if effects.is_empty() { "none".to_string() } else { effects.join(", ") }
    );
    Ok(())
}

pub fn diagnose(
    log_path: &Path,
    array: Option<&Path>,
    json: Option<&Path>,
    report: Option<&Path>,
    alpha: f64,
    temp_ref_c: f64,
) -> anyhow::Result<()> {
    use gfcal::discrepancy::Explanation;
    use gfcal::discrepancy::log::CalibrationLog;
    use gfcal::discrepancy::log::{Correlation, DiagnoseError, DiagnoseSettings, Verdict, diagnose};
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(InputError::Other(format!("--alpha must be between 0 and 1, got {alpha}")).into());
    }
    let array = match array {
        Some(p) => gfcal::config::array::load_array_file(p).map_err(InputError::Config)?,
        None => gfcal::array::Array::cube(0.1)?,
    };
    let log = CalibrationLog::read(log_path, array.len()).map_err(|e| InputError::Other(e.to_string()))?;
    let nominal = gfcal::sensor::ArrayParams::nominal(&array);
    let settings = DiagnoseSettings { alpha, temp_ref_c, ..DiagnoseSettings::default() };
    let d = diagnose(&log, &array, &nominal, &settings).map_err(|e| match e {
        DiagnoseError::TooShort { .. }
        | DiagnoseError::Calib(_)
        | DiagnoseError::Schedule(_)
        | DiagnoseError::NoNoise => anyhow::Error::new(InputError::Other(format!("{}: {e}", log_path.display()))),
        other => anyhow::Error::new(other),
    })?;
    let b = &d.baseline;
    println!(
        "log {}: {} steps, {} outputs{}; noise within steps {:.4e} m/s^2 per sample",
        log_path.display(),
        log.steps.len(),
        log.n,
        if log.has_temperature() { ", temperature" } else { "" },
        b.noise_sigma_m_s2
    );
    let held_out = |h: Option<f64>| {
        h.map(|v| format!("; held-out prediction error {v:.3} (1 is noise alone)"))
            .unwrap_or_else(|| "; no step can be left out and predicted (no held-out error)".into())
    };
    println!(
        "baseline fit: chi2/dof = {:.3} ({:.1} on {} dof, p = {:.2e}){}",
        d.gap_before,
        b.chi2,
        b.dof,
        b.p_value,
        held_out(d.held_out_before)
    );
    let n = log.n;
    let per_step = |rows: &[Vec<f64>]| {
        let mut s = format!("  {:>6} {:>7}", "step", "kind");
        for j in 1..=n {
            s.push_str(&format!(" {:>7}", format!("z_s{j}")));
        }
        s.push('\n');
        for (st, z) in log.steps.iter().zip(rows) {
            let kind = if st.omega_b_rad_s.norm() > 0.0 { "spin" } else { "static" };
            s.push_str(&format!("  {:>6} {:>7}", st.step, kind));
            for v in z {
                s.push_str(&format!(" {v:>7.2}"));
            }
            s.push('\n');
        }
        s
    };
    println!("\nwhitened residuals of the step means, baseline (|z| > 3 is unusual):");
    print!("{}", per_step(&b.whitened));
    let by_kind = |kind_spin: bool| {
        let z: Vec<f64> = log
            .steps
            .iter()
            .zip(&b.whitened)
            .filter(|(s, _)| (s.omega_b_rad_s.norm() > 0.0) == kind_spin)
            .flat_map(|(_, z)| z.iter().copied())
            .collect();
        z.iter().map(|v| v * v).sum::<f64>() / z.len().max(1) as f64
    };
    println!("mean z^2 by step kind: static {:.2}, spin {:.2}", by_kind(false), by_kind(true));
    let correlations = gfcal::discrepancy::log::regressor_correlations(&log, &array, b, settings.form, settings.g_m_s2);
    println!("\ncorrelation of the baseline residuals with candidate regressors (per accelerometer):");
    let mut head = format!("  {:<12}", "regressor");
    for j in 1..=n {
        head.push_str(&format!(" {:>7}", format!("s{j}")));
    }
    println!("{head}");
    for row in &correlations {
        match &row.correlation {
            Correlation::PerAccelerometer(r) => {
                let cells: String = r
                    .iter()
                    .map(|v| v.map(|v| format!(" {v:>7.2}")).unwrap_or_else(|| format!(" {:>7}", "-")))
                    .collect();
                println!("  {:<12}{cells}", row.regressor);
            }
            Correlation::Constant(v) if row.regressor == "temperature" => {
                println!(
                    "  {:<12} the temperature is constant ({v} degC) in this log: it says nothing of temperature effects",
                    row.regressor
                )
            }
            Correlation::Constant(v) => {
                println!("  {:<12} constant ({v}) in this log: no correlation", row.regressor)
            }
        }
    }
    println!("\neffects named:");
    if d.findings.is_empty() {
        println!("  none");
    }
    for f in &d.findings {
        let acc = f.accelerometer.map(|j| format!(" on accelerometer {}", j + 1)).unwrap_or_default();
        let vals: Vec<String> = f.value.iter().zip(&f.sigma).map(|(v, s)| format!("{v:.4e} +- {s:.1e}")).collect();
        println!(
            "  {}{acc}: {} {}; chi2/dof {:.3} -> {:.3} (p = {:.1e}){}",
            f.name,
            vals.join(", "),
            f.unit,
            f.gap_before,
            f.gap_after,
            f.p_value,
            f.confounded_with
                .as_ref()
                .map(|c| format!("; CONFOUNDED with {c}: this log cannot tell them apart"))
                .unwrap_or_default()
        );
        if f.unseen_directions > 0 {
            println!(
                "    ({} direction(s) of its parameters are absorbed by the baseline model and not fitted: the values are those with none of them)",
                f.unseen_directions
            );
        }
    }
    println!("\ncandidates the log cannot separate from the model:");
    for (label, v) in &d.verdicts {
        if let Verdict::ConfoundedWithModel(with) = v {
            println!("  {label}: confounded with {}", with.join(", "));
        }
    }
    println!("\nafter: chi2/dof = {:.3} (p = {:.2e}){}", d.gap_after, d.p_value_after, held_out(d.held_out_after));
    match d.explanation() {
        Explanation::Partial => println!(
            "a partial explanation: the named effects lower the gap, but what is left is still above the noise (an effect the library does not have remains)"
        ),
        Explanation::Unexplained => println!(
            "an unmodelled effect remains: the gap is above the noise and no candidate of the library explains it"
        ),
        Explanation::Complete | Explanation::NothingToExplain => {}
    }
    let body = match json {
        Some(_) => {
            let body =
                gfcal::discrepancy::log::output::to_json(&log_path.display().to_string(), &log, &d, &correlations);
            serde_json::to_string_pretty(&body)? + "\n"
        }
        None => String::new(),
    };
    let html = match report {
        Some(_) => gfcal::report::diagnosis::diagnosis_report(&log_path.display().to_string(), &log, &d, alpha)?.html,
        None => String::new(),
    };
    let mut files: Vec<(&Path, &[u8])> = Vec::new();
    files.extend(json.map(|p| (p, body.as_bytes())));
    files.extend(report.map(|p| (p, html.as_bytes())));
    super::outputs::write_all(&files)
}

/// The table of a real recording rather than a calibration log: a readable table without the
/// log's commanded pose (`up_x`). An unreadable file is left to the log reader, which says why.
pub fn recording_table(path: &Path) -> Option<gfcal::io::table::Table> {
    gfcal::io::table::Table::read(path).ok().filter(|t| t.index("up_x").is_none())
}

/// `gfcal diagnose RECORDING --array FILE [--held-out ...]`: the baseline's gap on real recordings.
/// Options of `gfcal diagnose` on recordings.
pub struct RecordingOptions<'a> {
    pub json: Option<&'a Path>,
    pub report: Option<&'a Path>,
    pub alpha: f64,
    pub use_gyro: bool,
    pub remove_bias_drift: bool,
}

pub fn diagnose_recordings(
    table: &gfcal::io::table::Table,
    array_path: &Path,
    held_out: &[std::path::PathBuf],
    options: RecordingOptions,
) -> anyhow::Result<()> {
    let RecordingOptions { json, report, alpha, use_gyro, remove_bias_drift } = options;
    use gfcal::discrepancy::Explanation;
    use gfcal::discrepancy::recorded::{Gap, RecordedError, diagnose_recordings};
    use gfcal::selfcal::calibrate::CalibrateSettings;
    use gfcal::selfcal::recording::Recording;
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(InputError::Other(format!("--alpha must be between 0 and 1, got {alpha}")).into());
    }
    let path = table.path.as_path();
    let array = gfcal::config::array::load_recording_array(array_path).map_err(InputError::Config)?;
    let rec = Recording::from_table(table, &array).map_err(|e| InputError::Other(e.to_string()))?;
    let settings = CalibrateSettings { use_gyro, remove_bias_drift, ..CalibrateSettings::default() };
    let mut others = Vec::new();
    for other in held_out {
        let o = Recording::read(other, &array)
            .map_err(|e| InputError::Other(format!("held-out recording for {}: {e}", path.display())))?;
        rec.same_array_as(&o).map_err(|e| InputError::Other(e.to_string()))?;
        gfcal::selfcal::predict::check_predictable(&o, &settings.detector)
            .map_err(|e| InputError::Other(format!("held-out recording for {}: {e}", path.display())))?;
        others.push(o);
    }
    let d = diagnose_recordings(&rec, &array, &others, &settings, alpha).map_err(|e| -> anyhow::Error {
        match e {
            RecordedError::Calibrate(e) => super::calibrate::calibrate_error(e, &rec, &array, &settings.detector),
            other => InputError::Other(other.to_string()).into(),
        }
    })?;
    let show = |g: &Gap| {
        format!(
            "static chi2/dof {:.3}, rotation-phase chi2/dof {}",
            g.static_chi2_dof,
            g.dynamic.map(|v| format!("{v:.1}")).unwrap_or_else(|| "- (no rotation phase)".into())
        )
    };
    println!(
        "recording {}: {} static interval(s), {} dynamic sample(s); the gap (1 is noise alone; the rotation-phase chi2/dof is the one gfcal calibrate prints)",
        path.display(),
        d.calibration.static_data.means.nrows(),
        d.calibration.dynamic_index.len()
    );
    if let Some(drift) = &d.calibration.removed_bias_drift {
        println!(
            "  each recording's bias drift in time taken out first (fitted to its own static phase alone); the fitting recording's: {}",
            super::calibrate::drift_test(drift)
        );
    }
    if let Some(why) = &d.calibration.bias_drift_note {
        println!("  {why}");
    }
    println!("  fitting recording, baseline: {}", show(&d.fitting));
    for (name, g) in &d.fitting_after_each {
        println!("    + {name:<35} {}", show(g));
    }
    for h in &d.held_out {
        println!("  held out {}:", h.recording.display());
        println!("    baseline (poses and motion refitted): {}", show(&h.before));
        for (name, g) in &h.after_each {
            println!("    + {name:<35} {}", show(g));
        }
    }
    if d.held_out.is_empty() {
        println!(
            "\neffects named on the fitting recording alone (no held-out recording confirms them: give --held-out):"
        );
    } else {
        println!("\neffects named (each lowers the gap on every held-out recording):");
    }
    if d.findings.is_empty() {
        println!("  none");
    }
    for f in &d.findings {
        if f.name == "sample_clock" {
            let values: Vec<String> = f.value.iter().zip(&f.sigma).map(|(v, s)| format!("{v:.2} +- {s:.2}")).collect();
            println!("  {} (relative rates per package, {}: {}): {}", f.name, f.unit, values.join(", "), f.what);
            continue;
        }
        if f.accelerometer.is_some() || f.package.is_some() || f.value.len() == 9 {
            let owner = match (f.accelerometer, f.package) {
                (Some(j), _) => format!("accelerometer {}", j + 1),
                (_, Some(m)) => format!("package {}", m + 1),
                _ => "shared".into(),
            };
            let values: Vec<String> =
                f.value.iter().zip(&f.sigma).map(|(v, s)| format!("{v:.3e} +- {s:.1e}")).collect();
            println!("  {} on {owner}: {} {}", f.name, values.join(", "), f.unit);
            continue;
        }
        let largest = f.value.iter().zip(&f.sigma).max_by(|a, b| a.0.abs().total_cmp(&b.0.abs()));
        println!(
            "  {}: {} accelerometer(s); largest {}; p <= {} on every held-out recording",
            f.name,
            f.value.len(),
            largest.map(|(v, s)| format!("{v:.4e} +- {s:.1e} {}", f.unit)).unwrap_or_default(),
            if f.p_value_largest > 0.0 { format!("{:.1e}", f.p_value_largest) } else { "1e-300".into() }
        );
    }
    for (name, why) in &d.not_named {
        println!("  not named: {name}: {why}");
    }
    println!("\nrank test on the fitting recording (directions of each effect the model absorbs):");
    for r in &d.ranks {
        println!("  {:<26} {:>3} parameter(s), {:>3} unseen", r.name, r.parameters, r.unseen);
    }
    println!(
        "\nsensing points inside each package (location error of each further axis minus the package's first, array axes, mm):"
    );
    for sp in &d.sensing_points {
        let v: Vec<String> = sp.offsets().iter().map(|o| o.describe_mm()).collect();
        println!("  package {}: p = {:.1e}: {}", sp.package + 1, sp.p_value, v.join("; "));
    }
    match d.explanation() {
        Explanation::Partial => println!(
            "\na partial explanation: what is left is still above the noise (unexplained, this large: the numbers after the named effects above)"
        ),
        Explanation::Unexplained => println!("\nunexplained: the gap is above the noise and nothing tried lowers it"),
        Explanation::Complete => println!("\nthe named effects explain the gap to the noise"),
        Explanation::NothingToExplain => println!("\nthe baseline explains the recordings to the noise"),
    }
    println!("\nassessment of the fitting recording's calibration:");
    for v in d.assessment() {
        println!("  {}: {}", v.kind, v.reason);
    }
    let body = match json {
        Some(_) => {
            let body = gfcal::discrepancy::recorded::output::to_json(
                &path.display().to_string(),
                &array_path.display().to_string(),
                &d,
                alpha,
            );
            serde_json::to_string_pretty(&body)? + "\n"
        }
        None => String::new(),
    };
    let html = match report {
        Some(_) => gfcal::report::recorded::recorded_report(&d, &rec, &array, settings.fit.gravity_m_s2)?.0,
        None => String::new(),
    };
    let mut files: Vec<(&Path, &[u8])> = Vec::new();
    files.extend(json.map(|p| (p, body.as_bytes())));
    files.extend(report.map(|p| (p, html.as_bytes())));
    super::outputs::write_all(&files)
}

/// `gfcal inject`: a known effect added to a real recording.
pub fn inject(
    path: &Path,
    array_path: &Path,
    effect: &str,
    accelerometer: Option<usize>,
    element: Option<&str>,
    value: f64,
    out: &Path,
) -> anyhow::Result<()> {
    use gfcal::discrepancy::inject::GYRO_EFFECT;
    let gyro = effect == GYRO_EFFECT;
    enum Target<'a> {
        Accelerometer(usize),
        Gyroscopes(&'a str),
    }
    let target = match (gyro, accelerometer, element) {
        (true, Some(_), _) => {
            return Err(InputError::Other(format!(
                "--accelerometer: {GYRO_EFFECT} is on the gyroscopes; give --element instead"
            ))
            .into());
        }
        (true, None, None) => {
            return Err(InputError::Other(format!(
                "--element: {GYRO_EFFECT} needs the element of G (xx, xy, ..., zz)"
            ))
            .into());
        }
        (false, _, Some(_)) => {
            return Err(InputError::Other(format!("--element: only for {GYRO_EFFECT}, not for {effect}")).into());
        }
        (false, None, _) => {
            return Err(
                InputError::Other(format!("--accelerometer: {effect} needs the accelerometer (1-based)")).into()
            );
        }
        (true, None, Some(e)) => Target::Gyroscopes(e),
        (false, Some(j), None) => Target::Accelerometer(j),
    };
    let array = gfcal::config::array::load_recording_array(array_path).map_err(InputError::Config)?;
    let mut table = gfcal::io::table::Table::read(path).map_err(|e| InputError::Other(e.to_string()))?;
    // The recording is checked as `calibrate` checks it (columns, values, time) before anything is added.
    gfcal::selfcal::recording::Recording::from_table(&table, &array).map_err(|e| InputError::Other(e.to_string()))?;
    let what = match target {
        Target::Accelerometer(j) => {
            let censored = gfcal::discrepancy::inject::inject(&mut table, &array, effect, j, value)
                .map_err(|e| InputError::Other(e.to_string()))?;
            let rows = table.rows();
            format!(
                "accelerometer {j} (column {}); {censored} of its {rows} outputs put at the rail by the effect (left out as clipped)",
                array.accelerometer_columns[j - 1]
            )
        }
        Target::Gyroscopes(element) => {
            gfcal::discrepancy::inject::inject_gyro(&mut table, &array, element, value)
                .map_err(|e| InputError::Other(e.to_string()))?;
            format!("the gyroscopes (element {element} of G)")
        }
    };
    table.write(out).map_err(|e| anyhow::anyhow!("{e}"))?;
    eprintln!("wrote {}: {} with {effect} = {value} on {what}", out.display(), path.display());
    Ok(())
}
