//! Runs a config's trials into an output folder, part by part.
//!
//! Layout of `DIR`: `run.json` (provenance: version, commit, config text, seed, times),
//! `trials/part-NNNNNN.parquet`, `parameters/part-NNNNNN.parquet` (part `p` holds trials
//! `p T .. (p + 1) T`, `T = output.trials_per_part`), `summary.csv`. A part's parameters file is
//! written before its trials file, each atomically; a part is done when both files are whole
//! (footer and row count). Shard `i` of `n` runs the parts with `p % n == i`. Processes started
//! together into one folder share it (see [`super::claim`]): the first prepares the run, the
//! others join it, and each part is computed by one process.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::SystemTime;

use rayon::prelude::*;

use super::claim::{self, Entry, RunLock};
use super::config::McConfig;
use super::output::{parameters_batch, trials_batch};
use super::summary::{Summarizer, Summary};
use super::trial::{Prepared, TrialRecord, run_trials};
use crate::io::parquet::{ParquetIoError, is_whole_part, write_part};

/// Receives progress; must not block (called from worker threads).
pub trait Observer: Sync {
    /// `total` trials in this shard, `done` of them already on disk.
    fn start(&self, total: u64, done: u64);
    fn advance(&self, trials: u64);
    fn finish(&self);
}

/// An observer that ignores everything.
pub struct Silent;

impl Observer for Silent {
    fn start(&self, _: u64, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
}

/// How to run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    /// Continue a run of the same config in `out`, running only missing parts.
    pub resume: bool,
    /// Delete a different (or the same) run in `out` and start over.
    pub force: bool,
    /// `(index, count)`, index in `0..count`.
    pub shard: (u64, u64),
    /// Worker threads (all cores when `None`).
    pub threads: Option<usize>,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOutcome {
    pub parts_written: u64,
    pub parts_skipped: u64,
    pub trials_run: u64,
    /// Every part of the run (all shards) is on disk.
    pub complete: bool,
    /// The run's summary, when this call wrote every part itself (built from the batches as they
    /// were written, so the folder need not be read back); otherwise `summary::summarize`.
    pub summary: Option<Summary>,
}

/// Why a run could not proceed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunError {
    /// The output folder cannot be used as asked (bad input: exit code 2).
    #[error("{path}: {problem}")]
    Output { path: PathBuf, problem: String },
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Parquet(#[from] ParquetIoError),
    #[error("cannot start worker threads: {0}")]
    Threads(String),
}

fn now() -> String {
    humantime::format_rfc3339_seconds(SystemTime::now()).to_string()
}

/// Path of part `p` under `dir/sub`.
pub fn part_path(dir: &Path, sub: &str, p: u64) -> PathBuf {
    dir.join(sub).join(format!("part-{p:06}.parquet"))
}

fn run_json(cfg: &McConfig, config_path: &Path, started: &str, finished: Option<&str>) -> serde_json::Value {
    serde_json::json!({
        "gfcal_version": env!("CARGO_PKG_VERSION"),
        "git_commit": env!("GFCAL_GIT_COMMIT"),
        "name": cfg.name,
        "config_path": config_path.display().to_string(),
        "config_text": cfg.text,
        "seed": cfg.seed,
        "cells": cfg.cells.len(),
        "factor_keys": cfg.factor_keys,
        "trials_per_cell": cfg.trials_per_cell,
        "trials_total": cfg.total_trials(),
        "trials_per_part": cfg.trials_per_part,
        "parts_total": cfg.parts(),
        "started": started,
        "finished": finished,
    })
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io { path: path.to_path_buf(), source }
}

/// Checks and prepares the output folder; returns the run's start time and this process's hold
/// on the folder (shared: other processes may join).
fn prepare_output(cfg: &McConfig, config_path: &Path, opts: &RunOptions) -> Result<(String, RunLock), RunError> {
    let dir = &opts.out;
    let output = |problem: String| RunError::Output { path: dir.clone(), problem };
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    // A process that finds another one writing the folder waits for it to have prepared the
    // folder and joins; if that one gave up (refused), the folder is looked at again.
    for _ in 0..100 {
        match claim::enter(dir).map_err(io_err(dir))? {
            Entry::Alone(lock) => {
                let started = prepare_alone(cfg, config_path, opts)?;
                return Ok((started, lock.share().map_err(io_err(dir))?));
            }
            Entry::Joining(lock) => {
                if opts.force {
                    return Err(output(
                        "another gfcal process is writing this run now; --force would destroy its work (wait for                          it, or stop it first)"
                            .into(),
                    ));
                }
                if let Some(started) = join(cfg, dir)? {
                    return Ok((started, lock));
                }
            }
        }
    }
    Err(output("other gfcal processes keep entering and leaving this folder; try again".into()))
}

/// The run in `dir` that other processes are writing, if it is this config's: its start time.
/// `None` when it has no run.json (the process that had the folder left without creating it).
fn join(cfg: &McConfig, dir: &Path) -> Result<Option<String>, RunError> {
    let run_file = dir.join("run.json");
    let output = |problem: String| RunError::Output { path: dir.to_path_buf(), problem };
    let text = match std::fs::read_to_string(&run_file) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io_err(&run_file)(e)),
    };
    let previous: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| output(format!("run.json is not readable ({e})")))?;
    if previous["config_text"].as_str() != Some(cfg.text.as_str()) {
        return Err(output(format!(
            "another gfcal process is writing a different run here now (`{}`, config {}); use another --out",
            previous["name"].as_str().unwrap_or("?"),
            previous["config_path"].as_str().unwrap_or("?")
        )));
    }
    Ok(Some(previous["started"].as_str().map(String::from).unwrap_or_else(now)))
}

