//! Simulated free-calibration recordings: poses placed by hand in random directions (or listed
//! ones, [`Protocol::pose_up`]), each held still, carried to the next by a smooth rotation, then a
//! smooth random rotation phase. The
//! outputs come from the engine's own sensor model (`sensor::params::ArrayParams::outputs` on a
//! `motion::RigidMotion`), not from `selfcal::model`, so a fit of these recordings is checked
//! against an independent generator.
//!
//! **The real board's physics (issue 28), off by default.** A hand-held rotation phase also
//! carries broadband vibration ([`Vibration`]: a rigid translation of the board, and optionally a
//! small rigid angular vibration, from [`super::vibration`]) that reaches far above the Nyquist
//! frequency of the host's samples; each package samples its parts on its own free-running clock
//! and the host reads the latest sample ([`super::sampling`]); a first-order anti-alias filter may
//! sit before each part's internal sampling ([`AntiAlias`]). With any of them on, the motion is
//! integrated on a fine grid ([`Protocol::fine_step_s`], 0.1 ms: see [`FINE_STEP_S`]) and every part is
//! read at its package's own instant; with all of them off the recording is today's, bit for bit
//! (the same code, the same random draws). The accelerometers may sample a fixed time before
//! their gyroscopes ([`Protocol::accelerometer_lag_s`], on the fine grid). A bias drift in time
//! ([`super::drift`], off by default) is added to every accelerometer output after the motion.

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::{DMatrix, Quaternion, UnitQuaternion, Vector3};
use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use super::clock::SampleClock;
use super::data::StaticData;
use super::drift::{BiasDrift, BiasDriftSpread};
use super::model::{SampleMotion, SensorSet};
use super::recording::{Recording, RecordingError};
use super::sampling::{ClockSpread, FirstOrder, draw_clocks, last_tick_s};
use super::vibration::{BandNoise, Bank, LowPass, MAX_AXES, Sample};
use crate::array::wiring::RecordingArray;
use crate::io::table::Table;
use crate::motion::RigidMotion;
use crate::sensor::misalignment::{tilt_axis, tilt_basis};
use crate::sensor::params::{ArrayParams, SensorParams};

/// The protocol of a free calibration (seconds, rad/s, m/s^2, Hz).
#[derive(Debug, Clone, PartialEq)]
pub struct Protocol {
    pub poses: usize,
    /// The poses' up directions in array axes, in their order, taken again from the first if
    /// there are fewer than [`Self::poses`] (`None`: random directions; a config must list one per
    /// pose). A
    /// board placed by hand on the faces of a solid, in a fixed order, is not placed at random:
    /// the order decides how a bias drift in time aliases into the scale factors and tilts.
    pub pose_up: Option<Vec<Vector3<f64>>>,
    pub pose_s: f64,
    pub transition_s: f64,
    pub dynamic_s: f64,
    /// RMS angular rate of the rotation phase (all three axes together).
    pub rate_rms_rad_s: f64,
    /// RMS inertial acceleration of the origin in the rotation phase.
    pub accel_rms_m_s2: f64,
    /// The band of the rotation phase's motion: each axis of the rate and of the acceleration is
    /// three sinusoids of random frequency in it, Hz ([`MOTION_BAND_HZ`] unless a study needs
    /// faster motion: hand-held rotation has power up to the Nyquist frequency of 62.5 Hz samples).
    pub motion_band_hz: [f64; 2],
    /// The band of the acceleration's sinusoids alone, Hz (`None`: [`Protocol::motion_band_hz`]):
    /// a hand translates the board more slowly than it turns it.
    pub accel_band_hz: Option<[f64; 2]>,
    pub sample_rate_hz: f64,
    /// White noise of one sample, per accelerometer.
    pub noise_sigma_m_s2: Vec<f64>,
    /// White noise of one gyroscope sample.
    pub gyro_noise_sigma_rad_s: f64,
    pub gravity_m_s2: f64,
    /// Broadband vibration in the rotation phase (none by default).
    pub vibration: Vibration,
    /// The packages' own sample clocks, drawn per recording: every package whose array-file
    /// entry declares `sample_clock_hz` and `sample_and_hold` samples on its clock (`None`: every
    /// part is read at the host's instants).
    pub clocks: Option<ClockSpread>,
    /// Anti-alias filters before the parts' internal sampling (none by default).
    pub anti_alias: AntiAlias,
    /// The accelerometers' bias drift in time, drawn per recording ([`super::drift`]; `None`:
    /// constant biases).
    pub bias_drift: Option<BiasDriftSpread>,
    /// How long every accelerometer samples before its package's gyroscope, s (0: at the same
    /// instant): each accelerometer output is the motion [`Self::accelerometer_lag_s`] before the
    /// instant its gyroscope (or the host, where the package has no clock) samples. The real
    /// board's accelerometers lag their gyroscopes by about 1.5 ms (an array file's
    /// `accelerometer_lag_ms`, which `gfcal calibrate --use-gyro` corrects). Its magnitude must be
    /// below [`MAX_ACCELEROMETER_LAG_SAMPLES`] of the host's sample interval.
    pub accelerometer_lag_s: f64,
    /// The time step of the motion's integration when the vibration, the clocks, the filters or
    /// the accelerometers' lag are on, s ([`FINE_STEP_S`]).
    pub fine_step_s: f64,
}

/// The largest accelerometer lag the simulator generates, in host sample intervals: every
/// sample's parts are read in time order, one sample after another, so no part of a sample may
/// be read before any part of the one before (a package's age is below one of its ticks, much
/// shorter than the host's interval).
pub const MAX_ACCELEROMETER_LAG_SAMPLES: f64 = 0.5;

/// The default band of the rotation phase's motion, Hz.
pub const MOTION_BAND_HZ: [f64; 2] = [0.3, 2.0];

/// The fine grid's step, s. The shortest times that matter are the packages' tick period (1 ms
/// on the MIMU4444), the sample ages within it (a few hundred microseconds make the effect) and
/// the vibration's upper band (50-100 Hz, periods of 10-20 ms). On a 0.1 ms grid: (i) the
/// vibration's held drive is white to within 0.4 % up to 1/(10 h) = 1 kHz, well past its band,
/// and its state is carried exactly to any instant between grid points, so a package's tick is
/// read exactly, not rounded to the grid (rounding to 0.1 ms would misplace a sample by up to
/// 50 us: about 0.25 m/s^2 at the jerk of a few thousand m/s^3 the real board sees, six times
/// its noise); (ii) the attitude's RK4 step turns by at most 5 mrad at 50 rad/s, an error of
/// order (w h)^5 / 120, below 1e-13; (iii) an anti-alias filter's input, taken linear between
/// grid points, is off by about h^2 / 12 times the filtered signal's second derivative: at a
/// 1 ms time constant and that jerk, about 0.004 m/s^2, a tenth of the board's noise.
pub const FINE_STEP_S: f64 = 1e-4;

