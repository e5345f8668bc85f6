//! A recording of a real (or simulated) array: one row per sample, the accelerometer outputs
//! read from the columns the array file names, the time in seconds (the column the array file's
//! `time_column` names, default `t_s`), an optional `step` column (a lab's own segmentation: rows
//! of one step are one static pose; a negative step is dynamic), and the reference gyroscopes if
//! the array file lists any.

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, Vector3};

use crate::array::wiring::RecordingArray;
use crate::io::table::{Table, TableError};

/// A recording that cannot be used; names the file, the column and the row where there is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordingError {
    #[error(transparent)]
    Table(#[from] TableError),
    #[error("{}: missing column(s) {} named by the array file {}", path.display(), missing.join(", "), array.display())]
    MissingColumns { path: PathBuf, array: PathBuf, missing: Vec<String> },
    #[error(
        "{}: no time column `{column}`: a recording needs the time of every sample, in seconds, in the column the \
         array file {}'s `time_column` names (default `t_s`); the table's columns: {}",
        path.display(),
        array.display(),
        columns.join(", ")
    )]
    MissingTime { path: PathBuf, array: PathBuf, column: String, columns: Vec<String> },
    #[error("{}: data row {row}, column `{column}`: {problem}", path.display())]
    Value { path: PathBuf, row: usize, column: String, problem: String },
    #[error("{}: {problem}", path.display())]
    Unusable { path: PathBuf, problem: String },
}

/// The samples of a recording.
#[derive(Debug, Clone)]
pub struct Recording {
    pub path: PathBuf,
    pub t_s: Vec<f64>,
    /// Samples x accelerometers, output units (m/s^2 for a scaled board).
    pub outputs: DMatrix<f64>,
    /// Samples x accelerometers: the output is at or beyond its range.
    pub clipped: Vec<bool>,
    /// The `step` column, if the table has one.
    pub step: Option<Vec<i64>>,
    /// Reference angular rate in array axes (least squares over the gyroscope axes), rad/s, and
    /// whether any gyroscope axis clipped at that sample. Empty without reference gyroscopes.
    pub gyro_rate_rad_s: Vec<Vector3<f64>>,
    pub gyro_clipped: Vec<bool>,
    /// Per package (index into the array's packages), its own gyroscope's rate in array axes
    /// (least squares over the package's gyroscope axes), rad/s; empty for a package whose axes do
    /// not span three dimensions, and empty altogether unless every gyroscope names its package.
    pub package_gyro_rate_rad_s: Vec<Vec<Vector3<f64>>>,
    /// How long the accelerometers lag the gyroscopes, s (the array file's
    /// `accelerometer_lag_ms`): `--use-gyro` takes the rate at the accelerometers' instants
    /// (`selfcal::lag`).
    pub accelerometer_lag_s: f64,
}

/// A column's values at one magnitude this close below its stated range, held at least
/// [`RAIL_REPEATS`] times, are a rail the array file does not know.
pub const RAIL_BELOW_RANGE: f64 = 0.01;

/// How many values at exactly the column's largest magnitude make a rail: a measured signal
/// quantised to its output's counts repeats its extreme a few times at a slow peak, a rail
/// hundreds of times (the MIMU4444's gyroscopes: 3,228-4,704 per recording).
pub const RAIL_REPEATS: usize = 10;

/// Refuses a column whose largest magnitude sits just below `range` ([`RAIL_BELOW_RANGE`]) and is
/// held by at least [`RAIL_REPEATS`] values: the part clips there (an int16 output rails at
/// 32767 counts, a little below the data sheet's round range), and with the array file's range
/// those outputs would be read as measured, not as clipped.
fn check_rail(
    path: &Path,
    column: &str,
    col: &[f64],
    range: f64,
    unit: &str,
    key: &str,
    array: &Path,
) -> Result<(), RecordingError> {
    if !range.is_finite() {
        return Ok(());
    }
    let largest = col.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if largest >= range || largest < range * (1.0 - RAIL_BELOW_RANGE) {
        return Ok(());
    }
    let held = col.iter().filter(|v| v.abs() == largest).count();
    if held < RAIL_REPEATS {
        return Ok(());
    }
    let row = col.iter().position(|v| v.abs() == largest).map_or(1, |i| i + 1);
    Err(RecordingError::Value {
        path: path.to_path_buf(),
        row,
        column: column.into(),
        problem: format!(
            "{held} values sit at {largest} {unit}, just below the range {range} {unit} of the array file {}: the part clips there (a rail the array file does not know), so they would be read as measured; set `{key}` to at most {largest}",
            array.display()
        ),
    })
}

