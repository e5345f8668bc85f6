//! The summary of a run, computed from its Parquet files part by part (memory flat whatever the
//! trial count): per cell and parameter the bias, RMSE, RMS Cramer-Rao sigma, the RMS of the
//! normalised error `error / crb_sigma` (`ratio`), the coverage of the estimator's 95% interval,
//! and two robust columns that say when one trial dominates a row: the median absolute error
//! (from a log-spaced histogram, within 0.5%) and `worst_share`, the share of the summed squared
//! error that the worst trial holds; per cell and drift column the median and 95th
//! percentile and 5th percentile (from a sparse log-spaced histogram, 500 bins per decade: within 0.5%, at
//! any magnitude). A diverged
//! navigation (+inf) counts as larger than any value; a missing one (NaN: no estimate) is left out.

use std::collections::BTreeMap;
use std::path::Path;

use arrow_array::{Array, Float64Array, RecordBatch, StringArray, UInt32Array};

use crate::io::parquet::{ParquetIoError, column, part_files as parts, read_batches};

/// Statistics of one parameter in one cell, SI.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterSummary {
    pub cell: u32,
    pub name: String,
    pub unit: String,
    /// Trials with a finite error.
    pub n: u64,
    pub bias: f64,
    pub rmse: f64,
    /// Root-mean-square Cramer-Rao sigma over the trials.
    pub crb_sigma: f64,
    /// Root-mean-square of each trial's `error / crb_sigma`: about 1 for an efficient estimator,
    /// however much the bound varies between trials (it equals `rmse / crb_sigma` when the bound
    /// is the same in every trial).
    pub ratio: f64,
    /// Fraction of trials with `|error| <= 1.96 estimated_sigma`.
    pub coverage_95: f64,
    /// Median of `|error|` over the trials.
    pub median_abs_error: f64,
    /// `max error^2 / sum error^2`: near `1 / n` when every trial contributes alike, near 1 when
    /// one trial makes the RMSE.
    pub worst_share: f64,
}

/// Distribution of one drift column in one cell.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftSummary {
    pub cell: u32,
    pub column: String,
    pub unit: String,
    /// Trials with a value (finite or diverged).
    pub n: u64,
    /// Trials whose navigation diverged (+inf) by this horizon.
    pub diverged: u64,
    pub median: f64,
    pub p95: f64,
    /// 5th percentile.
    pub p05: f64,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    pub trials: u64,
    pub parameters: Vec<ParameterSummary>,
    pub drift: Vec<DriftSummary>,
}

#[derive(Default)]
struct Acc {
    unit: String,
    n: u64,
    sum: f64,
    sum2: f64,
    crb2: f64,
    n_crb: u64,
    z2: f64,
    n_z: u64,
    covered: u64,
    n_cov: u64,
    worst2: f64,
    /// `|error|`, for its median, while the cell's trials are still being read.
    abs_error: Option<Histogram>,
    /// Its median, once the cell is complete (the histogram is then dropped).
    median_abs_error: Option<f64>,
}

impl Acc {
    /// The cell is complete: keep the median of `|error|`, drop its histogram.
    fn close(&mut self) {
        if let Some(h) = self.abs_error.take() {
            self.median_abs_error = Some(h.quantile(0.5));
        }
    }
}

const BINS_PER_DECADE: f64 = 500.0;

/// Log-spaced histogram of the magnitudes of values, 500 bins per decade (a quantile within 0.5%
/// of the data's), at any magnitude a `f64` holds: the bins are kept sparse, so only the decades
/// the data reach cost memory.
struct Histogram {
    unit: String,
    zeros: u64,
    infinite: u64,
    counts: BTreeMap<i32, u64>,
    n: u64,
}

impl Histogram {
    fn new(unit: String) -> Self {
        Self { unit, zeros: 0, infinite: 0, counts: BTreeMap::new(), n: 0 }
    }
    fn add(&mut self, v: f64) {
        if v.is_nan() {
            return;
        }
        self.n += 1;
        if v.is_infinite() {
            self.infinite += 1;
            return;
        }
        let v = v.abs();
        if v == 0.0 {
            self.zeros += 1;
            return;
        }
        *self.counts.entry((v.log10() * BINS_PER_DECADE).floor() as i32).or_insert(0) += 1;
    }
    fn quantile(&self, q: f64) -> f64 {
        if self.n == 0 {
            return f64::NAN;
        }
        let target = (q * self.n as f64).ceil().max(1.0) as u64;
        if self.zeros >= target {
            return 0.0;
        }
        let mut cum = self.zeros;
        for (b, c) in &self.counts {
            cum += c;
            if cum >= target {
                return 10f64.powf((*b as f64 + 0.5) / BINS_PER_DECADE);
            }
        }
        f64::INFINITY
    }
}

