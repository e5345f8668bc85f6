//! `gfcal run` on a hand-held protocol (`[protocol]`, `mc::protocol`): the MIMU4444 array file,
//! simulated recordings calibrated gyroscope-free, the bound at each truth; and bad protocol
//! configs refused naming the key.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shipped protocol config, shortened (8 poses of 9 s on 8 of its directions, 20 s of
/// rotation, 3 trials) and
/// without its sample clocks (the vibration and the filters kept: the clocks' estimation in each
/// trial's calibration would treble the test's time; tests/gfcal/simulate.rs checks the clocks'
/// generator), written beside the shipped one so that its array file resolves.
fn short_protocol(dir: &Path, edit: impl Fn(String) -> String) -> PathBuf {
    let text = std::fs::read_to_string(repo().join("configs/mimu4444_protocol.toml")).unwrap();
    // The 8 of the board's 20 pose directions that are a cube's vertices (for 8 poses; the first
    // 8 all lie below y = 0 and leave the y axes' scale factors weak).
    let cube = [1, 3, 5, 7, 10, 12, 15, 17];
    let (mut in_poses, mut listed) = (false, 0);
    let text: String = text
        .lines()
        .filter(|l| {
            if l.starts_with("pose_up = [") {
                in_poses = true;
                return true;
            }
            if in_poses && l.starts_with("    [") {
                listed += 1;
                return cube.contains(&(listed - 1));
            }
            in_poses = false;
            true
        })
        .filter(|l| !l.starts_with("clock_"))
        .map(|l| if l.starts_with("sample_clocks") { "sample_clocks = false" } else { l })
        .collect::<Vec<_>>()
        .join("\n");
    assert!(text.contains("sample_clocks = false"), "the shipped config has sample clocks");
    let text = text
        .replace("trials_per_cell = 100", "trials_per_cell = 3")
        .replace("poses = 20", "poses = 8")
        .replace("pose_s = 22.0", "pose_s = 9.0")
        .replace("dynamic_s = 100.0", "dynamic_s = 20.0")
        .replace(
            "file = \"arrays/mimu4444_corners.toml\"",
            &format!("file = \"{}\"", repo().join("configs/arrays/mimu4444_corners.toml").display()),
        );
    let path = dir.join("protocol.toml");
    std::fs::write(&path, edit(text)).unwrap();
    path
}

fn run(config: &Path, out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gfcal")).arg("run").arg(config).arg("--out").arg(out).output().unwrap()
}

#[test]
fn a_protocol_run_calibrates_every_trial_and_records_the_bound_of_every_parameter() {
    let dir = tempfile::tempdir().unwrap();
    let config = short_protocol(dir.path(), |t| t);
    let out = run(&config, &dir.path().join("out"));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary = std::fs::read_to_string(dir.path().join("out/summary.csv")).unwrap();
    let rows: Vec<Vec<&str>> =
        summary.lines().skip(1).map(|l| l.split(',').collect()).filter(|r: &Vec<&str>| r[0] == "parameter").collect();
    assert_eq!(rows.len(), 24 * 7, "every parameter of the 24 accelerometers");
    for r in &rows {
        let (n, crb): (usize, f64) = (r[4].parse().unwrap(), r[7].parse().unwrap());
        assert_eq!(n, 3, "{}: every trial estimated", r[2]);
        // A bound of a few times 1e-5 (scale factor, rad) to 1e-3 (bias, m/s^2; location, m).
        assert!(crb.is_finite() && crb > 1e-7 && crb < 1e-2, "{}: crb_sigma {crb}", r[2]);
    }
}

