//! Calibration logs: one row per sample, as CSV or Parquet (the same columns).
//!
//! | column | meaning |
//! | --- | --- |
//! | `step` | integer step number; a step's rows are contiguous and steps are in time order |
//! | `t_s` | time since the start of the log, s, increasing |
//! | `up_x, up_y, up_z` | commanded up direction, body axes (any length; constant within a step) |
//! | `omega_x_rad_s, omega_y_rad_s, omega_z_rad_s` | commanded body rate, rad/s (zero: static; otherwise along `up`, the rate table's axis vertical) |
//! | `temp_c` | optional temperature, deg C |
//! | `s1 ... sN` | the N outputs, output units |

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, Int64Array, RecordBatch};
use arrow_schema::{DataType, Field, Schema};
use nalgebra::Vector3;

use crate::calib::measure::{Measurements, StepStats};
use crate::calib::schedule::{Schedule, Step};
use crate::io::table::{Table, TableError};

/// One step of a log.
#[derive(Debug, Clone, PartialEq)]
pub struct LogStep {
    pub step: i64,
    pub up_b: Vector3<f64>,
    pub omega_b_rad_s: Vector3<f64>,
    pub t_s: Vec<f64>,
    /// Empty without a temperature column.
    pub temp_c: Vec<f64>,
    /// Sample-major: `outputs[i * n + j]` is sample i of accelerometer j.
    pub outputs: Vec<f64>,
}

impl LogStep {
    pub fn samples(&self) -> usize {
        self.t_s.len()
    }
}

/// A calibration log of an array of `n` accelerometers.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationLog {
    pub n: usize,
    pub steps: Vec<LogStep>,
}

/// A log that cannot be used; names the file, and the row and column where there is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LogError {
    #[error("{}: cannot read: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: cannot write: {problem}", path.display())]
    Write { path: PathBuf, problem: String },
    #[error("{}: {problem}", path.display())]
    Format { path: PathBuf, problem: String },
    #[error("{}: missing column(s): {}", path.display(), missing.join(", "))]
    MissingColumns { path: PathBuf, missing: Vec<String> },
    #[error("{}: unknown column(s): {} (expected step, t_s, up_*, omega_*_rad_s, temp_c, s1..sN)", path.display(), unknown.join(", "))]
    UnknownColumns { path: PathBuf, unknown: Vec<String> },
    #[error("{}: data row {row}, column `{column}`: {problem}", path.display())]
    Value { path: PathBuf, row: usize, column: String, problem: String },
    #[error("{}: step {step}: {problem}", path.display())]
    Step { path: PathBuf, step: i64, problem: String },
    #[error("{}: the log has {found} outputs (s1..s{found}) but the array has {expected} accelerometers", path.display())]
    Count { path: PathBuf, found: usize, expected: usize },
    #[error("{}: the log has {steps} step(s); fitting needs at least {needed}", path.display())]
    TooShort { path: PathBuf, steps: usize, needed: usize },
}

const FIXED: [&str; 8] = ["step", "t_s", "up_x", "up_y", "up_z", "omega_x_rad_s", "omega_y_rad_s", "omega_z_rad_s"];

/// Columns of a log as f64 vectors (the step as f64 too), with the row numbers used in messages
/// (CSV: the file's line number; Parquet: 1-based row index).
struct Columns {
    names: Vec<String>,
    data: Vec<Vec<f64>>,
    row_base: usize,
}

impl CalibrationLog {
    /// Reads and checks a log (`.parquet`, or CSV otherwise) of an array of `n` accelerometers.
    ///
    /// Read through `io::table` (the `csv` crate; Parquet of every codec, numeric columns of any
    /// width, pandas' index column ignored); rows are counted as data rows in both formats.
    pub fn read(path: &Path, n: usize) -> Result<Self, LogError> {
        let table = Table::read(path).map_err(|e| match e {
            TableError::Io { path, source } => LogError::Io { path, source },
            TableError::Value { path, row, column, problem } => LogError::Value { path, row, column, problem },
            other => LogError::Format { path: path.to_path_buf(), problem: other.to_string() },
        })?;
        if let Some((k, row)) = table.first_null_row.iter().enumerate().find_map(|(k, r)| r.map(|r| (k, r))) {
            return Err(LogError::Value {
                path: path.to_path_buf(),
                row,
                column: table.names[k].clone(),
                problem: "missing value (null)".into(),
            });
        }
        Self::from_columns(path, Columns { names: table.names, data: table.data, row_base: 1 }, n)
    }

