//! Numeric tables as labs write them: CSV (via the `csv` crate: quoted headers, a byte-order
//! mark, CRLF line ends) or Parquet (every codec pyarrow writes; integer and float columns of any
//! width, read as f64). One row per sample; every column read is numeric.
//!
//! Rows are numbered for messages the same way in both formats: data row 1 is the first row
//! after the header (a CSV file's line 2).
//!
//! ```no_run
//! use gfcal::io::table::Table;
//! let t = Table::read(std::path::Path::new("recording.parquet")).unwrap();
//! let time_s = t.column("t_s").unwrap();
//! ```

use std::path::{Path, PathBuf};

use arrow_array::{Array, ArrayRef};
use arrow_schema::DataType;

/// A table that cannot be read; names the file, and the row and column where there is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    #[error("{}: cannot read: {}", path.display(), io_message(source))]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: {problem}", path.display())]
    Format { path: PathBuf, problem: String },
    #[error("{}: data row {row}, column `{column}`: {problem}", path.display())]
    Value { path: PathBuf, row: usize, column: String, problem: String },
    #[error("{}: cannot write: {problem}", path.display())]
    Write { path: PathBuf, problem: String },
}

/// The OS message without the repeated "(os error N)" detail when the kind says the same.
fn io_message(e: &std::io::Error) -> String {
    let s = e.to_string();
    match s.find(" (os error") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

/// Named numeric columns of equal length. A missing (null) value is NaN in `data` and flagged in
/// `null_rows`, so a reader can say "null" rather than "NaN".
#[derive(Debug, Clone, Default)]
pub struct Table {
    pub path: PathBuf,
    pub names: Vec<String>,
    pub data: Vec<Vec<f64>>,
    /// Per column, the first null row (1-based data row), if any.
    pub first_null_row: Vec<Option<usize>>,
}

/// Columns a writer adds that are not data (pandas' index).
const IGNORED: [&str; 1] = ["__index_level_0__"];

impl Table {
    /// Reads a `.csv` or `.parquet` file (by extension; anything else is tried as CSV).
    pub fn read(path: &Path) -> Result<Self, TableError> {
        let is_parquet = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("parquet"));
        let mut table = if is_parquet { read_parquet(path)? } else { read_csv(path)? };
        let keep: Vec<usize> =
            (0..table.names.len()).filter(|&k| !IGNORED.contains(&table.names[k].as_str())).collect();
        let table = Table {
            path: path.to_path_buf(),
            names: keep.iter().map(|&k| table.names[k].clone()).collect(),
            first_null_row: keep.iter().map(|&k| table.first_null_row[k]).collect(),
            data: keep.iter().map(|&k| std::mem::take(&mut table.data[k])).collect(),
        };
        if table.names.is_empty() {
            return Err(TableError::Format { path: path.to_path_buf(), problem: "the table has no columns".into() });
        }
        Ok(table)
    }

    pub fn rows(&self) -> usize {
        self.data.first().map_or(0, Vec::len)
    }

    /// The column called `name`, if present.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.names.iter().position(|n| n == name).map(|i| self.data[i].as_slice())
    }

    /// Index of the column called `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Writes the table (atomically) as Parquet for a `.parquet` name, CSV otherwise; every column
    /// as 64-bit floats (shortest round-trip digits in CSV).
    pub fn write(&self, path: &Path) -> Result<(), TableError> {
        let fail = |problem: String| TableError::Write { path: path.to_path_buf(), problem };
        let io = |source: std::io::Error| fail(io_message(&source));
        let format = |problem: String| fail(problem);
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("parquet")) {
            let fields: Vec<arrow_schema::Field> =
                self.names.iter().map(|n| arrow_schema::Field::new(n, DataType::Float64, false)).collect();
            let arrays: Vec<ArrayRef> = self
                .data
                .iter()
                .map(|d| std::sync::Arc::new(arrow_array::Float64Array::from(d.clone())) as ArrayRef)
                .collect();
            let batch =
                arrow_array::RecordBatch::try_new(std::sync::Arc::new(arrow_schema::Schema::new(fields)), arrays)
                    .map_err(|e| format(e.to_string()))?;
            crate::io::parquet::write_part(path, &batch, &[("gfcal:version".into(), env!("CARGO_PKG_VERSION").into())])
                .map_err(|e| match e {
                    crate::io::parquet::ParquetIoError::Io { source, .. } => io(source),
                    crate::io::parquet::ParquetIoError::Format { message, .. } => format(message),
                })
        } else {
            let mut w = csv::Writer::from_writer(Vec::new());
            w.write_record(&self.names).map_err(|e| format(e.to_string()))?;
            for i in 0..self.rows() {
                w.write_record(self.data.iter().map(|c| format!("{}", c[i]))).map_err(|e| format(e.to_string()))?;
            }
            let bytes = w.into_inner().map_err(|e| format(e.to_string()))?;
            crate::io::write_atomic(path, &bytes).map_err(io)
        }
    }
}

