//! A `gfcal run` cell on the hand-held protocol of a real array (`selfcal`): poses placed by hand
//! in random or listed directions, then a smooth random rotation phase, calibrated with no rate
//! table and (unless `use_gyro`) no gyroscope. Replaces `[schedule]` in a run config:
//!
//! ```toml
//! [protocol]
//! poses = 20                  # static poses placed by hand (random directions)
//! pose_up = [[0.0, -0.93, 0.36], ...]   # or their up directions (array axes), one per pose, in order
//! pose_s = 22.0               # still time per pose
//! transition_s = 3.0          # carrying the board between poses
//! dynamic_s = 100.0           # the rotation phase
//! rate_rms_rad_s = 25.0       # RMS angular rate of the rotation phase
//! accel_rms_m_s2 = 30.0       # RMS acceleration of the origin in the rotation phase
//! sample_rate_hz = 62.5
//! use_gyro = false            # true: the rate from the reference gyroscopes of the array file
//! remove_bias_drift = false   # true: calibrate as `gfcal calibrate` does by default, each
//!                             # accelerometer's bias drift in time taken out first
//! gyro_noise_sigma_rad_s = 0.01
//! ```
//!
//! The real board's physics (issue 28), all off by default (then every recording is today's, bit
//! for bit):
//!
//! ```toml
//! motion_band_hz = [3.5, 5.5]           # band of the smooth rotation and acceleration (default [0.3, 2.0])
//! accel_band_hz = [0.3, 3.0]            # band of the smooth acceleration alone (default: motion_band_hz)
//! vibration_rms_m_s2 = 30.0             # broadband translational vibration, RMS (3 axes together)
//! vibration_rate_rms_rad_s = 0.0        # broadband angular vibration, RMS
//! vibration_rate_band_hz = [2.0, 15.0]  # its own band (default: vibration_band_hz)
//! vibration_rate_low_pass_order = 3     # its low-pass: 2 (default) or 3 (a finite angular jerk)
//! vibration_low_pass_order = 3          # the translation's: 2 (default) or 3 (less jerk above the band)
//! vibration_band_hz = [2.0, 50.0]       # its band: 1st-order high-pass, Butterworth low-pass of vibration_low_pass_order
//! vibration_rate_exponent = 0.0         # its RMS goes as (|rate| / rate_rms_rad_s)^k (0: stationary)
//! vibration_sensor_rms_m_s2 = 0.0       # each accelerometer's own error under the vibration, one axis
//!                                       # (independent per accelerometer: not a rigid motion; its band,
//!                                       # low-pass and envelope are the translation's)
//! vibration_sensor_rate_exponent = 8.0  # that error's own k (default: vibration_rate_exponent): bursts
//!                                       # at the fastest turns, the rigid vibration unchanged
//! vibration_sensor_burst_duty = 0.05    # or that error in bursts at random times (whatever the motion):
//! vibration_sensor_burst_s = 0.1        # the share of time on and the bursts' mean length, s (both or none)
//! sample_clocks = true                  # packages with sample_clock_hz + sample_and_hold sample on their own clocks
//! clock_rate_offset_ppm = { dist = "normal", sigma = 1300.0 }       # per package (also uniform, fixed)
//! clock_common_rate_offset_ppm = { dist = "normal", sigma = 65.0 }  # per recording, every package
//! clock_drift_ppm_per_s = { dist = "uniform", half_width = 0.25 }   # per recording, every package
//! bias_drift_ug_per_s = { dist = "normal", sigma = 1.5 }           # each accelerometer's bias drift in time
//! common_bias_drift_ug_per_s = { dist = "normal", mean = -1.6, sigma = 1.1 }  # per recording, every accelerometer
//! anti_alias_time_constant_ms = 0.0     # first-order filter before each accelerometer's sampling
//! gyro_anti_alias_time_constant_ms = 0.0   # the gyroscopes' (default: the accelerometers')
//! accelerometer_lag_ms = 0.0            # every accelerometer samples this long before its gyroscope
//!                                       # (the simulated recording declares it, as an array file's
//!                                       # accelerometer_lag_ms declares a real board's); within half
//!                                       # the sample interval
//! ```
//!
//! A `fixed` clock distribution takes `value`: one number for every package or one per package
//! of the array file. Phases are uniform over one clock period. The bias drift (`selfcal::drift`)
//! is linear in time about the recording's middle (the truth's bias is the one at mid-recording);
//! a `fixed` `bias_drift_ug_per_s` takes one value or one per accelerometer.
//!
//! The array is an array file (`[array] file = ...`; its ranges clip the simulated outputs), the
//! form is `tilt` (the parameters of `gfcal calibrate`), and `[noise]` gives the white noise of
//! one sample at the protocol's rate. Each trial draws its errors from `[errors]`, moves them onto
//! the gauge (`selfcal::simulate::project_to_gauge`), simulates a recording, calibrates it with
//! `selfcal::calibrate`, and records the Cramer-Rao bound at its truth on the samples the
//! calibration used.

