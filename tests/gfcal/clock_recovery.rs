//! The sample clocks `gfcal calibrate` fits, against the truth of the simulator that generates
//! them from physics (`selfcal::simulate`: vibration on a fine grid, each package reading by
//! sample-and-hold on its own clock, anti-alias filters): recovered within their sigmas, and
//! named by the diagnosis where they are and not where they are not.

use gfcal::discrepancy::recorded::diagnose::diagnose_recordings;
use gfcal::rng::trial_rng;
use gfcal::selfcal::calibrate::{CalibrateSettings, calibrate};
use gfcal::selfcal::clock::SampleClock;
use gfcal::selfcal::model::PER_ACCEL;
use gfcal::selfcal::simulate::simulate;

use super::simulate::{config_truth, matched_cell, short_matched};

/// One package's clock: estimated, true (moved to the estimate's reference time), sigmas.
type ClockPair = (SampleClock, SampleClock, [f64; 3]);

/// `(error / sigma)` of one estimate.
fn z(estimate: f64, truth: f64, sigma: f64) -> f64 {
    (estimate - truth) / sigma
}

/// The share of the mean square of `errors` (seed-major, `per_seed` values a seed) that the
/// values' means over the seeds carry: about 1 / seeds where each value's error is drawn afresh
/// with every seed, more where part of it repeats (a bias the sandwich cannot carry).
fn between_seed_share(errors: &[f64], per_seed: usize) -> f64 {
    let seeds = errors.len() / per_seed.max(1);
    if seeds == 0 {
        return f64::NAN;
    }
    let total: f64 = errors.iter().map(|e| e * e).sum();
    let between: f64 = (0..per_seed)
        .map(|i| {
            let mean = (0..seeds).map(|s| errors[s * per_seed + i]).sum::<f64>() / seeds as f64;
            seeds as f64 * mean * mean
        })
        .sum();
    between / total
}

