//! The `[array]` section and array files.
//!
//! ```toml
//! [array]
//! preset = "cube"     # Hung & Lee (2006) Table 1; the default
//! rho_m = 0.1
//! # or: file = "nine.toml" (relative to the config's folder)
//! ```
//!
//! An array file lists accelerometers (positions in m, axes normalised on reading) and, optionally,
//! triads (1-based) for the paper's misalignment form:
//!
//! ```toml
//! name = "nine"
//! triads = [[1, 4, 6], [2, 3, 5]]
//! [[accelerometer]]
//! position_m = [0.0, 0.0, -0.1]
//! axis = [1.0, 1.0, 0.0]
//! ```
//!
//! For calibrating a recording (`gfcal calibrate`), the file may name the recording's time column
//! (`time_column`, in seconds; default `t_s`), an accelerometer may also name the table column it
//! is read from (default `s1..sN`) and its range (`range_m_s2`: outputs at or beyond it are
//! clipped and left out), and the file may list reference gyroscopes used only to check the
//! result (or, with `--use-gyro`, to supply the angular rate):
//!
//! ```toml
//! time_column = "time_s"
//! [[accelerometer]]
//! position_m = [-0.00945, 0.00945, 0.001]
//! axis = [1.0, 0.0, 0.0]
//! column = "acc1_x_m_s2"
//! range_m_s2 = 156.9
//! [[gyroscope]]
//! axis = [1.0, 0.0, 0.0]
//! column = "gyro1_x_rad_s"
//! range_rad_s = 34.87
//! ```
//!
//! Each accelerometer and gyroscope may name the package (chip) it sits in, and a package may
//! declare its internal sample clock and that the host reads its latest sample (sample-and-hold)
//! rather than one synchronised to the host's sample instant (`array::wiring`):
//!
//! ```toml
//! [[package]]
//! name = "imu1"
//! sample_clock_hz = 1000.0
//! sample_and_hold = true
//! anti_alias_time_constant_ms = 2.0   # optional: a first-order filter before its accelerometers
//! [[accelerometer]]
//! package = "imu1"
//! # ...
//! ```
//!
//! Without `[[package]]` entries, the names the accelerometers give make packages without a
//! clock. With them, every name must be declared.
//!
//! `accelerometer_lag_ms` (top level, default 0) says how long the accelerometers lag the reference
//! gyroscopes (their outputs are the motion that much earlier; their filters' delays differ):
//! `--use-gyro` then takes the rate at the accelerometers' instants (`selfcal::lag`).

use std::path::Path;

use serde::Deserialize;

use super::{Bad, ConfigError, positive, read_toml};
use crate::array::wiring::{DEFAULT_TIME_COLUMN, Package, RecordingArray, ReferenceGyro};
use crate::array::{Array, ArrayError};

/// The largest anti-alias time constant an array file may declare, ms: the filter's term is
/// modelled to second order in it (`selfcal::filter`), which longer filters would break.
pub const MAX_ANTI_ALIAS_MS: f64 = 10.0;

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArraySection {
    pub preset: Option<String>,
    pub rho_m: Option<f64>,
    pub file: Option<std::path::PathBuf>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrayFile {
    pub name: Option<String>,
    /// Recordings: the column holding the time, s (default `t_s`).
    pub time_column: Option<String>,
    #[serde(default)]
    pub triads: Vec<[usize; 3]>,
    #[serde(default)]
    pub accelerometer: Vec<AccelerometerEntry>,
    #[serde(default)]
    pub gyroscope: Vec<GyroscopeEntry>,
    #[serde(default)]
    pub package: Vec<PackageEntry>,
    /// How long every accelerometer lags the reference gyroscopes (its output is the motion that much
    /// earlier), ms (default 0):
    /// `--use-gyro` takes the rate at the accelerometers' instants (`selfcal::lag`).
    pub accelerometer_lag_ms: Option<f64>,
}

/// A package (chip) and its sample clock.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PackageEntry {
    pub name: String,
    /// Nominal rate of the package's internal sample clock, Hz.
    pub sample_clock_hz: Option<f64>,
    /// The host reads the latest internal sample (default false: synchronised).
    #[serde(default)]
    pub sample_and_hold: bool,
    /// Time constant of a first-order anti-alias filter before the package's accelerometers'
    /// sampling, ms (default: none).
    pub anti_alias_time_constant_ms: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelerometerEntry {
    pub position_m: [f64; 3],
    pub axis: [f64; 3],
    /// Table column of a recording (default `s{j}`).
    pub column: Option<String>,
    /// Measurement range, m/s^2 (outputs at or beyond it are clipped).
    pub range_m_s2: Option<f64>,
    /// The package (chip) it sits in.
    pub package: Option<String>,
}

/// A reference gyroscope axis of a recording.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroscopeEntry {
    pub axis: [f64; 3],
    pub column: String,
    /// Measurement range, rad/s (readings at or beyond it are clipped).
    pub range_rad_s: Option<f64>,
    /// The package (chip) it sits in.
    pub package: Option<String>,
}