use nalgebra::DVector;
use rand::Rng;
use serde::Deserialize;

use crate::array::wiring::RecordingArray;
use crate::calib::params::Layout;
use crate::calib::{Estimate, FitStatus};
use crate::config::{Bad, OneOrEach, finite, positive};
use crate::selfcal::calibrate::{CalibrateSettings, calibrate};
use crate::selfcal::drift::BiasDriftSpread;
use crate::selfcal::model::{PER_ACCEL, SensorSet};
use crate::selfcal::sampling::{ClockSpread, Spread};
use crate::selfcal::simulate::{
    AntiAlias, FINE_STEP_S, MAX_ACCELEROMETER_LAG_SAMPLES, MOTION_BAND_HZ, SensorBursts, VIBRATION_BAND_HZ, Vibration,
};
use crate::selfcal::simulate::{Protocol, bound_at_truth, drift_removal_variance_at_truth, project_to_gauge, simulate};
use crate::selfcal::vibration::LowPass;
use crate::units::M_S2_PER_UG;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProtocolSection {
    pub poses: usize,
    pub pose_up: Option<Vec<[f64; 3]>>,
    pub pose_s: f64,
    pub transition_s: f64,
    pub dynamic_s: f64,
    pub rate_rms_rad_s: f64,
    pub accel_rms_m_s2: f64,
    pub sample_rate_hz: f64,
    #[serde(default)]
    pub use_gyro: bool,
    #[serde(default)]
    pub remove_bias_drift: bool,
    pub gyro_noise_sigma_rad_s: Option<f64>,
    pub motion_band_hz: Option<[f64; 2]>,
    pub accel_band_hz: Option<[f64; 2]>,
    pub vibration_rms_m_s2: Option<f64>,
    pub vibration_rate_rms_rad_s: Option<f64>,
    pub vibration_band_hz: Option<[f64; 2]>,
    pub vibration_rate_exponent: Option<f64>,
    pub vibration_sensor_rms_m_s2: Option<f64>,
    pub vibration_sensor_rate_exponent: Option<f64>,
    pub vibration_sensor_burst_duty: Option<f64>,
    pub vibration_sensor_burst_s: Option<f64>,
    pub vibration_rate_band_hz: Option<[f64; 2]>,
    pub vibration_rate_low_pass_order: Option<u32>,
    pub vibration_low_pass_order: Option<u32>,
    #[serde(default)]
    pub sample_clocks: bool,
    pub clock_rate_offset_ppm: Option<ClockDist>,
    pub clock_common_rate_offset_ppm: Option<ClockDist>,
    pub clock_drift_ppm_per_s: Option<ClockDist>,
    pub bias_drift_ug_per_s: Option<ClockDist>,
    pub common_bias_drift_ug_per_s: Option<ClockDist>,
    pub anti_alias_time_constant_ms: Option<f64>,
    pub gyro_anti_alias_time_constant_ms: Option<f64>,
    pub accelerometer_lag_ms: Option<f64>,
}

