//! The binary's calibration commands: load a config, call the library, format the answer.
//! (Part of the `gfcal` binary, not the library.)

use std::path::Path;

use anyhow::Context;
use nalgebra::DVector;

use crate::InputError;
use gfcal::calib::Layout;
use gfcal::calib::design::{candidate_pool, greedy};
use gfcal::calib::fisher::{Identifiability, analyse, structurally_unidentifiable};
use gfcal::calib::pose::{PoseError, marginal_fisher};
use gfcal::calib::reproduce::{PaperRun, reproduce};
use gfcal::calib::schedule::{Schedule, hung_lee_2006_augmented};
use gfcal::config::calibration::CalibrationConfig;
use gfcal::sensor::noise::{NoiseSpec, WhiteNoise};
use gfcal::units::{M_S2_PER_MG, M_S2_PER_UG, STANDARD_GRAVITY_M_S2};

struct Loaded {
    cfg: CalibrationConfig,
    layout: Layout,
    x: DVector<f64>,
    density_m_s2_per_sqrt_hz: f64,
}

fn load(path: &Path) -> anyhow::Result<Loaded> {
    let cfg = CalibrationConfig::load(path)
        .map_err(|e| crate::check::input_error(e, path, crate::check::ConfigKind::Calibration))?;
    let density_m_s2_per_sqrt_hz = cfg.white_density_m_s2_per_sqrt_hz();
    if density_m_s2_per_sqrt_hz <= 0.0 {
        return Err(InputError::Other(format!(
            "{}: key `noise`: identifiability needs a white noise level (`white_density_ug_per_sqrt_hz` or `white_sigma_mg`): the Cramer-Rao sigmas scale with it",
            path.display()
        ))
        .into());
    }
    let layout = Layout::new(&cfg.array, cfg.calibration.form)
        .map_err(|e| InputError::Other(format!("{}: {e}", path.display())))?;
    let x = layout
        .pack(&cfg.errors.truth)
        .map_err(|e| InputError::Other(format!("{}: key `errors`: {e}", path.display())))?;
    Ok(Loaded { cfg, layout, x, density_m_s2_per_sqrt_hz })
}

fn describe_noise(l: &Loaded) -> String {
    let rate = l.cfg.schedule.steps()[0].sample_rate_hz;
    format!(
        "white noise {:.4e} m/s^2/sqrt(Hz): {:.4e} m/s^2 per sample at {rate} Hz (bias instability and quantization are not in the bound)",
        l.density_m_s2_per_sqrt_hz,
        l.density_m_s2_per_sqrt_hz * rate.sqrt()
    )
}

fn describe_pose(pose: &PoseError) -> String {
    let one = |sigma_rad: f64| {
        if sigma_rad == 0.0 {
            "exact (perfect fixture)".to_string()
        } else if sigma_rad.is_infinite() {
            "free (placed by hand)".to_string()
        } else {
            format!("tilt sigma {sigma_rad:.3e} rad")
        }
    };
    format!("pose error: static poses {}, spin axes {}", one(pose.static_sigma_rad), one(pose.spin_sigma_rad))
}

fn sigma_table(layout: &Layout, before: &Identifiability, after: Option<&Identifiability>) -> String {
    // SI units, as in summary.csv, report.html and diagnose (the unit column says which).
    let mut s = format!("{:<18} {:>6} {:>14} {:>14}", "parameter", "unit", "target", "crb_sigma");
    if after.is_some() {
        s.push_str(&format!(" {:>14}", "crb_after"));
    }
    s.push_str("  status\n");
    for i in 0..layout.len() {
        let unit = layout.kind(i).si_unit();
        let fmt = |v: f64| if v.is_finite() { format!("{:>14.4e}", v) } else { format!("{:>14}", "unidentifiable") };
        let last = after.unwrap_or(before);
        let status = if !last.crb_sigma[i].is_finite() {
            "UNIDENTIFIABLE"
        } else if last.crb_sigma[i] > last.target[i] {
            "above target"
        } else {
            "ok"
        };
        s.push_str(&format!(
            "{:<18} {:>6} {} {}",
            before.names[i],
            unit,
            fmt(before.target[i]),
            fmt(before.crb_sigma[i])
        ));
        if let Some(a) = after {
            s.push_str(&format!(" {}", fmt(a.crb_sigma[i])));
        }
        s.push_str(&format!("  {status}\n"));
    }
    s
}