/// Broadband vibration of the hand-held board in the rotation phase (`super::vibration`): white
/// noise high-passed at `band_hz[0]` (first order) and low-passed at `band_hz[1]` (second-order
/// Butterworth), independent per axis, ramped in with the rotation. It is a rigid motion: the
/// translation is the board origin's acceleration in body axes (every point shares it), the
/// angular part adds to the body rate, with its exact angular acceleration.
#[derive(Debug, Clone, PartialEq)]
pub struct Vibration {
    /// RMS of the translational vibration, three axes together, m/s^2 (0: none).
    pub accel_rms_m_s2: f64,
    /// RMS of the angular vibration, three axes together, rad/s (0: none).
    pub rate_rms_rad_s: f64,
    /// Corners of the band, Hz.
    pub band_hz: [f64; 2],
    /// Corners of the angular vibration's band, Hz (`None`: `band_hz`).
    pub rate_band_hz: Option<[f64; 2]>,
    /// The order of the translational vibration's low-pass ([`super::vibration`]): the third
    /// takes the jerk's content above the corner down as `f^-4` (the second: `f^-2`).
    pub low_pass: LowPass,
    /// The order of the angular vibration's low-pass: the second leaves the angular jerk the
    /// fine grid's white drive, the third keeps it continuous and finite.
    pub rate_low_pass: LowPass,
    /// How the vibration follows the rotation's vigour: its RMS at an instant is the RMS above
    /// times `(|w_s| / rate_rms_rad_s)^k`, `w_s` the smooth rotation's rate (0: stationary). A
    /// hand shakes the board harder when it turns it faster; with `k > 0` the vibration is
    /// intermittent (heavy-tailed: rare peaks of several times its RMS) and the clocks' error
    /// grows with the rate, as on the real board.
    pub rate_exponent: f64,
    /// RMS of each accelerometer's own error under the vibration, one axis, m/s^2 (0: none): not
    /// a motion of the board (which every sensor sees through one rigid body) but an independent
    /// band-limited process per accelerometer (the translation's band, low-pass and envelope: its
    /// RMS goes with the rotation's rate as the translation's does), added to the accelerometer's
    /// output at its package's instant, after any anti-alias filter. A non-rigid misfit: no rigid
    /// body and no clock model can fit it, so it weighs on the estimates as noise, not as bias.
    pub sensor_rms_m_s2: f64,
    /// How the accelerometers' own error follows the rotation's vigour, as [`Self::rate_exponent`]
    /// does for the motion (`None`: the same exponent). A larger one puts that error in bursts at
    /// the fastest turns (the real board's misfit after the clocks sits in a few percent of the
    /// samples) without making the rigid vibration burstier.
    pub sensor_rate_exponent: Option<f64>,
    /// The accelerometers' own error in bursts at random times, whatever the motion (`None`: its
    /// envelope follows the rate, [`Self::sensor_rate_exponent`]).
    pub sensor_bursts: Option<SensorBursts>,
}

/// Bursts of the accelerometers' own error ([`Vibration::sensor_rms_m_s2`]) at random times: an
/// on/off process over the rotation phase (a two-state Markov chain in continuous time: bursts of
/// exponential length with mean `mean_s`, gaps of mean `mean_s (1 - duty) / duty`, the first state
/// on with probability `duty`), the same for every accelerometer (a knock or a grip shifting
/// moves the whole board's readings at once). While on, the error's RMS is
/// `sensor_rms_m_s2 / sqrt(duty)`, so that its RMS over the phase stays `sensor_rms_m_s2`; while
/// off it is zero. Its band is the translation's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorBursts {
    /// The share of the rotation phase's time the bursts are on, in (0, 1].
    pub duty: f64,
    /// Mean length of one burst, s.
    pub mean_s: f64,
}

impl SensorBursts {
    /// The bursts' intervals (start, end) in the rotation phase's time `[0, span_s]`, s.
    fn intervals<R: Rng + ?Sized>(&self, span_s: f64, rng: &mut R) -> Vec<(f64, f64)> {
        if self.duty >= 1.0 {
            return vec![(0.0, span_s)];
        }
        let gap_s = self.mean_s * (1.0 - self.duty) / self.duty;
        let mut on = Vec::new();
        let mut t = 0.0;
        let mut is_on = rng.random::<f64>() < self.duty;
        while t < span_s {
            // An exponential length by inversion (1 - u is in (0, 1]).
            let mean = if is_on { self.mean_s } else { gap_s };
            let end = t - mean * (1.0 - rng.random::<f64>()).ln();
            if is_on {
                on.push((t, end.min(span_s)));
            }
            t = end;
            is_on = !is_on;
        }
        on
    }
}

/// The default band of the vibration, Hz.
pub const VIBRATION_BAND_HZ: [f64; 2] = [2.0, 50.0];

impl Default for Vibration {
    fn default() -> Self {
        Self {
            accel_rms_m_s2: 0.0,
            rate_rms_rad_s: 0.0,
            band_hz: VIBRATION_BAND_HZ,
            rate_band_hz: None,
            low_pass: LowPass::Second,
            rate_low_pass: LowPass::Second,
            rate_exponent: 0.0,
            sensor_rms_m_s2: 0.0,
            sensor_rate_exponent: None,
            sensor_bursts: None,
        }
    }
}

impl Vibration {
    pub fn is_on(&self) -> bool {
        self.accel_rms_m_s2 > 0.0 || self.rate_rms_rad_s > 0.0 || self.sensor_rms_m_s2 > 0.0
    }
}

/// First-order anti-alias filters before the internal sampling of every part (accelerometers
/// and gyroscopes separately), time constants in s (0: none).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AntiAlias {
    pub accel_time_constant_s: f64,
    pub gyro_time_constant_s: f64,
}

impl AntiAlias {
    pub fn is_on(&self) -> bool {
        self.accel_time_constant_s > 0.0 || self.gyro_time_constant_s > 0.0
    }
}

impl Protocol {
    /// Whether the recording is today's smooth one, sampled at the host's instants.
    pub fn is_smooth(&self) -> bool {
        !self.vibration.is_on() && self.clocks.is_none() && !self.anti_alias.is_on() && self.accelerometer_lag_s == 0.0
    }

    /// The centre of the rotation phase, s: the clocks' reference instant.
    pub fn rotation_centre_s(&self) -> f64 {
        layout(self).rotation_start_s + 0.5 * self.dynamic_s
    }
}

/// A simulated recording with its truth.
#[derive(Debug, Clone)]
pub struct Simulated {
    pub recording: Recording,
    /// Up direction (array axes) at every sample; meaningful where the board is still.
    pub up: Vec<Vector3<f64>>,
    /// The motion at every sample (at the host's instant, less [`Protocol::accelerometer_lag_s`]:
    /// where the accelerometers of a package without a clock sample), in the form
    /// `selfcal::model` uses.
    pub motion: Vec<SampleMotion>,
    /// The time derivative of the specific force at the array origin in body axes (the jerk
    /// the sample clocks turn into output errors) at the instants of [`Self::motion`], m/s^3.
    pub jerk_m_s3: Vec<Vector3<f64>>,
    /// The truth of every package's sample clock (index into the array's packages; `None`
    /// where the package is read at the host's instants), phases at the rotation phase's centre.
    pub clocks: Vec<Option<SampleClock>>,
}

/// Random truth of the given sigmas, satisfying the gauge conditions of `selfcal::model`
/// (tilt rotation vectors sum to zero; location errors sum to zero and do not change the size).
pub fn random_truth<R: Rng + ?Sized>(
    array: &crate::array::Array,
    scale_sigma: f64,
    bias_sigma_m_s2: f64,
    tilt_sigma_rad: f64,
    location_sigma_m: f64,
    rng: &mut R,
) -> SensorSet {
    let n = array.len();
    let mut g = |s: f64| -> f64 { s * rng.sample::<f64, _>(StandardNormal) };
    let mut t = SensorSet::nominal(n);
    for j in 0..n {
        t.scale_factor[j] = 1.0 + g(scale_sigma);
        t.bias_m_s2[j] = g(bias_sigma_m_s2);
        t.tilt_rad[j] = [g(tilt_sigma_rad), g(tilt_sigma_rad)];
        t.location_error_m[j] = Vector3::new(g(location_sigma_m), g(location_sigma_m), g(location_sigma_m));
    }
    project_to_gauge(array, &mut t);
    t
}