    fn from_columns(path: &Path, cols: Columns, n: usize) -> Result<Self, LogError> {
        let p = || path.to_path_buf();
        let index = |name: &str| cols.names.iter().position(|c| c == name);
        let missing: Vec<String> = FIXED.iter().filter(|c| index(c).is_none()).map(|c| c.to_string()).collect();
        let outputs: Vec<usize> = (1..).map_while(|j| index(&format!("s{j}"))).collect();
        let mut missing = missing;
        if outputs.is_empty() {
            missing.push("s1..sN".into());
        }
        if !missing.is_empty() {
            return Err(LogError::MissingColumns { path: p(), missing });
        }
        let known = |c: &String| {
            FIXED.contains(&c.as_str())
                || c == "temp_c"
                || c.strip_prefix('s')
                    .and_then(|k| k.parse::<usize>().ok())
                    .is_some_and(|k| k >= 1 && k <= outputs.len())
        };
        let unknown: Vec<String> = cols.names.iter().filter(|c| !known(c)).cloned().collect();
        if !unknown.is_empty() {
            return Err(LogError::UnknownColumns { path: p(), unknown });
        }
        if outputs.len() != n {
            return Err(LogError::Count { path: p(), found: outputs.len(), expected: n });
        }
        let col = |name: &str| &cols.data[index(name).unwrap_or(0)];
        let rows = col("step").len();
        // Every value finite.
        for (k, name) in cols.names.iter().enumerate() {
            if let Some(i) = cols.data[k].iter().position(|v| !v.is_finite()) {
                return Err(LogError::Value {
                    path: p(),
                    row: i + cols.row_base,
                    column: name.clone(),
                    problem: format!("{} is not a finite number", cols.data[k][i]),
                });
            }
        }
        let temp = index("temp_c");
        let mut steps: Vec<LogStep> = Vec::new();
        let mut last_t = f64::NEG_INFINITY;
        for i in 0..rows {
            let row = i + cols.row_base;
            let sv = col("step")[i];
            if sv.fract() != 0.0 {
                return Err(LogError::Value {
                    path: p(),
                    row,
                    column: "step".into(),
                    problem: format!("{sv} is not an integer"),
                });
            }
            let step = sv as i64;
            let t = col("t_s")[i];
            if t <= last_t {
                return Err(LogError::Value {
                    path: p(),
                    row,
                    column: "t_s".into(),
                    problem: format!("{t} does not increase (previous {last_t})"),
                });
            }
            last_t = t;
            let up = Vector3::new(col("up_x")[i], col("up_y")[i], col("up_z")[i]);
            let w = Vector3::new(col("omega_x_rad_s")[i], col("omega_y_rad_s")[i], col("omega_z_rad_s")[i]);
            let new_step = steps.last().is_none_or(|s| s.step != step);
            if new_step {
                if let Some(prev) = steps.last()
                    && step < prev.step
                {
                    return Err(LogError::Step {
                        path: p(),
                        step,
                        problem: format!(
                            "comes after step {} (data row {row}): steps must be in time order, each step's rows together",
                            prev.step
                        ),
                    });
                }
                if up.norm() < 1e-9 {
                    return Err(LogError::Step {
                        path: p(),
                        step,
                        problem: format!("the up direction at data row {row} is not a direction"),
                    });
                }
                if w.norm() > 0.0 && (up.normalize().dot(&w.normalize())).abs() < 1.0 - 1e-6 {
                    return Err(LogError::Step {
                        path: p(),
                        step,
                        problem: format!(
                            "the spin axis at data row {row} is not vertical (omega not along up); the model needs the rate table's axis vertical"
                        ),
                    });
                }
                steps.push(LogStep { step, up_b: up, omega_b_rad_s: w, t_s: vec![], temp_c: vec![], outputs: vec![] });
            }
            let Some(s) = steps.last_mut() else { continue };
            if (s.up_b - up).norm() > 1e-9 * up.norm() || (s.omega_b_rad_s - w).norm() > 1e-9 * w.norm().max(1.0) {
                return Err(LogError::Step {
                    path: p(),
                    step,
                    problem: format!("the commanded up or rate changes within the step (data row {row})"),
                });
            }
            s.t_s.push(t);
            if let Some(k) = temp {
                s.temp_c.push(cols.data[k][i]);
            }
            s.outputs.extend(outputs.iter().map(|&k| cols.data[k][i]));
        }
        if steps.is_empty() {
            return Err(LogError::TooShort { path: p(), steps: 0, needed: 1 });
        }
        Ok(Self { n, steps })
    }