#[test]
fn bad_protocols_are_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    // The shipped config's sensor error in bursts, as it writes it.
    const BURSTS: &str = "vibration_sensor_burst_duty = 0.01\nvibration_sensor_burst_s = 0.05";
    const SENSOR_ERROR: &str =
        "vibration_sensor_rms_m_s2 = 0.5\nvibration_sensor_burst_duty = 0.01\nvibration_sensor_burst_s = 0.05";
    let cases: [(&str, &str, &str); 25] = [
        ("pose_up = [\n", "pose_up = [\n    [0.0, 0.0, 1.0],\n", "protocol.pose_up"),
        (
            "bias_drift_ug_per_s = { dist = \"normal\", sigma = 1.52 }",
            "bias_drift_ug_per_s = { dist = \"fixed\", value = [1.0, 2.0] }",
            "protocol.bias_drift_ug_per_s.value",
        ),
        (
            "common_bias_drift_ug_per_s = { dist = \"normal\", mean = -1.64, sigma = 1.06 }",
            "common_bias_drift_ug_per_s = { dist = \"normal\", mean = -1.64, sigma = -1.06 }",
            "protocol.common_bias_drift_ug_per_s.sigma",
        ),
        ("pose_s = 9.0", "pose_s = 3.0", "protocol.pose_s"),
        ("vibration_band_hz = [2.0, 90.0]", "vibration_band_hz = [90.0, 2.0]", "protocol.vibration_band_hz"),
        (
            "vibration_rate_band_hz = [3.0, 25.0]",
            "vibration_rate_band_hz = [3.0, 2000.0]",
            "protocol.vibration_rate_band_hz",
        ),
        ("vibration_rate_exponent = 2.0", "vibration_rate_exponent = -1.0", "protocol.vibration_rate_exponent"),
        ("vibration_sensor_rms_m_s2 = 0.5", "vibration_sensor_rms_m_s2 = -0.3", "protocol.vibration_sensor_rms_m_s2"),
        (BURSTS, "vibration_sensor_rate_exponent = -2.0", "protocol.vibration_sensor_rate_exponent"),
        (BURSTS, "vibration_sensor_rate_exponent = 17.0", "protocol.vibration_sensor_rate_exponent"),
        (SENSOR_ERROR, "vibration_sensor_rate_exponent = 8.0", "protocol.vibration_sensor_rate_exponent"),
        (BURSTS, "vibration_sensor_burst_duty = 0.01", "protocol.vibration_sensor_burst_s"),
        (BURSTS, "vibration_sensor_burst_s = 0.05", "protocol.vibration_sensor_burst_duty"),
        (
            BURSTS,
            "vibration_sensor_burst_duty = 0.0\nvibration_sensor_burst_s = 0.05",
            "protocol.vibration_sensor_burst_duty",
        ),
        (
            BURSTS,
            "vibration_sensor_burst_duty = 1.5\nvibration_sensor_burst_s = 0.05",
            "protocol.vibration_sensor_burst_duty",
        ),
        (
            BURSTS,
            "vibration_sensor_burst_duty = 0.01\nvibration_sensor_burst_s = -0.1",
            "protocol.vibration_sensor_burst_s",
        ),
        ("vibration_sensor_rms_m_s2 = 0.5\n", "", "protocol.vibration_sensor_burst_duty"),
        (
            BURSTS,
            "vibration_sensor_rate_exponent = 8.0\nvibration_sensor_burst_duty = 0.01\nvibration_sensor_burst_s = 0.05",
            "protocol.vibration_sensor_burst_duty",
        ),
        (
            "vibration_rate_low_pass_order = 3",
            "vibration_rate_low_pass_order = 4",
            "protocol.vibration_rate_low_pass_order",
        ),
        ("vibration_low_pass_order = 3", "vibration_low_pass_order = 1", "protocol.vibration_low_pass_order"),
        ("form = \"tilt\"", "form = \"triad\"", "calibration.form"),
        ("[protocol]", "[schedule]\npreset = \"hung_lee_2006\"\n\n[protocol]", "protocol"),
        ("use_gyro = false", "use_gyro = false\nposes_per_face = 2", "poses_per_face"),
        // beyond half the 16 ms sample interval, and not a number
        ("use_gyro = false", "use_gyro = false\naccelerometer_lag_ms = 9.0", "protocol.accelerometer_lag_ms"),
        ("use_gyro = false", "use_gyro = false\naccelerometer_lag_ms = nan", "protocol.accelerometer_lag_ms"),
    ];
    for (from, to, key) in cases {
        let config = short_protocol(dir.path(), |t| t.replace(from, to));
        let out = run(&config, &dir.path().join("bad"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{key}: {err}");
        assert!(err.contains(key) && err.contains("protocol.toml"), "{key}: {err}");
        assert!(!dir.path().join("bad").exists(), "nothing written for {key}");
    }
}
