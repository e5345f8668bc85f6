//! The config of `gfcal run`: everything a sweep needs, checked cell by cell before anything runs.
//!
//! ```toml
//! name = "quickstart"             # default: the file's stem
//! seed = 1                        # master seed
//! trials_per_cell = 20000
//!
//! [array]                         # as for `drift`
//! [noise]                         # as for `drift`; white noise also sets the Cramer-Rao sigmas
//! [schedule]                      # as for `identify`
//! [calibration]                   # form, estimator, start, gravity_m_s2
//!
//! [errors]
//! nominal_scale_factor = 1.0      # one, or one per accelerometer
//! bias_mg = { dist = "normal", sigma = 1.0 }                   # mean defaults to 0
//! # mean, sigma, half_width and value: one for every accelerometer, or one per accelerometer:
//! # location_mm = { dist = "normal", sigma = [1.0, 1.0, 2.0, 1.0, 1.0, 1.0] }
//! scale_factor_ppm = { dist = "uniform", half_width = 500.0 }  # deviation from nominal
//! misalignment_deg = { dist = "normal", sigma = 0.5 }          # the two angles of the form
//! location_mm = { dist = "fixed", value = [[0.5, 0.8, 0.6], ...] }
//!
//! [trajectory]                    # as for `drift`
//! [navigation]
//! step_s = 0.01
//! horizons_s = [1, 2, 5, 10]
//! compensations = ["nominal", "estimated", "true"]
//! noise = false                   # navigate noise-free outputs (isolates calibration residuals)
//!
//! [output]
//! trials_per_part = 2048          # rows of trials per Parquet part file
//!
//! [sweep]                         # optional
//! design = "factorial"            # or "latin_hypercube" / "sobol" (with `points`)
//! points = 16
//! [[sweep.factor]]
//! key = "noise.white_density_ug_per_sqrt_hz"
//! levels = [10.0, 50.0, 200.0]    # listed levels: crossed factorially
//! [[sweep.factor]]
//! key = "errors.location_mm.sigma"
//! low = 0.1                       # continuous: sampled by the space-filling design
//! high = 2.0
//! scale = "log"                   # or "linear"
//! ```
//!
//! ```toml
//! [sensitivity]                   # optional: Sobol' indices of the varying error parameters
//! design = "saltelli"
//! base_samples = 1000             # trials per cell = base_samples x (varying parameters + 2);
//!                                 # trials_per_cell must then be left out
//! ```
//!
//! A sweep factor overrides one key of this file (any key, dotted path) for each cell; every cell
//! is then read and checked as a config of its own, so a bad level is refused before the run
//! with the factor's key and level named.

use std::path::Path;

use serde::Deserialize;

use super::design::{factorial, latin_hypercube, sobol};
use super::sample::{Dist, ErrorModel, Saltelli};
use crate::array::Array;
use crate::calib::params::{Form, Layout};
use crate::calib::schedule::Schedule;
use crate::config::array::ArraySection;
use crate::config::calibration::{CalibrationSection, CalibrationSettings};
use crate::config::noise::NoiseSection;
use crate::config::schedule::ScheduleSection;
use crate::config::trajectory::TrajectorySection;
use crate::config::{Bad, ConfigError, OneOrEach, finite, positive};
use crate::nav::Trajectory;
use crate::sensor::noise::NoiseSpec;
use crate::units::{M_PER_MM, M_S2_PER_MG, RAD_PER_DEG};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DistKind {
    Normal,
    Uniform,
    Fixed,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, bound(deserialize = "T: serde::de::DeserializeOwned"))]