/// Moves a truth `t` onto the gauge of `selfcal::model`, so that it is the representative the fit
/// estimates: the common rotation of the tilts is removed (least squares), then the mean location
/// error and the common scaling about the centroid.
pub fn project_to_gauge(array: &crate::array::Array, t: &mut SensorSet) {
    let n = array.len();
    // Rotation gauge: remove the common rotation (least squares over the tilts).
    let mut a = nalgebra::Matrix3::zeros();
    let mut b = Vector3::zeros();
    let bases: Vec<_> = array.accelerometers().iter().map(|acc| tilt_basis(&acc.axis)).collect();
    for (j, (u, w)) in bases.iter().enumerate() {
        let phi = w * t.tilt_rad[j][0] - u * t.tilt_rad[j][1];
        a += u * u.transpose() + w * w.transpose();
        b += phi;
    }
    let e = a.try_inverse().map(|ai| ai * b).unwrap_or_default();
    for (j, (u, w)) in bases.iter().enumerate() {
        t.tilt_rad[j][0] -= e.dot(w);
        t.tilt_rad[j][1] += e.dot(u);
    }
    // Translation and scale gauges.
    let groups = crate::selfcal::model::axis_groups(array);
    if groups.iter().any(|&g| g > 0) {
        project_locations_to_groups(array, &groups, t);
        return;
    }
    let mean: Vector3<f64> = t.location_error_m.iter().sum::<Vector3<f64>>() / n as f64;
    for d in &mut t.location_error_m {
        *d -= mean;
    }
    let centroid: Vector3<f64> = array.accelerometers().iter().map(|a| a.position_m).sum::<Vector3<f64>>() / n as f64;
    let rel: Vec<Vector3<f64>> = array.accelerometers().iter().map(|a| a.position_m - centroid).collect();
    let num: f64 = rel.iter().zip(&t.location_error_m).map(|(r, d)| r.dot(d)).sum();
    let den: f64 = rel.iter().map(|r| r.norm_squared()).sum();
    if den > 0.0 {
        for (d, r) in t.location_error_m.iter_mut().zip(&rel) {
            *d -= r * (num / den);
        }
    }
}

/// The translation and scale gauges of an array of several axis groups (`selfcal::model::Gauge`):
/// the location errors less their least-squares part in the span of every group's translation
/// and the scaling about the centroid (the fit's constraints hold exactly for the result).
fn project_locations_to_groups(array: &crate::array::Array, groups: &[usize], t: &mut SensorSet) {
    let n = array.len();
    let k = 3 * (groups.iter().max().map_or(0, |g| g + 1)) + 1;
    let centroid: Vector3<f64> = array.accelerometers().iter().map(|a| a.position_m).sum::<Vector3<f64>>() / n as f64;
    let mut basis = nalgebra::DMatrix::zeros(3 * n, k);
    for (j, (acc, &g)) in array.accelerometers().iter().zip(groups).enumerate() {
        let r = acc.position_m - centroid;
        for d in 0..3 {
            basis[(3 * j + d, 3 * g + d)] = 1.0;
            basis[(3 * j + d, k - 1)] = r[d];
        }
    }
    let x = nalgebra::DVector::from_fn(3 * n, |i, _| t.location_error_m[i / 3][i % 3]);
    let gram = basis.transpose() * &basis;
    let Some(c) = gram.pseudo_inverse(1e-12).ok().map(|g| g * (basis.transpose() * &x)) else { return };
    let projected = x - basis * c;
    for (j, d) in t.location_error_m.iter_mut().enumerate() {
        *d = Vector3::new(projected[3 * j], projected[3 * j + 1], projected[3 * j + 2]);
    }
}

/// The poses' attitudes (body to inertial): random, or with their up directions
/// [`Protocol::pose_up`] (each turned about the vertical by its random draw's heading: the same
/// draws either way).
fn pose_attitudes<R: Rng + ?Sized>(protocol: &Protocol, rng: &mut R) -> Vec<UnitQuaternion<f64>> {
    let drawn: Vec<UnitQuaternion<f64>> = (0..protocol.poses).map(|_| random_attitude(rng)).collect();
    let Some(ups) = &protocol.pose_up else { return drawn };
    drawn
        .iter()
        .zip(ups.iter().cycle())
        .map(|(q, up)| {
            // Body `up` to the inertial vertical, then the drawn attitude's heading about it.
            let level = UnitQuaternion::rotation_between(&up.normalize(), &Vector3::z())
                .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
            let x = q * Vector3::x();
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), x.y.atan2(x.x)) * level
        })
        .collect()
}

fn random_attitude<R: Rng + ?Sized>(rng: &mut R) -> UnitQuaternion<f64> {
    let mut g = || rng.sample::<f64, _>(StandardNormal);
    UnitQuaternion::from_quaternion(Quaternion::new(g(), g(), g(), g()))
}

/// Smooth random signal per axis: three sinusoids of random frequency (in a band, Hz) and phase,
/// with value and derivative.
struct Smooth {
    terms: Vec<[(f64, f64, f64); 3]>,
}

impl Smooth {
    fn new<R: Rng + ?Sized>(rms_total: f64, band_hz: [f64; 2], rng: &mut R) -> Self {
        // Three axes with three sinusoids each: amplitude a gives RMS a / sqrt(2) per sinusoid.
        let a = rms_total / (9.0_f64 / 2.0).sqrt();
        let terms = (0..3)
            .map(|_| {
                let mut t = [(0.0, 0.0, 0.0); 3];
                for x in &mut t {
                    *x = (
                        a,
                        2.0 * std::f64::consts::PI * rng.random_range(band_hz[0]..band_hz[1]),
                        rng.random_range(0.0..6.3),
                    );
                }
                t
            })
            .collect();
        Self { terms }
    }
    fn at(&self, t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let mut v = Vector3::zeros();
        let mut d = Vector3::zeros();
        for (k, axis) in self.terms.iter().enumerate() {
            for &(a, w, p) in axis {
                v[k] += a * (w * t + p).sin();
                d[k] += a * w * (w * t + p).cos();
            }
        }
        (v, d)
    }
}

/// Smooth ramp 0 -> 1 over `[0, 1]` and its derivative.
fn smoothstep(x: f64) -> (f64, f64) {
    let x = x.clamp(0.0, 1.0);
    (x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x))
}

/// The engine's sensor model of `array` with the `truth` parameters.
fn true_params(array: &RecordingArray, truth: &SensorSet) -> ArrayParams {
    let arr = &array.array;
    ArrayParams {
        sensors: (0..arr.len())
            .map(|j| SensorParams {
                scale_factor: truth.scale_factor[j],
                bias_m_s2: truth.bias_m_s2[j],
                axis: tilt_axis(&arr.accelerometers()[j].axis, &truth.tilt_rad[j]),
                location_error_m: truth.location_error_m[j],
            })
            .collect(),
    }
}

/// The jerk at the origin in body axes: `d/dt [R^T (a_i - g_i)] = R^T da_i/dt - w x f`, with `f`
/// the origin's specific force of `m` (body axes) and `da_i` the inertial acceleration's rate.
fn body_jerk(q: &UnitQuaternion<f64>, da_i: &Vector3<f64>, m: &RigidMotion) -> Vector3<f64> {
    let f = m.accel_b_m_s2 - m.gravity_b_m_s2;
    q.inverse() * da_i - m.omega_b_rad_s.cross(&f)
}

/// Simulates a recording of `array` with the `truth` parameters (see the module docs): today's
/// smooth recording when [`Protocol::is_smooth`], otherwise with the vibration, the packages'
/// clocks and their filters, on the fine grid.
pub fn simulate<R: Rng + ?Sized>(
    array: &RecordingArray,
    truth: &SensorSet,
    protocol: &Protocol,
    rng: &mut R,
) -> Result<Simulated, RecordingError> {
    let lag_s = protocol.accelerometer_lag_s;
    if !lag_s.is_finite() || lag_s.abs() > MAX_ACCELEROMETER_LAG_SAMPLES / protocol.sample_rate_hz {
        return Err(RecordingError::Unusable {
            path: std::path::PathBuf::from("simulated"),
            problem: format!(
                "an accelerometer lag of {lag_s} s is not within {MAX_ACCELEROMETER_LAG_SAMPLES} of the {} s sample interval",
                1.0 / protocol.sample_rate_hz
            ),
        });
    }
    if protocol.is_smooth() {
        simulate_smooth(array, truth, protocol, rng)
    } else {
        simulate_fine(array, truth, protocol, rng)
    }
}

