//! What `gfcal lincov` writes, and the columns it owns: `lincov.csv` (and `lincov.parquet`, the
//! same table with its units and provenance in the file's metadata), `budget.csv`, and
//! `compare.csv` (LinCov beside a Monte Carlo run).
//!
//! `lincov.csv`, one row per cell, compensation, horizon and drift metric; its first columns are
//! those of `summary.csv`'s drift table, in its SI units:
//!
//! | column | meaning |
//! | --- | --- |
//! | `cell`, `name`, `unit` | as in summary.csv (`name` is the drift column, e.g. `estimated_velocity_err_m_s_at_10s`) |
//! | `median`, `p95`, `p05` | quantiles of the metric; `inf` where a parameter the schedule cannot identify reaches it |
//! | `compensation`, `metric`, `horizon_s` | what `name` says, split |
//! | `rms` | `sqrt(E |e|^2)` |
//! | `components` | Gaussians in the distribution: 1, or the truths of a mixture |
//! | `median_se`, `p95_se` | standard errors of a mixture's quantiles from its finite draws (0 for one Gaussian) |
//! | `nonlinearity` | the navigator's departure from the linear prediction at the sigma points (`lincov::nonlinearity`) |
//! | `linear` | `true` where LinCov stands by its number (nonlinearity at most 0.1, and bounded) |
//! | `unbounded_by` | the unidentifiable parameters that make the row unbounded, space-separated |
//! | then one column per sweep factor | the cell's level |

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{ArrayRef, BooleanArray, Float64Array, RecordBatch, StringArray, UInt32Array, UInt64Array};
use arrow_schema::{DataType, Field, Schema};

use super::analysis::{CellResult, MetricResult, Source};
use crate::calib::params::ParamKind;
use crate::io::parquet::{ParquetIoError, batch_error};
use crate::mc::config::{FactorValue, McConfig};
use crate::mc::output::drift_column;
use crate::mc::trial::DRIFT_METRICS;

/// The CSV value of a float: Rust's shortest round-trip form in scientific notation (`inf`,
/// `nan` as such).
fn num(v: f64) -> String {
    if v.is_finite() { format!("{v:e}") } else { format!("{v}") }
}

fn factor_text(v: &FactorValue) -> String {
    match v {
        FactorValue::Number(x) => format!("{x}"),
        FactorValue::Text(s) => s.clone(),
    }
}

/// The drift column a row describes.
pub fn row_name(r: &MetricResult) -> String {
    drift_column(r.compensation.name(), DRIFT_METRICS[r.metric].0, r.horizon_s)
}

/// `lincov.csv`.
pub fn lincov_csv(cfg: &McConfig, results: &[CellResult]) -> String {
    let mut out = String::from(
        "cell,name,unit,median,p95,p05,compensation,metric,horizon_s,rms,components,median_se,p95_se,nonlinearity,linear,unbounded_by",
    );
    for k in &cfg.factor_keys {
        out.push(',');
        out.push_str(k);
    }
    out.push('\n');
    for c in results {
        let factors: Vec<String> = cfg.cells[c.cell].factors.iter().map(|(_, v)| factor_text(v)).collect();
        for r in &c.rows {
            out.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                c.cell,
                row_name(r),
                DRIFT_METRICS[r.metric].1,
                num(r.median),
                num(r.p95),
                num(r.p05),
                r.compensation.name(),
                DRIFT_METRICS[r.metric].0,
                r.horizon_s,
                num(r.rms),
                r.components,
                num(r.median_se),
                num(r.p95_se),
                num(r.nonlinearity),
                r.linear,
                r.unbounded_by.join(" ")
            ));
            for f in &factors {
                out.push(',');
                out.push_str(f);
            }
            out.push('\n');
        }
    }
    out
}

fn field(name: &str, dt: DataType, unit: &str) -> Field {
    Field::new(name, dt, false).with_metadata(HashMap::from([("unit".to_string(), unit.to_string())]))
}