/// Reads every part of `dir/trials` and `dir/parameters`.
pub fn summarize(dir: &Path) -> Result<Summary, ParquetIoError> {
    // The two tables are independent: read them at the same time.
    let (parameters, drift) = std::thread::scope(|scope| {
        let parameters = scope.spawn(|| -> Result<ParameterTable, ParquetIoError> {
            let mut table = ParameterTable::default();
            for file in parts(&dir.join("parameters")) {
                for batch in read_batches(&file)? {
                    table.add(&batch, &file)?;
                }
            }
            Ok(table)
        });
        let drift = (|| -> Result<DriftTable, ParquetIoError> {
            let mut table = DriftTable::default();
            for file in parts(&dir.join("trials")) {
                for batch in read_batches(&file)? {
                    table.add(&batch, &file)?;
                }
            }
            Ok(table)
        })();
        let parameters = parameters.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
        (parameters, drift)
    });
    Ok(Summarizer { parameters: parameters?, drift: drift? }.finish())
}

/// The summary built part by part, in part order (from files, or from the batches a run writes).
#[derive(Default)]
pub struct Summarizer {
    parameters: ParameterTable,
    drift: DriftTable,
}

impl Summarizer {
    /// Adds one part's parameters and trials batches (`path` names the part in messages).
    pub fn add_part(
        &mut self,
        parameters: &RecordBatch,
        trials: &RecordBatch,
        path: &Path,
    ) -> Result<(), ParquetIoError> {
        self.parameters.add(parameters, path)?;
        self.drift.add(trials, path)
    }

    pub fn finish(self) -> Summary {
        let (trials, drift) = self.drift.finish();
        Summary { trials, parameters: self.parameters.finish(), drift }
    }
}

/// The per-parameter table.
#[derive(Default)]
struct ParameterTable {
    params: BTreeMap<(u32, String), Acc>,
    order: Vec<(u32, String)>,
    /// Keys whose cell may still have trials to come. Parts hold trials in order and cells are
    /// contiguous, so once a batch starts past a cell, that cell's histograms are reduced to their
    /// medians: memory holds the histograms of the cells of one part, whatever the run's size.
    open: Vec<(u32, String)>,
}

impl ParameterTable {
    fn add(&mut self, batch: &RecordBatch, file: &Path) -> Result<(), ParquetIoError> {
        let (params, order, open) = (&mut self.params, &mut self.order, &mut self.open);
        let cell = column::<UInt32Array>(batch, "cell", file)?;
        if let Some(first) = cell.iter().flatten().min() {
            let (done, keep): (Vec<_>, Vec<_>) = open.drain(..).partition(|k| k.0 < first);
            *open = keep;
            for k in done {
                if let Some(a) = params.get_mut(&k) {
                    a.close();
                }
            }
        }
        let name = column::<StringArray>(batch, "name", file)?;
        let unit = column::<StringArray>(batch, "unit", file)?;
        let err = column::<Float64Array>(batch, "error", file)?;
        let crb = column::<Float64Array>(batch, "crb_sigma", file)?;
        let es = column::<Float64Array>(batch, "estimated_sigma", file)?;
        for i in 0..batch.num_rows() {
            let key = (cell.value(i), name.value(i).to_string());
            let a = params.entry(key.clone()).or_insert_with(|| {
                order.push(key.clone());
                open.push(key);
                Acc { unit: unit.value(i).to_string(), ..Acc::default() }
            });
            let e = err.value(i);
            if e.is_finite() {
                a.n += 1;
                a.sum += e;
                a.sum2 += e * e;
                a.worst2 = a.worst2.max(e * e);
                a.abs_error.get_or_insert_with(|| Histogram::new(String::new())).add(e);
                let s = es.value(i);
                if s.is_finite() {
                    a.n_cov += 1;
                    if e.abs() <= 1.96 * s {
                        a.covered += 1;
                    }
                }
            }
            let c = crb.value(i);
            if c.is_finite() {
                a.n_crb += 1;
                a.crb2 += c * c;
                if c > 0.0 && e.is_finite() {
                    a.n_z += 1;
                    a.z2 += (e / c).powi(2);
                }
            }
        }
        Ok(())
    }

    fn finish(mut self) -> Vec<ParameterSummary> {
        self.order.sort_by_key(|k| k.0);
        let params = &self.params;
        self.order
            .iter()
            .map(|k| {
                let a = &params[k];
                let n = a.n.max(1) as f64;
                let rmse = (a.sum2 / n).sqrt();
                let crb = (a.crb2 / a.n_crb.max(1) as f64).sqrt();
                ParameterSummary {
                    cell: k.0,
                    name: k.1.clone(),
                    unit: a.unit.clone(),
                    n: a.n,
                    bias: if a.n > 0 { a.sum / n } else { f64::NAN },
                    rmse: if a.n > 0 { rmse } else { f64::NAN },
                    crb_sigma: if a.n_crb > 0 { crb } else { f64::NAN },
                    ratio: if a.n_z > 0 { (a.z2 / a.n_z as f64).sqrt() } else { f64::NAN },
                    coverage_95: if a.n_cov > 0 { a.covered as f64 / a.n_cov as f64 } else { f64::NAN },
                    median_abs_error: a
                        .median_abs_error
                        .or_else(|| a.abs_error.as_ref().map(|h| h.quantile(0.5)))
                        .unwrap_or(f64::NAN),
                    worst_share: if a.sum2 > 0.0 { a.worst2 / a.sum2 } else { f64::NAN },
                }
            })
            .collect()
    }
}

