//! The batch engine: reproducible across threads and shards, resumable after a kill, every shipped
//! config valid, bad input refused with nothing written.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use arrow_array::RecordBatch;
use gfcal::io::parquet::{read_batches, read_metadata};
use gfcal::mc::{McConfig, RunOptions, Silent, run};

/// A small sweep: two noise levels x two schedules, a short navigation.
const SMALL: &str = r#"
name = "small"
seed = 7
trials_per_cell = 30

[errors]
nominal_scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]
bias_mg = { dist = "normal", sigma = 1.0 }
scale_factor_ppm = { dist = "uniform", half_width = 300.0 }
misalignment_deg = { dist = "normal", sigma = 0.5 }
location_mm = { dist = "normal", sigma = 1.0 }

[noise]
white_density_ug_per_sqrt_hz = 50.0

[schedule]
preset = "hung_lee_2006"
step_duration_s = 0.5
sample_rate_hz = 100.0

[trajectory]
kind = "paper_manoeuvre"

[navigation]
step_s = 0.02
horizons_s = [0.5, 1.0]
compensations = ["nominal", "estimated", "true"]
noise = true

[output]
trials_per_part = 16

[sweep]
design = "factorial"
[[sweep.factor]]
key = "noise.white_density_ug_per_sqrt_hz"
levels = [20.0, 80.0]
[[sweep.factor]]
key = "schedule.preset"
levels = ["hung_lee_2006", "hung_lee_2006_augmented"]
"#;

fn write_config(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn opts(out: &Path, threads: usize, shard: (u64, u64)) -> RunOptions {
    RunOptions { out: out.to_path_buf(), resume: false, force: false, shard, threads: Some(threads) }
}

/// All batches of `dir/sub`, part by part, in part order.
fn table(dir: &Path, sub: &str) -> Vec<(String, Vec<RecordBatch>)> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir.join(sub)).unwrap().flatten().map(|e| e.path()).collect();
    files.retain(|p| p.extension().is_some_and(|e| e == "parquet"));
    files.sort();
    files.iter().map(|f| (f.file_name().unwrap().to_string_lossy().into_owned(), read_batches(f).unwrap())).collect()
}

fn same_tables(a: &Path, b: &Path) {
    for sub in ["trials", "parameters"] {
        let (ta, tb) = (table(a, sub), table(b, sub));
        assert_eq!(ta.len(), tb.len(), "{sub}: part count");
        for ((na, ba), (nb, bb)) in ta.iter().zip(&tb) {
            assert_eq!(na, nb);
            assert_eq!(ba, bb, "{sub}/{na} differs");
        }
    }
}

#[test]
fn same_tables_on_1_and_2_threads_and_in_3_shards() {
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = write_config(dir.path(), "small.toml", SMALL);
    let cfg = McConfig::load(&cfg_path).unwrap();
    assert_eq!(cfg.cells.len(), 4);
    assert_eq!(cfg.parts(), 8); // 120 trials, 16 per part
    let one = dir.path().join("one");
    let two = dir.path().join("two");
    let sharded = dir.path().join("sharded");
    let o = run(&cfg, &cfg_path, &opts(&one, 1, (0, 1)), &Silent).unwrap();
    assert!(o.complete && o.trials_run == 120);
    run(&cfg, &cfg_path, &opts(&two, 2, (0, 1)), &Silent).unwrap();
    same_tables(&one, &two);
    for i in 0..3 {
        let o = run(&cfg, &cfg_path, &opts(&sharded, 2, (i, 3)), &Silent).unwrap();
        assert_eq!(o.complete, i == 2, "complete only when the last shard is done");
        assert!(o.summary.is_none(), "a shard does not summarize the run from memory");
    }
    same_tables(&one, &sharded);
    // The summary a run builds from the batches it writes is the one read back from its files
    // (4 cells, so the per-cell reductions between parts are exercised).
    let from_files = gfcal::mc::summary::summarize(&one).unwrap();
    assert_eq!(o.summary.as_ref(), Some(&from_files));
    assert_eq!(from_files.trials, 120);
    // Rows, columns and provenance.
    let trials = table(&one, "trials");
    let rows: usize = trials.iter().flat_map(|(_, b)| b.iter().map(|b| b.num_rows())).sum();
    assert_eq!(rows, 120);
    let schema = trials[0].1[0].schema();
    for col in [
        "trial_id",
        "noise.white_density_ug_per_sqrt_hz",
        "schedule.preset",
        "converged",
        "true_velocity_err_m_s_at_1s",
    ] {
        assert!(schema.field_with_name(col).is_ok(), "{col}");
    }
    assert_eq!(schema.field_with_name("estimated_position_err_m_at_0.5s").unwrap().metadata()["unit"], "m");
    let params = table(&one, "parameters");
    let prow: usize = params.iter().flat_map(|(_, b)| b.iter().map(|b| b.num_rows())).sum();
    assert_eq!(prow, 120 * 42);
    let meta = read_metadata(&one.join("trials/part-000000.parquet")).unwrap();
    assert_eq!(meta["gfcal:seed"], "7");
    assert_eq!(meta["gfcal:config"], SMALL);
    assert!(meta.contains_key("gfcal:git_commit") && meta.contains_key("gfcal:part_finished"));
    let run_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(one.join("run.json")).unwrap()).unwrap();
    assert_eq!(run_json["trials_total"], 120);
    assert!(run_json["finished"].is_string());
}

