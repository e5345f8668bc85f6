//! The summary of a run, computed from its Parquet files part by part (memory flat whatever the
//! trial count): per cell and parameter the bias, RMSE, RMS Cramer-Rao sigma, the RMS of the
//! normalised error `error / crb_sigma` (`ratio`), the coverage of the estimator's 95% interval,
//! and two robust columns that say when one trial dominates a row: the median absolute error
//! (from a log-spaced histogram, within 0.5%) and `worst_share`, the share of the summed squared
//! error that the worst trial holds; per cell and drift column the median and 95th
//! percentile and 5th percentile (from a sparse log-spaced histogram, 500 bins per decade: within 0.5%, at
//! any magnitude). A diverged
//! navigation (+inf) counts as larger than any value; a missing one (null, or NaN in runs written
//! before issue 30: no estimate) is left out. Per cell, the outcome of every trial's fit (`fits`:
//! `estimated` or why not, see [`super::outcome`]), and the sweep factors' values; and the flags
//! of a cell whose estimated compensation should not be read as it stands ([`cell_flags`]).

use std::collections::BTreeMap;
use std::path::Path;

use arrow_array::{Array, BooleanArray, Float64Array, RecordBatch, StringArray, UInt32Array};

use super::outcome::{OUTCOMES, outcome};
use super::output::{drift_value, factor_columns};
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

/// How many trials of a cell had one outcome (see [`super::outcome`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FitCount {
    pub cell: u32,
    /// `estimated`, or why the trial has no estimate.
    pub outcome: String,
    pub n: u64,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    pub trials: u64,
    pub parameters: Vec<ParameterSummary>,
    pub drift: Vec<DriftSummary>,
    /// Per cell, each outcome that occurred, in the order of [`OUTCOMES`].
    pub fits: Vec<FitCount>,
    /// The sweep factors (the trials table's factor columns), and each cell's values as text.
    pub factor_keys: Vec<String>,
    pub factors: BTreeMap<u32, Vec<String>>,
}

/// The rows of cell `c` among `rows` sorted by cell (as every table of a [`Summary`] is): a
/// binary search, so that going through a sweep's cells costs no more than its rows.
pub fn of_cell<T>(rows: &[T], c: u32, cell: impl Fn(&T) -> u32) -> &[T] {
    let start = rows.partition_point(|r| cell(r) < c);
    let end = start + rows[start..].partition_point(|r| cell(r) <= c);
    &rows[start..end]
}

impl Summary {
    pub fn parameters_of(&self, c: u32) -> &[ParameterSummary] {
        of_cell(&self.parameters, c, |p| p.cell)
    }
    pub fn drift_of(&self, c: u32) -> &[DriftSummary] {
        of_cell(&self.drift, c, |d| d.cell)
    }
}

/// The fewest trials with an estimate whose drift statistics a cell may rest on without a flag:
/// the 5th and 95th percentiles of fewer than 20 values are their extremes.
pub const MIN_ESTIMATES: u64 = 20;

/// A cell's fits: its trials, those estimated, and the count of each other outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct CellFits {
    pub cell: u32,
    pub trials: u64,
    pub estimated: u64,
    pub others: Vec<(String, u64)>,
}

impl CellFits {
    /// "18642 of 20000 trials estimated (93.2%); not estimated: 1358 left_small_error_region".
    pub fn describe(&self) -> String {
        let mut s = format!(
            "{} of {} trials estimated ({:.1}%)",
            self.estimated,
            self.trials,
            100.0 * self.estimated as f64 / self.trials.max(1) as f64
        );
        if !self.others.is_empty() {
            let others: Vec<String> = self.others.iter().map(|(o, n)| format!("{n} {o}")).collect();
            s.push_str(&format!("; not estimated: {}", others.join(", ")));
        }
        s
    }
}

/// Each cell's fits, from the summary's `fits` rows.
pub fn cell_fits(s: &Summary) -> Vec<CellFits> {
    let mut out: Vec<CellFits> = Vec::new();
    for f in &s.fits {
        if out.last().is_none_or(|c| c.cell != f.cell) {
            out.push(CellFits { cell: f.cell, trials: 0, estimated: 0, others: Vec::new() });
        }
        let c = out.last_mut().expect("pushed above");
        c.trials += f.n;
        if f.outcome == "estimated" {
            c.estimated += f.n;
        } else {
            c.others.push((f.outcome.clone(), f.n));
        }
    }
    out
}