/// The simulated table read as a recording of `array`, declaring the accelerometers' lag behind
/// the gyroscopes the simulator generated ([`Protocol::accelerometer_lag_s`]), not the array
/// file's (a real board's, for its real recordings).
fn simulated_recording(
    table: &Table,
    array: &RecordingArray,
    protocol: &Protocol,
) -> Result<Recording, RecordingError> {
    let mut recording = Recording::from_table(table, array)?;
    recording.accelerometer_lag_s = protocol.accelerometer_lag_s;
    Ok(recording)
}

/// Today's recording: the motion at the host's instants, every part read there.
fn simulate_smooth<R: Rng + ?Sized>(
    array: &RecordingArray,
    truth: &SensorSet,
    protocol: &Protocol,
    rng: &mut R,
) -> Result<Simulated, RecordingError> {
    let arr = &array.array;
    let n = arr.len();
    let params = true_params(array, truth);
    let dt = 1.0 / protocol.sample_rate_hz;
    let g_i = Vector3::new(0.0, 0.0, -protocol.gravity_m_s2);
    let attitudes = pose_attitudes(protocol, rng);
    let rate = Smooth::new(protocol.rate_rms_rad_s, protocol.motion_band_hz, rng);
    let accel = Smooth::new(protocol.accel_rms_m_s2, protocol.accel_band_hz.unwrap_or(protocol.motion_band_hz), rng);
    let ramp_s = 2.0;
    let mut t_s = Vec::new();
    let mut motions: Vec<RigidMotion> = Vec::new();
    let mut jerks: Vec<Vector3<f64>> = Vec::new();
    let mut t = 0.0;
    let mut push = |t: f64, m: RigidMotion, t_s: &mut Vec<f64>, jerk: Vector3<f64>| {
        t_s.push(t);
        motions.push(m);
        jerks.push(jerk);
    };
    let mut q = attitudes[0];
    for p in 0..protocol.poses {
        q = attitudes[p];
        let end = t + protocol.pose_s;
        while t < end - 1e-9 {
            push(
                t,
                RigidMotion::from_inertial(&q, &Vector3::zeros(), &Vector3::zeros(), &Vector3::zeros(), &g_i),
                &mut t_s,
                Vector3::zeros(),
            );
            t += dt;
        }
        if p + 1 < protocol.poses {
            let rel = attitudes[p].inverse() * attitudes[p + 1];
            let (axis, angle) = rel.axis_angle().map(|(a, g)| (a.into_inner(), g)).unwrap_or((Vector3::z(), 0.0));
            let start = t;
            let end = t + protocol.transition_s;
            while t < end - 1e-9 {
                let x = (t - start) / protocol.transition_s;
                let (s, ds) = smoothstep(x);
                let dds = (6.0 - 12.0 * x) / protocol.transition_s.powi(2);
                let qt = attitudes[p] * UnitQuaternion::from_scaled_axis(axis * (angle * s));
                let omega = axis * (angle * ds / protocol.transition_s);
                let alpha = axis * (angle * dds);
                let m = RigidMotion::from_inertial(&qt, &Vector3::zeros(), &omega, &alpha, &g_i);
                push(t, m, &mut t_s, body_jerk(&qt, &Vector3::zeros(), &m));
                t += dt;
            }
        }
    }
    // Rotation phase: rate and acceleration ramped in from rest; attitude by RK4 on substeps.
    let start = t;
    let phase = |tau: f64| -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let (e, de) = smoothstep(tau / ramp_s);
        let de = de / ramp_s;
        let (w, dw) = rate.at(tau);
        let (a, _) = accel.at(tau);
        (w * e, dw * e + w * de, a * e)
    };
    let sub = 16;
    let h = dt / sub as f64;
    let qdot = |q: &UnitQuaternion<f64>, w: &Vector3<f64>| q.quaternion() * Quaternion::from_imag(*w) * 0.5;
    while t < start + protocol.dynamic_s - 1e-9 {
        let tau = t - start;
        let (w, al, a) = phase(tau);
        let m = RigidMotion::from_inertial(&q, &a, &w, &al, &g_i);
        let da = {
            let (e, de) = smoothstep(tau / ramp_s);
            let (a, da) = accel.at(tau);
            da * e + a * (de / ramp_s)
        };
        push(t, m, &mut t_s, body_jerk(&q, &da, &m));
        for k in 0..sub {
            let t0 = tau + k as f64 * h;
            let k1 = qdot(&q, &phase(t0).0);
            let q2 = UnitQuaternion::from_quaternion(q.quaternion() + k1 * (h / 2.0));
            let k2 = qdot(&q2, &phase(t0 + h / 2.0).0);
            let q3 = UnitQuaternion::from_quaternion(q.quaternion() + k2 * (h / 2.0));
            let k3 = qdot(&q3, &phase(t0 + h / 2.0).0);
            let q4 = UnitQuaternion::from_quaternion(q.quaternion() + k3 * h);
            let k4 = qdot(&q4, &phase(t0 + h).0);
            q = UnitQuaternion::from_quaternion(q.quaternion() + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0));
        }
        t += dt;
    }
    let rows = t_s.len();
    let mut outputs = DMatrix::zeros(rows, n);
    let mut buf = vec![0.0; n];
    let drift = bias_drift(protocol, n, &t_s, rng);
    for (i, m) in motions.iter().enumerate() {
        params.outputs(arr, m, &mut buf);
        for j in 0..n {
            let noisy =
                drift.added(j, t_s[i], buf[j]) + protocol.noise_sigma_m_s2[j] * rng.sample::<f64, _>(StandardNormal);
            outputs[(i, j)] = noisy.clamp(-array.ranges_m_s2[j], array.ranges_m_s2[j]);
        }
    }
    let mut names = vec![array.time_column.clone()];
    let mut data = vec![t_s.clone()];
    for (j, c) in array.accelerometer_columns.iter().enumerate() {
        names.push(c.clone());
        data.push(outputs.column(j).iter().copied().collect());
    }
    for gy in &array.gyroscopes {
        names.push(gy.column.clone());
        data.push(
            motions
                .iter()
                .map(|m| {
                    let v = gy.axis.dot(&m.omega_b_rad_s)
                        + protocol.gyro_noise_sigma_rad_s * rng.sample::<f64, _>(StandardNormal);
                    v.clamp(-gy.range_rad_s, gy.range_rad_s)
                })
                .collect(),
        );
    }
    let table =
        Table { path: std::path::PathBuf::from("simulated"), first_null_row: vec![None; names.len()], names, data };
    let recording = simulated_recording(&table, array, protocol)?;
    let up = motions.iter().map(|m| -m.gravity_b_m_s2.normalize()).collect();
    let motion = motions
        .iter()
        .map(|m| SampleMotion {
            f_m_s2: m.accel_b_m_s2 - m.gravity_b_m_s2,
            alpha_rad_s2: m.alpha_b_rad_s2,
            omega_rad_s: m.omega_b_rad_s,
        })
        .collect();
    Ok(Simulated { recording, up, motion, jerk_m_s3: jerks, clocks: vec![None; array.packages.len()] })
}

/// One stretch of the protocol in continuous time.
#[derive(Debug, Clone, Copy)]
enum Segment {
    /// Still in pose `p` from `start_s`.
    Pose { p: usize, start_s: f64 },
    /// Carried from pose `p` to pose `p + 1` from `start_s`, for the protocol's `transition_s`.
    Transition { p: usize, start_s: f64 },
    /// The rotation phase from `start_s`.
    Rotation { start_s: f64 },
}

impl Segment {
    fn start_s(&self) -> f64 {
        match *self {
            Segment::Pose { start_s, .. } | Segment::Transition { start_s, .. } | Segment::Rotation { start_s } => {
                start_s
            }
        }
    }
}

/// The host's sample instants and the protocol's segments, laid out exactly as today's
/// generator lays them out (the same sums of the sample interval).
struct Layout {
    t_s: Vec<f64>,
    segments: Vec<Segment>,
    rotation_start_s: f64,
}

