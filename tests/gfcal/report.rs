//! Reports: `gfcal report DIR` renders for the quickstart run, every plot has data and axis titles
//! with units; weak parameters are marked; bad folders are refused.

use std::path::Path;
use std::process::Command;

use gfcal::mc::{McConfig, RunOptions, Silent, run};
use gfcal::report::Figure;
use gfcal::report::run::write_run_report;

/// Runs `text` (a run config) into `dir/out` on 2 threads.
fn run_config(dir: &Path, text: &str) -> std::path::PathBuf {
    let path = dir.join("config.toml");
    std::fs::write(&path, text).unwrap();
    let cfg = McConfig::load(&path).unwrap();
    let out = dir.join("out");
    let opts = RunOptions { out: out.clone(), resume: false, force: false, shard: (0, 1), threads: Some(2) };
    run(&cfg, &path, &opts, &Silent).unwrap();
    out
}

/// Every panel has data and both axis titles name a unit in brackets, and the SVG shows them.
pub fn check_figure(f: &Figure) {
    assert!(f.data_points > 0, "{}: no data", f.name);
    assert!(!f.panels.is_empty(), "{}: no panels", f.name);
    for p in &f.panels {
        assert!(p.data_points > 0, "{} / {}: empty panel", f.name, p.title);
        for label in [&p.x_label, &p.y_label] {
            if label.starts_with("input") || label == "parameter" || label == "step" || label == "model" {
                // A categorical axis: its ticks name the categories.
                continue;
            }
            let unit = label.rsplit_once(" [").map(|(_, u)| u.trim_end_matches(']')).unwrap_or("");
            assert!(!unit.is_empty() && label.ends_with(']'), "{} / {}: axis `{label}` has no unit", f.name, p.title);
            let drawn = label
                .replace('&', "&amp;")
                .replace('<', "&lt;")
                .replace('>', "&gt;")
                .replace('\'', "&apos;")
                .replace('"', "&quot;");
            assert!(f.svg.contains(&drawn), "{}: axis title `{label}` not drawn", f.name);
        }
    }
    // Data are drawn as SVG shapes, not only the frame (lines, circles, polygons, or bars).
    let shapes = ["<polyline", "<circle", "<polygon"].iter().map(|s| f.svg.matches(s).count()).sum::<usize>()
        + f.svg.matches("<rect").count().saturating_sub(1);
    assert!(shapes > 0, "{}: nothing drawn", f.name);
}

fn check_page(html: &str, figures: &[Figure]) {
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(!html.contains("<script"), "no scripts");
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http") && !html.contains("url(http"), "no network");
    for f in figures {
        assert!(html.contains(f.svg.trim()), "{} is not inline", f.name);
    }
}

#[test]
fn report_renders_for_the_quickstart_run() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/quickstart.toml"))
        .unwrap()
        .replace("trials_per_cell = 20000", "trials_per_cell = 600");
    let out = run_config(tmp.path(), &text);
    let (report, written) = write_run_report(&out).unwrap();
    let names: Vec<&str> = report.figures.iter().map(|f| f.name.as_str()).collect();
    for want in ["identifiability", "location_recovery", "errors_cell0", "drift_cell0", "sensitivity_cell0"] {
        assert!(names.contains(&want), "figure {want} missing from {names:?}");
    }
    assert!(report.notes.is_empty(), "{:?}", report.notes);
    for f in &report.figures {
        check_figure(f);
        let file = out.join("report").join(format!("{}.svg", f.name));
        assert_eq!(std::fs::read_to_string(&file).unwrap(), f.svg);
    }
    assert_eq!(written.len(), report.figures.len() + 1);
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    check_page(&html, &report.figures);
    // 42 histograms of the cube's parameters, 4 drift metrics, 4 identifiability kinds.
    let panels = |n: &str| report.figures.iter().find(|f| f.name == n).map(|f| f.panels.len()).unwrap_or(0);
    assert_eq!(panels("errors_cell0"), 42);
    assert_eq!(panels("drift_cell0"), 4);
    assert_eq!(panels("identifiability"), 4);
    // The paper schedule's six blind location components are the weak ones, named in the
    // recovery plot and highlighted in the table.
    let recovery = report.figures.iter().find(|f| f.name == "location_recovery").unwrap();
    assert!(recovery.svg.contains("weak: a1.dz, a2.dy, a3.dx, a4.dx, a5.dy, a6.dz"), "weak set");
    assert_eq!(html.matches("<tr class=\"weak\">").count(), 6);
    fits_the_page(&html, &report.figures);
    // Issue 30, item 3: the share of the trials with an estimate, and which trials the parameter
    // statistics use.
    assert!(html.contains("of 600 trials") && html.contains("parameter statistics"), "fits per cell");
}