/// `lincov.parquet`: the rows of `lincov.csv` (sweep factors numeric where every level is).
pub fn lincov_batch(cfg: &McConfig, results: &[CellResult]) -> Result<RecordBatch, ParquetIoError> {
    let rows: Vec<(usize, &MetricResult)> =
        results.iter().flat_map(|c| c.rows.iter().map(move |r| (c.cell, r))).collect();
    let mut fields = vec![
        field("cell", DataType::UInt32, "1"),
        field("name", DataType::Utf8, "1"),
        field("unit", DataType::Utf8, "1"),
        field("median", DataType::Float64, "see column `unit`"),
        field("p95", DataType::Float64, "see column `unit`"),
        field("p05", DataType::Float64, "see column `unit`"),
        field("compensation", DataType::Utf8, "1"),
        field("metric", DataType::Utf8, "1"),
        field("horizon_s", DataType::Float64, "s"),
        field("rms", DataType::Float64, "see column `unit`"),
        field("components", DataType::UInt64, "1"),
        field("median_se", DataType::Float64, "see column `unit`"),
        field("p95_se", DataType::Float64, "see column `unit`"),
        field("nonlinearity", DataType::Float64, "1"),
        field("linear", DataType::Boolean, "1"),
        field("unbounded_by", DataType::Utf8, "1"),
    ];
    let floats = |f: &dyn Fn(&MetricResult) -> f64| -> ArrayRef {
        Arc::new(Float64Array::from(rows.iter().map(|(_, r)| f(r)).collect::<Vec<_>>()))
    };
    let strings = |f: &dyn Fn(usize, &MetricResult) -> String| -> ArrayRef {
        Arc::new(StringArray::from(rows.iter().map(|(c, r)| f(*c, r)).collect::<Vec<_>>()))
    };
    let mut cols: Vec<ArrayRef> = vec![
        Arc::new(UInt32Array::from(rows.iter().map(|(c, _)| *c as u32).collect::<Vec<_>>())),
        strings(&|_, r| row_name(r)),
        strings(&|_, r| DRIFT_METRICS[r.metric].1.to_string()),
        floats(&|r| r.median),
        floats(&|r| r.p95),
        floats(&|r| r.p05),
        strings(&|_, r| r.compensation.name().to_string()),
        strings(&|_, r| DRIFT_METRICS[r.metric].0.to_string()),
        floats(&|r| r.horizon_s),
        floats(&|r| r.rms),
        Arc::new(UInt64Array::from(rows.iter().map(|(_, r)| r.components as u64).collect::<Vec<_>>())),
        floats(&|r| r.median_se),
        floats(&|r| r.p95_se),
        floats(&|r| r.nonlinearity),
        Arc::new(BooleanArray::from(rows.iter().map(|(_, r)| r.linear).collect::<Vec<_>>())),
        strings(&|_, r| r.unbounded_by.join(" ")),
    ];
    for (k, key) in cfg.factor_keys.iter().enumerate() {
        let numeric = cfg.cells.iter().all(|c| matches!(c.factors[k].1, FactorValue::Number(_)));
        if numeric {
            fields.push(field(key, DataType::Float64, "as in the key's name"));
            cols.push(Arc::new(Float64Array::from(
                rows.iter()
                    .map(|(c, _)| match &cfg.cells[*c].factors[k].1 {
                        FactorValue::Number(x) => *x,
                        FactorValue::Text(_) => f64::NAN,
                    })
                    .collect::<Vec<_>>(),
            )));
        } else {
            fields.push(field(key, DataType::Utf8, "as in the key's name"));
            cols.push(strings(&|c, _| factor_text(&cfg.cells[c].factors[k].1)));
        }
    }
    RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).map_err(|e| batch_error("lincov table", e))
}

/// The kind of a budget source, as `budget.csv` names it.
fn source_kind(cfg: &McConfig, cell: usize, s: &Source) -> (String, String, String) {
    let layout = &cfg.cells[cell].layout;
    match s {
        Source::Parameter(i) => {
            let kind = match layout.kind(*i) {
                ParamKind::ScaleFactor => "scale_factor",
                ParamKind::Bias => "bias",
                ParamKind::Misalignment(_) => "misalignment",
                ParamKind::Location(_) => "location",
            };
            (layout.name(*i), kind.to_string(), (layout.accel(*i) + 1).to_string())
        }
        Source::Fixture => ("fixture".into(), "fixture".into(), String::new()),
        Source::Noise => ("noise".into(), "noise".into(), String::new()),
    }
}

/// `budget.csv`: per cell, drift column and source, the source's share of the metric's mean
/// square `E |e|^2` (`mean_square`, in the unit squared; `share` its fraction of the total).
/// Shares add up to the total; a source switched off contributes zero.
pub fn budget_csv(cfg: &McConfig, results: &[CellResult]) -> String {
    let mut out =
        String::from("cell,name,unit,compensation,metric,horizon_s,source,kind,accelerometer,mean_square,share\n");
    for c in results {
        for r in &c.rows {
            let total: f64 = r.budget.iter().map(|(_, v)| v).sum();
            let unit = DRIFT_METRICS[r.metric].1;
            for (s, v) in &r.budget {
                let (source, kind, accel) = source_kind(cfg, c.cell, s);
                let share = if total > 0.0 && total.is_finite() { v / total } else { f64::NAN };
                out.push_str(&format!(
                    "{},{},({unit})^2,{},{},{},{},{},{},{},{}\n",
                    c.cell,
                    row_name(r),
                    r.compensation.name(),
                    DRIFT_METRICS[r.metric].0,
                    r.horizon_s,
                    source,
                    kind,
                    accel,
                    num(*v),
                    num(share)
                ));
            }
        }
    }
    out
}