/// A knock-out's factor from the environment variable `name` (`None` where it is not set).
fn scale_from_env(name: &str) -> Option<f64> {
    let v = std::env::var(name).ok()?;
    match v.parse::<f64>() {
        Ok(k) if k.is_finite() && k >= 0.0 => Some(k),
        _ => panic!("{name}={v}: expected a factor, a finite number not below 0"),
    }
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The age difference of two clocks at `t_s`, wrapped into half a period either side.
fn age_difference_s(a: &SampleClock, b: &SampleClock, t_s: f64) -> f64 {
    let period = 1.0 / a.nominal_hz;
    let d = a.age_s(t_s) - b.age_s(t_s);
    d - period * (d / period).round()
}

/// Monte Carlo of the clocks' recovery on recordings of the matched protocol
/// (configs/mimu4444_protocol.toml: 20 poses, 100 s of hand-held rotation, the board's relative
/// clock rates, a random common rate and drift), gyroscope-free. Expectations written before the
/// first run (issue 28): over all packages and seeds, the RMS of (rate offset error / sigma)
/// within 15% of 1, for the rate offsets and for their relative part; the RMS of (location error
/// / sigma) within 15% of 1 (the locations recovered to their bounds). Printed: the same for the
/// phases and drifts, and the gyroscope-free rate's error against its sigma and the true rate.
///
/// ```sh
/// GFCAL_CLOCK_MC_SEEDS=12 cargo test --locked --test gfcal clock_recovery -- --ignored --nocapture
/// ```
///
/// (`GFCAL_CLOCK_MC_FIRST_SEED=8 GFCAL_CLOCK_MC_SEEDS=8` runs seed 8 alone; `GFCAL_CLOCK_MC_NO_DRIFT=1`
/// leaves the protocol's bias drift in time out of the simulation, a knock-out. The recordings are
/// calibrated as `gfcal calibrate` does, the drift taken out first (`remove_bias_drift`, as the
/// protocol config sets it); `GFCAL_CLOCK_MC_KEEP_DRIFT=1` calibrates them as they are;
/// `GFCAL_CLOCK_MC_NO_SENSOR=1` leaves out each accelerometer's own error in bursts, another knock-out,
/// but not a paired one: its generators' draws leave the random stream, so every later draw differs.
/// `GFCAL_CLOCK_MC_PLAIN=1` calibrates by plain least squares (no Huber's weights).
/// Paired knock-outs keep every draw and scale the error: `GFCAL_CLOCK_MC_SENSOR_SCALE=1e-6` the
/// accelerometers' own error, `GFCAL_CLOCK_MC_VIB_SCALE=0.5` that and the rigid vibration together.
/// Printed beside the clocks: the scale factors', tilts' and locations' RMS z, error and printed
/// sigma, per seed and over the seeds, and the share of each kind's mean square error that repeats
/// from seed to seed.)
#[test]
#[ignore = "Monte Carlo over simulated recordings of the full matched protocol (about a minute each)"]
fn simulated_clocks_and_locations_are_recovered_within_their_sigmas() {
    let seeds: u64 = std::env::var("GFCAL_CLOCK_MC_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(12);
    // The first seed (1 unless GFCAL_CLOCK_MC_FIRST_SEED says otherwise: one seed looked at again).
    let first: u64 = std::env::var("GFCAL_CLOCK_MC_FIRST_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let mut cell = matched_cell();
    if std::env::var("GFCAL_CLOCK_MC_NO_DRIFT").is_ok_and(|v| v == "1") {
        cell.protocol.bias_drift = None;
    }
    if std::env::var("GFCAL_CLOCK_MC_NO_SENSOR").is_ok_and(|v| v == "1") {
        cell.protocol.vibration.sensor_rms_m_s2 = 0.0;
    }
    if let Some(k) = scale_from_env("GFCAL_CLOCK_MC_VIB_SCALE") {
        let v = &mut cell.protocol.vibration;
        v.accel_rms_m_s2 *= k;
        v.rate_rms_rad_s *= k;
        v.sensor_rms_m_s2 *= k;
    }
    if let Some(k) = scale_from_env("GFCAL_CLOCK_MC_SENSOR_SCALE") {
        cell.protocol.vibration.sensor_rms_m_s2 *= k;
    }
    assert!(cell.remove_bias_drift, "the protocol config calibrates as gfcal calibrate does");
    let settings = CalibrateSettings {
        remove_bias_drift: !std::env::var("GFCAL_CLOCK_MC_KEEP_DRIFT").is_ok_and(|v| v == "1"),
        plain_least_squares: std::env::var("GFCAL_CLOCK_MC_PLAIN").is_ok_and(|v| v == "1"),
        ..CalibrateSettings::default()
    };
    let mut z_intrinsic = [Vec::new(), Vec::new(), Vec::new()];
    // Their errors and printed sigmas apart (RMS over the seeds), to tell a sigma that shrinks from
    // an error that grows.
    let (mut err_intrinsic, mut sigma_intrinsic) =
        ([Vec::new(), Vec::new(), Vec::new()], [Vec::new(), Vec::new(), Vec::new()]);
    let array = &cell.array;
    let n = array.array.len();
    let (mut z_rate, mut z_relative, mut z_drift, mut z_phase, mut z_location) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut err_location, mut sigma_location) = (Vec::new(), Vec::new());
    let (mut z_omega, mut omega_err2, mut omega_ref2) = (Vec::new(), 0.0, 0.0);
    let mut birge = Vec::new();
    let mut unfitted = Vec::new();
    for seed in first..=seeds {
        let truth = config_truth(array, seed);
        let sim = simulate(array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        let cal = calibrate(&sim.recording, array, &settings).expect("calibrates");
        let Some(c) = cal.clocks.as_ref() else {
            eprintln!("seed {seed}: no clocks fitted: {:?}", cal.clock_note);
            unfitted.push(seed);
            continue;
        };
        birge.push(c.sigma_check.birge_ratio);
        let pairs: Vec<ClockPair> = c
            .clocks
            .iter()
            .zip(&c.sigma)
            .zip(&sim.clocks)
            .filter_map(|((e, s), t)| {
                Some((e.as_ref().copied()?, t.as_ref()?.at_reference(e.as_ref()?.t_ref_s), (*s)?))
            })
            .collect();
        assert_eq!(pairs.len(), 8, "seed {seed}: every package clocked");
        let mean = |f: &dyn Fn(&ClockPair) -> f64| pairs.iter().map(f).sum::<f64>() / pairs.len() as f64;
        let (est_mean, true_mean) = (mean(&|p| p.0.rate_offset), mean(&|p| p.1.rate_offset));
        let relative_sigma = |s: &[f64; 3]| (s[0] * s[0] - c.common_sigma[0] * c.common_sigma[0]).max(0.0).sqrt();
        for (p, (e, t, s)) in pairs.iter().enumerate() {
            eprintln!(
                "seed {seed} package {}: rate offset {:.2} ppm (true {:.2}; error {:.4}, sigma {:.4}), drift {:.3e} /s (true {:.3e}), age error {:.2e} s (sigma {:.2e})",
                p + 1,
                e.rate_offset * 1e6,
                t.rate_offset * 1e6,
                (e.rate_offset - t.rate_offset) * 1e6,
                s[0] * 1e6,
                e.drift_per_s,
                t.drift_per_s,
                age_difference_s(e, t, e.t_ref_s),
                s[2]
            );
            z_rate.push(z(e.rate_offset, t.rate_offset, s[0]));
            z_relative.push(z(e.rate_offset - est_mean, t.rate_offset - true_mean, relative_sigma(s)));
            z_drift.push(z(e.drift_per_s, t.drift_per_s, s[1]));
            z_phase.push(age_difference_s(e, t, e.t_ref_s) / s[2]);
        }
        for j in 0..n {
            for p in 4..PER_ACCEL {
                z_location.push(z(cal.fit.params.get(j, p), truth.get(j, p), cal.fit.sigma(j, p)));
                err_location.push(cal.fit.params.get(j, p) - truth.get(j, p));
                sigma_location.push(cal.fit.sigma(j, p));
            }
            for (k, p) in [0, 2, 3].into_iter().enumerate() {
                z_intrinsic[k].push(z(cal.fit.params.get(j, p), truth.get(j, p), cal.fit.sigma(j, p)));
                err_intrinsic[k].push(cal.fit.params.get(j, p) - truth.get(j, p));
                sigma_intrinsic[k].push(cal.fit.sigma(j, p));
            }
        }
        {
            let last = |v: &[f64]| rms(&v[v.len() - n..]);
            eprintln!(
                "seed {seed}: static kinds RMS error {:.4e} {:.4e} {:.4e}, locations {:.4e}",
                last(&err_intrinsic[0]),
                last(&err_intrinsic[1]),
                last(&err_intrinsic[2]),
                rms(&err_location[err_location.len() - 3 * n..])
            );
        }
        for (k, &i) in cal.dynamic_index.iter().enumerate() {
            let (est, tru) = (cal.rate_motion()[k].omega_rad_s, sim.motion[i].omega_rad_s);
            let s = cal.fit.omega_sigma_rad_s[k];
            for a in 0..3 {
                z_omega.push((est[a] - tru[a]) / s[a]);
            }
            omega_err2 += (est - tru).norm_squared();
            omega_ref2 += tru.norm_squared();
        }
        eprintln!(
            "seed {seed}: rate offsets RMS z {:.2} (relative {:.2}), Birge ratio {:.2}, residual {:.3} -> {:.3} m/s^2",
            rms(&z_rate[z_rate.len() - 8..]),
            rms(&z_relative[z_relative.len() - 8..]),
            c.sigma_check.birge_ratio,
            c.residual_rms_before_m_s2,
            c.residual_rms_after_m_s2
        );
    }
    let omega_relative = (omega_err2 / omega_ref2).sqrt();
    eprintln!(
        "{seeds} seeds ({} without clocks fitted: {unfitted:?}), gyroscope-free: RMS z rate offset {:.3} (relative part {:.3}), drift {:.3}, phase {:.3}; locations {:.3} over {}; rate RMS z {:.3}, relative RMS error {:.4}; Birge ratios {:?}",
        unfitted.len(),
        rms(&z_rate),
        rms(&z_relative),
        rms(&z_drift),
        rms(&z_phase),
        rms(&z_location),
        z_location.len(),
        rms(&z_omega),
        omega_relative,
        birge.iter().map(|b| format!("{b:.2}")).collect::<Vec<_>>()
    );
    eprintln!(
        "scale factors RMS z {:.3}, tilt_u {:.3}, tilt_w {:.3} (not asserted); RMS error {:.3e}, {:.3e}, {:.3e}; RMS printed sigma {:.3e}, {:.3e}, {:.3e}",
        rms(&z_intrinsic[0]),
        rms(&z_intrinsic[1]),
        rms(&z_intrinsic[2]),
        rms(&err_intrinsic[0]),
        rms(&err_intrinsic[1]),
        rms(&err_intrinsic[2]),
        rms(&sigma_intrinsic[0]),
        rms(&sigma_intrinsic[1]),
        rms(&sigma_intrinsic[2])
    );
    // Where the errors repeat from seed to seed (the same accelerometer, the same sign), part of
    // them is a bias of the estimator, not the noise the sigmas describe.
    let fitted = z_location.len() / (3 * n);
    eprintln!("locations: RMS error {:.3e} m, RMS printed sigma {:.3e} m", rms(&err_location), rms(&sigma_location));
    eprintln!(
        "share of the mean square error in the means over {fitted} seeds (about {:.3} by chance): scale factors {:.3}, tilt_u {:.3}, tilt_w {:.3}, locations {:.3}",
        1.0 / fitted as f64,
        between_seed_share(&err_intrinsic[0], n),
        between_seed_share(&err_intrinsic[1], n),
        between_seed_share(&err_intrinsic[2], n),
        between_seed_share(&err_location, 3 * n)
    );
    assert!(unfitted.is_empty(), "seeds whose clocks were not fitted: {unfitted:?}");
    assert!((rms(&z_rate) - 1.0).abs() < 0.15, "rate offsets: RMS z {}", rms(&z_rate));
    assert!((rms(&z_relative) - 1.0).abs() < 0.15, "relative rate offsets: RMS z {}", rms(&z_relative));
    assert!((rms(&z_location) - 1.0).abs() < 0.15, "locations: RMS z {}", rms(&z_location));
}

/// The diagnosis's `sample_clock` against the generator: a simulated recording with the board's
/// clocks names it (the fitted clocks remove more of the rotation phase's misfit than all 99
/// shifted readings of them, rank p = 0.01); the same recording simulated without clocks (every
/// package read at the host's instants) names nothing, and says why (its gyroscopes show no
/// sawtooth).
#[test]
fn the_diagnosis_names_sample_clock_with_the_clocks_and_nothing_without() {
    // 6 poses (the fewest a calibration with a rotation phase takes) of 8 s, 30 s of rotation.
    let mut cell = short_matched(30.0);
    cell.protocol.poses = 6;
    let array = &cell.array;
    let truth = config_truth(array, 5);
    let settings = CalibrateSettings::default();
    let named = |p: &gfcal::selfcal::simulate::Protocol| {
        let sim = simulate(array, &truth, p, &mut trial_rng(5, 1)).expect("simulated");
        let d = diagnose_recordings(&sim.recording, array, &[], &settings, 0.01).expect("diagnosed");
        let found = d.findings.iter().find(|f| f.name == "sample_clock").map(|f| f.p_value_largest);
        let why = d.not_named.iter().find(|(name, _)| name == "sample_clock").map(|(_, why)| why.clone());
        (found, why)
    };
    let (with, why) = named(&cell.protocol);
    assert_eq!(with, Some(0.01), "with the clocks: {why:?}");
    let mut off = cell.protocol.clone();
    off.clocks = None;
    let (without, why) = named(&off);
    assert_eq!(without, None, "without the clocks nothing is named");
    let why = why.expect("the reason it is not named");
    assert!(why.contains("no sawtooth"), "{why}");
}

/// The library after the clocks, against the generator: the diagnosis tries it on every output
/// corrected by the clocks, each sample's timing motion eliminated and each output weighted by its
/// sample's other outputs' spread (`discrepancy::recorded::sample_spread`). A simulated clocked
/// recording names nothing of the library; the same recording with a quadratic scale factor of
/// 4e-5 /(m/s^2) on one accelerometer's true reading (0.04 m/s^2 at 32 m/s^2; set before the first
/// run at about eight times the sigma the route of the time printed there, 5.3e-6) is recovered
/// within 3 sigma, and named on it and no other accelerometer. Until 2026-12-01 the library was tried on
/// the outputs within the calibration's Huber clip, which selects on the residual: the effect read
/// 4.9e-6 +- 7.6e-6 there (12% of its size; 3.7e-5 +- 1.7e-5 now, too few sigmas to be named on
/// 30 s of rotation, and no sharper than the same recording simulated without clocks, 1.2e-5). The
/// check that it lies more than 2 sigmas from zero was added after the first run, at this seed's
/// 2.2: a regression check of this route, not a power claim.
#[test]
fn a_quadratic_scale_factor_hidden_in_a_clocked_recording_is_recovered_after_the_clocks() {
    let (cell, sim) = short_clocked_recording(7);
    let array = &cell.array;
    let truth = config_truth(array, 7);
    let settings = CalibrateSettings::default();
    let library = |d: &gfcal::discrepancy::recorded::RecordedDiagnosis| -> Vec<(String, Option<usize>)> {
        d.findings.iter().filter(|f| f.name != "sample_clock").map(|f| (f.name.clone(), f.accelerometer)).collect()
    };
    let clean = diagnose_recordings(&sim.recording, array, &[], &settings, 0.01).expect("diagnosed");
    assert!(library(&clean).is_empty(), "a clean clocked recording names {:?}", library(&clean));
    let (j, c) = (9, 4e-5);
    let hidden = super::recorded_generators::with_power(sim.recording.clone(), array, &truth, j, c, 2);
    let d = diagnose_recordings(&hidden, array, &[], &settings, 0.01).expect("diagnosed");
    let named = library(&d);
    // Named, on it alone: its single fit (4.9 sigma) is what the selection across the effects tests
    // (`discrepancy::recorded::selection`; `results/mimu4444/EXPECTATIONS.md` (by), written before the
    // run). Until then it was tested in the joint fit of every owner (2.2 sigma) and named nowhere.
    assert_eq!(named, [("scale_factor_quadratic".to_string(), Some(j))], "{:?}", d.not_named);
    // Named on this recording alone (no held-out recording was given), and said so.
    let finding = d.findings.iter().find(|f| f.name == "scale_factor_quadratic").expect("named");
    assert!(finding.what.contains("alone (no held-out recording to confirm it)"), "{}", finding.what);
    let rank = d.ranks.iter().find(|r| r.name == "scale_factor_quadratic").expect("tried");
    let (v, s) = (rank.value[j], rank.sigma[j]);
    assert!(s.is_finite() && s > 0.0 && (v - c).abs() < 3.0 * s, "{v} +- {s} against {c}");
    // Recovered, not merely not refuted: more than 2 sigma from zero.
    assert!(v > 2.0 * s, "{v} +- {s}");
    // The accelerometer's parameter fitted alone (the others left out): recovered within 3 sigma
    // (`results/mimu4444/EXPECTATIONS.md` (bv), written before the first run, which also guessed
    // its sigma at 0.7-1.1e-5; it is 6.8e-6 against the joint fit's 1.65e-5). How honest that
    // sigma is, is checked on clean recordings below, not here.
    let (va, sa) = (rank.value_alone[j], rank.sigma_alone[j]);
    assert!(sa.is_finite() && sa > 0.0 && (va - c).abs() < 3.0 * sa, "{va} +- {sa} against {c}");
    // An effect whose every direction the model absorbs has no single fits either (not 0 +- 0).
    let absorbed = d.ranks.iter().find(|r| r.name == "cross_axis").expect("tried");
    assert_eq!(absorbed.unseen, absorbed.parameters);
    assert!(absorbed.value_alone.iter().chain(&absorbed.sigma_alone).all(|v| v.is_nan()), "{absorbed:?}");
}

/// The library's sigmas after the clocks against clean simulated recordings (`results/mimu4444/
/// EXPECTATIONS.md`, (bo), written before the first run): six clocked recordings with no effect
/// hidden, each diagnosed alone; the RMS of value / sigma of the quadratic scale factor (144
/// values) and the cross-coupling (288) within 0.8-1.25, and nothing of the library named. The
/// same bound for each owner's parameters fitted alone ((bv); first run 1.004 and 0.991, the joint
/// fit's 1.010 and 0.980). Since (cb) the sampling delay's too (48 package delays; 42 in the joint
/// fit, which reads them relative to the median package): 0.892 and 0.892 with the clocks held,
/// 0.928 and 0.916 with their relative parameters in the nuisance (`blocks::ClockNuisance`; the
/// quadratic and cross-coupling then 1.018, 1.002, 0.988, 0.989).
#[test]
#[ignore = "six simulated recordings diagnosed, about a minute; run with --ignored after any change to the diagnosis's route after the clocks"]
fn the_librarys_sigmas_after_the_clocks_hold_on_clean_simulated_recordings() {
    let settings = CalibrateSettings::default();
    let mut z: std::collections::BTreeMap<&str, Vec<f64>> = Default::default();
    // Each seed's single fits (value, sigma) per owner, for the pooled check below.
    let mut single: std::collections::BTreeMap<&str, Vec<Vec<(f64, f64)>>> = Default::default();
    for seed in 11..17 {
        let (cell, sim) = short_clocked_recording(seed);
        let d = diagnose_recordings(&sim.recording, &cell.array, &[], &settings, 0.01).expect("diagnosed");
        let named: Vec<&str> = d.findings.iter().map(|f| f.name.as_str()).filter(|n| *n != "sample_clock").collect();
        assert!(named.is_empty(), "seed {seed} names {named:?}");
        for (name, alone) in [
            ("scale_factor_quadratic", "scale_factor_quadratic alone"),
            ("cross_coupling", "cross_coupling alone"),
            ("sampling_delay", "sampling_delay alone"),
        ] {
            let r = d.ranks.iter().find(|r| r.name == name).expect("tried");
            let finite = |(v, s): (&f64, &f64)| (s.is_finite() && *s > 0.0).then_some(v / s);
            z.entry(name).or_default().extend(r.value.iter().zip(&r.sigma).filter_map(finite));
            z.entry(alone).or_default().extend(r.value_alone.iter().zip(&r.sigma_alone).filter_map(finite));
            single
                .entry(name)
                .or_default()
                .push(r.value_alone.iter().copied().zip(r.sigma_alone.iter().copied()).collect());
            if name == "sampling_delay" {
                eprintln!("seed {seed} delay sigma joint {:?} alone {:?}", r.sigma, r.sigma_alone);
            }
        }
    }
    for (name, v) in &z {
        eprintln!("{name}: RMS z {:.3} over {}", rms(v), v.len());
    }
    for (name, v) in &z {
        let rms = rms(v);
        assert!((0.8..=1.25).contains(&rms), "{name}: RMS z {rms} over {}", v.len());
    }
    // The null of `results/mimu4444/discrepancy/whole_patterns.py` ((cc)): independent recordings
    // of a board without the effect do not repeat its single fits' pattern over the owners (the
    // median correlation of two seeds' value / sigma within 0.2 of zero: 3 times its spread over
    // 15 pairs), and each owner's single fits pooled over the six seeds stay within 3.5 sigma (24
    // owners) or 3.7 (48), the two-sided 0.01 level over the owners. First run: median
    // correlations -0.007 and 0.015, largest pooled 2.42 and 2.26 (the real recordings: 0.45-0.54
    // and up to 6.0 for the quadratic scale factor).
    for (name, limit) in [("scale_factor_quadratic", 3.5), ("cross_coupling", 3.7)] {
        let seeds = &single[name];
        let z_of = |fits: &[(f64, f64)]| -> Vec<f64> { fits.iter().map(|(v, s)| v / s).collect() };
        let mut r = Vec::new();
        for a in 0..seeds.len() {
            for b in a + 1..seeds.len() {
                r.push(correlation(&z_of(&seeds[a]), &z_of(&seeds[b])));
            }
        }
        r.sort_by(f64::total_cmp);
        let median = 0.5 * (r[(r.len() - 1) / 2] + r[r.len() / 2]);
        let pooled: Vec<f64> = (0..seeds[0].len())
            .map(|o| {
                let w: f64 = seeds.iter().map(|f| f[o].1.powi(-2)).sum();
                seeds.iter().map(|f| f[o].0 * f[o].1.powi(-2)).sum::<f64>() / w.sqrt()
            })
            .collect();
        let largest = pooled.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        eprintln!(
            "{name}: median correlation of the seeds' single-fit patterns {median:.3}, largest pooled |z| {largest:.2}"
        );
        assert!(median.abs() < 0.2, "{name}: median correlation {median} ({r:?})");
        assert!(largest < limit, "{name}: pooled z {pooled:?}");
    }
}

/// Pearson's correlation of two equally long series.
fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let sab: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let saa: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let sbb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    sab / (saa * sbb).sqrt()
}

/// `gfcal calibrate --held-out` on a clocked array scores each held-out recording's rotation
/// phase with its own gyroscopes' clocks (`selfcal::predict::HeldOut::own_clocks_share_removed`):
/// a recording's clocks are its own, so without them the held-out misfit says nothing of the
/// calibration. Against the generator (thresholds written before the first run): a second
/// recording of the same board (its own clocks' phases and noise) has at least 80% of its
/// misfit removed, within 0.1 of the share the fitting recording's own clocks remove; the same
/// held-out recording simulated without clocks (every package read at the host's instants) at
/// most 50% (six unknowns more a sample take about 6 of the 15 degrees of freedom the motion
/// leaves of a white misfit); an array without declared clocks has no share. With the held-out
/// recording's bias drift taken out first (`gfcal calibrate`'s default, on a held-out recording
/// with 10 poses, enough for the drift's fit) the share moves by at most 0.02; with `--use-gyro`
/// the held-out share meets the same two thresholds against that calibration's own.
#[test]
fn a_held_out_recording_is_scored_with_its_own_clocks() {
    use gfcal::selfcal::predict::predict_held_out;
    let (cell, fitting) = short_clocked_recording(7);
    let array = &cell.array;
    let truth = config_truth(array, 7);
    let settings = CalibrateSettings::default();
    let cal = calibrate(&fitting.recording, array, &settings).expect("calibrates");
    let own = cal.clocks.as_ref().expect("clocks fitted").share_removed;
    let held = simulate(array, &truth, &cell.protocol, &mut trial_rng(7, 2)).expect("simulated");
    let mut off = cell.protocol.clone();
    off.clocks = None;
    let unclocked = simulate(array, &truth, &off, &mut trial_rng(7, 2)).expect("simulated");
    let with = predict_held_out(array, &cal, &held.recording, &settings).expect("predicts");
    let without = predict_held_out(array, &cal, &unclocked.recording, &settings).expect("predicts");
    let (with_share, without_share) = (
        with.own_clocks_share_removed.expect("a share with clocks"),
        without.own_clocks_share_removed.expect("a share: the gyroscopes' clocks are read all the same"),
    );
    eprintln!(
        "the fitting recording's own clocks remove {own:.3}; a held-out recording's {with_share:.3} (residual {:.3} m/s^2 before them), without clocks {without_share:.3}",
        with.dynamic_residual_rms_m_s2
    );
    assert!(with_share >= 0.8 && (with_share - own).abs() <= 0.1, "held out {with_share}, fitting {own}");
    // As `gfcal calibrate` runs by default: the held-out recording's bias drift taken out first
    // (the drift touches the accelerometers only; the clocks come from its gyroscopes). A drift
    // needs the poses a static-only fit needs, so this held-out recording has 10.
    let mut more_poses = cell.protocol.clone();
    more_poses.poses = 10;
    let posed = simulate(array, &truth, &more_poses, &mut trial_rng(7, 3)).expect("simulated");
    let remove = CalibrateSettings { remove_bias_drift: true, ..settings };
    let drifted = predict_held_out(array, &cal, &posed.recording, &remove).expect("predicts");
    let as_recorded = predict_held_out(array, &cal, &posed.recording, &settings).expect("predicts");
    let (drifted_share, recorded_share) = (
        drifted.own_clocks_share_removed.expect("a share with the drift taken out"),
        as_recorded.own_clocks_share_removed.expect("a share as recorded"),
    );
    assert!(drifted.bias_drift_removed && !as_recorded.bias_drift_removed, "the drift taken out in one only");
    assert!(
        drifted_share >= 0.8 && (drifted_share - recorded_share).abs() <= 0.02,
        "drift taken out {drifted_share}, as recorded {recorded_share}"
    );
    assert!(without_share <= 0.5, "without clocks {without_share}");
    // The report's held-out table carries the share.
    let page = gfcal::report::calibration::render_page(
        &cal,
        &fitting.recording,
        array,
        &[(std::path::PathBuf::from("held.csv"), with.clone())],
    );
    assert!(
        page.contains("its own clocks remove") && page.contains(&format!("{:.1}%", 100.0 * with_share)),
        "the report's held-out table"
    );
    // With the rate from the gyroscopes (`--use-gyro`: the motion's rate is not refitted), alike.
    let gyro = CalibrateSettings { use_gyro: true, ..settings };
    let cal_gyro = calibrate(&fitting.recording, array, &gyro).expect("calibrates");
    let own_gyro = cal_gyro.clocks.as_ref().expect("clocks fitted").share_removed;
    let held_gyro = predict_held_out(array, &cal_gyro, &held.recording, &gyro).expect("predicts");
    let gyro_share = held_gyro.own_clocks_share_removed.expect("a share with --use-gyro");
    eprintln!(
        "--use-gyro: the fitting recording's own clocks remove {own_gyro:.3}, a held-out recording's {gyro_share:.3}"
    );
    assert!(
        gyro_share >= 0.8 && (gyro_share - own_gyro).abs() <= 0.1,
        "--use-gyro: held out {gyro_share}, fitting {own_gyro}"
    );
    let mut plain = array.clone();
    for p in plain.packages.iter_mut() {
        p.sample_clock_hz = None;
        p.sample_and_hold = false;
    }
    assert!(!plain.has_sample_clocks());
    let cal_plain = calibrate(&fitting.recording, &plain, &settings).expect("calibrates");
    let none = predict_held_out(&plain, &cal_plain, &held.recording, &settings).expect("predicts");
    assert_eq!(none.own_clocks_share_removed, None);
}

/// A short recording of the matched protocol with the board's clocks: 6 poses (the fewest a
/// calibration with a rotation phase takes) and 30 s of rotation, truth and noise from `seed`.
fn short_clocked_recording(seed: u64) -> (gfcal::mc::protocol::ProtocolCell, gfcal::selfcal::simulate::Simulated) {
    let mut cell = short_matched(30.0);
    cell.protocol.poses = 6;
    let truth = config_truth(&cell.array, seed);
    let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
    (cell, sim)
}

/// [`short_clocked_recording`] calibrated as `gfcal calibrate` calibrates it (default settings),
/// with what the covariance's tests read at its solution: the rotation phase prepared, each
/// output's package, the fitted sensors, each accelerometer's dynamic weight and each output's
/// relative age at the fitted clocks.
struct CalibratedShort {
    cell: gfcal::mc::protocol::ProtocolCell,
    cal: gfcal::selfcal::calibrate::Calibration,
    d: gfcal::selfcal::data::DynamicData,
    package_of: Vec<usize>,
    sens: Vec<gfcal::selfcal::model::Sensor>,
    weights: Vec<f64>,
    ages: nalgebra::DMatrix<f64>,
}

fn calibrated_short_recording(seed: u64) -> CalibratedShort {
    use gfcal::selfcal::calibrate::prepare_dynamic;
    use gfcal::selfcal::model::sensors;
    use gfcal::selfcal::timing::accelerometer_ages;
    let (cell, sim) = short_clocked_recording(seed);
    let cal = calibrate(&sim.recording, &cell.array, &CalibrateSettings::default()).expect("calibrates");
    let clocks = &cal.clocks.as_ref().expect("clocks fitted").clocks;
    let prepared = prepare_dynamic(&sim.recording, &cal.segmentation, false, cal.gyro_bias_rad_s);
    let d = prepared.data.expect("a rotation phase");
    let package_of: Vec<usize> = cell.array.package_of.iter().map(|p| p.expect("every axis has its package")).collect();
    let ages = accelerometer_ages(&d, clocks, &package_of);
    let sens = sensors(&cell.array.array, &cal.fit.params);
    let weights: Vec<f64> = cal.fit.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect();
    CalibratedShort { cell, cal, d, package_of, sens, weights, ages }
}

/// A run is a function of its input: one simulated recording with its clocks calibrated on one
/// thread and on two gives the same bits (clocks, sigmas, parameters, misfits). It failed while the
/// clock fit's normal equations were summed by rayon's fold/reduce, whose grouping of the sums
/// follows how the threads split the work (1 ulp on real recording 1 in a busy test harness; now
/// fixed chunks summed in order, `selfcal::timing`).
#[test]
fn a_clocked_calibration_has_the_same_bits_on_one_thread_and_on_two() {
    let (cell, sim) = short_clocked_recording(7);
    let array = &cell.array;
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool");
        pool.install(|| calibrate(&sim.recording, array, &CalibrateSettings::default()).expect("calibrates"))
    };
    let (one, two) = (on(1), on(2));
    let bits = |cal: &gfcal::selfcal::calibrate::Calibration| -> Vec<u64> {
        let c = cal.clocks.as_ref().expect("clocks fitted");
        let mut v: Vec<f64> = vec![cal.fit.dynamic_chi2_dof, cal.fit.static_chi2_dof, c.residual_rms_after_m_s2];
        for (clock, sigma) in c.clocks.iter().zip(&c.sigma) {
            if let (Some(k), Some(s)) = (clock, sigma) {
                v.extend([k.rate_offset, k.drift_per_s, k.age_s(k.t_ref_s)]);
                v.extend(s.iter().copied());
            }
        }
        let n = cal.fit.params.len();
        for j in 0..n {
            for p in 0..PER_ACCEL {
                v.extend([cal.fit.params.get(j, p), cal.fit.sigma(j, p)]);
            }
        }
        v.iter().map(|x| x.to_bits()).collect()
    };
    assert_eq!(one.fit.iterations, two.fit.iterations);
    assert_eq!(bits(&one), bits(&two));
}

/// The clock model's gauge, counted: a change common to every package's clock (its rate offset,
/// drift or phase) moves every age alike and the ages enter only relative to their mean, so the
/// clocks' normal matrix (the eight packages' rate offset, drift and phase: 24 unknowns, at the
/// calibration's own clocks) has exactly 3 null directions, the common ones, and every relative
/// direction is seen (scaled eigenvalues below 1e-9 of the largest counted as null; the next one
/// must stand 1e3 times above that).
#[test]
fn the_clock_models_gauge_has_exactly_the_three_common_null_directions() {
    use gfcal::selfcal::calibrate::prepare_dynamic;
    use gfcal::selfcal::model::sensors;
    use gfcal::selfcal::timing::ClockProblem;
    let (cell, sim) = short_clocked_recording(7);
    let array = &cell.array;
    let cal = calibrate(&sim.recording, array, &CalibrateSettings::default()).expect("calibrates");
    let clocks = cal.clocks.as_ref().expect("clocks fitted");
    // The dynamic variance is one for the whole rotation phase (above each static floor), and no
    // accelerometer is fitted below its static noise: per-accelerometer components ran away with
    // the clocks' local unknowns, down to a thirtieth of it on real recordings.
    let noise = &cal.static_data.sigma;
    let pooled = cal.fit.dynamic_sigma_m_s2.iter().copied().fold(0.0, f64::max);
    for (j, (&s, &r)) in cal.fit.dynamic_sigma_m_s2.iter().zip(&cal.fit.dynamic_residual_rms_m_s2).enumerate() {
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b;
        assert!(
            near(s, pooled) || near(s, noise[j]),
            "accelerometer {j}: dynamic sigma {s}, pooled {pooled}, noise {}",
            noise[j]
        );
        assert!(r > noise[j], "accelerometer {j}: dynamic residual {r} m/s^2 below the static noise {}", noise[j]);
    }
    let prepared = prepare_dynamic(&sim.recording, &cal.segmentation, false, cal.gyro_bias_rad_s);
    let d = prepared.data.expect("a rotation phase");
    let sens = sensors(&array.array, &cal.fit.params);
    let weights: Vec<f64> = cal.fit.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect();
    let package_of: Vec<usize> = array.package_of.iter().map(|p| p.expect("every axis has its package")).collect();
    let problem = ClockProblem::new(&sens, &d, &cal.fit.motion, &weights, &package_of);
    let normal = problem.relative_information(&clocks.clocks, 0..d.samples());
    assert_eq!(normal.nrows(), 24);
    // Symmetric (the step fills the upper triangle and mirrors it) and scaled by its diagonal.
    let scale: Vec<f64> = (0..24).map(|i| normal[(i, i)].max(1e-300).sqrt()).collect();
    let scaled = nalgebra::DMatrix::from_fn(24, 24, |a, b| normal[(a.min(b), a.max(b))] / (scale[a] * scale[b]));
    let mut eig: Vec<f64> = scaled.symmetric_eigenvalues().iter().copied().collect();
    eig.sort_by(f64::total_cmp);
    let largest = eig[23];
    let null = eig.iter().filter(|&&e| e < 1e-9 * largest).count();
    assert_eq!(null, 3, "scaled eigenvalues {:?}", &eig[..6]);
    assert!(eig[3] > 1e-6 * largest, "the weakest relative direction {:e} of the largest", eig[3] / largest);
    // The null directions are the common ones: every package's parameter moved alike.
    for a in 0..3 {
        let v = nalgebra::DVector::from_fn(24, |i, _| if i % 3 == a { scale[i] } else { 0.0 });
        let hv = &scaled * &v;
        assert!(hv.norm() < 1e-9 * largest * v.norm(), "common direction {a}: |H v| = {:e}", hv.norm());
    }
}

/// A held-out recording's clocks are scored on its own accelerometers with its motion tracked
/// without the timing model; with the motion held, the share the timing model removes depends
/// on where the motion's solve stopped (the timing term's gains are the motion's own, scaled by
/// the ages). Refitted with the timing model, it does not, to first order: scored at the motion
/// tracked on the uncorrected outputs and at a motion a tenth of the way from there to the
/// calibration's motion (fitted to the corrected outputs), the refitted shares agree within 0.01
/// and within a tenth of the held shares' difference; and at the tracked motion the refitted
/// share is at least the held one (more unknowns fitted). Halfway (a motion far outside any
/// solve's stopping tolerance) the first order no longer holds that well: refitted 0.980 and
/// 0.959, held 0.285 and 0.830 (seed 7, 2026-11-27).
#[test]
fn the_share_with_the_motion_refitted_does_not_depend_on_where_the_motion_stopped() {
    use gfcal::selfcal::model::SampleMotion;
    use gfcal::selfcal::timing::ClockProblem;
    use gfcal::selfcal::track;
    let CalibratedShort { cell, cal, d, package_of, sens, weights, .. } = calibrated_short_recording(7);
    let array = &cell.array;
    let clocks = &cal.clocks.as_ref().expect("clocks fitted").clocks;
    let tracked = track::refine(&array.array, &d, &weights, &cal.fit.params, &cal.fit.motion, true);
    let stopped_short: Vec<SampleMotion> = tracked
        .iter()
        .zip(&cal.fit.motion)
        .map(|(t, f)| SampleMotion {
            f_m_s2: t.f_m_s2 + (f.f_m_s2 - t.f_m_s2) * 0.1,
            alpha_rad_s2: t.alpha_rad_s2 + (f.alpha_rad_s2 - t.alpha_rad_s2) * 0.1,
            omega_rad_s: t.omega_rad_s + (f.omega_rad_s - t.omega_rad_s) * 0.1,
        })
        .collect();
    let shares = |motion: &[SampleMotion]| -> (f64, f64) {
        let problem = ClockProblem::new(&sens, &d, motion, &weights, &package_of);
        (
            problem.shares_removed(clocks, &[]).0,
            problem.share_removed_motion_refitted(&sens, motion, false, clocks, &[]).0,
        )
    };
    let (held_tracked, refitted_tracked) = shares(&tracked);
    let (held_short, refitted_short) = shares(&stopped_short);
    let refitted_difference = (refitted_tracked - refitted_short).abs();
    let held_difference = (held_tracked - held_short).abs();
    assert!(
        refitted_difference < 0.01 && refitted_difference < 0.1 * held_difference,
        "refitted {refitted_tracked:.4} / {refitted_short:.4}, held {held_tracked:.4} / {held_short:.4}"
    );
    assert!(refitted_tracked >= held_tracked - 1e-9, "refitted {refitted_tracked:.4} below held {held_tracked:.4}");
}

/// A package whose clock runs within a few ppm of a whole multiple of the host's rate: its
/// sawtooth does not complete a period in the rotation phase, so its gyroscope's offsets are a
/// ramp without a wrap, whose level a free scale and constant take up. Package 6 of the MIMU4444
/// runs -71 to +103 ppm over the six recordings (its relative rate plus their common part), so a
/// recording with it near 0 is to be expected. Trial 95 of configs/mimu4444_protocol.toml's
/// Monte Carlo (seed 1), drawn as `gfcal run` draws it, where package 6 runs at +1.1 ppm: before
/// 2026-11-30 it fitted no clock at all ("its gyroscope's time offsets show no sawtooth", the
/// rotation phase's residual 1.47 m/s^2 and the locations 420 um RMS off the truth). Now every
/// package's age is within 0.02 ms of the simulator's clocks (typically a few microseconds), and
/// the locations within 40 um (the Monte Carlo's median trial: 21 um).
#[test]
fn a_package_whose_sawtooth_the_gyroscopes_cannot_show_is_clocked_with_the_rest() {
    let cfg = gfcal::mc::config::McConfig::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/mimu4444_protocol.toml"),
    )
    .expect("shipped config");
    let cell = &cfg.cells[0];
    let pc = cell.protocol.as_ref().expect("a [protocol] config");
    let settings = CalibrateSettings { remove_bias_drift: pc.remove_bias_drift, ..CalibrateSettings::default() };
    // trials 0 and 56 (package 6 at +2.7 and -5.0 ppm, its sawtooth's scale shown) are the open
    // case: packages 5 and 6 still end 0.07-0.11 ms off together (docs/sample-clocks.md)
    let trial = 95;
    let mut rng = trial_rng(cfg.seed, trial);
    let x = gfcal::mc::protocol::truth_in_gauge(pc, &cell.errors.sample(&cell.layout, &mut rng));
    let truth = gfcal::selfcal::model::SensorSet::from_vector(x.as_slice());
    let sim = simulate(&pc.array, &truth, &pc.protocol, &mut rng).expect("simulated");
    let six = sim.clocks[5].expect("package 6 clocked").at_reference(pc.protocol.rotation_centre_s());
    assert!(six.rate_offset.abs() < 3e-6, "trial {trial}: package 6 at {} ppm", six.rate_offset * 1e6);
    let cal = calibrate(&sim.recording, &pc.array, &settings).expect("calibrates");
    let c = cal.clocks.as_ref().unwrap_or_else(|| panic!("trial {trial}: no clocks: {:?}", cal.clock_note));
    let errors_ms: Vec<f64> = c
        .clocks
        .iter()
        .zip(&sim.clocks)
        .map(|(e, t)| {
            let (e, t) = (e.expect("fitted"), t.expect("simulated"));
            age_difference_s(&e, &t.at_reference(e.t_ref_s), e.t_ref_s) * 1e3
        })
        .collect();
    let location_um: Vec<f64> = (0..pc.array.array.len())
        .flat_map(|j| (4..PER_ACCEL).map(move |p| (j, p)))
        .map(|(j, p)| (cal.fit.params.get(j, p) - truth.get(j, p)) * 1e6)
        .collect();
    eprintln!("trial {trial}: age errors {errors_ms:.4?} ms, locations RMS error {:.1} um", rms(&location_um));
    assert!(errors_ms.iter().all(|e| e.abs() < 0.02), "trial {trial}: age errors {errors_ms:.4?} ms");
    assert!(rms(&location_um) < 40.0, "trial {trial}: locations {} um", rms(&location_um));
}

