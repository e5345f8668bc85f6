//! Throughput of the quickstart trial (configs/quickstart.toml: the paper's schedule at 100 Hz,
//! 1 s per step; joint estimator; 10 s of navigation at 100 Hz with nominal and estimated
//! parameters), on 1 and 2 threads, and the cost of each piece of a trial.
//!
//!     cargo bench --bench trial

use std::path::Path;
use std::sync::OnceLock;

use divan::Bencher;
use divan::counter::ItemsCount;
use gfcal::calib::joint::estimate_unchecked;
use gfcal::calib::measure::simulate;
use gfcal::mc::McConfig;
use gfcal::mc::trial::{Prepared, crb_sigma, run_trial};
use gfcal::nav::SimulatedArray;
use gfcal::nav::navigate;
use gfcal::rng::trial_rng;
use gfcal::sensor::{ArrayParams, Compensator};
use nalgebra::Vector3;
use rayon::prelude::*;

fn main() {
    divan::main();
}

fn quickstart() -> &'static (McConfig, Prepared) {
    static CFG: OnceLock<(McConfig, Prepared)> = OnceLock::new();
    CFG.get_or_init(|| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/quickstart.toml");
        let cfg = McConfig::load(&path).expect("configs/quickstart.toml loads");
        let prepared = Prepared::new(&cfg.cells[0]);
        (cfg, prepared)
    })
}

const BATCH: u64 = 512;

/// Trials per second with `threads` worker threads (a batch of 512 trials per sample).
#[divan::bench(args = [1, 2], sample_count = 20)]
fn quickstart_trials(bencher: Bencher, threads: usize) {
    let (cfg, prepared) = quickstart();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
    let mut next = 0u64;
    bencher.counter(ItemsCount::new(BATCH)).bench_local(|| {
        let start = next;
        next += BATCH;
        pool.install(|| {
            (start..start + BATCH)
                .into_par_iter()
                .map(|t| run_trial(&cfg.cells[0], prepared, cfg.seed, t))
                .collect::<Vec<_>>()
        })
    });
}

/// The pieces of one trial, single-threaded: where the time goes.
mod pieces {
    use super::*;

    #[divan::bench]
    fn whole_trial(bencher: Bencher) {
        let (cfg, prepared) = quickstart();
        let mut t = 0;
        bencher.bench_local(|| {
            t += 1;
            run_trial(&cfg.cells[0], prepared, cfg.seed, t)
        });
    }

    #[divan::bench]
    fn sample_and_simulate_calibration(bencher: Bencher) {
        let (cfg, _) = quickstart();
        let cell = &cfg.cells[0];
        let mut t = 0;
        bencher.bench_local(|| {
            t += 1;
            let mut rng = trial_rng(cfg.seed, t);
            let x = cell.errors.sample(&cell.layout, &mut rng);
            simulate(&cell.array, &cell.layout.unpack(&x), &cell.schedule, &cell.noise, 9.80665, &mut rng)
        });
    }

    #[divan::bench]
    fn joint_fit(bencher: Bencher) {
        let (cfg, _) = quickstart();
        let cell = &cfg.cells[0];
        let mut rng = trial_rng(cfg.seed, 0);
        let x = cell.errors.sample(&cell.layout, &mut rng);
        let meas = simulate(&cell.array, &cell.layout.unpack(&x), &cell.schedule, &cell.noise, 9.80665, &mut rng);
        let nominal = ArrayParams::nominal(&cell.array);
        bencher.bench_local(|| {
            estimate_unchecked(&cell.layout, &cell.schedule, &meas, &nominal, cell.calibration.start, 9.80665)
        });
    }

    #[divan::bench]
    fn cramer_rao(bencher: Bencher) {
        let (cfg, _) = quickstart();
        let cell = &cfg.cells[0];
        let x = cell.errors.sample(&cell.layout, &mut trial_rng(cfg.seed, 0));
        bencher.bench_local(|| crb_sigma(cell, &x, 5e-4));
    }

    #[divan::bench]
    fn navigate_10s_at_100hz(bencher: Bencher) {
        let (cfg, _) = quickstart();
        let cell = &cfg.cells[0];
        let truth = cell.layout.unpack(&cell.errors.sample(&cell.layout, &mut trial_rng(cfg.seed, 0)));
        let nominal = ArrayParams::nominal(&cell.array);
        let gravity = Vector3::new(0.0, 0.0, -9.80665);
        let nav = &cell.navigation;
        bencher.bench_local(|| {
            let comp = Compensator::new(&cell.array, &nominal).expect("nominal cube");
            let mut source =
                SimulatedArray::<rand_chacha::ChaCha8Rng>::new(&cell.array, &truth, &nav.trajectory, gravity);
            navigate(&nav.trajectory, &mut source, &comp, &gravity, nav.step_s, &nav.horizons_s)
        });
    }
}