/// The trial count and the drift table. Parts hold trials in order and cells are contiguous
/// runs of trials: once a batch starts past a cell, that cell's histograms are final and are
/// reduced to their quantiles, so memory holds at most the cells of one part.
#[derive(Default)]
struct DriftTable {
    hist: BTreeMap<(u32, String), Histogram>,
    order: Vec<(u32, String)>,
    drift: Vec<DriftSummary>,
    trials: u64,
}

impl DriftTable {
    fn finalize(&mut self, below: u32) {
        let (done, keep): (Vec<_>, Vec<_>) = self.order.drain(..).partition(|k| k.0 < below);
        self.order = keep;
        for k in done {
            if let Some(h) = self.hist.remove(&k) {
                self.drift.push(DriftSummary {
                    cell: k.0,
                    column: k.1,
                    unit: h.unit.clone(),
                    n: h.n,
                    diverged: h.infinite,
                    median: h.quantile(0.5),
                    p95: h.quantile(0.95),
                    p05: h.quantile(0.05),
                });
            }
        }
    }

    fn add(&mut self, batch: &RecordBatch, file: &Path) -> Result<(), ParquetIoError> {
        self.trials += batch.num_rows() as u64;
        let cell = column::<UInt32Array>(batch, "cell", file)?;
        if let Some(first) = cell.iter().flatten().min() {
            self.finalize(first);
        }
        let schema = batch.schema();
        for (k, f) in schema.fields().iter().enumerate() {
            if !f.name().contains("_err_") || !f.name().ends_with('s') || !f.name().contains("_at_") {
                continue;
            }
            let Some(values) = batch.column(k).as_any().downcast_ref::<Float64Array>() else { continue };
            for i in 0..batch.num_rows() {
                let key = (cell.value(i), f.name().clone());
                let order = &mut self.order;
                self.hist
                    .entry(key.clone())
                    .or_insert_with(|| {
                        order.push(key);
                        Histogram::new(f.metadata().get("unit").cloned().unwrap_or_default())
                    })
                    .add(values.value(i));
            }
        }
        Ok(())
    }

    fn finish(mut self) -> (u64, Vec<DriftSummary>) {
        self.finalize(u32::MAX);
        self.drift.sort_by_key(|d| d.cell);
        (self.trials, self.drift)
    }
}

/// The summary as one CSV table (`table` is `parameter` or `drift`; empty fields where a
/// statistic does not apply).
pub fn summary_csv(s: &Summary) -> String {
    let mut out = String::from(
        "table,cell,name,unit,n,bias,rmse,crb_sigma,ratio,coverage_95,diverged,median,p95,p05,median_abs_error,worst_share\n",
    );
    for p in &s.parameters {
        out.push_str(&format!(
            "parameter,{},{},{},{},{:e},{:e},{:e},{:e},{:e},,,,,{:e},{:e}\n",
            p.cell,
            p.name,
            p.unit,
            p.n,
            p.bias,
            p.rmse,
            p.crb_sigma,
            p.ratio,
            p.coverage_95,
            p.median_abs_error,
            p.worst_share
        ));
    }
    for d in &s.drift {
        out.push_str(&format!(
            "drift,{},{},{},{},,,,,,{},{:e},{:e},{:e},,\n",
            d.cell, d.column, d.unit, d.n, d.diverged, d.median, d.p95, d.p05
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::Histogram;

    /// Quantiles within 0.5% at any magnitude (the histogram used to end at 1e10, so a median of
    /// 6.87e10 came out as 9.977e9), with zeros and diverged values at the ends.
    #[test]
    fn quantiles_are_right_at_any_magnitude() {
        for scale in [1e-300, 1e-12, 1.0, 6.87e10, 1e200] {
            let mut h = Histogram::new(String::new());
            for i in 1..=1001 {
                h.add(scale * i as f64);
            }
            let median = h.quantile(0.5);
            assert!((median / (scale * 501.0) - 1.0).abs() < 0.005, "{scale}: median {median}");
            let p95 = h.quantile(0.95);
            assert!((p95 / (scale * 951.0) - 1.0).abs() < 0.005, "{scale}: p95 {p95}");
        }
        let mut h = Histogram::new(String::new());
        for v in [0.0, 0.0, 3.0, f64::INFINITY, f64::NAN] {
            h.add(v);
        }
        assert_eq!(h.quantile(0.5), 0.0);
        assert!(h.quantile(1.0).is_infinite());
    }
}
