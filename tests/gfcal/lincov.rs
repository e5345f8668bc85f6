//! Linear covariance analysis (issue 31): LinCov against the Monte Carlo engine on the same
//! configs, its error budget, unidentifiable parameters, the command's files, and design for
//! drift confirmed by Monte Carlo. The closed forms (growth laws, central differences of the
//! navigator, the norm's distribution) are unit tests in `src/lincov/`.
//!
//! The statistical comparisons at 20,000 trials are `#[ignore]`d (minutes each); run them with
//! `cargo test --test gfcal lincov -- --ignored --nocapture`. Their figures are in docs/lincov.md.

use std::path::{Path, PathBuf};
use std::process::Command;

use gfcal::lincov::analysis::{CellResult, MetricResult, Settings, Source};
use gfcal::lincov::compare::{Comparison, compare};
use gfcal::mc::config::Compensation;
use gfcal::mc::{McConfig, RunOptions, Silent, run};

fn gfcal() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_gfcal"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

fn configs() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("configs")
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// A shipped config's text with its trial count (and optionally other lines) replaced.
fn shipped(name: &str, trials: u64, replace: &[(&str, &str)]) -> String {
    let mut text = std::fs::read_to_string(configs().join(name)).unwrap();
    let line = text.lines().find(|l| l.starts_with("trials_per_cell")).unwrap().to_string();
    text = text.replace(&line, &format!("trials_per_cell = {trials}"));
    for (a, b) in replace {
        assert!(text.contains(a), "{name} has `{a}`");
        text = text.replace(a, b);
    }
    text
}

/// `text` loaded as if it sat in configs/ (so that relative array files resolve).
fn load(text: &str) -> McConfig {
    McConfig::from_text(text.to_string(), &configs().join("lincov_test.toml")).unwrap_or_else(|e| panic!("{e}"))
}

fn analyse(cfg: &McConfig, truths: usize) -> Vec<CellResult> {
    gfcal::lincov::run::analyse(cfg, &Settings { truths, ..Settings::default() }).unwrap_or_else(|e| panic!("{e}"))
}

/// The Monte Carlo run of `cfg` in `dir`, then LinCov beside it.
fn monte_carlo(cfg: &McConfig, dir: &Path, results: &[CellResult]) -> Vec<Comparison> {
    let opts = RunOptions { out: dir.to_path_buf(), resume: false, force: true, shard: (0, 1), threads: None };
    run(cfg, &configs().join("lincov_test.toml"), &opts, &Silent).unwrap_or_else(|e| panic!("{e}"));
    compare(dir, results).unwrap()
}

fn rows(results: &[CellResult], comp: Compensation) -> impl Iterator<Item = (usize, &MetricResult)> {
    results.iter().flat_map(move |c| c.rows.iter().filter(move |r| r.compensation == comp).map(move |r| (c.cell, r)))
}

/// The Monte Carlo's own relative half-width (95%) of a row's median and p95, the larger side.
fn mc_half_widths(c: &Comparison) -> (f64, f64) {
    let rel = |q: &gfcal::lincov::compare::SampleQuantile| {
        ((q.high / q.value - 1.0).abs()).max((q.low / q.value - 1.0).abs())
    };
    (rel(&c.mc_median), rel(&c.mc_p95))
}

fn print_comparison(title: &str, rows: &[Comparison]) {
    eprintln!("\n{title}: LinCov / Monte Carlo (MC 95% half-width), nonlinearity, linear");
    for c in rows {
        let (hm, hp) = mc_half_widths(c);
        eprintln!(
            "  cell {} {:<44} n {:>6}  median {:.3} (+-{:.1}%)  p95 {:.3} (+-{:.1}%)  nl {:.3} {}",
            c.cell,
            c.name,
            c.n,
            c.median_ratio(),
            100.0 * hm,
            c.p95_ratio(),
            100.0 * hp,
            c.nonlinearity,
            c.linear
        );
    }
}

