//! The LinCov page of `gfcal report DIR` (`DIR/lincov.html`, figures in `DIR/lincov_report/`):
//! from the files `gfcal lincov` wrote, each drift metric's median and 5-95% band against
//! horizon (with the Monte Carlo's median and p95 beside them when `compare.csv` is there, and
//! the rows LinCov does not stand by marked), and the error budget as stacked bars of each
//! source's share against horizon.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::html::Page;
use super::plot::{Figure, Item, Panel, render};
use super::{PlotError, ReportError};

/// Cells drawn (the others are in the CSV files).
const MAX_CELLS: usize = 6;

/// The budget's sources as the stacked bars show them (kinds of parameter, then the others).
const KINDS: [&str; 6] = ["bias", "scale_factor", "misalignment", "location", "fixture", "noise"];

const METRICS: [(&str, &str); 4] =
    [("rate_err_rad_s", "rad/s"), ("attitude_err_rad", "rad"), ("velocity_err_m_s", "m/s"), ("position_err_m", "m")];

/// The LinCov page and its figures.
#[derive(Debug, Clone)]
pub struct LincovReport {
    pub html: String,
    pub figures: Vec<Figure>,
    pub notes: Vec<String>,
}

type Record = BTreeMap<String, String>;

fn read_csv(path: &Path) -> Result<Vec<Record>, ReportError> {
    let input = |problem: String| ReportError::Input { path: path.to_path_buf(), problem };
    let mut reader = csv::Reader::from_path(path).map_err(|e| input(e.to_string()))?;
    let header = reader.headers().map_err(|e| input(e.to_string()))?.clone();
    let mut out = Vec::new();
    for row in reader.records() {
        let row = row.map_err(|e| input(e.to_string()))?;
        out.push(header.iter().zip(row.iter()).map(|(h, v)| (h.to_string(), v.to_string())).collect());
    }
    Ok(out)
}

fn num(r: &Record, key: &str) -> f64 {
    r.get(key).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN)
}

fn text<'a>(r: &'a Record, key: &str) -> &'a str {
    r.get(key).map(String::as_str).unwrap_or("")
}

/// Whether `dir` holds the output of `gfcal lincov`.
pub fn has_lincov(dir: &Path) -> bool {
    dir.join("lincov.csv").exists() && dir.join("budget.csv").exists()
}

