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

use std::path::Path;

use serde::Deserialize;

use super::{Bad, ConfigError, positive, read_toml};
use crate::array::{Array, ArrayError};

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
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelerometerEntry {
    pub position_m: [f64; 3],
    pub axis: [f64; 3],
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