/// A small sweep with every source: random errors of every kind, a tilted fixture, noise in the
/// navigation, three compensations; and the same with the bias switched off.
const BUDGET: &str = r#"
name = "budget"
seed = 5
trials_per_cell = 10

[array]
preset = "cube"
rho_m = 0.1

[errors]
nominal_scale_factor = 1.0
bias_mg = { dist = "normal", sigma = 1.0 }
scale_factor_ppm = { dist = "uniform", half_width = 300.0 }
misalignment_deg = { dist = "normal", sigma = 0.2 }
location_mm = { dist = "normal", sigma = 0.5 }

[noise]
white_density_ug_per_sqrt_hz = 50.0

[schedule]
preset = "hung_lee_2006_augmented"
step_duration_s = 0.5
sample_rate_hz = 100.0

[calibration]
form = "triad"
estimator = "joint"
pose_tilt_sigma_arcsec = 36.0

[trajectory]
kind = "paper_manoeuvre"

[navigation]
step_s = 0.02
horizons_s = [0.5, 2.0]
compensations = ["nominal", "estimated", "true"]
noise = true
"#;

/// The budget's shares add up to the metric's mean square (rms^2) for every row of every
/// compensation, each part of a source of the right kind; a source switched off (the bias
/// distribution at 0, the navigation's noise off, a perfect fixture) contributes exactly zero,
/// and one left on does not.
#[test]
fn budget_shares_sum_to_the_total_and_a_switched_off_source_gives_zero() {
    let check_sum = |results: &[CellResult]| {
        for c in results {
            for r in &c.rows {
                let total: f64 = r.budget.iter().map(|(_, v)| v).sum();
                let ms = r.rms * r.rms;
                assert!(ms > 0.0, "{:?} {} at {}", r.compensation, r.metric, r.horizon_s);
                assert!(
                    (total / ms - 1.0).abs() < 1e-9,
                    "{:?} metric {} at {}: {total} vs {ms}",
                    r.compensation,
                    r.metric,
                    r.horizon_s
                );
            }
        }
    };
    let share = |r: &MetricResult, pick: &dyn Fn(&Source) -> bool| -> f64 {
        r.budget.iter().filter(|(s, _)| pick(s)).map(|(_, v)| v.abs()).sum()
    };
    let all = load(BUDGET);
    let layout = &all.cells[0].layout;
    let is_bias =
        |s: &Source| matches!(s, Source::Parameter(i) if matches!(layout.kind(*i), gfcal::calib::ParamKind::Bias));
    let on = analyse(&all, 64);
    check_sum(&on);
    for (_, r) in rows(&on, Compensation::Nominal).chain(rows(&on, Compensation::Estimated)) {
        assert!(share(r, &is_bias) > 0.0, "bias on: {:?}", r.compensation);
        assert!(share(r, &|s| *s == Source::Noise) > 0.0);
    }
    for (_, r) in rows(&on, Compensation::Estimated) {
        assert!(share(r, &|s| *s == Source::Fixture) > 0.0, "the fixture's tilts cost something");
    }
    for (_, r) in rows(&on, Compensation::True) {
        // Noise alone: every other source is zero.
        assert_eq!(share(r, &|s| *s != Source::Noise), 0.0);
        // The errors vary, so the noise's propagation is linearised again at drawn truths: an
        // index is computed (a positive, finite number; what it is worth, the Monte Carlo
        // comparison with fixture error says).
        assert!(r.nonlinearity > 0.0 && r.nonlinearity.is_finite(), "true at {}: {}", r.horizon_s, r.nonlinearity);
    }
    // Bias off, noise off, a perfect fixture.
    let off = load(
        &BUDGET
            .replace("bias_mg = { dist = \"normal\", sigma = 1.0 }", "bias_mg = { dist = \"fixed\", value = 0.0 }")
            .replace("noise = true", "noise = false")
            .replace("pose_tilt_sigma_arcsec = 36.0", "")
            .replace(", \"true\"]", "]"),
    );
    let off_results = analyse(&off, 64);
    check_sum(&off_results);
    for (_, r) in rows(&off_results, Compensation::Nominal) {
        assert_eq!(share(r, &is_bias), 0.0, "the nominal compensation's bias error is 0 when the bias is 0");
    }
    for (_, r) in rows(&off_results, Compensation::Nominal).chain(rows(&off_results, Compensation::Estimated)) {
        assert_eq!(share(r, &|s| *s == Source::Noise), 0.0);
        assert_eq!(share(r, &|s| *s == Source::Fixture), 0.0);
    }
}