#[test]
fn summary_matches_the_parameters_table() {
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = write_config(dir.path(), "small.toml", SMALL);
    let cfg = McConfig::load(&cfg_path).unwrap();
    let out = dir.path().join("out");
    run(&cfg, &cfg_path, &opts(&out, 2, (0, 1)), &Silent).unwrap();
    let s = gfcal::mc::summary::summarize(&out).unwrap();
    assert_eq!(s.trials, 120);
    assert_eq!(s.parameters.len(), 4 * 42);
    // Recompute one RMSE by hand from the Parquet rows.
    let (mut errs, mut z2) = (Vec::new(), 0.0);
    for (_, batches) in table(&out, "parameters") {
        for b in batches {
            let cell = b.column_by_name("cell").unwrap().as_any().downcast_ref::<arrow_array::UInt32Array>().unwrap();
            let name = b.column_by_name("name").unwrap().as_any().downcast_ref::<arrow_array::StringArray>().unwrap();
            let err = b.column_by_name("error").unwrap().as_any().downcast_ref::<arrow_array::Float64Array>().unwrap();
            let crb =
                b.column_by_name("crb_sigma").unwrap().as_any().downcast_ref::<arrow_array::Float64Array>().unwrap();
            for i in 0..b.num_rows() {
                if cell.value(i) == 1 && name.value(i) == "a3.beta_yx" {
                    errs.push(err.value(i));
                    z2 += (err.value(i) / crb.value(i)).powi(2);
                }
            }
        }
    }
    assert_eq!(errs.len(), 30);
    let rmse = (errs.iter().map(|e| e * e).sum::<f64>() / 30.0).sqrt();
    let row = s.parameters.iter().find(|p| p.cell == 1 && p.name == "a3.beta_yx").unwrap();
    assert!((row.rmse / rmse - 1.0).abs() < 1e-12);
    // ratio: the RMS of each trial's error / crb_sigma.
    assert!((row.ratio / (z2 / 30.0f64).sqrt() - 1.0).abs() < 1e-12, "{row:?}");
    // 30 trials: ratio^2 is chi^2_30 / 30 for an efficient estimator, below 0.55^2 or above 1.5^2
    // with probability near 1e-4 each.
    assert!(row.ratio > 0.55 && row.ratio < 1.5, "{row:?}");
    // Robust columns: the median |error| (30 trials: between the 15th and 16th, within the
    // histogram's 0.5%) and the worst trial's share of the squared error.
    let mut abs: Vec<f64> = errs.iter().map(|e| e.abs()).collect();
    abs.sort_by(f64::total_cmp);
    assert!(row.median_abs_error >= abs[14] * 0.995 && row.median_abs_error <= abs[15] * 1.005, "{row:?} {abs:?}");
    let worst = abs[29] * abs[29] / errs.iter().map(|e| e * e).sum::<f64>();
    assert!((row.worst_share / worst - 1.0).abs() < 1e-12, "{row:?}");
    let csv = gfcal::mc::summary::summary_csv(&s);
    // The sweep's factors are columns after `cell` (issue 30, item 3).
    assert!(csv.starts_with("table,cell,noise.white_density_ug_per_sqrt_hz,schedule.preset,name,unit,n,bias,rmse,crb_sigma,ratio,coverage_95,diverged,median,p95,p05,median_abs_error,worst_share\n"));
    let d = s.drift.iter().find(|d| d.cell == 0 && d.column == "nominal_rate_err_rad_s_at_1s").unwrap();
    assert_eq!(d.n, 30);
    assert!(d.median > 0.0 && d.p95 >= d.median);
}

fn gfcal() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_gfcal"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

/// A run long enough to be killed part-way: 3000 trials in parts of 100.
fn long_config() -> String {
    SMALL
        .replace("trials_per_cell = 30", "trials_per_cell = 750")
        .replace("trials_per_part = 16", "trials_per_part = 100")
}

