//! Parquet files: atomic writes of a record batch with provenance in the key-value metadata (each
//! column's unit from its field metadata into the file's `gfcal:units` key), and reading back.
//! What the columns mean belongs to the module that owns the table (`mc::output` for a run).

use std::collections::HashMap;
use std::fs::File;
use std::path::Path;
use std::sync::Arc;

use arrow_array::RecordBatch;
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;

/// Why a Parquet file could not be written or read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ParquetIoError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: {message}")]
    Format { path: String, message: String },
}

/// A record batch or Parquet stream that could not be built or decoded, as an error naming `path`.
pub fn batch_error(path: &str, e: impl std::fmt::Display) -> ParquetIoError {
    ParquetIoError::Format { path: path.to_string(), message: e.to_string() }
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