impl ArraySection {
    /// Builds the array; `config_path` names the config in errors and anchors relative files.
    pub fn build(&self, config_path: &Path) -> Result<Array, ConfigError> {
        match (&self.preset, &self.file) {
            (Some(_), Some(_)) => {
                Err(Bad::new("array", "give either `preset` or `file`, not both").in_file(config_path))
            }
            (_, Some(file)) => {
                if self.rho_m.is_some() {
                    return Err(Bad::new("array.rho_m", "applies to presets only; an array file gives positions")
                        .in_file(config_path));
                }
                let path = config_path.parent().unwrap_or(Path::new(".")).join(file);
                load_array_file(&path)
            }
            (preset, None) => {
                let preset = preset.as_deref().unwrap_or("cube");
                if preset != "cube" {
                    return Err(Bad::new("array.preset", format!("unknown preset `{preset}` (known: cube)"))
                        .in_file(config_path));
                }
                let rho_m = positive("array.rho_m", self.rho_m.unwrap_or(0.1)).map_err(|b| b.in_file(config_path))?;
                Array::cube(rho_m).map_err(|e| Bad::new("array", e.to_string()).in_file(config_path))
            }
        }
    }
}

/// Reads an array file (see the module docs).
pub fn load_array_file(path: &Path) -> Result<Array, ConfigError> {
    let (file, _): (ArrayFile, _) = read_toml(path)?;
    build_array(path, &file)
}

