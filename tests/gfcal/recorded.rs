//! `gfcal diagnose` on recordings (issue 11): the baseline's gap on the fitting and held-out
//! recordings, and the per-recording turn-on bias, on simulated recordings whose truth comes from
//! the protocol simulator (not from the refit) and on the six real recordings.

use std::path::PathBuf;

use gfcal::array::wiring::RecordingArray;
use gfcal::discrepancy::Explanation;
use gfcal::discrepancy::recorded::{RecordedDiagnosis, diagnose_recordings};
use gfcal::rng::trial_rng;
use gfcal::selfcal::calibrate::CalibrateSettings;
use gfcal::selfcal::model::SensorSet;
use gfcal::selfcal::recording::Recording;
use gfcal::selfcal::simulate::{random_truth, simulate};

use super::selfcal::{mimu_array, protocol};

/// The real board's array with its packages' clocks not declared: the library's effects on the real
/// recordings were established, and these tests' criteria written, before the clocks were modelled.
/// With the clocks declared, the diagnosis first corrects the outputs to the packages' mean instant
/// (tests/gfcal/clock_recovery.rs; the six diagnoses in results/mimu4444/discrepancy/clock_effect.md).
fn real_array() -> RecordingArray {
    super::simulate::without_clocks(&mimu_array())
}

pub fn truth(array: &RecordingArray) -> SensorSet {
    random_truth(&array.array, 0.005, 0.3, 0.004, 0.5e-3, &mut trial_rng(21, 0))
}

pub fn recording(array: &RecordingArray, truth: &SensorSet, seed: u64) -> Recording {
    simulate(array, truth, &protocol(array.array.len()), &mut trial_rng(seed, 1)).expect("simulated").recording
}

pub fn diagnose(fitting: &Recording, array: &RecordingArray, held: &[Recording]) -> RecordedDiagnosis {
    diagnose_recordings(fitting, array, held, &CalibrateSettings::default(), 0.01).expect("diagnosed")
}

