//! `gfcal report DIR`: the report of a run, from its Parquet output.
//!
//! Per cell (schedule, noise level, ... of the sweep):
//! - the estimation error of every parameter: histogram, with the normal density the Cramer-Rao
//!   bound predicts drawn over it, and a table of bias, RMSE, Cramer-Rao sigma, normalised error
//!   and 95% coverage;
//! - drift against horizon: median and 5-95% band of each drift metric for each compensation,
//!   log-log, with t, t^2, t^3, t^4 guide lines;
//! - sensitivity: standardised rank regression coefficients of the error parameters for each
//!   drift metric at the last horizon, and first-order and total Sobol' indices with bootstrap
//!   confidence intervals when the run used a Saltelli design (`[sensitivity]` in its config).
//!
//! Across cells: the Cramer-Rao sigma of every parameter on a log scale, cells side by side, weak
//! parameters marked; and recovered against true for every location error.
//!
//! A parameter is *weak* in a cell when its Cramer-Rao sigma is more than [`WEAK_FACTOR`] times
//! the median sigma of the parameters of its kind in that cell (or infinite).
//!
//! Histograms and scatter plots use the first trials of each cell (at most [`SAMPLE_PER_CELL`]);
//! the tables use every trial (the run's summary).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow_array::{Float64Array, StringArray, UInt32Array};

use super::html::Page;
use super::plot::{Figure, Item, Panel, render};
use super::{ReportError, display_unit, kind_of_unit};
use crate::io::format::significant as sig;
use crate::io::parquet::{ParquetIoError, column, part_files, read_batches};
use crate::mc::config::{Cell, FactorValue, McConfig};
use crate::mc::output::drift_column;
use crate::mc::sensitivity::{SensitivityRow, sensitivity};
use crate::mc::sobol::{SobolRow, sobol};
use crate::mc::summary::{Summary, cell_fits, cell_flags, of_cell, summarize};
use crate::mc::trial::DRIFT_METRICS;

/// A parameter is weak when its Cramer-Rao sigma exceeds this multiple of its kind's median.
pub const WEAK_FACTOR: f64 = 10.0;
/// Trials per cell read for the histograms and scatter plots.
pub const SAMPLE_PER_CELL: usize = 2000;
/// Trials per cell used for the rank regression.
pub const SENSITIVITY_TRIALS: usize = 5000;
/// Cells shown side by side in the across-cell figures.
pub const MAX_CELLS_SIDE_BY_SIDE: usize = 6;

/// A rendered report.
#[derive(Debug, Clone)]
pub struct RunReport {
    pub html: String,
    pub figures: Vec<Figure>,
    /// What could not be shown, and why.
    pub notes: Vec<String>,
}

/// Reads the run's config back from `DIR/run.json`.
pub fn load_config(dir: &Path) -> Result<McConfig, ReportError> {
    let run_file = dir.join("run.json");
    let input = |problem: String| ReportError::Input { path: run_file.clone(), problem };
    let text = std::fs::read_to_string(&run_file)
        .map_err(|e| input(format!("cannot read ({e}); is this a gfcal run folder?")))?;
    let run: serde_json::Value = serde_json::from_str(&text).map_err(|e| input(format!("not JSON: {e}")))?;
    let config_text = run["config_text"].as_str().ok_or_else(|| input("no `config_text`".into()))?.to_string();
    let origin = PathBuf::from(run["config_path"].as_str().unwrap_or("run.json"));
    McConfig::from_text(config_text, &origin).map_err(|e| input(format!("its config does not load: {e}")))
}