/// The kind of a clock quantity's distribution (the `[errors]` section's kinds).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DistKind {
    Normal,
    Uniform,
    Fixed,
}

/// A distribution of a clock quantity: `normal` (mean, sigma), `uniform` (mean +- half_width) or
/// `fixed` (value: one for every package or one per package).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClockDist {
    pub dist: DistKind,
    pub mean: Option<f64>,
    pub sigma: Option<f64>,
    pub half_width: Option<f64>,
    pub value: Option<OneOrEach<f64>>,
}

impl ClockDist {
    /// The distribution in SI (`to_si` per display unit), for an array of `packages` packages.
    /// `each`: what a `fixed` list has one value per, and how many there are.
    fn resolve(&self, key: &str, to_si: f64, each: (&str, usize)) -> Result<Spread, Bad> {
        let (what, count) = each;
        let k = |s: &str| format!("{key}.{s}");
        let forbid = |name: &str, given: bool, kind: &str| {
            if given { Err(Bad::new(k(name), format!("does not apply to dist = \"{kind}\""))) } else { Ok(()) }
        };
        let non_negative = |name: &str, v: Option<f64>, kind: &str| -> Result<f64, Bad> {
            let v = v.ok_or_else(|| Bad::new(k(name), format!("is required for dist = \"{kind}\"")))?;
            if finite(&k(name), v)? < 0.0 {
                return Err(Bad::new(k(name), format!("must not be negative, got {v}")));
            }
            Ok(v * to_si)
        };
        let mean = finite(&k("mean"), self.mean.unwrap_or(0.0))? * to_si;
        match self.dist {
            DistKind::Normal => {
                forbid("half_width", self.half_width.is_some(), "normal")?;
                forbid("value", self.value.is_some(), "normal")?;
                Ok(Spread::Normal { mean, sigma: non_negative("sigma", self.sigma, "normal")? })
            }
            DistKind::Uniform => {
                forbid("sigma", self.sigma.is_some(), "uniform")?;
                forbid("value", self.value.is_some(), "uniform")?;
                Ok(Spread::Uniform { mean, half_width: non_negative("half_width", self.half_width, "uniform")? })
            }
            DistKind::Fixed => {
                for (name, given) in [
                    ("mean", self.mean.is_some()),
                    ("sigma", self.sigma.is_some()),
                    ("half_width", self.half_width.is_some()),
                ] {
                    forbid(name, given, "fixed")?;
                }
                let v = self.value.as_ref().ok_or_else(|| Bad::new(k("value"), "is required for dist = \"fixed\""))?;
                let values = match v {
                    OneOrEach::One(x) => vec![*x],
                    OneOrEach::Each(xs) if xs.len() == count => xs.clone(),
                    OneOrEach::Each(xs) => {
                        return Err(Bad::new(
                            k("value"),
                            format!("needs one value, or one per {what} of the array file ({count}), got {}", xs.len()),
                        ));
                    }
                };
                let mut out = Vec::with_capacity(values.len());
                for (i, x) in values.iter().enumerate() {
                    out.push(finite(&format!("{}[{i}]", k("value")), *x)? * to_si);
                }
                Ok(Spread::Fixed(out))
            }
        }
    }
}

/// A band `[lo, hi]` in Hz with `0 < lo < hi`.
fn band(key: &str, b: [f64; 2]) -> Result<[f64; 2], Bad> {
    let lo = positive(&format!("{key}[0]"), b[0])?;
    let hi = positive(&format!("{key}[1]"), b[1])?;
    if hi <= lo {
        return Err(Bad::new(key, format!("needs its lower corner below its upper, got [{lo}, {hi}]")));
    }
    Ok([lo, hi])
}

/// A vibration low-pass's order, 2 (the default, when absent) or 3.
fn low_pass(key: &str, order: Option<u32>) -> Result<LowPass, Bad> {
    match order {
        None => Ok(LowPass::Second),
        Some(o) => LowPass::from_order(o)
            .ok_or_else(|| Bad::new(key, format!("must be 2 or 3 (the order of the vibration's low-pass), got {o}"))),
    }
}