#[test]
fn killed_run_resumes_to_the_uninterrupted_result() {
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = write_config(dir.path(), "long.toml", &long_config());
    let out = dir.path().join("killed");
    let mut child = gfcal()
        .args(["run", cfg_path.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !out.join("trials/part-000002.parquet").exists() && t0.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    // Every part file on disk reads; none is half-written.
    let parts = table(&out, "trials");
    assert!(!parts.is_empty() && parts.len() < 30, "killed part-way: {} parts", parts.len());
    let _ = table(&out, "parameters");
    // Without --resume the folder is refused; with it, only missing parts run.
    let again = gfcal().args(["run", cfg_path.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    assert_eq!(again.status.code(), Some(2), "{}", String::from_utf8_lossy(&again.stderr));
    assert!(String::from_utf8_lossy(&again.stderr).contains("--resume"));
    let resumed =
        gfcal().args(["run", cfg_path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--resume"]).output().unwrap();
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    assert!(String::from_utf8_lossy(&resumed.stderr).contains("already done"));
    // Equal to an uninterrupted run.
    let cfg = McConfig::load(&cfg_path).unwrap();
    let clean = dir.path().join("clean");
    run(&cfg, &cfg_path, &opts(&clean, 2, (0, 1)), &Silent).unwrap();
    same_tables(&clean, &out);
    // No temporary file is left behind.
    for sub in ["trials", "parameters"] {
        let left: Vec<_> = std::fs::read_dir(out.join(sub))
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp."))
            .collect();
        assert!(left.is_empty(), "{left:?}");
    }
}

#[test]
fn every_config_in_configs_parses_and_validates() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let mut checked = 0;
    for entry in std::fs::read_dir(&root).unwrap().flatten() {
        let path = entry.path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let table: toml::Table = toml::from_str(&text).unwrap();
        let run = table.contains_key("trials_per_cell") || table.contains_key("sensitivity");
        if table.contains_key("effects") || (table.contains_key("seed") && !run) {
            gfcal::config::simulate_log::SimulateLogConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        } else if run {
            let cfg = McConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
            assert!(cfg.total_trials() > 0);
        } else if table.contains_key("schedule") {
            gfcal::config::calibration::CalibrationConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        } else {
            gfcal::config::drift::DriftConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        }
        checked += 1;
    }
    for entry in std::fs::read_dir(root.join("arrays")).unwrap().flatten() {
        gfcal::config::array::load_array_file(&entry.path()).unwrap_or_else(|e| panic!("{e}"));
        checked += 1;
    }
    assert!(checked >= 8, "{checked} configs");
    for name in ["quickstart", "hung_lee_2006", "identifiability_sweep", "overnight", "sobol_indices"] {
        assert!(root.join(format!("{name}.toml")).exists(), "configs/{name}.toml");
    }
    let overnight = McConfig::load(&root.join("overnight.toml")).unwrap();
    assert!(overnight.total_trials() >= 1_000_000);
}

/// Runs `gfcal run` on a config text; expects exit 2, the words, and nothing written.
fn run_refused(text: &str, words: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "bad.toml", text);
    let out = dir.path().join("out");
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    for w in words {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
    assert!(!out.exists(), "nothing written");
}

#[test]
fn bad_run_configs_are_refused_before_anything_is_written() {
    run_refused(&SMALL.replace("seed = 7", "seed = 7\nsede = 8"), &["bad.toml", "sede", "unknown field", "line 4"]);
    run_refused(
        &SMALL.replace("bias_mg = { dist = \"normal\", sigma = 1.0 }", "bias_mg = { dist = \"normal\", sigma = -1.0 }"),
        &["errors.bias_mg.sigma", "negative"],
    );
    run_refused(&SMALL.replace("levels = [20.0, 80.0]", "levels = []"), &["sweep.factor[0].levels", "empty"]);
    let no_factors = SMALL.split("[[sweep.factor]]").next().unwrap().to_string();
    run_refused(&no_factors, &["sweep.factor", "at least one"]);
    run_refused(
        &SMALL.replace("levels = [20.0, 80.0]", "levels = [20.0, -80.0]"),
        &["noise.white_density_ug_per_sqrt_hz", "negative", "sweep cell"],
    );
    run_refused(&SMALL.replace("key = \"schedule.preset\"", "key = \"schedule.presett\""), &["presett", "sweep cell"]);
    run_refused(&SMALL.replace("trials_per_cell = 30", "trials_per_cell = 0"), &["trials_per_cell"]);
    run_refused(&SMALL.replace("horizons_s = [0.5, 1.0]", "horizons_s = []"), &["navigation.horizons_s"]);
}

#[test]
fn an_output_folder_with_another_run_is_refused_unless_forced() {
    let dir = tempfile::tempdir().unwrap();
    let a = write_config(dir.path(), "a.toml", SMALL);
    let b = write_config(dir.path(), "b.toml", &SMALL.replace("seed = 7", "seed = 8"));
    let out = dir.path().join("out");
    let ok = gfcal().args(["run", a.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let before = std::fs::read_to_string(out.join("run.json")).unwrap();
    for extra in [&[][..], &["--resume"][..]] {
        let o =
            gfcal().args(["run", b.to_str().unwrap(), "--out", out.to_str().unwrap()]).args(extra).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains("holds a different run") && err.contains(out.to_str().unwrap()), "{err}");
    }
    assert_eq!(std::fs::read_to_string(out.join("run.json")).unwrap(), before, "untouched");
    let forced =
        gfcal().args(["run", b.to_str().unwrap(), "--out", out.to_str().unwrap(), "--force"]).output().unwrap();
    assert!(forced.status.success());
    let meta = read_metadata(&out.join("trials/part-000000.parquet")).unwrap();
    assert_eq!(meta["gfcal:seed"], "8");
    // The provenance is in the Arrow schema's metadata too (what pyarrow's read_table and Polars
    // show), for both tables.
    for sub in ["trials", "parameters"] {
        let file = std::fs::File::open(out.join(sub).join("part-000000.parquet")).unwrap();
        let schema =
            parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap().schema().clone();
        assert_eq!(schema.metadata().get("gfcal:seed").map(String::as_str), Some("8"), "{sub}");
        assert!(
            schema.metadata().contains_key("gfcal:config") && schema.metadata().contains_key("gfcal:units"),
            "{sub}"
        );
    }
}

#[test]
fn shard_flag_and_slurm_variables() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "small.toml", SMALL);
    let out = dir.path().join("out");
    let bad = gfcal()
        .args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--shard", "3/3"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    assert!(!out.exists());
    // Slurm: tasks 1..=2 of an array starting at 1 -> shards 0/2 and 1/2.
    for id in ["1", "2"] {
        let o = gfcal()
            .args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()])
            .env("SLURM_ARRAY_TASK_ID", id)
            .env("SLURM_ARRAY_TASK_MIN", "1")
            .env("SLURM_ARRAY_TASK_COUNT", "2")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let clean = dir.path().join("clean");
    let cfgv = McConfig::load(&cfg).unwrap();
    run(&cfgv, &cfg, &opts(&clean, 2, (0, 1)), &Silent).unwrap();
    same_tables(&clean, &out);
}

#[test]
fn distributions_take_one_value_or_one_per_accelerometer() {
    let dir = tempfile::tempdir().unwrap();
    let text = SMALL.replace(
        "location_mm = { dist = \"normal\", sigma = 1.0 }",
        "location_mm = { dist = \"normal\", mean = [0, 0, 5, 0, 0, 0], sigma = [0, 0, 0, 0, 0, 2.0] }",
    );
    let cfg = McConfig::load(&write_config(dir.path(), "d.toml", &text)).unwrap();
    let cell = &cfg.cells[0];
    let mut rng = gfcal::rng::trial_rng(1, 0);
    let (mut a6, mut n) = (0.0, 0.0);
    for _ in 0..2000 {
        let x = cell.errors.sample(&cell.layout, &mut rng);
        let loc = |j: usize, c: usize| x[7 * j + 4 + c];
        assert_eq!(loc(2, 1), 5e-3, "fixed mean 5 mm, sigma 0 on accelerometer 3");
        assert_eq!(loc(0, 0), 0.0);
        a6 += loc(5, 2).powi(2);
        n += 1.0;
    }
    let sd = (a6 / n).sqrt();
    assert!((sd / 2e-3 - 1.0).abs() < 0.08, "accelerometer 6 sd {sd}");
    let bad = SMALL.replace("sigma = 1.0 }\nscale", "sigma = [1.0, 1.0] }\nscale");
    let err = McConfig::load(&write_config(dir.path(), "e.toml", &bad)).unwrap_err().to_string();
    assert!(err.contains("errors.bias_mg.sigma") && err.contains("one value per accelerometer (6), got 2"), "{err}");
    let neg = SMALL.replace("half_width = 300.0", "half_width = [300, 300, -1, 300, 300, 300]");
    let err = McConfig::load(&write_config(dir.path(), "f.toml", &neg)).unwrap_err().to_string();
    assert!(err.contains("errors.scale_factor_ppm.half_width[2]") && err.contains("negative"), "{err}");
}

#[test]
fn space_filling_designs_cover_their_ranges() {
    use gfcal::mc::design::{factorial, latin_hypercube, sobol};
    // Latin hypercube: every stratum of every dimension holds exactly one point.
    let pts = latin_hypercube(50, 3, &mut gfcal::rng::trial_rng(3, 0));
    for d in 0..3 {
        let mut strata: Vec<usize> = pts.iter().map(|p| (p[d] * 50.0).floor() as usize).collect();
        strata.sort_unstable();
        assert_eq!(strata, (0..50).collect::<Vec<_>>());
    }
    // Sobol: in range, and a 2^k prefix is stratified in each dimension (a (0, m, s)-net property).
    let s = sobol(64, 2, 9);
    for d in 0..2 {
        let mut strata: Vec<usize> = s.iter().map(|p| (p[d] * 64.0).floor() as usize).collect();
        strata.sort_unstable();
        assert_eq!(strata, (0..64).collect::<Vec<_>>());
    }
    assert_eq!(factorial(&[2, 3]).len(), 6);
    // A config with a log-scale Latin hypercube: every cell's value within [low, high].
    let dir = tempfile::tempdir().unwrap();
    let text = SMALL.split("[sweep]").next().unwrap().to_string()
        + "[sweep]\ndesign = \"sobol\"\npoints = 8\n[[sweep.factor]]\nkey = \"errors.location_mm.sigma\"\nlow = 0.1\nhigh = 3.0\nscale = \"log\"\n[[sweep.factor]]\nkey = \"schedule.preset\"\nlevels = [\"hung_lee_2006\", \"hung_lee_2006_augmented\"]\n";
    let cfg = McConfig::load(&write_config(dir.path(), "s.toml", &text)).unwrap();
    assert_eq!(cfg.cells.len(), 16);
    for c in &cfg.cells {
        let gfcal::mc::config::FactorValue::Number(v) = c.factors[0].1 else { panic!() };
        assert!((0.1..=3.0).contains(&v), "{v}");
        let gfcal::mc::sample::Dist::Normal { sigma, .. } = &c.errors.location_m else { panic!() };
        assert!((sigma[0] - v * 1e-3).abs() < 1e-15);
    }
}

#[test]
fn progress_lines_when_stderr_is_not_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "small.toml", SMALL);
    let out = dir.path().join("out");
    let o = gfcal()
        .args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--progress-interval-s", "0.000001"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("trials in this run, 0 already done"), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("trials/s") && l.contains("ETA")).collect();
    assert!(lines.len() >= 2, "{err}");
    assert!(lines.last().unwrap().starts_with("gfcal: 120/120 trials (100.0%)"), "{err}");
    // The summary is printed and written.
    assert!(String::from_utf8_lossy(&o.stdout).starts_with("Summary of 120 trials"));
    assert!(out.join("summary.csv").exists());
}

#[test]
fn srrc_recovers_known_answers() {
    use gfcal::mc::sensitivity::{ranks, srrc};
    assert_eq!(ranks(&[3.0, 1.0, 2.0, 2.0]), vec![3.0, 0.0, 1.5, 1.5]);
    let mut rng = gfcal::rng::trial_rng(5, 0);
    use rand::RngExt;
    let x1: Vec<f64> = (0..2000).map(|_| rng.random::<f64>()).collect();
    let x2: Vec<f64> = (0..2000).map(|_| rng.random::<f64>()).collect();
    // A monotone function of x1 alone: x1 gets the whole index.
    let y: Vec<f64> = x1.iter().map(|v| v.powi(3)).collect();
    let (c, r2) = srrc(&[x1.clone(), x2.clone(), vec![1.0; 2000]], &y);
    assert!(
        (c[0].unwrap() - 1.0).abs() < 1e-9 && c[1].unwrap().abs() < 1e-9 && c[2].is_none() && (r2 - 1.0).abs() < 1e-9
    );
    // Two equal, independent contributions share it.
    let y: Vec<f64> = x1.iter().zip(&x2).map(|(a, b)| a + b).collect();
    let (c, _) = srrc(&[x1, x2], &y);
    assert!((c[0].unwrap() - c[1].unwrap()).abs() < 0.05 && c[0].unwrap() > 0.6, "{c:?}");
}

/// A run at rest where only the errors of `errors` (lines of the `[errors]` section) vary, with
/// nominal compensation only; its folder, output and SRRC rows.
fn one_source_run(
    name: &str,
    seed: u64,
    errors: &str,
) -> (tempfile::TempDir, PathBuf, Vec<gfcal::mc::sensitivity::SensitivityRow>) {
    let text = format!(
        r#"
name = "{name}"
seed = {seed}
trials_per_cell = 200
[errors]
{errors}
[noise]
white_density_ug_per_sqrt_hz = 50.0
[schedule]
preset = "hung_lee_2006"
step_duration_s = 0.2
[trajectory]
kind = "rest"
[navigation]
step_s = 0.05
horizons_s = [2.0]
compensations = ["nominal"]
"#
    );
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = write_config(dir.path(), "one.toml", &text);
    let cfg = McConfig::load(&cfg_path).unwrap();
    let out = dir.path().join("out");
    run(&cfg, &cfg_path, &opts(&out, 2, (0, 1)), &Silent).unwrap();
    let rows = gfcal::mc::sensitivity::sensitivity(&out, 1000).unwrap();
    (dir, out, rows)
}

/// Only accelerometer 2's scale factor varies (nominal 2.5, +-1000 ppm; its axis sees gravity at rest): the nominal-compensation
/// drift follows |k - k_nominal|, so that is the SRRC's input. With |k| (about 2.5 (1 + delta),
/// ranked by the signed delta) the index was near 0 (issue 12, defect 3).
#[test]
fn a_scale_factors_sensitivity_is_measured_from_its_nominal() {
    let (_dir, _out, rows) = one_source_run(
        "one_scale_factor",
        5,
        "nominal_scale_factor = 2.5\nscale_factor_ppm = { dist = \"normal\", sigma = [0.0, 1000.0, 0.0, 0.0, 0.0, 0.0] }",
    );
    let column = "nominal_rate_err_rad_s_at_2s";
    let mine: Vec<_> = rows.iter().filter(|r| r.output == column).collect();
    assert_eq!(mine.len(), 1, "{column}: only a2.scale_factor varies: {mine:?}");
    assert_eq!(mine[0].input, "|a2.scale_factor|");
    assert!(mine[0].srrc.unwrap() > 0.95 && mine[0].r2.unwrap() > 0.9, "{:?}", mine[0]);
}

#[test]
fn one_error_source_gets_the_whole_index() {
    // Only accelerometer 1's bias varies: the nominal-compensation drift depends on it alone.
    let (_dir, out, rows) =
        one_source_run("one_source", 3, "bias_mg = { dist = \"normal\", sigma = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0] }");
    for metric in ["rate_err_rad_s", "attitude_err_rad", "velocity_err_m_s"] {
        let column = format!("nominal_{metric}_at_2s");
        let mine: Vec<_> = rows.iter().filter(|r| r.output == column).collect();
        assert_eq!(mine.len(), 1, "{column}: only |a1.bias| varies: {mine:?}");
        assert_eq!(mine[0].input, "|a1.bias|");
        assert!(mine[0].srrc.unwrap() > 0.99 && mine[0].r2.unwrap() > 0.98, "{:?}", mine[0]);
        assert_eq!(mine[0].trials, 200);
    }
    // Through the command: the CSV is written.
    let o = gfcal().args(["sensitivity", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("sensitivity.csv")).unwrap();
    assert!(csv.starts_with("cell,output,input,srrc,r2,trials,note\n") && csv.contains("\"|a1.bias|\""));
}

/// Quickstart trial 8931 (issue 12, defect 4): the joint fit ran off along a weak location's
/// valley to a5.dy = -798.9 m (truth 0.6 mm) and called that converged. A fit that leaves the
/// small-error region of the model is not converged; one that stays in it may be poor along a weak
/// direction but not absurd.
#[test]
fn a_fit_that_leaves_the_small_error_region_is_not_called_converged() {
    use gfcal::mc::trial::{Prepared, run_trial};
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let cfg = McConfig::load(&root.join("quickstart.toml")).unwrap();
    let cell = &cfg.cells[0];
    let prepared = Prepared::new(cell);
    let r = run_trial(cell, &prepared, cfg.seed, 8931);
    let extent_m = cell.array.accelerometers().iter().map(|a| a.position_m.norm()).fold(0.0, f64::max);
    let worst = (0..cell.layout.len())
        .filter(|&i| {
            cell.layout.name(i).ends_with(".dx")
                || cell.layout.name(i).ends_with(".dy")
                || cell.layout.name(i).ends_with(".dz")
        })
        .map(|i| (r.estimated[i] - r.truth[i]).abs())
        .fold(0.0, f64::max);
    eprintln!("trial 8931: converged {} ({}), worst location error {worst:e} m", r.converged, r.message);
    assert!(!r.converged || worst < extent_m, "converged with a location error of {worst} m");
    if !r.converged {
        assert!(r.message.contains("small-error region"), "{}", r.message);
    }
}

/// Issue 14: trials navigated in lockstep (their compensations side by side in packed lanes) give
/// the records each gives alone, including beside a trial whose estimate is refused (8931: its
/// estimated compensation is absent and reads NaN), so the sets of lanes hold three
/// compensations.
#[test]
fn trials_in_lockstep_give_the_records_each_gives_alone() {
    use gfcal::mc::trial::{Prepared, run_trial, run_trials};
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let cfg = McConfig::load(&root.join("quickstart.toml")).unwrap();
    let cell = &cfg.cells[0];
    let prepared = Prepared::new(cell);
    for range in [8930..8932, 8931..8933, 40..44] {
        let together = run_trials(cell, &prepared, cfg.seed, range.clone());
        assert_eq!(together.len(), range.clone().count());
        for (t, r) in range.zip(&together) {
            // Debug prints every f64 to its bits (NaN included, which `==` would not equate).
            assert_eq!(format!("{:?}", run_trial(cell, &prepared, cfg.seed, t)), format!("{r:?}"), "trial {t}");
        }
    }
    let alone = run_trial(cell, &prepared, cfg.seed, 8931);
    assert!(!alone.converged && alone.drift.iter().any(|d| d.is_nan()), "8931's estimate is refused");

    // Through the runner, with lockstep chunks cut by cells of 7 trials and parts of 6 (the part
    // 6..12 would pair trials 6 and 7 across the cells were it not cut there): every drift
    // value in the table is the one its trial gives alone.
    let text = std::fs::read_to_string(root.join("quickstart.toml")).unwrap();
    let text = text
        .replace("trials_per_cell = 20000", "trials_per_cell = 7")
        .replace("trials_per_part = 2048", "trials_per_part = 6")
        + "\n[sweep]\ndesign = \"factorial\"\n[[sweep.factor]]\nkey = \"noise.white_density_ug_per_sqrt_hz\"\nlevels = [20.0, 80.0]\n";
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = write_config(dir.path(), "odd.toml", &text);
    let cfg = McConfig::load(&cfg_path).unwrap();
    assert_eq!((cfg.cells.len(), cfg.trials_per_cell, cfg.parts()), (2, 7, 3));
    let out = dir.path().join("out");
    run(&cfg, &cfg_path, &opts(&out, 2, (0, 1)), &Silent).unwrap();
    let mut checked = 0;
    for (_, batches) in table(&out, "trials") {
        for b in batches {
            let ids =
                b.column_by_name("trial_id").unwrap().as_any().downcast_ref::<arrow_array::UInt64Array>().unwrap();
            for row in 0..b.num_rows() {
                let t = ids.value(row);
                let cell = &cfg.cells[(t / cfg.trials_per_cell) as usize];
                let alone = run_trial(cell, &Prepared::new(cell), cfg.seed, t);
                let mut k = 0;
                for comp in ["nominal", "estimated"] {
                    for h in ["1", "2", "5", "10"] {
                        for (metric, _) in gfcal::mc::trial::DRIFT_METRICS {
                            let name = format!("{comp}_{metric}_at_{h}s");
                            let column = b.column_by_name(&name).unwrap_or_else(|| panic!("{name}"));
                            let got = column.as_any().downcast_ref::<arrow_array::Float64Array>().unwrap().value(row);
                            assert_eq!(got.to_bits(), alone.drift[k].to_bits(), "trial {t}, {name}");
                            k += 1;
                            checked += 1;
                        }
                    }
                }
            }
        }
    }
    assert_eq!(checked, 14 * 32);
}

/// Issue 13: a run in which every fit fails (a schedule of two static poses cannot identify the
/// locations) writes its tables and summary but exits 1 saying no trial produced an estimate; a
/// run with no noise says before it starts that `ratio` and `coverage_95` are undefined.
#[test]
fn a_run_without_any_estimate_fails_and_a_noise_free_run_says_what_is_undefined() {
    let text = r#"
name = "allfail"
seed = 7
trials_per_cell = 10
[errors]
bias_mg = { dist = "normal", sigma = 1.0 }
[noise]
white_density_ug_per_sqrt_hz = 50.0
[schedule]
[[schedule.step]]
kind = "static"
up = [0.0, 0.0, 1.0]
duration_s = 1.0
sample_rate_hz = 100.0
[[schedule.step]]
kind = "static"
up = [0.0, 0.0, -1.0]
duration_s = 1.0
sample_rate_hz = 100.0
[trajectory]
kind = "rest"
[navigation]
step_s = 0.05
horizons_s = [1.0]
compensations = ["estimated"]
"#;
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "allfail.toml", text);
    let out = dir.path().join("out");
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no trial of the 10") && err.contains("produced an estimate"), "{err}");
    assert!(out.join("summary.csv").exists(), "the summary is still written");

    let quiet = text.replace("white_density_ug_per_sqrt_hz = 50.0", "").replace(
        "[schedule]\n[[schedule.step]]\nkind = \"static\"\nup = [0.0, 0.0, 1.0]\nduration_s = 1.0\nsample_rate_hz = 100.0\n[[schedule.step]]\nkind = \"static\"\nup = [0.0, 0.0, -1.0]\nduration_s = 1.0\nsample_rate_hz = 100.0\n",
        "[schedule]\npreset = \"hung_lee_2006\"\n",
    );
    assert!(quiet.contains("preset"), "{quiet}");
    let cfg = write_config(dir.path(), "quiet.toml", &quiet);
    let out = dir.path().join("quiet");
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("has no noise") && err.contains("`ratio`") && err.contains("undefined"), "{err}");
}

