//! `gfcal identify`, `gfcal design` and `gfcal paper`: load a config, call the library, format
//! the answer.

use std::path::Path;

use anyhow::Context;
use nalgebra::DVector;

use super::error::InputError;
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
        .map_err(|e| super::check::input_error(e, path, super::check::ConfigKind::Calibration))?;
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

/// Writes the designed schedule where `--schedule-out` asks.
fn write_schedule(out: Option<&Path>, schedule: &gfcal::calib::schedule::Schedule) -> anyhow::Result<()> {
    if let Some(out) = out {
        let text = gfcal::config::schedule::schedule_toml(schedule);
        gfcal::io::write_atomic(out, text.as_bytes()).with_context(|| format!("cannot write {}", out.display()))?;
        eprintln!("wrote {} (the designed schedule as [[schedule.step]])", out.display());
    }
    Ok(())
}

pub fn design(path: &Path, schedule_out: Option<&Path>) -> anyhow::Result<()> {
    let l = load(path)?;
    let (cfg, layout) = (&l.cfg, &l.layout);
    let first = &cfg.schedule.steps()[0];
    let pool = candidate_pool(first.duration_s, first.sample_rate_hz, &cfg.design.spin_rates_rad_s);
    if let Some(navigation) = &cfg.drift_navigation {
        return design_for_drift(path, &l, &pool, navigation, schedule_out);
    }
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
    write_schedule(schedule_out, &result.schedule)
}

/// `gfcal design` with drift targets: steps added until LinCov's drift meets them.
fn design_for_drift(
    path: &Path,
    l: &Loaded,
    pool: &[gfcal::calib::schedule::Step],
    navigation: &gfcal::config::calibration::DriftNavigation,
    schedule_out: Option<&Path>,
) -> anyhow::Result<()> {
    use gfcal::lincov::design::{DriftProblem, greedy_drift};
    let cfg = &l.cfg;
    let targets = &cfg.drift_targets;
    let result = greedy_drift(&DriftProblem {
        layout: &l.layout,
        x: &l.x,
        base: &cfg.schedule,
        pool,
        targets,
        navigation,
        density_m_s2_per_sqrt_hz: l.density_m_s2_per_sqrt_hz,
        g_m_s2: cfg.calibration.gravity_m_s2,
        pose: &cfg.calibration.pose,
        max_added: cfg.design.max_added_steps,
    })
    .map_err(|e| InputError::Other(format!("{}: {e}", path.display())))?;
    println!(
        "base schedule `{}` ({} steps); pool of {} candidate steps; designing for drift (LinCov, estimated \
         compensation at the config's error parameters, noise-free navigation)",
        cfg.schedule.name,
        cfg.schedule.len(),
        pool.len()
    );
    println!("{}", describe_noise(l));
    if !cfg.calibration.pose.is_perfect() {
        println!("{}", describe_pose(&cfg.calibration.pose));
    }
    println!();
    println!("Steps added ({}):", result.added.len());
    for (i, s) in result.added.iter().enumerate() {
        println!("  {:>2}. {}", i + 1, s.name);
    }
    println!();
    let unit = |m: usize| ["rad/s", "rad", "m/s", "m"][m];
    println!("{:<36} {:>6} {:>12} {:>12} {:>12}  status", "drift target", "unit", "target", "before", "after");
    let fmt = |v: f64| if v.is_finite() { format!("{v:>12.4e}") } else { format!("{:>12}", "unbounded") };
    for ((t, b), a) in targets.iter().zip(&result.before).zip(&result.after) {
        println!(
            "{:<36} {:>6} {:>12.4e} {} {}  {}",
            t.key,
            unit(t.metric),
            t.value,
            fmt(*b),
            fmt(*a),
            if *a <= t.value { "ok" } else { "above target" }
        );
    }
    if result.met(targets) {
        println!("\nEvery drift target is met with {} steps.", result.schedule.len());
    } else {
        println!(
            "\nDrift targets NOT met after adding {} steps (limit design.max_added_steps = {}).",
            result.added.len(),
            cfg.design.max_added_steps
        );
    }
    write_schedule(schedule_out, &result.schedule)
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
    use gfcal::calib::reproduce::{table_csv, table_markdown};
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