/// A non-negative finite value (0 when absent).
fn non_negative(key: &str, v: Option<f64>) -> Result<f64, Bad> {
    let v = finite(key, v.unwrap_or(0.0))?;
    if v < 0.0 {
        return Err(Bad::new(key, format!("must not be negative, got {v}")));
    }
    Ok(v)
}

impl ProtocolSection {
    /// `vibration_sensor_burst_duty` and `vibration_sensor_burst_s`, given together or not at all.
    fn sensor_bursts(&self) -> Result<Option<SensorBursts>, Bad> {
        let (duty_key, length_key) = ("protocol.vibration_sensor_burst_duty", "protocol.vibration_sensor_burst_s");
        match (self.vibration_sensor_burst_duty, self.vibration_sensor_burst_s) {
            (None, None) => Ok(None),
            (Some(_), None) => {
                Err(Bad::new(length_key, format!("is needed with {duty_key} (the bursts' mean length, s)")))
            }
            (None, Some(_)) => {
                Err(Bad::new(duty_key, format!("is needed with {length_key} (the share of time in bursts)")))
            }
            (Some(duty), Some(mean_s)) => {
                let duty = finite(duty_key, duty)?;
                if !(duty > 0.0 && duty <= 1.0) {
                    return Err(Bad::new(
                        duty_key,
                        format!("must be above 0 and at most 1 (a share of time), got {duty}"),
                    ));
                }
                Ok(Some(SensorBursts { duty, mean_s: positive(length_key, mean_s)? }))
            }
        }
    }
}

/// A checked protocol with its recording array.
#[derive(Debug, Clone)]
pub struct ProtocolCell {
    pub protocol: Protocol,
    pub array: RecordingArray,
    pub use_gyro: bool,
    /// Calibrate with `remove_bias_drift` (`selfcal::calibrate::CalibrateSettings`).
    pub remove_bias_drift: bool,
}

