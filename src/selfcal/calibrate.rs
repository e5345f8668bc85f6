//! `gfcal calibrate`: a recording in, every parameter with its sigma out.
//!
//! Segments the recording, forms the static means and the dynamic samples, fits
//! (`selfcal::fit`), and checks the gyroscope-free angular rate against the reference gyroscopes.

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::{DMatrix, Vector3};

use super::fit::{DynamicData, Fit, FitError, FitSettings, StaticData, fit};
use super::recording::{Recording, RecordingArray};
use super::segment::{DetectorSettings, Interval, Segmentation, segment};

/// Settings of a calibration.
#[derive(Debug, Clone, Copy, Default)]
pub struct CalibrateSettings {
    pub detector: DetectorSettings,
    pub fit: FitSettings,
    /// Take the angular rate from the reference gyroscopes (the published method) instead of
    /// estimating it from the accelerometers.
    pub use_gyro: bool,
}

/// Why a calibration cannot be done.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CalibrateError {
    #[error("{}: {problem}", path.display())]
    Recording { path: std::path::PathBuf, problem: String },
    #[error("{}: {source}", path.display())]
    Fit { path: std::path::PathBuf, source: FitError },
}

/// The gyroscope-free rate against the reference gyroscopes (bias-corrected from the static
/// intervals), over dynamic samples where no gyroscope clipped.
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
    /// +-[`LAG_SEARCH_S`] in steps of [`LAG_STEP_S`]), and the RMS difference at it.
    pub accelerometer_lag_s: f64,
    pub rms_at_lag_rad_s: f64,
}

/// The lag search of [`GyroCheck`]: half-width and step, s.
pub const LAG_SEARCH_S: f64 = 5e-3;
pub const LAG_STEP_S: f64 = 1e-4;

/// A finished calibration of one recording.
#[derive(Debug, Clone)]
pub struct Calibration {
    pub segmentation: Segmentation,
    pub fit: Fit,
    pub static_data: StaticData,
    /// Indices into the recording of the dynamic samples used.
    pub dynamic_index: Vec<usize>,
    /// Dynamic-phase outputs left out as clipped, and samples dropped (gyroscope clipped with
    /// `--use-gyro`, or fewer than 10 unclipped outputs).
    pub clipped_outputs: usize,
    pub dropped_samples: usize,
    pub gyro_bias_rad_s: Option<Vector3<f64>>,
    pub gyro_check: Option<GyroCheck>,
    pub use_gyro: bool,
}

/// The static means and pooled per-sample scatter of every interval. An output at or beyond its
/// range inside a static interval is refused (the problem, in words): a board at rest cannot
/// saturate an accelerometer, so the range is wrong or the sample is a glitch, and a railed value
/// in a mean would be read as measured.
pub fn static_data(rec: &Recording, intervals: &[Interval]) -> Result<StaticData, String> {
    let n = rec.accelerometers();
    for (p, iv) in intervals.iter().enumerate() {
        for i in iv.start..iv.end {
            if let Some(j) = (0..n).find(|&j| rec.is_clipped(i, j)) {
                return Err(format!(
                    "data row {} (t = {:.2} s): accelerometer {}'s output {} is at or beyond its range inside static interval {} ({:.2}-{:.2} s); a board at rest cannot saturate an accelerometer, so the array file's `accelerometer[{}].range_m_s2` is below what the part reads, or the sample is a glitch",
                    i + 1,
                    rec.t_s[i],
                    j + 1,
                    rec.outputs[(i, j)],
                    p + 1,
                    rec.t_s[iv.start],
                    rec.t_s[iv.end - 1],
                    j
                ));
            }
        }
    }
    let mut means = DMatrix::zeros(intervals.len(), n);
    let mut counts = Vec::with_capacity(intervals.len());
    let mut ss = vec![0.0; n];
    let mut dof = vec![0.0; n];
    for (p, iv) in intervals.iter().enumerate() {
        counts.push(iv.len());
        for j in 0..n {
            let col = rec.outputs.column(j);
            let xs = &col.as_slice()[iv.start..iv.end];
            let mean = xs.iter().sum::<f64>() / xs.len() as f64;
            means[(p, j)] = mean;
            ss[j] += xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>();
            dof[j] += xs.len() as f64 - 1.0;
        }
    }
    let sigma = (0..n).map(|j| (ss[j] / dof[j].max(1.0)).sqrt().max(1e-12)).collect();
    Ok(StaticData { means, counts, sigma })
}