fn drift_figure(cell: &str, rows: &[&Record], compare: &[Record]) -> Result<Option<Figure>, PlotError> {
    let mut panels = Vec::new();
    let compensations: Vec<&str> = {
        let mut c: Vec<&str> = rows.iter().map(|r| text(r, "compensation")).collect();
        c.dedup();
        c.sort();
        c.dedup();
        c
    };
    for (metric, unit) in METRICS {
        let mut panel = Panel::new(metric, "horizon [s]", format!("{metric} [{unit}]")).log_y();
        for (ci, comp) in compensations.iter().enumerate() {
            let mine: Vec<&&Record> =
                rows.iter().filter(|r| text(r, "metric") == metric && text(r, "compensation") == *comp).collect();
            let at = |k: &str| mine.iter().map(|r| (num(r, "horizon_s"), num(r, k))).collect::<Vec<_>>();
            panel = panel.with(Item::Band { label: None, lower: at("p05"), upper: at("p95"), colour: ci }).with(
                Item::Line {
                    label: Some(format!("{comp}: LinCov median, 5-95%")),
                    points: at("median"),
                    colour: ci,
                    dashed: false,
                },
            );
            let flagged: Vec<(f64, f64)> = mine
                .iter()
                .filter(|r| text(r, "linear") != "true")
                .map(|r| (num(r, "horizon_s"), num(r, "p95")))
                .collect();
            if !flagged.is_empty() {
                panel = panel.with(Item::Points {
                    label: Some(format!("{comp}: not linear (p95)")),
                    points: flagged,
                    colour: 7,
                });
            }
            let mc: Vec<&Record> = compare
                .iter()
                .filter(|r| text(r, "cell") == cell && text(r, "name").starts_with(&format!("{comp}_{metric}_at_")))
                .collect();
            if !mc.is_empty() {
                let horizon = |r: &Record| -> f64 {
                    text(r, "name")
                        .rsplit("_at_")
                        .next()
                        .and_then(|h| h.trim_end_matches('s').parse().ok())
                        .unwrap_or(f64::NAN)
                };
                let pts = |k: &str| mc.iter().map(|r| (horizon(r), num(r, k))).collect::<Vec<_>>();
                panel = panel
                    .with(Item::Points {
                        label: Some(format!("{comp}: Monte Carlo median")),
                        points: pts("mc_median"),
                        colour: ci,
                    })
                    .with(Item::Line {
                        label: Some(format!("{comp}: Monte Carlo p95")),
                        points: pts("mc_p95"),
                        colour: ci,
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
    let caption = "Median (line) and 5-95% band of each drift metric by LinCov, per compensation; with \
                   `--compare`, the Monte Carlo's median (points) and p95 (dashed). Black points: rows whose \
                   nonlinearity index exceeds the threshold (LinCov does not stand by them). SI units."
        .to_string();
    render(
        &format!("lincov_drift_cell{cell}"),
        &format!("Cell {cell}: drift by LinCov"),
        &caption,
        &panels,
        2,
        (560, 400),
    )
    .map(Some)
}

fn budget_figure(cell: &str, comp: &str, budget: &[&Record]) -> Result<Option<Figure>, PlotError> {
    let mut panels = Vec::new();
    for (metric, _) in METRICS {
        let mine: Vec<&&Record> =
            budget.iter().filter(|r| text(r, "metric") == metric && text(r, "compensation") == comp).collect();
        let mut horizons: Vec<f64> = mine.iter().map(|r| num(r, "horizon_s")).collect();
        horizons.sort_by(f64::total_cmp);
        horizons.dedup();
        if horizons.is_empty() {
            continue;
        }
        // Share of each kind at each horizon (negative shares, from negative correlations, are
        // drawn at zero; the CSV holds them).
        let share = |kind: &str, h: f64| -> f64 {
            mine.iter()
                .filter(|r| text(r, "kind") == kind && num(r, "horizon_s") == h)
                .map(|r| num(r, "share"))
                .filter(|v| v.is_finite())
                .sum::<f64>()
                .max(0.0)
        };
        let names: Vec<String> = horizons.iter().map(|h| format!("{h} s")).collect();
        let mut panel = Panel::new(metric, "horizon", "share of E|e|^2").categorical(names);
        // Stacked: cumulative bars drawn from the tallest down, each over the previous.
        let cumulative: Vec<Vec<f64>> = (0..KINDS.len())
            .map(|k| horizons.iter().map(|&h| KINDS[..=k].iter().map(|kind| share(kind, h)).sum()).collect())
            .collect();
        for k in (0..KINDS.len()).rev() {
            let bars: Vec<(f64, f64, f64)> =
                cumulative[k].iter().enumerate().map(|(i, v)| (i as f64 - 0.35, i as f64 + 0.35, *v)).collect();
            if KINDS[..=k].iter().any(|kind| horizons.iter().any(|&h| share(kind, h) > 0.0)) {
                panel = panel.with(Item::Bars { label: Some(KINDS[k].to_string()), bars, colour: k });
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
        "Error budget of the {comp} compensation: each source's share of the metric's mean square E|e|^2 against \
         horizon, stacked (parameters by kind, over every accelerometer; the fixture's pose errors; the \
         navigation's noise). A correlated pair of parameters shares its covariance half and half; budget.csv \
         holds every parameter and accelerometer."
    );
    render(
        &format!("lincov_budget_cell{cell}_{comp}"),
        &format!("Cell {cell}: error budget, {comp}"),
        &caption,
        &panels,
        2,
        (560, 360),
    )
    .map(Some)
}

/// Builds the LinCov page of `dir`.
pub fn lincov_report(dir: &Path) -> Result<LincovReport, ReportError> {
    let rows = read_csv(&dir.join("lincov.csv"))?;
    let budget = read_csv(&dir.join("budget.csv"))?;
    let compare = if dir.join("compare.csv").exists() { read_csv(&dir.join("compare.csv"))? } else { Vec::new() };
    let mut page = Page::new("gfcal LinCov report");
    let mut figures = Vec::new();
    let mut notes = Vec::new();
    let cells: Vec<String> = {
        let mut c: Vec<String> = rows.iter().map(|r| text(r, "cell").to_string()).collect();
        c.dedup();
        c
    };
    let nonlinear = rows.iter().filter(|r| text(r, "linear") != "true").count();
    page.text(&format!(
        "Linear covariance analysis: {} rows in {} cell(s); {} rows not linear (nonlinearity index above the \
         threshold, or unbounded). Units: SI, as in summary.csv.",
        rows.len(),
        cells.len(),
        nonlinear
    ));
    if cells.len() > MAX_CELLS {
        let n =
            format!("{} cells: the first {MAX_CELLS} are drawn; lincov.csv and budget.csv hold them all", cells.len());
        page.note(&n);
        notes.push(n);
    }
    for cell in cells.iter().take(MAX_CELLS) {
        page.heading(2, &format!("Cell {cell}"));
        let mine: Vec<&Record> = rows.iter().filter(|r| text(r, "cell") == cell).collect();
        if let Some(f) = drift_figure(cell, &mine, &compare)? {
            page.figure(&f, Some(&format!("lincov_report/{}.svg", f.name)));
            figures.push(f);
        }
        let flagged: Vec<(Vec<String>, bool)> = mine
            .iter()
            .filter(|r| text(r, "linear") != "true")
            .map(|r| {
                (
                    vec![
                        text(r, "name").to_string(),
                        text(r, "median").to_string(),
                        text(r, "p95").to_string(),
                        text(r, "nonlinearity").to_string(),
                        text(r, "unbounded_by").to_string(),
                    ],
                    true,
                )
            })
            .collect();
        if !flagged.is_empty() {
            page.heading(3, "Rows LinCov does not stand by");
            page.table(&["drift", "median", "p95", "nonlinearity", "unbounded by"], &flagged);
        }
        let cell_budget: Vec<&Record> = budget.iter().filter(|r| text(r, "cell") == cell).collect();
        let mut comps: Vec<&str> = cell_budget.iter().map(|r| text(r, "compensation")).collect();
        comps.sort();
        comps.dedup();
        for comp in comps {
            match budget_figure(cell, comp, &cell_budget)? {
                Some(f) => {
                    page.figure(&f, Some(&format!("lincov_report/{}.svg", f.name)));
                    figures.push(f);
                }
                None => {
                    let n = format!("cell {cell} {comp}: no error budget to draw (no error source)");
                    page.note(&n);
                    notes.push(n);
                }
            }
        }
    }
    Ok(LincovReport { html: page.finish(), figures, notes })
}

/// Writes `dir/lincov_report/*.svg`, then `dir/lincov.html`.
pub fn write_lincov_report(dir: &Path) -> Result<(LincovReport, Vec<PathBuf>), ReportError> {
    let report = lincov_report(dir)?;
    let svg_dir = dir.join("lincov_report");
    std::fs::create_dir_all(&svg_dir).map_err(|source| ReportError::Write { path: svg_dir.clone(), source })?;
    let mut written = Vec::new();
    for f in &report.figures {
        let path = svg_dir.join(format!("{}.svg", f.name));
        crate::io::write_atomic(&path, f.svg.as_bytes())
            .map_err(|source| ReportError::Write { path: path.clone(), source })?;
        written.push(path);
    }
    let path = dir.join("lincov.html");
    crate::io::write_atomic(&path, report.html.as_bytes())
        .map_err(|source| ReportError::Write { path: path.clone(), source })?;
    written.push(path);
    Ok((report, written))
}
