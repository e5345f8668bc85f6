//! The config of `gfcal identify` and `gfcal design`: an array, the true errors (the point where
//! identifiability is evaluated), white noise, a schedule, the estimator's form and the targets.
//!
//! ```toml
//! [calibration]
//! form = "triad"            # or "tilt"
//! estimator = "joint"       # or "paper"
//! start = "linear"          # joint only: or "nominal"
//! gravity_m_s2 = 9.80665
//! pose_tilt_sigma_arcsec = 36.0       # fixture error of every commanded pose: 0 perfect (default),
//!                                     # inf a pose placed by hand (free)
//! spin_axis_tilt_sigma_arcsec = 36.0  # of every spin axis (default: pose_tilt_sigma_arcsec)
//!
//! [targets]                 # Cramer-Rao sigmas a schedule should reach
//! scale_factor_ppm = 100.0
//! bias_ug = 50.0
//! misalignment_deg = 0.01
//! location_mm = 0.1
//! velocity_err_m_s_p95_at_10s = 0.5   # or drift targets instead (`gfcal design`, by LinCov):
//!                                     # <metric>_<median|p95>_at_<h>s, the metric in SI as in
//!                                     # summary.csv; they need [trajectory] and [navigation]
//!
//! [trajectory]              # with drift targets: as for `drift`
//! [navigation]              # with drift targets: the navigation's step
//! step_s = 0.01
//!
//! [design]                  # gfcal design: the candidate pool and a limit
//! spin_rates_rad_s = [3.14159, 6.28319, 12.56637]
//! max_added_steps = 12
//! ```

use std::path::Path;

use serde::Deserialize;

