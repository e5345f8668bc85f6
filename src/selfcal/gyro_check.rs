//! The gyroscope-free rate of a calibration checked against the reference gyroscopes: the
//! gyroscopes' bias from the static intervals, and the RMS difference overall, by rate, after the
//! best rotation between the frames and at the best lag.

use nalgebra::Vector3;

use super::lag::rates_behind;
use super::model::SampleMotion;
use super::recording::Recording;
use super::segment::Segmentation;

/// The gyroscope-free rate against the reference gyroscopes (bias-corrected from the static
/// intervals, and read at the accelerometers' instants where the array file declares their lag:
/// `w - L alpha`, `selfcal::lag`), over dynamic samples where no gyroscope clipped.
#[derive(Debug, Clone, PartialEq)]
pub struct GyroCheck {
    pub samples: usize,
    pub rms_rad_s: f64,
    /// RMS difference over the RMS reference rate.
    pub relative: f64,
    pub rms_reference_rad_s: f64,
    /// The same after the best rotation between the two frames (Kabsch), and that rotation's angle.
    pub aligned_rms_rad_s: f64,
    pub frame_rotation_rad: f64,
    /// Median of |gyroscope-free| / |reference| (a scale error of the rate shows here).
    pub median_magnitude_ratio: f64,
    /// `(low, high, samples, rms_rad_s, relative)` by reference rate, rad/s.
    pub by_rate: Vec<(f64, f64, usize, f64, f64)>,
    /// The lag of the accelerometers behind the gyroscopes that best aligns the two rates (the
    /// gyroscopes' rate taken at `t - lag` by a band-limited fractional delay; searched over
    /// +-[`LAG_SEARCH_S`] in steps of [`LAG_STEP_S`], from the gyroscopes as recorded, whatever lag the
    /// array file declares), and the RMS difference at it.
    pub accelerometer_lag_s: f64,
    pub rms_at_lag_rad_s: f64,
}

/// The lag search of [`GyroCheck`]: half-width and step, s.
pub const LAG_SEARCH_S: f64 = 5e-3;
pub const LAG_STEP_S: f64 = 1e-4;

/// Gyroscope bias (array axes): the mean reference rate over the static intervals.
pub fn gyro_bias(rec: &Recording, seg: &Segmentation) -> Option<Vector3<f64>> {
    (!rec.gyro_rate_rad_s.is_empty()).then(|| {
        let mut s = Vector3::zeros();
        let mut c = 0.0;
        for iv in &seg.static_intervals {
            for i in iv.start..iv.end {
                s += rec.gyro_rate_rad_s[i];
                c += 1.0;
            }
        }
        if c > 0.0 { s / c } else { s }
    })
}

/// The gyroscope-free rate `motion` (at the dynamic samples `index` of `rec`) against the
/// reference gyroscopes less `bias` (see [`GyroCheck`]).
pub(super) fn gyro_check(rec: &Recording, index: &[usize], motion: &[SampleMotion], bias: &Vector3<f64>) -> GyroCheck {
    // The gyroscopes at the accelerometers' instants, `accelerometer_lag_s` earlier, to first
    // order from the fitted angular acceleration (`selfcal::lag`): the rates compared are the
    // same instant's.
    let at_accelerometers = rates_behind(rec, index, bias, motion);
    // (dynamic sample, recording row) where no gyroscope clipped
    let used: Vec<(usize, usize)> =
        index.iter().enumerate().filter(|(_, i)| !rec.gyro_clipped[**i]).map(|(k, &i)| (k, i)).collect();
    let pairs: Vec<(Vector3<f64>, Vector3<f64>)> =
        used.iter().map(|&(k, _)| (motion[k].omega_rad_s, at_accelerometers[k])).collect();
    let rms = |v: &[(Vector3<f64>, Vector3<f64>)]| {
        let d = (v.iter().map(|(a, b)| (a - b).norm_squared()).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let r = (v.iter().map(|(_, b)| b.norm_squared()).sum::<f64>() / v.len().max(1) as f64).sqrt();
        (d, r)
    };
    let (d, r) = rms(&pairs);
    // Kabsch: the rotation R minimising sum |R a - b|^2.
    let cross: nalgebra::Matrix3<f64> = pairs.iter().map(|(a, b)| b * a.transpose()).sum();
    let svd = cross.svd(true, true);
    let (rot, angle) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => {
            let mut dmat = nalgebra::Matrix3::identity();
            dmat[(2, 2)] = (u * vt).determinant().signum();
            let rot = u * dmat * vt;
            let angle = ((rot.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
            (rot, angle)
        }
        _ => (nalgebra::Matrix3::identity(), f64::NAN),
    };
    let aligned: Vec<_> = pairs.iter().map(|(a, b)| (rot * a, *b)).collect();
    let (ad, _) = rms(&aligned);
    let mut ratios: Vec<f64> = pairs.iter().filter(|(_, b)| b.norm() > 1.0).map(|(a, b)| a.norm() / b.norm()).collect();
    ratios.sort_by(f64::total_cmp);
    let median_magnitude_ratio = ratios.get(ratios.len() / 2).copied().unwrap_or(f64::NAN);
    let edges = [0.0, 5.0, 10.0, 20.0, 30.0, f64::INFINITY];
    let by_rate = edges
        .windows(2)
        .map(|e| {
            let sel: Vec<_> = pairs.iter().filter(|(_, b)| b.norm() >= e[0] && b.norm() < e[1]).cloned().collect();
            let (d, r) = rms(&sel);
            (e[0], e[1], sel.len(), d, d / r)
        })
        .collect();
    // The lag: the gyroscopes' rate delayed by `lag` against the same gyroscope-free rate.
    let dt =
        if rec.t_s.len() > 1 { (rec.t_s[rec.t_s.len() - 1] - rec.t_s[0]) / (rec.t_s.len() - 1) as f64 } else { 0.0 };
    let columns: Vec<Vec<f64>> = (0..3).map(|a| rec.gyro_rate_rad_s.iter().map(|w| w[a]).collect()).collect();
    let steps = (LAG_SEARCH_S / LAG_STEP_S).round() as i64;
    // (from the gyroscopes as recorded: the search starts at their own instants)
    let raw: Vec<(Vector3<f64>, Vector3<f64>)> =
        used.iter().map(|&(k, i)| (motion[k].omega_rad_s, rec.gyro_rate_rad_s[i] - bias)).collect();
    let (mut accelerometer_lag_s, mut rms_at_lag_rad_s) = (0.0, rms(&raw).0);
    if dt > 0.0 {
        for step in -steps..=steps {
            let lag = step as f64 * LAG_STEP_S;
            let delay = crate::signal::FractionalDelay::new(lag / dt);
            let ss: f64 = used
                .iter()
                .map(|&(k, i)| {
                    let reference = Vector3::from_fn(|a, _| delay.at(&columns[a], i));
                    (motion[k].omega_rad_s - (reference - bias)).norm_squared()
                })
                .sum();
            let rms = (ss / used.len().max(1) as f64).sqrt();
            if rms < rms_at_lag_rad_s {
                (accelerometer_lag_s, rms_at_lag_rad_s) = (lag, rms);
            }
        }
    }
    GyroCheck {
        accelerometer_lag_s,
        rms_at_lag_rad_s,
        samples: pairs.len(),
        rms_rad_s: d,
        relative: d / r,
        rms_reference_rad_s: r,
        aligned_rms_rad_s: ad,
        frame_rotation_rad: angle,
        median_magnitude_ratio,
        by_rate,
    }
}
