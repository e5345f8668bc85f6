//! `gfcal diagnose` on recordings (issue 11): the baseline's gap on the fitting and held-out
//! recordings, and the per-recording turn-on bias, on simulated recordings whose truth comes from
//! the protocol simulator (not from the refit) and on the six real recordings.

use std::path::PathBuf;

use gfcal::discrepancy::diagnose::Explanation;
use gfcal::discrepancy::recorded::{RecordedDiagnosis, diagnose_recordings};
use gfcal::rng::trial_rng;
use gfcal::selfcal::calibrate::CalibrateSettings;
use gfcal::selfcal::model::SensorSet;
use gfcal::selfcal::recording::{Recording, RecordingArray};
use gfcal::selfcal::simulate::{random_truth, simulate};

use super::selfcal::{mimu_array, protocol};

fn truth(array: &RecordingArray) -> SensorSet {
    random_truth(&array.array, 0.005, 0.3, 0.004, 0.5e-3, &mut trial_rng(21, 0))
}

fn recording(array: &RecordingArray, truth: &SensorSet, seed: u64) -> Recording {
    simulate(array, truth, &protocol(array.array.len()), &mut trial_rng(seed, 1)).expect("simulated").recording
}

fn diagnose(fitting: &Recording, array: &RecordingArray, held: &[Recording]) -> RecordedDiagnosis {
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
}

fn real(k: usize) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("../shared/data/mimu4444/recording_{k}.parquet"))
}

/// The real board: fitted on recording 1, scored on recordings 2-6. The criteria are those of
/// results/mimu4444/discrepancy/EXPECTATIONS.md, written before the first run.
#[test]
fn real_recordings_name_a_turn_on_bias_that_holds_up_on_every_held_out_recording() {
    let array = mimu_array();
    let fitting = Recording::read(&real(1), &array).expect("recording 1");
    let held: Vec<Recording> = (2..=6).map(|k| Recording::read(&real(k), &array).expect("recording")).collect();
    let d = diagnose(&fitting, &array, &held);
    let names: Vec<&str> = d.findings.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["bias_turn_on"]);
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
    let array = mimu_array();
    let fitting = Recording::read(&real(1), &array).unwrap();
    let clean = Recording::read(&real(2), &array).unwrap();
    let with = Recording::read(&injected, &array).unwrap();
    let d = diagnose(&fitting, &array, &[clean, with]);
    assert_eq!(d.findings.iter().map(|f| f.name.as_str()).collect::<Vec<_>>(), ["bias_turn_on"]);
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
    for (o, says) in [
        (run("warp_drive", "1", "1"), "unknown effect `warp_drive` (known: bias_turn_on"),
        (run("bias_turn_on", "25", "1"), "25 is not an accelerometer"),
        (run("bias_turn_on", "0", "1"), "0 is not an accelerometer"),
        (run("bias_turn_on", "1", "nan"), "--value: must be a finite number"),
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
                // Between samples i-1 and i: 4 ms back of a 16 ms period is a quarter of the way.
                _ => table.data[col][i] + 0.25 * (table.data[col][i - 1] - table.data[col][i]),
            };
            assert!((y - want).abs() < 1e-12, "{effect} at row {i}: {y} against {want}");
        }
    }
}