impl ProtocolSection {
    /// Checks the section; `noise_sigma_m_s2` is the white noise of one sample at its rate.
    pub fn resolve(
        &self,
        array: RecordingArray,
        noise_sigma_m_s2: f64,
        gravity_m_s2: f64,
    ) -> Result<ProtocolCell, Bad> {
        if self.poses < 4 {
            return Err(Bad::new(
                "protocol.poses",
                format!("a calibration needs at least 4 poses, got {}", self.poses),
            ));
        }
        let rate = positive("protocol.sample_rate_hz", self.sample_rate_hz)?;
        let pose_s = positive("protocol.pose_s", self.pose_s)?;
        // The segmentation keeps still runs of 5 s and trims 1 s from each end.
        if pose_s < 7.0 {
            return Err(Bad::new(
                "protocol.pose_s",
                format!(
                    "poses of {pose_s} s are too short: still runs of at least 7 s are found and trimmed (5 s + 2 x 1 s)"
                ),
            ));
        }
        let dynamic_s = positive("protocol.dynamic_s", self.dynamic_s)?;
        if dynamic_s < 10.0 {
            return Err(Bad::new(
                "protocol.dynamic_s",
                format!("a rotation phase of {dynamic_s} s is shorter than the 10 s the segmentation needs"),
            ));
        }
        if self.use_gyro && array.gyroscopes.is_empty() {
            return Err(Bad::new(
                "protocol.use_gyro",
                format!("the array file {} lists no reference gyroscopes", array.path.display()),
            ));
        }
        if noise_sigma_m_s2.is_nan() || noise_sigma_m_s2 <= 0.0 {
            return Err(Bad::new(
                "noise",
                "a protocol run needs white noise (the bound and the segmentation scale with it)",
            ));
        }
        let n = array.array.len();
        let gyro = match self.gyro_noise_sigma_rad_s {
            Some(v) => positive("protocol.gyro_noise_sigma_rad_s", v)?,
            None => 0.01,
        };
        let motion_band_hz = match self.motion_band_hz {
            Some(b) => band("protocol.motion_band_hz", b)?,
            None => MOTION_BAND_HZ,
        };
        let vibration = Vibration {
            accel_rms_m_s2: non_negative("protocol.vibration_rms_m_s2", self.vibration_rms_m_s2)?,
            rate_rms_rad_s: non_negative("protocol.vibration_rate_rms_rad_s", self.vibration_rate_rms_rad_s)?,
            band_hz: match self.vibration_band_hz {
                Some(b) => band("protocol.vibration_band_hz", b)?,
                None => VIBRATION_BAND_HZ,
            },
            rate_band_hz: self
                .vibration_rate_band_hz
                .map(|b| band("protocol.vibration_rate_band_hz", b))
                .transpose()?,
            low_pass: low_pass("protocol.vibration_low_pass_order", self.vibration_low_pass_order)?,
            rate_low_pass: low_pass("protocol.vibration_rate_low_pass_order", self.vibration_rate_low_pass_order)?,
            rate_exponent: non_negative("protocol.vibration_rate_exponent", self.vibration_rate_exponent)?,
            sensor_rms_m_s2: non_negative("protocol.vibration_sensor_rms_m_s2", self.vibration_sensor_rms_m_s2)?,
            sensor_rate_exponent: self
                .vibration_sensor_rate_exponent
                .map(|k| non_negative("protocol.vibration_sensor_rate_exponent", Some(k)))
                .transpose()?,
            sensor_bursts: self.sensor_bursts()?,
        };
        if vibration.sensor_bursts.is_some() {
            let key = "protocol.vibration_sensor_burst_duty";
            if vibration.sensor_rms_m_s2 == 0.0 {
                return Err(Bad::new(key, "has no effect without protocol.vibration_sensor_rms_m_s2 above 0"));
            }
            if vibration.sensor_rate_exponent.is_some() {
                return Err(Bad::new(
                    key,
                    "bursts at random times and protocol.vibration_sensor_rate_exponent (bursts at the fastest turns) are two envelopes of one error: give one",
                ));
            }
        }
        if let Some(k) = vibration.sensor_rate_exponent {
            // At twice the RMS rate the envelope is 2^k: 65,536 at 16, far past any burst wanted.
            if k > 16.0 {
                return Err(Bad::new(
                    "protocol.vibration_sensor_rate_exponent",
                    format!("must be at most 16 (the sensor error's RMS goes as the rate to this power), got {k}"),
                ));
            }
            if vibration.sensor_rms_m_s2 == 0.0 {
                return Err(Bad::new(
                    "protocol.vibration_sensor_rate_exponent",
                    "has no effect without protocol.vibration_sensor_rms_m_s2 above 0",
                ));
            }
        }
        if vibration.rate_exponent > 4.0 {
            return Err(Bad::new(
                "protocol.vibration_rate_exponent",
                format!(
                    "must be at most 4 (the vibration's RMS goes as the rate to this power), got {}",
                    vibration.rate_exponent
                ),
            ));
        }
        for (key, given) in [
            ("protocol.vibration_band_hz", self.vibration_band_hz.is_some()),
            ("protocol.vibration_rate_exponent", self.vibration_rate_exponent.is_some()),
            ("protocol.vibration_low_pass_order", self.vibration_low_pass_order.is_some()),
        ] {
            if given && !vibration.is_on() {
                return Err(Bad::new(
                    key,
                    "has no effect without protocol.vibration_rms_m_s2 or protocol.vibration_rate_rms_rad_s above 0",
                ));
            }
        }
        // The fine grid must resolve the vibration: ten steps a period at its upper corner.
        let top_hz = 0.1 / FINE_STEP_S;
        for (key, b) in [
            ("protocol.vibration_band_hz", Some(vibration.band_hz)),
            ("protocol.vibration_rate_band_hz", vibration.rate_band_hz),
        ] {
            if let Some(b) = b.filter(|b| vibration.is_on() && b[1] > top_hz) {
                return Err(Bad::new(
                    key,
                    format!(
                        "an upper corner of {} Hz is above the {top_hz} Hz the simulator's {} ms grid resolves",
                        b[1],
                        FINE_STEP_S * 1e3
                    ),
                ));
            }
        }
        for (key, given) in [
            ("protocol.vibration_rate_band_hz", self.vibration_rate_band_hz.is_some()),
            ("protocol.vibration_rate_low_pass_order", self.vibration_rate_low_pass_order.is_some()),
        ] {
            if given && vibration.rate_rms_rad_s == 0.0 {
                return Err(Bad::new(key, "has no effect without protocol.vibration_rate_rms_rad_s above 0"));
            }
        }
        let clocks = self.clocks(&array, rate)?;
        let accel_tau_ms = non_negative("protocol.anti_alias_time_constant_ms", self.anti_alias_time_constant_ms)?;
        let gyro_tau_ms = match self.gyro_anti_alias_time_constant_ms {
            Some(v) => non_negative("protocol.gyro_anti_alias_time_constant_ms", Some(v))?,
            None => accel_tau_ms,
        };
        let anti_alias =
            AntiAlias { accel_time_constant_s: accel_tau_ms * 1e-3, gyro_time_constant_s: gyro_tau_ms * 1e-3 };
        let accelerometer_lag_s = match self.accelerometer_lag_ms {
            None => 0.0,
            Some(ms) => {
                let key = "protocol.accelerometer_lag_ms";
                let half_interval_ms = MAX_ACCELEROMETER_LAG_SAMPLES * 1e3 / rate;
                if finite(key, ms)?.abs() > half_interval_ms {
                    return Err(Bad::new(
                        key,
                        format!(
                            "a lag of {ms} ms is beyond the {half_interval_ms} ms (half the sample interval) the simulator generates"
                        ),
                    ));
                }
                if ms != 0.0 && array.gyroscopes.is_empty() {
                    return Err(Bad::new(
                        key,
                        format!(
                            "the array file {} lists no gyroscopes for the accelerometers to lag",
                            array.path.display()
                        ),
                    ));
                }
                ms * 1e-3
            }
        };
        Ok(ProtocolCell {
            protocol: Protocol {
                poses: self.poses,
                pose_up: self.pose_up()?,
                pose_s,
                transition_s: positive("protocol.transition_s", self.transition_s)?,
                dynamic_s,
                rate_rms_rad_s: positive("protocol.rate_rms_rad_s", self.rate_rms_rad_s)?,
                accel_rms_m_s2: positive("protocol.accel_rms_m_s2", self.accel_rms_m_s2)?,
                motion_band_hz,
                accel_band_hz: self.accel_band_hz.map(|b| band("protocol.accel_band_hz", b)).transpose()?,
                sample_rate_hz: rate,
                noise_sigma_m_s2: vec![noise_sigma_m_s2; n],
                gyro_noise_sigma_rad_s: gyro,
                gravity_m_s2,
                vibration,
                clocks,
                anti_alias,
                bias_drift: self.bias_drift(n)?,
                accelerometer_lag_s,
                fine_step_s: FINE_STEP_S,
            },
            array,
            use_gyro: self.use_gyro,
            remove_bias_drift: self.remove_bias_drift,
        })
    }
}

