//! The static tension check (`selfcal::tension`) on simulated recordings of the matched protocol,
//! where the truth is known: the simulator's static phase is the model's plus white noise, and its
//! rotation phase carries the board's physics (vibration, anti-alias filters, sample clocks) that
//! the calibration models only in part.

use gfcal::rng::trial_rng;
use gfcal::selfcal::calibrate::{CalibrateSettings, calibrate};
use gfcal::selfcal::simulate::simulate;

use super::simulate::{config_truth, matched_cell};

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Expectation written before the first run (2026-11-27): the pull's p-value is conservative, so
/// on recordings whose static phase holds nothing the model leaves out it falls below 1e-3 on at
/// most one seed of eight (the check says "pulls" only where the real board's recording 4 does).
/// Printed beside it, per seed: the static chi^2/dof as fitted and refitted alone, the pull, and
/// the tilts' errors against the truth in the joint fit's printed sigmas, joint and static-only (a
/// joint fit pulled off the truth by the rotation phase would show the joint's errors above the
/// static-only ones).
///
/// ```sh
/// GFCAL_TENSION_SEEDS=8 cargo test --locked --test gfcal static_tension -- --ignored --nocapture
/// ```
#[test]
#[ignore = "Monte Carlo over simulated recordings of the full matched protocol (about a minute each)"]
fn the_pull_is_rare_on_simulated_recordings() {
    let seeds: u64 = std::env::var("GFCAL_TENSION_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(8);
    let cell = matched_cell();
    let array = &cell.array;
    let n = array.array.len();
    let mut flagged = Vec::new();
    for seed in 1..=seeds {
        let truth = config_truth(array, seed);
        let sim = simulate(array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        let cal = calibrate(&sim.recording, array, &CalibrateSettings::default()).expect("calibrates");
        let t = cal.static_tension.as_ref().expect("a rotation phase, so a tension check");
        let (mut z_joint, mut z_static) = (Vec::new(), Vec::new());
        for j in 0..n {
            for p in 2..4 {
                let sigma = cal.fit.sigma(j, p);
                let joint = cal.fit.params.get(j, p);
                let static_only = joint + t.move_sigma[j][p] * sigma;
                z_joint.push((joint - truth.get(j, p)) / sigma);
                z_static.push((static_only - truth.get(j, p)) / sigma);
            }
        }
        eprintln!(
            "seed {seed}: static chi2/dof {:.3} fitted, {:.3} alone; pull chi2 {:.1} on {} dof, p {:.2e}; moves RMS {:.2} sigma; tilts' error RMS in sigmas: joint {:.2}, static-only {:.2}",
            cal.fit.static_chi2_dof,
            t.chi2_dof_static_only,
            t.pull_chi2,
            t.pull_dof,
            t.pull_p_value,
            t.move_rms_sigma,
            rms(&z_joint),
            rms(&z_static)
        );
        if t.pull_p_value < 1e-3 {
            flagged.push(seed);
        }
    }
    assert!(flagged.len() <= 1, "the pull flagged seeds {flagged:?} of {seeds}");
}