fn layout(protocol: &Protocol) -> Layout {
    let dt = 1.0 / protocol.sample_rate_hz;
    let mut t_s = Vec::new();
    let mut segments = Vec::new();
    let mut t = 0.0;
    for p in 0..protocol.poses {
        segments.push(Segment::Pose { p, start_s: t });
        let end = t + protocol.pose_s;
        while t < end - 1e-9 {
            t_s.push(t);
            t += dt;
        }
        if p + 1 < protocol.poses {
            segments.push(Segment::Transition { p, start_s: t });
            let end = t + protocol.transition_s;
            while t < end - 1e-9 {
                t_s.push(t);
                t += dt;
            }
        }
    }
    let start = t;
    segments.push(Segment::Rotation { start_s: start });
    while t < start + protocol.dynamic_s - 1e-9 {
        t_s.push(t);
        t += dt;
    }
    Layout { t_s, segments, rotation_start_s: start }
}

/// The rigid motion at an instant and the jerk at the origin (body axes).
#[derive(Debug, Clone, Copy)]
struct Kinematics {
    motion: RigidMotion,
    jerk_m_s3: Vector3<f64>,
}

/// The rotation phase on the fine grid `t_n = start + n h`: the attitude at grid point `n` (RK4
/// from the last pose's attitude), the body rate there, and the vibration's state.
struct Spin {
    n: i64,
    q: UnitQuaternion<f64>,
    omega_n: Vector3<f64>,
    bank: Option<Bank>,
    /// The angular vibration's own process when its band differs from the translation's (then
    /// `bank` holds the translation alone).
    angular_bank: Option<Bank>,
    /// RMS per axis of the translational and the angular vibration (the bank's axes 0-2 and
    /// 3-5 when both are on; a single one uses axes 0-2; with an angular bank, its axes 0-2).
    accel_axis_rms: f64,
    rate_axis_rms: f64,
    /// The accelerometers' own errors ([`Vibration::sensor_rms_m_s2`]): accelerometer `j` is axis
    /// `j % MAX_AXES` of bank `j / MAX_AXES` (empty when off).
    sensor_banks: Vec<Bank>,
    /// Where [`Vibration::sensor_bursts`] is set, the root of its duty and the bursts' intervals
    /// in the rotation phase's time (s, in order).
    sensor_bursts_s: Option<(f64, Vec<(f64, f64)>)>,
}

/// The vibration's processes sampled at one instant: `bank` and `angular_bank` of [`Spin`].
type Pair = (Sample, Sample);

const ZERO_SAMPLE: Sample = [(0.0, 0.0); super::vibration::MAX_AXES];

/// The whole protocol's motion at any instant: poses, transitions (analytic) and the rotation
/// phase on its fine grid, evaluated forward in time only.
struct Hand<'a> {
    protocol: &'a Protocol,
    attitudes: &'a [UnitQuaternion<f64>],
    /// Axis and angle of every transition (from pose `p` to `p + 1`, body axes of pose `p`).
    turns: Vec<(Vector3<f64>, f64)>,
    segments: &'a [Segment],
    rate: &'a Smooth,
    accel: &'a Smooth,
    g_i: Vector3<f64>,
    start_s: f64,
    h: f64,
    spin: Spin,
}

/// The rotation phase's ramp from rest, s.
const RAMP_S: f64 = 2.0;

fn qdot(q: &Quaternion<f64>, w: &Vector3<f64>) -> Quaternion<f64> {
    q * Quaternion::from_imag(*w) * 0.5
}

/// One RK4 step of the attitude over `h`, the rate at its start, middle and end given.
fn rk4(
    q: &UnitQuaternion<f64>,
    w0: &Vector3<f64>,
    wm: &Vector3<f64>,
    w1: &Vector3<f64>,
    h: f64,
) -> UnitQuaternion<f64> {
    let q0 = q.quaternion();
    let k1 = qdot(q0, w0);
    let k2 = qdot(&(q0 + k1 * (h / 2.0)), wm);
    let k3 = qdot(&(q0 + k2 * (h / 2.0)), wm);
    let k4 = qdot(&(q0 + k3 * h), w1);
    UnitQuaternion::from_quaternion(q0 + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0))
}