impl ProtocolSection {
    /// The clocks' distributions, checked against the array file: `None` unless `sample_clocks`.
    /// The accelerometers' bias drift in time (`None` when neither key is given).
    /// The poses' up directions (unit vectors, array axes), one per pose in their order.
    fn pose_up(&self) -> Result<Option<Vec<nalgebra::Vector3<f64>>>, Bad> {
        let Some(ups) = &self.pose_up else { return Ok(None) };
        if ups.len() != self.poses {
            return Err(Bad::new(
                "protocol.pose_up",
                format!(
                    "lists {} directions for protocol.poses = {} (one per pose, in their order)",
                    ups.len(),
                    self.poses
                ),
            ));
        }
        let mut out = Vec::with_capacity(ups.len());
        for (i, u) in ups.iter().enumerate() {
            let key = format!("protocol.pose_up[{i}]");
            let v = nalgebra::Vector3::new(finite(&key, u[0])?, finite(&key, u[1])?, finite(&key, u[2])?);
            if v.norm() < 1e-6 {
                return Err(Bad::new(key, "is not a direction (zero length)"));
            }
            out.push(v.normalize());
        }
        Ok(Some(out))
    }

    /// `accelerometers`: how many the array file lists.
    fn bias_drift(&self, accelerometers: usize) -> Result<Option<BiasDriftSpread>, Bad> {
        if self.bias_drift_ug_per_s.is_none() && self.common_bias_drift_ug_per_s.is_none() {
            return Ok(None);
        }
        let resolve = |key: &str, d: &Option<ClockDist>, count: usize| match d {
            Some(d) => d.resolve(key, M_S2_PER_UG, ("accelerometer", count)),
            None => Ok(Spread::zero()),
        };
        Ok(Some(BiasDriftSpread {
            own: resolve("protocol.bias_drift_ug_per_s", &self.bias_drift_ug_per_s, accelerometers)?,
            common: resolve("protocol.common_bias_drift_ug_per_s", &self.common_bias_drift_ug_per_s, 1)?,
        }))
    }

