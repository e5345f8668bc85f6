//! LinCov beside a Monte Carlo run of the same config (`gfcal lincov CONFIG --compare RUN_DIR`):
//! per cell and drift column, the median and 95th percentile of both, their ratio, and the Monte
//! Carlo's own sampling uncertainty.
//!
//! The Monte Carlo's quantiles are the order statistics the summary's histogram approximates
//! (the `ceil(q n)`-th smallest; a diverged trial counts as larger than any value, a trial
//! without an estimate is left out), read from the run's `trials/` Parquet files. Their 95%
//! interval is distribution-free: the order statistics `q n -+ 1.96 sqrt(n q (1 - q))`.

use std::path::Path;

use arrow_array::{Array, Float64Array, UInt32Array};

use super::analysis::{CellResult, MetricResult};
use super::output::row_name;
use crate::io::parquet::{ParquetIoError, column, part_files, read_batches};

/// A quantile of the Monte Carlo with its 95% interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleQuantile {
    pub value: f64,
    pub low: f64,
    pub high: f64,
}

/// The `q`-quantile of sorted values (`ceil(q n)`-th smallest) and its distribution-free 95%
/// interval.
pub fn sample_quantile(sorted: &[f64], q: f64) -> SampleQuantile {
    let n = sorted.len();
    if n == 0 {
        return SampleQuantile { value: f64::NAN, low: f64::NAN, high: f64::NAN };
    }
    let at = |k: f64| sorted[(k.ceil().max(1.0) as usize).min(n) - 1];
    let spread = 1.96 * (n as f64 * q * (1.0 - q)).sqrt();
    let k = q * n as f64;
    SampleQuantile { value: at(k), low: at(k - spread), high: at(k + spread) }
}

/// One row of the comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub cell: usize,
    pub name: String,
    /// Trials with a value (finite or diverged).
    pub n: usize,
    pub lincov_median: f64,
    pub mc_median: SampleQuantile,
    pub lincov_p95: f64,
    pub mc_p95: SampleQuantile,
    pub nonlinearity: f64,
    pub linear: bool,
}

impl Comparison {
    pub fn median_ratio(&self) -> f64 {
        self.lincov_median / self.mc_median.value
    }
    pub fn p95_ratio(&self) -> f64 {
        self.lincov_p95 / self.mc_p95.value
    }
    /// The largest relative difference of median and p95.
    pub fn worst_difference(&self) -> f64 {
        (self.median_ratio() - 1.0).abs().max((self.p95_ratio() - 1.0).abs())
    }
}

/// The drift columns of a run's trials, per cell: `values[cell][column]`, sorted.
fn read_run(dir: &Path, names: &[String], cells: usize) -> Result<Vec<Vec<Vec<f64>>>, ParquetIoError> {
    let mut values = vec![vec![Vec::new(); names.len()]; cells];
    for file in part_files(&dir.join("trials")) {
        for batch in read_batches(&file)? {
            let cell = column::<UInt32Array>(&batch, "cell", &file)?;
            for (k, name) in names.iter().enumerate() {
                let Some(col) = batch.column_by_name(name).and_then(|c| c.as_any().downcast_ref::<Float64Array>())
                else {
                    continue;
                };
                for i in 0..batch.num_rows() {
                    let c = cell.value(i) as usize;
                    let v = col.value(i);
                    if c < cells && !v.is_nan() && !col.is_null(i) {
                        values[c][k].push(v);
                    }
                }
            }
        }
    }
    for cell in &mut values {
        for v in cell {
            v.sort_by(f64::total_cmp);
        }
    }
    Ok(values)
}

/// LinCov's rows beside the run in `dir` (rows the run did not navigate are left out).
pub fn compare(dir: &Path, results: &[CellResult]) -> Result<Vec<Comparison>, ParquetIoError> {
    let mut names: Vec<String> = results.iter().flat_map(|c| c.rows.iter().map(row_name)).collect();
    names.sort();
    names.dedup();
    let cells = results.iter().map(|c| c.cell + 1).max().unwrap_or(0);
    let values = read_run(dir, &names, cells)?;
    let mut out = Vec::new();
    for c in results {
        for r in &c.rows {
            let name = row_name(r);
            let Some(k) = names.iter().position(|n| *n == name) else { continue };
            let sorted = &values[c.cell][k];
            if sorted.is_empty() {
                continue;
            }
            out.push(row(c.cell, r, name, sorted));
        }
    }
    Ok(out)
}

fn row(cell: usize, r: &MetricResult, name: String, sorted: &[f64]) -> Comparison {
    Comparison {
        cell,
        name,
        n: sorted.len(),
        lincov_median: r.median,
        mc_median: sample_quantile(sorted, 0.5),
        lincov_p95: r.p95,
        mc_p95: sample_quantile(sorted, 0.95),
        nonlinearity: r.nonlinearity,
        linear: r.linear,
    }
}

/// `compare.csv`.
pub fn compare_csv(rows: &[Comparison]) -> String {
    let num = |v: f64| if v.is_finite() { format!("{v:e}") } else { format!("{v}") };
    let mut out = String::from(
        "cell,name,n,lincov_median,mc_median,median_ratio,mc_median_low,mc_median_high,lincov_p95,mc_p95,p95_ratio,\
         mc_p95_low,mc_p95_high,nonlinearity,linear\n",
    );
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.cell,
            r.name,
            r.n,
            num(r.lincov_median),
            num(r.mc_median.value),
            num(r.median_ratio()),
            num(r.mc_median.low),
            num(r.mc_median.high),
            num(r.lincov_p95),
            num(r.mc_p95.value),
            num(r.p95_ratio()),
            num(r.mc_p95.low),
            num(r.mc_p95.high),
            num(r.nonlinearity),
            r.linear
        ));
    }
    out
}