impl Hand<'_> {
    /// The vibration's translational and angular parts (value, derivative) from the banks'
    /// samples.
    fn split(&self, pair: &Pair) -> [(Vector3<f64>, Vector3<f64>); 2] {
        let (s, sa) = (&pair.0, &pair.1);
        let v = |k: usize, rms: f64| -> (Vector3<f64>, Vector3<f64>) {
            (Vector3::new(s[k].0, s[k + 1].0, s[k + 2].0) * rms, Vector3::new(s[k].1, s[k + 1].1, s[k + 2].1) * rms)
        };
        let zero = (Vector3::zeros(), Vector3::zeros());
        let (a, r) = (self.spin.accel_axis_rms, self.spin.rate_axis_rms);
        if self.spin.angular_bank.is_some() {
            let ang = (Vector3::new(sa[0].0, sa[1].0, sa[2].0) * r, Vector3::new(sa[0].1, sa[1].1, sa[2].1) * r);
            return [if a > 0.0 { v(0, a) } else { zero }, ang];
        }
        match (a > 0.0, r > 0.0) {
            (true, true) => [v(0, a), v(3, r)],
            (true, false) => [v(0, a), zero],
            (false, true) => [zero, v(0, r)],
            (false, false) => [zero, zero],
        }
    }

    /// Body rate and angular acceleration `tau` seconds into the rotation phase, with the angular
    /// vibration `ang` (value, derivative) there.
    fn rate_at(&self, tau: f64, ang: &(Vector3<f64>, Vector3<f64>)) -> (Vector3<f64>, Vector3<f64>) {
        let (e, de) = smoothstep(tau / RAMP_S);
        let de = de / RAMP_S;
        let (w, dw) = self.rate.at(tau);
        let (g, dg) = self.envelope(tau, e, de);
        (w * e + ang.0 * g, dw * e + w * de + ang.1 * g + ang.0 * dg)
    }

    /// The vibration's envelope `tau` seconds into the rotation phase and its time derivative:
    /// the ramp `e` times `(|w_s|^2 + (rate_rms / 20)^2)^(k / 2) / rate_rms^k`, `w_s` the smooth
    /// rotation's rate and `k` [`Vibration::rate_exponent`] (1 when `k` is 0).
    fn envelope(&self, tau: f64, e: f64, de: f64) -> (f64, f64) {
        self.envelope_with(self.protocol.vibration.rate_exponent, tau, e, de)
    }

    /// [`Self::envelope`] with the exponent `k` given.
    fn envelope_with(&self, k: f64, tau: f64, e: f64, de: f64) -> (f64, f64) {
        if k == 0.0 {
            return (e, de);
        }
        let rms = self.protocol.rate_rms_rad_s;
        let (w, dw) = self.rate.at(tau);
        let m2 = w.norm_squared() + (rms / 20.0).powi(2);
        let g = (m2 / (rms * rms)).powf(0.5 * k);
        // d/dt of (m2 / rms^2)^(k/2) = k g (w . dw) / m2
        let dg = k * g * w.dot(&dw) / m2;
        (e * g, de * g + e * dg)
    }

    /// Both banks through `f` (zero where a bank is absent).
    fn sample(&self, f: impl Fn(&Bank) -> Sample) -> Pair {
        let s = self.spin.bank.as_ref().map_or(ZERO_SAMPLE, &f);
        let sa = self.spin.angular_bank.as_ref().map_or(ZERO_SAMPLE, &f);
        (s, sa)
    }

    /// Advances the rotation's grid by one step (attitude by RK4, the vibration exactly).
    fn step<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let h = self.h;
        let tau0 = self.spin.n as f64 * h;
        let (half, next) = (self.sample(Bank::half), self.sample(Bank::next));
        let wm = self.rate_at(tau0 + 0.5 * h, &self.split(&half)[1]).0;
        let w1 = self.rate_at(tau0 + h, &self.split(&next)[1]).0;
        self.spin.q = rk4(&self.spin.q, &self.spin.omega_n, &wm, &w1, h);
        if let Some(b) = self.spin.bank.as_mut() {
            b.advance(rng);
        }
        if let Some(b) = self.spin.angular_bank.as_mut() {
            b.advance(rng);
        }
        for b in &mut self.spin.sensor_banks {
            b.advance(rng);
        }
        self.spin.n += 1;
        self.spin.omega_n = w1;
    }

    /// The motion at grid index `m` plus `d` seconds (`0 <= d <= h`) of the rotation phase.
    fn spin_at<R: Rng + ?Sized>(&mut self, m: i64, d: f64, rng: &mut R) -> Kinematics {
        while self.spin.n < m {
            self.step(rng);
        }
        let h = self.h;
        let tau0 = self.spin.n as f64 * h;
        let tau = tau0 + d;
        let (now, mid) = if d > 0.0 {
            (self.sample(|b| b.after(d)), self.sample(|b| b.after(0.5 * d)))
        } else {
            let now = self.sample(Bank::now);
            (now, now)
        };
        let [trans, ang] = self.split(&now);
        let (omega, alpha) = self.rate_at(tau, &ang);
        let q = if d > 0.0 {
            let wm = self.rate_at(tau0 + 0.5 * d, &self.split(&mid)[1]).0;
            rk4(&self.spin.q, &self.spin.omega_n, &wm, &omega, d)
        } else {
            self.spin.q
        };
        let (e, de) = smoothstep(tau / RAMP_S);
        let de = de / RAMP_S;
        let (a, da) = self.accel.at(tau);
        let (a_i, da_i) = (a * e, da * e + a * de);
        let mut motion = RigidMotion::from_inertial(&q, &a_i, &omega, &alpha, &self.g_i);
        let (g, dg) = self.envelope(tau, e, de);
        // the smooth part's jerk (its inertial acceleration seen from the turning body), then the
        // vibration's, which is given in body axes: its own derivative, not turned by w
        let smooth_jerk = body_jerk(&q, &da_i, &motion);
        motion.accel_b_m_s2 += trans.0 * g;
        let jerk = smooth_jerk + trans.1 * g + trans.0 * dg;
        Kinematics { motion, jerk_m_s3: jerk }
    }

    /// Adds every accelerometer's own error ([`Vibration::sensor_rms_m_s2`]) at grid index `m`
    /// plus `d` seconds to `out` (the outputs; the rotation's grid already at `m`, as
    /// [`Self::at`] leaves it). Zero before the rotation phase.
    fn add_sensor_errors(&self, m: i64, d: f64, out: &mut [f64]) {
        if m < 0 || self.spin.sensor_banks.is_empty() {
            return;
        }
        let tau = m as f64 * self.h + d;
        let (e, de) = smoothstep(tau / RAMP_S);
        let vibration = &self.protocol.vibration;
        let g = match &self.spin.sensor_bursts_s {
            Some((root_duty, on)) => {
                let k = on.partition_point(|iv| iv.1 <= tau);
                if on.get(k).is_some_and(|iv| iv.0 <= tau) { e / root_duty } else { 0.0 }
            }
            None => {
                let k = vibration.sensor_rate_exponent.unwrap_or(vibration.rate_exponent);
                self.envelope_with(k, tau, e, de / RAMP_S).0
            }
        };
        let scale = g * vibration.sensor_rms_m_s2;
        if scale == 0.0 {
            // Between bursts: nothing to add (and no process to evaluate).
            return;
        }
        // The banks are one process (the translation's band and low-pass), so they share the
        // transition over `d`.
        let transition = self.spin.sensor_banks[0].transition_over(d);
        for (b, bank) in self.spin.sensor_banks.iter().enumerate() {
            let s = bank.after_with(transition.as_ref());
            for (k, v) in s.iter().enumerate() {
                if let Some(o) = out.get_mut(b * MAX_AXES + k) {
                    *o += scale * v.0;
                }
            }
        }
    }

    /// The motion at `t = start + m h + d` (the rotation's grid, extended back over the poses).
    fn at<R: Rng + ?Sized>(&mut self, m: i64, d: f64, rng: &mut R) -> Kinematics {
        if m >= 0 {
            return self.spin_at(m, d, rng);
        }
        let t = self.start_s + m as f64 * self.h + d;
        let k = self.segments.partition_point(|s| s.start_s() <= t).saturating_sub(1);
        let rest = |q: &UnitQuaternion<f64>, g_i: &Vector3<f64>| Kinematics {
            motion: RigidMotion::from_inertial(q, &Vector3::zeros(), &Vector3::zeros(), &Vector3::zeros(), g_i),
            jerk_m_s3: Vector3::zeros(),
        };
        match self.segments[k] {
            Segment::Pose { p, .. } => rest(&self.attitudes[p], &self.g_i),
            Segment::Transition { p, start_s } => {
                let span = self.protocol.transition_s;
                let x = (t - start_s) / span;
                if x >= 1.0 {
                    return rest(&self.attitudes[p + 1], &self.g_i);
                }
                let (axis, angle) = self.turns[p];
                let (s, ds) = smoothstep(x);
                let dds = if x > 0.0 { (6.0 - 12.0 * x) / span.powi(2) } else { 0.0 };
                let qt = self.attitudes[p] * UnitQuaternion::from_scaled_axis(axis * (angle * s));
                let omega = axis * (angle * ds / span);
                let alpha = axis * (angle * dds);
                let motion = RigidMotion::from_inertial(&qt, &Vector3::zeros(), &omega, &alpha, &self.g_i);
                Kinematics { motion, jerk_m_s3: body_jerk(&qt, &Vector3::zeros(), &motion) }
            }
            // t < start never reaches the rotation segment
            Segment::Rotation { .. } => self.spin_at(0, 0.0, rng),
        }
    }

    /// The grid index and offset of instant `t`.
    fn grid(&self, t: f64) -> (i64, f64) {
        let x = (t - self.start_s) / self.h;
        let m = x.floor() as i64;
        let d = ((t - self.start_s) - m as f64 * self.h).clamp(0.0, self.h);
        (m, d)
    }

    /// Whether `t` lies in a pose at least `settle_s` after its start.
    fn settled(&self, t: f64, settle_s: f64) -> Option<usize> {
        if t >= self.start_s {
            return None;
        }
        let k = self.segments.partition_point(|s| s.start_s() <= t).saturating_sub(1);
        match self.segments[k] {
            Segment::Pose { start_s, .. } if t - start_s > settle_s => Some(k),
            _ => None,
        }
    }
}

/// One recording's bias drift ([`super::drift`]), drawn here when the protocol has one (no draw otherwise: a recording without it is today's, bit for bit).
fn bias_drift<R: Rng + ?Sized>(protocol: &Protocol, n: usize, t_s: &[f64], rng: &mut R) -> BiasDrift {
    let rates = match &protocol.bias_drift {
        Some(spread) => spread.draw(n, rng),
        None => vec![],
    };
    BiasDrift::new(rates, t_s)
}

/// The noise-free outputs of every accelerometer (first) and reference gyroscope (after) in a
/// motion.
fn signals(array: &RecordingArray, params: &ArrayParams, m: &RigidMotion, out: &mut [f64]) {
    let n = array.array.len();
    params.outputs(&array.array, m, &mut out[..n]);
    for (g, gy) in array.gyroscopes.iter().enumerate() {
        out[n + g] = gy.axis.dot(&m.omega_b_rad_s);
    }
}