/// Issue 30, item 8: figures scale to the page (no fixed 1,750-1,920 px SVG running off it): none
/// is wider than 1,200 px, each has a viewBox, and the page scales them to its width; no axis
/// reads "density [1/1]".
fn fits_the_page(html: &str, figures: &[Figure]) {
    assert!(html.contains("svg{max-width:100%;height:auto}"), "the page scales its figures");
    for f in figures {
        let head = &f.svg[..f.svg.find('>').unwrap()];
        let attr = |name: &str| -> f64 {
            let at = head.find(&format!(" {name}=\"")).unwrap_or_else(|| panic!("{}: no {name}: {head}", f.name));
            let rest = &head[at + name.len() + 3..];
            rest[..rest.find('"').unwrap()].parse().unwrap()
        };
        assert!(attr("width") <= 1200.0, "{}: {} px wide", f.name, attr("width"));
        assert!(head.contains("viewBox"), "{}: {head}", f.name);
        assert!(!f.svg.contains("[1/1]"), "{}: density [1/1]", f.name);
    }
    assert!(!html.contains("[1/1]"));
}

#[test]
fn report_marks_weak_parameters_only_on_the_paper_schedule() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/hung_lee_2006.toml"))
        .unwrap()
        .replace("trials_per_cell = 1000", "trials_per_cell = 60")
        .replace("horizons_s = [1.0, 2.0, 5.0, 10.0]", "horizons_s = [0.5, 1.0]")
        .replace("step_s = 0.01", "step_s = 0.05");
    let out = run_config(tmp.path(), &text);
    let (report, _) = write_run_report(&out).unwrap();
    for f in &report.figures {
        check_figure(f);
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    check_page(&html, &report.figures);
    // Two cells: the paper schedule's six weak rows, none on the augmented schedule.
    let (paper, augmented) = html.split_once("Cell 1:").unwrap();
    assert_eq!(paper.matches("<tr class=\"weak\">").count(), 6);
    assert_eq!(augmented.matches("<tr class=\"weak\">").count(), 0);
    let ident = report.figures.iter().find(|f| f.name == "identifiability").unwrap();
    assert!(ident.svg.contains("schedule.preset = hung_lee_2006_augmented"));
    // Fixed true errors: nothing varies for the nominal compensation, the estimated one's
    // errors do, but 60 trials cannot carry a regression on as many inputs (issue 30, item 4): no
    // sensitivity figure, and the page says why.
    assert!(!report.figures.iter().any(|f| f.name.starts_with("sensitivity")));
    assert!(
        augmented.contains("get no sensitivity coefficients") && augmented.contains("fewer than 10 trials per input")
    );
}

#[test]
fn report_of_a_folder_without_a_run_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_gfcal")).args(["report"]).arg(tmp.path()).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("run.json") && err.contains("is this a gfcal run folder"), "{err}");
    assert!(!tmp.path().join("report.html").exists());
}

/// A Saltelli design where only a1.bias matters (a2.bias varies a thousand times less).
const SALTELLI: &str = r#"
name = "saltelli"
seed = 3

[sensitivity]
design = "saltelli"
base_samples = 500

[errors]
bias_mg = { dist = "normal", sigma = [1.0, 0.001, 0.0, 0.0, 0.0, 0.0] }

[noise]
white_density_ug_per_sqrt_hz = 50.0

