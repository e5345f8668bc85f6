//! Parquet part files of a run: schemas (each column's unit in its field metadata and in the
//! file's `gfcal:units` key), atomic writes, provenance in the key-value metadata, reading back.

use std::collections::HashMap;
use std::fs::File;
use std::path::Path;
use std::sync::Arc;

use arrow_array::{
    ArrayRef, BooleanArray, Float64Array, RecordBatch, StringArray, UInt16Array, UInt32Array, UInt64Array,
};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;

use crate::mc::config::{FactorValue, McConfig};
use crate::mc::sample::SaltelliRow;
use crate::mc::trial::{DRIFT_METRICS, TrialRecord};

/// Why a Parquet file could not be written or read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ParquetIoError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: {message}")]
    Format { path: String, message: String },
}

fn field(name: &str, dt: DataType, unit: &str) -> Field {
    Field::new(name, dt, false).with_metadata(HashMap::from([("unit".to_string(), unit.to_string())]))
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
                fields.push(field(&drift_column(comp.name(), metric, *h), DataType::Float64, unit));
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

fn batch_error(path: &str, e: impl std::fmt::Display) -> ParquetIoError {
    ParquetIoError::Format { path: path.to_string(), message: e.to_string() }
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
        cols.push(floats(&|r| r.drift[d]));
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
    // What nominal compensation assumes, per cell: the nominal scale factors, every other error 0.
    let nominal: Vec<Vec<f64>> = cfg
        .cells
        .iter()
        .map(|c| {
            let params = crate::sensor::params::ArrayParams::nominal_with_scale_factors(
                &c.array,
                &c.errors.nominal_scale_factor,
            );
            c.layout.pack(&params).map(|x| x.iter().copied().collect()).unwrap_or_else(|_| vec![f64::NAN; p])
        })
        .collect();
    for r in records {
        let layout = &cfg.cells[r.cell as usize].layout;
        let nominal = &nominal[r.cell as usize];
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

/// Writes `batch` to `path` (zstd) with key-value metadata: to a hidden temporary name in the
/// same folder, synced, then renamed, so the file appears only when complete.
pub fn write_part(path: &Path, batch: &RecordBatch, metadata: &[(String, String)]) -> Result<(), ParquetIoError> {
    let shown = path.display().to_string();
    let io = |source| ParquetIoError::Io { path: shown.clone(), source };
    let tmp = super::temporary_path(path).map_err(io)?;
    let units: HashMap<String, String> = batch
        .schema()
        .fields()
        .iter()
        .map(|f| (f.name().clone(), f.metadata().get("unit").cloned().unwrap_or_default()))
        .collect();
    let mut kv: Vec<KeyValue> = metadata.iter().map(|(k, v)| KeyValue::new(k.clone(), v.clone())).collect();
    kv.push(KeyValue::new("gfcal:units".to_string(), serde_json::to_string(&units).unwrap_or_default()));
    // The same keys in the Arrow schema's metadata, so that readers that show the schema
    // (`pyarrow.parquet.read_table(f).schema.metadata`, Polars) see the provenance too.
    let schema_metadata: HashMap<String, String> =
        kv.iter().map(|k| (k.key.clone(), k.value.clone().unwrap_or_default())).collect();
    let schema = Arc::new(batch.schema().as_ref().clone().with_metadata(schema_metadata));
    let batch = batch.clone().with_schema(schema.clone()).map_err(|e| batch_error(&shown, e))?;
    let zstd = ZstdLevel::try_new(1).map_err(|e| batch_error(&shown, e))?;
    let props =
        WriterProperties::builder().set_compression(Compression::ZSTD(zstd)).set_key_value_metadata(Some(kv)).build();
    let result = (|| {
        let file = File::create(&tmp).map_err(io)?;
        let mut writer = ArrowWriter::try_new(file, schema, Some(props)).map_err(|e| batch_error(&shown, e))?;
        writer.write(&batch).map_err(|e| batch_error(&shown, e))?;
        let file = writer.into_inner().map_err(|e| batch_error(&shown, e))?;
        file.sync_all().map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The Parquet part files of a folder, in name order (empty if the folder is missing).
pub fn part_files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "parquet")).collect())
        .unwrap_or_default();
    files.sort();
    files
}

/// Column `name` of a batch read from `path`, as array type `T`.
pub fn column<'a, T: 'static>(batch: &'a RecordBatch, name: &str, path: &Path) -> Result<&'a T, ParquetIoError> {
    batch.column_by_name(name).and_then(|c| c.as_any().downcast_ref::<T>()).ok_or_else(|| ParquetIoError::Format {
        path: path.display().to_string(),
        message: format!("column `{name}` missing or mistyped"),
    })
}

/// The decoder's failure on a damaged file, as an error naming the file.
fn damaged(shown: &str, message: String) -> ParquetIoError {
    ParquetIoError::Format {
        path: shown.to_string(),
        message: format!("not a readable Parquet file (the decoder failed: {message})"),
    }
}

/// Reads every record batch of a Parquet file.
pub fn read_batches(path: &Path) -> Result<Vec<RecordBatch>, ParquetIoError> {
    let shown = path.display().to_string();
    let file = File::open(path).map_err(|source| ParquetIoError::Io { path: shown.clone(), source })?;
    super::guard::decode(|| {
        let reader = ParquetRecordBatchReaderBuilder::try_new(file)
            .and_then(|b| b.build())
            .map_err(|e| batch_error(&shown, e))?;
        reader.collect::<Result<Vec<_>, _>>().map_err(|e| batch_error(&shown, e))
    })
    .map_err(|m| damaged(&shown, m))?
}

/// Whether `path` is a whole Parquet file of `rows` rows: its footer reads (a file truncated by a
/// crash has none) and its row count is the expected one. Reads the footer only.
pub fn is_whole_part(path: &Path, rows: u64) -> bool {
    let Ok(file) = File::open(path) else { return false };
    super::guard::decode(|| match ParquetRecordBatchReaderBuilder::try_new(file) {
        Ok(b) => b.metadata().file_metadata().num_rows() == rows as i64,
        Err(_) => false,
    })
    .unwrap_or(false)
}

/// The key-value metadata of a Parquet file.
pub fn read_metadata(path: &Path) -> Result<HashMap<String, String>, ParquetIoError> {
    let shown = path.display().to_string();
    let file = File::open(path).map_err(|source| ParquetIoError::Io { path: shown.clone(), source })?;
    super::guard::decode(|| {
        let builder = ParquetRecordBatchReaderBuilder::try_new(file).map_err(|e| batch_error(&shown, e))?;
        Ok(builder
            .metadata()
            .file_metadata()
            .key_value_metadata()
            .map(|kv| kv.iter().map(|k| (k.key.clone(), k.value.clone().unwrap_or_default())).collect())
            .unwrap_or_default())
    })
    .map_err(|m| damaged(&shown, m))?
}
