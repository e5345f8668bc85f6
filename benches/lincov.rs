//! LinCov's speed (issue 31, item 5): one cell of the quickstart (the paper's schedule, random
//! errors: a mixture over 1,024 drawn truths, nonlinearity index included), on 1 and 2 threads,
//! and the 10,000-point design sweep of configs/lincov_sweep.toml (2,500 cells x 4 horizons), on
//! 2 threads. Measured figures, beside the Monte Carlo's for the same work, are in docs/lincov.md.
//!
//!     cargo bench --bench lincov

use std::path::Path;
use std::sync::OnceLock;

use divan::Bencher;
use gfcal::lincov::analysis::Settings;
use gfcal::lincov::run::analyse;
use gfcal::mc::McConfig;

fn main() {
    divan::main();
}

fn config(name: &str) -> McConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs").join(name);
    McConfig::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn quickstart() -> &'static McConfig {
    static CFG: OnceLock<McConfig> = OnceLock::new();
    CFG.get_or_init(|| config("quickstart.toml"))
}

fn sweep() -> &'static McConfig {
    static CFG: OnceLock<McConfig> = OnceLock::new();
    CFG.get_or_init(|| config("lincov_sweep.toml"))
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool")
}

/// The quickstart's one cell, whole: linearisation, 1,024 truths, quantiles, budget,
/// nonlinearity probes (the work `gfcal lincov configs/quickstart.toml` times).
#[divan::bench(args = [1, 2], sample_count = 20)]
fn quickstart_cell(bencher: Bencher, threads: usize) {
    let (cfg, pool) = (quickstart(), pool(threads));
    bencher.bench_local(|| pool.install(|| analyse(cfg, &Settings::default()).expect("analyses")));
}

/// The 10,000-point sweep on 2 threads.
#[divan::bench(sample_count = 3, sample_size = 1)]
fn sweep_10000_points(bencher: Bencher) {
    let (cfg, pool) = (sweep(), pool(2));
    bencher.bench_local(|| pool.install(|| analyse(cfg, &Settings::default()).expect("analyses")));
}