/// A run is a function of its config and seed: the same rows, bit for bit, on 1 and on 3 threads
/// (the compensations, truths, probes and rows of a cell run in parallel), for the quickstart
/// (weighted truths, probes at a tail truth), for a config with the `true` compensation, a
/// tilted fixture and navigation noise, and for two cells that navigate apart (their truths
/// calibrated beside their linearisations on 3 threads, in their own analyses on 1).
#[test]
fn the_same_rows_bit_for_bit_on_one_and_on_three_threads() {
    let bits = |results: &[CellResult]| -> Vec<u64> {
        let mut out = Vec::new();
        for c in results {
            out.push(c.excluded_truths as u64);
            out.push(c.refused_fraction.to_bits());
            for r in &c.rows {
                for v in [r.median, r.p95, r.p05, r.rms, r.median_se, r.p95_se, r.nonlinearity] {
                    out.push(v.to_bits());
                }
                out.extend(r.budget.iter().map(|(_, v)| v.to_bits()));
            }
        }
        out
    };
    // Two cells that navigate apart (two groups): on 1 thread each calibrates its truths in its own
    // analysis, on 3 beside its linearisation; the same bits either way.
    let two_groups =
        shipped("quickstart.toml", 1, &[]) + "\n[[sweep.factor]]\nkey = \"navigation.step_s\"\nlevels = [0.01, 0.02]\n";
    for (name, text, truths) in [
        ("quickstart", shipped("quickstart.toml", 1, &[]), 256),
        ("budget", BUDGET.to_string(), 64),
        ("two groups", two_groups, 64),
    ] {
        let cfg = load(&text);
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| analyse(&cfg, truths))
        };
        let (one, three) = (on(1), on(3));
        assert!(one.iter().all(|c| !c.rows.is_empty()), "{name}: rows");
        assert_eq!(one.len(), if name == "two groups" { 2 } else { 1 }, "{name}: cells");
        assert!(bits(&one) == bits(&three), "{name}: rows differ between 1 and 3 threads");
    }
}

