//! The gyroscope-free rate on the path over its branches (`selfcal::branch`): issue 28's rate
//! targets, on a simulated recording against its truth and on the six real recordings against
//! their gyroscopes. Bounds written before the runs (`results/mimu4444/EXPECTATIONS.md` (ax)).

use gfcal::rng::trial_rng;
use gfcal::selfcal::calibrate::{CalibrateSettings, calibrate};
use gfcal::selfcal::recording::Recording;
use gfcal::selfcal::simulate::simulate;

use super::selfcal::mimu_array;
use super::simulate::{config_truth, matched_cell, rate_off_gyroscopes};

/// Seed 4 of `configs/mimu4444_protocol.toml` (no probe of (at)-(aw) saw it), calibrated as `gfcal
/// calibrate` does: the rate off the truth under 12% overall and 10% above 20 rad/s. Before the
/// path the same protocol's rate was 24-30% off (seeds 1-3, (as)), all but a few percent of it
/// in the samples whose sign or plane's reflection was wrong.
#[test]
fn the_simulated_gyroscope_free_rate_takes_its_branch_on_the_path() {
    let cell = matched_cell();
    let truth = config_truth(&cell.array, 4);
    let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(4, 1)).expect("simulated");
    let settings = CalibrateSettings { remove_bias_drift: cell.remove_bias_drift, ..CalibrateSettings::default() };
    let cal = calibrate(&sim.recording, &cell.array, &settings).expect("calibrates");
    assert!(cal.clocks.is_some(), "the clocks are fitted");
    let (mut e, mut r, mut e_fast, mut r_fast) = (0.0, 0.0, 0.0, 0.0);
    for (k, &i) in cal.dynamic_index.iter().enumerate() {
        let w = sim.motion[i].omega_rad_s;
        let d = (cal.rate_motion()[k].omega_rad_s - w).norm_squared();
        (e, r) = (e + d, r + w.norm_squared());
        if w.norm() > 20.0 {
            (e_fast, r_fast) = (e_fast + d, r_fast + w.norm_squared());
        }
    }
    let (all, fast) = (100.0 * (e / r).sqrt(), 100.0 * (e_fast / r_fast).sqrt());
    eprintln!("the rate off the truth: {all:.1}% overall, {fast:.1}% above 20 rad/s");
    assert!(all < 12.0 && fast < 10.0, "{all:.1}% and {fast:.1}%");
}

/// Issue 28's targets on the six real recordings, gyroscope-free: the rate under 15% off the
/// gyroscopes overall and under 10% above 20 rad/s on every one (16.0-22.1% and 13.1-20.0% with
/// the sign by continuity alone; 7.3-9.8% and 5.9-8.8% expected, (aw)). About a minute.
#[test]
fn the_real_gyroscope_free_rate_meets_issue_28s_targets() {
    let array = mimu_array();
    for k in 1..=6 {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join(format!("../shared/data/mimu4444/recording_{k}.parquet"));
        let rec = Recording::read(&path, &array).expect("recording");
        let cal = calibrate(&rec, &array, &CalibrateSettings::default()).expect("calibrates");
        let (all, fast) = rate_off_gyroscopes(&cal);
        eprintln!("recording {k}: the rate off the gyroscopes {all:.1}% overall, {fast:.1}% above 20 rad/s");
        assert!(all < 15.0 && fast < 10.0, "recording {k}: {all:.1}% and {fast:.1}%");
    }
}