#[test]
fn a_turn_on_bias_between_simulated_recordings_is_named_and_recovered_within_its_sigma() {
    let array = mimu_array();
    let n = array.array.len();
    let t = truth(&array);
    // The second recording's biases differ by 0.05-0.2 m/s^2 (the generator's truth, not a term
    // of the diagnosis).
    let mut shifted = t.clone();
    let shift: Vec<f64> = (0..n).map(|j| 0.05 + 0.15 * ((j as f64 * 0.37).sin().abs())).collect();
    for (j, (b, s)) in shifted.bias_m_s2.iter_mut().zip(&shift).enumerate() {
        *b += if j % 2 == 0 { *s } else { -*s };
    }
    let a = recording(&array, &t, 31);
    let b = recording(&array, &shifted, 32);
    let d = diagnose(&a, &array, std::slice::from_ref(&b));
    assert_eq!(d.findings.len(), 1, "{:?}", d.not_named);
    assert_eq!(d.findings[0].name, "bias_turn_on");
    let h = &d.held_out[0];
    assert!(h.after.static_chi2_dof < h.before.static_chi2_dof / 10.0, "{:?} -> {:?}", h.before, h.after);
    // Each change within 4 sigma of the injected one, and the normalised errors of unit RMS
    // (0.6-1.6 for 24 values).
    let z: Vec<f64> = (0..n)
        .map(|j| (h.bias_change_m_s2[j] - (shifted.bias_m_s2[j] - t.bias_m_s2[j])) / h.bias_change_sigma_m_s2[j])
        .collect();
    assert!(z.iter().all(|v| v.abs() < 4.0), "{z:?}");
    let rms = (z.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    assert!((0.6..1.6).contains(&rms), "RMS of the normalised errors {rms}: {z:?}");
    // The simulated recordings have no unmodelled effect: after the turn-on bias, nothing is left.
    assert!(h.after.static_chi2_dof < 1.5, "{:?}", h.after);
    assert_eq!(d.explanation(), Explanation::Complete, "{:?} {:?}", d.fitting, d.held_out);
}

#[test]
fn a_scale_factor_change_between_simulated_recordings_is_named_after_the_bias_and_recovered() {
    let array = mimu_array();
    let n = array.array.len();
    let t = truth(&array);
    let mut shifted = t.clone();
    for j in 0..n {
        shifted.bias_m_s2[j] += 0.03 * if j % 3 == 0 { 1.0 } else { -0.5 };
        // 500-1,500 ppm (a temperature change of tens of degrees on a MEMS part).
        shifted.scale_factor[j] *= 1.0 + 1e-3 * ((j as f64 * 0.61).sin());
    }
    let a = recording(&array, &t, 35);
    let b = recording(&array, &shifted, 36);
    let d = diagnose(&a, &array, std::slice::from_ref(&b));
    let names: Vec<&str> = d.findings.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["bias_turn_on", "scale_factor_turn_on"], "{:?}", d.not_named);
    let h = &d.held_out[0];
    let z: Vec<f64> = (0..n)
        .map(|j| {
            (h.scale_factor_change[j] - (shifted.scale_factor[j] - t.scale_factor[j])) / h.scale_factor_change_sigma[j]
        })
        .collect();
    assert!(z.iter().all(|v| v.abs() < 4.0), "{z:?}");
    let rms = (z.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    assert!((0.6..1.6).contains(&rms), "RMS of the normalised errors {rms}: {z:?}");
    // The gap after each addition: the bias alone leaves the scale-factor change, both leave noise.
    assert_eq!(h.after_each.len(), 2);
    assert!(h.after_each[0].1.static_chi2_dof > 2.0 && h.after_each[1].1.static_chi2_dof < 1.5, "{:?}", h.after_each);
    assert_eq!(d.explanation(), Explanation::Complete);
}

#[test]
fn recordings_with_the_same_biases_name_no_turn_on_bias() {
    let array = mimu_array();
    let t = truth(&array);
    let a = recording(&array, &t, 33);
    let b = recording(&array, &t, 34);
    let d = diagnose(&a, &array, std::slice::from_ref(&b));
    assert!(d.findings.is_empty(), "{:?}", d.findings);
    assert_eq!(d.explanation(), Explanation::NothingToExplain, "{:?} {:?}", d.fitting, d.held_out);
    // Every sigma of the library is a claim: with nothing hidden, each effect's values as a whole are
    // consistent with zero under their robust covariance, neither too far (sigmas too small) nor too near
    // (too large): the joint Wald test's p-value within 0.001-0.999 (false failure 1% over five effects).
    for r in d.ranks.iter().filter(|r| r.unseen < r.parameters) {
        assert!(
            (0.001..0.999).contains(&r.p_value_joint),
            "{}: joint p {} ({:?} +- {:?})",
            r.name,
            r.p_value_joint,
            r.value,
            r.sigma
        );
    }
}

pub fn real(k: usize) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("../shared/data/mimu4444/recording_{k}.parquet"))
}

/// The real board: fitted on recording 1, scored on recordings 2-6. The criteria are those of
/// results/mimu4444/discrepancy/EXPECTATIONS.md, written before the first run.
#[test]
#[ignore = "slow: about 1.7 minutes (a diagnosis of real recording 1 scored on five held-out recordings); run with --ignored (docs/testing.md)"]
fn real_recordings_name_a_turn_on_bias_that_holds_up_on_every_held_out_recording() {
    let array = real_array();
    let fitting = Recording::read(&real(1), &array).expect("recording 1");
    let held: Vec<Recording> = (2..=6).map(|k| Recording::read(&real(k), &array).expect("recording")).collect();
    let d = diagnose(&fitting, &array, &held);
    let names: Vec<&str> = d.findings.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names[0], "bias_turn_on");
    // The library (EXPECTATIONS.md, its section written before the six were run): a warm-up drift, refitted
    // per recording, on some accelerometers, and nothing else.
    assert!(names[1..].iter().all(|n| *n == "bias_time_drift") && names.len() > 1, "{names:?}");
    assert!(d.findings.iter().filter(|f| f.name == "bias_time_drift").all(|f| f.value[0] < 0.0), "{:?}", d.findings);
    for h in &d.held_out {
        // It holds up on recordings it was not fitted to: the held-out static gap falls a lot.
        assert!(
            h.after.static_chi2_dof < h.before.static_chi2_dof / 5.0,
            "{}: {:?} -> {:?}",
            h.recording.display(),
            h.before,
            h.after
        );
        // The rotation phase stays far above the noise (the unexplained gap).
        assert!(h.after.dynamic.is_some_and(|g| g > 100.0), "{:?}", h.after);
    }
    assert!(d.fitting.dynamic.is_some_and(|g| g > 100.0), "{:?}", d.fitting);
    assert_eq!(d.explanation(), Explanation::Partial);
}