use super::array::ArraySection;
use super::error_set::{ErrorSet, ErrorsSection};
use super::noise::NoiseSection;
use super::schedule::ScheduleSection;
use super::trajectory::TrajectorySection;
use super::{Bad, ConfigError, positive, read_toml};
use crate::array::Array;
use crate::calib::Form;
use crate::calib::fisher::Targets;
use crate::calib::joint::Start;
use crate::calib::pose::PoseError;
use crate::calib::schedule::Schedule;
use crate::nav::Trajectory;
use crate::sensor::noise::NoiseSpec;
use crate::units::{RAD_PER_ARCSEC, STANDARD_GRAVITY_M_S2};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FormEntry {
    #[default]
    Triad,
    Tilt,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Estimator {
    #[default]
    Joint,
    Paper,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum StartEntry {
    Nominal,
    #[default]
    Linear,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSection {
    #[serde(default)]
    pub form: FormEntry,
    #[serde(default)]
    pub estimator: Estimator,
    #[serde(default)]
    pub start: StartEntry,
    pub gravity_m_s2: Option<f64>,
    pub pose_tilt_sigma_arcsec: Option<f64>,
    pub spin_axis_tilt_sigma_arcsec: Option<f64>,
}

#[derive(Debug, Clone, Default, Deserialize)]
pub struct TargetsSection {
    pub scale_factor_ppm: Option<f64>,
    pub bias_ug: Option<f64>,
    pub misalignment_deg: Option<f64>,
    pub location_mm: Option<f64>,
    /// Every other key: a drift target (`<metric>_<median|p95>_at_<h>s`), or refused.
    #[serde(flatten)]
    pub drift: std::collections::BTreeMap<String, toml::Value>,
}

/// The drift metrics a drift target can name, in SI as summary.csv names them.
pub const DRIFT_TARGET_METRICS: [&str; 4] =
    ["rate_err_rad_s", "attitude_err_rad", "velocity_err_m_s", "position_err_m"];

/// A target on a drift metric's quantile of the estimated compensation (`gfcal design`).
#[derive(Debug, Clone, PartialEq)]
pub struct DriftTarget {
    /// The key as written, e.g. `velocity_err_m_s_p95_at_10s`.
    pub key: String,
    /// Index into [`DRIFT_TARGET_METRICS`].
    pub metric: usize,
    /// 0.5 (median) or 0.95 (p95).
    pub quantile: f64,
    pub horizon_s: f64,
    /// SI, the metric's unit.
    pub value: f64,
}

/// `[navigation]` of a calibration config with drift targets.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignNavigationSection {
    pub step_s: f64,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignSection {
    pub spin_rates_rad_s: Option<Vec<f64>>,
    pub max_added_steps: Option<usize>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    #[serde(default)]
    pub array: ArraySection,
    #[serde(default)]
    pub errors: ErrorsSection,
    #[serde(default)]
    pub noise: NoiseSection,
    pub schedule: ScheduleSection,
    #[serde(default)]
    pub calibration: CalibrationSection,
    #[serde(default)]
    pub targets: TargetsSection,
    #[serde(default)]
    pub design: DesignSection,
    /// With drift targets: the trajectory and the navigation's step.
    pub trajectory: Option<TrajectorySection>,
    pub navigation: Option<DesignNavigationSection>,
}

/// The navigation a drift target is evaluated on.
#[derive(Debug, Clone)]
pub struct DriftNavigation {
    pub trajectory: Trajectory,
    pub step_s: f64,
}

/// Calibration settings in SI.
#[derive(Debug, Clone)]
pub struct CalibrationSettings {
    pub form: Form,
    pub estimator: Estimator,
    pub start: Start,
    pub gravity_m_s2: f64,
    /// Tilt prior of every commanded pose and spin axis (`calib::pose`).
    pub pose: PoseError,
}

/// Design settings.
#[derive(Debug, Clone)]
pub struct DesignSettings {
    pub spin_rates_rad_s: Vec<f64>,
    pub max_added_steps: usize,
}

/// A checked calibration config.
#[derive(Debug, Clone)]
pub struct CalibrationConfig {
    pub array: Array,
    pub errors: ErrorSet,
    pub noise: NoiseSpec,
    pub noise_seed: u64,
    pub schedule: Schedule,
    pub calibration: CalibrationSettings,
    pub targets: Targets,
    /// Drift targets (`gfcal design` then designs for them instead of `targets`).
    pub drift_targets: Vec<DriftTarget>,
    /// The navigation of the drift targets (given with them).
    pub drift_navigation: Option<DriftNavigation>,
    pub design: DesignSettings,
    pub text: String,
}

impl CalibrationSection {
    pub fn resolve(&self) -> Result<CalibrationSettings, Bad> {
        Ok(CalibrationSettings {
            form: match self.form {
                FormEntry::Triad => Form::Triad,
                FormEntry::Tilt => Form::Tilt,
            },
            estimator: self.estimator,
            start: match self.start {
                StartEntry::Nominal => Start::Nominal,
                StartEntry::Linear => Start::Linear,
            },
            gravity_m_s2: positive("calibration.gravity_m_s2", self.gravity_m_s2.unwrap_or(STANDARD_GRAVITY_M_S2))?,
            pose: {
                let pose =
                    tilt_sigma("calibration.pose_tilt_sigma_arcsec", self.pose_tilt_sigma_arcsec.unwrap_or(0.0))?;
                let spin = match self.spin_axis_tilt_sigma_arcsec {
                    Some(v) => tilt_sigma("calibration.spin_axis_tilt_sigma_arcsec", v)?,
                    None => pose,
                };
                PoseError { static_sigma_rad: pose, spin_sigma_rad: spin }
            },
        })
    }
}

/// A tilt prior sigma in arc seconds, as radians: 0 or more, `inf` for a free tilt.
fn tilt_sigma(key: &str, arcsec: f64) -> Result<f64, Bad> {
    if arcsec.is_nan() || arcsec < 0.0 {
        return Err(Bad::new(key, format!("must be 0 (perfect fixture), positive, or inf (free), got {arcsec}")));
    }
    Ok(arcsec * RAD_PER_ARCSEC)
}

impl TargetsSection {
    pub fn resolve(&self) -> Result<Targets, Bad> {
        let d = Targets::default();
        Ok(Targets {
            scale_factor_ppm: positive(
                "targets.scale_factor_ppm",
                self.scale_factor_ppm.unwrap_or(d.scale_factor_ppm),
            )?,
            bias_ug: positive("targets.bias_ug", self.bias_ug.unwrap_or(d.bias_ug))?,
            misalignment_deg: positive(
                "targets.misalignment_deg",
                self.misalignment_deg.unwrap_or(d.misalignment_deg),
            )?,
            location_mm: positive("targets.location_mm", self.location_mm.unwrap_or(d.location_mm))?,
        })
    }
}

impl TargetsSection {
    /// The drift targets among the section's keys; any other unknown key is refused.
    pub fn drift_targets(&self) -> Result<Vec<DriftTarget>, Bad> {
        let mut out = Vec::new();
        for (key, value) in &self.drift {
            let full = format!("targets.{key}");
            let parsed = DRIFT_TARGET_METRICS.iter().enumerate().find_map(|(m, name)| {
                let rest = key.strip_prefix(name)?.strip_prefix('_')?;
                let (q, rest) = if let Some(r) = rest.strip_prefix("median_at_") {
                    (0.5, r)
                } else {
                    (0.95, rest.strip_prefix("p95_at_")?)
                };
                let h: f64 = rest.strip_suffix('s')?.parse().ok()?;
                Some((m, q, h))
            });
            let Some((metric, quantile, horizon_s)) = parsed else {
                return Err(Bad::new(
                    full,
                    "unknown key: a target is scale_factor_ppm, bias_ug, misalignment_deg, location_mm, or a drift \
                     target <metric>_<median|p95>_at_<h>s with metric rate_err_rad_s, attitude_err_rad, \
                     velocity_err_m_s or position_err_m (e.g. velocity_err_m_s_p95_at_10s)",
                ));
            };
            let value = value
                .as_float()
                .or_else(|| value.as_integer().map(|i| i as f64))
                .ok_or_else(|| Bad::new(full.clone(), format!("must be a number, got {value}")))?;
            positive(&full, horizon_s).map_err(|b| Bad::new(full.clone(), format!("its horizon {}", b.problem)))?;
            positive(&full, value)?;
            out.push(DriftTarget { key: key.clone(), metric, quantile, horizon_s, value });
        }
        Ok(out)
    }
}

impl DesignSection {
    pub fn resolve(&self) -> Result<DesignSettings, Bad> {
        let pi = std::f64::consts::PI;
        let rates = self.spin_rates_rad_s.clone().unwrap_or_else(|| vec![pi, 2.0 * pi, 4.0 * pi]);
        if rates.is_empty() {
            return Err(Bad::new("design.spin_rates_rad_s", "needs at least one rate"));
        }
        for (i, r) in rates.iter().enumerate() {
            positive(&format!("design.spin_rates_rad_s[{i}]"), *r)?;
        }
        let max = self.max_added_steps.unwrap_or(12);
        if max == 0 {
            return Err(Bad::new("design.max_added_steps", "must be at least 1"));
        }
        Ok(DesignSettings { spin_rates_rad_s: rates, max_added_steps: max })
    }
}

impl CalibrationConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let (file, text): (CalibrationFile, _) = read_toml(path)?;
        let array = file.array.build(path)?;
        let in_file = |b: Bad| b.in_file(path);
        let errors = file.errors.resolve(&array).map_err(in_file)?;
        let (noise, noise_seed) = file.noise.resolve().map_err(in_file)?;
        let schedule = file.schedule.build(&array).map_err(in_file)?;
        let calibration = file.calibration.resolve().map_err(in_file)?;
        if calibration.form == Form::Triad && array.triads().is_empty() {
            return Err(
                Bad::new("calibration.form", "the triad form needs an array with triads; use \"tilt\"").in_file(path)
            );
        }
        let targets = file.targets.resolve().map_err(in_file)?;
        let drift_targets = file.targets.drift_targets().map_err(in_file)?;
        let drift_navigation = match (&file.trajectory, &file.navigation, drift_targets.is_empty()) {
            (None, None, true) => None,
            (_, _, true) => {
                return Err(Bad::new(
                    if file.trajectory.is_some() { "trajectory" } else { "navigation" },
                    "is read only with a drift target in [targets] (e.g. velocity_err_m_s_p95_at_10s)",
                )
                .in_file(path));
            }
            (Some(t), Some(n), false) => {
                let step_s = positive("navigation.step_s", n.step_s).map_err(in_file)?;
                let last = drift_targets.iter().map(|d| d.horizon_s).fold(0.0, f64::max);
                super::trajectory::check_navigation_work(step_s, &[last]).map_err(in_file)?;
                Some(DriftNavigation { trajectory: t.build(last).map_err(in_file)?, step_s })
            }
            (None, _, false) => {
                return Err(
                    Bad::new("trajectory", "a drift target needs the [trajectory] it is navigated on").in_file(path)
                );
            }
            (_, None, false) => {
                return Err(Bad::new("navigation", "a drift target needs [navigation] step_s").in_file(path));
            }
        };
        let design = file.design.resolve().map_err(in_file)?;
        Ok(Self {
            array,
            errors,
            noise,
            noise_seed,
            schedule,
            calibration,
            targets,
            drift_targets,
            drift_navigation,
            design,
            text,
        })
    }

    /// White-noise density (input-referred, m/s^2/sqrt(Hz)): each step's per-sample sigma is
    /// this times the square root of its own sample rate.
    pub fn white_density_m_s2_per_sqrt_hz(&self) -> f64 {
        self.noise.white.density_m_s2_per_sqrt_hz()
    }
}