/// Each sample's local design written out densely (an independent route to
/// `selfcal::timing_information`): `W^(1/2) L` (9 motion columns, then with `ages` the 6 timing
/// columns, the specific force's and the angular acceleration's times the output's age) with its
/// columns scaled to unit norm, an orthonormal basis `Q` of its span from an SVD, and
/// `H += R^T R` with `R = (I - Q Q^T) W^(1/2) G`, `G` every output's 7 parameter derivatives.
fn dense_reduced_information(
    sens: &[gfcal::selfcal::model::Sensor],
    d: &gfcal::selfcal::data::DynamicData,
    motion: &[gfcal::selfcal::model::SampleMotion],
    weights: &[f64],
    ages: Option<&nalgebra::DMatrix<f64>>,
) -> nalgebra::DMatrix<f64> {
    use nalgebra::DMatrix;
    let n = sens.len();
    let na = PER_ACCEL * n;
    let local = if ages.is_some() { 15 } else { 9 };
    let mut h = DMatrix::zeros(na, na);
    for (i, m) in motion.iter().enumerate().take(d.samples()) {
        let mut l = DMatrix::zeros(n, local);
        let mut g = DMatrix::zeros(n, na);
        for (j, s) in sens.iter().enumerate() {
            if !d.used[i * n + j] {
                continue;
            }
            let sw = weights[j].sqrt();
            let dl = s.d_motion(m);
            for c in 0..local {
                l[(j, c)] = sw * if c < 9 { dl[c] } else { ages.map_or(0.0, |a| a[(i, j)]) * dl[c - 9] };
            }
            let intrinsic = s.d_intrinsic(&m.specific_force_m_s2(&s.position_m));
            let location = s.d_location(m);
            let row = [intrinsic[0], intrinsic[1], intrinsic[2], intrinsic[3], location.x, location.y, location.z];
            for (c, v) in row.iter().enumerate() {
                g[(j, PER_ACCEL * j + c)] = sw * v;
            }
        }
        for mut c in l.column_iter_mut() {
            let norm = c.norm();
            if norm > 0.0 {
                c /= norm;
            }
        }
        let svd = l.svd(true, false);
        let largest = svd.singular_values.max();
        let keep: Vec<usize> =
            (0..svd.singular_values.len()).filter(|&k| svd.singular_values[k] > 1e-10 * largest).collect();
        let q = svd.u.expect("left singular vectors").select_columns(&keep);
        let r = &g - &q * (q.transpose() * &g);
        h += r.transpose() * r;
    }
    h
}

