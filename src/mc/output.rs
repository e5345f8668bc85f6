//! The run's tables as written to Parquet: the schemas of `trials/` (one row per trial) and
//! `parameters/` (one row per trial, accelerometer and parameter), each column's unit in its field
//! metadata, and the record batches built from the trial records. `io::parquet` writes them.
//!
//! The drift columns are nullable: a trial with no estimate to navigate with has null there (not
//! NaN, which polars and pandas count in quantiles and means; they skip null). +inf means the
//! navigation diverged. Runs written before issue 30 have NaN where there is no estimate; readers
//! here take both.

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{
    ArrayRef, BooleanArray, Float64Array, RecordBatch, StringArray, UInt16Array, UInt32Array, UInt64Array,
};
use arrow_schema::{DataType, Field, Schema, SchemaRef};

use super::config::{FactorValue, McConfig};
use super::sample::SaltelliRow;
use super::trial::{DRIFT_METRICS, TrialRecord};
use crate::io::parquet::{ParquetIoError, batch_error};

fn field(name: &str, dt: DataType, unit: &str) -> Field {
    Field::new(name, dt, false).with_metadata(HashMap::from([("unit".to_string(), unit.to_string())]))
}

/// A drift column: nullable (null where the trial has no estimate to navigate with).
fn drift_field(name: &str, unit: &str) -> Field {
    field(name, DataType::Float64, unit).with_nullable(true)
}

/// The sweep factors' columns of a trials table: those between `cell` and the noise density.
pub fn factor_columns(schema: &Schema) -> Vec<String> {
    let names: Vec<&String> = schema.fields().iter().map(|f| f.name()).collect();
    let start = names.iter().position(|n| *n == "cell").map(|i| i + 1);
    let end = names.iter().position(|n| *n == "white_noise_density_m_s2_per_sqrt_hz");
    match (start, end) {
        (Some(a), Some(b)) if a <= b => names[a..b].iter().map(|n| n.to_string()).collect(),
        _ => Vec::new(),
    }
}

/// Row `i` of a drift column, NaN where there is no value (null; NaN in runs before issue 30).
pub fn drift_value(values: &Float64Array, i: usize) -> f64 {
    use arrow_array::Array;
    if values.is_null(i) { f64::NAN } else { values.value(i) }
}

/// Name of a drift column, e.g. `estimated_velocity_err_m_s_at_10s`.
pub fn drift_column(compensation: &str, metric: &str, horizon_s: f64) -> String {
    format!("{compensation}_{metric}_at_{horizon_s}s")
}

/// Whether every cell's value of factor `k` is a number.
fn numeric_factor(cfg: &McConfig, k: usize) -> bool {
    cfg.cells.iter().all(|c| matches!(c.factors[k].1, FactorValue::Number(_)))
}

/// Schema of `trials/`: one row per trial.
pub fn trials_schema(cfg: &McConfig) -> SchemaRef {
    let mut fields = vec![field("trial_id", DataType::UInt64, "1"), field("cell", DataType::UInt32, "1")];
    for (k, key) in cfg.factor_keys.iter().enumerate() {
        let dt = if numeric_factor(cfg, k) { DataType::Float64 } else { DataType::Utf8 };
        fields.push(field(key, dt, "as in the key's name"));
    }
    fields.extend([
        field("white_noise_density_m_s2_per_sqrt_hz", DataType::Float64, "m/s^2/sqrt(Hz)"),
        field("schedule", DataType::Utf8, "1"),
        field("estimator", DataType::Utf8, "1"),
        field("form", DataType::Utf8, "1"),
        field("seed", DataType::UInt64, "1"),
        field("stream", DataType::UInt64, "1"),
        field("converged", DataType::Boolean, "1"),
        field("iterations", DataType::UInt32, "1"),
        field("cost", DataType::Float64, "(m/s^2)^2"),
        field("condition_number", DataType::Float64, "1"),
        field("residual_sigma_m_s2", DataType::Float64, "m/s^2"),
        field("message", DataType::Utf8, "1"),
    ]);
    if cfg.cells[0].saltelli.is_some() {
        fields.push(field("saltelli_sample", DataType::UInt64, "1"));
        fields.push(field("saltelli_matrix", DataType::Utf8, "1"));
    }
    let nav = &cfg.cells[0].navigation;
    for comp in &nav.compensations {
        for h in &nav.horizons_s {
            for (metric, unit) in DRIFT_METRICS {
                fields.push(drift_field(&drift_column(comp.name(), metric, *h), unit));
            }
        }
    }
    Arc::new(Schema::new(fields))
}

