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
//! For calibrating a recording (`gfcal calibrate`), an accelerometer may also name the table
//! column it is read from (default `s1..sN`) and its range (`range_m_s2`: outputs at or beyond it
//! are clipped and left out), and the file may list reference gyroscopes used only to check the
//! result (or, with `--use-gyro`, to supply the angular rate):
//!
//! ```toml
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

use std::path::Path;

use serde::Deserialize;

use super::{Bad, ConfigError, positive, read_toml};
use crate::array::{Array, ArrayError};
use crate::selfcal::recording::{RecordingArray, ReferenceGyro};

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
    #[serde(default)]
    pub triads: Vec<[usize; 3]>,
    #[serde(default)]
    pub accelerometer: Vec<AccelerometerEntry>,
    #[serde(default)]
    pub gyroscope: Vec<GyroscopeEntry>,
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
}

/// A reference gyroscope axis of a recording.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroscopeEntry {
    pub axis: [f64; 3],
    pub column: String,
    /// Measurement range, rad/s (readings at or beyond it are clipped).
    pub range_rad_s: Option<f64>,
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
        gyroscopes.push(ReferenceGyro { axis: axis.normalize(), column: g.column.clone(), range_rad_s });
    }
    if !gyroscopes.is_empty() {
        let m: nalgebra::Matrix3<f64> = gyroscopes.iter().map(|g| g.axis * g.axis.transpose()).sum();
        if m.symmetric_eigenvalues().min() < 1e-6 {
            return Err(
                Bad::new("gyroscope", "the reference gyroscopes' axes do not span three dimensions").in_file(path)
            );
        }
    }
    let mut seen = std::collections::HashSet::new();
    for c in accelerometer_columns.iter().chain(gyroscopes.iter().map(|g| &g.column)) {
        if !seen.insert(c.clone()) {
            return Err(Bad::new("accelerometer", format!("column `{c}` is named twice")).in_file(path));
        }
    }
    Ok(RecordingArray { array, accelerometer_columns, ranges_m_s2, gyroscopes, path: path.to_path_buf() })
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
