//! Progress of a run (part of the `gfcal` binary): an indicatif bar with rate and ETA when
//! stderr is a terminal, otherwise a plain line at a steady interval (batch jobs, CI logs).

use std::io::IsTerminal;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use gfcal::mc::Observer;
use indicatif::{ProgressBar, ProgressStyle};

pub enum Progress {
    Bar(ProgressBar),
    Lines { interval: Duration, state: Mutex<LineState>, done: AtomicU64, total: AtomicU64 },
}

pub struct LineState {
    started: Instant,
    last: Instant,
    already: u64,
}

impl Progress {
    /// A bar on a terminal, else lines every `interval`.
    pub fn new(interval: Duration) -> Self {
        if std::io::stderr().is_terminal() {
            let bar = ProgressBar::hidden();
            let style = ProgressStyle::with_template("{bar:40} {pos}/{len} trials  {per_sec}  ETA {eta}  {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_bar());
            bar.set_style(style);
            Progress::Bar(bar)
        } else {
            let now = Instant::now();
            Progress::Lines {
                interval,
                state: Mutex::new(LineState { started: now, last: now, already: 0 }),
                done: AtomicU64::new(0),
                total: AtomicU64::new(0),
            }
        }
    }

    fn line(&self, done: u64, total: u64, state: &LineState) {
        let run = done.saturating_sub(state.already);
        let secs = state.started.elapsed().as_secs_f64().max(1e-9);
        let rate = run as f64 / secs;
        let left = total.saturating_sub(done);
        // No ETA until this process has a rate (nothing run yet, e.g. resuming a finished run).
        let eta = match (left, rate > 0.0) {
            (0, _) => "ETA 0 s".to_string(),
            (_, true) => format!("ETA {:.0} s", left as f64 / rate),
            (_, false) => "ETA unknown".to_string(),
        };
        eprintln!(
            "gfcal: {done}/{total} trials ({:.1}%), {rate:.0} trials/s, elapsed {:.0} s, {eta}",
            100.0 * done as f64 / total.max(1) as f64,
            secs
        );
    }
}

impl Observer for Progress {
    fn start(&self, total: u64, done: u64) {
        match self {
            Progress::Bar(bar) => {
                bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                bar.set_length(total);
                bar.set_position(done);
                bar.reset_eta();
            }
            Progress::Lines { state, done: d, total: t, .. } => {
                d.store(done, Ordering::Relaxed);
                t.store(total, Ordering::Relaxed);
                if let Ok(mut s) = state.lock() {
                    let now = Instant::now();
                    *s = LineState { started: now, last: now, already: done };
                }
                eprintln!("gfcal: {total} trials in this run, {done} already done");
            }
        }
    }

    fn advance(&self, trials: u64) {
        match self {
            Progress::Bar(bar) => bar.inc(trials),
            Progress::Lines { interval, state, done, total } => {
                let d = done.fetch_add(trials, Ordering::Relaxed) + trials;
                // try_lock: a worker never waits for another's printing.
                if let Ok(mut s) = state.try_lock()
                    && s.last.elapsed() >= *interval
                {
                    s.last = Instant::now();
                    self.line(d, total.load(Ordering::Relaxed), &s);
                }
            }
        }
    }

    fn finish(&self) {
        match self {
            Progress::Bar(bar) => bar.finish(),
            Progress::Lines { state, done, total, .. } => {
                if let Ok(s) = state.lock() {
                    self.line(done.load(Ordering::Relaxed), total.load(Ordering::Relaxed), &s);
                }
            }
        }
    }
}