/// The recording with the vibration, the packages' clocks and their filters on: the motion on
/// the fine grid, every part read at its package's own instant (the latest tick at or before
/// the host's instant), through its filter.
fn simulate_fine<R: Rng + ?Sized>(
    array: &RecordingArray,
    truth: &SensorSet,
    protocol: &Protocol,
    rng: &mut R,
) -> Result<Simulated, RecordingError> {
    let arr = &array.array;
    let n = arr.len();
    let gyros = array.gyroscopes.len();
    let params = true_params(array, truth);
    let g_i = Vector3::new(0.0, 0.0, -protocol.gravity_m_s2);
    // The same draws as today's, in the same order, then the new ones.
    let attitudes = pose_attitudes(protocol, rng);
    let rate = Smooth::new(protocol.rate_rms_rad_s, protocol.motion_band_hz, rng);
    let accel = Smooth::new(protocol.accel_rms_m_s2, protocol.accel_band_hz.unwrap_or(protocol.motion_band_hz), rng);
    let lay = layout(protocol);
    let centre_s = lay.rotation_start_s + 0.5 * protocol.dynamic_s;
    let clocks: Vec<Option<SampleClock>> = match &protocol.clocks {
        Some(spread) => draw_clocks(&array.packages, spread, centre_s, rng),
        None => vec![None; array.packages.len()],
    };
    let h = protocol.fine_step_s;
    let vib = &protocol.vibration;
    let accel_axis_rms = vib.accel_rms_m_s2.max(0.0) / 3f64.sqrt();
    let rate_axis_rms = vib.rate_rms_rad_s.max(0.0) / 3f64.sqrt();
    let noise = |band: [f64; 2], low_pass: LowPass| {
        BandNoise::with_low_pass(band, 1.0, h, low_pass).ok_or_else(|| RecordingError::Unusable {
            path: std::path::PathBuf::from("simulated"),
            problem: format!("vibration band {band:?} Hz with a {h} s step is not usable"),
        })
    };
    // The angular vibration has its own process when its band or its low-pass differs.
    let rate_band = vib.rate_band_hz.unwrap_or(vib.band_hz);
    let separate = rate_axis_rms > 0.0 && (rate_band != vib.band_hz || vib.rate_low_pass != vib.low_pass);
    let shared = if separate { 0.0 } else { rate_axis_rms };
    let axes = 3 * (usize::from(accel_axis_rms > 0.0) + usize::from(shared > 0.0));
    let bank = if axes > 0 { Some(Bank::start(noise(vib.band_hz, vib.low_pass)?, axes, rng)) } else { None };
    let angular_bank = if separate { Some(Bank::start(noise(rate_band, vib.rate_low_pass)?, 3, rng)) } else { None };
    let mut sensor_banks = Vec::new();
    if vib.sensor_rms_m_s2 > 0.0 {
        for first in (0..n).step_by(MAX_AXES) {
            sensor_banks.push(Bank::start(noise(vib.band_hz, vib.low_pass)?, (n - first).min(MAX_AXES), rng));
        }
    }
    // Drawn last, and only when set, so that the draws above stay as they were without it.
    let sensor_bursts_s = vib
        .sensor_bursts
        .filter(|_| vib.sensor_rms_m_s2 > 0.0)
        .map(|b| (b.duty.sqrt(), b.intervals(protocol.dynamic_s + RAMP_S, rng)));
    let turns = (0..protocol.poses.saturating_sub(1))
        .map(|p| {
            let rel = attitudes[p].inverse() * attitudes[p + 1];
            rel.axis_angle().map(|(a, g)| (a.into_inner(), g)).unwrap_or((Vector3::z(), 0.0))
        })
        .collect();
    let last = attitudes.last().copied().unwrap_or_else(UnitQuaternion::identity);
    let mut hand = Hand {
        protocol,
        attitudes: &attitudes,
        turns,
        segments: &lay.segments,
        rate: &rate,
        accel: &accel,
        g_i,
        start_s: lay.rotation_start_s,
        h,
        spin: Spin {
            n: 0,
            q: last,
            omega_n: Vector3::zeros(),
            bank,
            angular_bank,
            accel_axis_rms,
            rate_axis_rms,
            sensor_banks,
            sensor_bursts_s,
        },
    };
    // Who reads each part: its package when that package has a clock, otherwise the host.
    const HOST: usize = usize::MAX;
    let owner = |p: Option<usize>| p.filter(|&p| clocks.get(p).is_some_and(Option::is_some)).unwrap_or(HOST);
    let acc_owner: Vec<usize> = (0..n).map(|j| owner(array.package_of.get(j).copied().flatten())).collect();
    let gyro_owner: Vec<usize> = array.gyroscopes.iter().map(|g| owner(g.package)).collect();
    // Anti-alias filters on the fine grid (the rotation's grid extended back over the poses).
    let aa = &protocol.anti_alias;
    let taus: Vec<f64> = (0..n)
        .map(|_| aa.accel_time_constant_s.max(0.0))
        .chain((0..gyros).map(|_| aa.gyro_time_constant_s.max(0.0)))
        .collect();
    let settle_s = 40.0 * taus.iter().cloned().fold(0.0, f64::max);
    let mut buf = vec![0.0; n + gyros];
    let mut filter: Option<(FirstOrder, i64)> = if aa.is_on() {
        let first = lay.t_s.first().copied().unwrap_or(0.0) - 2.0 * h - 1.0 / protocol.sample_rate_hz;
        let (m0, _) = hand.grid(first);
        let k = hand.at(m0, 0.0, rng);
        signals(array, &params, &k.motion, &mut buf);
        Some((FirstOrder::at_rest(taus, &buf), m0))
    } else {
        None
    };
    let rows = lay.t_s.len();
    let mut clean = DMatrix::zeros(rows, n);
    let mut clean_gyro = vec![vec![0.0; rows]; gyros];
    let mut motions: Vec<RigidMotion> = Vec::with_capacity(rows);
    let mut jerks: Vec<Vector3<f64>> = Vec::with_capacity(rows);
    // Each reader's instant and the parts it reads there: with a lag the accelerometers read
    // `lag` before their gyroscopes (two events), without one both at once (one event, today's).
    const ACCELEROMETERS: u8 = 1;
    const GYROSCOPES: u8 = 2;
    let lag_s = protocol.accelerometer_lag_s;
    let mut events: Vec<(f64, usize, u8)> = Vec::with_capacity(2 * (array.packages.len() + 1));
    let push = |events: &mut Vec<(f64, usize, u8)>, te: f64, who: usize| {
        if lag_s == 0.0 {
            events.push((te, who, ACCELEROMETERS | GYROSCOPES));
        } else {
            events.push((te - lag_s, who, ACCELEROMETERS));
            events.push((te, who, GYROSCOPES));
        }
    };
    for (i, &t) in lay.t_s.iter().enumerate() {
        events.clear();
        push(&mut events, t, HOST);
        for (p, c) in clocks.iter().enumerate() {
            if let Some(c) = c {
                push(&mut events, last_tick_s(c, t), p);
            }
        }
        events.sort_by(|a, b| a.0.total_cmp(&b.0));
        for &(te, who, parts) in &events {
            let (m, d) = hand.grid(te);
            // the filters are moved through every grid point up to the event
            if let Some((f, fm)) = filter.as_mut() {
                while *fm < m {
                    let pose = hand.settled(hand.start_s + *fm as f64 * h, settle_s);
                    if pose.is_some() && hand.settled(te, settle_s) == pose {
                        // still in the same pose, long after its start: the filters sit at its
                        // constant input
                        let k = hand.at(m, 0.0, rng);
                        signals(array, &params, &k.motion, &mut buf);
                        f.rest(&buf);
                        *fm = m;
                        break;
                    }
                    let next = *fm + 1;
                    let k = hand.at(next, 0.0, rng);
                    signals(array, &params, &k.motion, &mut buf);
                    f.advance(h, &buf);
                    *fm = next;
                }
            }
            let k = hand.at(m, d, rng);
            signals(array, &params, &k.motion, &mut buf);
            if let Some((f, fm)) = filter.as_ref() {
                let since = te - (hand.start_s + *fm as f64 * h);
                for (j, v) in buf.iter_mut().enumerate() {
                    *v = f.peek(j, since, *v);
                }
            }
            if parts & ACCELEROMETERS != 0 {
                hand.add_sensor_errors(m, d, &mut buf[..n]);
            }
            if parts & ACCELEROMETERS != 0 {
                for j in 0..n {
                    if acc_owner[j] == who {
                        clean[(i, j)] = buf[j];
                    }
                }
            }
            if parts & GYROSCOPES != 0 {
                for g in 0..gyros {
                    if gyro_owner[g] == who {
                        clean_gyro[g][i] = buf[n + g];
                    }
                }
            }
            // the truth is the motion where the host's accelerometers sample
            if who == HOST && parts & ACCELEROMETERS != 0 {
                motions.push(k.motion);
                jerks.push(k.jerk_m_s3);
            }
        }
    }
    // Noise in today's order: every sample's accelerometers, then each gyroscope's samples.
    let mut outputs = DMatrix::zeros(rows, n);
    let drift = bias_drift(protocol, n, &lay.t_s, rng);
    for i in 0..rows {
        for j in 0..n {
            let noisy = drift.added(j, lay.t_s[i], clean[(i, j)])
                + protocol.noise_sigma_m_s2[j] * rng.sample::<f64, _>(StandardNormal);
            outputs[(i, j)] = noisy.clamp(-array.ranges_m_s2[j], array.ranges_m_s2[j]);
        }
    }
    let mut names = vec!["t_s".to_string()];
    let mut data = vec![lay.t_s.clone()];
    for (j, c) in array.accelerometer_columns.iter().enumerate() {
        names.push(c.clone());
        data.push(outputs.column(j).iter().copied().collect());
    }
    for (g, gy) in array.gyroscopes.iter().enumerate() {
        names.push(gy.column.clone());
        data.push(
            clean_gyro[g]
                .iter()
                .map(|&v| {
                    let v = v + protocol.gyro_noise_sigma_rad_s * rng.sample::<f64, _>(StandardNormal);
                    v.clamp(-gy.range_rad_s, gy.range_rad_s)
                })
                .collect(),
        );
    }
    let table =
        Table { path: std::path::PathBuf::from("simulated"), first_null_row: vec![None; names.len()], names, data };
    let recording = simulated_recording(&table, array, protocol)?;
    let up = motions.iter().map(|m| -m.gravity_b_m_s2.normalize()).collect();
    let motion = motions
        .iter()
        .map(|m| SampleMotion {
            f_m_s2: m.accel_b_m_s2 - m.gravity_b_m_s2,
            alpha_rad_s2: m.alpha_b_rad_s2,
            omega_rad_s: m.omega_b_rad_s,
        })
        .collect();
    Ok(Simulated { recording, up, motion, jerk_m_s3: jerks, clocks })
}

