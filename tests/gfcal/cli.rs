//! The `gfcal` binary: the shipped configs run; bad input exits with code 2 and a message naming
//! the file, the key and the problem, and writes nothing.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn gfcal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gfcal")).args(args).current_dir(env!("CARGO_MANIFEST_DIR")).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Writes `text` as a config in a fresh folder (with the nine-array file beside it).
fn config(dir: &Path, text: &str) -> PathBuf {
    let path = dir.join("bad.toml");
    std::fs::write(&path, text).unwrap();
    path
}

const PAPER: &str = "configs/paper_manoeuvre.toml";

fn paper_with(from: &str, to: &str) -> String {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(PAPER)).unwrap();
    assert!(text.contains(from), "the paper config has `{from}`");
    text.replacen(from, to, 1)
}

/// Runs `drift` on a config text and checks exit code 2, the file and the words of the message.
fn refused(text: &str, words: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let path = config(dir.path(), text);
    let csv = dir.path().join("out.csv");
    let o = gfcal(&["drift", path.to_str().unwrap(), "--csv", csv.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(path.to_str().unwrap()), "names the file: {err}");
    for w in words {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(!csv.exists(), "nothing written");
}

#[test]
fn paper_config_runs_and_writes_csv() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("drift.csv");
    let o = gfcal(&["drift", PAPER, "--csv", csv.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "compensation,horizon_s,rate_err_rad_s,attitude_err_rad,velocity_err_m_s,position_err_m");
    assert_eq!(lines.len(), 1 + 2 * 5);
    for line in &lines[1..] {
        let cols: Vec<&str> = line.split(',').collect();
        let values: Vec<f64> = cols[2..].iter().map(|c| c.parse().unwrap()).collect();
        match cols[0] {
            "true" => assert!(values.iter().all(|v| *v < 1e-6), "{line}"),
            "nominal" => assert!(values.iter().all(|v| *v > 1e-3), "{line}"),
            other => panic!("unexpected compensation {other}"),
        }
    }
}

#[test]
fn nine_accelerometer_config_runs() {
    let o = gfcal(&["drift", "configs/nine_accelerometer.toml"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(out.lines().filter(|l| l.starts_with("true")).count(), 4);
}

#[test]
fn unknown_key_is_refused() {
    refused(&paper_with("bias_mg = 1.0", "bias_mg = 1.0\nbias_mgg = 2.0"), &["bias_mgg", "unknown field"]);
}

#[test]
fn non_finite_number_is_refused() {
    refused(&paper_with("bias_mg = 1.0", "bias_mg = nan"), &["errors.bias_mg[0]", "finite"]);
    refused(&paper_with("step_s = 0.001", "step_s = inf"), &["navigation.step_s", "finite"]);
}

#[test]
fn out_of_range_numbers_are_refused() {
    refused(&paper_with("rho_m = 0.1", "rho_m = -0.1"), &["array.rho_m", "positive"]);
    refused(&paper_with("step_s = 0.001", "step_s = 0.0"), &["navigation.step_s", "positive"]);
    refused(&paper_with("horizons_s = [0.5, 1, 2, 5, 10]", "horizons_s = []"), &["navigation.horizons_s"]);
    refused(
        &paper_with("scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]", "scale_factor = [0.5, 0.0, 0.5, 2.5, 2.5, 2.5]"),
        &["errors.scale_factor[1]", "zero"],
    );
}

#[test]
fn wrong_types_are_refused() {
    refused(&paper_with("bias_mg = 1.0", "bias_mg = \"x\""), &["line 13", "one value for every accelerometer"]);
}

#[test]
fn wrong_counts_are_refused() {
    refused(
        &paper_with("scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]", "scale_factor = [0.5, 2.5]"),
        &["errors.scale_factor", "one value per accelerometer (6), got 2"],
    );
}

#[test]
fn horizon_past_the_segments_is_refused() {
    let text = "[trajectory]\nkind = \"segments\"\n[[trajectory.segment]]\nduration_s = 2.0\n[navigation]\nstep_s = 0.01\nhorizons_s = [1, 3]\n";
    refused(text, &["navigation.horizons_s", "past the end of the segments"]);
}

fn array_file_refused(accelerometers: &str, words: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let array = dir.path().join("arr.toml");
    std::fs::write(&array, accelerometers).unwrap();
    let cfg = config(
        dir.path(),
        "[array]\nfile = \"arr.toml\"\n[trajectory]\nkind = \"rest\"\n[navigation]\nstep_s = 0.01\nhorizons_s = [1]\n",
    );
    let o = gfcal(&["drift", cfg.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(array.to_str().unwrap()), "names the array file: {err}");
    for w in words {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
}

fn cube_entries(axis_override: Option<(usize, &str)>) -> String {
    let cube = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/arrays/nine.toml")).unwrap();
    let mut blocks: Vec<String> =
        cube.split("[[accelerometer]]").skip(1).take(6).map(|b| format!("[[accelerometer]]{b}")).collect();
    if let Some((j, axis)) = axis_override {
        let start = blocks[j].find("axis = ").unwrap();
        let end = blocks[j][start..].find('\n').unwrap() + start;
        blocks[j].replace_range(start..end, &format!("axis = {axis}"));
    }
    blocks.join("")
}

#[test]
fn zero_length_axis_is_refused() {
    array_file_refused(&cube_entries(Some((3, "[0.0, 0.0, 0.0]"))), &["accelerometer[3].axis", "zero length"]);
}

#[test]
fn degenerate_array_is_refused() {
    // Accelerometer 6's axis made equal to accelerometer 1's: the cube loses a motion.
    array_file_refused(&cube_entries(Some((5, "[1.0, 1.0, 0.0]"))), &["degenerate array", "cannot sense"]);
}

#[test]
fn too_few_accelerometers_are_refused() {
    let five: String = cube_entries(None)
        .split("[[accelerometer]]")
        .skip(1)
        .take(5)
        .map(|b| format!("[[accelerometer]]{b}"))
        .collect();
    array_file_refused(&five, &["at least 6", "got 5"]);
}

#[test]
fn missing_config_is_refused() {
    let o = gfcal(&["drift", "configs/no_such_file.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("no_such_file.toml"));
}

#[test]
fn unwritable_csv_fails_without_partial_file() {
    let o = gfcal(&["drift", PAPER, "--csv", "/nonexistent-dir/drift.csv"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("/nonexistent-dir/drift.csv"));
}

const NOISE: &str = "[noise]\nseed = 7\nwhite_density_ug_per_sqrt_hz = 50.0\ngauss_markov_sigma_ug = 10.0\ngauss_markov_correlation_time_s = 100.0\nrandom_walk_ug_per_sqrt_s = 1.0\nquantization_ug = 1.0\n\n[trajectory]";

fn drift_stdout(text: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = config(dir.path(), text);
    let o = gfcal(&["drift", path.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn noise_is_reproducible_by_seed() {
    let noisy = paper_with("[trajectory]", NOISE);
    let a = drift_stdout(&noisy);
    assert_eq!(a, drift_stdout(&noisy), "same seed, same table");
    let other = drift_stdout(&noisy.replace("seed = 7", "seed = 8"));
    assert_ne!(a, other, "another seed, another realisation");
    // With noise, even true compensation drifts: rate error at 10 s well above the noise-free 1e-12.
    let true_10s: Vec<&str> =
        a.lines().filter(|l| l.starts_with("true") && l.split_whitespace().nth(1) == Some("10")).collect();
    let rate: f64 = true_10s[0].split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!(rate > 1e-6, "{}", true_10s[0]);
}

#[test]
fn bad_noise_is_refused() {
    refused(
        &paper_with("[trajectory]", "[noise]\nwhite_density_ug_per_sqrt_hz = -1.0\n[trajectory]"),
        &["noise.white_density_ug_per_sqrt_hz", "negative"],
    );
    refused(
        &paper_with("[trajectory]", "[noise]\nwhite_sigma_mg = 1.0\n[trajectory]"),
        &["noise.white_sample_rate_hz", "sample rate"],
    );
    refused(
        &paper_with("[trajectory]", "[noise]\ngauss_markov_sigma_ug = 1.0\n[trajectory]"),
        &["noise.gauss_markov_correlation_time_s"],
    );
}