/// Schema of `parameters/`: one row per trial, accelerometer and parameter.
pub fn parameters_schema() -> SchemaRef {
    Arc::new(Schema::new(vec![
        field("trial_id", DataType::UInt64, "1"),
        field("cell", DataType::UInt32, "1"),
        field("accelerometer", DataType::UInt16, "1"),
        field("parameter", DataType::Utf8, "1"),
        field("name", DataType::Utf8, "1"),
        field("unit", DataType::Utf8, "1"),
        field("true", DataType::Float64, "see column `unit`"),
        field("nominal", DataType::Float64, "see column `unit`"),
        field("estimated", DataType::Float64, "see column `unit`"),
        field("error", DataType::Float64, "see column `unit`"),
        field("crb_sigma", DataType::Float64, "see column `unit`"),
        field("estimated_sigma", DataType::Float64, "see column `unit`"),
    ]))
}

/// The trials of one part as a record batch.
pub fn trials_batch(cfg: &McConfig, records: &[TrialRecord]) -> Result<RecordBatch, ParquetIoError> {
    let schema = trials_schema(cfg);
    let cell = |r: &TrialRecord| &cfg.cells[r.cell as usize];
    let mut cols: Vec<ArrayRef> = vec![
        Arc::new(UInt64Array::from(records.iter().map(|r| r.trial).collect::<Vec<_>>())),
        Arc::new(UInt32Array::from(records.iter().map(|r| r.cell).collect::<Vec<_>>())),
    ];
    for k in 0..cfg.factor_keys.len() {
        if numeric_factor(cfg, k) {
            let v: Vec<f64> = records
                .iter()
                .map(|r| match &cell(r).factors[k].1 {
                    FactorValue::Number(x) => *x,
                    FactorValue::Text(_) => f64::NAN,
                })
                .collect();
            cols.push(Arc::new(Float64Array::from(v)));
        } else {
            let v: Vec<String> = records
                .iter()
                .map(|r| match &cell(r).factors[k].1 {
                    FactorValue::Number(x) => x.to_string(),
                    FactorValue::Text(s) => s.clone(),
                })
                .collect();
            cols.push(Arc::new(StringArray::from(v)));
        }
    }
    let strings = |f: &dyn Fn(&TrialRecord) -> String| -> ArrayRef {
        Arc::new(StringArray::from(records.iter().map(f).collect::<Vec<_>>()))
    };
    let floats = |f: &dyn Fn(&TrialRecord) -> f64| -> ArrayRef {
        Arc::new(Float64Array::from(records.iter().map(f).collect::<Vec<_>>()))
    };
    cols.push(floats(&|r| cell(r).noise.white.density_m_s2_per_sqrt_hz()));
    cols.push(strings(&|r| cell(r).schedule.name.clone()));
    cols.push(strings(&|r| format!("{:?}", cell(r).calibration.estimator).to_lowercase()));
    cols.push(strings(&|r| cell(r).calibration.form.name().to_string()));
    cols.push(Arc::new(UInt64Array::from(vec![cfg.seed; records.len()])));
    cols.push(Arc::new(UInt64Array::from(records.iter().map(|r| r.trial).collect::<Vec<_>>())));
    cols.push(Arc::new(BooleanArray::from(records.iter().map(|r| r.converged).collect::<Vec<_>>())));
    cols.push(Arc::new(UInt32Array::from(records.iter().map(|r| r.iterations).collect::<Vec<_>>())));
    cols.push(floats(&|r| r.cost));
    cols.push(floats(&|r| r.condition_number));
    cols.push(floats(&|r| r.residual_sigma_m_s2));
    cols.push(strings(&|r| r.message.clone()));
    if cfg.cells[0].saltelli.is_some() {
        let role = |r: &TrialRecord| {
            let c = cell(r);
            c.saltelli.as_ref().map(|s| (s.role(r.trial), s, c))
        };
        cols.push(Arc::new(UInt64Array::from(
            records.iter().map(|r| role(r).map(|((j, _), ..)| j).unwrap_or(0)).collect::<Vec<_>>(),
        )));
        cols.push(strings(&|r| match role(r) {
            Some(((_, SaltelliRow::A), ..)) => "A".to_string(),
            Some(((_, SaltelliRow::B), ..)) => "B".to_string(),
            Some(((_, SaltelliRow::AB(i)), s, c)) => format!("AB:{}", c.layout.name(s.inputs[i])),
            None => String::new(),
        }));
    }
    let n_drift = records.first().map(|r| r.drift.len()).unwrap_or(0);
    for d in 0..n_drift {
        // NaN in a record means no estimate: null in the table.
        let values: Vec<Option<f64>> = records.iter().map(|r| Some(r.drift[d]).filter(|v| !v.is_nan())).collect();
        cols.push(Arc::new(Float64Array::from(values)));
    }
    RecordBatch::try_new(schema, cols).map_err(|e| batch_error("trials batch", e))
}