/// Issue 13: a part file truncated by a crash was counted as done by `--resume`, and the summary
/// then failed. Resume checks each part's footer and row count and redoes a bad one; the result
/// equals an uninterrupted run.
#[test]
fn resume_redoes_a_truncated_part() {
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = write_config(dir.path(), "small.toml", SMALL);
    let cfg = McConfig::load(&cfg_path).unwrap();
    let clean = dir.path().join("clean");
    run(&cfg, &cfg_path, &opts(&clean, 2, (0, 1)), &Silent).unwrap();
    let out = dir.path().join("crashed");
    run(&cfg, &cfg_path, &opts(&out, 2, (0, 1)), &Silent).unwrap();
    // Truncate one trials part and one parameters part (of different parts) to half their bytes.
    for (sub, part) in [("trials", 2), ("parameters", 5)] {
        let path = out.join(sub).join(format!("part-{part:06}.parquet"));
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    }
    let resumed =
        gfcal().args(["run", cfg_path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--resume"]).output().unwrap();
    let err = String::from_utf8_lossy(&resumed.stderr);
    assert!(resumed.status.success(), "{err}");
    assert!(err.contains("2 parts written"), "the two damaged parts are redone: {err}");
    same_tables(&clean, &out);
}

/// Issue 13's messages: re-running a finished run says it is finished (not "use --resume to
/// finish it"), and resuming it prints no "ETA NaN".
#[test]
fn a_finished_run_says_so_and_resuming_it_has_no_nan_eta() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "small.toml", SMALL);
    let out = dir.path().join("out");
    let args = ["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--progress-interval-s", "0.001"];
    assert!(gfcal().args(args).output().unwrap().status.success());
    let again = gfcal().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(2), "{err}");
    assert!(err.contains("finished") && err.contains("summarize") && !err.contains("to finish it"), "{err}");
    let resumed = gfcal().args(args).arg("--resume").output().unwrap();
    let err = String::from_utf8_lossy(&resumed.stderr);
    assert!(resumed.status.success(), "{err}");
    assert!(!err.contains("NaN"), "{err}");
}