fn weak_list(id: &Identifiability) -> String {
    if id.weak.is_empty() {
        return "none: every combination is within its targets\n".into();
    }
    let mut s = String::new();
    for d in &id.weak {
        let how = if d.sigma_in_targets.is_finite() {
            format!("{:>9.2} x target", d.sigma_in_targets)
        } else {
            "  unidentifiable".into()
        };
        s.push_str(&format!("  {how}   {}\n", id.describe(d)));
    }
    s
}

pub fn identify(path: &Path) -> anyhow::Result<()> {
    let l = load(path)?;
    let (cfg, layout) = (&l.cfg, &l.layout);
    let g = cfg.calibration.gravity_m_s2;
    let fim = marginal_fisher(layout, &l.x, &cfg.schedule, g, l.density_m_s2_per_sqrt_hz, &cfg.calibration.pose);
    let id = analyse(layout, &l.x, &fim, &cfg.targets);
    println!(
        "schedule `{}` ({} steps), {} form, evaluated at the config's error parameters",
        cfg.schedule.name,
        cfg.schedule.len(),
        cfg.calibration.form.name()
    );
    println!("{}", describe_noise(&l));
    if !cfg.calibration.pose.is_perfect() {
        println!("{}", describe_pose(&cfg.calibration.pose));
    }
    println!();
    print!("{}", sigma_table(layout, &id, None));
    let structural = structurally_unidentifiable(layout, &l.x, &cfg.schedule, g);
    println!("\nUnidentifiable whatever the errors (structural):");
    if structural.is_empty() {
        println!("  none");
    } else {
        for i in &structural {
            println!("  {}", layout.name(*i));
        }
    }
    if !id.unidentifiable.is_empty() {
        let names: Vec<String> = id.unidentifiable.iter().map(|&i| layout.name(i)).collect();
        println!("Unidentifiable at these error parameters: {}", names.join(", "));
    }
    println!("\nWeak or unidentifiable combinations (Cramer-Rao sigma of the unit combination, in targets):");
    print!("{}", weak_list(&id));
    Ok(())
}

pub fn design(path: &Path) -> anyhow::Result<()> {
    let l = load(path)?;
    let (cfg, layout) = (&l.cfg, &l.layout);
    let first = &cfg.schedule.steps()[0];
    let pool = candidate_pool(first.duration_s, first.sample_rate_hz, &cfg.design.spin_rates_rad_s);
    let result = greedy(
        layout,
        &l.x,
        &cfg.schedule,
        &pool,
        &cfg.targets,
        l.density_m_s2_per_sqrt_hz,
        cfg.calibration.gravity_m_s2,
        cfg.design.max_added_steps,
        &cfg.calibration.pose,
    )
    .map_err(|e| InputError::Other(format!("{}: key `schedule`: {e}", path.display())))?;
    println!(
        "base schedule `{}` ({} steps); pool of {} candidate steps",
        cfg.schedule.name,
        cfg.schedule.len(),
        pool.len()
    );
    println!("{}", describe_noise(&l));
    if !cfg.calibration.pose.is_perfect() {
        println!("{}", describe_pose(&cfg.calibration.pose));
    }
    println!();
    println!("Steps added ({}):", result.added.len());
    for (i, s) in result.added.iter().enumerate() {
        println!("  {:>2}. {}", i + 1, s.name);
    }
    println!();
    print!("{}", sigma_table(layout, &result.before, Some(&result.after)));
    println!("\nWeak combinations before:");
    print!("{}", weak_list(&result.before));
    println!("Weak combinations after:");
    print!("{}", weak_list(&result.after));
    if result.met() {
        println!("\nEvery Cramer-Rao sigma is below its target with {} steps.", result.schedule.len());
    } else {
        println!(
            "\nTargets NOT met after adding {} steps (limit design.max_added_steps = {}).",
            result.added.len(),
            cfg.design.max_added_steps
        );
    }
    Ok(())
}