/// Prepares the folder when no other process is writing it.
fn prepare_alone(cfg: &McConfig, config_path: &Path, opts: &RunOptions) -> Result<String, RunError> {
    let dir = &opts.out;
    let run_file = dir.join("run.json");
    let output = |problem: String| RunError::Output { path: dir.clone(), problem };
    let sharded = opts.shard.1 > 1;
    if run_file.exists() {
        let text = std::fs::read_to_string(&run_file).map_err(io_err(&run_file))?;
        let previous: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| output(format!("run.json is not readable ({e}); use --force to start over")))?;
        let same = previous["config_text"].as_str() == Some(cfg.text.as_str());
        if opts.force {
            clear(dir)?;
        } else if !same {
            return Err(output(format!(
                "holds a different run (`{}`, config {}); use another --out, or --force to replace it",
                previous["name"].as_str().unwrap_or("?"),
                previous["config_path"].as_str().unwrap_or("?")
            )));
        } else if !(opts.resume || sharded) {
            let finished = previous["finished"].as_str().is_some();
            return Err(output(if finished {
                "holds this run, finished; `gfcal summarize` recomputes its summary, --force starts it over".into()
            } else {
                "holds this run, unfinished; use --resume to finish it or --force to start over".into()
            }));
        } else {
            remove_stale_temporaries(dir);
            return Ok(previous["started"].as_str().map(String::from).unwrap_or_else(now));
        }
    } else if dir.join("trials").exists() || dir.join("parameters").exists() {
        if opts.force {
            clear(dir)?;
        } else {
            return Err(output(
                "holds results without a run.json; use another --out, or --force to replace them".into(),
            ));
        }
    }
    remove_stale_temporaries(dir);
    // run.json first: a folder with part folders but no run.json is never a run in progress.
    let started = now();
    let body = serde_json::to_string_pretty(&run_json(cfg, config_path, &started, None)).unwrap_or_default() + "\n";
    crate::io::create_new_atomic(&run_file, body.as_bytes()).map_err(io_err(&run_file))?;
    for sub in ["trials", "parameters"] {
        std::fs::create_dir_all(dir.join(sub)).map_err(io_err(dir))?;
    }
    Ok(started)
}

fn clear(dir: &Path) -> Result<(), RunError> {
    for sub in ["trials", "parameters", "locks"] {
        let p = dir.join(sub);
        if p.exists() {
            std::fs::remove_dir_all(&p).map_err(io_err(&p))?;
        }
    }
    for f in ["run.json", "summary.csv"] {
        let p = dir.join(f);
        if p.exists() {
            std::fs::remove_file(&p).map_err(io_err(&p))?;
        }
    }
    Ok(())
}

