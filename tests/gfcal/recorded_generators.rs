//! Item 3 of issue 11 on simulated recordings: each effect of the recordings' library, hidden in a
//! pair of recordings by a generator in the simulator's truth model (the true motion at the true
//! sensing point, the true scale factor and axis, a 1 kHz simulation shifted and decimated; never
//! the fitted state), is named on its owner alone and recovered within 3 sigma. The sizes were
//! chosen before the first run: realistic for MEMS parts and a few sigmas or more.

use gfcal::array::wiring::RecordingArray;
use gfcal::discrepancy::recorded::RecordedDiagnosis;
use gfcal::discrepancy::recorded::effect::EffectLayout;
use gfcal::rng::trial_rng;
use gfcal::selfcal::calibrate::CalibrateSettings;
use gfcal::selfcal::model::SensorSet;
use gfcal::selfcal::recording::Recording;
use gfcal::selfcal::simulate::{Simulated, project_to_gauge, simulate};
use gfcal::sensor::misalignment::{tilt_axis, tilt_basis};
use nalgebra::{Matrix3, Vector3};

use super::recorded::{diagnose, named_on, recording, tried, truth};
use super::selfcal::{mimu_array, protocol};

fn simulated(array: &RecordingArray, truth: &SensorSet, seed: u64, rate_hz: f64) -> Simulated {
    let mut p = protocol(array.array.len());
    p.sample_rate_hz = rate_hz;
    simulate(array, truth, &p, &mut trial_rng(seed, 1)).expect("simulated")
}

/// A recording simulated at `factor` times 62.5 Hz, decimated to 62.5 Hz; accelerometer `j`'s column read
/// `late(j)` samples of the fast rate late, the gyroscopes `gyro_late` samples late.
fn decimated(sim: &Simulated, factor: usize, late: impl Fn(usize) -> usize, gyro_late: usize) -> Recording {
    let r = &sim.recording;
    let rows: Vec<usize> = (1..r.samples() / factor).map(|i| i * factor).collect();
    let n = r.outputs.ncols();
    let late = &late;
    let mut out = r.clone();
    out.t_s = rows.iter().map(|&i| r.t_s[i]).collect();
    out.outputs = nalgebra::DMatrix::from_fn(rows.len(), n, |k, j| r.outputs[(rows[k] - late(j), j)]);
    out.clipped = rows.iter().flat_map(|&i| (0..n).map(move |j| r.clipped[(i - late(j)) * n + j])).collect();
    out.gyro_rate_rad_s = rows.iter().map(|&i| r.gyro_rate_rad_s[i - gyro_late]).collect();
    out.gyro_clipped = rows.iter().map(|&i| r.gyro_clipped[i - gyro_late]).collect();
    out
}

/// The true specific force at accelerometer `j`'s true sensing point, and its true axis.
fn truth_at(
    array: &RecordingArray,
    t: &SensorSet,
    sim: &Simulated,
    i: usize,
    j: usize,
) -> (Vector3<f64>, Vector3<f64>) {
    let a = &array.array.accelerometers()[j];
    let r = a.position_m + t.location_error_m[j];
    (sim.motion[i].specific_force_m_s2(&r), tilt_axis(&a.axis, &t.tilt_rad[j]))
}

/// The library's effects named, less the turn-on effects (tried first; a hidden effect's static
/// part may shift the biases differently for the two pose sets).
fn library_named(d: &RecordedDiagnosis) -> Vec<&str> {
    d.findings.iter().map(|f| f.name.as_str()).filter(|n| !n.ends_with("_turn_on")).collect()
}

/// Sets an output as the board would record it: clipped at its range, and flagged.
fn set(r: &mut Recording, i: usize, j: usize, s: f64, range: f64) {
    let n = r.outputs.ncols();
    r.outputs[(i, j)] = s.clamp(-range, range);
    r.clipped[i * n + j] = s.abs() >= range;
}

/// An input-dependent scale factor `s = k (b + u + c u^power)` on accelerometer `j`, applied to the
/// true reading (the output less the truth's bias, over its scale factor) of a simulated recording.
pub fn with_power(mut r: Recording, array: &RecordingArray, t: &SensorSet, j: usize, c: f64, power: i32) -> Recording {
    let range = array.ranges_m_s2[j];
    for i in 0..r.samples() {
        let s = r.outputs[(i, j)];
        let u = s / t.scale_factor[j] - t.bias_m_s2[j];
        set(&mut r, i, j, s + t.scale_factor[j] * c * u.powi(power), range);
    }
    r
}