/// The true up direction of each static interval of `seg` (at its middle sample).
fn true_static_up(sim: &Simulated, seg: &super::segment::Segmentation) -> Vec<Vector3<f64>> {
    seg.static_intervals.iter().map(|iv| sim.up[(iv.start + iv.end) / 2]).collect()
}

/// The variance that a bias drift taken out before the calibration (`CalibrateSettings::
/// remove_bias_drift`) adds to each accelerometer's `(k, b, tilt_u, tilt_w)` at the truth of a
/// simulated recording: [`super::static_drift::StaticDrift::added_variance`] of the drift check on
/// the truth's noise-free static means at the true poses of the calibration's static intervals,
/// for white noise of `noise_sigma_m_s2` (the refit lands on the truth, so its information is the
/// bound's). `None` where the check cannot be made (fewer than 6 poses).
pub fn drift_removal_variance_at_truth(
    array: &RecordingArray,
    sim: &Simulated,
    cal: &super::calibrate::Calibration,
    truth: &SensorSet,
    noise_sigma_m_s2: &[f64],
    gravity_m_s2: f64,
) -> Option<Vec<[f64; 4]>> {
    let seg = &cal.segmentation;
    let up = true_static_up(sim, seg);
    let sens = super::model::sensors(&array.array, truth);
    let means = DMatrix::from_fn(up.len(), sens.len(), |p, j| sens[j].output(&(up[p] * gravity_m_s2)));
    let stat = StaticData {
        means,
        counts: seg.static_intervals.iter().map(|iv| iv.len()).collect(),
        sigma: noise_sigma_m_s2.to_vec(),
    };
    let (static_t_s, t_mid_s) = super::static_drift::static_times(&sim.recording.t_s, &seg.static_intervals);
    let d = super::static_drift::static_drift_at(&array.array, &stat, truth, &up, &static_t_s, t_mid_s, gravity_m_s2)?;
    Some((0..sens.len()).map(|j| [0, 1, 2, 3].map(|p| d.added_variance(j, p))).collect())
}

/// The Cramer-Rao bound in the gauge at the truth of a simulated recording, on the samples the
/// calibration `cal` used (its static intervals and dynamic samples), for white noise of
/// `noise_sigma_m_s2` per sample and accelerometer; with `use_gyro`, the rate taken as known (the
/// gyroscopes'). Where the calibration modelled the packages' sample clocks, each sample's timing
/// motion is eliminated too, at the true clocks' relative ages. Also returns the Fisher
/// information's null directions before the gauge.
pub fn bound_at_truth(
    array: &RecordingArray,
    sim: &Simulated,
    cal: &super::calibrate::Calibration,
    truth: &SensorSet,
    noise_sigma_m_s2: &[f64],
    gravity_m_s2: f64,
    use_gyro: bool,
) -> Result<(nalgebra::DMatrix<f64>, usize), super::fit::FitError> {
    let seg = &cal.segmentation;
    let counts: Vec<usize> = seg.static_intervals.iter().map(|iv| iv.len()).collect();
    let up = true_static_up(sim, seg);
    let prepared = super::calibrate::prepare_dynamic(&sim.recording, seg, use_gyro, Some(Vector3::zeros()));
    let mut dynamic = prepared.data;
    if let (Some(d), true) = (dynamic.as_mut(), use_gyro) {
        d.reference_rate_rad_s = Some(prepared.index.iter().map(|&i| sim.motion[i].omega_rad_s).collect());
    }
    let motion: Vec<SampleMotion> = prepared.index.iter().map(|&i| sim.motion[i]).collect();
    let package_of = array.package_indices();
    let ages = match (&dynamic, cal.clocks.is_some()) {
        (Some(d), true) => Some(super::timing::accelerometer_ages(d, &sim.clocks, &package_of)),
        _ => None,
    };
    super::fit::cramer_rao(
        &array.array,
        &counts,
        noise_sigma_m_s2,
        &up,
        dynamic.as_ref(),
        &motion,
        truth,
        gravity_m_s2,
        ages.as_ref(),
    )
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::SensorBursts;

    /// The bursts' schedule against the on/off chain's closed forms, over 100,000 s: the share of
    /// time on is the duty, and a burst's mean length `mean_s` (its own sampling error over about
    /// 20,000 bursts: 0.7% for the length, 0.2 points for the share); the intervals are in order
    /// and within the span; a duty of 1 is one burst over the whole span.
    #[test]
    fn the_bursts_are_on_for_their_duty_in_bursts_of_their_mean_length() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (span_s, b) = (1e5, SensorBursts { duty: 0.2, mean_s: 1.0 });
        let on = b.intervals(span_s, &mut rng);
        let total_s: f64 = on.iter().map(|iv| iv.1 - iv.0).sum();
        let share = total_s / span_s;
        let mean_s = total_s / on.len() as f64;
        assert!((share - 0.2).abs() < 0.01, "share {share}");
        assert!((mean_s - 1.0).abs() < 0.04, "mean length {mean_s} s over {} bursts", on.len());
        assert!(on.windows(2).all(|w| w[0].1 < w[1].0) && on.iter().all(|iv| iv.0 < iv.1 && iv.1 <= span_s));
        let whole = SensorBursts { duty: 1.0, mean_s: 1.0 }.intervals(30.0, &mut rng);
        assert_eq!(whole, vec![(0.0, 30.0)]);
    }
}