/// Issue 13: a huge trial count (1e12) allocated gigabytes and checked every part before any
/// work started (1e13 aborted). Part bookkeeping now grows with the work: the first part is on
/// disk within seconds.
#[test]
fn a_huge_trial_count_starts_work_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(
        dir.path(),
        "huge.toml",
        &SMALL.replace("trials_per_cell = 30", "trials_per_cell = 1000000000000"),
    );
    let out = dir.path().join("out");
    let mut child = gfcal()
        .args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !out.join("trials/part-000000.parquet").exists() && t0.elapsed() < Duration::from_secs(60) {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let exited = child.try_wait().unwrap();
    let _ = child.kill();
    let _ = child.wait();
    assert!(exited.is_none(), "the run stopped: {exited:?}");
    assert!(out.join("trials/part-000000.parquet").exists(), "no part after {:?}", t0.elapsed());
}

/// Parts written, from a run's closing line ("N trials run, M parts written, ...").
fn parts_written(stderr: &str) -> u64 {
    let line =
        stderr.lines().find(|l| l.contains("parts written")).unwrap_or_else(|| panic!("no closing line: {stderr}"));
    let before = line.split(" parts written").next().unwrap();
    before.rsplit(' ').next().unwrap().parse().unwrap()
}

#[test]
fn processes_started_together_into_one_folder_share_it() {
    // Before the folder lock: 4 shards started together left runs incomplete ("holds results
    // without a run.json") in most repetitions, and two unsharded runs ended the same way.
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "small.toml", SMALL);
    let clean = dir.path().join("clean");
    let cfgv = McConfig::load(&cfg).unwrap();
    run(&cfgv, &cfg, &opts(&clean, 2, (0, 1)), &Silent).unwrap();
    let parts = cfgv.parts();
    for repetition in 0..6 {
        let out = dir.path().join(format!("together-{repetition}"));
        // Four shards with --resume (the README's job array), then two unsharded runs, each at once.
        let commands: Vec<Vec<String>> = if repetition % 2 == 0 {
            (0..4).map(|i| vec!["--shard".to_string(), format!("{i}/4"), "--resume".to_string()]).collect()
        } else {
            vec![vec![], vec![]]
        };
        let children: Vec<_> = commands
            .iter()
            .map(|extra| {
                gfcal()
                    .args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--threads", "1"])
                    .args(extra)
                    .stdout(std::process::Stdio::null())
                    .stderr(std::process::Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        let mut written = 0;
        for child in children {
            let o = child.wait_with_output().unwrap();
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert!(o.status.success(), "repetition {repetition}: {stderr}");
            written += parts_written(&stderr);
        }
        assert_eq!(written, parts, "repetition {repetition}: each part computed by exactly one process");
        same_tables(&clean, &out);
        let run_json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
        assert!(run_json["finished"].is_string(), "repetition {repetition}: the run is marked finished");
        assert!(std::fs::read_dir(out.join("locks")).map_or(true, |d| d.count() == 0), "no part claims left");
    }
}

#[test]
fn a_different_config_cannot_join_a_run_in_progress() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "small.toml", SMALL);
    let other = write_config(dir.path(), "other.toml", &SMALL.replace("seed = 7", "seed = 8"));
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    // A process writing the folder holds its lock: stand in for it with the library's own lock.
    let cfgv = McConfig::load(&cfg).unwrap();
    run(&cfgv, &cfg, &RunOptions { shard: (0, 8), ..opts(&out, 1, (0, 8)) }, &Silent).unwrap();
    let gfcal::mc::claim::Entry::Alone(lock) = gfcal::mc::claim::enter(&out).unwrap() else { panic!("alone") };
    let _held = lock.share().unwrap();
    for (config, extra, expected) in [
        (&other, vec!["--resume"], "another gfcal process is writing a different run here now"),
        (&cfg, vec!["--force"], "--force would destroy its work"),
    ] {
        let o = gfcal()
            .args(["run", config.to_str().unwrap(), "--out", out.to_str().unwrap()])
            .args(extra)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(expected), "{stderr}");
    }
    // The same config joins without --resume and finishes the run.
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(parts_written(&String::from_utf8_lossy(&o.stderr)), cfgv.parts() - 1);
}