pub fn paper(out: &Path, trials: usize, seed: u64, density_ug: f64) -> anyhow::Result<()> {
    if trials < 2 {
        return Err(InputError::Other(format!("--trials must be at least 2, got {trials}")).into());
    }
    if !(density_ug.is_finite() && density_ug > 0.0) {
        return Err(
            InputError::Other(format!("--noise-density-ug-per-sqrt-hz must be positive, got {density_ug}")).into()
        );
    }
    let array = gfcal::array::Array::cube(0.1)?;
    let (rate_rad_s, duration_s, sample_rate_hz) = (2.0 * std::f64::consts::PI, 1.0, 100.0);
    let paper_schedule = Schedule::hung_lee_2006(&array, rate_rad_s, duration_s, sample_rate_hz)?;
    let augmented = hung_lee_2006_augmented(&array, rate_rad_s, duration_s, sample_rate_hz)?;
    let noise = NoiseSpec {
        white: WhiteNoise::Density { density_m_s2_per_sqrt_hz: density_ug * M_S2_PER_UG },
        ..NoiseSpec::default()
    };
    let run = PaperRun { noise, seed, trials, g_m_s2: STANDARD_GRAVITY_M_S2 };
    let tables = reproduce(&array, &paper_schedule, &augmented, &run)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let setting = format!(
        "Noise: white, {density_ug} ug/sqrt(Hz) on every accelerometer ({:.4} mg per sample at {sample_rate_hz} Hz), {duration_s} s per step, spins at {rate_rad_s:.4} rad/s. Monte Carlo: {trials} trials per schedule (seed {seed}), joint estimator (triad form, linear start); converged {} / {} (paper schedule), {} / {} (augmented, {} steps). `noise_free`: the paper's own procedure on noise-free data.",
        density_ug * M_S2_PER_UG * sample_rate_hz.sqrt() / M_S2_PER_MG,
        tables.paper_schedule.converged,
        trials,
        tables.augmented_schedule.converged,
        trials,
        augmented.len()
    );
    let write = |name: &str, text: String| -> anyhow::Result<()> {
        let path = out.join(name);
        gfcal::io::write_atomic(&path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
    };
    use gfcal::io::csv::{table_csv, table_markdown};
    write("table8.csv", table_csv(&tables.table8))?;
    write("table9.csv", table_csv(&tables.table9))?;
    let t8 =
        table_markdown(&format!("Table 8 reproduced (bias, scale factor, misalignment). {setting}"), &tables.table8);
    let t9 = table_markdown(&format!("Table 9 reproduced (location errors). {setting}"), &tables.table9);
    write("table8.md", t8.clone())?;
    write("table9.md", t9.clone())?;
    let mut from8 =
        String::from("accelerometer,dx_mm,dy_mm,dz_mm,paper_model_dx_mm,paper_model_dy_mm,paper_model_dz_mm\n");
    for (j, (d, m)) in tables.table9_from_table8_mm.iter().zip(&tables.table9_from_table8_paper_model_mm).enumerate() {
        from8.push_str(&format!("{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}\n", j + 1, d[0], d[1], d[2], m[0], m[1], m[2]));
    }
    write("table9_from_table8.csv", from8)?;
    let settings = serde_json::json!({
        "gfcal_version": env!("CARGO_PKG_VERSION"),
        "noise_density_ug_per_sqrt_hz": density_ug,
        "sample_rate_hz": sample_rate_hz,
        "step_duration_s": duration_s,
        "spin_rate_rad_s": rate_rad_s,
        "trials": trials,
        "seed": seed,
        "estimator": "joint, triad form, linear start",
        "converged_paper_schedule": tables.paper_schedule.converged,
        "converged_augmented_schedule": tables.augmented_schedule.converged,
        "paper_schedule_steps": paper_schedule.steps().iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
        "augmented_schedule_steps": augmented.steps().iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
    });
    write("settings.json", serde_json::to_string_pretty(&settings)? + "\n")?;
    println!("{t8}\n{t9}");
    eprintln!(
        "wrote {}/table8.csv, table9.csv, table8.md, table9.md, table9_from_table8.csv, settings.json",
        out.display()
    );
    Ok(())
}

pub fn simulate_log(config: &Path, out: &Path) -> anyhow::Result<()> {
    use gfcal::config::simulate_log::SimulateLogConfig;
    use gfcal::discrepancy::simulate::LogSimulation;
    let cfg = SimulateLogConfig::load(config)
        .map_err(|e| crate::check::input_error(e, config, crate::check::ConfigKind::SimulateLog))?;
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
    use gfcal::discrepancy::diagnose::{Correlation, DiagnoseError, DiagnoseSettings, Explanation, Verdict, diagnose};
    use gfcal::discrepancy::log::CalibrationLog;
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
    let correlations =
        gfcal::discrepancy::diagnose::regressor_correlations(&log, &array, b, settings.form, settings.g_m_s2);
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
    if let Some(path) = json {
        let verdict_json = |v: &Verdict| match v {
            Verdict::ConfoundedWithModel(with) => serde_json::json!({"confounded_with_model": with}),
            Verdict::Tested { delta_chi2, p_value } => {
                serde_json::json!({"delta_chi2": delta_chi2, "p_value": p_value})
            }
            Verdict::NoSigma => serde_json::json!({"no_sigma": true}),
        };
        let body = serde_json::json!({
            "log": log_path.display().to_string(),
            "noise_sigma_m_s2": b.noise_sigma_m_s2,
            "gap_before": d.gap_before,
            "gap_after": d.gap_after,
            "p_value_before": b.p_value,
            "p_value_after": d.p_value_after,
            "held_out_before": d.held_out_before,
            "held_out_after": d.held_out_after,
            "unmodelled_effect_remains": d.unmodelled_effect_remains,
            "explanation": d.explanation().as_str(),
            "effects": d.findings.iter().map(|f| serde_json::json!({
                "name": f.name,
                "accelerometer": f.accelerometer.map(|j| j + 1),
                "value": if f.value.len() == 1 { serde_json::json!(f.value[0]) } else { serde_json::json!(f.value) },
                "sigma": if f.sigma.len() == 1 { serde_json::json!(f.sigma[0]) } else { serde_json::json!(f.sigma) },
                "unit": f.unit,
                "gap_before": f.gap_before,
                "gap_after": f.gap_after,
                "p_value": f.p_value,
                "confounded_with": f.confounded_with,
                "unseen_directions": f.unseen_directions,
            })).collect::<Vec<_>>(),
            "regressor_correlations": correlations.iter().map(|row| match &row.correlation {
                Correlation::PerAccelerometer(r) => serde_json::json!({"regressor": row.regressor, "per_accelerometer": r}),
                Correlation::Constant(v) if row.regressor == "temperature" => serde_json::json!({"regressor": row.regressor, "constant_c": v}),
                Correlation::Constant(v) => serde_json::json!({"regressor": row.regressor, "constant": v}),
            }).collect::<Vec<_>>(),
            "candidates": d.verdicts.iter().map(|(l, v)| serde_json::json!({"candidate": l, "verdict": verdict_json(v)})).collect::<Vec<_>>(),
            "per_step": log.steps.iter().enumerate().map(|(i, s)| serde_json::json!({
                "step": s.step,
                "kind": if s.omega_b_rad_s.norm() > 0.0 { "spin" } else { "static" },
                "whitened_before": b.whitened[i],
                "whitened_after": d.per_step_after[i],
            })).collect::<Vec<_>>(),
        });
        gfcal::io::write_atomic(path, (serde_json::to_string_pretty(&body)? + "\n").as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = report {
        let r = gfcal::report::diagnosis::diagnosis_report(&log_path.display().to_string(), &log, &d, alpha)?;
        gfcal::io::write_atomic(path, r.html.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
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
}

pub fn diagnose_recordings(
    table: &gfcal::io::table::Table,
    array_path: &Path,
    held_out: &[std::path::PathBuf],
    options: RecordingOptions,
) -> anyhow::Result<()> {
    let RecordingOptions { json, report, alpha, use_gyro } = options;
    use gfcal::discrepancy::diagnose::Explanation;
    use gfcal::discrepancy::recorded::{Gap, RecordedError, diagnose_recordings};
    use gfcal::selfcal::calibrate::{CalibrateError, CalibrateSettings};
    use gfcal::selfcal::fit::FitError;
    use gfcal::selfcal::recording::Recording;
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(InputError::Other(format!("--alpha must be between 0 and 1, got {alpha}")).into());
    }
    let path = table.path.as_path();
    let array = gfcal::config::array::load_recording_array(array_path).map_err(InputError::Config)?;
    let rec = Recording::from_table(table, &array).map_err(|e| InputError::Other(e.to_string()))?;
    let mut others = Vec::new();
    for other in held_out {
        let o = Recording::read(other, &array)
            .map_err(|e| InputError::Other(format!("held-out recording for {}: {e}", path.display())))?;
        rec.same_array_as(&o).map_err(|e| InputError::Other(e.to_string()))?;
        others.push(o);
    }
    let settings = CalibrateSettings { use_gyro, ..CalibrateSettings::default() };
    let d = diagnose_recordings(&rec, &array, &others, &settings, alpha).map_err(|e| -> anyhow::Error {
        match e {
            RecordedError::Calibrate(CalibrateError::Fit { source: FitError::Singular(_), .. }) => {
                anyhow::anyhow!("{e}")
            }
            other => InputError::Other(other.to_string()).into(),
        }
    })?;
    let show = |g: &Gap| {
        format!(
            "static chi2/dof {:.3}, dynamic {}",
            g.static_chi2_dof,
            g.dynamic.map(|v| format!("{v:.1}")).unwrap_or_else(|| "- (no rotation phase)".into())
        )
    };
    println!(
        "recording {}: {} static interval(s), {} dynamic sample(s); the gap (1 is noise alone; dynamic: (residual RMS / static noise RMS)^2)",
        path.display(),
        d.calibration.static_data.means.nrows(),
        d.calibration.dynamic_index.len()
    );
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
    println!("\neffects named (each lowers the gap on every held-out recording):");
    if d.findings.is_empty() {
        println!("  none");
    }
    for f in &d.findings {
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
    println!("\nsensing points inside each package (location of each axis minus the first axis's, mm):");
    for sp in &d.sensing_points {
        let v: Vec<String> =
            sp.difference_m.iter().zip(&sp.sigma_m).map(|(v, s)| format!("{:.2}+-{:.2}", v * 1e3, s * 1e3)).collect();
        println!(
            "  package {} (accelerometers {:?}): p = {:.1e}: {}",
            sp.package + 1,
            sp.accelerometers.iter().map(|j| j + 1).collect::<Vec<_>>(),
            sp.p_value,
            v.join(" ")
        );
    }
    match d.explanation() {
        Explanation::Partial => println!(
            "\na partial explanation: what is left is still above the noise (unexplained, this large: the numbers after the named effects above)"
        ),
        Explanation::Unexplained => println!("\nunexplained: the gap is above the noise and nothing tried lowers it"),
        Explanation::Complete => println!("\nthe named effects explain the gap to the noise"),
        Explanation::NothingToExplain => println!("\nthe baseline explains the recordings to the noise"),
    }
    if let Some(json_path) = json {
        let gap = |g: &Gap| {
            serde_json::json!({
                "static_chi2_dof": g.static_chi2_dof,
                "dynamic_gap": g.dynamic,
            })
        };
        let fitting_after = d.fitting_after_each.last().map_or(d.fitting, |(_, g)| *g);
        let body = serde_json::json!({
            "recording": path.display().to_string(),
            "array": array_path.display().to_string(),
            "gap_before": d.fitting.static_chi2_dof,
            "gap_after": fitting_after.static_chi2_dof,
            "dynamic_gap_before": d.fitting.dynamic,
            "dynamic_gap_after": fitting_after.dynamic,
            "fitting": {"before": gap(&d.fitting), "after": gap(&fitting_after)},
            "held_out": d.held_out.iter().map(|h| serde_json::json!({
                "recording": h.recording.display().to_string(),
                "gap_before": h.before.static_chi2_dof,
                "gap_after": h.after.static_chi2_dof,
                "dynamic_gap_before": h.before.dynamic,
                "dynamic_gap_after": h.after.dynamic,
                "bias_change_m_s2": h.bias_change_m_s2,
                "bias_change_sigma_m_s2": h.bias_change_sigma_m_s2,
                "scale_factor_change": h.scale_factor_change,
                "scale_factor_change_sigma": h.scale_factor_change_sigma,
                "bias_change_p_value": h.bias_change_p_value,
                "scale_factor_change_p_value": h.scale_factor_change_p_value,
                "after_each": h.after_each.iter().map(|(name, g)| serde_json::json!({
                    "effect": name,
                    "gap": g.static_chi2_dof,
                    "dynamic_gap": g.dynamic,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "fitting_after_each": d.fitting_after_each.iter().map(|(name, g)| serde_json::json!({
                "effect": name,
                "gap": g.static_chi2_dof,
                "dynamic_gap": g.dynamic,
            })).collect::<Vec<_>>(),
            "rank_tests": d.ranks.iter().map(|r| serde_json::json!({
                "name": r.name, "parameters": r.parameters, "unseen": r.unseen,
                "value": r.value, "sigma": r.sigma, "p_value_joint": r.p_value_joint,
            })).collect::<Vec<_>>(),
            "sensing_points": d.sensing_points.iter().map(|sp| serde_json::json!({
                "package": sp.package + 1,
                "accelerometers": sp.accelerometers.iter().map(|j| j + 1).collect::<Vec<_>>(),
                "difference_m": sp.difference_m,
                "sigma_m": sp.sigma_m,
                "p_value": sp.p_value,
            })).collect::<Vec<_>>(),
            "effects": d.findings.iter().map(|f| serde_json::json!({
                "name": f.name,
                "accelerometer": f.accelerometer.map(|j| j + 1),
                "package": f.package.map(|m| m + 1),
                "package": f.package.map(|m| m + 1),
                "value": f.value,
                "sigma": f.sigma,
                "unit": f.unit,
                "what": f.what,
                "p_value_largest": f.p_value_largest,
            })).collect::<Vec<_>>(),
            "not_named": d.not_named.iter().map(|(n, w)| serde_json::json!({"name": n, "why": w})).collect::<Vec<_>>(),
            "explanation": d.explanation().as_str(),
            "alpha": alpha,
        });
        gfcal::io::write_atomic(json_path, (serde_json::to_string_pretty(&body)? + "\n").as_bytes())
            .with_context(|| format!("cannot write {}", json_path.display()))?;
        eprintln!("wrote {}", json_path.display());
    }
    if let Some(path) = report {
        let (html, _) = gfcal::report::recorded::recorded_report(&d, &rec, &array, settings.fit.gravity_m_s2)?;
        gfcal::io::write_atomic(path, html.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
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