    pub fn has_temperature(&self) -> bool {
        self.steps.first().is_some_and(|s| !s.temp_c.is_empty())
    }

    /// The schedule the log followed: a static pose or a spin per step, with the step's sample
    /// rate (from its median sample interval) and duration.
    pub fn schedule(&self) -> Result<Schedule, crate::calib::schedule::ScheduleError> {
        let steps = self
            .steps
            .iter()
            .map(|s| {
                let mut dts: Vec<f64> = s.t_s.windows(2).map(|w| w[1] - w[0]).collect();
                dts.sort_by(f64::total_cmp);
                let rate_hz = dts.get(dts.len() / 2).map(|dt| 1.0 / dt).unwrap_or(1.0);
                let duration_s = s.samples() as f64 / rate_hz;
                let name = format!("step {}", s.step);
                let w = s.omega_b_rad_s.norm();
                if w == 0.0 {
                    Step::static_pose(name, s.up_b, duration_s, rate_hz)
                } else {
                    let axis = s.omega_b_rad_s / w;
                    Step::spin(name, axis, w, axis.dot(&s.up_b) > 0.0, duration_s, rate_hz)
                }
            })
            .collect();
        Schedule::new("log", steps)
    }

    /// Mean and within-step scatter of each output per step.
    pub fn measurements(&self) -> Measurements {
        let n = self.n;
        let steps = self
            .steps
            .iter()
            .map(|s| {
                let mut stats = StepStats::empty(n);
                for sample in s.outputs.chunks_exact(n) {
                    stats.push(sample);
                }
                stats
            })
            .collect();
        Measurements { steps }
    }

    fn column_names(&self) -> Vec<String> {
        let mut names: Vec<String> = FIXED.iter().map(|s| s.to_string()).collect();
        if self.has_temperature() {
            names.push("temp_c".into());
        }
        names.extend((1..=self.n).map(|j| format!("s{j}")));
        names
    }

    /// The rows as columns of f64 (the step column as i64 values in f64).
    fn columns(&self) -> Vec<Vec<f64>> {
        let names = self.column_names();
        let mut data = vec![Vec::new(); names.len()];
        for s in &self.steps {
            for i in 0..s.samples() {
                let mut row = vec![s.step as f64, s.t_s[i], s.up_b.x, s.up_b.y, s.up_b.z];
                row.extend(s.omega_b_rad_s.iter());
                if self.has_temperature() {
                    row.push(s.temp_c[i]);
                }
                row.extend_from_slice(&s.outputs[i * self.n..(i + 1) * self.n]);
                for (d, v) in data.iter_mut().zip(row) {
                    d.push(v);
                }
            }
        }
        data
    }

    /// Writes the log as Parquet (`.parquet`) or CSV, atomically.
    pub fn write(&self, path: &Path) -> Result<(), LogError> {
        let names = self.column_names();
        let data = self.columns();
        if path.extension().is_some_and(|e| e == "parquet") {
            let fields: Vec<Field> = names
                .iter()
                .map(|n| Field::new(n, if n == "step" { DataType::Int64 } else { DataType::Float64 }, false))
                .collect();
            let arrays: Vec<ArrayRef> = names
                .iter()
                .zip(&data)
                .map(|(n, d)| -> ArrayRef {
                    if n == "step" {
                        Arc::new(Int64Array::from(d.iter().map(|v| *v as i64).collect::<Vec<_>>()))
                    } else {
                        Arc::new(Float64Array::from(d.clone()))
                    }
                })
                .collect();
            let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), arrays)
                .map_err(|e| LogError::Format { path: path.to_path_buf(), problem: e.to_string() })?;
            crate::io::parquet::write_part(path, &batch, &[("gfcal:version".into(), env!("CARGO_PKG_VERSION").into())])
                .map_err(|e| LogError::Write {
                    path: path.to_path_buf(),
                    problem: match e {
                        crate::io::parquet::ParquetIoError::Io { source, .. } => source.to_string(),
                        other => other.to_string(),
                    },
                })
        } else {
            let mut text = names.join(",") + "\n";
            let rows = data.first().map(|d| d.len()).unwrap_or(0);
            for i in 0..rows {
                let row: Vec<String> = data
                    .iter()
                    .enumerate()
                    .map(|(k, d)| if k == 0 { format!("{}", d[i] as i64) } else { format!("{}", d[i]) })
                    .collect();
                text.push_str(&row.join(","));
                text.push('\n');
            }
            crate::io::write_atomic(path, text.as_bytes())
                .map_err(|source| LogError::Write { path: path.to_path_buf(), problem: source.to_string() })
        }
    }
}