/// A quickstart-like config with a factorial sweep of two factors of `levels` levels each
/// (`levels^2` cells).
fn factorial_sweep(levels: usize) -> String {
    let list = |scale: f64| (1..=levels).map(|i| format!("{}", i as f64 * scale)).collect::<Vec<_>>().join(", ");
    format!(
        "{}\n[sweep]\ndesign = \"factorial\"\n[[sweep.factor]]\nkey = \"noise.white_density_ug_per_sqrt_hz\"\nlevels = [{}]\n[[sweep.factor]]\nkey = \"errors.bias_mg.sigma\"\nlevels = [{}]\n",
        SMALL.split("[sweep]").next().unwrap(),
        list(1.0),
        list(0.001)
    )
}

/// `gfcal ARGS` in a child whose address space is limited to `limit_mb` (RLIMIT_AS, through the
/// shell's `ulimit -v`, so the test holds on any Linux CI, as root too); killed after 120 s.
fn gfcal_within(limit_mb: u64, args: &[&str]) -> (std::process::Output, Duration) {
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let script =
        format!("ulimit -v {} && exec '{}' {}", limit_mb * 1024, env!("CARGO_BIN_EXE_gfcal"), quoted.join(" "));
    let t0 = Instant::now();
    let mut child = Command::new("sh")
        .args(["-c", &script])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    while child.try_wait().unwrap().is_none() && t0.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    let o = child.wait_with_output().unwrap();
    (o, t0.elapsed())
}

