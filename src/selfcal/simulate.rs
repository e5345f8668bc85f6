//! Simulated free-calibration recordings: poses placed by hand in random directions, each held
//! still, carried to the next by a smooth rotation, then a smooth random rotation phase. The
//! outputs come from the engine's own sensor model (`sensor::params::ArrayParams::outputs` on a
//! `motion::RigidMotion`), not from `selfcal::model`, so a fit of these recordings is checked
//! against an independent generator.

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::{DMatrix, Quaternion, UnitQuaternion, Vector3};
use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use super::model::{SampleMotion, SensorSet};
use super::recording::{Recording, RecordingArray, RecordingError};
use crate::io::table::Table;
use crate::motion::RigidMotion;
use crate::sensor::misalignment::{tilt_axis, tilt_basis};
use crate::sensor::params::{ArrayParams, SensorParams};

/// The protocol of a free calibration (seconds, rad/s, m/s^2, Hz).
#[derive(Debug, Clone, PartialEq)]
pub struct Protocol {
    pub poses: usize,
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
    pub sample_rate_hz: f64,
    /// White noise of one sample, per accelerometer.
    pub noise_sigma_m_s2: Vec<f64>,
    /// White noise of one gyroscope sample.
    pub gyro_noise_sigma_rad_s: f64,
    pub gravity_m_s2: f64,
}

/// The default band of the rotation phase's motion, Hz.
pub const MOTION_BAND_HZ: [f64; 2] = [0.3, 2.0];

/// A simulated recording with its truth.
#[derive(Debug, Clone)]
pub struct Simulated {
    pub recording: Recording,
    /// Up direction (array axes) at every sample; meaningful where the board is still.
    pub up: Vec<Vector3<f64>>,
    /// The motion at every sample, in the form `selfcal::model` uses.
    pub motion: Vec<SampleMotion>,
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

/// Simulates a recording of `array` with the `truth` parameters (see the module docs).
pub fn simulate<R: Rng + ?Sized>(
    array: &RecordingArray,
    truth: &SensorSet,
    protocol: &Protocol,
    rng: &mut R,
) -> Result<Simulated, RecordingError> {
    let arr = &array.array;
    let n = arr.len();
    let params = ArrayParams {
        sensors: (0..n)
            .map(|j| SensorParams {
                scale_factor: truth.scale_factor[j],
                bias_m_s2: truth.bias_m_s2[j],
                axis: tilt_axis(&arr.accelerometers()[j].axis, &truth.tilt_rad[j]),
                location_error_m: truth.location_error_m[j],
            })
            .collect(),
    };
    let dt = 1.0 / protocol.sample_rate_hz;
    let g_i = Vector3::new(0.0, 0.0, -protocol.gravity_m_s2);
    let attitudes: Vec<UnitQuaternion<f64>> = (0..protocol.poses).map(|_| random_attitude(rng)).collect();
    let rate = Smooth::new(protocol.rate_rms_rad_s, protocol.motion_band_hz, rng);
    let accel = Smooth::new(protocol.accel_rms_m_s2, protocol.motion_band_hz, rng);
    let ramp_s = 2.0;
    let mut t_s = Vec::new();
    let mut motions: Vec<RigidMotion> = Vec::new();
    let mut t = 0.0;
    let mut push = |t: f64, m: RigidMotion, t_s: &mut Vec<f64>| {
        t_s.push(t);
        motions.push(m);
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
                push(t, RigidMotion::from_inertial(&qt, &Vector3::zeros(), &omega, &alpha, &g_i), &mut t_s);
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
        push(t, RigidMotion::from_inertial(&q, &a, &w, &al, &g_i), &mut t_s);
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
    for (i, m) in motions.iter().enumerate() {
        params.outputs(arr, m, &mut buf);
        for j in 0..n {
            let noisy = buf[j] + protocol.noise_sigma_m_s2[j] * rng.sample::<f64, _>(StandardNormal);
            outputs[(i, j)] = noisy.clamp(-array.ranges_m_s2[j], array.ranges_m_s2[j]);
        }
    }
    let mut names = vec!["t_s".to_string()];
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
    let recording = Recording::from_table(&table, array)?;
    let up = motions.iter().map(|m| -m.gravity_b_m_s2.normalize()).collect();
    let motion = motions
        .iter()
        .map(|m| SampleMotion {
            f_m_s2: m.accel_b_m_s2 - m.gravity_b_m_s2,
            alpha_rad_s2: m.alpha_b_rad_s2,
            omega_rad_s: m.omega_b_rad_s,
        })
        .collect();
    Ok(Simulated { recording, up, motion })
}

/// The Cramer-Rao bound in the gauge at the truth of a simulated recording, on the samples the
/// calibration `cal` used (its static intervals and dynamic samples), for white noise of
/// `noise_sigma_m_s2` per sample and accelerometer; with `use_gyro`, the rate taken as known (the
/// gyroscopes'). Also returns the Fisher information's null directions before the gauge.
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
    let up: Vec<_> = seg.static_intervals.iter().map(|iv| sim.up[(iv.start + iv.end) / 2]).collect();
    let prepared = super::calibrate::prepare_dynamic(&sim.recording, seg, use_gyro, Some(Vector3::zeros()));
    let mut dynamic = prepared.data;
    if let (Some(d), true) = (dynamic.as_mut(), use_gyro) {
        d.reference_rate_rad_s = Some(prepared.index.iter().map(|&i| sim.motion[i].omega_rad_s).collect());
    }
    let motion: Vec<SampleMotion> = prepared.index.iter().map(|&i| sim.motion[i]).collect();
    super::fit::cramer_rao(&array.array, &counts, noise_sigma_m_s2, &up, dynamic.as_ref(), &motion, truth, gravity_m_s2)
}
