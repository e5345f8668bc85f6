//! The array file's wiring: which column of a recording holds each accelerometer's output, its
//! range, the reference gyroscopes, the packages (chips) the sensors sit in with their sample
//! clocks, and which column holds the time. Read from the array file by `config::array`; used by
//! every reader of a recording (self-calibration, the diagnosis, injection, the protocol's
//! simulator).
//!
//! **Packages and clocks.** A package is one chip holding several axes (an IMU's accelerometer
//! triad and gyroscope). Its axes are sampled together, at the instants of the package's own
//! clock. A package that declares `sample_clock_hz` refreshes its output registers at that
//! nominal rate on a free-running clock; with `sample_and_hold` the host reads the latest refresh
//! at each of its own sample times, so every sample is between 0 and one clock period old, and
//! the age drifts from sample to sample as the two clocks beat (`selfcal::clock`).

use std::path::PathBuf;

use nalgebra::Vector3;

use super::Array;

/// The time column of a recording when the array file names none.
pub const DEFAULT_TIME_COLUMN: &str = "t_s";

/// A reference gyroscope axis (array frame, unit), the column it is read from, its range, and
/// the package it sits in (index into [`RecordingArray::packages`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceGyro {
    pub axis: Vector3<f64>,
    pub column: String,
    pub range_rad_s: f64,
    pub package: Option<usize>,
}

/// One package (chip) of the array and how its samples are timed.
#[derive(Debug, Clone, PartialEq)]
pub struct Package {
    pub name: String,
    /// The nominal rate of the package's internal sample clock, Hz (`None`: the package is
    /// sampled at the host's instants, as every package was before clocks were modelled).
    pub sample_clock_hz: Option<f64>,
    /// The host reads the latest internal sample (its age is 0 to one clock period) rather than
    /// one synchronised to the host's sample instant.
    pub sample_and_hold: bool,
    /// Time constant of a first-order anti-alias filter before the package's accelerometers'
    /// internal sampling, s (0: none declared). Its second-order term is modelled in a
    /// calibration (`selfcal::filter`).
    pub anti_alias_time_constant_s: f64,
}

impl Package {
    /// Whether the package's samples are the latest of a free-running internal clock: the
    /// effect `selfcal::clock` models.
    pub fn free_running(&self) -> bool {
        self.sample_clock_hz.is_some() && self.sample_and_hold
    }
}

/// An array with what a recording needs: the column of every accelerometer, its range, and the
/// reference gyroscopes.
#[derive(Debug, Clone)]
pub struct RecordingArray {
    pub array: Array,
    pub accelerometer_columns: Vec<String>,
    /// Outputs with `|s| >= range` are clipped (infinite: never).
    pub ranges_m_s2: Vec<f64>,
    pub gyroscopes: Vec<ReferenceGyro>,
    /// The packages the array file declares or names, in the order they first appear.
    pub packages: Vec<Package>,
    /// The package of every accelerometer (`None` where the file names none).
    pub package_of: Vec<Option<usize>>,
    /// The column holding the time of each sample, in seconds (the array file's `time_column`).
    pub time_column: String,
    /// How long the accelerometers lag the reference gyroscopes, s (the array file's
    /// `accelerometer_lag_ms`; 0 by default).
    pub accelerometer_lag_s: f64,
    /// The array file, for messages.
    pub path: PathBuf,
}

impl RecordingArray {
    /// An array with the default columns `s1..sN` and `t_s`, no range (never clipped) and no
    /// gyroscopes; `path` names it in messages.
    pub fn plain(array: Array, path: &std::path::Path) -> Self {
        let n = array.len();
        Self {
            array,
            accelerometer_columns: (1..=n).map(|j| format!("s{j}")).collect(),
            ranges_m_s2: vec![f64::INFINITY; n],
            gyroscopes: Vec::new(),
            packages: Vec::new(),
            package_of: vec![None; n],
            time_column: DEFAULT_TIME_COLUMN.to_string(),
            accelerometer_lag_s: 0.0,
            path: path.to_path_buf(),
        }
    }

    /// Each accelerometer's package index (0 where it names none), as the timing model takes it.
    pub fn package_indices(&self) -> Vec<usize> {
        self.package_of.iter().map(|p| p.unwrap_or(0)).collect()
    }

    /// Whether any package declares a free-running sample clock read by sample-and-hold.
    pub fn has_sample_clocks(&self) -> bool {
        self.packages.iter().any(Package::free_running)
    }

    /// The packages as groups of accelerometers: the declared packages where every accelerometer
    /// names one, otherwise accelerometers that share a nominal position (the axes of one chip).
    pub fn accelerometer_groups(&self) -> Vec<Vec<usize>> {
        if !self.packages.is_empty() && self.package_of.iter().all(Option::is_some) {
            let mut groups = vec![Vec::new(); self.packages.len()];
            for (j, p) in self.package_of.iter().enumerate() {
                if let Some(p) = p {
                    groups[*p].push(j);
                }
            }
            return groups.into_iter().filter(|g| !g.is_empty()).collect();
        }
        let acc = self.array.accelerometers();
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for (j, a) in acc.iter().enumerate() {
            match groups.iter().position(|g| (acc[g[0]].position_m - a.position_m).norm() < 1e-9) {
                Some(m) => groups[m].push(j),
                None => groups.push(vec![j]),
            }
        }
        groups
    }
}