/// Why a cell's estimated compensation should not be read as it stands.
#[derive(Debug, Clone, PartialEq)]
pub enum CellFlag {
    /// Fewer than [`MIN_ESTIMATES`] trials, or fewer than half the cell's, have an estimate: the
    /// estimated drift describes the trials whose fit succeeded, not the cell.
    FewEstimates { cell: u32, estimated: u64, trials: u64 },
    /// The estimated compensation's median drift is above the nominal's: calibrating made the
    /// navigation worse. `(metric column without the compensation, estimated median, nominal
    /// median, unit)`, for every such column.
    WorseThanNominal { cell: u32, columns: Vec<(String, f64, f64, String)> },
}

impl CellFlag {
    pub fn cell(&self) -> u32 {
        match self {
            CellFlag::FewEstimates { cell, .. } | CellFlag::WorseThanNominal { cell, .. } => *cell,
        }
    }

    /// One sentence saying what is wrong, with the numbers.
    pub fn describe(&self) -> String {
        match self {
            CellFlag::FewEstimates { estimated, trials, .. } => format!(
                "the estimated compensation rests on few trials: {estimated} of {trials} ({:.1}%) have an estimate \
                 (flagged below {MIN_ESTIMATES} or below half the cell); its drift describes the trials whose fit \
                 succeeded, not the cell",
                100.0 * *estimated as f64 / (*trials).max(1) as f64
            ),
            CellFlag::WorseThanNominal { columns, .. } => {
                let shown: Vec<String> = columns
                    .iter()
                    .take(3)
                    .map(|(c, e, n, unit)| {
                        use crate::io::format::significant as sig;
                        format!("{c} median {} against {} {unit}", sig(*e, 3), sig(*n, 3))
                    })
                    .collect();
                let more = columns.len().saturating_sub(3);
                format!(
                    "the estimated compensation is worse than nominal (no calibration) in {} drift column(s): {}{}",
                    columns.len(),
                    shown.join("; "),
                    if more > 0 { format!("; and {more} more") } else { String::new() }
                )
            }
        }
    }
}