fn read_csv(path: &Path) -> Result<Table, TableError> {
    let bytes = std::fs::read(path).map_err(|source| TableError::Io { path: path.to_path_buf(), source })?;
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    let mut reader = csv::ReaderBuilder::new().has_headers(true).trim(csv::Trim::All).from_reader(bytes);
    let format = |problem: String| TableError::Format { path: path.to_path_buf(), problem };
    let names: Vec<String> = reader
        .headers()
        .map_err(|e| format(format!("cannot read the header: {e}")))?
        .iter()
        .map(str::to_string)
        .collect();
    if names.iter().all(|n| n.is_empty()) {
        return Err(format("the file is empty (no header)".into()));
    }
    if names.len() == 1
        && let Some(problem) = other_separator(&names[0], bytes)
    {
        return Err(format(problem));
    }
    let mut data = vec![Vec::new(); names.len()];
    let mut first_null_row = vec![None; names.len()];
    for (i, record) in reader.records().enumerate() {
        let row = i + 1;
        let record = record.map_err(|e| TableError::Value {
            path: path.to_path_buf(),
            row,
            column: "*".into(),
            problem: match e.kind() {
                csv::ErrorKind::UnequalLengths { len, expected_len, .. } if len > expected_len => format!(
                    "{len} fields, the header has {expected_len}: decimal commas (9,81) would split numbers in \
                     two; gfcal reads numbers with a decimal point (9.81)"
                ),
                csv::ErrorKind::UnequalLengths { len, expected_len, .. } => {
                    format!("{len} fields, the header has {expected_len}")
                }
                _ => e.to_string(),
            },
        })?;
        for (k, field) in record.iter().enumerate() {
            let v = if field.is_empty() {
                first_null_row[k].get_or_insert(row);
                f64::NAN
            } else {
                field.parse::<f64>().map_err(|_| TableError::Value {
                    path: path.to_path_buf(),
                    row,
                    column: names[k].clone(),
                    problem: if field.replacen(',', ".", 1).parse::<f64>().is_ok() {
                        format!("`{field}` is not a number: a decimal comma? gfcal reads a decimal point (9.81)")
                    } else {
                        format!("`{field}` is not a number")
                    },
                })?
            };
            data[k].push(v);
        }
    }
    Ok(Table { path: path.to_path_buf(), names, data, first_null_row })
}