/// Reads an array file with the columns, ranges and reference gyroscopes of a recording.
pub fn load_recording_array(path: &Path) -> Result<RecordingArray, ConfigError> {
    let (file, _): (ArrayFile, _) = read_toml(path)?;
    let array = build_array(path, &file)?;
    let mut accelerometer_columns = Vec::new();
    let mut ranges_m_s2 = Vec::new();
    for (j, a) in file.accelerometer.iter().enumerate() {
        accelerometer_columns.push(a.column.clone().unwrap_or_else(|| format!("s{}", j + 1)));
        let range = match a.range_m_s2 {
            Some(r) => positive(&format!("accelerometer[{j}].range_m_s2"), r).map_err(|b| b.in_file(path))?,
            None => f64::INFINITY,
        };
        ranges_m_s2.push(range);
    }
    let (packages, package_of, gyro_packages) = packages(path, &file)?;
    let mut gyroscopes = Vec::new();
    for (i, g) in file.gyroscope.iter().enumerate() {
        let axis = super::vec3(&format!("gyroscope[{i}].axis"), g.axis).map_err(|b| b.in_file(path))?;
        if axis.norm() < 1e-12 {
            return Err(Bad::new(format!("gyroscope[{i}].axis"), "has zero length").in_file(path));
        }
        let range_rad_s = match g.range_rad_s {
            Some(r) => positive(&format!("gyroscope[{i}].range_rad_s"), r).map_err(|b| b.in_file(path))?,
            None => f64::INFINITY,
        };
        gyroscopes.push(ReferenceGyro {
            axis: axis.normalize(),
            column: g.column.clone(),
            range_rad_s,
            package: gyro_packages[i],
        });
    }
    if !gyroscopes.is_empty() {
        let m: nalgebra::Matrix3<f64> = gyroscopes.iter().map(|g| g.axis * g.axis.transpose()).sum();
        if m.symmetric_eigenvalues().min() < 1e-6 {
            return Err(
                Bad::new("gyroscope", "the reference gyroscopes' axes do not span three dimensions").in_file(path)
            );
        }
    }
    let time_column = match &file.time_column {
        None => DEFAULT_TIME_COLUMN.to_string(),
        Some(c) if c.trim().is_empty() => {
            return Err(Bad::new("time_column", "is empty: name the recording's time column (seconds)").in_file(path));
        }
        Some(c) => c.clone(),
    };
    let mut seen = std::collections::HashSet::new();
    for c in accelerometer_columns.iter().chain(gyroscopes.iter().map(|g| &g.column)) {
        if !seen.insert(c.clone()) {
            return Err(Bad::new("accelerometer", format!("column `{c}` is named twice")).in_file(path));
        }
    }
    if seen.contains(&time_column) {
        return Err(Bad::new(
            "time_column",
            format!("`{time_column}` is also a sensor's column: the time needs a column of its own"),
        )
        .in_file(path));
    }
    let accelerometer_lag_s = match file.accelerometer_lag_ms {
        None => 0.0,
        Some(_) if gyroscopes.is_empty() => {
            return Err(Bad::new(
                "accelerometer_lag_ms",
                "needs [[gyroscope]] entries (the lag is the accelerometers' behind the gyroscopes)",
            )
            .in_file(path));
        }
        Some(ms) if !ms.is_finite() || ms.abs() > MAX_ACCELEROMETER_LAG_MS => {
            return Err(Bad::new(
                "accelerometer_lag_ms",
                format!("must be a number of milliseconds within +-{MAX_ACCELEROMETER_LAG_MS}, got {ms}"),
            )
            .in_file(path));
        }
        Some(ms) => ms * 1e-3,
    };
    Ok(RecordingArray {
        array,
        accelerometer_columns,
        ranges_m_s2,
        gyroscopes,
        packages,
        package_of,
        time_column,
        accelerometer_lag_s,
        path: path.to_path_buf(),
    })
}

/// The largest `accelerometer_lag_ms` an array file may declare (a lag of the order of a sensor's
/// filter delay, not of its sample period's multiples).
const MAX_ACCELEROMETER_LAG_MS: f64 = 100.0;