/// The flags of every cell, in cell order.
pub fn cell_flags(s: &Summary) -> Vec<CellFlag> {
    let mut flags = Vec::new();
    let fits = cell_fits(s);
    let mut cells: Vec<u32> = fits.iter().map(|f| f.cell).collect();
    cells.extend(s.drift.iter().map(|d| d.cell));
    cells.sort_unstable();
    cells.dedup();
    for cell in cells {
        if let Some(f) = of_cell(&fits, cell, |f| f.cell).first()
            && f.trials > 0
            && (f.estimated < MIN_ESTIMATES || 2 * f.estimated < f.trials)
        {
            flags.push(CellFlag::FewEstimates { cell, estimated: f.estimated, trials: f.trials });
        }
        let mut worse = Vec::new();
        let drift = s.drift_of(cell);
        for d in drift {
            let Some(rest) = d.column.strip_prefix("estimated_") else { continue };
            let nominal = format!("nominal_{rest}");
            let Some(n) = drift.iter().find(|n| n.column == nominal) else { continue };
            if d.median.is_nan() || n.median.is_nan() {
                continue;
            }
            if d.median > n.median {
                worse.push((rest.to_string(), d.median, n.median, d.unit.clone()));
            }
        }
        if !worse.is_empty() {
            flags.push(CellFlag::WorseThanNominal { cell, columns: worse });
        }
    }
    flags
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
        let DriftOutput { trials, drift, fits, factor_keys, factors } = self.drift.finish();
        Summary { trials, parameters: self.parameters.finish(), drift, fits, factor_keys, factors }
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

/// The trial count, the drift table, the fits and the factors. Parts hold trials in order and
/// cells are contiguous runs of trials: once a batch starts past a cell, that cell's histograms
/// are final and are reduced to their quantiles, so memory holds at most the cells of one part.
#[derive(Default)]
struct DriftTable {
    hist: BTreeMap<(u32, String), Histogram>,
    order: Vec<(u32, String)>,
    drift: Vec<DriftSummary>,
    trials: u64,
    /// (cell, index in [`OUTCOMES`]) -> trials.
    fits: BTreeMap<(u32, usize), u64>,
    factor_keys: Vec<String>,
    factors: BTreeMap<u32, Vec<String>>,
}

/// What the drift table gives the summary.
struct DriftOutput {
    trials: u64,
    drift: Vec<DriftSummary>,
    fits: Vec<FitCount>,
    factor_keys: Vec<String>,
    factors: BTreeMap<u32, Vec<String>>,
}

/// A sweep factor's value as text: numbers as Rust writes them (shortest exact form).
fn factor_text(column: &dyn Array, i: usize) -> String {
    if let Some(v) = column.as_any().downcast_ref::<Float64Array>() {
        format!("{}", v.value(i))
    } else if let Some(v) = column.as_any().downcast_ref::<StringArray>() {
        v.value(i).to_string()
    } else {
        String::new()
    }
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
        // The outcome of each trial's fit, and each cell's factor values.
        let converged = column::<BooleanArray>(batch, "converged", file)?;
        let message = column::<StringArray>(batch, "message", file)?;
        let iterations = column::<UInt32Array>(batch, "iterations", file)?;
        let cost = column::<Float64Array>(batch, "cost", file)?;
        let estimated = schema
            .fields()
            .iter()
            .position(|f| f.name().starts_with("estimated_") && f.name().contains("_at_"))
            .and_then(|k| batch.column(k).as_any().downcast_ref::<Float64Array>());
        let factor_keys = factor_columns(&schema);
        if self.factor_keys.is_empty() {
            self.factor_keys = factor_keys.clone();
        }
        let factor_cols: Vec<&dyn Array> =
            factor_keys.iter().filter_map(|k| batch.column_by_name(k).map(|c| c.as_ref())).collect();
        for i in 0..batch.num_rows() {
            let has_estimate = !(iterations.value(i) == 0 && cost.value(i).is_nan());
            let missing = estimated.map(|e| drift_value(e, i).is_nan());
            let o = outcome(converged.value(i), message.value(i), has_estimate, missing);
            let k = OUTCOMES.iter().position(|x| *x == o).unwrap_or(OUTCOMES.len() - 1);
            *self.fits.entry((cell.value(i), k)).or_insert(0) += 1;
            self.factors
                .entry(cell.value(i))
                .or_insert_with(|| factor_cols.iter().map(|c| factor_text(*c, i)).collect());
        }
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
                    .add(drift_value(values, i));
            }
        }
        Ok(())
    }

    fn finish(mut self) -> DriftOutput {
        self.finalize(u32::MAX);
        self.drift.sort_by_key(|d| d.cell);
        let fits =
            self.fits.iter().map(|(&(cell, k), &n)| FitCount { cell, outcome: OUTCOMES[k].to_string(), n }).collect();
        DriftOutput {
            trials: self.trials,
            drift: self.drift,
            fits,
            factor_keys: self.factor_keys,
            factors: self.factors,
        }
    }
}

/// A CSV field: quoted when it holds a comma, a quote or a line break.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// The summary as one CSV table: `table` is `parameter`, `drift` or `fits` (per cell, `name`
/// an outcome and `n` its count); empty fields where a statistic does not apply. A sweep's
/// factors are columns after `cell`, named by their keys, with each cell's value.
pub fn summary_csv(s: &Summary) -> String {
    let factors = |cell: u32| -> String {
        let values = s.factors.get(&cell);
        (0..s.factor_keys.len())
            .map(|k| format!("{},", csv_field(values.and_then(|v| v.get(k)).map(String::as_str).unwrap_or(""))))
            .collect()
    };
    let mut out = String::from("table,cell,");
    for k in &s.factor_keys {
        out.push_str(&csv_field(k));
        out.push(',');
    }
    out.push_str(
        "name,unit,n,bias,rmse,crb_sigma,ratio,coverage_95,diverged,median,p95,p05,median_abs_error,worst_share\n",
    );
    for p in &s.parameters {
        out.push_str(&format!(
            "parameter,{},{}{},{},{},{:e},{:e},{:e},{:e},{:e},,,,,{:e},{:e}\n",
            p.cell,
            factors(p.cell),
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
            "drift,{},{}{},{},{},,,,,,{},{:e},{:e},{:e},,\n",
            d.cell,
            factors(d.cell),
            d.column,
            d.unit,
            d.n,
            d.diverged,
            d.median,
            d.p95,
            d.p05
        ));
    }
    for f in &s.fits {
        out.push_str(&format!("fits,{},{}{},,{},,,,,,,,,,,\n", f.cell, factors(f.cell), f.outcome, f.n));
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