/// Issue 30, item 2: `check` and `run` of a sweep of 1e7 cells (a factorial of two factors of
/// 3,163 levels, a Latin hypercube of 1e7 points) grew past 13 GB expanding every cell up front.
/// Under a 200 MB address-space limit both now answer (exit 2) with the cell count and the memory
/// it would take, and nothing is written.
#[test]
fn a_sweep_of_ten_million_cells_is_refused_in_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let factorial = write_config(dir.path(), "factorial.toml", &factorial_sweep(3163));
    let lhs_text = format!(
        "{}\n[sweep]\ndesign = \"latin_hypercube\"\npoints = 10000000\n[[sweep.factor]]\nkey = \"noise.white_density_ug_per_sqrt_hz\"\nlow = 10.0\nhigh = 100.0\n",
        SMALL.split("[sweep]").next().unwrap()
    );
    let lhs = write_config(dir.path(), "lhs.toml", &lhs_text);
    for (cfg, cells) in [(&factorial, "10,004,569"), (&lhs, "10,000,000")] {
        let out = dir.path().join("out");
        for args in
            [vec!["check", cfg.to_str().unwrap()], vec!["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]]
        {
            let (o, took) = gfcal_within(200, &args);
            let err = String::from_utf8_lossy(&o.stderr);
            eprintln!("{args:?}: {:?} in {took:?}: {err}", o.status);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
            assert!(err.contains(cells) && err.contains("cells") && err.contains("GB"), "{args:?}: {err}");
            assert!(!out.exists(), "nothing written");
        }
    }
}

/// Issue 30, item 2: a sweep small enough to run is checked cell by cell without holding the
/// cells: 10,000 cells in well under 200 MB.
#[test]
fn a_large_sweep_is_checked_in_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "large.toml", &factorial_sweep(100));
    let (o, took) = gfcal_within(200, &["check", cfg.to_str().unwrap()]);
    let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    eprintln!("check of 10,000 cells: {took:?}");
    assert!(o.status.success(), "{err}");
    assert!(out.contains("10000 cell(s)"), "{out}");
}

/// A column of one batch as f64 values, `None` where null.
fn nullable_f64(b: &RecordBatch, name: &str) -> Vec<Option<f64>> {
    use arrow_array::Array;
    let c = b.column_by_name(name).unwrap_or_else(|| panic!("no column {name}"));
    let v = c.as_any().downcast_ref::<arrow_array::Float64Array>().unwrap();
    (0..v.len()).map(|i| (!v.is_null(i)).then(|| v.value(i))).collect()
}

/// The small sweep's navigation with two cells: well-calibrated misalignments (0.5 deg) and
/// misalignments near the model's small-error bound (4.6 deg against 0.1 rad), where most fits
/// leave the small-error region.
fn few_estimates_config() -> String {
    SMALL
        .replace("trials_per_cell = 30", "trials_per_cell = 40")
        .replace(
            "compensations = [\"nominal\", \"estimated\", \"true\"]",
            "compensations = [\"nominal\", \"estimated\"]",
        )
        .split("[sweep]")
        .next()
        .unwrap()
        .to_string()
        + "[sweep]\ndesign = \"factorial\"\n[[sweep.factor]]\nkey = \"errors.misalignment_deg.sigma\"\nlevels = [0.5, 4.6]\n"
}

/// Issue 30, item 3: a sweep cell where most fits fail printed its estimated drift from the few
/// that did, without a word. summary.csv now has `fits` rows (per cell, each outcome and its
/// count, the counts adding up to the cell's trials and `estimated` to the converged trials of
/// the Parquet table), the sweep's factor as a column, and the printed summary shows the share
/// and flags the cell whose estimated compensation rests on few trials.
#[test]
fn a_cell_with_few_estimates_is_counted_and_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "few.toml", &few_estimates_config());
    let out = dir.path().join("out");
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{stderr}");
    // The converged trials per cell, from the Parquet table (independent of the summary).
    let mut converged = [0u64; 2];
    for (_, batches) in table(&out, "trials") {
        for b in batches {
            let cell = b.column_by_name("cell").unwrap().as_any().downcast_ref::<arrow_array::UInt32Array>().unwrap();
            let conv =
                b.column_by_name("converged").unwrap().as_any().downcast_ref::<arrow_array::BooleanArray>().unwrap();
            for i in 0..b.num_rows() {
                converged[cell.value(i) as usize] += conv.value(i) as u64;
            }
        }
    }
    eprintln!("converged per cell: {converged:?}");
    // One cell whose estimates are most of its trials (not flagged: 20 or more, and half or more),
    // one with few.
    assert!(
        converged[0] >= 20 && 2 * converged[0] >= 40 && converged[1] < 20,
        "the case needs one good and one poor cell: {converged:?}"
    );
    let csv = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name}"));
    let (table_c, cell_c, name_c, n_c) = (col("table"), col("cell"), col("name"), col("n"));
    let factor_c = col("errors.misalignment_deg.sigma");
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    for (cell, &converged) in converged.iter().enumerate() {
        let fits: Vec<&Vec<&str>> =
            rows.iter().filter(|r| r[table_c] == "fits" && r[cell_c] == cell.to_string()).collect();
        let total: u64 = fits.iter().map(|r| r[n_c].parse::<u64>().unwrap()).sum();
        assert_eq!(total, 40, "cell {cell}: outcomes add up to the trials: {fits:?}");
        let estimated = fits.iter().find(|r| r[name_c] == "estimated").map(|r| r[n_c].parse::<u64>().unwrap());
        assert_eq!(estimated.unwrap_or(0), converged, "cell {cell}: {fits:?}");
        // The drift rows of the estimated compensation count the same trials.
        let drift = rows
            .iter()
            .find(|r| r[table_c] == "drift" && r[cell_c] == cell.to_string() && r[name_c].starts_with("estimated_"))
            .unwrap();
        assert_eq!(drift[n_c].parse::<u64>().unwrap(), converged);
    }
    // Every row carries its cell's factor value.
    for r in &rows {
        let want = if r[cell_c] == "0" { "0.5" } else { "4.6" };
        assert_eq!(r[factor_c], want, "{r:?}");
    }
    // The printed summary: the share per cell, and the poor cell flagged, the good one not.
    let (good, poor) = stdout.split_once("\ncell 1").expect("two cells printed");
    for (section, n) in [(good, converged[0]), (poor, converged[1])] {
        assert!(section.contains(&format!("{n} of 40 trials estimated")), "{section}");
        assert!(section.contains("parameter statistics"), "says which trials the parameter rows use: {section}");
    }
    assert!(!good.contains("FLAG"), "{good}");
    assert!(poor.contains("FLAG: the estimated compensation rests on few trials"), "{poor}");
    // The report too: the share per cell and the flag, under the poor cell's heading only.
    gfcal::report::run::write_run_report(&out).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let (good, poor) = html.split_once("Cell 1:").expect("two cells in the report");
    let good = good.split("Cell 0:").nth(1).expect("cell 0 in the report");
    assert!(good.contains(&format!("{} of 40 trials estimated", converged[0])) && !good.contains("Flag:"));
    assert!(poor.contains(&format!("{} of 40 trials estimated", converged[1])));
    assert!(poor.contains("Flag: the estimated compensation rests on few trials"));
}