/// A table the `csv` crate reads as one column: if its header is separated by semicolons or tabs,
/// the problem in words (with whether its numbers have decimal commas), for a file many
/// spreadsheets write in locales with a decimal comma.
fn other_separator(header: &str, bytes: &[u8]) -> Option<String> {
    let (separator, name) =
        [(';', "semicolons (`;`)"), ('\t', "tabs")].into_iter().find(|(c, _)| header.contains(*c))?;
    // The first data line: decimal commas show as a comma between two digits.
    let text = String::from_utf8_lossy(&bytes[..bytes.len().min(64 * 1024)]);
    let first = text.lines().nth(1).unwrap_or("");
    let decimal_comma = first.split(separator).any(|f| {
        f.trim().split_once(',').is_some_and(|(a, b)| {
            a.ends_with(|c: char| c.is_ascii_digit()) && b.starts_with(|c: char| c.is_ascii_digit())
        })
    });
    let shown: String = header.chars().take(60).collect();
    let sep = if separator == ';' { ";" } else { "\\t" };
    Some(format!(
        "the header `{shown}{}` is separated by {name}, not commas{}: gfcal reads CSV as comma-separated values with \
         a decimal point (9.81); write it so (pandas: `pd.read_csv(f, sep=\"{sep}\"{}).to_csv(out, index=False)`), \
         or as Parquet",
        if header.chars().count() > 60 { "..." } else { "" },
        if decimal_comma { ", and its numbers have decimal commas (9,81)" } else { "" },
        if decimal_comma { ", decimal=\",\"" } else { "" },
    ))
}

/// Reads a Parquet table; the decoder's panic on a damaged file is an error (see `io::guard`).
fn read_parquet(path: &Path) -> Result<Table, TableError> {
    crate::io::guard::decode(|| read_parquet_unguarded(path)).map_err(|m| TableError::Format {
        path: path.to_path_buf(),
        problem: format!("not a readable Parquet file (the decoder failed: {m})"),
    })?
}

fn read_parquet_unguarded(path: &Path) -> Result<Table, TableError> {
    let batches = crate::io::parquet::read_batches(path)
        .map_err(|e| TableError::Format { path: path.to_path_buf(), problem: e.to_string() })?;
    let schema = match batches.first() {
        Some(b) => b.schema(),
        None => {
            // A file with a schema and no rows still names its columns.
            let file =
                std::fs::File::open(path).map_err(|source| TableError::Io { path: path.to_path_buf(), source })?;
            parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
                .map_err(|e| TableError::Format { path: path.to_path_buf(), problem: e.to_string() })?
                .schema()
                .clone()
        }
    };
    let names: Vec<String> = schema.fields().iter().map(|f| f.name().clone()).collect();
    let mut data = vec![Vec::new(); names.len()];
    let mut first_null_row = vec![None; names.len()];
    for field in schema.fields().iter() {
        if IGNORED.contains(&field.name().as_str()) {
            continue;
        }
        if !is_numeric(field.data_type()) {
            return Err(TableError::Format {
                path: path.to_path_buf(),
                problem: format!("column `{}` is {}, expected numbers", field.name(), field.data_type()),
            });
        }
    }
    let mut offset = 0;
    for b in &batches {
        for (k, col) in b.columns().iter().enumerate() {
            if IGNORED.contains(&names[k].as_str()) {
                data[k].extend(std::iter::repeat_n(0.0, col.len()));
                continue;
            }
            let as_f64: ArrayRef = arrow_cast::cast(col, &DataType::Float64).map_err(|e| TableError::Format {
                path: path.to_path_buf(),
                problem: format!("`{}`: {e}", names[k]),
            })?;
            let a = as_f64.as_any().downcast_ref::<arrow_array::Float64Array>().ok_or_else(|| TableError::Format {
                path: path.to_path_buf(),
                problem: format!("`{}`: not castable to f64", names[k]),
            })?;
            for i in 0..a.len() {
                if a.is_null(i) {
                    first_null_row[k].get_or_insert(offset + i + 1);
                    data[k].push(f64::NAN);
                } else {
                    data[k].push(a.value(i));
                }
            }
        }
        offset += b.num_rows();
    }
    Ok(Table { path: path.to_path_buf(), names, data, first_null_row })
}

fn is_numeric(t: &DataType) -> bool {
    use DataType::*;
    matches!(t, Int8 | Int16 | Int32 | Int64 | UInt8 | UInt16 | UInt32 | UInt64 | Float16 | Float32 | Float64)
        || matches!(t, Dictionary(_, v) if is_numeric(v))
}