    fn clocks(&self, array: &RecordingArray, host_rate_hz: f64) -> Result<Option<ClockSpread>, Bad> {
        let keys = [
            ("protocol.clock_rate_offset_ppm", self.clock_rate_offset_ppm.is_some()),
            ("protocol.clock_common_rate_offset_ppm", self.clock_common_rate_offset_ppm.is_some()),
            ("protocol.clock_drift_ppm_per_s", self.clock_drift_ppm_per_s.is_some()),
        ];
        if !self.sample_clocks {
            if let Some((key, _)) = keys.iter().find(|(_, given)| *given) {
                return Err(Bad::new(*key, "has no effect without protocol.sample_clocks = true"));
            }
            return Ok(None);
        }
        if !array.has_sample_clocks() {
            return Err(Bad::new(
                "protocol.sample_clocks",
                format!(
                    "the array file {} declares no package with `sample_clock_hz` and `sample_and_hold`",
                    array.path.display()
                ),
            ));
        }
        for (i, p) in array.packages.iter().enumerate() {
            if let (Some(f), true) = (p.sample_clock_hz, p.free_running())
                && f <= host_rate_hz
            {
                return Err(Bad::new(
                    "protocol.sample_clocks",
                    format!(
                        "package[{i}].sample_clock_hz = {f} of the array file {} is not above protocol.sample_rate_hz = {host_rate_hz}: the host would read some internal samples twice",
                        array.path.display()
                    ),
                ));
            }
        }
        let packages = array.packages.len();
        let ppm = 1e-6;
        let rate_offset = match &self.clock_rate_offset_ppm {
            Some(d) => d.resolve("protocol.clock_rate_offset_ppm", ppm, ("package", packages))?,
            None => Spread::Normal { mean: 0.0, sigma: DEFAULT_RATE_OFFSET_SIGMA_PPM * ppm },
        };
        let common_rate_offset = match &self.clock_common_rate_offset_ppm {
            Some(d) => d.resolve("protocol.clock_common_rate_offset_ppm", ppm, ("package", 1))?,
            None => Spread::zero(),
        };
        let drift_per_s = match &self.clock_drift_ppm_per_s {
            Some(d) => d.resolve("protocol.clock_drift_ppm_per_s", ppm, ("package", 1))?,
            None => Spread::zero(),
        };
        Ok(Some(ClockSpread { rate_offset, common_rate_offset, drift_per_s }))
    }
}

