//! Time to calibrate one real recording of the MIMU4444 board (about 600 s, 37,000 samples of 24
//! accelerometers; `../shared/data/mimu4444/recording_1.parquet`) gyroscope-free: reading the
//! table, segmentation, the joint static and dynamic fit and its covariance. Target: under 5 s
//! on 2 cores.
//!
//!     cargo bench --bench calibrate

use std::path::PathBuf;

use divan::Bencher;
use gfcal::config::array::load_recording_array;
use gfcal::selfcal::calibrate::{CalibrateSettings, calibrate};
use gfcal::selfcal::recording::Recording;

fn main() {
    divan::main();
}

/// Reading and calibrating recording 1, on every core.
#[divan::bench(sample_count = 5)]
fn calibrate_recording_1(bencher: Bencher) {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let array = load_recording_array(&root.join("configs/arrays/mimu4444_corners.toml")).expect("array file");
    let path = root.join("../shared/data/mimu4444/recording_1.parquet");
    bencher.bench(|| {
        let rec = Recording::read(&path, &array).expect("reads");
        calibrate(&rec, &array, &CalibrateSettings::default()).expect("calibrates")
    });
}
