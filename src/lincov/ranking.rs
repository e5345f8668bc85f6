//! LinCov's error budget ranked beside the Monte Carlo's sensitivity indices of the same run
//! (`gfcal lincov CONFIG --compare RUN_DIR` writes `ranking.csv`): which parameters drive each
//! drift column, by each method.
//!
//! The three answer different questions, so only their rankings are compared:
//! - LinCov's share: the part of `E |e|^2` a parameter's error carries (its own variance and
//!   half of its covariances, [`super::analysis::Source::Parameter`]);
//! - SRRC (`mc::sensitivity`): the standardised rank regression coefficient of the drift on the
//!   parameter's error magnitude (`|true - nominal|` for nominal compensation, `|estimated -
//!   true|` for estimated), over the run's trials; ranked by `|SRRC|`;
//! - Sobol' total index (`mc::sobol`, runs on a Saltelli design only): the share of the variance
//!   of `log10` of the drift that involves the parameter's true value. For nominal compensation
//!   the true value is the error, so it ranks the same drivers; for estimated compensation it
//!   ranks what moves the calibration's accuracy, not the residual errors (a different question).
//!
//! Per drift column: Spearman's rank correlation of LinCov's shares with `|SRRC|` (and with the
//! Sobol' total indices), and the kind of parameter (bias, scale factor, misalignment, location)
//! that carries the largest sum by each method.

use std::collections::BTreeMap;
use std::path::Path;

use super::analysis::{CellResult, Source};
use super::output::row_name;
use crate::calib::params::{Layout, ParamKind};
use crate::io::parquet::ParquetIoError;
use crate::mc::McConfig;
use crate::mc::sensitivity::{ranks, sensitivity};

/// One parameter of one drift column.
#[derive(Debug, Clone, PartialEq)]
pub struct RankRow {
    pub cell: usize,
    /// The drift column.
    pub name: String,
    pub parameter: String,
    pub kind: &'static str,
    /// Fraction of the metric's mean square (LinCov).
    pub lincov_share: f64,
    /// NaN where the run has no index for the parameter.
    pub srrc: f64,
    pub sobol_first: f64,
    pub sobol_total: f64,
}

/// How the rankings of one drift column agree.
#[derive(Debug, Clone, PartialEq)]
pub struct Agreement {
    pub cell: usize,
    pub name: String,
    /// Spearman's rank correlation of LinCov's shares with `|SRRC|` (NaN without SRRC).
    pub spearman_srrc: f64,
    /// ... with the Sobol' total indices (NaN without a Saltelli design).
    pub spearman_sobol: f64,
    /// The kind of parameter with the largest sum by LinCov, by `SRRC^2`, by Sobol' total.
    pub top_kind_lincov: &'static str,
    pub top_kind_srrc: &'static str,
    pub top_kind_sobol: &'static str,
    /// The single largest parameter by LinCov and by `|SRRC|`.
    pub top_lincov: String,
    pub top_srrc: String,
}

fn kind_name(k: ParamKind) -> &'static str {
    match k {
        ParamKind::ScaleFactor => "scale_factor",
        ParamKind::Bias => "bias",
        ParamKind::Misalignment(_) => "misalignment",
        ParamKind::Location(_) => "location",
    }
}

/// Spearman's rank correlation of `a` and `b` (NaN with fewer than 3 pairs or no spread).
pub fn spearman(a: &[f64], b: &[f64]) -> f64 {
    if a.len() < 3 || a.len() != b.len() {
        return f64::NAN;
    }
    let (ra, rb) = (ranks(a), ranks(b));
    let n = ra.len() as f64;
    let (ma, mb) = (ra.iter().sum::<f64>() / n, rb.iter().sum::<f64>() / n);
    let cov: f64 = ra.iter().zip(&rb).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = ra.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = rb.iter().map(|y| (y - mb).powi(2)).sum();
    if va <= 0.0 || vb <= 0.0 { f64::NAN } else { cov / (va * vb).sqrt() }
}

/// The kind with the largest sum of `value` (NaN values left out); "" when none is positive.
fn top_kind(layout: &Layout, values: &[(usize, f64)]) -> &'static str {
    let mut sums: BTreeMap<&'static str, f64> = BTreeMap::new();
    for &(i, v) in values {
        if v.is_finite() {
            *sums.entry(kind_name(layout.kind(i))).or_insert(0.0) += v;
        }
    }
    sums.into_iter().filter(|(_, v)| *v > 0.0).max_by(|a, b| a.1.total_cmp(&b.1)).map_or("", |(k, _)| k)
}