pub struct DistEntry<T> {
    pub dist: DistKind,
    pub mean: Option<OneOrEach<f64>>,
    pub sigma: Option<OneOrEach<f64>>,
    pub half_width: Option<OneOrEach<f64>>,
    pub value: Option<OneOrEach<T>>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct McErrorsSection {
    pub nominal_scale_factor: Option<OneOrEach<f64>>,
    pub bias_mg: Option<DistEntry<f64>>,
    pub scale_factor_ppm: Option<DistEntry<f64>>,
    pub misalignment_deg: Option<DistEntry<[f64; 2]>>,
    pub location_mm: Option<DistEntry<[f64; 3]>>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Compensation {
    Nominal,
    Estimated,
    True,
}

impl Compensation {
    pub fn name(&self) -> &'static str {
        match self {
            Compensation::Nominal => "nominal",
            Compensation::Estimated => "estimated",
            Compensation::True => "true",
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct McNavigationSection {
    pub step_s: f64,
    pub horizons_s: Vec<f64>,
    pub compensations: Option<Vec<Compensation>>,
    pub noise: Option<bool>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSection {
    pub trials_per_part: Option<u64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DesignKind {
    #[default]
    Factorial,
    LatinHypercube,
    Sobol,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Scale {
    #[default]
    Linear,
    Log,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FactorEntry {
    pub key: String,
    pub levels: Option<Vec<toml::Value>>,
    pub low: Option<f64>,
    pub high: Option<f64>,
    pub scale: Option<Scale>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepSection {
    #[serde(default)]
    pub design: DesignKind,
    pub points: Option<usize>,
    #[serde(default)]
    pub factor: Vec<FactorEntry>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensitivityDesign {
    Saltelli,
}

/// `[sensitivity]`: sample the error parameters on a Saltelli design, for Sobol' indices.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensitivitySection {
    pub design: SensitivityDesign,
    pub base_samples: u64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct McFile {
    pub name: Option<String>,
    pub seed: u64,
    /// Required, except with a Saltelli design (which sets it).
    pub trials_per_cell: Option<u64>,
    pub sensitivity: Option<SensitivitySection>,
    #[serde(default)]
    pub array: ArraySection,
    pub errors: McErrorsSection,
    #[serde(default)]
    pub noise: NoiseSection,
    /// Either a schedule (a rate table) or a hand-held protocol (`mc::protocol`).
    pub schedule: Option<ScheduleSection>,
    pub protocol: Option<super::protocol::ProtocolSection>,
    #[serde(default)]
    pub calibration: CalibrationSection,
    pub trajectory: TrajectorySection,
    pub navigation: McNavigationSection,
    #[serde(default)]
    pub output: OutputSection,
    pub sweep: Option<SweepSection>,
}

/// A sweep factor's value in one cell.
#[derive(Debug, Clone, PartialEq)]
pub enum FactorValue {
    Number(f64),
    Text(String),
}

/// Navigation settings of a cell, SI.
#[derive(Debug, Clone)]
pub struct McNavigation {
    pub trajectory: Trajectory,
    pub step_s: f64,
    pub horizons_s: Vec<f64>,
    pub compensations: Vec<Compensation>,
    pub noise: bool,
}

/// One cell of a sweep: a complete, checked trial setup.
#[derive(Debug, Clone)]
pub struct Cell {
    pub index: usize,
    /// (factor key, value), in the sweep's factor order.
    pub factors: Vec<(String, FactorValue)>,
    pub array: Array,
    pub layout: Layout,
    pub errors: ErrorModel,
    pub noise: NoiseSpec,
    pub schedule: Schedule,
    pub calibration: CalibrationSettings,
    pub navigation: McNavigation,
    /// The Saltelli design of the cell's trials, if the config asks for Sobol' indices.
    pub saltelli: Option<Saltelli>,
    /// A hand-held protocol in place of the schedule (whose one step then only names it).
    pub protocol: Option<super::protocol::ProtocolCell>,
}

/// A checked run config.
#[derive(Debug, Clone)]
pub struct McConfig {
    pub name: String,
    pub seed: u64,
    pub trials_per_cell: u64,
    pub trials_per_part: u64,
    pub factor_keys: Vec<String>,
    pub cells: Vec<Cell>,
    pub text: String,
}

/// A run of this config holds every cell in memory (its checked setup, its preparation and its
/// summary's accumulators); a sweep whose cells would take more than this is refused before
/// anything is expanded, with the cell count and the estimate.
pub const MAX_SWEEP_BYTES: u64 = 2_000_000_000;

/// The memory a run holds per cell of an array of `accelerometers` (bytes): a fixed part and one
/// that grows with the parameters (7 per accelerometer), from the peak RSS of `gfcal run` on
/// sweeps of one trial a cell (release, 2026-11-25): the cube 58.7 KB a cell (1,024 and 4,096
/// cells), the 24-axis MIMU4444 array 184.6 KB (256 and 1,024 cells). About 8 KB of it is the
/// checked cell; most is the summary (per cell and parameter, its accumulators and its rows).
pub fn bytes_per_cell(accelerometers: usize) -> u64 {
    BYTES_PER_CELL_FIXED + BYTES_PER_CELL_PER_ACCELEROMETER * accelerometers as u64
}
const BYTES_PER_CELL_FIXED: u64 = 17_000;
const BYTES_PER_CELL_PER_ACCELEROMETER: u64 = 7_000;

/// What `gfcal check` says of a run config, found cell by cell without holding the cells.
#[derive(Debug, Clone, PartialEq)]
pub struct RunShape {
    pub name: String,
    pub cells: u64,
    pub trials_per_cell: u64,
    pub parts: u64,
}

impl McConfig {
    pub fn total_trials(&self) -> u64 {
        self.trials_per_cell * self.cells.len() as u64
    }

    pub fn parts(&self) -> u64 {
        self.total_trials().div_ceil(self.trials_per_part)
    }

    /// Reads and checks a run config and every cell of its sweep.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        Self::from_text(text, path)
    }

    /// Reads and checks a run config given as text; `path` names it in messages and anchors
    /// relative files.
    pub fn from_text(text: String, path: &Path) -> Result<Self, ConfigError> {
        let plan = Plan::new(&text, path)?;
        let mut cells = Vec::with_capacity(plan.assignments.len());
        let mut saltelli = SaltelliInputs::default();
        for index in 0..plan.assignments.len() {
            let cell = plan.cell(index)?;
            saltelli.see(&plan, &cell)?;
            cells.push(cell);
        }
        let trials_per_cell = plan.trials_per_cell(&saltelli)?;
        if let (Some(s), Some(inputs)) = (&plan.file.sensitivity, saltelli.inputs) {
            for (i, c) in cells.iter_mut().enumerate() {
                c.saltelli = Some(Saltelli {
                    base_samples: s.base_samples,
                    inputs: inputs.clone(),
                    first_trial: i as u64 * trials_per_cell,
                });
            }
        }
        let Plan { name, file, trials_per_part, factor_keys, .. } = plan;
        Ok(Self { name, seed: file.seed, trials_per_cell, trials_per_part, factor_keys, cells, text })
    }

    /// Checks a run config as [`McConfig::load`] does, every cell of its sweep included, but one
    /// cell at a time: memory stays that of one cell whatever the sweep's size.
    pub fn check(path: &Path) -> Result<RunShape, ConfigError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        let plan = Plan::new(&text, path)?;
        let mut saltelli = SaltelliInputs::default();
        for index in 0..plan.assignments.len() {
            let cell = plan.cell(index)?;
            saltelli.see(&plan, &cell)?;
        }
        let trials_per_cell = plan.trials_per_cell(&saltelli)?;
        let cells = plan.assignments.len() as u64;
        let parts = (cells * trials_per_cell).div_ceil(plan.trials_per_part);
        Ok(RunShape { name: plan.name, cells, trials_per_cell, parts })
    }
}

/// A run config read and checked up to its cells: the cells are built from it one by one.
struct Plan<'a> {
    path: &'a Path,
    /// The file as a table, without its `[sweep]`: each cell is this with its factors set.
    base: toml::Table,
    file: McFile,
    name: String,
    trials_per_part: u64,
    factor_keys: Vec<String>,
    /// Each cell's factor values (bounded: the sweep's size is checked before they are made).
    assignments: Vec<Vec<FactorValue>>,
}

impl<'a> Plan<'a> {
    fn new(text: &str, path: &'a Path) -> Result<Self, ConfigError> {
        let mut base: toml::Table = toml::from_str(text)
            .map_err(|e| ConfigError::Parse { path: path.to_path_buf(), message: e.to_string() })?;
        base.remove("sweep");
        // Read from the text itself (not the table), so that an error names its line.
        let file: McFile = toml::from_str(text)
            .map_err(|e: toml::de::Error| ConfigError::Parse { path: path.to_path_buf(), message: e.to_string() })?;
        let bad = |b: Bad| b.in_file(path);
        if let Some(s) = &file.sensitivity {
            if s.base_samples < 2 {
                return Err(bad(Bad::new("sensitivity.base_samples", "must be at least 2")));
            }
            if file.trials_per_cell.is_some() {
                return Err(bad(Bad::new(
                    "trials_per_cell",
                    "is set by the Saltelli design (sensitivity.base_samples x (varying parameters + 2)); remove it",
                )));
            }
        } else if file.trials_per_cell.is_none() {
            return Err(bad(Bad::new("trials_per_cell", "is missing (or give a [sensitivity] Saltelli design)")));
        }
        if file.trials_per_cell == Some(0) {
            return Err(bad(Bad::new("trials_per_cell", "must be at least 1")));
        }
        let trials_per_part = file.output.trials_per_part.unwrap_or(2048);
        if trials_per_part == 0 {
            return Err(bad(Bad::new("output.trials_per_part", "must be at least 1")));
        }
        let name = file.name.clone().unwrap_or_else(|| {
            path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "run".into())
        });
        if name.is_empty() || name.contains(['/', '\\']) {
            return Err(bad(Bad::new("name", format!("`{name}` cannot name a results folder"))));
        }
        let (factor_keys, assignments) = match &file.sweep {
            None => (vec![], vec![vec![]]),
            Some(s) => {
                let design = SweepDesign::new(s).map_err(bad)?;
                // The size first, from the design alone: a sweep too large to hold is refused
                // before any cell (or any design point) is made.
                let accelerometers = file.array.build(path).map(|a| a.len()).unwrap_or(6);
                design.check_size(accelerometers).map_err(bad)?;
                (design.keys(), design.expand(file.seed))
            }
        };
        Ok(Self { path, base, file, name, trials_per_part, factor_keys, assignments })
    }

    /// Builds and checks cell `index`.
    fn cell(&self, index: usize) -> Result<Cell, ConfigError> {
        let path = self.path;
        let bad = |b: Bad| b.in_file(path);
        let values = &self.assignments[index];
        let mut doc = self.base.clone();
        for (key, value) in self.factor_keys.iter().zip(values) {
            set_dotted(&mut doc, key, toml_value(value))
                .map_err(|p| bad(Bad::new(format!("sweep.factor `{key}`"), p)))?;
        }
        let describe = || describe_values(&self.factor_keys, values);
        let cell_file: McFile = doc.try_into().map_err(|e: toml::de::Error| ConfigError::Parse {
            path: path.to_path_buf(),
            message: format!("in the sweep cell with {}: {}", describe(), e.message()),
        })?;
        let factors = self.factor_keys.iter().cloned().zip(values.iter().cloned()).collect();
        build_cell(&cell_file, path, index, factors).map_err(|e| match e {
            ConfigError::Invalid { path, key, problem } if !self.factor_keys.is_empty() => ConfigError::Invalid {
                path,
                key,
                problem: format!("{problem} (in the sweep cell with {})", describe()),
            },
            other => other,
        })
    }

    /// Trials per cell (set by the Saltelli design when there is one), with the run's total
    /// checked to fit in 64 bits.
    fn trials_per_cell(&self, saltelli: &SaltelliInputs) -> Result<u64, ConfigError> {
        let bad = |b: Bad| b.in_file(self.path);
        let per_cell = match (&self.file.sensitivity, &saltelli.inputs) {
            (Some(s), Some(inputs)) => s.base_samples * (inputs.len() as u64 + 2),
            _ => self.file.trials_per_cell.unwrap_or(1),
        };
        if per_cell.checked_mul(self.assignments.len() as u64).is_none() {
            return Err(bad(Bad::new(
                "trials_per_cell",
                format!(
                    "{per_cell} trials in each of {} cells: more trials than gfcal can count",
                    self.assignments.len()
                ),
            )));
        }
        Ok(per_cell)
    }
}

/// The varying error parameters of a Saltelli design: the same in every cell.
#[derive(Default)]
struct SaltelliInputs {
    inputs: Option<Vec<usize>>,
}

impl SaltelliInputs {
    fn see(&mut self, plan: &Plan, c: &Cell) -> Result<(), ConfigError> {
        if plan.file.sensitivity.is_none() {
            return Ok(());
        }
        let bad = |b: Bad| b.in_file(plan.path);
        if c.protocol.is_some() {
            return Err(bad(Bad::new("sensitivity.design", "a Saltelli design is not available with [protocol]")));
        }
        let varying = c.errors.varying(&c.layout);
        match &self.inputs {
            None => {
                if varying.is_empty() {
                    return Err(bad(Bad::new(
                        "sensitivity",
                        "no error parameter varies between trials: a Saltelli design has nothing to attribute",
                    )));
                }
                self.inputs = Some(varying);
            }
            Some(first) if *first != varying => {
                return Err(bad(Bad::new(
                    "sensitivity",
                    format!(
                        "the sweep cell with {} varies other error parameters than cell 0; a Saltelli design \
                         needs the same inputs in every cell",
                        c.factors.iter().map(|(k, v)| format!("{k} = {}", fmt_value(v))).collect::<Vec<_>>().join(", ")
                    ),
                )));
            }
            Some(_) => {}
        }
        Ok(())
    }
}

fn describe_values(keys: &[String], values: &[FactorValue]) -> String {
    keys.iter().zip(values).map(|(k, v)| format!("{k} = {}", fmt_value(v))).collect::<Vec<_>>().join(", ")
}

/// `n` with thousands separators: 10,004,569.
fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, ch) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(ch);
    }
    out
}

fn fmt_value(v: &FactorValue) -> String {
    match v {
        FactorValue::Number(x) => format!("{x}"),
        FactorValue::Text(s) => format!("\"{s}\""),
    }
}

fn toml_value(v: &FactorValue) -> toml::Value {
    match v {
        FactorValue::Number(x) => toml::Value::Float(*x),
        FactorValue::Text(s) => toml::Value::String(s.clone()),
    }
}

/// Sets `a.b.c = value` in a TOML table, creating tables on the way.
fn set_dotted(doc: &mut toml::Table, key: &str, value: toml::Value) -> Result<(), String> {
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err("is not a dotted key".into());
    }
    let mut table = doc;
    for p in &parts[..parts.len() - 1] {
        let entry = table.entry(p.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        table = entry.as_table_mut().ok_or_else(|| format!("`{p}` is not a table"))?;
    }
    // An integer key (e.g. trials) keeps its type when the level is a whole number.
    let last = parts[parts.len() - 1].to_string();
    let value = match (&value, table.get(&last)) {
        (toml::Value::Float(f), Some(toml::Value::Integer(_))) if f.fract() == 0.0 => toml::Value::Integer(*f as i64),
        _ => value,
    };
    table.insert(last, value);
    Ok(())
}

/// A sweep's factors, checked, before any cell is made.
struct SweepDesign<'a> {
    section: &'a SweepSection,
    /// Listed factors: (index among the factors, levels).
    listed: Vec<(usize, Vec<FactorValue>)>,
    /// Continuous factors: (index, low, high, scale).
    continuous: Vec<(usize, f64, f64, Scale)>,
    /// Space-filling points (1 without continuous factors).
    points: usize,
}

impl<'a> SweepDesign<'a> {
    fn new(s: &'a SweepSection) -> Result<Self, Bad> {
        if s.factor.is_empty() {
            return Err(Bad::new("sweep.factor", "a sweep needs at least one [[sweep.factor]] (or no [sweep] at all)"));
        }
        let mut listed: Vec<(usize, Vec<FactorValue>)> = Vec::new();
        let mut continuous: Vec<(usize, f64, f64, Scale)> = Vec::new();
        for (i, f) in s.factor.iter().enumerate() {
            let key = |k: &str| format!("sweep.factor[{i}].{k}");
            if f.key.trim().is_empty() {
                return Err(Bad::new(key("key"), "is empty"));
            }
            if f.key == "name" {
                // summary.csv has a column `name`, and the name is the folder's: one per run.
                return Err(Bad::new(
                    key("key"),
                    "`name` names the run's results folder: it cannot vary between cells",
                ));
            }
            match (&f.levels, f.low, f.high) {
                (Some(levels), None, None) => {
                    if levels.is_empty() {
                        return Err(Bad::new(key("levels"), "is empty: give at least one level"));
                    }
                    let vals = levels
                        .iter()
                        .map(|v| match v {
                            toml::Value::Float(x) => Ok(FactorValue::Number(*x)),
                            toml::Value::Integer(x) => Ok(FactorValue::Number(*x as f64)),
                            toml::Value::String(t) => Ok(FactorValue::Text(t.clone())),
                            other => {
                                Err(Bad::new(key("levels"), format!("levels are numbers or strings, got {other}")))
                            }
                        })
                        .collect::<Result<Vec<_>, _>>()?;
                    listed.push((i, vals));
                }
                (None, Some(lo), Some(hi)) => {
                    if s.design == DesignKind::Factorial {
                        return Err(Bad::new(
                            key("low"),
                            "a continuous factor needs design = \"latin_hypercube\" or \"sobol\"",
                        ));
                    }
                    finite(&key("low"), lo)?;
                    finite(&key("high"), hi)?;
                    if hi <= lo {
                        return Err(Bad::new(key("high"), format!("must be above low ({lo}), got {hi}")));
                    }
                    let scale = f.scale.unwrap_or_default();
                    if scale == Scale::Log && lo <= 0.0 {
                        return Err(Bad::new(key("low"), "a log scale needs low > 0"));
                    }
                    continuous.push((i, lo, hi, scale));
                }
                _ => return Err(Bad::new(format!("sweep.factor[{i}]"), "give either `levels`, or `low` and `high`")),
            }
        }
        let points = if continuous.is_empty() {
            1
        } else {
            let n = s.points.ok_or_else(|| Bad::new("sweep.points", "needed with continuous factors"))?;
            if n == 0 {
                return Err(Bad::new("sweep.points", "must be at least 1"));
            }
            n
        };
        Ok(Self { section: s, listed, continuous, points })
    }

    fn keys(&self) -> Vec<String> {
        self.section.factor.iter().map(|f| f.key.clone()).collect()
    }

    /// The number of cells, by arithmetic (`None` beyond 64 bits).
    fn cells(&self) -> Option<u64> {
        self.listed.iter().try_fold(self.points as u64, |n, (_, levels)| n.checked_mul(levels.len() as u64))
    }

    /// Refuses a sweep whose cells a run could not hold (see [`MAX_SWEEP_BYTES`]).
    fn check_size(&self, accelerometers: usize) -> Result<(), Bad> {
        let per_cell = bytes_per_cell(accelerometers);
        let max_cells = MAX_SWEEP_BYTES / per_cell;
        let cells = self.cells();
        if cells.is_some_and(|n| n <= max_cells) {
            return Ok(());
        }
        let mut how: Vec<String> = Vec::new();
        if !self.listed.is_empty() {
            let levels: Vec<String> = self.listed.iter().map(|(_, l)| l.len().to_string()).collect();
            how.push(format!("levels {}", levels.join(" x ")));
        }
        if !self.continuous.is_empty() {
            how.push(format!("{} points", thousands(self.points as u64)));
        }
        let count = match cells {
            Some(n) => format!("{} cells", thousands(n)),
            None => "more than 2^64 cells".into(),
        };
        let total_gb = cells.map_or(f64::INFINITY, |n| n as f64 * per_cell as f64 / 1e9);
        Err(Bad::new(
            "sweep",
            format!(
                "{count} ({}): a run holds every cell (its checked setup, its preparation and its summary) in \
                 memory, about {} KB a cell of {accelerometers} accelerometers, so {total_gb:.0} GB for this sweep, \
                 more than the {} GB gfcal allows ({} cells at most); sweep fewer levels or points, or split the \
                 sweep over several configs",
                how.join(" x "),
                per_cell / 1000,
                MAX_SWEEP_BYTES / 1_000_000_000,
                thousands(max_cells)
            ),
        ))
    }

    /// Every cell's factor values: the listed levels crossed factorially (the last factor
    /// fastest), then, within each combination, the space-filling points.
    fn expand(&self, seed: u64) -> Vec<Vec<FactorValue>> {
        let (listed, continuous) = (&self.listed, &self.continuous);
        let points: Vec<Vec<f64>> = if continuous.is_empty() {
            vec![vec![]]
        } else {
            let n = self.points;
            let mut rng = crate::rng::trial_rng(seed ^ 0x5357_4545_5000, 0);
            let unit = match self.section.design {
                DesignKind::LatinHypercube => latin_hypercube(n, continuous.len(), &mut rng),
                _ => sobol(n, continuous.len(), (seed & 0xffff_ffff) as u32),
            };
            unit.into_iter()
                .map(|u| {
                    u.iter()
                        .zip(continuous)
                        .map(|(u, (_, lo, hi, scale))| match scale {
                            Scale::Linear => lo + u * (hi - lo),
                            Scale::Log => (lo.ln() + u * (hi.ln() - lo.ln())).exp(),
                        })
                        .collect()
                })
                .collect()
        };
        let combos = factorial(&listed.iter().map(|(_, v)| v.len()).collect::<Vec<_>>());
        let k = self.section.factor.len();
        let mut cells = Vec::with_capacity(combos.len() * points.len());
        for combo in &combos {
            for point in &points {
                let mut values = vec![FactorValue::Number(f64::NAN); k];
                for ((i, levels), &l) in listed.iter().zip(combo) {
                    values[*i] = levels[l].clone();
                }
                for ((i, ..), v) in continuous.iter().zip(point) {
                    values[*i] = FactorValue::Number(*v);
                }
                cells.push(values);
            }
        }
        cells
    }
}

fn dist<T: Clone>(
    key: &str,
    entry: &Option<DistEntry<T>>,
    n: usize,
    width: usize,
    to_si: f64,
    components: impl Fn(&T) -> Vec<f64>,
) -> Result<Dist, Bad> {
    let Some(e) = entry else { return Ok(Dist::Fixed(vec![vec![0.0; width]; n])) };
    let k = |s: &str| format!("errors.{key}.{s}");
    // One value, or one per accelerometer; finite, and not negative where `non_negative`.
    let per_accel = |name: &str, v: &Option<OneOrEach<f64>>, non_negative: bool| -> Result<Vec<f64>, Bad> {
        let values = v.clone().unwrap_or(OneOrEach::One(0.0)).expand(&k(name), n)?;
        values
            .iter()
            .enumerate()
            .map(|(j, x)| {
                let key = if matches!(v, Some(OneOrEach::Each(_))) { format!("{}[{j}]", k(name)) } else { k(name) };
                let x = finite(&key, *x)?;
                if non_negative && x < 0.0 {
                    return Err(Bad::new(key, format!("must not be negative, got {x}")));
                }
                Ok(x * to_si)
            })
            .collect()
    };
    let mean = per_accel("mean", &e.mean, false)?;
    let forbid = |name: &str, given: bool, kind: &str| {
        if given { Err(Bad::new(k(name), format!("does not apply to dist = \"{kind}\""))) } else { Ok(()) }
    };
    match e.dist {
        DistKind::Normal => {
            forbid("half_width", e.half_width.is_some(), "normal")?;
            forbid("value", e.value.is_some(), "normal")?;
            if e.sigma.is_none() {
                return Err(Bad::new(k("sigma"), "is required for dist = \"normal\""));
            }
            Ok(Dist::Normal { mean, sigma: per_accel("sigma", &e.sigma, true)? })
        }
        DistKind::Uniform => {
            forbid("sigma", e.sigma.is_some(), "uniform")?;
            forbid("value", e.value.is_some(), "uniform")?;
            if e.half_width.is_none() {
                return Err(Bad::new(k("half_width"), "is required for dist = \"uniform\""));
            }
            Ok(Dist::Uniform { mean, half_width: per_accel("half_width", &e.half_width, true)? })
        }
        DistKind::Fixed => {
            for (name, given) in
                [("mean", e.mean.is_some()), ("sigma", e.sigma.is_some()), ("half_width", e.half_width.is_some())]
            {
                forbid(name, given, "fixed")?;
            }
            let v = e.value.as_ref().ok_or_else(|| Bad::new(k("value"), "is required for dist = \"fixed\""))?;
            let rows = v.expand(&k("value"), n)?;
            let mut out = Vec::with_capacity(n);
            for (j, r) in rows.iter().enumerate() {
                let c = components(r);
                let mut row = Vec::with_capacity(width);
                for (i, x) in c.iter().enumerate() {
                    row.push(finite(&format!("{}[{j}][{i}]", k("value")), *x)? * to_si);
                }
                out.push(row);
            }
            Ok(Dist::Fixed(out))
        }
    }
}

fn build_cell(f: &McFile, path: &Path, index: usize, factors: Vec<(String, FactorValue)>) -> Result<Cell, ConfigError> {
    let bad = |b: Bad| b.in_file(path);
    let array = f.array.build(path)?;
    let n = array.len();
    let e = &f.errors;
    let nominal_scale_factor = e
        .nominal_scale_factor
        .clone()
        .unwrap_or(OneOrEach::One(1.0))
        .expand("errors.nominal_scale_factor", n)
        .map_err(bad)?;
    for (j, k) in nominal_scale_factor.iter().enumerate() {
        let key = format!("errors.nominal_scale_factor[{j}]");
        if finite(&key, *k).map_err(bad)? == 0.0 {
            return Err(bad(Bad::new(key, "a scale factor of zero makes the accelerometer blind")));
        }
    }
    let errors = ErrorModel {
        nominal_scale_factor,
        bias_m_s2: dist("bias_mg", &e.bias_mg, n, 1, M_S2_PER_MG, |v| vec![*v]).map_err(bad)?,
        scale_factor_rel: dist("scale_factor_ppm", &e.scale_factor_ppm, n, 1, 1e-6, |v| vec![*v]).map_err(bad)?,
        misalignment_rad: dist("misalignment_deg", &e.misalignment_deg, n, 2, RAD_PER_DEG, |v| v.to_vec())
            .map_err(bad)?,
        location_m: dist("location_mm", &e.location_mm, n, 3, M_PER_MM, |v| v.to_vec()).map_err(bad)?,
    };
    let (noise, _) = f.noise.resolve().map_err(bad)?;
    let calibration = f.calibration.resolve().map_err(bad)?;
    let (schedule, protocol) = match (&f.schedule, &f.protocol) {
        (Some(s), None) => (s.build(&array).map_err(bad)?, None),
        (None, Some(p)) => {
            if calibration.form != Form::Tilt {
                return Err(bad(Bad::new(
                    "calibration.form",
                    "a hand-held protocol is calibrated in the tilt form: set form = \"tilt\"",
                )));
            }
            let recording_array = match &f.array.file {
                Some(file) => {
                    crate::config::array::load_recording_array(&path.parent().unwrap_or(Path::new(".")).join(file))?
                }
                None => crate::array::wiring::RecordingArray::plain(array.clone(), path),
            };
            let sigma = noise.white.sigma_m_s2(p.sample_rate_hz);
            let cell = p.resolve(recording_array, sigma, calibration.gravity_m_s2).map_err(bad)?;
            let rate = cell.protocol.sample_rate_hz;
            let step = crate::calib::schedule::Step::static_pose(
                "protocol",
                nalgebra::Vector3::z(),
                cell.protocol.pose_s,
                rate,
            );
            let named = Schedule::new("hand_held_protocol", vec![step])
                .map_err(|e| bad(Bad::new("protocol", e.to_string())))?;
            (named, Some(cell))
        }
        (Some(_), Some(_)) => return Err(bad(Bad::new("protocol", "give either [schedule] or [protocol], not both"))),
        (None, None) => {
            return Err(bad(Bad::new("schedule", "a run needs [schedule] (a rate table) or [protocol] (hand-held)")));
        }
    };
    if calibration.form == Form::Triad && array.triads().is_empty() {
        return Err(bad(Bad::new("calibration.form", "the triad form needs an array with triads; use \"tilt\"")));
    }
    if calibration.pose.has_free() {
        let key = if calibration.pose.static_sigma_rad.is_infinite() {
            "calibration.pose_tilt_sigma_arcsec"
        } else {
            "calibration.spin_axis_tilt_sigma_arcsec"
        };
        return Err(bad(Bad::new(
            key,
            "a run draws every trial's fixture tilts from this sigma, so it must be finite (inf, a free pose, is for `gfcal identify` and `gfcal design`)",
        )));
    }
    let layout = Layout::new(&array, calibration.form).map_err(|e| bad(Bad::new("calibration.form", e.to_string())))?;
    let nav = &f.navigation;
    let step_s = positive("navigation.step_s", nav.step_s).map_err(bad)?;
    if nav.horizons_s.is_empty() {
        return Err(bad(Bad::new("navigation.horizons_s", "needs at least one horizon")));
    }
    let mut horizons_s = Vec::new();
    for (k, h) in nav.horizons_s.iter().enumerate() {
        horizons_s.push(positive(&format!("navigation.horizons_s[{k}]"), *h).map_err(bad)?);
    }
    horizons_s.sort_by(f64::total_cmp);
    horizons_s.dedup();
    crate::config::trajectory::check_navigation_work(step_s, &horizons_s).map_err(bad)?;
    let mut compensations =
        nav.compensations.clone().unwrap_or_else(|| vec![Compensation::Nominal, Compensation::Estimated]);
    let mut seen = Vec::new();
    compensations.retain(|c| {
        if seen.contains(c) {
            false
        } else {
            seen.push(*c);
            true
        }
    });
    if compensations.is_empty() {
        return Err(bad(Bad::new(
            "navigation.compensations",
            "needs at least one of \"nominal\", \"estimated\", \"true\"",
        )));
    }
    let last = horizons_s.last().copied().unwrap_or(1.0);
    let trajectory = f.trajectory.build(last).map_err(bad)?;
    Ok(Cell {
        index,
        factors,
        array,
        layout,
        errors,
        noise,
        schedule,
        calibration,
        navigation: McNavigation { trajectory, step_s, horizons_s, compensations, noise: nav.noise.unwrap_or(false) },
        saltelli: None,
        protocol,
    })
}