[schedule]
# The augmented schedule: with exact nominal axes the paper's schedule cannot see the weak
# location components, and a fit that runs off along them is not converged (no estimated
# compensation to navigate with).
preset = "hung_lee_2006_augmented"
step_duration_s = 0.5
sample_rate_hz = 100.0

[trajectory]
kind = "paper_manoeuvre"

[navigation]
step_s = 0.02
horizons_s = [0.5, 1.0]
compensations = ["nominal", "estimated"]

[output]
trials_per_part = 300
"#;

#[test]
fn sobol_indices_give_the_one_error_source_the_whole_index() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run_config(tmp.path(), SALTELLI);
    // The design comes from per-block streams: one thread and three shards give the same table.
    let path = tmp.path().join("config.toml");
    let cfg = McConfig::load(&path).unwrap();
    let other = tmp.path().join("other");
    for shard in 0..3 {
        let opts =
            RunOptions { out: other.clone(), resume: shard > 0, force: false, shard: (shard, 3), threads: Some(1) };
        run(&cfg, &path, &opts, &Silent).unwrap();
    }
    for sub in ["trials", "parameters"] {
        let read = |dir: &Path| -> Vec<arrow_array::RecordBatch> {
            gfcal::io::parquet::part_files(&dir.join(sub))
                .iter()
                .flat_map(|f| gfcal::io::parquet::read_batches(f).unwrap())
                .collect()
        };
        assert_eq!(read(&out), read(&other), "{sub}");
    }
    let cfg = gfcal::report::run::load_config(&out).unwrap();
    // Two inputs: 500 x (2 + 2) trials.
    assert_eq!(cfg.trials_per_cell, 2000);
    let rows = gfcal::mc::sobol::sobol(&out, &cfg).unwrap();
    for metric in ["velocity_err_m_s", "position_err_m"] {
        let col = format!("nominal_{metric}_at_1s");
        let get = |input: &str| rows.iter().find(|r| r.output == col && r.input == input).unwrap();
        let (a1, a2) = (get("a1.bias"), get("a2.bias"));
        assert_eq!(a1.base_samples, 500);
        // One input explains everything: S = ST = 1, up to the estimators' sampling error
        // (about 1/sqrt(500) for the first order).
        assert!((a1.first_order - 1.0).abs() < 0.12 && (a1.total - 1.0).abs() < 0.05, "{col}: {a1:?}");
        assert!(a1.first_order_lo <= a1.first_order && a1.first_order <= a1.first_order_hi);
        assert!(a2.first_order.abs() < 0.01 && a2.total < 0.01, "{col}: {a2:?}");
    }
    // With estimated compensation the drift comes from the estimation error, which for a bias is
    // the noise's alone (the model is linear in it): the true bias explains none of it. The noise
    // is held between a block's A and AB rows, so it does not leak into the bias's total index.
    let col = "estimated_velocity_err_m_s_at_1s";
    let a1 = rows.iter().find(|r| r.output == col && r.input == "a1.bias").unwrap();
    assert!(a1.total < 0.02 && a1.first_order.abs() < 0.1, "{a1:?}");
    // The design is in the trials table for an analyst.
    let parts = gfcal::io::parquet::part_files(&out.join("trials"));
    assert_eq!(parts.len(), 7);
    let batches = gfcal::io::parquet::read_batches(&parts[0]).unwrap();
    let matrix = batches[0].column_by_name("saltelli_matrix").unwrap();
    let matrix = matrix.as_any().downcast_ref::<arrow_array::StringArray>().unwrap();
    let first: Vec<&str> = (0..4).map(|i| matrix.value(i)).collect();
    assert_eq!(first, ["A", "B", "AB:a1.bias", "AB:a2.bias"]);
    // The report draws them.
    let (report, _) = write_run_report(&out).unwrap();
    let sobol = report.figures.iter().find(|f| f.name == "sobol_cell0").expect("Sobol' figure");
    check_figure(sobol);
    assert_eq!(sobol.panels.len(), 8);
}

/// `gfcal run` of `text` exits with 2, names `words` and writes nothing.
fn run_refused(text: &str, words: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("bad.toml");
    std::fs::write(&path, text).unwrap();
    let out = tmp.path().join("o");
    let o = Command::new(env!("CARGO_BIN_EXE_gfcal")).arg("run").arg(&path).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    for w in words {
        assert!(err.contains(w), "`{w}` not in: {err}");
    }
    assert!(!out.exists());
}

