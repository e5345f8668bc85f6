//! The binary's `run` and `summarize` commands (part of the `gfcal` binary).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;

use super::error::InputError;
use super::outputs::{Output, check_outputs};
use super::progress::Progress;
use gfcal::mc::runner::RunError;
use gfcal::mc::summary::{Summary, summarize as summarize_dir, summary_csv};
use gfcal::mc::{McConfig, RunOptions};

/// `I/N` from the flag, else from Slurm's array variables, else `0/1`.
fn shard(flag: Option<&str>) -> Result<(u64, u64), InputError> {
    let parse = |i: &str, n: &str, what: &str| -> Result<(u64, u64), InputError> {
        let bad = || InputError::Other(format!("{what}: expected I/N with 0 <= I < N, got `{i}/{n}`"));
        let i: u64 = i.trim().parse().map_err(|_| bad())?;
        let n: u64 = n.trim().parse().map_err(|_| bad())?;
        if n == 0 || i >= n { Err(bad()) } else { Ok((i, n)) }
    };
    if let Some(f) = flag {
        let (i, n) = f.split_once('/').ok_or_else(|| InputError::Other(format!("--shard: expected I/N, got `{f}`")))?;
        return parse(i, n, "--shard");
    }
    match (std::env::var("SLURM_ARRAY_TASK_ID"), std::env::var("SLURM_ARRAY_TASK_COUNT")) {
        (Ok(id), Ok(count)) => {
            let min: i64 = std::env::var("SLURM_ARRAY_TASK_MIN").ok().and_then(|m| m.parse().ok()).unwrap_or(0);
            let id: i64 = id
                .trim()
                .parse()
                .map_err(|_| InputError::Other(format!("SLURM_ARRAY_TASK_ID is not a number: `{id}`")))?;
            parse(
                &(id - min).to_string(),
                &count,
                "SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN / SLURM_ARRAY_TASK_COUNT",
            )
        }
        _ => Ok((0, 1)),
    }
}

pub fn run(
    config: &Path,
    out: Option<PathBuf>,
    resume: bool,
    force: bool,
    shard_flag: Option<&str>,
    threads: Option<usize>,
    interval_s: f64,
) -> anyhow::Result<()> {
    let cfg =
        McConfig::load(config).map_err(|e| super::check::input_error(e, config, super::check::ConfigKind::Run))?;
    let shard = shard(shard_flag)?;
    if threads == Some(0) {
        return Err(InputError::Other("--threads must be at least 1".into()).into());
    }
    if !(interval_s.is_finite() && interval_s > 0.0) {
        return Err(InputError::Other(format!("--progress-interval-s must be positive, got {interval_s}")).into());
    }
    let out = out.unwrap_or_else(|| PathBuf::from("results").join(&cfg.name));
    check_outputs(&[Output::Folder("--out", &out)])?;
    let opts = RunOptions { out: out.clone(), resume, force, shard, threads };
    eprintln!(
        "gfcal: run `{}`: {} cell(s) x {} trials = {} trials in {} parts; shard {}/{}; output {}",
        cfg.name,
        cfg.cells.len(),
        cfg.trials_per_cell,
        cfg.total_trials(),
        cfg.parts(),
        shard.0,
        shard.1,
        out.display()
    );
    // What would make part of the result meaningless, said before the work starts.
    for cell in cfg.cells.iter().filter(|c| c.noise.is_zero()) {
        eprintln!(
            "gfcal: warning: cell {} has no noise: its Cramer-Rao sigmas are 0, so the summary's `ratio` and \
             `coverage_95` are undefined for it (the recovered values and the drift are exact)",
            cell.index
        );
    }
    let progress = Progress::new(Duration::from_secs_f64(interval_s));
    let outcome = gfcal::mc::run(&cfg, config, &opts, &progress).map_err(|e| match e {
        RunError::Output { .. } => anyhow::Error::new(InputError::Other(e.to_string())),
        other => anyhow::Error::new(other),
    })?;
    eprintln!(
        "gfcal: {} trials run, {} parts written, {} already done{}",
        outcome.trials_run,
        outcome.parts_written,
        outcome.parts_skipped,
        if outcome.complete { "" } else { "; other shards' parts are still missing" }
    );
    let summary = match outcome.summary {
        Some(summary) => summary,
        None => summarize_dir(&out).context("cannot summarize the run")?,
    };
    write_summary(&out, &summary)?;
    print_summary(&cfg, &summary, outcome.complete);
    no_estimate_is_a_failure(&out, &summary)
}

/// A run in which no trial produced an estimate has no result: exit 1, saying where to look.
fn no_estimate_is_a_failure(dir: &Path, summary: &Summary) -> anyhow::Result<()> {
    if summary.trials > 0 && !summary.parameters.is_empty() && summary.parameters.iter().all(|p| p.n == 0) {
        anyhow::bail!(
            "no trial of the {} in {} produced an estimate: every parameter is NaN (the trials table's `message` \
             column says why each fit failed)",
            summary.trials,
            dir.display()
        );
    }
    Ok(())
}

