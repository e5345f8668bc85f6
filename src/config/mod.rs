//! Configs (TOML) read at the edge: every key carries its unit (`bias_mg`, `location_error_mm`),
//! values are checked and converted to SI once, here. Unknown keys are refused.

pub mod array;
pub mod calibration;
pub mod drift;
pub mod error_set;
pub mod noise;
pub mod schedule;
pub mod simulate_log;
pub mod trajectory;

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

/// A config that cannot be used; always names the file, and the key where there is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    #[error("{}: cannot read: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{}: {message}", path.display())]
    Parse { path: PathBuf, message: String },
    #[error("{}: key `{key}`: {problem}", path.display())]
    Invalid { path: PathBuf, key: String, problem: String },
}

/// A problem with one key, before the file is known.
#[derive(Debug, Clone, PartialEq)]
pub struct Bad {
    pub key: String,
    pub problem: String,
}

impl Bad {
    pub fn new(key: impl Into<String>, problem: impl Into<String>) -> Self {
        Self { key: key.into(), problem: problem.into() }
    }
    pub fn in_file(self, path: &Path) -> ConfigError {
        ConfigError::Invalid { path: path.to_path_buf(), key: self.key, problem: self.problem }
    }
}

/// Reads and parses a TOML file; returns the value and the file's text (for provenance).
pub fn read_toml<T: DeserializeOwned>(path: &Path) -> Result<(T, String), ConfigError> {
    let text =
        std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
    let value =
        toml::from_str(&text).map_err(|e| ConfigError::Parse { path: path.to_path_buf(), message: e.to_string() })?;
    Ok((value, text))
}

pub(crate) fn finite(key: &str, v: f64) -> Result<f64, Bad> {
    if v.is_finite() { Ok(v) } else { Err(Bad::new(key, format!("must be a finite number, got {v}"))) }
}

pub(crate) fn positive(key: &str, v: f64) -> Result<f64, Bad> {
    if finite(key, v)? > 0.0 { Ok(v) } else { Err(Bad::new(key, format!("must be positive, got {v}"))) }
}

pub(crate) fn vec3(key: &str, v: [f64; 3]) -> Result<nalgebra::Vector3<f64>, Bad> {
    for (k, x) in v.iter().enumerate() {
        finite(&format!("{key}[{k}]"), *x)?;
    }
    Ok(nalgebra::Vector3::from(v))
}

/// One value for every accelerometer, or one value each.
#[derive(Debug, Clone, PartialEq)]
pub enum OneOrEach<T> {
    One(T),
    Each(Vec<T>),
}

impl<'de, T: DeserializeOwned> serde::Deserialize<'de> for OneOrEach<T> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        // A single value is tried first: a single [x, y, z] is one value, not a list of three.
        let value = toml::Value::deserialize(d)?;
        if let Ok(one) = value.clone().try_into::<T>() {
            return Ok(OneOrEach::One(one));
        }
        value.try_into::<Vec<T>>().map(OneOrEach::Each).map_err(|e| {
            serde::de::Error::custom(format!(
                "expected one value for every accelerometer or a list with one value each ({})",
                e.to_string().trim()
            ))
        })
    }
}

impl<T: Clone> OneOrEach<T> {
    /// Expands to `n` values; a list must have exactly `n`.
    pub fn expand(&self, key: &str, n: usize) -> Result<Vec<T>, Bad> {
        match self {
            OneOrEach::One(v) => Ok(vec![v.clone(); n]),
            OneOrEach::Each(vs) if vs.len() == n => Ok(vs.clone()),
            OneOrEach::Each(vs) => {
                Err(Bad::new(key, format!("needs one value per accelerometer ({n}), got {}", vs.len())))
            }
        }
    }
}