#[test]
fn bad_saltelli_designs_are_refused() {
    run_refused(
        &SALTELLI.replace("seed = 3", "seed = 3\ntrials_per_cell = 10"),
        &["bad.toml", "trials_per_cell", "Saltelli"],
    );
    run_refused(
        &SALTELLI.replace("sigma = [1.0, 0.001, 0.0, 0.0, 0.0, 0.0]", "sigma = 0.0"),
        &["no error parameter varies"],
    );
    run_refused(
        &SALTELLI.replace("base_samples = 500", "base_samples = 1"),
        &["sensitivity.base_samples", "at least 2"],
    );
    run_refused(&SALTELLI.replace("design = \"saltelli\"", "design = \"morris\""), &["bad.toml", "morris"]);
}

#[test]
fn diagnosis_report_shows_the_gap_shrink_after_each_effect() {
    use gfcal::discrepancy::log::CalibrationLog;
    use gfcal::discrepancy::log::{DiagnoseSettings, diagnose};
    let tmp = tempfile::tempdir().unwrap();
    let log_path = tmp.path().join("log.parquet");
    let html_path = tmp.path().join("diagnosis.html");
    let gfcal = |args: &[&std::ffi::OsStr]| {
        let o = Command::new(env!("CARGO_BIN_EXE_gfcal"))
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    gfcal(&[
        "simulate-log".as_ref(),
        "configs/discrepancy_example.toml".as_ref(),
        "--out".as_ref(),
        log_path.as_os_str(),
    ]);
    gfcal(&["diagnose".as_ref(), log_path.as_os_str(), "--report".as_ref(), html_path.as_os_str()]);
    let html = std::fs::read_to_string(&html_path).unwrap();
    // The same diagnosis through the library, to check the figures.
    let array = gfcal::array::Array::cube(0.1).unwrap();
    let log = CalibrationLog::read(&log_path, 6).unwrap();
    let d = diagnose(&log, &array, &gfcal::sensor::ArrayParams::nominal(&array), &DiagnoseSettings::default()).unwrap();
    let r = gfcal::report::diagnosis::diagnosis_report(&log_path.display().to_string(), &log, &d, 0.01).unwrap();
    assert_eq!(r.html, html);
    check_page(&html, &r.figures);
    for f in &r.figures {
        check_figure(f);
    }
    // Baseline, then the hidden quadratic term on accelerometer 3: the gap falls from well above
    // the noise to about 1, and the residual panels are one per stage.
    let labels: Vec<&str> = d.stages.iter().map(|s| s.label.as_str()).collect();
    assert_eq!(labels, ["baseline", "+ scale_factor_quadratic (accelerometer 3)"]);
    assert!(d.stages[0].gap > 5.0 && d.stages[1].gap < 1.5, "{:?}", d.stages.iter().map(|s| s.gap).collect::<Vec<_>>());
    assert_eq!(d.stages[1].per_step, d.per_step_after);
    assert_eq!(d.stages[0].per_step, d.baseline.whitened);
    let residuals = r.figures.iter().find(|f| f.name == "residuals").unwrap();
    assert_eq!(residuals.panels.len(), 2);
    // Every step of every accelerometer is drawn in each panel.
    assert!(residuals.panels.iter().all(|p| p.data_points >= log.steps.len() * 6));
    assert!(html.contains("scale_factor_quadratic"));
}

#[test]
fn report_of_an_incomplete_run_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("config.toml");
    std::fs::write(&path, SALTELLI).unwrap();
    let cfg = McConfig::load(&path).unwrap();
    let out = tmp.path().join("out");
    // The first of three shards: 3 of the 7 parts.
    let opts = RunOptions { out: out.clone(), resume: false, force: false, shard: (0, 3), threads: Some(2) };
    run(&cfg, &path, &opts, &Silent).unwrap();
    std::fs::create_dir_all(out.join("report")).unwrap();
    std::fs::write(out.join("report/sobol_cell0.svg"), "<svg/>").unwrap();
    let (report, written) = write_run_report(&out).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("The run is not complete"));
    // A figure this report does not draw is not left behind from an earlier one.
    assert!(!out.join("report/sobol_cell0.svg").exists());
    assert_eq!(std::fs::read_dir(out.join("report")).unwrap().count(), written.len() - 1);
    // Sobol' indices need every row of a block: none are drawn, and the page says why.
    assert!(report.figures.iter().all(|f| !f.name.starts_with("sobol")));
    assert!(report.notes.iter().any(|n| n.contains("Sobol' indices (the run is incomplete")), "{:?}", report.notes);
    for f in &report.figures {
        check_figure(f);
    }
}