/// A clocked calibration's covariance eliminates each sample's timing motion
/// (`selfcal::timing_information`): its reduced information equals the dense route above (with
/// the motion alone and with the timing motion too) to 1e-12 of its norm; no sigma falls with the
/// timing motion free (more unknowns cannot add information); and the locations' sigmas grow by a
/// median between 1.1 and 1.6, the bounds written from the clock Monte Carlo's floor (the locations'
/// errors at RMS z 1.35-1.36 against sigmas that held the timing motion, with no vibration,
/// `results/mimu4444/EXPECTATIONS.md` (w), (aa)). On this 30 s recording of 6 poses the growth is
/// 1.31, the static kinds' 1.33 ((ac); until 2026-11-30 wrong ages made it look like 8-15).
#[test]
fn the_covariance_eliminates_each_samples_timing_motion() {
    use gfcal::selfcal::robust::timing_free_sigma_ratios;
    use gfcal::selfcal::timing_information::{TimingSamples, reduced_information};
    let CalibratedShort { cell, cal, d, sens, weights, ages, .. } = calibrated_short_recording(7);
    let array = &cell.array;
    let settings = CalibrateSettings::default();
    for with_ages in [None, Some(&ages)] {
        let samples = TimingSamples {
            sens: &sens,
            data: &d,
            motion: &cal.fit.motion,
            weights: &weights,
            output_w: None,
            fixed: false,
            ages: with_ages,
        };
        let library = reduced_information(&samples);
        let dense = dense_reduced_information(&sens, &d, &cal.fit.motion, &weights, with_ages);
        let agreement = (&library - &dense).norm() / dense.norm();
        eprintln!("timing motion {}: agreement {agreement:.2e}", if with_ages.is_some() { "free" } else { "held" });
        assert!(agreement < 1e-12, "the reduced information against the dense route: {agreement:e}");
    }
    let ratio =
        timing_free_sigma_ratios(&array.array, &cal.static_data, &d, &settings.fit, &cal.fit, &ages).expect("inverts");
    let median = |kinds: &[usize]| {
        let mut v: Vec<f64> = (0..ratio.len() / PER_ACCEL)
            .flat_map(|j| kinds.iter().map(move |&p| PER_ACCEL * j + p))
            .map(|i| ratio[i])
            .filter(|r| r.is_finite())
            .collect();
        assert!(!v.is_empty());
        assert!(v.iter().all(|&r| r >= 1.0 - 1e-9), "a sigma fell with more unknowns: {v:?}");
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (intrinsic, locations) = (median(&[0, 1, 2, 3]), median(&[4, 5, 6]));
    eprintln!(
        "median sigma growth with the timing motion free: scale factor, bias, tilts {intrinsic:.3}, locations {locations:.3}"
    );
    assert!((1.1..1.6).contains(&locations), "the locations' sigmas grow {locations} times");
}

/// A sample left on the saddle at numerically zero rate (about 1e-158 rad/s, as real recording 1
/// had one after 50 of Huber's iterations) does not poison the covariance: with its rate's columns
/// that small, the reduced information and score equal those of the same sample at exactly zero
/// rate (where the columns vanish and the dense route leaves them out) to 1e-12 of their norms,
/// and are finite. Before the floor on the local diagonal (`timing_information::local_inverse`)
/// both were NaN.
#[test]
fn a_sample_at_numerically_zero_rate_leaves_the_reduced_information_finite() {
    use gfcal::selfcal::timing_information::{TimingSamples, reduced_information, reduced_score};
    let CalibratedShort { cal, d, sens, weights, ages, .. } = calibrated_short_recording(7);
    let at_rate = |omega_rad_s: nalgebra::Vector3<f64>| {
        let mut motion = cal.fit.motion.clone();
        motion[11].omega_rad_s = omega_rad_s;
        motion
    };
    let tiny = at_rate(nalgebra::Vector3::new(-5.8e-159, -7.8e-158, -4.5e-158));
    let zero = at_rate(nalgebra::Vector3::zeros());
    let samples = |motion| TimingSamples {
        sens: &sens,
        data: &d,
        motion,
        weights: &weights,
        output_w: None,
        fixed: false,
        ages: Some(&ages),
    };
    let (h_tiny, h_zero) = (reduced_information(&samples(&tiny)), reduced_information(&samples(&zero)));
    let (g_tiny, g_zero) =
        (reduced_score(&samples(&tiny), 0..d.samples()), reduced_score(&samples(&zero), 0..d.samples()));
    assert!(h_tiny.iter().chain(g_tiny.iter()).all(|v| v.is_finite()), "a non-finite information or score");
    let h_gap = (&h_tiny - &h_zero).norm() / h_zero.norm();
    let g_gap = (&g_tiny - &g_zero).norm() / g_zero.norm();
    assert!(h_gap < 1e-12 && g_gap < 1e-12, "information {h_gap:e}, score {g_gap:e}");
    // At exactly zero rate the library agrees with the dense route (which leaves zero columns out).
    let dense = dense_reduced_information(&sens, &d, &zero, &weights, Some(&ages));
    let agreement = (&h_zero - &dense).norm() / dense.norm();
    assert!(agreement < 1e-12, "the reduced information at zero rate against the dense route: {agreement:e}");
}

/// The clocks' columns in the library's nuisance (`discrepancy::recorded::blocks::ClockNuisance`)
/// against central differences of the correction they stand for (`selfcal::clocked::
/// corrected_dynamic`, each sample's timing motion held): each clocked package's rate offset, drift
/// and phase moved both ways by a small step, on every sample where no package's age wraps between
/// the two (the correction is linear in the clocks between the wraps, so the columns match to
/// rounding).
#[test]
fn the_clocks_nuisance_columns_are_the_corrections_central_differences() {
    use gfcal::discrepancy::recorded::blocks::ClockNuisance;
    use gfcal::selfcal::clocked::{corrected_dynamic, corrected_dynamic_and_rates};
    use gfcal::selfcal::timing::accelerometer_ages;
    let (cell, sim) = short_clocked_recording(7);
    let array = &cell.array;
    let cal = calibrate(&sim.recording, array, &CalibrateSettings::default()).expect("calibrates");
    let c = cal.clocks.as_ref().expect("clocks fitted");
    let d = gfcal::selfcal::calibrate::prepare_dynamic(&sim.recording, &cal.segmentation, false, cal.gyro_bias_rad_s)
        .data
        .expect("a rotation phase");
    let rates = corrected_dynamic_and_rates(array, &cal.fit, &d, c).1;
    let package_of = array.package_indices();
    let nuisance = ClockNuisance { clocks: &c.clocks, package_of: &package_of, rate_m_s3: &rates };
    let clocked: Vec<usize> = (0..c.clocks.len()).filter(|&p| c.clocks[p].is_some()).collect();
    assert_eq!(nuisance.columns(), 3 * clocked.len());
    assert!(clocked.len() >= 2, "{clocked:?}");
    let n = package_of.len();
    // Steps: 1e-7 (rate offset), 1e-9 /s (drift), 1e-6 s (phase, a thousandth of a period): ages
    // move by up to about 1e-6 s, far above their rounding (1e-14 s on tick counts of 1e5) and
    // far below a period.
    let steps = [1e-7, 1e-9, 1e-6];
    let mut row = vec![0.0; nuisance.columns()];
    let (mut compared, mut skipped, mut samples) = (0usize, 0usize, 0usize);
    for (k, &q) in clocked.iter().enumerate() {
        for a in 0..3 {
            let at = |sign: f64| {
                let mut moved = c.clone();
                let mut delta = [0.0; 3];
                delta[a] = sign * steps[a];
                moved.clocks[q] = c.clocks[q].map(|clock| clock.moved(delta));
                let out = corrected_dynamic(array, &cal.fit, &d, &moved).outputs;
                (out, accelerometer_ages(&d, &moved.clocks, &package_of))
            };
            let ((plus, age_plus), (minus, age_minus)) = (at(1.0), at(-1.0));
            for i in 0..d.samples() {
                samples += 1;
                if (0..n).any(|j| (age_plus[(i, j)] - age_minus[(i, j)]).abs() > 1e-4) {
                    skipped += 1;
                    continue;
                }
                for j in (0..n).filter(|&j| d.used[i * n + j]) {
                    nuisance.regress(i, j, d.t_s[i], &mut row);
                    let fd = (plus[(i, j)] - minus[(i, j)]) / (2.0 * steps[a]);
                    let column = row[3 * k + a];
                    // The ages' rounding (tick counts near 1e5 to 2e-16 of themselves: about
                    // 2e-14 s), over the step, times the output's rate of change, on top of 1e-6.
                    let rounding = rates[(i, j)].abs() * 1e-13 / steps[a];
                    assert!(
                        (fd - column).abs() <= 1e-6 * column.abs() + rounding,
                        "package {q}, parameter {a}, sample {i}, output {j}: {fd} against {column}"
                    );
                    compared += 1;
                }
            }
        }
    }
    assert!(
        compared > 100_000 && skipped < samples / 100,
        "{compared} compared, {skipped} of {samples} samples skipped"
    );
}