impl Recording {
    pub fn samples(&self) -> usize {
        self.t_s.len()
    }
    pub fn accelerometers(&self) -> usize {
        self.outputs.ncols()
    }
    pub fn is_clipped(&self, i: usize, j: usize) -> bool {
        self.clipped[i * self.accelerometers() + j]
    }

    /// Reads and checks a recording for `array`.
    pub fn read(path: &Path, array: &RecordingArray) -> Result<Self, RecordingError> {
        let table = Table::read(path)?;
        Self::from_table(&table, array)
    }

    /// Checks a table against `array`: every named column present, no NaN or null, time strictly
    /// increasing, not everything clipped.
    pub fn from_table(table: &Table, array: &RecordingArray) -> Result<Self, RecordingError> {
        let path = table.path.clone();
        let time = array.time_column.as_str();
        if table.index(time).is_none() {
            // The first few columns, enough to show what the table holds.
            const SHOWN: usize = 12;
            let mut columns: Vec<String> = table.names.iter().take(SHOWN).map(|c| format!("`{c}`")).collect();
            if table.names.len() > SHOWN {
                columns.push(format!("and {} more", table.names.len() - SHOWN));
            }
            return Err(RecordingError::MissingTime {
                path,
                array: array.path.clone(),
                column: time.to_string(),
                columns,
            });
        }
        let mut missing = Vec::new();
        let needed =
            array.accelerometer_columns.iter().cloned().chain(array.gyroscopes.iter().map(|g| g.column.clone()));
        for c in needed {
            if table.index(&c).is_none() {
                missing.push(format!("`{c}`"));
            }
        }
        if !missing.is_empty() {
            return Err(RecordingError::MissingColumns { path, array: array.path.clone(), missing });
        }
        let rows = table.rows();
        if rows < 2 {
            return Err(RecordingError::Unusable { path, problem: format!("the table has {rows} row(s)") });
        }
        let finite_column = |name: &str| -> Result<&[f64], RecordingError> {
            let k = table.index(name).unwrap_or(0);
            let col = &table.data[k];
            if let Some(row) = table.first_null_row[k] {
                return Err(RecordingError::Value {
                    path: path.clone(),
                    row,
                    column: name.into(),
                    problem: "missing value (null)".into(),
                });
            }
            if let Some(i) = col.iter().position(|v| !v.is_finite()) {
                return Err(RecordingError::Value {
                    path: path.clone(),
                    row: i + 1,
                    column: name.into(),
                    problem: format!("{} is not a finite number", col[i]),
                });
            }
            Ok(col)
        };
        let t_s = finite_column(time)?.to_vec();
        if let Some(i) = t_s.windows(2).position(|w| w[1] <= w[0]) {
            return Err(RecordingError::Value {
                path,
                row: i + 2,
                column: time.into(),
                problem: format!("time does not increase ({} s after {} s)", t_s[i + 1], t_s[i]),
            });
        }
        let n = array.accelerometer_columns.len();
        let mut outputs = DMatrix::zeros(rows, n);
        let mut clipped = vec![false; rows * n];
        for (j, name) in array.accelerometer_columns.iter().enumerate() {
            let col = finite_column(name)?;
            check_rail(&path, name, col, array.ranges_m_s2[j], "m/s^2", "range_m_s2", &array.path)?;
            for (i, &v) in col.iter().enumerate() {
                outputs[(i, j)] = v;
                clipped[i * n + j] = v.abs() >= array.ranges_m_s2[j];
            }
        }
        if clipped.iter().all(|&c| c) {
            return Err(RecordingError::Unusable {
                path,
                problem: "every accelerometer output is at or beyond its range (all clipped)".into(),
            });
        }
        for (j, name) in array.accelerometer_columns.iter().enumerate() {
            if (0..rows).all(|i| clipped[i * n + j]) {
                return Err(RecordingError::Value {
                    path,
                    row: 1,
                    column: name.clone(),
                    problem: format!("every sample is at or beyond the range {} m/s^2 (clipped)", array.ranges_m_s2[j]),
                });
            }
        }
        let step = match table.index("step") {
            None => None,
            Some(_) => {
                let col = finite_column("step")?;
                if let Some(i) = col.iter().position(|v| v.fract() != 0.0) {
                    return Err(RecordingError::Value {
                        path,
                        row: i + 1,
                        column: "step".into(),
                        problem: format!("{} is not a whole number", col[i]),
                    });
                }
                Some(col.iter().map(|&v| v as i64).collect())
            }
        };
        let (gyro_rate_rad_s, gyro_clipped) = if array.gyroscopes.is_empty() {
            (Vec::new(), Vec::new())
        } else {
            let cols: Vec<&[f64]> =
                array.gyroscopes.iter().map(|g| finite_column(&g.column)).collect::<Result<_, _>>()?;
            for (g, col) in array.gyroscopes.iter().zip(&cols) {
                check_rail(&path, &g.column, col, g.range_rad_s, "rad/s", "range_rad_s", &array.path)?;
            }
            let normal: nalgebra::Matrix3<f64> = array.gyroscopes.iter().map(|g| g.axis * g.axis.transpose()).sum();
            let inv = normal.try_inverse().unwrap_or_else(nalgebra::Matrix3::zeros);
            let mut rate = Vec::with_capacity(rows);
            let mut clip = Vec::with_capacity(rows);
            for i in 0..rows {
                let mut b = Vector3::zeros();
                let mut c = false;
                for (g, col) in array.gyroscopes.iter().zip(&cols) {
                    b += g.axis * col[i];
                    c |= col[i].abs() >= g.range_rad_s;
                }
                rate.push(inv * b);
                clip.push(c);
            }
            (rate, clip)
        };
        let mut package_gyro_rate_rad_s = Vec::new();
        if !array.gyroscopes.is_empty() && array.gyroscopes.iter().all(|g| g.package.is_some()) {
            for p in 0..array.packages.len() {
                let own: Vec<usize> =
                    (0..array.gyroscopes.len()).filter(|&i| array.gyroscopes[i].package == Some(p)).collect();
                let normal: nalgebra::Matrix3<f64> =
                    own.iter().map(|&i| array.gyroscopes[i].axis * array.gyroscopes[i].axis.transpose()).sum();
                let rates = match normal.try_inverse().filter(|_| normal.symmetric_eigenvalues().min() > 1e-6) {
                    Some(inv) => {
                        let cols: Vec<&[f64]> = own
                            .iter()
                            .map(|&i| finite_column(&array.gyroscopes[i].column))
                            .collect::<Result<_, _>>()?;
                        (0..rows)
                            .map(|r| {
                                inv * own
                                    .iter()
                                    .zip(&cols)
                                    .map(|(&i, c)| array.gyroscopes[i].axis * c[r])
                                    .sum::<Vector3<f64>>()
                            })
                            .collect()
                    }
                    None => Vec::new(),
                };
                package_gyro_rate_rad_s.push(rates);
            }
        }
        Ok(Self {
            path,
            t_s,
            outputs,
            clipped,
            step,
            gyro_rate_rad_s,
            gyro_clipped,
            package_gyro_rate_rad_s,
            accelerometer_lag_s: array.accelerometer_lag_s,
        })
    }

    /// Checks that a second recording is of the same array (for held-out prediction).
    pub fn same_array_as(&self, other: &Recording) -> Result<(), RecordingError> {
        if self.accelerometers() != other.accelerometers() {
            return Err(RecordingError::Unusable {
                path: other.path.clone(),
                problem: format!(
                    "has {} accelerometers but {} has {}: not the same array",
                    other.accelerometers(),
                    self.path.display(),
                    self.accelerometers()
                ),
            });
        }
        Ok(())
    }
}