/// Units that belong to no SI display: before issue 13 the report showed mg, ppm, mrad and mm,
/// `identify` g, deg and mm, while summary.csv was SI.
const NOT_SI: [&str; 10] = ["[mg]", "[ppm]", "[mrad]", "[mm]", "(mg)", "(ppm)", "(mrad)", "(mm)", " arcsec", "[deg]"];

#[test]
fn one_unit_per_quantity_in_summary_report_identify_and_diagnose() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(repo.join("configs/quickstart.toml"))
        .unwrap()
        .replace("trials_per_cell = 20000", "trials_per_cell = 200");
    let out = run_config(tmp.path(), &text);
    // summary.csv: parameter name -> unit.
    let summary = gfcal::mc::summary::summary_csv(&gfcal::mc::summary::summarize(&out).unwrap());
    let units: std::collections::HashMap<String, String> = summary
        .lines()
        .filter(|l| l.starts_with("parameter,"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[2].to_string(), f[3].to_string())
        })
        .collect();
    assert_eq!(units["a1.bias"], "m/s^2");
    assert_eq!(units["a1.dx"], "m");
    // report.html: every axis in an SI unit; no other unit in its text.
    let (report, _) = write_run_report(&out).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for bad in NOT_SI {
        assert!(!html.contains(bad), "report.html shows {bad}");
    }
    let si = ["1", "m/s^2", "rad", "m", "rad/s", "m/s", "s", "m/s^2/sqrt(Hz)", "m per m"];
    for f in &report.figures {
        for p in &f.panels {
            for label in [&p.x_label, &p.y_label] {
                if let Some((_, u)) = label.rsplit_once(" [") {
                    let u = u.trim_end_matches(']');
                    let base = u.strip_prefix("1/").unwrap_or(u); // a density per unit
                    assert!(si.contains(&base) || u.starts_with("log10"), "{} / {}: axis unit [{u}]", f.name, label);
                }
            }
        }
    }
    assert!(html.contains("Units: SI throughout"));
    // identify: the same unit as summary.csv for every parameter both name.
    let o = Command::new(env!("CARGO_BIN_EXE_gfcal"))
        .args(["identify", "configs/hung_lee_2006_design.toml"])
        .current_dir(repo)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let mut compared = 0;
    for line in stdout.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.len() >= 4
            && let Some(u) = units.get(f[0])
        {
            assert_eq!(f[1], u, "identify shows {} in {}, summary.csv in {u}", f[0], f[1]);
            compared += 1;
        }
    }
    assert!(compared >= 30, "{compared} parameters compared:\n{stdout}");
    for bad in NOT_SI.iter().chain(&[" mg ", " ug/sqrt(Hz)"]) {
        assert!(!stdout.contains(bad), "identify shows {bad}");
    }
    // diagnose: SI in its JSON, its report and its printout.
    let log = tmp.path().join("log.parquet");
    let sim = Command::new(env!("CARGO_BIN_EXE_gfcal"))
        .args(["simulate-log", "configs/discrepancy_example.toml", "--out", log.to_str().unwrap()])
        .current_dir(repo)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    let json = tmp.path().join("d.json");
    let page = tmp.path().join("d.html");
    let d = Command::new(env!("CARGO_BIN_EXE_gfcal"))
        .args(["diagnose", log.to_str().unwrap(), "--json", json.to_str().unwrap(), "--report", page.to_str().unwrap()])
        .current_dir(repo)
        .output()
        .unwrap();
    assert!(d.status.success(), "{}", String::from_utf8_lossy(&d.stderr));
    let printed = String::from_utf8_lossy(&d.stdout);
    let page = std::fs::read_to_string(&page).unwrap();
    for bad in NOT_SI.iter().chain(&[" mg ", " ppm"]) {
        assert!(!printed.contains(bad) && !page.contains(bad), "diagnose shows {bad}");
    }
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for e in v["effects"].as_array().unwrap() {
        let u = e["unit"].as_str().unwrap();
        assert!(!["mg", "ppm", "deg", "mm", "mrad", "ug"].iter().any(|b| u.contains(b)), "effect unit {u}");
    }
}