/// The packages of an array file: those `[[package]]` declares, or else those the sensors name
/// (in the order they first appear), with the package of every accelerometer and gyroscope.
#[allow(clippy::type_complexity)]
fn packages(
    path: &Path,
    file: &ArrayFile,
) -> Result<(Vec<Package>, Vec<Option<usize>>, Vec<Option<usize>>), ConfigError> {
    let mut packages: Vec<Package> = Vec::new();
    for (i, p) in file.package.iter().enumerate() {
        if p.name.trim().is_empty() {
            return Err(Bad::new(format!("package[{i}].name"), "is empty").in_file(path));
        }
        if packages.iter().any(|q| q.name == p.name) {
            return Err(
                Bad::new(format!("package[{i}].name"), format!("package `{}` is declared twice", p.name)).in_file(path)
            );
        }
        let sample_clock_hz = match p.sample_clock_hz {
            Some(f) => Some(positive(&format!("package[{i}].sample_clock_hz"), f).map_err(|b| b.in_file(path))?),
            None => None,
        };
        if p.sample_and_hold && sample_clock_hz.is_none() {
            return Err(Bad::new(
                format!("package[{i}].sample_and_hold"),
                "needs the package's `sample_clock_hz` (the latest sample of which clock?)",
            )
            .in_file(path));
        }
        let anti_alias_time_constant_s = match p.anti_alias_time_constant_ms {
            Some(ms) if ms.is_finite() && (0.0..=MAX_ANTI_ALIAS_MS).contains(&ms) => ms * 1e-3,
            Some(ms) => {
                return Err(Bad::new(
                    format!("package[{i}].anti_alias_time_constant_ms"),
                    format!("{ms} is not a time constant from 0 to {MAX_ANTI_ALIAS_MS} ms"),
                )
                .in_file(path));
            }
            None => 0.0,
        };
        packages.push(Package {
            name: p.name.clone(),
            sample_clock_hz,
            sample_and_hold: p.sample_and_hold,
            anti_alias_time_constant_s,
        });
    }
    let declared = !packages.is_empty();
    let mut find = |key: String, name: &Option<String>, what: String| -> Result<Option<usize>, ConfigError> {
        let Some(name) = name else { return Ok(None) };
        if let Some(i) = packages.iter().position(|p| &p.name == name) {
            return Ok(Some(i));
        }
        if declared {
            let known: Vec<&str> = packages.iter().map(|p| p.name.as_str()).collect();
            return Err(Bad::new(
                key,
                format!(
                    "{what}: package `{name}` is not declared by a [[package]] entry (declared: {})",
                    known.join(", ")
                ),
            )
            .in_file(path));
        }
        packages.push(Package {
            name: name.clone(),
            sample_clock_hz: None,
            sample_and_hold: false,
            anti_alias_time_constant_s: 0.0,
        });
        Ok(Some(packages.len() - 1))
    };
    let mut package_of = Vec::new();
    for (j, a) in file.accelerometer.iter().enumerate() {
        package_of.push(find(format!("accelerometer[{j}].package"), &a.package, format!("accelerometer {}", j + 1))?);
    }
    let mut gyro_packages = Vec::new();
    for (i, g) in file.gyroscope.iter().enumerate() {
        gyro_packages.push(find(format!("gyroscope[{i}].package"), &g.package, format!("gyroscope {}", i + 1))?);
    }
    if packages.iter().any(Package::free_running) && package_of.iter().any(Option::is_none) {
        let j = package_of.iter().position(Option::is_none).unwrap_or(0);
        return Err(Bad::new(
            format!("accelerometer[{j}].package"),
            format!("accelerometer {}: names no package, but the array's packages declare sample clocks: every accelerometer must name its package", j + 1),
        )
        .in_file(path));
    }
    Ok((packages, package_of, gyro_packages))
}

fn build_array(path: &Path, file: &ArrayFile) -> Result<Array, ConfigError> {
    let mut positions = Vec::new();
    let mut axes = Vec::new();
    for (j, a) in file.accelerometer.iter().enumerate() {
        positions
            .push(super::vec3(&format!("accelerometer[{j}].position_m"), a.position_m).map_err(|b| b.in_file(path))?);
        axes.push(super::vec3(&format!("accelerometer[{j}].axis"), a.axis).map_err(|b| b.in_file(path))?);
    }
    let mut triads = Vec::new();
    for (t, tr) in file.triads.iter().enumerate() {
        if tr.contains(&0) {
            return Err(Bad::new(format!("triads[{t}]"), "accelerometers are numbered from 1").in_file(path));
        }
        triads.push([tr[0] - 1, tr[1] - 1, tr[2] - 1]);
    }
    let name = file
        .name
        .clone()
        .unwrap_or_else(|| path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default());
    Array::new(name, &positions, &axes, triads).map_err(|e| {
        let key = match &e {
            ArrayError::ZeroAxis { index } => format!("accelerometer[{}].axis", index - 1),
            ArrayError::NonFinite { index, what } => {
                format!("accelerometer[{}].{}", index - 1, if *what == "position" { "position_m" } else { "axis" })
            }
            ArrayError::BadTriad { triad, .. } => format!("triads[{}]", triad - 1),
            _ => "accelerometer".to_string(),
        };
        Bad::new(key, e.to_string()).in_file(path)
    })
}