fn gfcal(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_gfcal"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("gfcal runs")
}

const ARRAY: &str = "configs/arrays/mimu4444_corners.toml";

/// Item 5: a turn-on bias of 0.05 m/s^2 (a realistic size: the recordings' own changes are a median
/// 0.01, at most 0.16) added by `gfcal inject` to accelerometer 5 of real recording 2 comes back on
/// accelerometer 5, on top of what the clean recording shows, within its sigma; the others do not move.
#[test]
#[ignore = "slow: about 1.3 minutes (two diagnoses of real recordings); run with --ignored (docs/testing.md)"]
fn a_turn_on_bias_injected_into_a_real_recording_is_recovered_on_the_right_accelerometer() {
    let dir = tempfile::tempdir().unwrap();
    let injected = dir.path().join("recording_2_injected.parquet");
    let o = gfcal(&[
        "inject",
        real(2).to_str().unwrap(),
        "--array",
        ARRAY,
        "--effect",
        "bias_turn_on",
        "--accelerometer",
        "5",
        "--value",
        "0.05",
        "--out",
        injected.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let array = real_array();
    let fitting = Recording::read(&real(1), &array).unwrap();
    let clean = Recording::read(&real(2), &array).unwrap();
    let with = Recording::read(&injected, &array).unwrap();
    let d = diagnose(&fitting, &array, &[clean, with]);
    // The turn-on effects (the library's warm-up drift is named too on these recordings; see
    // results/mimu4444/discrepancy/README.md).
    let turn_on: Vec<&str> = d.findings.iter().map(|f| f.name.as_str()).filter(|n| n.ends_with("_turn_on")).collect();
    assert_eq!(turn_on, ["bias_turn_on"]);
    let k5 = d.calibration.fit.params.scale_factor[4];
    let (c, w) = (&d.held_out[0], &d.held_out[1]);
    for j in 0..array.array.len() {
        let extra = w.bias_change_m_s2[j] - c.bias_change_m_s2[j];
        let sigma = w.bias_change_sigma_m_s2[j];
        if j == 4 {
            // Input-referred: the injected output offset over the scale factor.
            assert!((extra - 0.05 / k5).abs() < sigma, "accelerometer 5: {extra} against {} +- {sigma}", 0.05 / k5);
        } else {
            assert!(extra.abs() < 0.1 * sigma, "accelerometer {}: moved by {extra} (sigma {sigma})", j + 1);
        }
    }
}

#[test]
fn inject_refuses_unknown_effects_and_accelerometers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.csv");
    let run = |effect: &str, j: &str, v: &str| {
        gfcal(&[
            "inject",
            real(1).to_str().unwrap(),
            "--array",
            ARRAY,
            "--effect",
            effect,
            "--accelerometer",
            j,
            "--value",
            v,
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let first = real(1);
    let without = |effect: &str, extra: &[&str]| {
        let mut args = vec!["inject", first.to_str().unwrap(), "--array", ARRAY, "--effect", effect, "--value", "1e-3"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        gfcal(&args)
    };
    let gyro = |extra: &[&str]| without("gyro_scale_misalignment", extra);
    let accel = |extra: &[&str]| without("bias_turn_on", extra);
    for (o, says) in [
        (run("warp_drive", "1", "1"), "unknown effect `warp_drive` (known: bias_turn_on"),
        (run("bias_turn_on", "25", "1"), "25 is not an accelerometer"),
        (run("bias_turn_on", "0", "1"), "0 is not an accelerometer"),
        (run("bias_turn_on", "1", "nan"), "--value: must be a finite number"),
        (run("gyro_scale_misalignment", "1", "1e-3"), "--accelerometer: gyro_scale_misalignment is on the gyroscopes"),
        (gyro(&["--element", "xw"]), "--element: unknown element `xw`"),
        (gyro(&[]), "--element: gyro_scale_misalignment needs the element"),
        (accel(&["--element", "xy"]), "--element: only for gyro_scale_misalignment"),
        (accel(&[]), "--accelerometer: bias_turn_on needs the accelerometer"),
    ] {
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(says), "{err}");
        assert!(!out.exists(), "nothing written");
    }
}

/// The generators against their definitions on a small table: each changes only its column, by
/// the documented amount.
#[test]
fn each_injected_effect_changes_its_column_as_documented() {
    use gfcal::discrepancy::inject::inject;
    use gfcal::io::table::Table;
    let array = mimu_array();
    let n = array.array.len();
    let rows = 50;
    let t: Vec<f64> = (0..rows).map(|i| 10.0 + 0.016 * i as f64).collect();
    let mut names = vec!["t_s".to_string()];
    names.extend(array.accelerometer_columns.iter().cloned());
    let mut data = vec![t.clone()];
    data.extend((0..n).map(|j| t.iter().map(|ti| 3.0 * (ti * (j + 1) as f64).sin()).collect::<Vec<f64>>()));
    let table = Table { path: "test.csv".into(), names, data, first_null_row: vec![None; n + 1] };
    let col = 1 + 6; // accelerometer 7
    for (effect, v) in [
        ("bias_turn_on", 0.05),
        ("bias_time_drift", 0.001),
        ("scale_factor_quadratic", 1e-3),
        ("scale_factor_cubic", 1e-4),
        ("cross_coupling", 1e-3),
        ("sampling_delay", 0.004),
    ] {
        let mut x = table.clone();
        inject(&mut x, &array, effect, 7, v).unwrap();
        for (c, (a, b)) in x.data.iter().zip(&table.data).enumerate() {
            if c != col {
                assert_eq!(a, b, "{effect}: column {c} changed");
            }
        }
        for i in 1..rows {
            let (s, y) = (table.data[col][i], x.data[col][i]);
            let want = match effect {
                "bias_turn_on" => s + v,
                "bias_time_drift" => s + v * (t[i] - t[0]),
                "scale_factor_quadratic" => s + v * s * s,
                "scale_factor_cubic" => s + v * s * s * s,
                // Accelerometer 7 is IMU 3's x axis: its first cross direction is +y, IMU 3's y axis
                // (accelerometer 8, the next column).
                "cross_coupling" => s + v * s * table.data[col + 1][i],
                // The column is 3 sin(7 t): delayed by v, 3 sin(7 (t - v)), to the band-limited
                // interpolator's accuracy, away from the ends (16 samples each side).
                _ => 3.0 * (7.0 * (t[i] - v)).sin(),
            };
            let tolerance = if effect == "sampling_delay" { 1e-4 } else { 1e-12 };
            if effect == "sampling_delay" && !(16..rows - 16).contains(&i) {
                continue;
            }
            assert!((y - want).abs() < tolerance, "{effect} at row {i}: {y} against {want}");
        }
    }
}

/// The rank test and the parameters of one effect of the library, as fitted on the fitting recording.
pub fn tried<'a>(d: &'a RecordedDiagnosis, name: &str) -> &'a gfcal::discrepancy::recorded::RankTest {
    d.ranks.iter().find(|r| r.name == name).unwrap_or_else(|| panic!("{name} not tried: {:?}", d.ranks))
}

pub fn named_on(d: &RecordedDiagnosis, name: &str) -> Vec<usize> {
    d.findings.iter().filter(|f| f.name == name).filter_map(|f| f.accelerometer).collect()
}

/// `gfcal inject` from `from` to `to`; `target` is `["--accelerometer", J]` or `["--element", AB]`.
pub fn inject_into(from: &std::path::Path, to: &std::path::Path, effect: &str, target: [&str; 2], value: &str) {
    let o = gfcal(&[
        "inject",
        from.to_str().unwrap(),
        "--array",
        ARRAY,
        "--effect",
        effect,
        target[0],
        target[1],
        "--value",
        value,
        "--out",
        to.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// One injection step: the effect, its target (`["--accelerometer", J]` or `["--element", AB]`) and its value.
type Step<'a> = (&'a str, [&'a str; 2], &'a str);

/// Real recordings 2 and 3, clean and with `steps` injected into both in turn, diagnosed (fitted on 2, 3 held
/// out) with `settings`: (clean, injected).
fn injected_pair(steps: &[Step], settings: &CalibrateSettings) -> (RecordedDiagnosis, RecordedDiagnosis) {
    let dir = tempfile::tempdir().unwrap();
    let mut injected = Vec::new();
    for k in [2, 3] {
        let mut from = real(k);
        for (i, (effect, target, value)) in steps.iter().enumerate() {
            let to = dir.path().join(format!("r{k}_{i}.parquet"));
            inject_into(&from, &to, effect, *target, value);
            from = to;
        }
        injected.push(from);
    }
    let array = real_array();
    let read = |p: &std::path::Path| Recording::read(p, &array).unwrap();
    let run = |a: &std::path::Path, b: &std::path::Path| {
        diagnose_recordings(&read(a), &array, &[read(b)], settings, 0.01).expect("diagnosed")
    };
    (run(&real(2), &real(3)), run(&injected[0], &injected[1]))
}

/// Items 3 and 5 on the real board: an input-dependent scale factor (1.5e-4 /(m/s^2) on accelerometer 5,
/// 2.4% of the reading at the rail, about 6 robust sigmas), a bias drift (1e-4 m/s^2/s on accelerometer
/// 11, 0.06 m/s^2 over a recording), a cross-coupling of accelerometer 19 with its package's y axis (2e-4
/// /(m/s^2), 2e-3 /g, about 10 sigmas) and a sampling delay of package 3 (0.4 ms on its three axes, 13 sigmas)
/// added by `gfcal inject` to real recordings 2 and 3 (a property of the hardware is in every recording)
/// come back named on their accelerometers and package, each recovered on top of what the clean pair shows
/// within its sigma. The rank tests are exact: a linear cross-axis sensitivity is a tilt, a
/// delay common to every package is a rigid motion at another time.
#[test]
#[ignore = "slow: about 2 minutes (diagnoses of real recordings with injected effects); run with --ignored (docs/testing.md)"]
fn effects_injected_into_real_recordings_are_named_on_their_accelerometer_and_recovered() {
    // Package 3 is accelerometers 7-9.
    let steps: [Step; 6] = [
        ("scale_factor_quadratic", ["--accelerometer", "5"], "1.5e-4"),
        ("bias_time_drift", ["--accelerometer", "11"], "1e-4"),
        ("cross_coupling", ["--accelerometer", "19"], "2e-4"),
        ("sampling_delay", ["--accelerometer", "7"], "4e-4"),
        ("sampling_delay", ["--accelerometer", "8"], "4e-4"),
        ("sampling_delay", ["--accelerometer", "9"], "4e-4"),
    ];
    let (clean, with) = injected_pair(&steps, &CalibrateSettings::default());
    assert!(named_on(&with, "scale_factor_quadratic").contains(&4), "{:?} {:?}", with.findings, with.not_named);
    assert!(named_on(&with, "bias_time_drift").contains(&10), "{:?} {:?}", with.findings, with.not_named);
    assert!(named_on(&with, "cross_coupling").contains(&18), "{:?} {:?}", with.findings, with.not_named);
    let k = &clean.calibration.fit.params.scale_factor;
    // Input-referred: the output term V s^2 is k V u^2 + lower orders (absorbed by the bias and the scale
    // factor); the output drift V t is V / k of input.
    // The cross-coupling V s_19 s_20 is k_19 (V k_20) u_19 (e1 . q) plus terms the baseline absorbs: its first
    // parameter (along e1 = +y, accelerometer 20's axis) is V k_20.
    for (name, j, want) in [
        ("scale_factor_quadratic", 4, 1.5e-4 * k[4]),
        ("bias_time_drift", 10, 1e-4 / k[10]),
        ("cross_coupling", 2 * 18, 2e-4 * k[19]),
    ] {
        let (w, c) = (tried(&with, name), tried(&clean, name));
        let extra = w.value[j] - c.value[j];
        assert!((extra - want).abs() < w.sigma[j], "{name} on {}: {extra} against {want} +- {}", j + 1, w.sigma[j]);
    }
    // The delay: package 3 against the mean of the others (the common delay is unseen).
    assert_eq!(
        with.findings.iter().filter(|f| f.name == "sampling_delay").map(|f| f.package).collect::<Vec<_>>(),
        [Some(2)],
        "{:?} {:?}",
        with.findings,
        with.not_named
    );
    let p = tried(&with, "sampling_delay").value.len();
    let c = nalgebra::DVector::from_fn(p, |i, _| if i == 2 { 1.0 } else { -1.0 / (p - 1) as f64 });
    let against_others =
        |d: &RecordedDiagnosis| c.dot(&nalgebra::DVector::from_column_slice(&tried(d, "sampling_delay").value));
    let extra = against_others(&with) - against_others(&clean);
    let sigma = (c.transpose() * &tried(&with, "sampling_delay").covariance * &c)[(0, 0)].sqrt();
    assert!((extra - 4e-4).abs() < sigma, "delay of package 3: {extra} against 4e-4 +- {sigma}");
    for d in [&clean, &with] {
        assert_eq!(tried(d, "cross_axis").unseen, 48);
        assert_eq!(tried(d, "sampling_delay").unseen, 1);
        for name in ["bias_time_drift", "scale_factor_quadratic", "scale_factor_cubic", "cross_coupling"] {
            assert_eq!(tried(d, name).unseen, 0, "{name}");
        }
    }
}

/// Item 5 for the delay `--use-gyro` sees, the one common to every package (gyroscope-free it is unseen):
/// every accelerometer of real recordings 2 and 3 advanced by 1.2 ms with `gfcal inject`, against the
/// gyroscopes. The first criterion was written before the run (EXPECTATIONS.md, prediction 2 of "Censored
/// samples un-censored"): every package's delay below 0.3 ms in magnitude after the advance. It held, but the
/// change read 1.07-1.08 ms, 3 printed sigmas short. The cause (EXPECTATIONS.md, "The runs' edges", predicted
/// before the run): the gyroscopes' rails split the rotation phase into short runs, and on two thirds of the rows
/// the delay's column took a shortened or one-sided derivative. With the column on the rows that hold the whole
/// differentiator (`recorded_blocks::whole_differentiator`) every package moves by 1.184-1.193 ms +- 0.065: the
/// issue's criterion, the injected magnitude within its sigma on top of the clean pair's value, now asserted.
/// After the advance the delay was rightly no longer named (0.13-0.19 ms, joint p 0.06); a 1.2 ms *delay* of every
/// accelerometer instead (about 2.5 ms in all; EXPECTATIONS.md, "The common delay named when injected") was named on
/// every package and recovered within its sigma as well. Since the array file's `accelerometer_lag_ms` takes the
/// common lag out (2026-11-29) the clean pair reads under 0.3 ms, so both the advance and the delay are named on
/// every package (EXPECTATIONS.md (bz): the test's old precondition, a clean lag above 1 ms, failed there).
/// Before the delay's column took the rate's derivative from the gyroscopes, the same advance moved it by 0.62 ms.
#[test]
#[ignore = "slow: about 2.5 minutes (four --use-gyro diagnoses of real recordings); run with --ignored (docs/testing.md)"]
fn a_common_advance_injected_into_real_recordings_moves_the_use_gyro_delay_with_it() {
    let numbers: Vec<String> = (1..=24).map(|j| j.to_string()).collect();
    let settings = CalibrateSettings { use_gyro: true, ..CalibrateSettings::default() };
    for value in ["-1.2e-3", "1.2e-3"] {
        let steps: Vec<Step> =
            numbers.iter().map(|j| ("sampling_delay", ["--accelerometer", j.as_str()], value)).collect();
        let (clean, with) = injected_pair(&steps, &settings);
        let (c, w) = (tried(&clean, "sampling_delay"), tried(&with, "sampling_delay"));
        assert_eq!(w.unseen, 0);
        let named: Vec<Option<usize>> =
            with.findings.iter().filter(|f| f.name == "sampling_delay").map(|f| f.package).collect();
        for (m, (before, after)) in c.value.iter().zip(&w.value).enumerate() {
            eprintln!("{value} s: package {}: {before:.4e} s -> {after:.4e} s +- {:.1e}", m + 1, w.sigma[m]);
            // The array file's `accelerometer_lag_ms` (1.5 ms) takes the accelerometers' common lag out
            // before the diagnosis (since 2026-11-29; before, the clean pair read 1.2 ms here).
            assert!(before.abs() < 0.3e-3, "package {}: the clean lag {before}", m + 1);
            assert!(
                named.contains(&Some(m)),
                "package {} named after {value} s: {named:?} {:?}",
                m + 1,
                with.not_named
            );
            // The criterion: the injected magnitude within its sigma, on top of the clean pair's value.
            let moved = after - before;
            let want = if value.starts_with('-') { -1.2e-3 } else { 1.2e-3 };
            assert!((moved - want).abs() < w.sigma[m], "package {}: moved {moved} s +- {}", m + 1, w.sigma[m]);
        }
    }
}

/// `--report` on recordings: the page has the gap after each addition, the effects, the rank tests, the
/// sensing points and the residual figure (rate, input level, time), and the figure has data.
///
/// Issue 30 item 7, on the same recordings: `calibrate` and `diagnose` give the rotation phase's gap one
/// name and one number (before, "dynamic chi2/dof 1811" in one and "dynamic 833.9" in the other for
/// recording 1): the diagnosis's gap after the sample clocks is calibrate's rotation-phase chi2/dof, and
/// a held-out recording's gap is calibrate's held-out one; both end with the same verdict per parameter
/// kind; the sensing points' differences are labelled with their accelerometers and axes.
#[test]
fn diagnose_writes_a_report_for_recordings() {
    let dir = tempfile::tempdir().unwrap();
    let html = dir.path().join("diagnose.html");
    let diagnosis_json = dir.path().join("diagnose.json");
    let calibration_json = dir.path().join("calibrate.json");
    let o = gfcal(&[
        "diagnose",
        real(1).to_str().unwrap(),
        "--array",
        ARRAY,
        "--held-out",
        real(2).to_str().unwrap(),
        "--report",
        html.to_str().unwrap(),
        "--json",
        diagnosis_json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let diagnose_text = String::from_utf8_lossy(&o.stdout).to_string();
    let page = std::fs::read_to_string(&html).unwrap();
    for says in [
        "Gap after each addition",
        "Effects named",
        "Rank tests",
        "Sensing points inside each package",
        "dynamic residual RMS against the rate",
        "dynamic residual RMS against the input level",
        "static interval means against time",
        "bias_turn_on",
        "Assessment: what to trust",
        "rotation-phase chi2/dof",
        "a2 - a1: x ",
    ] {
        assert!(page.contains(says), "{says} missing");
    }
    assert!(page.matches("<circle").count() > 50, "the residual figure has its points");

    // `diagnose` diagnoses the recording as it is (its library tests the bias drift in time): the
    // same baseline is `calibrate --keep-bias-drift`.
    let o = gfcal(&[
        "calibrate",
        real(1).to_str().unwrap(),
        "--array",
        ARRAY,
        "--keep-bias-drift",
        "--held-out",
        real(2).to_str().unwrap(),
        "--json",
        calibration_json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let calibrate_text = String::from_utf8_lossy(&o.stdout).to_string();
    for text in [&diagnose_text, &calibrate_text] {
        assert!(text.contains("rotation-phase chi2/dof"), "{text}");
        assert!(!text.contains("dynamic: (residual RMS"), "{text}");
    }
    let read = |p: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    };
    let (d, c) = (read(&diagnosis_json), read(&calibration_json));
    let calibrated = c["dynamic"]["chi2_dof"].as_f64().expect("calibrate's rotation-phase chi2/dof");
    let after_clocks = d["fitting_after_each"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["effect"] == "sample_clock")
        .expect("sample_clock named on recording 1 (results/mimu4444/discrepancy/clock_effect.md)");
    let diagnosed = after_clocks["dynamic_gap"].as_f64().unwrap();
    assert!((diagnosed / calibrated - 1.0).abs() < 1e-12, "diagnose {diagnosed}, calibrate {calibrated}");
    let held_calibrated = c["held_out"][0]["dynamic_chi2_dof"].as_f64().unwrap();
    let held_diagnosed = d["held_out"][0]["dynamic_gap_before"].as_f64().unwrap();
    assert!((held_diagnosed / held_calibrated - 1.0).abs() < 1e-12, "{held_diagnosed} against {held_calibrated}");
    // One verdict: the same kinds and the same answers.
    let verdicts = |v: &serde_json::Value| -> Vec<(String, bool)> {
        v["assessment"]
            .as_array()
            .expect("assessment")
            .iter()
            .map(|a| (a["kind"].as_str().unwrap().to_string(), a["trustworthy"].as_bool().unwrap()))
            .collect()
    };
    assert_eq!(verdicts(&d), verdicts(&c));
    assert!(verdicts(&d).iter().any(|(k, t)| k == "locations" && !t), "{:?}", verdicts(&d));
    assert!(diagnose_text.contains("assessment of the fitting recording's calibration:"));
    // Labelled sensing points: package 1 holds accelerometers 1-3, each further one against the first.
    let offsets = d["sensing_points"][0]["offsets"].as_array().expect("offsets");
    assert_eq!(offsets.len(), 2);
    assert_eq!((offsets[0]["accelerometer"].as_u64(), offsets[0]["minus"].as_u64()), (Some(2), Some(1)));
    for axis in ["x", "y", "z"] {
        assert!(offsets[1]["difference_m"][axis].is_f64() && offsets[1]["sigma_m"][axis].is_f64());
    }
}

/// Item 5 for `--use-gyro`: the gyroscopes' own scale and misalignment, `G_xy = G_zz = 1.5e-2`, added by
/// `gfcal inject --effect gyro_scale_misalignment` to the gyroscope columns of real recordings 2 and 3 (the
/// expectation was written before the first run: `results/mimu4444/discrepancy/EXPECTATIONS.md`, last
/// section). The effect is named, and the change of its seen part (symmetric, traceless: the antisymmetric part is
/// a rotation of the accelerometers and the trace a size, 4 of 9 unseen) from the clean pair equals the injected
/// one's within one sigma of each element, the sigma of that combination from the effect's covariance.
///
/// It failed at first (xx's seen part changed by -2.42e-2 against -5.0e-3 +- 4.1e-3, static chi2/dof 3.0 -> 185):
/// the array file's gyroscope range, 34.9 rad/s, was above the part's rail (34.87), so no railed rate was
/// censored, and `inject` moved the railed rates inside the range. With both mended (sixth session; expectations
/// in EXPECTATIONS.md, "Censored samples un-censored", written before the re-run): every element within 0.06
/// sigma, static chi2/dof 2.142 clean and injected.
#[test]
#[ignore = "slow: about 1.5 minutes (--use-gyro diagnoses of real recordings); run with --ignored (docs/testing.md)"]
fn gyroscope_scale_and_misalignment_injected_into_real_recordings_are_named_and_recovered() {
    use nalgebra::{DVector, Matrix3};
    let value = 1.5e-2;
    let steps: [Step; 2] = [
        ("gyro_scale_misalignment", ["--element", "xy"], "1.5e-2"),
        ("gyro_scale_misalignment", ["--element", "zz"], "1.5e-2"),
    ];
    let (clean, with) = injected_pair(&steps, &CalibrateSettings { use_gyro: true, ..CalibrateSettings::default() });
    eprintln!("static chi2/dof: clean {}, injected {}", clean.fitting.static_chi2_dof, with.fitting.static_chi2_dof);
    // Expectation 1 (EXPECTATIONS.md, "Censored samples un-censored"): the injection leaves the fit's static gap
    // within 2x of the clean one's.
    assert!(with.fitting.static_chi2_dof < 2.0 * clean.fitting.static_chi2_dof);
    assert!(with.findings.iter().any(|f| f.name == "gyro_scale_misalignment"), "{:?}", with.not_named);
    let (w, c) = (tried(&with, "gyro_scale_misalignment"), tried(&clean, "gyro_scale_misalignment"));
    assert_eq!(w.unseen, 4);
    let mut g = Matrix3::zeros();
    g[(0, 1)] = value;
    g[(2, 2)] = value;
    // The symmetric traceless part of a 3 x 3 matrix, element (a, b), as a row on its 9 elements (row-major).
    let seen = |a: usize, b: usize| {
        DVector::from_fn(9, |i, _| {
            let (r, s) = (i / 3, i % 3);
            let sym = 0.5 * (f64::from(r == a && s == b) + f64::from(r == b && s == a));
            sym - if a == b && r == s { 1.0 / 3.0 } else { 0.0 }
        })
    };
    let extra = DVector::from_column_slice(&w.value) - DVector::from_column_slice(&c.value);
    let cov = &w.covariance;
    let truth = DVector::from_column_slice(g.transpose().as_slice());
    for (a, b) in [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)] {
        let l = seen(a, b);
        let (got, want) = (l.dot(&extra), l.dot(&truth));
        let sigma = (l.transpose() * cov * &l)[(0, 0)].sqrt();
        eprintln!("seen part ({a}, {b}): {got:.3e} against {want:.3e} +- {sigma:.2e}");
        assert!((got - want).abs() < sigma, "seen part ({a}, {b}): {got} against {want} +- {sigma}");
    }
}
