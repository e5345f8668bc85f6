//! The config of `gfcal simulate-log`: an array, its true errors, noise, a schedule, an optional
//! temperature ramp, and the effects to hide in the log.
//!
//! ```toml
//! seed = 1
//! gravity_m_s2 = 9.80665            # the value the log's model assumes
//! [array]  [errors]  [noise]  [schedule]      # as for `identify`
//! [noise]                           # gauss_markov_* here is the `bias_instability` effect
//! [temperature]                     # writes a temp_c column
//! start_c = 20.0
//! end_c = 40.0
//! reference_c = 25.0
//! wobble_c = 3.0                    # optional sinusoid on the ramp (separates temperature from time)
//! wobble_period_s = 60.0
//! [effects]                         # all optional; one value, or one per accelerometer
//! scale_factor_quadratic_ug_per_g2 = 50.0
//! scale_factor_cubic_ug_per_g3 = 5.0
//! bias_time_drift_ug_per_s = 0.5
//! bias_temperature_ug_per_c = 10.0
//! scale_factor_temperature_ppm_per_c = 20.0
//! spin_axis_offset_mm = [0.5, -0.3, 0.2]   # the table axis's offset from the array centre, body axes
//! spin_rate_error_ppm = 300.0
//! gravity_magnitude_ppm = 200.0            # local g over the assumed value, minus 1
//! pose_misalignment_sigma_deg = 0.05       # random, per static step (from the seed)
//! ```

use std::path::Path;

use serde::Deserialize;