/// Calibrates a recording (see the module docs).
pub fn calibrate(
    rec: &Recording,
    array: &RecordingArray,
    settings: &CalibrateSettings,
) -> Result<Calibration, CalibrateError> {
    let bad = |problem: String| CalibrateError::Recording { path: rec.path.clone(), problem };
    if settings.use_gyro && array.gyroscopes.is_empty() {
        return Err(bad(format!(
            "--use-gyro needs reference gyroscopes, and the array file {} lists none",
            array.path.display()
        )));
    }
    let seg = segment(rec, &settings.detector).map_err(|e| bad(e.to_string()))?;
    let stat = static_data(rec, &seg.static_intervals)
        .map_err(|problem| bad(format!("{problem} (array file {})", array.path.display())))?;
    let gyro_bias_rad_s = gyro_bias(rec, &seg);
    let prepared = prepare_dynamic(rec, &seg, settings.use_gyro, gyro_bias_rad_s);
    let dynamic = prepared.data.as_ref();
    let fit = fit(&array.array, &stat, dynamic, &settings.fit)
        .map_err(|source| CalibrateError::Fit { path: rec.path.clone(), source })?;
    let gyro_check = match (gyro_bias_rad_s, settings.use_gyro, fit.motion.is_empty()) {
        (Some(b), false, false) => Some(gyro_check(rec, &prepared.index, &fit, &b)),
        _ => None,
    };
    Ok(Calibration {
        segmentation: seg,
        fit,
        static_data: stat,
        dynamic_index: prepared.index.clone(),
        clipped_outputs: prepared.clipped_outputs,
        dropped_samples: prepared.dropped_samples,
        gyro_bias_rad_s,
        gyro_check,
        use_gyro: settings.use_gyro,
    })
}

/// The dynamic samples of a recording, ready for the fit.
pub struct PreparedDynamic {
    pub data: Option<DynamicData>,
    pub index: Vec<usize>,
    pub clipped_outputs: usize,
    pub dropped_samples: usize,
}

/// Dynamic samples: unclipped outputs; a sample needs 10 of them (9 motion unknowns and one
/// degree of freedom), and with a reference rate, no clipped gyroscope.
pub fn prepare_dynamic(
    rec: &Recording,
    seg: &Segmentation,
    use_gyro: bool,
    gyro_bias_rad_s: Option<Vector3<f64>>,
) -> PreparedDynamic {
    let n = rec.accelerometers();
    let mut index = Vec::new();
    let mut run_starts = Vec::new();
    let mut clipped_outputs = 0;
    let mut dropped_samples = 0;
    for iv in &seg.dynamic_intervals {
        let mut new_run = true;
        for i in iv.start..iv.end {
            let unclipped = (0..n).filter(|&j| !rec.is_clipped(i, j)).count();
            let gyro_bad = use_gyro && rec.gyro_clipped[i];
            if unclipped < 10 || gyro_bad {
                dropped_samples += 1;
                new_run = true;
                continue;
            }
            clipped_outputs += n - unclipped;
            if new_run {
                run_starts.push(index.len());
                new_run = false;
            }
            index.push(i);
        }
    }
    let data = (!index.is_empty()).then(|| DynamicData {
        t_s: index.iter().map(|&i| rec.t_s[i]).collect(),
        outputs: DMatrix::from_fn(index.len(), n, |r, j| rec.outputs[(index[r], j)]),
        used: index.iter().flat_map(|&i| (0..n).map(move |j| !rec.is_clipped(i, j))).collect(),
        run_starts,
        reference_rate_rad_s: use_gyro.then(|| {
            let b = gyro_bias_rad_s.unwrap_or_default();
            index.iter().map(|&i| rec.gyro_rate_rad_s[i] - b).collect()
        }),
    });
    PreparedDynamic { data, index, clipped_outputs, dropped_samples }
}

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

fn gyro_check(rec: &Recording, index: &[usize], fit: &Fit, bias: &Vector3<f64>) -> GyroCheck {
    let pairs: Vec<(Vector3<f64>, Vector3<f64>)> = index
        .iter()
        .enumerate()
        .filter(|(_, i)| !rec.gyro_clipped[**i])
        .map(|(k, &i)| (fit.motion[k].omega_rad_s, rec.gyro_rate_rad_s[i] - bias))
        .collect();
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
    let used: Vec<(usize, usize)> =
        index.iter().enumerate().filter(|(_, i)| !rec.gyro_clipped[**i]).map(|(k, &i)| (k, i)).collect();
    let steps = (LAG_SEARCH_S / LAG_STEP_S).round() as i64;
    let (mut accelerometer_lag_s, mut rms_at_lag_rad_s) = (0.0, d);
    if dt > 0.0 {
        for step in -steps..=steps {
            let lag = step as f64 * LAG_STEP_S;
            let delay = crate::signal::FractionalDelay::new(lag / dt);
            let ss: f64 = used
                .iter()
                .map(|&(k, i)| {
                    let reference = Vector3::from_fn(|a, _| delay.at(&columns[a], i));
                    (fit.motion[k].omega_rad_s - (reference - bias)).norm_squared()
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