fn within(value: f64, want: f64, sigma: f64, what: &str) {
    assert!(sigma.is_finite() && sigma > 0.0, "{what}: sigma {sigma}");
    assert!((value - want).abs() < 3.0 * sigma, "{what}: {value} +- {sigma} against {want}");
}

/// An input-dependent scale factor, `s = k (b + u + c u^2)` applied to the true reading of the
/// protocol simulator (not to the fitted state), in both recordings of a pair.
#[test]
fn a_quadratic_scale_factor_hidden_by_the_simulator_is_named_on_its_accelerometer() {
    let array = mimu_array();
    let t = truth(&array);
    let c = 2e-4;
    let j = 6;
    let hide = |seed: u64| with_power(recording(&array, &t, seed), &array, &t, j, c, 2);
    let d = diagnose(&hide(41), &array, &[hide(42)]);
    assert_eq!(named_on(&d, "scale_factor_quadratic"), [j], "{:?} {:?}", d.findings, d.not_named);
    let f = d.findings.iter().find(|f| f.name == "scale_factor_quadratic").unwrap();
    within(f.value[0], c, f.sigma[0], "quadratic");
    assert_eq!(library_named(&d), ["scale_factor_quadratic"]);
}

/// Cross-coupling: `s = k (b + u + c u (e1 . q))`, with `q` the true specific force at the true
/// sensing point and `e1` the first tilt direction of the nominal axis; 2e-4 /(m/s^2) (2e-3 /g,
/// the top of MEMS data sheets) on accelerometer 9.
#[test]
fn a_cross_coupling_hidden_by_the_simulator_is_named_on_its_accelerometer() {
    let array = mimu_array();
    let t = truth(&array);
    let (c, j) = (2e-4, 8);
    let (e1, _) = tilt_basis(&array.array.accelerometers()[j].axis);
    let hide = |seed: u64| {
        let sim = simulated(&array, &t, seed, 62.5);
        let mut r = sim.recording.clone();
        let range = array.ranges_m_s2[j];
        for i in 0..r.samples() {
            let (q, axis) = truth_at(&array, &t, &sim, i, j);
            let u = axis.dot(&q);
            let s = r.outputs[(i, j)] + t.scale_factor[j] * c * u * e1.dot(&q);
            set(&mut r, i, j, s, range);
        }
        r
    };
    let d = diagnose(&hide(43), &array, &[hide(44)]);
    assert_eq!(named_on(&d, "cross_coupling"), [j], "{:?} {:?}", d.findings, d.not_named);
    assert_eq!(library_named(&d), ["cross_coupling"]);
    let f = d.findings.iter().find(|f| f.name == "cross_coupling").unwrap();
    within(f.value[0], c, f.sigma[0], "cross-coupling along e1");
    within(f.value[1], 0.0, f.sigma[1], "cross-coupling along e2");
}