/// A schedule of static poses only cannot identify the locations (they are seen only through a
/// rotation): on a manoeuvre that rotates, every metric of the estimated compensation is
/// unbounded and names them (`a1.dy`, ...); at rest the locations move nothing and the drift stays a number.
/// The command says so too (inf in lincov.csv, the names in `unbounded_by`).
#[test]
fn an_unidentifiable_parameter_makes_the_metrics_it_reaches_unbounded_naming_it() {
    let statics = r#"
[[schedule.step]]
kind = "static"
up = [1.0, 1.0, 0.0]
[[schedule.step]]
kind = "static"
up = [-1.0, -1.0, 0.0]
[[schedule.step]]
kind = "static"
up = [1.0, 0.0, 1.0]
[[schedule.step]]
kind = "static"
up = [-1.0, 0.0, -1.0]
[[schedule.step]]
kind = "static"
up = [0.0, 1.0, 1.0]
[[schedule.step]]
kind = "static"
up = [0.0, -1.0, -1.0]
[[schedule.step]]
kind = "static"
up = [0.0, -1.0, 1.0]
[[schedule.step]]
kind = "static"
up = [0.0, 1.0, -1.0]
[[schedule.step]]
kind = "static"
up = [-1.0, 0.0, 1.0]
[[schedule.step]]
kind = "static"
up = [1.0, 0.0, -1.0]
[[schedule.step]]
kind = "static"
up = [-1.0, 1.0, 0.0]
[[schedule.step]]
kind = "static"
up = [1.0, -1.0, 0.0]

[calibration]"#;
    let text = BUDGET
        .replace("preset = \"hung_lee_2006_augmented\"\n", "")
        .replace("\n[calibration]", statics)
        .replace("pose_tilt_sigma_arcsec = 36.0", "");
    let manoeuvre = load(&text);
    for (_, r) in rows(&analyse(&manoeuvre, 8), Compensation::Estimated) {
        assert!(
            r.median.is_infinite() && r.p95.is_infinite(),
            "metric {} at {} s: {}",
            r.metric,
            r.horizon_s,
            r.median
        );
        // The locations are named a1.dx ... a6.dz; only they are unidentifiable.
        assert!(!r.unbounded_by.is_empty(), "metric {} at {} s", r.metric, r.horizon_s);
        assert!(r.unbounded_by.iter().all(|n| n.contains(".d")), "{:?}", r.unbounded_by);
        assert!(!r.linear);
    }
    let rest = text.replace("kind = \"paper_manoeuvre\"", "kind = \"rest\"");
    for (_, r) in rows(&analyse(&load(&rest), 8), Compensation::Estimated) {
        assert!(r.median.is_finite() && r.median > 0.0, "at rest: metric {} at {} s", r.metric, r.horizon_s);
        assert!(r.unbounded_by.is_empty());
    }
    // Through the command.
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "statics.toml", &text);
    let out = dir.path().join("out");
    let o = gfcal()
        .args(["lincov", path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--truths", "8"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("unbounded") && stdout.contains("a1.dz"), "{stdout}");
    let csv = std::fs::read_to_string(out.join("lincov.csv")).unwrap();
    let line = csv.lines().find(|l| l.contains("estimated_velocity_err_m_s_at_2s")).unwrap();
    assert!(line.contains(",inf,inf,inf,") && line.contains("a1.dz"), "{line}");
}

/// `gfcal lincov`: lincov.csv with summary.csv's drift columns (name, unit, median, p95, p05)
/// and the nonlinearity and linear columns, the same table in Parquet with its provenance,
/// lincov.json, budget.csv; `--compare` against a run of the same config writes compare.csv; bad
/// input exits 2 naming the file and the key, with nothing written.
#[test]
fn the_command_writes_its_tables_and_refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let text = BUDGET.replace("trials_per_cell = 10", "trials_per_cell = 40");
    let path = write(dir.path(), "budget.toml", &text);
    let run_dir = dir.path().join("run");
    let o = gfcal().args(["run", path.to_str().unwrap(), "--out", run_dir.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = dir.path().join("lincov");
    let o = gfcal()
        .args(["lincov", path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--truths", "32"])
        .args(["--compare", run_dir.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("lincov.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    assert!(header.starts_with("cell,name,unit,median,p95,p05,"), "{header}");
    assert!(header.contains(",nonlinearity,linear,"), "{header}");
    // 3 compensations x 4 metrics x 2 horizons.
    assert_eq!(csv.lines().count(), 1 + 24);
    // Every drift column of the run's summary is there, in its unit.
    let summary = std::fs::read_to_string(run_dir.join("summary.csv")).unwrap();
    for line in summary.lines().filter(|l| l.starts_with("drift,")) {
        let f: Vec<&str> = line.split(',').collect();
        let mine = csv.lines().find(|l| l.split(',').nth(1) == Some(f[2])).unwrap_or_else(|| panic!("{}", f[2]));
        assert_eq!(mine.split(',').nth(2), Some(f[3]), "unit of {}", f[2]);
    }
    let meta = gfcal::io::parquet::read_metadata(&out.join("lincov.parquet")).unwrap();
    for key in ["gfcal:version", "gfcal:git_commit", "gfcal:config", "gfcal:seed"] {
        assert!(meta.contains_key(key), "{key} in {meta:?}");
    }
    let batches = gfcal::io::parquet::read_batches(&out.join("lincov.parquet")).unwrap();
    assert_eq!(batches.iter().map(|b| b.num_rows()).sum::<usize>(), 24);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("lincov.json")).unwrap()).unwrap();
    assert_eq!(json["seed"], 5);
    assert_eq!(json["config_text"].as_str(), Some(text.as_str()));
    let budget = std::fs::read_to_string(out.join("budget.csv")).unwrap();
    assert!(
        budget
            .starts_with("cell,name,unit,compensation,metric,horizon_s,source,kind,accelerometer,mean_square,share\n")
    );
    let compare = std::fs::read_to_string(out.join("compare.csv")).unwrap();
    assert_eq!(compare.lines().count(), 1 + 24, "{compare}");
    // `gfcal report` on the folder draws the page.
    let o = gfcal().args(["report", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("lincov.html").exists());

    // Bad input: exit 2, the file and the key named, nothing written.
    let refused = |text: &str, words: &[&str], extra: &[&str]| {
        let d = tempfile::tempdir().unwrap();
        let p = write(d.path(), "bad.toml", text);
        let out = d.path().join("out");
        let o =
            gfcal().args(["lincov", p.to_str().unwrap(), "--out", out.to_str().unwrap()]).args(extra).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        for w in words {
            assert!(err.contains(w), "mentions `{w}`: {err}");
        }
        assert!(!out.exists(), "nothing written");
    };
    refused(&BUDGET.replace("seed = 5", "seed = 5\nsede = 8"), &["bad.toml", "sede"], &[]);
    refused(
        &BUDGET.replace("[noise]\n", "[noise]\ngauss_markov_sigma_ug = 10.0\ngauss_markov_correlation_time_s = 1.0\n"),
        &["bad.toml", "noise.gauss_markov_sigma_ug", "white noise only"],
        &[],
    );
    refused(&BUDGET.replace("estimator = \"joint\"", "estimator = \"paper\""), &["calibration.estimator"], &[]);
    refused(BUDGET, &["--truths"], &["--truths", "0"]);
}

/// The Monte Carlo of a fixed truth (the paper's errors) on the augmented schedule, where every
/// parameter is well determined, against LinCov's one Gaussian: the estimated compensation's
/// median and p95 within the Monte Carlo's own 95% interval plus 5% at 2,000 trials, and every
/// row `linear`. (The 20,000-trial comparisons are the ignored tests below.)
#[test]
fn lincov_matches_a_small_monte_carlo_where_every_parameter_is_well_determined() {
    let text = shipped(
        "hung_lee_2006.toml",
        2000,
        &[
            ("levels = [\"hung_lee_2006\", \"hung_lee_2006_augmented\"]", "levels = [\"hung_lee_2006_augmented\"]"),
            ("trials_per_part = 1000", "trials_per_part = 500"),
            ("horizons_s = [1.0, 2.0, 5.0, 10.0]", "horizons_s = [1.0, 5.0]"),
        ],
    );
    let cfg = load(&text);
    let results = analyse(&cfg, 1);
    let dir = tempfile::tempdir().unwrap();
    let cmp = monte_carlo(&cfg, dir.path(), &results);
    let estimated: Vec<Comparison> = cmp.into_iter().filter(|c| c.name.starts_with("estimated_")).collect();
    print_comparison("augmented schedule, 2,000 trials", &estimated);
    assert_eq!(estimated.len(), 8);
    for c in &estimated {
        let (hm, hp) = mc_half_widths(c);
        assert!((c.median_ratio() - 1.0).abs() < hm + 0.05, "{}: median {}", c.name, c.median_ratio());
        assert!((c.p95_ratio() - 1.0).abs() < hp + 0.05, "{}: p95 {}", c.name, c.p95_ratio());
        assert!(c.linear, "{}: nonlinearity {}", c.name, c.nonlinearity);
    }
}

/// The rows of a comparison the issue's checks read: the estimated compensation's within 10%
/// (median and p95), and every row whose LinCov differs from the Monte Carlo by more than 25%
/// flagged (`linear` false). Returns (estimated rows, estimated rows within 10%, estimated rows
/// `linear`, rows over 25% unflagged).
fn tally(cmp: &[Comparison]) -> (usize, usize, usize, Vec<String>) {
    let est: Vec<&Comparison> = cmp.iter().filter(|c| c.name.starts_with("estimated_")).collect();
    let within = est.iter().filter(|c| c.worst_difference() <= 0.10).count();
    let linear = est.iter().filter(|c| c.linear).count();
    let unflagged = cmp
        .iter()
        .filter(|c| c.linear && c.worst_difference() > 0.25)
        .map(|c| format!("cell {} {} (median {:.3}, p95 {:.3})", c.cell, c.name, c.median_ratio(), c.p95_ratio()))
        .collect();
    (est.len(), within, linear, unflagged)
}

/// What a comparison must show for the estimated compensation.
#[derive(Clone, Copy, PartialEq)]
enum Expect {
    /// Every row within 10% (median and p95).
    Within10,
    /// Every row within 10% or flagged (`linear` false).
    Within10OrFlagged,
}

/// LinCov against 20,000 Monte Carlo trials of `text`: the estimated (and `true`) compensation's
/// rows as `expect` says, most of them `linear` where `well_determined`, and every row of any
/// compensation that differs by more than 25% flagged.
fn against_monte_carlo(
    title: &str,
    text: &str,
    expect: Expect,
    well_determined: bool,
) -> (Vec<CellResult>, Vec<Comparison>) {
    let cfg = load(text);
    let clock = std::time::Instant::now();
    let results = analyse(&cfg, Settings::default().truths);
    let lincov_s = clock.elapsed().as_secs_f64();
    let dir = tempfile::tempdir().unwrap();
    let clock = std::time::Instant::now();
    let cmp = monte_carlo(&cfg, dir.path(), &results);
    let mc_s = clock.elapsed().as_secs_f64();
    print_comparison(title, &cmp);
    for c in &results {
        eprintln!(
            "  cell {}: {} truths left out of the mixture; a fit leaves the small-error region with chance {:.4}",
            c.cell, c.excluded_truths, c.refused_fraction
        );
    }
    let (n, within, linear, unflagged) = tally(&cmp);
    eprintln!(
        "{title}: estimated rows {n}, within 10% {within}, linear {linear}; rows over 25% not flagged: {}; \
         LinCov {lincov_s:.2} s, Monte Carlo {mc_s:.1} s (test profile)",
        unflagged.len()
    );
    assert!(unflagged.is_empty(), "{title}: differ by more than 25% but linear: {unflagged:#?}");
    // The `true` compensation (noise alone) as the estimated one: its noise's propagation also
    // depends on the true errors (the `true` index, docs/lincov.md).
    for c in cmp.iter().filter(|c| c.name.starts_with("estimated_") || c.name.starts_with("true_")) {
        let ok = match expect {
            Expect::Within10 => c.worst_difference() <= 0.10,
            Expect::Within10OrFlagged => c.worst_difference() <= 0.10 || !c.linear,
        };
        assert!(ok, "{title}: {} median {:.3} p95 {:.3} linear {}", c.name, c.median_ratio(), c.p95_ratio(), c.linear);
    }
    if well_determined {
        assert!(2 * linear > n, "{title}: most estimated rows linear ({linear} of {n})");
    }
    (results, cmp)
}

/// The paper's errors (fixed) on the augmented schedule, 20,000 trials.
#[test]
#[ignore = "statistical: 20,000 Monte Carlo trials (about a minute in the test profile)"]
fn lincov_against_20000_trials_on_the_augmented_schedule() {
    let text = shipped(
        "hung_lee_2006.toml",
        20_000,
        &[
            ("levels = [\"hung_lee_2006\", \"hung_lee_2006_augmented\"]", "levels = [\"hung_lee_2006_augmented\"]"),
            ("trials_per_part = 1000", "trials_per_part = 2048"),
        ],
    );
    against_monte_carlo("augmented schedule (paper's errors), 20,000 trials", &text, Expect::Within10, true);
}

/// The nine-accelerometer config (random errors, tilt form, augmented schedule), 20,000 trials.
#[test]
#[ignore = "statistical: 20,000 Monte Carlo trials of nine accelerometers (minutes)"]
fn lincov_against_20000_trials_on_nine_accelerometers() {
    against_monte_carlo(
        "nine accelerometers, 20,000 trials",
        &shipped("nine_accelerometer_run.toml", 20_000, &[]),
        Expect::Within10,
        true,
    );
}

/// Random errors on the augmented schedule with a tilted fixture and navigation noise, 20,000
/// trials. Within 10% or flagged: on the paper's manoeuvre the rate reaches 7.9 rad/s at 10 s,
/// and the centripetal feedback of the rate error then depends on the true misalignments, which
/// LinCov's one linearisation (at the centre of the error distributions) does not carry; the
/// rate error at 10 s (p95 18% low, docs/lincov.md) is flagged by the probed truth's own
/// linearisation. The `true` compensation's noise-driven rate error at 10 s (p95 24% low) is off
/// by the same feedback and is flagged by the noise's linearisation at drawn truths.
#[test]
#[ignore = "statistical: 20,000 Monte Carlo trials with fixture error (minutes)"]
fn lincov_against_20000_trials_with_fixture_error() {
    let text = shipped("fixture_error.toml", 20_000, &[]);
    against_monte_carlo("fixture error, 20,000 trials", &text, Expect::Within10OrFlagged, true);
}

/// The quickstart (the paper's schedule, six weak location components): within 10% or flagged.
/// Its truths are weighted by the chance that their fit stays in the model's small-error region
/// (docs/lincov.md): that chance, averaged over the truths, predicts the fraction of fits the
/// Monte Carlo refuses (within 3 points, written before the run; 6.6% against 6.8% measured), and
/// with it every estimated row up to 5 s is within 10% of the Monte Carlo (median and p95; 8.1%
/// at worst measured), where the hard cut it replaced left the p95s 24-30% low.
#[test]
#[ignore = "statistical: 20,000 Monte Carlo trials of the quickstart (about a minute)"]
fn lincov_against_20000_trials_on_the_quickstart() {
    let trials = 20_000;
    let text = shipped("quickstart.toml", trials, &[]);
    let (results, cmp) = against_monte_carlo("quickstart, 20,000 trials", &text, Expect::Within10OrFlagged, false);
    let estimated: Vec<&Comparison> = cmp.iter().filter(|c| c.name.starts_with("estimated_")).collect();
    let refused = 1.0 - estimated[0].n as f64 / trials as f64;
    let predicted = results[0].refused_fraction;
    eprintln!("fits refused: Monte Carlo {refused:.4}, LinCov's mixture {predicted:.4}");
    assert!((predicted - refused).abs() < 0.03, "refused fits: LinCov {predicted}, Monte Carlo {refused}");
    for c in estimated.iter().filter(|c| !c.name.ends_with("_at_10s")) {
        assert!(c.worst_difference() <= 0.10, "{}: median {:.3} p95 {:.3}", c.name, c.median_ratio(), c.p95_ratio());
    }
}

/// `gfcal design` with a drift target (configs/hung_lee_2006_drift_design.toml: the estimated
/// compensation's velocity error at 10 s, p95 below 10 m/s; the paper's schedule gives 29 m/s)
/// adds steps until LinCov meets it and prints the drift before and after; the Monte Carlo of the
/// paper's errors calibrated on the designed schedule (written by --schedule-out) confirms it:
/// its p95 is below the target (within its own 95% interval) and within 10% + its interval of
/// LinCov's, while on the paper's schedule it is above the target.
fn design_confirmed_by_monte_carlo(trials: u64) {
    let dir = tempfile::tempdir().unwrap();
    let designed = dir.path().join("designed.toml");
    let o = gfcal()
        .args(["design", "configs/hung_lee_2006_drift_design.toml", "--schedule-out", designed.to_str().unwrap()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("Every drift target is met"), "{stdout}");
    let line = stdout.lines().find(|l| l.starts_with("velocity_err_m_s_p95_at_10s")).unwrap();
    let f: Vec<&str> = line.split_whitespace().collect();
    let (target, before, after): (f64, f64, f64) =
        (f[2].parse().unwrap(), f[3].parse().unwrap(), f[4].parse().unwrap());
    assert!(before > target && after <= target, "{line}");
    let schedule = std::fs::read_to_string(&designed).unwrap();
    let base = shipped("hung_lee_2006.toml", trials, &[("trials_per_part = 1000", "trials_per_part = 2048")]);
    let start = base.find("[schedule]").unwrap();
    let end = base.find("[calibration]").unwrap();
    let text = format!("{}{}\n{}", &base[..start], schedule, &base[end..])
        .replace("compensations = [\"nominal\", \"estimated\", \"true\"]", "compensations = [\"estimated\"]");
    let text = text[..text.find("[sweep]").unwrap()].to_string();
    let cfg = load(&text);
    let results = analyse(&cfg, 1);
    let run_dir = dir.path().join("run");
    let cmp = monte_carlo(&cfg, &run_dir, &results);
    let v = cmp.iter().find(|c| c.name == "estimated_velocity_err_m_s_at_10s").unwrap();
    print_comparison(&format!("designed schedule, {trials} trials"), std::slice::from_ref(v));
    // LinCov on the run config agrees with what design printed (4 significant digits).
    assert!((v.lincov_p95 / after - 1.0).abs() < 1e-3, "{} vs {after}", v.lincov_p95);
    let (_, hp) = mc_half_widths(v);
    assert!(v.mc_p95.value <= target * (1.0 + hp), "Monte Carlo p95 {} vs target {target}", v.mc_p95.value);
    assert!((v.p95_ratio() - 1.0).abs() <= 0.10 + hp, "p95 ratio {}", v.p95_ratio());
    // The paper's schedule misses the target in the Monte Carlo too.
    let paper = load(&shipped(
        "hung_lee_2006.toml",
        trials.min(2000),
        &[
            ("levels = [\"hung_lee_2006\", \"hung_lee_2006_augmented\"]", "levels = [\"hung_lee_2006\"]"),
            ("compensations = [\"nominal\", \"estimated\", \"true\"]", "compensations = [\"estimated\"]"),
        ],
    ));
    let paper_results = analyse(&paper, 1);
    let cmp = monte_carlo(&paper, &dir.path().join("paper"), &paper_results);
    let p = cmp.iter().find(|c| c.name == "estimated_velocity_err_m_s_at_10s").unwrap();
    print_comparison("paper's schedule", std::slice::from_ref(p));
    assert!(p.mc_p95.low > target, "the paper's schedule: Monte Carlo p95 {:?}", p.mc_p95);
}

#[test]
fn design_for_a_drift_target_is_confirmed_by_monte_carlo() {
    design_confirmed_by_monte_carlo(2000);
}

#[test]
#[ignore = "statistical: 20,000 Monte Carlo trials of the designed schedule (about a minute)"]
fn design_for_a_drift_target_is_confirmed_by_20000_trials() {
    design_confirmed_by_monte_carlo(20_000);
}