/// The small sweep of the batch-engine tests: 30 trials a cell against 42 varying inputs.
const THIRTY_A_CELL: &str = r#"
name = "thirty"
seed = 7
trials_per_cell = 30

[errors]
bias_mg = { dist = "normal", sigma = 1.0 }
scale_factor_ppm = { dist = "uniform", half_width = 300.0 }
misalignment_deg = { dist = "normal", sigma = 0.5 }
location_mm = { dist = "normal", sigma = 1.0 }

[noise]
white_density_ug_per_sqrt_hz = 50.0

[schedule]
preset = "hung_lee_2006_augmented"
step_duration_s = 0.5
sample_rate_hz = 100.0

[trajectory]
kind = "paper_manoeuvre"

[navigation]
step_s = 0.02
horizons_s = [0.5, 1.0]
compensations = ["nominal", "estimated"]
"#;

/// Issue 30, item 4: with fewer than 10 trials per input the rank regression gives no
/// coefficients, and the report draws none (it says why instead).
#[test]
fn the_report_draws_no_coefficients_that_overfit() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run_config(tmp.path(), THIRTY_A_CELL);
    let (report, _) = write_run_report(&out).unwrap();
    assert!(!report.figures.iter().any(|f| f.name.starts_with("sensitivity")), "no sensitivity figure");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("fewer than 10 trials per input"), "says why");
}

/// Issue 30, item 8: a sensitivity panel whose rank regression explains little (R^2 below 0.1)
/// is marked weak. Tiny true errors and navigation noise: the nominal compensation's drift is
/// the noise's, which the errors' magnitudes do not explain.
#[test]
fn a_weak_sensitivity_panel_is_marked() {
    let text = THIRTY_A_CELL
        .replace("trials_per_cell = 30", "trials_per_cell = 450")
        .replace("sigma = 1.0 }", "sigma = 0.00001 }")
        .replace("half_width = 300.0", "half_width = 0.001")
        .replace("sigma = 0.5 }", "sigma = 0.00001 }")
        .replace("white_density_ug_per_sqrt_hz = 50.0", "white_density_ug_per_sqrt_hz = 500.0")
        .replace("compensations = [\"nominal\", \"estimated\"]", "compensations = [\"nominal\"]\nnoise = true");
    let tmp = tempfile::tempdir().unwrap();
    let out = run_config(tmp.path(), &text);
    let (report, _) = write_run_report(&out).unwrap();
    let sens = report.figures.iter().find(|f| f.name == "sensitivity_cell0").expect("a sensitivity figure");
    // Each panel's R^2, from the regression the report draws (not from its title, which rounds).
    let rows = gfcal::mc::sensitivity::sensitivity(&out, gfcal::report::run::SENSITIVITY_TRIALS).unwrap();
    let mut weak = 0;
    for p in &sens.panels {
        let output = p.title.split(' ').next().unwrap();
        let r2 = rows.iter().find(|r| r.output == output).and_then(|r| r.r2).expect("the panel's regression");
        eprintln!("{}: R^2 {r2}", p.title);
        if r2 < 0.1 {
            weak += 1;
            assert!(p.title.contains("weak"), "{}", p.title);
        } else {
            assert!(!p.title.contains("weak"), "{}", p.title);
        }
    }
    assert!(weak > 0, "the case has a weak panel");
}