/// A warm-up drift, `b(t) = A (1 - exp(-t / T))` with T = 1,000 s, A = 0.3 m/s^2 in the fitting
/// recording and 0.2 in the held-out one (a board warming up after each power-on: 30 mg over a
/// quarter of an hour, a consumer MEMS part's temperature coefficient over a 20 K warm-up), on
/// accelerometer 14. Its value is the least-squares slope of the generator over the fitting
/// recording's samples (the exponential bends by 7e-4 m/s^2 over a recording). First tried at
/// A = 0.1: a slope of 9e-5 against a sigma of 4.3e-5, not named (the Bonferroni level over 24
/// accelerometers and 6 effects needs about 4 sigma); that is the detection limit of these
/// recordings, not a failure.
#[test]
fn a_warm_up_drift_hidden_by_the_simulator_is_named_on_its_accelerometer() {
    let array = mimu_array();
    let t = truth(&array);
    let (j, time_constant_s) = (13, 1000.0);
    let hide = |seed: u64, amplitude_m_s2: f64| {
        let mut r = recording(&array, &t, seed);
        for i in 0..r.samples() {
            let b = amplitude_m_s2 * (1.0 - (-r.t_s[i] / time_constant_s).exp());
            r.outputs[(i, j)] += t.scale_factor[j] * b;
        }
        r
    };
    let a = hide(45, 0.3);
    let d = diagnose(&a, &array, &[hide(46, 0.2)]);
    assert_eq!(named_on(&d, "bias_time_drift"), [j], "{:?} {:?}", d.findings, d.not_named);
    assert_eq!(library_named(&d), ["bias_time_drift"]);
    let n = a.t_s.len() as f64;
    let tm = a.t_s.iter().sum::<f64>() / n;
    let y: Vec<f64> = a.t_s.iter().map(|x| 0.3 * (1.0 - (-x / time_constant_s).exp())).collect();
    let ym = y.iter().sum::<f64>() / n;
    let slope = a.t_s.iter().zip(&y).map(|(x, v)| (x - tm) * (v - ym)).sum::<f64>()
        / a.t_s.iter().map(|x| (x - tm).powi(2)).sum::<f64>();
    let f = d.findings.iter().find(|f| f.name == "bias_time_drift").unwrap();
    within(tried(&d, "bias_time_drift").value[j], slope, tried(&d, "bias_time_drift").sigma[j], "drift");
    assert!(f.value[0].is_finite() && f.sigma[0] > 0.0, "{f:?}");
}

/// A sampling delay of one package: the pair simulated at 1 kHz, package 4's three axes read 1 ms
/// (one 1 kHz sample) late, then every column decimated to 62.5 Hz. Named on package 4 alone
/// and recovered within 3 sigma (relative to the median package, which is undelayed).
#[test]
fn a_sampling_delay_of_one_package_made_at_1_khz_is_named_on_its_package() {
    let array = mimu_array();
    let t = truth(&array);
    let layout = EffectLayout::new(&array.array);
    let m = 3;
    let factor = 16;
    let hide = |seed: u64| -> Recording {
        decimated(&simulated(&array, &t, seed, 1000.0), factor, |j| usize::from(layout.package_of[j] == m), 0)
    };
    let d = diagnose(&hide(47), &array, &[hide(48)]);
    let delayed: Vec<Option<usize>> =
        d.findings.iter().filter(|f| f.name == "sampling_delay").map(|f| f.package).collect();
    assert_eq!(delayed, [Some(m)], "{:?} {:?}", d.findings, d.not_named);
    assert_eq!(library_named(&d), ["sampling_delay"]);
    let f = d.findings.iter().find(|f| f.name == "sampling_delay").unwrap();
    within(f.value[0], 1e-3, f.sigma[0], "delay");
}

/// The gyroscopes' own scale factor and misalignment in `--use-gyro` mode: the reference rate of
/// both recordings read through `(I + G)^-1` (the true rate is `(I + G) w_ref`), G of 0.1-0.3%.
/// Its rank test: 4 of 9 directions unseen (the antisymmetric part is a rotation of the
/// accelerometers, the common scale a size). The seen part, the symmetric part less its trace, is
/// recovered within 3 sigma.
#[test]
fn a_gyro_scale_and_misalignment_hidden_by_the_simulator_is_named_in_use_gyro_mode() {
    let array = mimu_array();
    let t = truth(&array);
    let g = Matrix3::new(2e-3, 1.5e-3, -1e-3, 0.5e-3, -2e-3, 2.5e-3, -1.5e-3, 1e-3, 3e-3);
    let inverse = (Matrix3::identity() + g).try_inverse().unwrap();
    let hide = |seed: u64| {
        let mut r = recording(&array, &t, seed);
        for w in &mut r.gyro_rate_rad_s {
            *w = inverse * *w;
        }
        r
    };
    let settings = CalibrateSettings { use_gyro: true, ..CalibrateSettings::default() };
    let d = gfcal::discrepancy::recorded::diagnose_recordings(&hide(49), &array, &[hide(50)], &settings, 0.01)
        .expect("diagnosed");
    let rank = tried(&d, "gyro_scale_misalignment");
    assert_eq!(rank.unseen, 4, "{rank:?}");
    assert_eq!(library_named(&d), ["gyro_scale_misalignment"], "{:?}", d.not_named);
    let e = Matrix3::from_fn(|a, b| rank.value[3 * a + b]) - g;
    let s = (e + e.transpose()) / 2.0 - Matrix3::identity() * (e.trace() / 3.0);
    let sd = |a: usize, b: usize| rank.sigma[3 * a + b];
    for a in 0..3 {
        for b in 0..3 {
            let bound =
                if a == b { sd(a, a) + (sd(0, 0) + sd(1, 1) + sd(2, 2)) / 3.0 } else { (sd(a, b) + sd(b, a)) / 2.0 };
            within(s[(a, b)], 0.0, bound, &format!("symmetric traceless part ({a}, {b})"));
        }
    }
}