use super::array::ArraySection;
use super::error_set::{ErrorSet, ErrorsSection};
use super::noise::NoiseSection;
use super::schedule::ScheduleSection;
use super::{Bad, ConfigError, OneOrEach, finite, positive, read_toml};
use crate::array::Array;
use crate::calib::schedule::Schedule;
use crate::discrepancy::effect::by_name;
use crate::discrepancy::log::{ActiveEffect, Temperature};
use crate::sensor::noise::NoiseSpec;
use crate::units::{M_PER_MM, M_S2_PER_UG, RAD_PER_DEG, STANDARD_GRAVITY_M_S2};

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureSection {
    pub start_c: f64,
    pub end_c: f64,
    pub reference_c: Option<f64>,
    pub wobble_c: Option<f64>,
    pub wobble_period_s: Option<f64>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EffectsSection {
    pub scale_factor_quadratic_ug_per_g2: Option<OneOrEach<f64>>,
    pub scale_factor_cubic_ug_per_g3: Option<OneOrEach<f64>>,
    pub bias_time_drift_ug_per_s: Option<OneOrEach<f64>>,
    pub bias_temperature_ug_per_c: Option<OneOrEach<f64>>,
    pub scale_factor_temperature_ppm_per_c: Option<OneOrEach<f64>>,
    pub spin_axis_offset_mm: Option<[f64; 3]>,
    pub spin_rate_error_ppm: Option<f64>,
    pub gravity_magnitude_ppm: Option<f64>,
    pub pose_misalignment_sigma_deg: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulateLogFile {
    pub seed: u64,
    pub gravity_m_s2: Option<f64>,
    #[serde(default)]
    pub array: ArraySection,
    #[serde(default)]
    pub errors: ErrorsSection,
    #[serde(default)]
    pub noise: NoiseSection,
    pub schedule: ScheduleSection,
    pub temperature: Option<TemperatureSection>,
    #[serde(default)]
    pub effects: EffectsSection,
}

/// A checked simulate-log config, SI.
pub struct SimulateLogConfig {
    pub seed: u64,
    pub gravity_m_s2: f64,
    pub array: Array,
    pub errors: ErrorSet,
    pub noise: NoiseSpec,
    pub schedule: Schedule,
    pub temperature: Option<Temperature>,
    pub effects: Vec<ActiveEffect>,
}

fn per_accel(key: &str, v: &Option<OneOrEach<f64>>, n: usize, to_si: f64) -> Result<Option<Vec<f64>>, Bad> {
    let Some(v) = v else { return Ok(None) };
    let values = v.expand(&format!("effects.{key}"), n)?;
    values
        .iter()
        .enumerate()
        .map(|(j, x)| Ok(finite(&format!("effects.{key}[{j}]"), *x)? * to_si))
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

impl SimulateLogConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let (file, _): (SimulateLogFile, _) = read_toml(path)?;
        let bad = |b: Bad| b.in_file(path);
        let array = file.array.build(path)?;
        let n = array.len();
        let errors = file.errors.resolve(&array).map_err(bad)?;
        let (noise, _) = file.noise.resolve().map_err(bad)?;
        let schedule = file.schedule.build(&array).map_err(bad)?;
        let g = positive("gravity_m_s2", file.gravity_m_s2.unwrap_or(STANDARD_GRAVITY_M_S2)).map_err(bad)?;
        let temperature = match &file.temperature {
            None => None,
            Some(t) => Some(Temperature {
                start_c: finite("temperature.start_c", t.start_c).map_err(bad)?,
                end_c: finite("temperature.end_c", t.end_c).map_err(bad)?,
                reference_c: finite("temperature.reference_c", t.reference_c.unwrap_or(t.start_c)).map_err(bad)?,
                wobble_c: finite("temperature.wobble_c", t.wobble_c.unwrap_or(0.0)).map_err(bad)?,
                wobble_period_s: positive("temperature.wobble_period_s", t.wobble_period_s.unwrap_or(60.0))
                    .map_err(bad)?,
            }),
        };
        let e = &file.effects;
        let mut effects = Vec::new();
        let mut push = |name: &str, values: Option<Vec<f64>>| {
            if let (Some(values), Some(effect)) = (values, by_name(name)) {
                effects.push(ActiveEffect { effect, values });
            }
        };
        // e = K2 [ug/g^2] 1e-6 g0 (u / g0)^2 = (K2 1e-6 / g0) u^2, and likewise for K3.
        let g0 = STANDARD_GRAVITY_M_S2;
        push(
            "scale_factor_quadratic",
            per_accel("scale_factor_quadratic_ug_per_g2", &e.scale_factor_quadratic_ug_per_g2, n, 1e-6 / g0)
                .map_err(bad)?,
        );
        push(
            "scale_factor_cubic",
            per_accel("scale_factor_cubic_ug_per_g3", &e.scale_factor_cubic_ug_per_g3, n, 1e-6 / (g0 * g0))
                .map_err(bad)?,
        );
        push(
            "bias_time_drift",
            per_accel("bias_time_drift_ug_per_s", &e.bias_time_drift_ug_per_s, n, M_S2_PER_UG).map_err(bad)?,
        );
        for (key, name, v, to_si) in [
            ("bias_temperature_ug_per_c", "bias_temperature", &e.bias_temperature_ug_per_c, M_S2_PER_UG),
            (
                "scale_factor_temperature_ppm_per_c",
                "scale_factor_temperature",
                &e.scale_factor_temperature_ppm_per_c,
                1e-6,
            ),
        ] {
            let values = per_accel(key, v, n, to_si).map_err(bad)?;
            if values.is_some() && temperature.is_none() {
                return Err(bad(Bad::new(
                    format!("effects.{key}"),
                    "needs a [temperature] section (the log's temp_c)",
                )));
            }
            push(name, values);
        }
        if let Some(d) = e.spin_axis_offset_mm {
            push(
                "spin_axis_offset",
                Some(
                    super::vec3("effects.spin_axis_offset_mm", d).map_err(bad)?.iter().map(|v| v * M_PER_MM).collect(),
                ),
            );
        }
        if let Some(v) = e.spin_rate_error_ppm {
            push("spin_rate_error", Some(vec![finite("effects.spin_rate_error_ppm", v).map_err(bad)? * 1e-6]));
        }
        if let Some(v) = e.gravity_magnitude_ppm {
            push("gravity_magnitude", Some(vec![finite("effects.gravity_magnitude_ppm", v).map_err(bad)? * 1e-6]));
        }
        if let Some(sigma) = e.pose_misalignment_sigma_deg {
            let sigma = finite("effects.pose_misalignment_sigma_deg", sigma).map_err(bad)?;
            if sigma < 0.0 {
                return Err(bad(Bad::new(
                    "effects.pose_misalignment_sigma_deg",
                    format!("must not be negative, got {sigma}"),
                )));
            }
            let statics = schedule.steps().iter().filter(|s| !s.is_spin()).count();
            let mut rng = crate::rng::trial_rng(file.seed ^ 0x706f_7365, 0);
            let normal = rand_distr::Normal::new(0.0, sigma * RAD_PER_DEG)
                .map_err(|e| bad(Bad::new("effects.pose_misalignment_sigma_deg", e.to_string())))?;
            use rand_distr::Distribution;
            push("pose_misalignment", Some((0..2 * statics).map(|_| normal.sample(&mut rng)).collect()));
        }
        Ok(Self { seed: file.seed, gravity_m_s2: g, array, errors, noise, schedule, temperature, effects })
    }
}