/// The `<text>` elements of an SVG: (attributes, content).
fn svg_texts(svg: &str) -> Vec<(std::collections::HashMap<String, String>, String)> {
    let mut out = Vec::new();
    for chunk in svg.split("<text ").skip(1) {
        let (head, rest) = chunk.split_once('>').unwrap();
        let content = rest.split("</text>").next().unwrap().to_string();
        let mut attrs = std::collections::HashMap::new();
        for part in head.split("\" ") {
            if let Some((k, v)) = part.split_once("=\"") {
                attrs.insert(k.trim().to_string(), v.trim_end_matches('"').to_string());
            }
        }
        out.push((attrs, content));
    }
    out
}

/// The centres' y of the `<circle>` elements of an SVG.
fn circle_ys(svg: &str) -> Vec<f64> {
    svg.split("<circle ").skip(1).filter_map(|c| c.split("cy=\"").nth(1)?.split('"').next()?.parse().ok()).collect()
}

/// Issue 30, item 8: one number format per axis (tick labels were "1.00e-6" beside "0.00100" on
/// one log axis, "5.0e-5" beside "0.00010" on one linear axis), and legends that do not cover
/// data (five entries in a small panel hid its upper left).
#[test]
fn one_number_format_per_axis_and_legends_off_the_data() {
    use gfcal::report::{Item, Panel, render};
    let points: Vec<(f64, f64)> = (0..50).map(|i| (i as f64 * 7e-6, 1e-6 * 10f64.powf(i as f64 / 7.0))).collect();
    // The points carry no label, so that every circle drawn is data (a labelled item's legend
    // glyph would be a circle too); five guides make five legend entries.
    let mut panel = Panel::new("formats", "time [s]", "error [m]").log_y().with(Item::Points {
        label: None,
        points: points.clone(),
        colour: 0,
    });
    for k in 1..6 {
        panel = panel.with(Item::Line {
            label: Some(format!("guide {k}")),
            points: vec![(0.0, 1e-6 * k as f64), (3.4e-4, 30.0)],
            colour: k,
            dashed: k % 2 == 0,
        });
    }
    let linear = Panel::new("linear", "offset [m]", "value [m]").with(Item::Line {
        label: None,
        points: vec![(990.0, 0.001), (1010.0, 0.0025)],
        colour: 0,
        dashed: false,
    });
    for (panels, size) in [(vec![panel.clone()], (250, 190)), (vec![linear], (400, 300)), (vec![panel], (560, 380))] {
        let f = render("t", "T", "", &panels, 1, size).unwrap();
        let texts: Vec<_> = svg_texts(&f.svg).into_iter().map(|(a, c)| (a, c.trim().to_string())).collect();
        let tick_size = format!("{}", 10.0 / 1.24);
        for anchor in ["end", "middle"] {
            let labels: Vec<&str> = texts
                .iter()
                .filter(|(a, _)| {
                    a.get("font-size") == Some(&tick_size) && a.get("text-anchor").map(String::as_str) == Some(anchor)
                })
                .map(|(_, c)| c.as_str())
                .filter(|c| *c != "0")
                .collect();
            assert!(labels.len() >= 2, "{anchor}: {labels:?}");
            let scientific = labels.iter().filter(|l| l.contains('e')).count();
            assert!(scientific == 0 || scientific == labels.len(), "one format per axis ({anchor}): {labels:?}");
        }
        let ys = circle_ys(&f.svg);
        if ys.is_empty() {
            continue;
        }
        assert_eq!(ys.len(), points.len(), "one circle per point");
        let (top, bottom) = (ys.iter().copied().fold(f64::INFINITY, f64::min), ys.iter().copied().fold(0.0, f64::max));
        assert_eq!(texts.iter().filter(|(_, c)| c.starts_with("guide ")).count(), 5, "five legend entries");
        for (attrs, content) in &texts {
            if content.starts_with("guide ") {
                let y: f64 = attrs["y"].parse().unwrap();
                assert!(
                    y < top - 3.0 || y > bottom + 3.0,
                    "legend `{content}` at y {y} lies over the data ({top}..{bottom})"
                );
            }
        }
    }
}