/// The sensing point of each axis: package 6's z axis sits 8 mm above its x axis (along z) in the
/// truth, the other axes differ by the truth's random 0.5 mm. Every within-package difference is
/// recovered (normalised errors below 4, RMS 0.5-1.6 over the 48 values) and package 6's test
/// rejects. The z axes' common shift is the gauge's (`selfcal::model::Gauge`, axis groups): the
/// truth is moved onto it, so package 6's z axis is 7 mm above its x axis there and every other
/// package's z axis 1 mm below (what a calibration can tell: an axis against its group's mean).
#[test]
fn a_sensing_point_per_axis_made_by_the_simulator_is_found_inside_its_package() {
    let array = mimu_array();
    let mut t = truth(&array);
    let layout = EffectLayout::new(&array.array);
    let (m, zaxis) = (5, layout.packages[5][2]);
    t.location_error_m[zaxis].z += 8e-3;
    project_to_gauge(&array.array, &mut t);
    let d = diagnose(&recording(&array, &t, 51), &array, &[recording(&array, &t, 52)]);
    let mut z = Vec::new();
    for sp in &d.sensing_points {
        let accs = &layout.packages[sp.package];
        for (i, &j) in accs.iter().skip(1).enumerate() {
            for c in 0..3 {
                let want = t.location_error_m[j][c] - t.location_error_m[accs[0]][c];
                z.push((sp.difference_m[3 * i + c] - want) / sp.sigma_m[3 * i + c]);
            }
        }
        if sp.package == m {
            assert!(sp.p_value < 1e-6, "{sp:?}");
        }
    }
    assert_eq!(z.len(), 48);
    assert!(z.iter().all(|v| v.abs() < 4.0), "{z:?}");
    let rms = (z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64).sqrt();
    assert!((0.5..1.6).contains(&rms), "RMS {rms}: {z:?}");
}

/// The lag search of `gfcal calibrate`'s gyroscope check: a recording simulated at 1 kHz whose gyroscopes
/// read 1 ms late (one 1 kHz sample), decimated to 62.5 Hz: the accelerometers lead by 1 ms, found to
/// within the search's 0.1 ms step, and the RMS difference at that lag is below the one at none.
#[test]
fn the_gyroscope_check_finds_a_lag_made_at_1_khz() {
    let array = mimu_array();
    let t = truth(&array);
    let factor = 16;
    let rec = decimated(&simulated(&array, &t, 53, 1000.0), factor, |_| 0, 1);
    let cal = gfcal::selfcal::calibrate::calibrate(&rec, &array, &CalibrateSettings::default()).expect("calibrated");
    let g = cal.gyro_check.expect("gyroscopes");
    assert!((g.accelerometer_lag_s + 1e-3).abs() < 1.5e-4, "lag {} s", g.accelerometer_lag_s);
    assert!(g.rms_at_lag_rad_s < g.rms_rad_s, "{g:?}");
}

/// A cubic scale factor, `s = k (b + u + c u^3)` on the simulator's true reading, at a size these
/// recordings can see (c = 2e-5 /(m/s^2)^2: 6% of the reading at 5 g; the real recordings' sigma is about
/// 2e-6), on accelerometer 16, named there and recovered within 3 sigma.
#[test]
fn a_cubic_scale_factor_hidden_by_the_simulator_is_named_on_its_accelerometer() {
    let array = mimu_array();
    let t = truth(&array);
    let (c, j) = (2e-5, 15);
    let hide = |seed: u64| with_power(recording(&array, &t, seed), &array, &t, j, c, 3);
    let d = diagnose(&hide(55), &array, &[hide(56)]);
    assert_eq!(named_on(&d, "scale_factor_cubic"), [j], "{:?} {:?}", d.findings, d.not_named);
    // The cubic alone: the rotation phase's readings are not symmetric about zero (the centripetal part has
    // one sign), so u^3 has a part along u^2, and while the effects were tried in a fixed order the
    // quadratic, tried first, was named on the same accelerometer too. Selected across the effects
    // (`discrepancy::recorded::selection`), the cubic enters first and holds what the quadratic took.
    assert_eq!(library_named(&d), ["scale_factor_cubic"], "{:?} {:?}", d.findings, d.not_named);
    let f = d.findings.iter().find(|f| f.name == "scale_factor_cubic").unwrap();
    within(f.value[0], c, f.sigma[0], "cubic");
}