pub fn summarize(dir: &Path) -> anyhow::Result<()> {
    let run_file = dir.join("run.json");
    let text = std::fs::read_to_string(&run_file).map_err(|e| {
        InputError::Other(format!("{}: cannot read ({e}); is this a gfcal run folder?", run_file.display()))
    })?;
    let run: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| InputError::Other(format!("{}: {e}", run_file.display())))?;
    let config_text = run["config_text"].as_str().unwrap_or_default().to_string();
    let origin = PathBuf::from(run["config_path"].as_str().unwrap_or("run.json"));
    let cfg = McConfig::from_text(config_text, &origin).map_err(InputError::Config)?;
    check_outputs(&[Output::File("summary.csv", &dir.join("summary.csv"))])?;
    let summary = summarize_dir(dir).context("cannot summarize the run")?;
    write_summary(dir, &summary)?;
    if summary.trials == cfg.total_trials() {
        gfcal::mc::claim::tidy(dir);
    }
    print_summary(&cfg, &summary, summary.trials == cfg.total_trials());
    no_estimate_is_a_failure(dir, &summary)
}

fn write_summary(dir: &Path, summary: &Summary) -> anyhow::Result<()> {
    let path = dir.join("summary.csv");
    gfcal::io::write_atomic(&path, summary_csv(summary).as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}

fn print_summary(cfg: &McConfig, s: &Summary, complete: bool) {
    use gfcal::io::format::significant as sig;
    println!(
        "Summary of {} trials{} (summary.csv; SI units)",
        s.trials,
        if complete { "" } else { ", partial: the run is not complete" }
    );
    let fits = gfcal::mc::summary::cell_fits(s);
    let flags = gfcal::mc::summary::cell_flags(s);
    for cell in &cfg.cells {
        let factors: Vec<String> = cell
            .factors
            .iter()
            .map(|(k, v)| match v {
                gfcal::mc::config::FactorValue::Number(x) => format!("{k} = {}", sig(*x, 4)),
                gfcal::mc::config::FactorValue::Text(t) => format!("{k} = {t}"),
            })
            .collect();
        println!(
            "\ncell {}{}",
            cell.index,
            if factors.is_empty() { String::new() } else { format!(": {}", factors.join(", ")) }
        );
        let c = cell.index as u32;
        if let Some(f) = gfcal::mc::summary::of_cell(&fits, c, |f| f.cell).first() {
            println!("  fits: {}", f.describe());
            println!(
                "  parameter statistics: the trials with an estimate, converged or not (column n); drift of the \
                 estimated compensation: the {} estimated trials",
                f.estimated
            );
        }
        for flag in gfcal::mc::summary::of_cell(&flags, c, |f| f.cell()) {
            println!("  FLAG: {}", flag.describe());
        }
        println!(
            "  {:<16} {:>6} {:>7} {:>12} {:>12} {:>12} {:>7} {:>11} {:>12} {:>11}",
            "parameter", "unit", "n", "bias", "rmse", "crb_sigma", "ratio", "coverage_95", "median_abs", "worst_share"
        );
        for p in s.parameters_of(c) {
            println!(
                "  {:<16} {:>6} {:>7} {:>12} {:>12} {:>12} {:>7.3} {:>11.3} {:>12} {:>11.3}",
                p.name,
                p.unit,
                p.n,
                sig(p.bias, 4),
                sig(p.rmse, 4),
                sig(p.crb_sigma, 4),
                p.ratio,
                p.coverage_95,
                sig(p.median_abs_error, 4),
                p.worst_share
            );
        }
        println!(
            "  {:<44} {:>7} {:>7} {:>9} {:>12} {:>12} {:>12}",
            "drift", "unit", "n", "diverged", "median", "p95", "p05"
        );
        for d in s.drift_of(c) {
            println!(
                "  {:<44} {:>7} {:>7} {:>9} {:>12} {:>12} {:>12}",
                d.column,
                d.unit,
                d.n,
                d.diverged,
                sig(d.median, 4),
                sig(d.p95, 4),
                sig(d.p05, 4)
            );
        }
    }
    if !flags.is_empty() {
        let mut cells: Vec<String> = flags.iter().map(|f| f.cell().to_string()).collect();
        cells.dedup();
        println!("\n{} cell(s) flagged (FLAG lines above): {}", cells.len(), cells.join(", "));
    }
}

pub fn sensitivity(dir: &Path, max_trials: usize) -> anyhow::Result<()> {
    if !dir.join("run.json").exists() {
        return Err(InputError::Other(format!("{}: no run.json; is this a gfcal run folder?", dir.display())).into());
    }
    if max_trials < 10 {
        return Err(InputError::Other(format!("--max-trials must be at least 10, got {max_trials}")).into());
    }
    check_outputs(&[Output::File("sensitivity.csv", &dir.join("sensitivity.csv"))])?;
    let rows = gfcal::mc::sensitivity::sensitivity(dir, max_trials).context("cannot compute the sensitivity")?;
    let path = dir.join("sensitivity.csv");
    gfcal::io::write_atomic(&path, gfcal::mc::sensitivity::sensitivity_csv(&rows).as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    let cfg = gfcal::report::run::load_config(dir).map_err(|e| InputError::Other(e.to_string()))?;
    if cfg.cells.iter().any(|c| c.saltelli.is_some()) {
        let rows = gfcal::mc::sobol::sobol(dir, &cfg).context("cannot compute the Sobol' indices")?;
        let sobol_path = dir.join("sobol.csv");
        gfcal::io::write_atomic(&sobol_path, gfcal::mc::sobol::sobol_csv(&rows).as_bytes())
            .with_context(|| format!("cannot write {}", sobol_path.display()))?;
        println!("Largest total Sobol' indices of log10 of each drift column (first order in brackets):");
        let mut outputs: Vec<(u32, String)> = rows.iter().map(|r| (r.cell, r.output.clone())).collect();
        outputs.dedup();
        for (cell, output) in outputs {
            let mut mine: Vec<&gfcal::mc::sobol::SobolRow> =
                rows.iter().filter(|r| r.cell == cell && r.output == output).collect();
            mine.sort_by(|a, b| b.total.total_cmp(&a.total));
            let top: Vec<String> =
                mine.iter().take(3).map(|r| format!("{} {:.2} ({:.2})", r.input, r.total, r.first_order)).collect();
            println!("  cell {cell} {output:<40} {}", top.join(", "));
        }
        eprintln!("wrote {}", sobol_path.display());
    }
    // The three largest drivers of each output, or why there are none.
    let mut outputs: Vec<(u32, String)> = rows.iter().map(|r| (r.cell, r.output.clone())).collect();
    outputs.dedup();
    println!("Largest standardised rank regression coefficients (SRRC) per drift column; R^2 of the rank regression:");
    for (cell, output) in outputs {
        let mut mine: Vec<&gfcal::mc::sensitivity::SensitivityRow> =
            rows.iter().filter(|r| r.cell == cell && r.output == output).collect();
        if let Some(note) = mine.iter().find_map(|r| r.note.as_ref()) {
            println!("  cell {cell} {output:<40} no coefficients: {note}");
            continue;
        }
        let size = |r: &&gfcal::mc::sensitivity::SensitivityRow| r.srrc.unwrap_or(0.0).abs();
        mine.sort_by(|a, b| size(b).total_cmp(&size(a)));
        let top: Vec<String> =
            mine.iter().take(3).map(|r| format!("{} {:+.2}", r.input, r.srrc.unwrap_or(f64::NAN))).collect();
        println!(
            "  cell {cell} {output:<40} R^2 {:.2} ({} trials): {}",
            mine.first().and_then(|r| r.r2).unwrap_or(f64::NAN),
            mine.first().map_or(0, |r| r.trials),
            top.join(", ")
        );
    }
    eprintln!("wrote {}", path.display());
    Ok(())
}

pub fn report(dir: &Path) -> anyhow::Result<()> {
    use gfcal::report::ReportError;
    // The output of `gfcal lincov` alone (no run): its page only.
    let lincov = gfcal::report::lincov::has_lincov(dir);
    if lincov && !dir.join("run.json").exists() {
        return lincov_report(dir);
    }
    if dir.join("run.json").exists() {
        check_outputs(&[
            Output::File("report.html", &dir.join("report.html")),
            Output::Folder("report/", &dir.join("report")),
        ])?;
    }
    let (report, written) = gfcal::report::run::write_run_report(dir).map_err(|e| match e {
        ReportError::Input { .. } => anyhow::Error::new(InputError::Other(e.to_string())),
        other => anyhow::Error::new(other),
    })?;
    for note in &report.notes {
        eprintln!("gfcal: note: {note}");
    }
    println!(
        "wrote {} ({} figures, {} data points) and {} SVG files in {}",
        dir.join("report.html").display(),
        report.figures.len(),
        report.figures.iter().map(|f| f.data_points).sum::<usize>(),
        written.len().saturating_sub(1),
        dir.join("report").display()
    );
    if lincov {
        lincov_report(dir)?;
    }
    Ok(())
}

/// `DIR/lincov.html` from the files `gfcal lincov` wrote.
fn lincov_report(dir: &Path) -> anyhow::Result<()> {
    use gfcal::report::ReportError;
    let (report, written) = gfcal::report::lincov::write_lincov_report(dir).map_err(|e| match e {
        ReportError::Input { .. } => anyhow::Error::new(InputError::Other(e.to_string())),
        other => anyhow::Error::new(other),
    })?;
    for note in &report.notes {
        eprintln!("gfcal: note: {note}");
    }
    println!(
        "wrote {} ({} figures) and {} SVG files in {}",
        dir.join("lincov.html").display(),
        report.figures.len(),
        written.len().saturating_sub(1),
        dir.join("lincov_report").display()
    );
    Ok(())
}