/// One cell's description: its sweep factors, else its schedule.
pub fn describe(cell: &Cell) -> String {
    if cell.factors.is_empty() {
        return format!("schedule {}", cell.schedule.name);
    }
    cell.factors
        .iter()
        .map(|(k, v)| match v {
            FactorValue::Number(x) => format!("{k} = {}", sig(*x, 4)),
            FactorValue::Text(t) => format!("{k} = {t}"),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// (true, estimated, error, crb_sigma) of the first trials of a cell, SI, per parameter name.
#[derive(Debug, Default)]
struct Sample {
    rows: BTreeMap<String, Vec<[f64; 4]>>,
}

fn read_samples(dir: &Path, cells: usize, cap: usize) -> Result<Vec<Sample>, ParquetIoError> {
    let mut out: Vec<Sample> = (0..cells).map(|_| Sample::default()).collect();
    for file in part_files(&dir.join("parameters")) {
        if out.iter().all(|s| s.rows.values().all(|r| r.len() >= cap) && !s.rows.is_empty()) {
            break;
        }
        for b in read_batches(&file)? {
            let cell = column::<UInt32Array>(&b, "cell", &file)?;
            let name = column::<StringArray>(&b, "name", &file)?;
            let t = column::<Float64Array>(&b, "true", &file)?;
            let e = column::<Float64Array>(&b, "estimated", &file)?;
            let err = column::<Float64Array>(&b, "error", &file)?;
            let crb = column::<Float64Array>(&b, "crb_sigma", &file)?;
            for i in 0..b.num_rows() {
                let Some(s) = out.get_mut(cell.value(i) as usize) else { continue };
                // No allocation per row once the parameter is known.
                let rows = match s.rows.get_mut(name.value(i)) {
                    Some(rows) => rows,
                    None => s.rows.entry(name.value(i).to_string()).or_default(),
                };
                if rows.len() < cap {
                    rows.push([t.value(i), e.value(i), err.value(i), crb.value(i)]);
                }
            }
        }
    }
    Ok(out)
}

fn median(v: Vec<f64>) -> f64 {
    crate::stats::median(&v)
}

/// Which parameters of a cell are weak (by name), from the summary's RMS Cramer-Rao sigmas.
fn weak_parameters(summary: &Summary, cell: u32) -> Vec<String> {
    let mine: Vec<_> = summary.parameters_of(cell).iter().collect();
    let mut weak = Vec::new();
    for kind in ["bias", "scale factor", "misalignment", "location"] {
        let of_kind: Vec<_> = mine.iter().filter(|p| kind_of_unit(&p.unit) == kind).collect();
        let m = median(of_kind.iter().map(|p| p.crb_sigma).collect());
        for p in of_kind {
            if p.crb_sigma.is_infinite() || (m > 0.0 && p.crb_sigma > WEAK_FACTOR * m) {
                weak.push(p.name.clone());
            }
        }
    }
    weak
}

fn normal_pdf(x: f64, sigma: f64) -> f64 {
    (-0.5 * (x / sigma).powi(2)).exp() / (sigma * (2.0 * std::f64::consts::PI).sqrt())
}

/// The estimation-error histograms of one cell.
fn error_figure(cfg: &McConfig, c: usize, sample: &Sample) -> Result<Option<Figure>, ReportError> {
    let cell = &cfg.cells[c];
    let layout = &cell.layout;
    let mut panels = Vec::new();
    let mut n_used = 0;
    for i in 0..layout.len() {
        let name = layout.name(i);
        let Some(rows) = sample.rows.get(&name) else { continue };
        let (unit, f) = display_unit(layout.kind(i).si_unit());
        let errs: Vec<f64> = rows.iter().map(|r| r[2] * f).filter(|e| e.is_finite()).collect();
        if errs.is_empty() {
            continue;
        }
        n_used = n_used.max(rows.len());
        let crbs: Vec<f64> = rows.iter().map(|r| r[3] * f).filter(|s| s.is_finite() && *s > 0.0).collect();
        let centre = median(errs.clone());
        let mad = 1.4826 * median(errs.iter().map(|e| (e - centre).abs()).collect());
        // The median bound, not the RMS: a weak parameter's bound is huge in a few trials.
        let mut range = 4.0 * median(crbs.clone()).max(mad);
        if !(range.is_finite() && range > 0.0) {
            range = errs.iter().fold(0.0f64, |m, e| m.max(e.abs())).max(1e-12);
        }
        let bins = 30;
        let w = 2.0 * range / bins as f64;
        let mut counts = vec![0usize; bins];
        let mut outside = 0;
        for e in &errs {
            let b = ((e + range) / w).floor();
            if b >= 0.0 && (b as usize) < bins {
                counts[b as usize] += 1;
            } else {
                outside += 1;
            }
        }
        let n = errs.len() as f64;
        let bars: Vec<(f64, f64, f64)> = counts
            .iter()
            .enumerate()
            .map(|(k, &m)| (-range + k as f64 * w, -range + (k + 1) as f64 * w, m as f64 / (n * w)))
            .collect();
        let first = panels.is_empty();
        let title = if outside > 0 { format!("{name} ({outside} outside)") } else { name.clone() };
        // The density of a dimensionless error is dimensionless: [1], not [1/1].
        let density = if unit == "1" { "density [1]".to_string() } else { format!("density [1/{unit}]") };
        let mut panel = Panel::new(title, format!("error [{unit}]"), density).with(Item::Bars {
            label: first.then(|| "trials".to_string()),
            bars,
            colour: 0,
        });
        if !crbs.is_empty() {
            let curve: Vec<(f64, f64)> = (0..=100)
                .map(|k| {
                    let x = -range + 2.0 * range * k as f64 / 100.0;
                    (x, crbs.iter().map(|s| normal_pdf(x, *s)).sum::<f64>() / crbs.len() as f64)
                })
                .collect();
            panel = panel.with(Item::Line {
                label: first.then(|| "Cramer-Rao normal".to_string()),
                points: curve,
                colour: 1,
                dashed: false,
            });
        }
        panels.push(panel);
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let caption = format!(
        "Estimated minus true value of every parameter over the first {n_used} trials of cell {c} ({}). \
         The curve is the density the Cramer-Rao bound predicts: the average over trials of N(0, crb_sigma^2), \
         which holds when the bound varies from trial to trial. A histogram wider than its curve means an \
         inefficient estimator; a shifted one, a bias.",
        describe(cell)
    );
    Ok(Some(render(
        &format!("errors_cell{c}"),
        &format!("Estimation error, cell {c}"),
        &caption,
        &panels,
        crate::calib::params::PER_ACCEL,
        (170, 160),
    )?))
}

/// Cramer-Rao sigma of every parameter, cells side by side, weak ones marked.
fn identifiability_figure(cfg: &McConfig, summary: &Summary) -> Result<Option<Figure>, ReportError> {
    let cells: Vec<usize> = (0..cfg.cells.len().min(MAX_CELLS_SIDE_BY_SIDE)).collect();
    let layout = &cfg.cells[0].layout;
    let mut panels = Vec::new();
    for kind in ["bias", "scale factor", "misalignment", "location"] {
        let idx: Vec<usize> = (0..layout.len()).filter(|&i| kind_of_unit(layout.kind(i).si_unit()) == kind).collect();
        if idx.is_empty() {
            continue;
        }
        let (unit, f) = display_unit(layout.kind(idx[0]).si_unit());
        let names: Vec<String> = idx.iter().map(|&i| layout.name(i)).collect();
        let mut panel =
            Panel::new(format!("{kind}: Cramer-Rao sigma"), "parameter", format!("Cramer-Rao sigma [{unit}]"))
                .log_y()
                .categorical(names.clone());
        let k = cells.len() as f64;
        let mut weak_points = Vec::new();
        for (ci, &c) in cells.iter().enumerate() {
            let weak = weak_parameters(summary, c as u32);
            let mut bars = Vec::new();
            for (x, name) in names.iter().enumerate() {
                let Some(p) = summary.parameters_of(c as u32).iter().find(|p| &p.name == name) else {
                    continue;
                };
                let x0 = x as f64 - 0.4 + 0.8 * ci as f64 / k;
                let x1 = x0 + 0.8 / k;
                bars.push((x0, x1, p.crb_sigma * f));
                if weak.contains(name) && p.crb_sigma.is_finite() {
                    weak_points.push((0.5 * (x0 + x1), p.crb_sigma * f * 1.6));
                }
            }
            panel = panel.with(Item::Bars {
                label: Some(format!("cell {c}: {}", describe(&cfg.cells[c]))),
                bars,
                colour: ci,
            });
        }
        if !weak_points.is_empty() {
            panel = panel.with(Item::Points {
                label: Some(format!("weak (> {WEAK_FACTOR}x its kind's median)")),
                points: weak_points,
                colour: 7,
            });
        }
        if panel.data_points() > 0 {
            panels.push(panel);
        }
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let caption = format!(
        "Root-mean-square Cramer-Rao sigma of every parameter over each cell's trials, on a log scale, \
         cells side by side{}. A black dot marks a weak parameter: its bound is more than {WEAK_FACTOR} times \
         the median of its kind in that cell, so the schedule hardly sees it.",
        if cfg.cells.len() > MAX_CELLS_SIDE_BY_SIDE {
            format!(" (the first {MAX_CELLS_SIDE_BY_SIDE} of {} cells)", cfg.cells.len())
        } else {
            String::new()
        }
    );
    Ok(Some(render("identifiability", "Identifiability", &caption, &panels, 1, (1200, 330))?))
}

/// Median and 5-95% band of every drift metric against horizon, per compensation.
fn drift_figure(cfg: &McConfig, c: usize, summary: &Summary) -> Result<Option<Figure>, ReportError> {
    let cell = &cfg.cells[c];
    let nav = &cell.navigation;
    let labels = ["angular-rate error [rad/s]", "attitude error [rad]", "velocity error [m/s]", "position error [m]"];
    let mut panels = Vec::new();
    let mut diverged = Vec::new();
    let mut floors = Vec::new();
    let quantiles = |comp: &str, metric: &str| -> Vec<(f64, f64, f64, f64, u64, u64)> {
        nav.horizons_s
            .iter()
            .filter_map(|h| {
                let col = drift_column(comp, metric, *h);
                let d = summary.drift_of(c as u32).iter().find(|d| d.column == col)?;
                Some((*h, d.p05, d.median, d.p95, d.diverged, d.n))
            })
            .collect()
    };
    // With true parameters and noise-free outputs only the integrator's error is left: when it is
    // more than a hundred times below every median of the other compensations, for every metric,
    // drawing it would squeeze the other curves into the top of the plots; it is named instead.
    let largest_true = |metric: &str| quantiles("true", metric).iter().map(|q| q.2).fold(0.0, f64::max);
    let smallest_other = |metric: &str| {
        nav.compensations
            .iter()
            .filter(|comp| comp.name() != "true")
            .flat_map(|comp| quantiles(comp.name(), metric))
            .map(|q| q.2)
            .filter(|v| v.is_finite() && *v > 0.0)
            .fold(f64::INFINITY, f64::min)
    };
    let hide_true = nav.compensations.iter().any(|c| c.name() == "true")
        && DRIFT_METRICS.iter().all(|(metric, _)| {
            let other = smallest_other(metric);
            other.is_finite() && largest_true(metric) < 1e-2 * other
        });
    if hide_true {
        floors.extend(
            DRIFT_METRICS.iter().map(|(metric, _)| format!("{metric} at most {}", sig(largest_true(metric), 2))),
        );
    }
    for (m, (metric, _)) in DRIFT_METRICS.iter().enumerate() {
        let mut panel =
            Panel::new(labels[m].split(" [").next().unwrap_or(metric), "horizon [s]", labels[m]).log_x().log_y();
        let mut anchor: Option<(f64, f64)> = None;
        for (k, comp) in nav.compensations.iter().enumerate() {
            if hide_true && comp.name() == "true" {
                continue;
            }
            let q = quantiles(comp.name(), metric);
            let legend = m == 0;
            let mut med = Vec::new();
            let (mut lo, mut hi) = (Vec::new(), Vec::new());
            for &(h, p05, median, p95, n_diverged, n) in &q {
                // A navigation that diverges stays diverged: its count at the last horizon says it.
                if n_diverged > 0 && m == 0 && Some(&h) == nav.horizons_s.last() {
                    diverged.push(format!("{}, {n_diverged} of {n} trials by {h} s", comp.name()));
                }
                med.push((h, median));
                lo.push((h, p05));
                hi.push((h, p95));
            }
            if (anchor.is_none() || comp.name() == "estimated")
                && let Some(&(h, v)) = med.iter().find(|(_, v)| v.is_finite() && *v > 0.0)
            {
                anchor = Some((h, v));
            }
            panel = panel.with(Item::Band { label: None, lower: lo, upper: hi, colour: k }).with(Item::Line {
                label: legend.then(|| format!("{} (median, 5-95%)", comp.name())),
                points: med,
                colour: k,
                dashed: false,
            });
        }
        if let (Some((h0, y0)), true) = (anchor, nav.horizons_s.len() > 1) {
            let h1 = nav.horizons_s.last().copied().unwrap_or(h0);
            for p in 1..=4 {
                let pts: Vec<(f64, f64)> = (0..=10)
                    .map(|s| {
                        let h = h0 * (h1 / h0).powf(s as f64 / 10.0);
                        (h, y0 * (h / h0).powi(p))
                    })
                    .collect();
                panel = panel.with(Item::Line {
                    label: (m == 0).then(|| if p == 1 { "~ t".into() } else { format!("~ t^{p}") }),
                    points: pts,
                    colour: 2 + p as usize,
                    dashed: true,
                });
            }
        }
        if panel.data_points() > 0 {
            panels.push(panel);
        }
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let caption = format!(
        "Navigation error against horizon for cell {c} ({}) on the configured trajectory: median (line) and \
         5-95% band over the trials, for each compensation, log-log. Dashed: t, t^2, t^3, t^4 through the \
         median at the first horizon (a bias gives velocity ~ t and position ~ t^2; an angular-rate error gives \
         attitude ~ t, velocity ~ t^2, position ~ t^3).{} {}",
        describe(cell),
        if floors.is_empty() {
            String::new()
        } else {
            format!(
                " Not drawn: true-parameter compensation, whose error is the integrator's alone (median {}).",
                floors.join(", ")
            )
        },
        if diverged.is_empty() {
            "No navigation diverged.".to_string()
        } else {
            format!(
                "Diverged navigations (counted above every quantile; a quantile they reach is not drawn): {}.",
                diverged.join("; ")
            )
        }
    );
    Ok(Some(render(&format!("drift_cell{c}"), &format!("Drift, cell {c}"), &caption, &panels, 2, (560, 380))?))
}

/// Recovered against true for every location error, one panel per cell.
fn location_figure(cfg: &McConfig, samples: &[Sample], summary: &Summary) -> Result<Option<Figure>, ReportError> {
    let mut panels = Vec::new();
    for (c, cell) in cfg.cells.iter().enumerate().take(MAX_CELLS_SIDE_BY_SIDE) {
        let layout = &cell.layout;
        let weak = weak_parameters(summary, c as u32);
        let (mut strong_pts, mut weak_pts) = (Vec::new(), Vec::new());
        let mut weak_names = Vec::new();
        for i in (0..layout.len()).filter(|&i| layout.kind(i).si_unit() == "m") {
            let name = layout.name(i);
            let Some(rows) = samples[c].rows.get(&name) else { continue };
            let (_, f) = display_unit("m");
            let pts = rows.iter().take(200).map(|r| (r[0] * f, r[1] * f));
            if weak.contains(&name) {
                weak_names.push(name);
                weak_pts.extend(pts);
            } else {
                strong_pts.extend(pts);
            }
        }
        // Shown within +-limit: twice the largest true value, or the 95th percentile of the
        // recovered magnitudes if larger (a weak component can be off by metres when the
        // misalignment that reveals it is near zero); what lies beyond is counted in the title.
        let max_true =
            strong_pts.iter().chain(&weak_pts).map(|p| p.0.abs()).filter(|v| v.is_finite()).fold(0.0, f64::max);
        let mut recovered: Vec<f64> =
            strong_pts.iter().chain(&weak_pts).map(|p| p.1.abs()).filter(|v| v.is_finite()).collect();
        recovered.sort_by(f64::total_cmp);
        let p95 = recovered.get((0.95 * recovered.len() as f64) as usize).copied().unwrap_or(0.0);
        let limit = (2.0 * max_true).max(p95);
        let before = strong_pts.len() + weak_pts.len();
        let inside = |p: &(f64, f64)| p.0.abs() <= limit && p.1.abs() <= limit;
        strong_pts.retain(inside);
        weak_pts.retain(inside);
        let beyond = before - strong_pts.len() - weak_pts.len();
        let all: Vec<f64> = strong_pts.iter().chain(&weak_pts).map(|p| p.0).collect();
        if all.is_empty() || limit.is_nan() || limit <= 0.0 {
            continue;
        }
        let lo = all.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = all.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut panel = Panel::new(
            format!(
                "cell {c}: {}{}",
                describe(cell),
                if beyond > 0 { format!(" ({beyond} beyond +-{} m)", sig(limit, 2)) } else { String::new() }
            ),
            "true location error [m]",
            "recovered location error [m]",
        )
        .with(Item::Line {
            label: Some("recovered = true".into()),
            points: vec![(lo, lo), (hi, hi)],
            colour: 7,
            dashed: true,
        });
        // The weak ones first, so that the tight clusters of the others stay visible on top.
        if !weak_pts.is_empty() {
            panel = panel.with(Item::Points {
                label: Some(format!("weak: {}", weak_names.join(", "))),
                points: weak_pts,
                colour: 1,
            });
        }
        if !strong_pts.is_empty() {
            panel = panel.with(Item::Points { label: Some("well determined".into()), points: strong_pts, colour: 0 });
        }
        panels.push(panel);
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let caption = "Recovered against true value of every location error (each accelerometer's dx, dy, dz; at most 200 \
                   trials per parameter and cell). Points on the dashed line are recovered exactly; a weak component \
                   (orange) scatters along the vertical: the schedule cannot tell where that accelerometer sits along \
                   that axis (the question of the paper's Table 9).";
    Ok(Some(render("location_recovery", "Location errors: recovered against true", caption, &panels, 2, (560, 440))?))
}

/// Below this R^2 a rank regression explains too little of its output for its coefficients to be
/// read: the panel is marked weak.
pub const WEAK_R2: f64 = 0.1;

/// Top inputs by |SRRC| for each drift metric at the last horizon, nominal and estimated; the
/// outputs given no coefficients (too few trials per input) are not drawn but named in the
/// caption.
fn sensitivity_figure(cfg: &McConfig, c: usize, rows: &[SensitivityRow]) -> Result<Option<Figure>, ReportError> {
    let cell = &cfg.cells[c];
    let h = *cell.navigation.horizons_s.last().unwrap_or(&1.0);
    let mut panels = Vec::new();
    let mut weak = 0;
    for comp in ["nominal", "estimated"] {
        for (metric, _) in DRIFT_METRICS {
            let col = drift_column(comp, metric, h);
            let mut mine: Vec<(&SensitivityRow, f64, f64)> = of_cell(rows, c as u32, |r| r.cell)
                .iter()
                .filter(|r| r.output == col)
                .filter_map(|r| Some((r, r.srrc?, r.r2?)))
                .collect();
            if mine.is_empty() {
                continue;
            }
            mine.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            mine.truncate(8);
            // `|error a1.dz|` -> `a1.dz`: the axis title says which magnitude.
            let names: Vec<String> =
                mine.iter().map(|r| r.0.input.trim_matches('|').trim_start_matches("error ").to_string()).collect();
            let bars: Vec<(f64, f64, f64)> =
                mine.iter().enumerate().map(|(x, r)| (x as f64 - 0.35, x as f64 + 0.35, r.1)).collect();
            let input = if comp == "nominal" { "input: |true value|" } else { "input: |estimation error|" };
            let r2 = mine[0].2;
            // NaN (no R^2) is weak too.
            let is_weak = r2.is_nan() || r2 < WEAK_R2;
            weak += is_weak as usize;
            // A weak panel's R^2 rounded down, so that it never reads as the bound (0.0996: 0.099).
            let title = if is_weak {
                format!("{col} (R^2 {:.3}: weak, do not read)", (r2 * 1000.0).floor() / 1000.0)
            } else {
                format!("{col} (R^2 {r2:.2})")
            };
            // A weak panel is drawn in grey.
            let colour = if is_weak {
                6
            } else if comp == "nominal" {
                0
            } else {
                1
            };
            panels.push(Panel::new(title, input, "SRRC [1]").categorical(names).with(Item::Bars {
                label: None,
                bars,
                colour,
            }));
        }
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let trials = of_cell(rows, c as u32, |r| r.cell).iter().map(|r| r.trials).max().unwrap_or(0);
    let caption = format!(
        "Which error parameters drive each drift metric at {h} s in cell {c} ({}): standardised rank regression \
         coefficients of the inputs (|true value| for nominal compensation, |estimation error| for estimated), \
         the eight largest per metric. An SRRC of 1 means the metric's rank follows that input's alone; read \
         them only when R^2 is high{}. Computed on {trials} trials of the cell (at most the first \
         {SENSITIVITY_TRIALS}).",
        describe(cell),
        if weak > 0 {
            format!(
                ": {weak} panel(s) here have R^2 below {WEAK_R2} and are drawn in grey, marked weak: the inputs explain \
                 too little of the metric's rank for their coefficients to mean anything"
            )
        } else {
            String::new()
        }
    );
    Ok(Some(render(
        &format!("sensitivity_cell{c}"),
        &format!("Sensitivity, cell {c}"),
        &caption,
        &panels,
        2,
        (480, 300),
    )?))
}

/// Why a cell's sensitivity has no coefficients to draw, if the regression refused to fit.
fn sensitivity_refusal(c: usize, rows: &[SensitivityRow]) -> Option<String> {
    let refused: Vec<&SensitivityRow> =
        of_cell(rows, c as u32, |r| r.cell).iter().filter(|r| r.note.is_some()).collect();
    let first = refused.first()?;
    Some(format!(
        "{} drift column(s) of cell {c} get no sensitivity coefficients: {}",
        refused.len(),
        first.note.as_deref().unwrap_or_default()
    ))
}

/// First-order and total Sobol' indices with 95% intervals, the eight largest totals per metric.
fn sobol_figure(cfg: &McConfig, c: usize, rows: &[SobolRow]) -> Result<Option<Figure>, ReportError> {
    let cell = &cfg.cells[c];
    let h = *cell.navigation.horizons_s.last().unwrap_or(&1.0);
    let mut panels = Vec::new();
    let mut used = 0;
    for comp in &cell.navigation.compensations {
        for (metric, _) in DRIFT_METRICS {
            let col = drift_column(comp.name(), metric, h);
            let mut mine: Vec<&SobolRow> =
                of_cell(rows, c as u32, |r| r.cell).iter().filter(|r| r.output == col).collect();
            if mine.is_empty() {
                continue;
            }
            used = mine[0].base_samples;
            mine.sort_by(|a, b| b.total.total_cmp(&a.total));
            mine.truncate(8);
            let names: Vec<String> = mine.iter().map(|r| r.input.clone()).collect();
            let first = mine
                .iter()
                .enumerate()
                .map(|(x, r)| (x as f64 - 0.12, r.first_order, r.first_order_lo, r.first_order_hi));
            let total = mine.iter().enumerate().map(|(x, r)| (x as f64 + 0.12, r.total, r.total_lo, r.total_hi));
            let legend = panels.is_empty();
            panels.push(
                Panel::new(format!("log10 {col}"), "input", "Sobol' index [1]")
                    .categorical(names)
                    .with(Item::Intervals {
                        label: legend.then(|| "first order (95% interval)".to_string()),
                        points: first.collect(),
                        colour: 0,
                    })
                    .with(Item::Intervals {
                        label: legend.then(|| "total (95% interval)".to_string()),
                        points: total.collect(),
                        colour: 1,
                    }),
            );
        }
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let caption = format!(
        "Sobol' indices of the error parameters for log10 of each drift metric at {h} s in cell {c} ({}), from the run's \
         Saltelli design ({used} base samples): first order (the share of the metric's variance an input explains \
         alone) and total (with all its interactions), with bootstrap 95% intervals; the eight largest totals per \
         metric. Total well above first order means the input acts through interactions (a drift metric is the norm \
         of an error vector, and a norm is not additive in its contributions). For the estimated compensation \
         the calibration noise is one more input, held between a block's A and AB rows: its share is in the \
         variance, not in the parameters' indices.",
        describe(cell)
    );
    Ok(Some(render(&format!("sobol_cell{c}"), &format!("Sobol' indices, cell {c}"), &caption, &panels, 2, (480, 300))?))
}

fn parameter_table(page: &mut Page, summary: &Summary, c: u32) {
    let weak = weak_parameters(summary, c);
    let rows: Vec<(Vec<String>, bool)> = summary
        .parameters_of(c)
        .iter()
        .map(|p| {
            let (unit, f) = display_unit(&p.unit);
            (
                vec![
                    p.name.clone(),
                    unit.to_string(),
                    p.n.to_string(),
                    sig(p.bias * f, 3),
                    sig(p.rmse * f, 3),
                    sig(p.crb_sigma * f, 3),
                    format!("{:.3}", p.ratio),
                    format!("{:.3}", p.coverage_95),
                ],
                weak.contains(&p.name),
            )
        })
        .collect();
    page.table(
        &["parameter", "unit", "trials", "bias", "RMSE", "Cramer-Rao sigma", "RMS error/CRB", "95% coverage"],
        &rows,
    );
}

/// Builds the report of the run in `dir`.
pub fn run_report(dir: &Path) -> Result<RunReport, ReportError> {
    let cfg = load_config(dir)?;
    let summary = summarize(dir)?;
    if summary.trials == 0 {
        return Err(ReportError::Input {
            path: dir.join("trials"),
            problem: "no trials: the run has written no part files yet".into(),
        });
    }
    let cap = (100_000 / cfg.cells.len()).clamp(200, SAMPLE_PER_CELL);
    let samples = read_samples(dir, cfg.cells.len(), cap)?;
    let sens = sensitivity(dir, SENSITIVITY_TRIALS)?;
    let sobol_rows = if summary.trials == cfg.total_trials() { sobol(dir, &cfg)? } else { Vec::new() };
    let mut figures = Vec::new();
    let mut notes = Vec::new();
    let mut page = Page::new(&format!("gfcal run report: {}", cfg.name));
    page.text(&format!(
        "{} trials of {} expected, in {} cell(s) of {} trials; seed {}. Units: SI throughout, as in summary.csv: bias in \
         m/s^2, scale factor error dimensionless (1), misalignment in rad, location in m, drift in rad/s, rad, m/s, m. Weak parameters (Cramer-Rao sigma more than {WEAK_FACTOR} \
         times the median of their kind in the cell) are highlighted in the tables.",
        summary.trials,
        cfg.total_trials(),
        cfg.cells.len(),
        cfg.trials_per_cell,
        cfg.seed
    ));
    if summary.trials < cfg.total_trials() {
        page.note("The run is not complete: the report covers the parts written so far.");
    }
    let flagged: Vec<String> = {
        let mut cells: Vec<String> = cell_flags(&summary).iter().map(|f| f.cell().to_string()).collect();
        cells.dedup();
        cells
    };
    if !flagged.is_empty() {
        page.note(&format!(
            "{} cell(s) flagged, whose estimated compensation should not be read as it stands (see each cell): {}.",
            flagged.len(),
            flagged.join(", ")
        ));
    }
    let mut add = |page: &mut Page, fig: Option<Figure>, what: &str, notes: &mut Vec<String>| match fig {
        Some(f) => {
            page.figure(&f, Some(&format!("report/{}.svg", f.name)));
            figures.push(f);
        }
        None => {
            let n = format!("{what}: no data to plot");
            page.note(&n);
            notes.push(n);
        }
    };
    page.heading(2, "Identifiability across cells");
    add(&mut page, identifiability_figure(&cfg, &summary)?, "identifiability", &mut notes);
    add(&mut page, location_figure(&cfg, &samples, &summary)?, "location recovery", &mut notes);
    let fits = cell_fits(&summary);
    let flags = cell_flags(&summary);
    for (c, cell) in cfg.cells.iter().enumerate() {
        page.heading(2, &format!("Cell {c}: {}", describe(cell)));
        if let Some(f) = of_cell(&fits, c as u32, |f| f.cell).first() {
            page.text(&format!(
                "Fits: {}. The parameter statistics below use the trials with an estimate, converged or not (the \
                 trials column); the drift of the estimated compensation uses the {} estimated trials.",
                f.describe(),
                f.estimated
            ));
        }
        for flag in of_cell(&flags, c as u32, |f| f.cell()) {
            page.note(&format!("Flag: {}.", flag.describe()));
        }
        page.heading(3, "Estimation error");
        parameter_table(&mut page, &summary, c as u32);
        add(&mut page, error_figure(&cfg, c, &samples[c])?, &format!("cell {c} estimation errors"), &mut notes);
        page.heading(3, "Drift");
        add(&mut page, drift_figure(&cfg, c, &summary)?, &format!("cell {c} drift"), &mut notes);
        page.heading(3, "Sensitivity");
        match (sensitivity_figure(&cfg, c, &sens)?, sensitivity_refusal(c, &sens)) {
            (figure, Some(refusal)) => {
                page.note(&refusal);
                notes.push(refusal);
                if figure.is_some() {
                    add(&mut page, figure, "", &mut notes);
                }
            }
            (figure, None) => add(
                &mut page,
                figure,
                &format!("cell {c} sensitivity (no error parameter varies between trials)"),
                &mut notes,
            ),
        }
        if cell.saltelli.is_some() {
            add(
                &mut page,
                sobol_figure(&cfg, c, &sobol_rows)?,
                &format!("cell {c} Sobol' indices (the run is incomplete, or too few base samples have every output)"),
                &mut notes,
            );
        }
    }
    page.heading(2, "Config");
    page.pre(&cfg.text);
    Ok(RunReport { html: page.finish(), figures, notes })
}

/// Writes `dir/report/*.svg`, then `dir/report.html` (each file atomically; the page last).
pub fn write_run_report(dir: &Path) -> Result<(RunReport, Vec<PathBuf>), ReportError> {
    let report = run_report(dir)?;
    let svg_dir = dir.join("report");
    std::fs::create_dir_all(&svg_dir).map_err(|source| ReportError::Write { path: svg_dir.clone(), source })?;
    let mut written = Vec::new();
    for f in &report.figures {
        let path = svg_dir.join(format!("{}.svg", f.name));
        crate::io::write_atomic(&path, f.svg.as_bytes())
            .map_err(|source| ReportError::Write { path: path.clone(), source })?;
        written.push(path);
    }
    // SVGs of an earlier report that this one does not draw (e.g. a cell's Sobol' figure of a
    // run since replaced) would be stale: removed.
    for old in
        std::fs::read_dir(&svg_dir).map(|d| d.flatten().map(|e| e.path()).collect::<Vec<_>>()).unwrap_or_default()
    {
        if old.extension().is_some_and(|x| x == "svg") && !written.contains(&old) {
            std::fs::remove_file(&old).map_err(|source| ReportError::Write { path: old.clone(), source })?;
        }
    }
    let path = dir.join("report.html");
    crate::io::write_atomic(&path, report.html.as_bytes())
        .map_err(|source| ReportError::Write { path: path.clone(), source })?;
    written.push(path);
    Ok((report, written))
}