/// Issue 30, item 3: a cell whose calibration makes the drift worse than no calibration at all
/// (tiny true errors, estimated from very noisy data) is flagged.
#[test]
fn a_cell_whose_estimated_compensation_is_worse_than_nominal_is_flagged() {
    let text = SMALL
        .replace("bias_mg = { dist = \"normal\", sigma = 1.0 }", "bias_mg = { dist = \"normal\", sigma = 0.0001 }")
        .replace("half_width = 300.0", "half_width = 0.01")
        .replace(
            "misalignment_deg = { dist = \"normal\", sigma = 0.5 }",
            "misalignment_deg = { dist = \"normal\", sigma = 0.0001 }",
        )
        .replace(
            "location_mm = { dist = \"normal\", sigma = 1.0 }",
            "location_mm = { dist = \"normal\", sigma = 0.0001 }",
        )
        .replace("nominal_scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]", "nominal_scale_factor = 1.0")
        .replace("trials_per_cell = 30", "trials_per_cell = 24")
        .replace("white_density_ug_per_sqrt_hz = 50.0", "white_density_ug_per_sqrt_hz = 300.0")
        // The augmented schedule sees every location: the fits converge (on the paper's schedule
        // the weak locations run out of the small-error region).
        .replace("preset = \"hung_lee_2006\"", "preset = \"hung_lee_2006_augmented\"")
        .replace("noise = true", "noise = false")
        .split("[sweep]")
        .next()
        .unwrap()
        .to_string();
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "worse.toml", &text);
    let out = dir.path().join("out");
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{stderr}");
    let s = gfcal::mc::summary::summarize(&out).unwrap();
    let median = |col: &str| s.drift.iter().find(|d| d.column == col).unwrap().median;
    let (nominal, estimated) = (median("nominal_velocity_err_m_s_at_1s"), median("estimated_velocity_err_m_s_at_1s"));
    assert!(estimated > nominal, "the case: estimated {estimated} against nominal {nominal}");
    assert!(stdout.contains("FLAG: the estimated compensation is worse than nominal"), "{stdout}");
    assert!(stdout.contains("velocity_err_m_s_at_0.5s median"), "names the columns: {stdout}");
    gfcal::report::run::write_run_report(&out).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("Flag: the estimated compensation is worse than nominal"));
}

/// Issue 30, item 4: `gfcal sensitivity` printed R^2 = 1.00 for a cell with fewer trials than
/// inputs. sensitivity.csv has a `trials` column; with fewer than 10 trials per input it gives no
/// coefficients (empty `srrc` and `r2`, and a `note`), and the printed table says so.
#[test]
fn sensitivity_refuses_to_fit_more_inputs_than_its_trials_carry() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "small.toml", SMALL);
    let out = dir.path().join("out");
    assert!(
        gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap().status.success()
    );
    let o = gfcal().args(["sensitivity", out.to_str().unwrap()]).output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{stderr}");
    let csv = std::fs::read_to_string(out.join("sensitivity.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for c in ["cell", "output", "input", "srrc", "r2", "trials", "note"] {
        assert!(header.contains(&c), "{header:?}");
    }
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<String>> = lines.map(split_csv).collect();
    assert!(!rows.is_empty());
    for r in &rows {
        // 30 trials a cell against 42 varying inputs: no coefficients anywhere.
        assert!(r[col("srrc")].is_empty() && r[col("r2")].is_empty(), "{r:?}");
        // Every trial has a nominal drift; one without an estimate has no estimated drift.
        let trials: usize = r[col("trials")].parse().unwrap();
        assert!(trials <= 30 && (trials == 30 || r[col("output")].starts_with("estimated_")), "{r:?}");
        assert!(r[col("note")].contains("10 trials per input"), "{r:?}");
    }
    assert!(!stdout.contains("R^2 1.00") && stdout.contains("no coefficients"), "{stdout}");
}

/// Fields of a CSV line (double-quoted fields may hold commas).
fn split_csv(line: &str) -> Vec<String> {
    let mut out = vec![String::new()];
    let mut quoted = false;
    for ch in line.chars() {
        match ch {
            '"' => quoted = !quoted,
            ',' if !quoted => out.push(String::new()),
            c => out.last_mut().unwrap().push(c),
        }
    }
    out
}

/// Issue 30, item 9: "no estimate" is null in the drift columns (polars' and pandas' quantiles
/// skip null; NaN silently shifts them), and a finished run leaves no lock file or empty folder.
#[test]
fn no_estimate_is_null_and_a_finished_run_leaves_no_locks() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "few.toml", &few_estimates_config());
    let out = dir.path().join("out");
    let o = gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (mut nulls, mut values) = (0, 0);
    for (_, batches) in table(&out, "trials") {
        for b in batches {
            let conv =
                b.column_by_name("converged").unwrap().as_any().downcast_ref::<arrow_array::BooleanArray>().unwrap();
            let schema = b.schema();
            for f in schema.fields().iter().filter(|f| f.name().contains("_err_") && f.name().contains("_at_")) {
                assert!(f.is_nullable(), "{} is nullable", f.name());
                for (i, v) in nullable_f64(&b, f.name()).into_iter().enumerate() {
                    match v {
                        None => {
                            nulls += 1;
                            assert!(f.name().starts_with("estimated_") && !conv.value(i), "{}: null", f.name());
                        }
                        Some(v) => {
                            values += 1;
                            assert!(!v.is_nan(), "{}: NaN", f.name());
                        }
                    }
                }
            }
        }
    }
    assert!(nulls > 0 && values > 0, "{nulls} nulls, {values} values");
    assert!(!out.join(".gfcal-run.lock").exists(), "the folder lock is removed");
    assert!(!out.join("locks").exists(), "no empty locks folder");
    let entries: Vec<String> =
        std::fs::read_dir(&out).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    for e in &entries {
        let p = out.join(e);
        assert!(!p.is_dir() || std::fs::read_dir(&p).unwrap().next().is_some(), "empty folder {e}");
    }
    // Resuming and forcing still work on a folder without its lock file.
    let again =
        gfcal().args(["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--force"]).output().unwrap();
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert!(!out.join(".gfcal-run.lock").exists() && !out.join("locks").exists());
}