/// Clean simulated pairs name nothing of the library (nor a turn-on effect) in at least 97 of 100 seeds:
/// at a nominal familywise 1% per diagnosis, 4 or more would happen with p < 2%. About 8 minutes on two
/// cores in the test profile, so not in CI: `cargo test --test gfcal clean_simulated_pairs -- --ignored`.
///
/// History: with the turn-on test's sigmas taken as the held-out refit's and the fitting recording's own
/// sigma combined, 15 of 100 pairs named `bias_turn_on`. With the changes' whole covariance
/// (`discrepancy::recorded::change`), 1 of 100 (seed 34, `bias_turn_on`), run on 2026-11-24; the same with the
/// library's owners selected across the effects (`discrepancy::recorded::selection`), run on 2026-12-01.
#[test]
#[ignore = "about 8 minutes on two cores; run it after any change to the diagnosis of recordings"]
fn clean_simulated_pairs_name_nothing_in_at_least_97_of_100_seeds() {
    use rayon::prelude::*;
    let array = mimu_array();
    let named: Vec<(u64, Vec<String>)> = (0..100u64)
        .into_par_iter()
        .map(|seed| {
            let t = gfcal::selfcal::simulate::random_truth(
                &array.array,
                0.005,
                0.3,
                0.004,
                0.5e-3,
                &mut trial_rng(1000 + seed, 0),
            );
            let a = recording(&array, &t, 2000 + 2 * seed);
            let b = recording(&array, &t, 2001 + 2 * seed);
            let d = diagnose(&a, &array, &[b]);
            (seed, d.findings.iter().map(|f| f.name.clone()).collect())
        })
        .collect();
    let loud: Vec<_> = named.iter().filter(|(_, n)| !n.is_empty()).collect();
    eprintln!("clean pairs naming something: {} of 100: {loud:?}", loud.len());
    assert!(loud.len() <= 3, "{loud:?}");
}

/// Issue 11's open question (on real recordings `--use-gyro` read 39% of an accelerometer advance
/// injected with `gfcal inject`), in simulation: a pair simulated at 1 kHz whose 24 accelerometers
/// all read 1 ms (one 1 kHz sample) behind the gyroscopes, decimated to 62.5 Hz. Expected before
/// the first run: with `--use-gyro` every package's delay is named and reads 1 ms within 3 sigma.
#[test]
fn a_common_accelerometer_delay_made_at_1_khz_reads_whole_in_use_gyro_mode() {
    let array = mimu_array();
    let t = truth(&array);
    let hide = |seed: u64| decimated(&simulated(&array, &t, seed, 1000.0), 16, |_| 1, 0);
    let settings = CalibrateSettings { use_gyro: true, ..CalibrateSettings::default() };
    let d = gfcal::discrepancy::recorded::diagnose_recordings(&hide(61), &array, &[hide(62)], &settings, 0.01)
        .expect("diagnosed");
    let rank = tried(&d, "sampling_delay");
    let delayed: Vec<Option<usize>> =
        d.findings.iter().filter(|f| f.name == "sampling_delay").map(|f| f.package).collect();
    eprintln!("delays {:?} sigmas {:?} named {:?}", rank.value, rank.sigma, delayed);
    assert_eq!(delayed.len(), 8, "{:?} {:?}", d.findings, d.not_named);
    for (m, (v, s)) in rank.value.iter().zip(&rank.sigma).enumerate() {
        within(*v, 1e-3, *s, &format!("package {m}'s delay"));
    }
}