/// The packages' rate offset spread when `sample_clocks` is on and none is given, ppm: the
/// standard deviation of the MIMU4444's eight clocks (-2580 to +1270 ppm).
pub const DEFAULT_RATE_OFFSET_SIGMA_PPM: f64 = 1300.0;

/// Moves a sampled truth (tilt-form layout vector) onto the gauge the calibration estimates in.
pub fn truth_in_gauge(cell: &ProtocolCell, x: &DVector<f64>) -> DVector<f64> {
    let mut t = SensorSet::from_vector(x.as_slice());
    project_to_gauge(&cell.array.array, &mut t);
    DVector::from_vec(t.to_vector())
}

/// Simulates and calibrates one recording; the estimate (tilt form) and the Cramer-Rao sigma of
/// every parameter at the truth (NaN where the calibration failed), with `remove_bias_drift` the
/// removed drift's variance at the truth added to the scale factors', biases' and tilts'
/// (`selfcal::simulate::drift_removal_variance_at_truth`), as the calibration adds it to theirs.
pub fn calibrate_one<R: Rng + ?Sized>(
    cell: &ProtocolCell,
    layout: &Layout,
    x_true: &DVector<f64>,
    rng: &mut R,
) -> (Result<Estimate, String>, Vec<f64>) {
    let p = layout.len();
    let truth = SensorSet::from_vector(x_true.as_slice());
    let sim = match simulate(&cell.array, &truth, &cell.protocol, rng) {
        Ok(s) => s,
        Err(e) => return (Err(format!("simulation: {e}")), vec![f64::NAN; p]),
    };
    let settings = CalibrateSettings {
        use_gyro: cell.use_gyro,
        remove_bias_drift: cell.remove_bias_drift,
        ..CalibrateSettings::default()
    };
    let cal = match calibrate(&sim.recording, &cell.array, &settings) {
        Ok(c) => c,
        Err(e) => return (Err(format!("calibration: {e}")), vec![f64::NAN; p]),
    };
    let sigma = &cell.protocol.noise_sigma_m_s2;
    let g = cell.protocol.gravity_m_s2;
    // A calibration that takes the drift out carries the removed drift's variance in its scale
    // factors, biases and tilts: its bound is the joint model's plus that variance at the truth.
    // (Only where it took one out: too few poses for a fit without the rotation phase leave it in.)
    let removal = cal
        .removed_bias_drift
        .is_some()
        .then(|| drift_removal_variance_at_truth(&cell.array, &sim, &cal, &truth, sigma, g))
        .flatten();
    let added = |i: usize| match &removal {
        Some(v) if i % PER_ACCEL < 4 => v[i / PER_ACCEL][i % PER_ACCEL],
        _ => 0.0,
    };
    let crb: Vec<f64> = match bound_at_truth(&cell.array, &sim, &cal, &truth, sigma, g, cell.use_gyro) {
        Ok((cov, _)) => (0..p).map(|i| (cov[(i, i)] + added(i)).max(0.0).sqrt()).collect(),
        Err(_) => vec![f64::NAN; p],
    };
    let fit = &cal.fit;
    let x = DVector::from_vec(fit.params.to_vector());
    let covariance = fit.covariance.view((0, 0), (p, p)).clone_owned();
    let residual = fit.dynamic_residual_rms_m_s2.iter().copied().fold(0.0_f64, |a, b| a.max(b));
    let status = FitStatus {
        converged: fit.converged,
        iterations: fit.iterations,
        cost: f64::NAN,
        condition_number: f64::NAN,
        message: format!(
            "{} poses found; static chi2/dof {:.3}, dynamic chi2/dof {:.3}",
            cal.segmentation.static_intervals.len(),
            fit.static_chi2_dof,
            fit.dynamic_chi2_dof
        ),
    };
    debug_assert_eq!(p, PER_ACCEL * cell.array.array.len());
    let estimate = Estimate {
        form: layout.form(),
        params: layout.unpack(&x),
        x,
        covariance,
        residual_sigma_m_s2: residual,
        status,
    };
    (Ok(estimate), crb)
}
