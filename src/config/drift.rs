//! The config of `gfcal drift`: an array, one error set, a trajectory and navigation settings.

use std::path::Path;

use serde::Deserialize;

use super::array::ArraySection;
use super::error_set::{ErrorSet, ErrorsSection};
use super::noise::NoiseSection;
use super::trajectory::{NavigationSection, NavigationSettings, TrajectorySection};
use super::{ConfigError, read_toml};
use crate::array::Array;
use crate::nav::trajectory::Trajectory;
use crate::sensor::noise::NoiseSpec;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriftFile {
    #[serde(default)]
    pub array: ArraySection,
    #[serde(default)]
    pub errors: ErrorsSection,
    #[serde(default)]
    pub noise: NoiseSection,
    pub trajectory: TrajectorySection,
    pub navigation: NavigationSection,
}

/// A checked drift config, in SI.
#[derive(Debug, Clone)]
pub struct DriftConfig {
    pub array: Array,
    pub errors: ErrorSet,
    pub noise: NoiseSpec,
    pub noise_seed: u64,
    pub trajectory: Trajectory,
    pub navigation: NavigationSettings,
    pub text: String,
}

impl DriftConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let (file, text): (DriftFile, _) = read_toml(path)?;
        let array = file.array.build(path)?;
        let errors = file.errors.resolve(&array).map_err(|b| b.in_file(path))?;
        let (noise, noise_seed) = file.noise.resolve().map_err(|b| b.in_file(path))?;
        let navigation = file.navigation.resolve().map_err(|b| b.in_file(path))?;
        let last_s = navigation.horizons_s.last().copied().unwrap_or(0.0);
        let trajectory = file.trajectory.build(last_s).map_err(|b| b.in_file(path))?;
        Ok(Self { array, errors, noise, noise_seed, trajectory, navigation, text })
    }
}