/// Where the `--use-gyro` common delay's last 10% on real recordings goes (EXPECTATIONS.md, "Where the
/// `--use-gyro` delay's last 10% goes", written before the run): a pair simulated at 1 kHz whose rotation
/// moves faster than the usual 0.3-2 Hz, (a) every accelerometer 1 ms late at 1 kHz, decimated (a true delay),
/// (b) no delay, then 1 ms added to every accelerometer by `inject`'s generator on the 62.5 Hz table.
///
/// Planned, at 0.3-12 Hz: (a) 0.998-1.002 ms and (b) 1.001-1.005 ms, sigma 0.035 ms: both whole, so the check as
/// planned found neither. Then, not planned, at 0.3-25 Hz: (a) still 1.005-1.007 ms, but (b) 0.17 ms. The
/// centripetal term, which alone carries a delay common to every package, has twice the rate's frequencies; past
/// the Nyquist frequency its samples are aliased, and interpolating them is not a delay. So the estimator reads a
/// true delay whole on fast motion, and `inject`'s delay is faithful only on motion below about a quarter of the
/// sample rate. Asserted: (a) at both bands and (b) at 12 Hz, within 3 sigma; (b) at 25 Hz below half the delay.
#[test]
#[ignore = "slow: about a minute (four simulated recordings at two motion bands, diagnosed); run with --ignored (docs/testing.md)"]
fn a_true_common_delay_reads_whole_on_fast_motion_and_an_injected_one_only_below_a_quarter_of_the_sample_rate() {
    use gfcal::io::table::Table;
    let array = mimu_array();
    let t = truth(&array);
    let settings = CalibrateSettings { use_gyro: true, ..CalibrateSettings::default() };
    let read = |a: &Recording, b: &Recording| {
        let d = gfcal::discrepancy::recorded::diagnose_recordings(a, &array, std::slice::from_ref(b), &settings, 0.01)
            .expect("diagnosed");
        let r = tried(&d, "sampling_delay");
        (r.value.clone(), r.sigma.clone())
    };
    let injected = |r: Recording| {
        let mut names = vec!["t_s".to_string()];
        names.extend(array.accelerometer_columns.iter().cloned());
        let mut data = vec![r.t_s.clone()];
        data.extend((0..r.outputs.ncols()).map(|j| r.outputs.column(j).iter().copied().collect::<Vec<f64>>()));
        let mut table = Table { path: "sim.csv".into(), first_null_row: vec![None; names.len()], names, data };
        for j in 1..=array.array.len() {
            gfcal::discrepancy::inject::inject(&mut table, &array, "sampling_delay", j, 1e-3).expect("injected");
        }
        let mut out = r.clone();
        let n = out.outputs.ncols();
        for j in 0..n {
            for i in 0..out.samples() {
                out.outputs[(i, j)] = table.data[j + 1][i];
                out.clipped[i * n + j] = table.data[j + 1][i].abs() >= array.ranges_m_s2[j];
            }
        }
        out
    };
    for top_hz in [12.0, 25.0] {
        let fast = |seed: u64| {
            let mut p = protocol(array.array.len());
            p.sample_rate_hz = 1000.0;
            p.motion_band_hz = [0.3, top_hz];
            simulate(&array, &t, &p, &mut trial_rng(seed, 1)).expect("simulated")
        };
        let (s1, s2) = (fast(71), fast(72));
        let late = |s: &Simulated| decimated(s, 16, |_| 1, 0);
        let none = |s: &Simulated| decimated(s, 16, |_| 0, 0);
        let (a, sa) = read(&late(&s1), &late(&s2));
        let (b, sb) = read(&injected(none(&s1)), &injected(none(&s2)));
        eprintln!("0.3-{top_hz} Hz: true 1 ms {a:?} +- {sa:?}; injected 1 ms {b:?} +- {sb:?}");
        for m in 0..a.len() {
            within(a[m], 1e-3, sa[m], &format!("{top_hz} Hz, true delay, package {}", m + 1));
            if top_hz < 20.0 {
                within(b[m], 1e-3, sb[m], &format!("{top_hz} Hz, injected delay, package {}", m + 1));
            } else {
                assert!(b[m] < 0.5e-3, "{top_hz} Hz, injected delay, package {}: {}", m + 1, b[m]);
            }
        }
    }
}