/// The parameters of one part as a record batch.
pub fn parameters_batch(cfg: &McConfig, records: &[TrialRecord]) -> Result<RecordBatch, ParquetIoError> {
    let layout = &cfg.cells[0].layout;
    let p = layout.len();
    let rows = records.len() * p;
    let (mut trial, mut cell, mut accel) =
        (Vec::with_capacity(rows), Vec::with_capacity(rows), Vec::with_capacity(rows));
    let (mut parameter, mut name, mut unit) =
        (Vec::with_capacity(rows), Vec::with_capacity(rows), Vec::with_capacity(rows));
    let (mut t, mut e, mut err, mut crb, mut es) = (vec![], vec![], vec![], vec![], vec![]);
    let mut nom = Vec::with_capacity(rows);
    // What nominal compensation assumes, per cell of the part: the nominal scale factors, every
    // other error 0.
    let mut nominal: std::collections::BTreeMap<u32, Vec<f64>> = std::collections::BTreeMap::new();
    for r in records {
        nominal.entry(r.cell).or_insert_with(|| {
            let c = &cfg.cells[r.cell as usize];
            let params = crate::sensor::params::ArrayParams::nominal_with_scale_factors(
                &c.array,
                &c.errors.nominal_scale_factor,
            );
            c.layout.pack(&params).map(|x| x.iter().copied().collect()).unwrap_or_else(|_| vec![f64::NAN; p])
        });
    }
    for r in records {
        let layout = &cfg.cells[r.cell as usize].layout;
        let nominal = &nominal[&r.cell];
        for (i, nominal_i) in nominal.iter().enumerate().take(p) {
            trial.push(r.trial);
            cell.push(r.cell);
            accel.push((layout.accel(i) + 1) as u16);
            parameter.push(layout.quantity(i));
            name.push(layout.name(i));
            unit.push(layout.kind(i).si_unit());
            t.push(r.truth[i]);
            nom.push(*nominal_i);
            e.push(r.estimated[i]);
            err.push(r.estimated[i] - r.truth[i]);
            crb.push(r.crb_sigma[i]);
            es.push(r.estimated_sigma[i]);
        }
    }
    let cols: Vec<ArrayRef> = vec![
        Arc::new(UInt64Array::from(trial)),
        Arc::new(UInt32Array::from(cell)),
        Arc::new(UInt16Array::from(accel)),
        Arc::new(StringArray::from(parameter)),
        Arc::new(StringArray::from(name)),
        Arc::new(StringArray::from(unit)),
        Arc::new(Float64Array::from(t)),
        Arc::new(Float64Array::from(nom)),
        Arc::new(Float64Array::from(e)),
        Arc::new(Float64Array::from(err)),
        Arc::new(Float64Array::from(crb)),
        Arc::new(Float64Array::from(es)),
    ];
    RecordBatch::try_new(parameters_schema(), cols).map_err(|e| batch_error("parameters batch", e))
}
