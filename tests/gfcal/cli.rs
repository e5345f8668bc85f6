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

/// An output into a folder that does not exist is refused before the work (issue 30: it used to
/// be computed, then fail with exit 1).
#[test]
fn unwritable_csv_is_refused_without_partial_file() {
    let o = gfcal(&["drift", PAPER, "--csv", "/nonexistent-dir/drift.csv"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("/nonexistent-dir/drift.csv") && stderr(&o).contains("--csv"));
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

const DESIGN: &str = "configs/hung_lee_2006_design.toml";

fn design_with(from: &str, to: &str) -> String {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(DESIGN)).unwrap();
    assert!(text.contains(from), "the design config has `{from}`");
    text.replacen(from, to, 1)
}

/// The design config with the preset replaced by explicit steps (after the [schedule] keys).
fn design_with_steps(steps: &str) -> String {
    design_with("preset = \"hung_lee_2006\"\n", "").replacen(
        "sample_rate_hz = 100.0\n",
        &format!("sample_rate_hz = 100.0\n{steps}"),
        1,
    )
}

fn refused_cmd(cmd: &str, text: &str, words: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let path = config(dir.path(), text);
    let o = gfcal(&[cmd, path.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(path.to_str().unwrap()), "names the file: {err}");
    for w in words {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
}

#[test]
fn identify_names_the_weak_location_components() {
    let o = gfcal(&["identify", DESIGN]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let weak: Vec<&str> = out.lines().filter(|l| l.contains("x target")).collect();
    assert_eq!(weak.len(), 6, "{out}");
    for name in ["a1.dz", "a2.dy", "a3.dx", "a4.dx", "a5.dy", "a6.dz"] {
        assert!(weak.iter().any(|l| l.ends_with(&format!("1.000 {name}"))), "{name}: {out}");
    }
}

#[test]
fn design_adds_the_augmented_spins_and_meets_the_targets() {
    let o = gfcal(&["design", DESIGN]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("Steps added (2):"), "{out}");
    assert!(out.contains("spin about [0.0000, 0.7071, 0.7071] at 12.5664 rad/s, + end up"), "{out}");
    assert!(out.contains("Every Cramer-Rao sigma is below its target with 17 steps."), "{out}");
}

#[test]
fn paper_writes_both_tables() {
    let dir = tempfile::tempdir().unwrap();
    let o = gfcal(&["paper", "--out", dir.path().to_str().unwrap(), "--trials", "50"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for (name, rows) in [("table8.csv", 24), ("table9.csv", 18)] {
        let text = std::fs::read_to_string(dir.path().join(name)).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "parameter,accelerometer,unit,true,paper,paper_model,noise_free,mc_mean,mc_std,crb_sigma,augmented_mc_std,augmented_crb_sigma"
        );
        assert_eq!(lines.len(), 1 + rows, "{name}");
    }
    let t9 = std::fs::read_to_string(dir.path().join("table9.csv")).unwrap();
    let a1_dz: Vec<&str> = t9.lines().find(|l| l.starts_with("dz,1,mm")).unwrap().split(',').collect();
    let v = |k: usize| a1_dz[k].parse::<f64>().unwrap();
    assert_eq!((v(3), v(4)), (0.6, 8.91), "truth and the paper's value");
    assert!((v(5) - 0.6).abs() < 1e-9, "the paper_model hypothesis: exact locations");
    assert!((v(6) - 0.6).abs() < 1e-9, "noise-free recovery");
    assert!(v(9) > 1.5 && v(11) < 0.05, "weak on the paper's schedule, fixed by the augmented one");
    for f in ["table8.md", "table9.md", "table9_from_table8.csv", "settings.json"] {
        assert!(dir.path().join(f).exists(), "{f}");
    }
}

#[test]
fn bad_calibration_configs_are_refused() {
    refused_cmd("identify", &design_with("white_density_ug_per_sqrt_hz = 50.0", ""), &["noise", "white noise level"]);
    refused_cmd(
        "identify",
        &design_with("preset = \"hung_lee_2006\"", "preset = \"hung_lee\""),
        &["schedule.preset", "unknown preset"],
    );
    refused_cmd("identify", &design_with("preset = \"hung_lee_2006\"", ""), &["schedule", "no steps"]);
    refused_cmd(
        "identify",
        &design_with("spin_rate_rad_s = 6.283185307179586", "spin_rate_rad_s = 0.0"),
        &["schedule.spin_rate_rad_s", "non-zero rate"],
    );
    refused_cmd("design", &design_with("max_added_steps = 12", "max_added_steps = 0"), &["design.max_added_steps"]);
    refused_cmd(
        "identify",
        &design_with("location_mm = 0.1", "location_mm = -0.1"),
        &["targets.location_mm", "positive"],
    );
    let steps = "[[schedule.step]]\nkind = \"static\"\nup = [0.0, 0.0, 0.0]\n";
    refused_cmd("identify", &design_with_steps(steps), &["schedule.step[0].up", "not a direction"]);
    let spin = "[[schedule.step]]\nkind = \"spin\"\naxis = [1.0, 0.0, 0.0]\nrate_rad_s = 0.0\nup_end = \"negative\"\n";
    refused_cmd("identify", &design_with_steps(spin), &["schedule.step[0].rate_rad_s", "non-zero rate"]);
    let no_end = "[[schedule.step]]\nkind = \"spin\"\naxis = [1.0, 0.0, 0.0]\n";
    refused_cmd("identify", &design_with_steps(no_end), &["schedule.step[0].up_end", "required"]);
}

#[test]
fn explicit_schedule_in_toml_works() {
    // The paper's twelve static poses written out, plus three spins: the same answer as the preset.
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let mut steps = String::new();
    for up in [[-s, 0.0, s], [s, 0.0, s], [0.0, s, s], [0.0, -s, s], [s, s, 0.0], [-s, s, 0.0]] {
        for sign in [1.0, -1.0] {
            steps.push_str(&format!(
                "[[schedule.step]]\nkind = \"static\"\nup = [{}, {}, {}]\n",
                sign * up[0],
                sign * up[1],
                sign * up[2]
            ));
        }
    }
    for axis in ["[1, 0, 0]", "[0, 1, 0]", "[0, 0, 1]"] {
        steps.push_str(&format!("[[schedule.step]]\nkind = \"spin\"\naxis = {axis}\nup_end = \"negative\"\n"));
    }
    let dir = tempfile::tempdir().unwrap();
    let path = config(dir.path(), &design_with_steps(&steps));
    let o = gfcal(&["identify", path.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let preset = gfcal(&["identify", DESIGN]);
    let body = |o: &Output| String::from_utf8_lossy(&o.stdout).lines().skip(1).collect::<Vec<_>>().join("\n");
    assert_eq!(body(&o), body(&preset));
}

#[test]
fn simulate_log_then_diagnose_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("log.parquet");
    let o = gfcal(&["simulate-log", "configs/discrepancy_example.toml", "--out", log.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("effects hidden: scale_factor_quadratic"));
    let json = dir.path().join("d.json");
    let o = gfcal(&["diagnose", log.to_str().unwrap(), "--json", json.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("scale_factor_quadratic on accelerometer 3"), "{out}");
    let d: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let effects = d["effects"].as_array().unwrap();
    assert_eq!(effects.len(), 1);
    assert_eq!(effects[0]["name"], "scale_factor_quadratic");
    assert_eq!(effects[0]["accelerometer"], 3);
    for key in ["value", "sigma", "unit"] {
        assert!(!effects[0][key].is_null(), "{key}");
    }
    assert!(d["gap_before"].as_f64().unwrap() > 3.0 && d["gap_after"].as_f64().unwrap() < 1.5);
    assert_eq!(d["per_step"].as_array().unwrap().len(), 15);
}

#[test]
fn bad_logs_and_short_logs_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "step,t_s,up_x\n1,0,1\n").unwrap();
    let o = gfcal(&["diagnose", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("bad.csv: missing column(s): up_y, up_z"), "{}", stderr(&o));
    // A log of the first five steps only: refused with the number of steps it needs.
    let full = dir.path().join("full.csv");
    assert!(
        gfcal(&["simulate-log", "configs/discrepancy_example.toml", "--out", full.to_str().unwrap()]).status.success()
    );
    let text = std::fs::read_to_string(&full).unwrap();
    let short: String = text
        .lines()
        .filter(|l| l.split(',').next().is_some_and(|s| s == "step" || s.parse::<i64>().is_ok_and(|v| v <= 5)))
        .map(|l| format!("{l}\n"))
        .collect();
    let short_path = dir.path().join("short.csv");
    std::fs::write(&short_path, short).unwrap();
    let o = gfcal(&["diagnose", short_path.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("the log has 5 steps; the baseline fit needs at least 8"), "{}", stderr(&o));
    // A 9-accelerometer array against a 6-output log.
    let o = gfcal(&["diagnose", full.to_str().unwrap(), "--array", "configs/arrays/nine.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("6 outputs (s1..s6) but the array has 9"), "{}", stderr(&o));
    // A temperature effect without a temperature profile.
    let cfg =
        std::fs::read_to_string("configs/discrepancy_example.toml").unwrap() + "bias_temperature_ug_per_c = 5.0\n";
    let p = dir.path().join("t.toml");
    std::fs::write(&p, cfg).unwrap();
    let o = gfcal(&["simulate-log", p.to_str().unwrap(), "--out", dir.path().join("x.csv").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("effects.bias_temperature_ug_per_c") && stderr(&o).contains("[temperature]"),
        "{}",
        stderr(&o)
    );
    assert!(!dir.path().join("x.csv").exists());
}

/// Issue 13: `gfcal check` validates any config without running it and says whose it is; a
/// command given another command's config says so instead of failing on its first unknown key
/// (`run configs/paper_manoeuvre.toml` said "expected struct DistEntry in errors.bias_mg").
#[test]
fn check_names_the_command_of_every_shipped_config_and_commands_name_the_right_one() {
    for (file, command) in [
        ("configs/quickstart.toml", "`gfcal run`"),
        ("configs/paper_manoeuvre.toml", "`gfcal drift`"),
        ("configs/hung_lee_2006_design.toml", "`gfcal identify / gfcal design`"),
        ("configs/discrepancy_example.toml", "`gfcal simulate-log`"),
        ("configs/arrays/mimu4444_corners.toml", "an array file"),
    ] {
        let o = gfcal(&["check", file]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{file}: {}", stderr(&o));
        assert!(out.contains(file) && out.contains(command), "{file}: {out}");
    }
    let o = gfcal(&["run", "configs/paper_manoeuvre.toml", "--out", "/nonexistent/never-written"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("a config for `gfcal drift`, not for `gfcal run`"), "{}", stderr(&o));
    let o = gfcal(&["drift", "configs/quickstart.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("a config for `gfcal run`, not for `gfcal drift`"), "{}", stderr(&o));
    // A broken config: exit 2 naming the file and the key, nothing run.
    let dir = tempfile::tempdir().unwrap();
    let bad = config(dir.path(), &paper_with("[navigation]", "[navigation]\nstep_s = -1.0\n"));
    let o = gfcal(&["check", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains(bad.to_str().unwrap()) && stderr(&o).contains("step_s"), "{}", stderr(&o));
}

/// Issue 13: configs that cannot finish or that would be adjusted silently are refused with the
/// key and the estimate: horizons of 1e9 s, a step of 1e-12 s, a step longer than every horizon,
/// a step duration shorter than one sample.
#[test]
fn endless_and_silently_adjusted_configs_are_refused() {
    for (from, to, words) in [
        (
            "horizons_s = [0.5, 1, 2, 5, 10]",
            "horizons_s = [1e9]",
            &["navigation.horizons_s", "steps per navigation"][..],
        ),
        ("step_s = 0.001", "step_s = 1e-12", &["navigation.horizons_s", "steps per navigation"][..]),
        ("step_s = 0.001", "step_s = 20.0", &["navigation.step_s", "longer than every horizon"][..]),
    ] {
        refused(&paper_with(from, to), words);
    }
    let design = design_with("step_duration_s = 1.0", "step_duration_s = 0.001");
    refused_cmd("identify", &design, &["schedule.step_duration_s", "less than one sample"]);
}

/// Issue 13's messages: `simulate-log` into a missing folder says it cannot write (it said
/// "cannot read"), once, naming the file; since issue 30, before the work (exit 2).
#[test]
fn simulate_log_into_a_missing_folder_says_it_cannot_write() {
    for name in ["log.csv", "log.parquet"] {
        let out = format!("/nonexistent-gfcal-folder/{name}");
        let o = gfcal(&["simulate-log", "configs/discrepancy_example.toml", "--out", &out]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(&out) && err.contains("cannot write") && !err.contains("cannot read"), "{err}");
        assert!(err.matches("No such file or directory").count() <= 1, "{err}");
    }
}

/// No command writes over a file it reads, however the output is spelled (through `..` or a link), and
/// no two outputs of one command are one file: exit code 2, the flag, both files named, and the input left
/// byte for byte. (`gfcal inject --out` naming its own recording used to replace the recording.)
#[test]
fn an_output_over_an_input_is_refused_and_the_input_is_left_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("sub")).unwrap();
    let recording = d.join("r.csv");
    std::fs::write(&recording, "t_s,acc1_x_m_s2\n0,1\n").unwrap();
    let config = d.join("c.toml");
    std::fs::write(&config, "not read\n").unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(&recording, d.join("link.csv")).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let via_dots = s(&d.join("sub").join("..").join("r.csv"));
    let array = "configs/arrays/mimu4444_corners.toml";
    let (r, c) = (s(&recording), s(&config));
    let a = s(&d.join("a.json"));
    let inject = |out: &str| {
        let args = ["inject", &r, "--array", array, "--effect", "bias_turn_on", "--accelerometer", "1", "--value", "1"];
        args.iter().chain(&["--out", out]).map(|a| a.to_string()).collect::<Vec<String>>()
    };
    let owned = |args: &[&str]| args.iter().map(|a| a.to_string()).collect::<Vec<String>>();
    let mut cases: Vec<(Vec<String>, &str, &str)> = vec![
        (inject(&via_dots), "--out", &r),
        (owned(&["calibrate", &r, "--array", array, "--json", &r]), "--json", &r),
        (owned(&["calibrate", &r, "--array", array, "--json", &a, "--report", &a]), "--json and --report", &a),
        (owned(&["diagnose", &c, "--array", array, "--held-out", &r, "--report", &via_dots]), "--report", &r),
        (owned(&["simulate-log", &c, "--out", &c]), "--out", &c),
        (owned(&["drift", &c, "--csv", &c]), "--csv", &c),
    ];
    let link = s(&d.join("link.csv"));
    if cfg!(unix) {
        cases.push((inject(&link), "--out", &r));
    }
    for (args, flag, named) in cases {
        let o = gfcal(&args.iter().map(String::as_str).collect::<Vec<_>>());
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(flag) && err.contains(named), "{args:?}: names {flag} and {named}: {err}");
    }
    assert_eq!(std::fs::read_to_string(&recording).unwrap(), "t_s,acc1_x_m_s2\n0,1\n");
    assert_eq!(std::fs::read_to_string(&config).unwrap(), "not read\n");
    assert!(!d.join("a.json").exists());
}

/// Issue 30, item 5: `calibrate --json` into a folder that could not be written fitted everything,
/// then exited 1 and skipped the writable `--report`. Every output path and `--out` folder is
/// checked before any data is read: exit 2 naming the flag and the path, nothing written. The
/// unwritable places hold as root too: a path under a regular file, and /proc (which no one can
/// create files in).
#[test]
fn outputs_are_checked_before_the_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let file = d.join("plain-file");
    std::fs::write(&file, "a file, not a folder\n").unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let under_file = |name: &str| s(&file.join(name));
    let in_proc = |name: &str| format!("/proc/gfcal-test-{}-{name}", std::process::id());
    let good = |name: &str| s(&d.join(name));
    let recording = s(&crate::common::shared_dir().join("data/mimu4444/recording_1.parquet"));
    let missing = good("no-such-input.csv");
    let array = "configs/arrays/mimu4444_corners.toml";
    // (arguments, the flag and path the message must name, outputs that must not appear)
    let mut cases: Vec<(Vec<String>, String, String, Vec<String>)> = Vec::new();
    let mut add = |args: Vec<String>, flag: &str, path: String, absent: Vec<String>| {
        cases.push((args, flag.to_string(), path, absent))
    };
    let v = |a: &[&str]| a.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    for bad in [under_file("r.json"), in_proc("r.json")] {
        // The case: a real recording, fitted for seconds before the JSON failed.
        add(
            v(&["calibrate", &recording, "--array", array, "--json", &bad, "--report", &good("r.html")]),
            "--json",
            bad.clone(),
            vec![good("r.html")],
        );
        add(
            v(&["calibrate", &missing, "--array", array, "--json", &good("c.json"), "--report", &bad]),
            "--report",
            bad.clone(),
            vec![good("c.json")],
        );
        add(
            v(&["diagnose", &missing, "--json", &good("d.json"), "--report", &bad]),
            "--report",
            bad.clone(),
            vec![good("d.json")],
        );
        add(
            v(&["diagnose", &missing, "--array", array, "--json", &bad, "--report", &good("d.html")]),
            "--json",
            bad.clone(),
            vec![good("d.html")],
        );
        add(v(&["drift", PAPER, "--csv", &bad]), "--csv", bad.clone(), vec![]);
        add(v(&["simulate-log", "configs/discrepancy_example.toml", "--out", &bad]), "--out", bad.clone(), vec![]);
        add(
            v(&[
                "inject",
                &missing,
                "--array",
                array,
                "--effect",
                "bias_turn_on",
                "--accelerometer",
                "1",
                "--value",
                "1",
                "--out",
                &bad,
            ]),
            "--out",
            bad.clone(),
            vec![],
        );
    }
    for bad in [under_file("paper"), in_proc("paper")] {
        add(v(&["paper", "--out", &bad, "--trials", "2"]), "--out", bad, vec![]);
    }
    for bad in [under_file("run"), in_proc("run")] {
        add(v(&["run", "configs/quickstart.toml", "--out", &bad]), "--out", bad, vec![]);
    }
    for (args, flag, path, absent) in &cases {
        let o = gfcal(&args.iter().map(String::as_str).collect::<Vec<_>>());
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(flag.as_str()) && err.contains(path.as_str()), "{args:?}: names {flag} and {path}: {err}");
        assert!(!err.contains(&missing), "{args:?}: refused before reading the input: {err}");
        for a in absent {
            assert!(!Path::new(a).exists(), "{args:?}: {a} written");
        }
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "a file, not a folder\n");
    let left: Vec<_> = std::fs::read_dir(d).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(left.len(), 1, "nothing but the plain file: {left:?}");
}
