//! Held-out prediction: a calibration of one recording applied to another recording of the same
//! array, with only what must differ between recordings refitted there (the pose directions of
//! the static intervals and the motion of every dynamic sample). The residuals against the
//! noise say whether the calibration carries over.

use nalgebra::Vector3;

use super::calibrate::{prepare_dynamic, static_data};
use super::fit::DynamicData;
use super::model::{SensorSet, sensors};
use super::recording::Recording;
use super::segment::{DetectorSettings, segment};
use super::track;
use crate::array::Array;
use crate::sensor::misalignment::tilt_basis;

/// Residuals of a held-out recording.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOut {
    pub static_intervals: usize,
    /// RMS over intervals and accelerometers of the static mean's residual, m/s^2.
    pub static_residual_rms_m_s2: f64,
    /// RMS of the static mean's noise, `sigma_j / sqrt(n_p)`, m/s^2.
    pub static_noise_rms_m_s2: f64,
    /// `sum (r / (sigma_j / sqrt(n_p)))^2 / (N P - 2 P)`.
    pub static_chi2_dof: f64,
    pub dynamic_samples: usize,
    /// RMS of the dynamic residuals, m/s^2, against the per-sample static noise RMS.
    pub dynamic_residual_rms_m_s2: f64,
    pub dynamic_noise_rms_m_s2: f64,
}

/// Predicts `rec` with `params` (see the module docs).
pub fn predict(
    array: &Array,
    params: &SensorSet,
    rec: &Recording,
    detector: &DetectorSettings,
    gravity_m_s2: f64,
) -> Result<HeldOut, super::recording::RecordingError> {
    let seg = segment(rec, detector)?;
    let stat = static_data(rec, &seg.static_intervals);
    let sens = sensors(array, params);
    let n = array.len();
    let mut ss = 0.0;
    let mut noise = 0.0;
    let mut chi2 = 0.0;
    for p in 0..stat.means.nrows() {
        // Pose direction only: Gauss-Newton on two tangent angles.
        let normal: nalgebra::Matrix3<f64> = sens.iter().map(|s| s.axis * s.axis.transpose()).sum();
        let b: Vector3<f64> =
            sens.iter().enumerate().map(|(j, s)| s.axis * (stat.means[(p, j)] / s.k - s.b_m_s2)).sum();
        let mut u = normal.try_inverse().map(|m| m * b).unwrap_or_else(Vector3::z).normalize();
        for _ in 0..20 {
            let (e1, e2) = tilt_basis(&u);
            let mut h = nalgebra::Matrix2::zeros();
            let mut g = nalgebra::Vector2::zeros();
            for (j, s) in sens.iter().enumerate() {
                let w = stat.counts[p] as f64 / stat.sigma[j].powi(2);
                let r = stat.means[(p, j)] - s.output(&(u * gravity_m_s2));
                let d =
                    nalgebra::Vector2::new(s.k * gravity_m_s2 * s.axis.dot(&e1), s.k * gravity_m_s2 * s.axis.dot(&e2));
                h += d * d.transpose() * w;
                g += d * (w * r);
            }
            let Some(step) = h.try_inverse().map(|hi| hi * g) else { break };
            u = (u + e1 * step[0] + e2 * step[1]).normalize();
            if step.norm() < 1e-12 {
                break;
            }
        }
        for (j, s) in sens.iter().enumerate() {
            let r = stat.means[(p, j)] - s.output(&(u * gravity_m_s2));
            let sd = stat.sigma[j] / (stat.counts[p] as f64).sqrt();
            ss += r * r;
            noise += sd * sd;
            chi2 += (r / sd).powi(2);
        }
    }
    let count = (stat.means.nrows() * n) as f64;
    let prepared = prepare_dynamic(rec, &seg, false, None);
    let (dyn_rms, dyn_noise, dyn_samples) = match prepared.data.as_ref() {
        Some(d) => dynamic_residual(array, params, d, &stat.sigma),
        None => (f64::NAN, f64::NAN, 0),
    };
    Ok(HeldOut {
        static_intervals: stat.means.nrows(),
        static_residual_rms_m_s2: (ss / count).sqrt(),
        static_noise_rms_m_s2: (noise / count).sqrt(),
        static_chi2_dof: chi2 / (count - 2.0 * stat.means.nrows() as f64).max(1.0),
        dynamic_samples: dyn_samples,
        dynamic_residual_rms_m_s2: dyn_rms,
        dynamic_noise_rms_m_s2: dyn_noise,
    })
}

fn dynamic_residual(array: &Array, params: &SensorSet, d: &DynamicData, sigma: &[f64]) -> (f64, f64, usize) {
    let weights: Vec<f64> = sigma.iter().map(|s| 1.0 / (s * s)).collect();
    let motion = track::from_scratch(array, d, &weights, params);
    let sens = sensors(array, params);
    let n = array.len();
    let mut ss = 0.0;
    let mut noise = 0.0;
    let mut count = 0.0;
    for (i, m) in motion.iter().enumerate() {
        for (j, s) in sens.iter().enumerate() {
            if d.used[i * n + j] {
                ss += (d.outputs[(i, j)] - s.output(&m.specific_force_m_s2(&s.position_m))).powi(2);
                noise += sigma[j] * sigma[j];
                count += 1.0;
            }
        }
    }
    ((ss / count).sqrt(), (noise / count).sqrt(), d.samples())
}