/// Removes temporary files left by an interrupted writer (only while no other process writes).
fn remove_stale_temporaries(dir: &Path) {
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(".run.json.tmp.") {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    for sub in ["trials", "parameters"] {
        if let Ok(entries) = std::fs::read_dir(dir.join(sub)) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with(".part-") && name.contains(".tmp.") {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}

/// The part numbers that have a trials file in `dir` (whole or not).
fn parts_on_disk(dir: &Path) -> Vec<u64> {
    std::fs::read_dir(dir.join("trials"))
        .map(|d| {
            d.flatten()
                .filter_map(|e| {
                    let name = e.file_name().to_string_lossy().into_owned();
                    name.strip_prefix("part-")?.strip_suffix(".parquet")?.parse().ok()
                })
                .collect()
        })
        .unwrap_or_default()
}

/// A computed part on its way to disk, with its claim.
struct Computed {
    part: u64,
    claim: claim::PartClaim,
    records: Vec<TrialRecord>,
    metadata: Vec<(String, String)>,
}

/// `range`'s trials in runs that navigate in lockstep: consecutive trials of one cell, as many
/// as fill the navigation's lanes with their compensations (two trials of two compensations).
fn lockstep_chunks(cfg: &McConfig, range: std::ops::Range<u64>) -> Vec<std::ops::Range<u64>> {
    let mut chunks = Vec::new();
    let mut start = range.start;
    while start < range.end {
        let cell = start / cfg.trials_per_cell;
        let compensations = cfg.cells[cell as usize].navigation.compensations.len().max(1);
        let per_chunk = (crate::nav::LANES / compensations).max(1) as u64;
        let end = (start + per_chunk).min(range.end).min((cell + 1) * cfg.trials_per_cell);
        chunks.push(start..end);
        start = end;
    }
    chunks
}

/// Writes a computed part (parameters first, then trials, each atomically), gives up its claim,
/// and adds the part to the summary being built, if any.
fn write_computed(
    cfg: &McConfig,
    out: &Path,
    c: Computed,
    summarizer: &Mutex<Option<Summarizer>>,
) -> Result<(), RunError> {
    let parameters = parameters_batch(cfg, &c.records)?;
    let trials = trials_batch(cfg, &c.records)?;
    let trials_path = part_path(out, "trials", c.part);
    write_part(&part_path(out, "parameters", c.part), &parameters, &c.metadata)?;
    write_part(&trials_path, &trials, &c.metadata)?;
    c.claim.release();
    let mut guard = summarizer.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some(s) = guard.as_mut()
        && s.add_part(&parameters, &trials, &trials_path).is_err()
    {
        // Cannot happen for batches gfcal built; the summary is then read back from disk.
        *guard = None;
    }
    Ok(())
}

/// Runs the parts of this shard that are not on disk yet.
pub fn run(
    cfg: &McConfig,
    config_path: &Path,
    opts: &RunOptions,
    observer: &dyn Observer,
) -> Result<RunOutcome, RunError> {
    let (shard, shards) = opts.shard;
    let (started, folder_lock) = prepare_output(cfg, config_path, opts)?;
    // Part bookkeeping grows with the work on disk, not with the trial count: this shard's parts
    // are `shard, shard + shards, ...`, taken lazily; only the parts that have a file are checked.
    let part_count = cfg.parts();
    let part_trials = |p: u64| (p * cfg.trials_per_part)..((p + 1) * cfg.trials_per_part).min(cfg.total_trials());
    let part_len = |p: u64| part_trials(p).end - part_trials(p).start;
    // A part is done when both its files are whole (footer and row count: a file truncated by a
    // crash is redone, not counted).
    let params_per_trial = cfg.cells.first().map_or(0, |c| c.layout.len() as u64);
    let done = |p: u64| {
        is_whole_part(&part_path(&opts.out, "trials", p), part_len(p))
            && is_whole_part(&part_path(&opts.out, "parameters", p), part_len(p) * params_per_trial)
    };
    let mine = |p: &u64| *p < part_count && p % shards == shard;
    let done_parts: std::collections::BTreeSet<u64> =
        parts_on_disk(&opts.out).into_iter().filter(mine).filter(|&p| done(p)).collect();
    // This shard's trials, by arithmetic: its parts are full but perhaps the run's last one.
    let mine_count = if shard < part_count { (part_count - 1 - shard) / shards + 1 } else { 0 };
    let short_last =
        if mine(&part_count.saturating_sub(1)) { cfg.trials_per_part - part_len(part_count - 1) } else { 0 };
    let total: u64 = (mine_count * cfg.trials_per_part).saturating_sub(short_last);
    let already: u64 = done_parts.iter().map(|&p| part_len(p)).sum();
    let prepared: Vec<Prepared> = Prepared::for_cells(&cfg.cells);
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(t) = opts.threads {
        builder = builder.num_threads(t);
    }
    let pool = builder.build().map_err(|e| RunError::Threads(e.to_string()))?;
    observer.start(total, already);
    let mut trials_run = 0;
    let mut parts_written = 0;
    let mut parts_skipped = done_parts.len() as u64;
    let mut pending: Option<Computed> = None;
    // Parts go to disk in order; when this call writes every part of the run, the summary is
    // built from the batches on their way out.
    let summarizer = Mutex::new((shards == 1 && done_parts.is_empty()).then(Summarizer::default));
    for p in (shard..part_count).step_by(shards as usize).filter(|p| !done_parts.contains(p)) {
        // One process per part: a part another process holds is left to it; one finished since
        // the listing above is skipped.
        let Some(claim) = claim::claim_part(&opts.out, p).map_err(io_err(&opts.out))? else {
            // Another process computes this part: this one cannot summarize the run from memory.
            *summarizer.lock().unwrap_or_else(|poisoned| poisoned.into_inner()) = None;
            continue;
        };
        if done(p) {
            *summarizer.lock().unwrap_or_else(|poisoned| poisoned.into_inner()) = None;
            claim.release();
            parts_skipped += 1;
            observer.advance(part_len(p));
            continue;
        }
        let range = part_trials(p);
        let part_started = now();
        // The previous part is written while this one is computed.
        let (records, written) = std::thread::scope(|scope| {
            let writer = pending.take().map(|c| scope.spawn(|| write_computed(cfg, &opts.out, c, &summarizer)));
            let records: Vec<TrialRecord> = pool.install(|| {
                lockstep_chunks(cfg, range.clone())
                    .into_par_iter()
                    .flat_map_iter(|chunk| {
                        let cell = (chunk.start / cfg.trials_per_cell) as usize;
                        let n = chunk.end - chunk.start;
                        let r = run_trials(&cfg.cells[cell], &prepared[cell], cfg.seed, chunk);
                        observer.advance(n);
                        r
                    })
                    .collect()
            });
            let written =
                writer.map(|w| w.join().unwrap_or_else(|_| Err(RunError::Threads("the part writer panicked".into()))));
            (records, written)
        });
        if let Some(w) = written {
            w?;
            parts_written += 1;
        }
        trials_run += records.len() as u64;
        let metadata = vec![
            ("gfcal:version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
            ("gfcal:git_commit".to_string(), env!("GFCAL_GIT_COMMIT").to_string()),
            ("gfcal:config".to_string(), cfg.text.clone()),
            ("gfcal:seed".to_string(), cfg.seed.to_string()),
            ("gfcal:run_started".to_string(), started.clone()),
            ("gfcal:part".to_string(), p.to_string()),
            ("gfcal:trials".to_string(), format!("{}..{}", range.start, range.end)),
            ("gfcal:part_started".to_string(), part_started),
            ("gfcal:part_finished".to_string(), now()),
        ];
        pending = Some(Computed { part: p, claim, records, metadata });
    }
    if let Some(c) = pending.take() {
        write_computed(cfg, &opts.out, c, &summarizer)?;
        parts_written += 1;
    }
    observer.finish();
    let complete = (0..part_count).all(done);
    if complete {
        let run_file = opts.out.join("run.json");
        let body = serde_json::to_string_pretty(&run_json(cfg, config_path, &started, Some(&now())))
            .unwrap_or_default()
            + "\n";
        crate::io::write_atomic(&run_file, body.as_bytes()).map_err(io_err(&run_file))?;
    }
    let summary = if complete {
        summarizer.into_inner().unwrap_or_else(|poisoned| poisoned.into_inner()).map(Summarizer::finish)
    } else {
        None
    };
    // No lock file or empty `locks/` folder is left behind by the last process to leave.
    folder_lock.leave(&opts.out);
    Ok(RunOutcome { parts_written, parts_skipped, trials_run, complete, summary })
}
