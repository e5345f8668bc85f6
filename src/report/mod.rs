//! Reports a person can look at: `gfcal report DIR` (a run) and `gfcal diagnose --report`
//! (a diagnosis). Each is one self-contained HTML file with its plots inline as SVG (no scripts,
//! no network), plus the same plots as separate SVG files.

pub mod calibration;
pub mod diagnosis;
pub mod html;
pub mod lincov;
pub mod plot;
pub mod recorded;
pub mod run;

use std::path::PathBuf;

use crate::io::parquet::ParquetIoError;

pub use plot::{AxisScale, Figure, Item, Panel, PlotError, render};

/// Why a report could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// The folder or file given is not what a report reads.
    #[error("{path}: {problem}")]
    Input { path: PathBuf, problem: String },
    #[error(transparent)]
    Parquet(#[from] ParquetIoError),
    #[error(transparent)]
    Plot(#[from] PlotError),
    #[error("cannot write {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}

/// The verdicts on what to trust (`selfcal::assessment`) as a table: kind, trustworthy, why; the
/// untrustworthy rows marked. Shared by the calibration and the diagnosis pages.
pub fn verdict_table(page: &mut html::Page, verdicts: Vec<crate::selfcal::assessment::Verdict>) {
    let rows: Vec<(Vec<String>, bool)> = verdicts
        .into_iter()
        .map(|v| {
            (vec![v.kind.to_string(), if v.trustworthy { "yes" } else { "no" }.to_string(), v.reason], !v.trustworthy)
        })
        .collect();
    page.table(&["kind", "trustworthy", "why"], &rows);
}

/// The unit a report shows a parameter in, given its SI unit, and the factor from SI to it: SI
/// itself, as in summary.csv, the Parquet tables, `identify` and `diagnose` (one unit per
/// quantity everywhere gfcal writes).
pub fn display_unit(si_unit: &str) -> (&str, f64) {
    (si_unit, 1.0)
}

/// The kind of a parameter from its SI unit, for grouping plots.
pub fn kind_of_unit(si_unit: &str) -> &'static str {
    match si_unit {
        "m/s^2" => "bias",
        "1" => "scale factor",
        "rad" => "misalignment",
        "m" => "location",
        _ => "other",
    }
}