/// LinCov's budget beside the run in `dir`'s SRRC (at most `max_trials` trials per cell) and,
/// for a Saltelli design, its Sobol' indices. Columns LinCov leaves unbounded are left out.
pub fn ranking(
    dir: &Path,
    cfg: &McConfig,
    results: &[CellResult],
    max_trials: usize,
) -> Result<(Vec<RankRow>, Vec<Agreement>), ParquetIoError> {
    let srrc = sensitivity(dir, max_trials)?;
    let sobol = crate::mc::sobol::sobol(dir, cfg)?;
    let mut srrc_of: BTreeMap<(u32, &str, &str), f64> = BTreeMap::new();
    for r in &srrc {
        let param = r.input.trim_start_matches('|').trim_end_matches('|').trim_start_matches("error ");
        // A regression refused for too few trials per input has no coefficient.
        if let Some(v) = r.srrc {
            srrc_of.insert((r.cell, r.output.as_str(), param), v);
        }
    }
    let mut sobol_of: BTreeMap<(u32, &str, &str), (f64, f64)> = BTreeMap::new();
    for r in &sobol {
        sobol_of.insert((r.cell, r.output.as_str(), r.input.as_str()), (r.first_order, r.total));
    }
    let (mut rows, mut agreements) = (Vec::new(), Vec::new());
    for c in results {
        let layout = &cfg.cells[c.cell].layout;
        let cell = c.cell as u32;
        for r in &c.rows {
            let total: f64 = r.budget.iter().map(|(_, v)| v).sum();
            if !(total.is_finite() && total > 0.0) {
                continue;
            }
            let name = row_name(r);
            let mine: Vec<RankRow> = r
                .budget
                .iter()
                .filter_map(|(s, v)| match s {
                    Source::Parameter(i) => Some((*i, *v)),
                    _ => None,
                })
                .map(|(i, v)| {
                    let p = layout.name(i);
                    let s = srrc_of.get(&(cell, name.as_str(), p.as_str())).copied().unwrap_or(f64::NAN);
                    let (f, t) =
                        sobol_of.get(&(cell, name.as_str(), p.as_str())).copied().unwrap_or((f64::NAN, f64::NAN));
                    RankRow {
                        cell: c.cell,
                        name: name.clone(),
                        parameter: p,
                        kind: kind_name(layout.kind(i)),
                        lincov_share: v / total,
                        srrc: s,
                        sobol_first: f,
                        sobol_total: t,
                    }
                })
                .collect();
            if mine.iter().all(|m| m.srrc.is_nan() && m.sobol_total.is_nan()) {
                continue;
            }
            let index = |p: &str| layout.index_of(p).unwrap_or(0);
            let pairs = |f: &dyn Fn(&RankRow) -> f64| -> (Vec<f64>, Vec<f64>) {
                mine.iter().filter(|m| f(m).is_finite()).map(|m| (m.lincov_share, f(m))).unzip()
            };
            let (a, b) = pairs(&|m| m.srrc.abs());
            let (c_, d) = pairs(&|m| m.sobol_total);
            let largest = |f: &dyn Fn(&RankRow) -> f64| {
                mine.iter()
                    .filter(|m| f(m).is_finite())
                    .max_by(|x, y| f(x).total_cmp(&f(y)))
                    .map_or(String::new(), |m| m.parameter.clone())
            };
            agreements.push(Agreement {
                cell: c.cell,
                name: name.clone(),
                spearman_srrc: spearman(&a, &b),
                spearman_sobol: spearman(&c_, &d),
                top_kind_lincov: top_kind(
                    layout,
                    &mine.iter().map(|m| (index(&m.parameter), m.lincov_share)).collect::<Vec<_>>(),
                ),
                top_kind_srrc: top_kind(
                    layout,
                    &mine.iter().map(|m| (index(&m.parameter), m.srrc * m.srrc)).collect::<Vec<_>>(),
                ),
                top_kind_sobol: top_kind(
                    layout,
                    &mine.iter().map(|m| (index(&m.parameter), m.sobol_total)).collect::<Vec<_>>(),
                ),
                top_lincov: largest(&|m| m.lincov_share),
                top_srrc: largest(&|m| m.srrc.abs()),
            });
            rows.extend(mine);
        }
    }
    Ok((rows, agreements))
}

/// `ranking.csv`: per cell, drift column and parameter, LinCov's share and the run's indices.
pub fn ranking_csv(rows: &[RankRow]) -> String {
    let num = |v: f64| if v.is_finite() { format!("{v:e}") } else { format!("{v}") };
    let mut out = String::from("cell,name,parameter,kind,lincov_share,srrc,sobol_first,sobol_total\n");
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{}\n",
            r.cell,
            r.name,
            r.parameter,
            r.kind,
            num(r.lincov_share),
            num(r.srrc),
            num(r.sobol_first),
            num(r.sobol_total)
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spearman_of_monotone_and_reversed_orders() {
        let a = [1.0, 2.0, 3.0, 4.0, 10.0];
        assert!((spearman(&a, &[0.1, 0.2, 0.25, 7.0, 8.0]) - 1.0).abs() < 1e-12);
        assert!((spearman(&a, &[5.0, 4.0, 3.0, 2.0, 1.0]) + 1.0).abs() < 1e-12);
        // One swap in five: 1 - 6 * 2 / (5 * 24) = 0.9.
        assert!((spearman(&a, &[1.0, 3.0, 2.0, 4.0, 5.0]) - 0.9).abs() < 1e-12);
        assert!(spearman(&a[..2], &[1.0, 2.0]).is_nan());
    }
}
