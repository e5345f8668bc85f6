//! `gfcal lincov`: linear covariance analysis of a run config, its files, and the comparison with
//! a Monte Carlo run of the same config.

use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

use anyhow::Context;

use super::error::InputError;
use gfcal::io::format::significant as sig;
use gfcal::lincov::analysis::{LincovError, Settings};
use gfcal::lincov::compare::{compare, compare_csv};
use gfcal::lincov::output::{budget_csv, lincov_batch, lincov_csv, row_name};
use gfcal::mc::McConfig;

/// Trials per cell the ranking's SRRC reads (as `gfcal sensitivity`'s default).
const RANKING_TRIALS: usize = 20_000;

fn now() -> String {
    humantime::format_rfc3339_seconds(SystemTime::now()).to_string()
}

pub struct LincovArgs<'a> {
    pub config: &'a Path,
    pub out: Option<PathBuf>,
    pub compare: Option<&'a Path>,
    pub truths: usize,
    pub threads: Option<usize>,
}

pub fn lincov(a: LincovArgs<'_>) -> anyhow::Result<()> {
    let cfg =
        McConfig::load(a.config).map_err(|e| super::check::input_error(e, a.config, super::check::ConfigKind::Run))?;
    if a.truths == 0 {
        return Err(InputError::Other("--truths must be at least 1".into()).into());
    }
    if a.threads == Some(0) {
        return Err(InputError::Other("--threads must be at least 1".into()).into());
    }
    if let Some(run) = a.compare
        && !run.join("run.json").exists()
    {
        return Err(InputError::Other(format!(
            "--compare: {}: no run.json; is this a gfcal run folder?",
            run.display()
        ))
        .into());
    }
    let out = a.out.unwrap_or_else(|| PathBuf::from("results").join(&cfg.name));
    let settings = Settings { truths: a.truths, ..Settings::default() };
    let started = now();
    let clock = Instant::now();
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(n) = a.threads {
            b = b.num_threads(n);
        }
        b.build().context("cannot start worker threads")?
    };
    let results = pool.install(|| gfcal::lincov::run::analyse(&cfg, &settings)).map_err(|e| match e {
        LincovError::Unsupported { key, problem } => {
            anyhow::Error::new(InputError::Other(format!("{}: key `{key}`: {problem}", a.config.display())))
        }
        other => anyhow::Error::new(other),
    })?;
    let elapsed = clock.elapsed();
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let write = |name: &str, text: &str| -> anyhow::Result<()> {
        let path = out.join(name);
        gfcal::io::write_atomic(&path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
    };
    write("lincov.csv", &lincov_csv(&cfg, &results))?;
    write("budget.csv", &budget_csv(&cfg, &results))?;
    let finished = now();
    let metadata = vec![
        ("gfcal:version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("gfcal:git_commit".to_string(), env!("GFCAL_GIT_COMMIT").to_string()),
        ("gfcal:config".to_string(), cfg.text.clone()),
        ("gfcal:seed".to_string(), cfg.seed.to_string()),
        ("gfcal:truths".to_string(), a.truths.to_string()),
        ("gfcal:lincov_started".to_string(), started.clone()),
        ("gfcal:lincov_finished".to_string(), finished.clone()),
    ];
    let batch = lincov_batch(&cfg, &results).context("cannot build the lincov table")?;
    gfcal::io::parquet::write_part(&out.join("lincov.parquet"), &batch, &metadata)?;
    let provenance = serde_json::json!({
        "gfcal_version": env!("CARGO_PKG_VERSION"),
        "git_commit": env!("GFCAL_GIT_COMMIT"),
        "name": cfg.name,
        "config_path": a.config.display().to_string(),
        "config_text": cfg.text,
        "seed": cfg.seed,
        "cells": cfg.cells.len(),
        "factor_keys": cfg.factor_keys,
        "truths": a.truths,
        "refused_fraction": results.iter().map(|c| c.refused_fraction).collect::<Vec<_>>(),
        "nonlinearity_threshold": gfcal::lincov::analysis::LINEAR_THRESHOLD,
        "compute_s": elapsed.as_secs_f64(),
        "started": started,
        "finished": finished,
    });
    write("lincov.json", &(serde_json::to_string_pretty(&provenance)? + "\n"))?;
    println!(
        "LinCov of `{}`: {} cell(s) in {:.3} s (lincov.csv, lincov.parquet, budget.csv; SI units)",
        cfg.name,
        cfg.cells.len(),
        elapsed.as_secs_f64()
    );
    for c in results.iter().filter(|c| c.refused_fraction >= 5e-4 || c.excluded_truths > 0) {
        println!(
            "cell {}: the estimated compensation's fit leaves the model's small-error region with chance {:.1}% over \
             the {} truths drawn (the Monte Carlo refuses those fits; each truth is weighted by the chance its fit \
             stays, and keeps the fits that stay; {} truths without any chance left out)",
            c.cell,
            100.0 * c.refused_fraction,
            a.truths,
            c.excluded_truths
        );
    }
    if cfg.cells.len() <= 8 {
        for c in &results {
            println!(
                "\ncell {}\n  {:<44} {:>7} {:>12} {:>12} {:>12} {:>8} {:>6}",
                c.cell, "drift", "unit", "median", "p95", "p05", "nonlin", "linear"
            );
            for r in &c.rows {
                println!(
                    "  {:<44} {:>7} {:>12} {:>12} {:>12} {:>8} {:>6}{}",
                    row_name(r),
                    gfcal::mc::trial::DRIFT_METRICS[r.metric].1,
                    sig(r.median, 4),
                    sig(r.p95, 4),
                    sig(r.p05, 4),
                    sig(r.nonlinearity, 2),
                    r.linear,
                    if r.unbounded_by.is_empty() {
                        String::new()
                    } else {
                        format!("  unbounded: {} unidentifiable", r.unbounded_by.join(", "))
                    }
                );
            }
        }
    }
    if let Some(run) = a.compare {
        let rows = compare(run, &results).with_context(|| format!("cannot read the run in {}", run.display()))?;
        write("compare.csv", &compare_csv(&rows))?;
        println!(
            "\nLinCov against the Monte Carlo in {} (ratio = LinCov / Monte Carlo; the Monte Carlo's 95% interval \
             relative to its value):",
            run.display()
        );
        println!(
            "  {:>4} {:<44} {:>6} {:>8} {:>15} {:>8} {:>15} {:>8} {:>6}",
            "cell", "drift", "n", "median", "mc interval", "p95", "mc interval", "nonlin", "linear"
        );
        let interval = |q: &gfcal::lincov::compare::SampleQuantile| {
            format!("{:+.1}%/{:+.1}%", (q.low / q.value - 1.0) * 100.0, (q.high / q.value - 1.0) * 100.0)
        };
        for r in &rows {
            println!(
                "  {:>4} {:<44} {:>6} {:>8.3} {:>15} {:>8.3} {:>15} {:>8} {:>6}",
                r.cell,
                r.name,
                r.n,
                r.median_ratio(),
                interval(&r.mc_median),
                r.p95_ratio(),
                interval(&r.mc_p95),
                sig(r.nonlinearity, 2),
                r.linear
            );
        }
        eprintln!("wrote {}", out.join("compare.csv").display());
        let (ranked, agreements) = gfcal::lincov::ranking::ranking(run, &cfg, &results, RANKING_TRIALS)
            .with_context(|| format!("cannot read the run's sensitivity in {}", run.display()))?;
        if !agreements.is_empty() {
            write("ranking.csv", &gfcal::lincov::ranking::ranking_csv(&ranked))?;
            println!(
                "
LinCov's error budget ranked beside the run's sensitivity (Spearman's rank correlation of the \
                 parameters' shares with |SRRC| and with the Sobol' total indices; the kind of parameter each puts \
                 first):"
            );
            println!(
                "  {:>4} {:<44} {:>7} {:>7}  {:<14} {:<14} {:<14}",
                "cell", "drift", "srrc", "sobol", "lincov first", "srrc first", "sobol first"
            );
            for a in &agreements {
                println!(
                    "  {:>4} {:<44} {:>7} {:>7}  {:<14} {:<14} {:<14}",
                    a.cell,
                    a.name,
                    sig(a.spearman_srrc, 2),
                    sig(a.spearman_sobol, 2),
                    a.top_kind_lincov,
                    a.top_kind_srrc,
                    a.top_kind_sobol
                );
            }
            eprintln!("wrote {}", out.join("ranking.csv").display());
        }
    }
    eprintln!("wrote {} (lincov.csv, lincov.parquet, lincov.json, budget.csv)", out.display());
    Ok(())
}
