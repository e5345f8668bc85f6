//! The hand-held recordings' generator (`selfcal::simulate`): today's smooth motion unchanged bit
//! for bit when the new physics is off.

use gfcal::rng::trial_rng;
use gfcal::selfcal::simulate::{Simulated, random_truth, simulate};

use super::selfcal::{mimu_array, protocol};

/// FNV-1a over the bits of everything a simulated recording holds: time, outputs, clipping,
/// the gyroscopes' rates (all and per package), the truth's up direction and motion.
fn digest(sim: &Simulated) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    let r = &sim.recording;
    r.t_s.iter().for_each(|v| eat(v.to_bits()));
    r.outputs.iter().for_each(|v| eat(v.to_bits()));
    r.clipped.iter().for_each(|&c| eat(u64::from(c)));
    r.gyro_rate_rad_s.iter().flat_map(|w| w.iter()).for_each(|v| eat(v.to_bits()));
    r.gyro_clipped.iter().for_each(|&c| eat(u64::from(c)));
    r.package_gyro_rate_rad_s.iter().flatten().flat_map(|w| w.iter()).for_each(|v| eat(v.to_bits()));
    sim.up.iter().flat_map(|u| u.iter()).for_each(|v| eat(v.to_bits()));
    for m in &sim.motion {
        m.f_m_s2.iter().chain(m.alpha_rad_s2.iter()).chain(m.omega_rad_s.iter()).for_each(|v| eat(v.to_bits()));
    }
    h
}

/// The truth these digests were measured with: `random_truth`'s draws, in the gauge it had then
/// (one translation for the whole array). The axis groups' translation gauge (2026-11-26) moves
/// the truth `random_truth` now returns, not the generator; the tilts are projected as before.
fn truth_in_the_single_translation_gauge(
    array: &gfcal::array::wiring::RecordingArray,
) -> gfcal::selfcal::model::SensorSet {
    let drawn = random_truth(&array.array, 0.005, 0.3, 0.004, 0.5e-3, &mut trial_rng(5, 0));
    // The same draws without any projection: random_truth less its gauge is not recoverable, so
    // draw again in its order (per accelerometer: scale, bias, two tilts, three location errors).
    use rand::RngExt;
    let mut rng = trial_rng(5, 0);
    let mut g = |s: f64| -> f64 { s * rng.sample::<f64, _>(rand_distr::StandardNormal) };
    let mut t = drawn.clone();
    for j in 0..t.len() {
        let _ = (g(0.005), g(0.3), g(0.004), g(0.004));
        t.location_error_m[j] = Vector3::new(g(0.5e-3), g(0.5e-3), g(0.5e-3));
    }
    let n = t.len();
    let mean: Vector3<f64> = t.location_error_m.iter().sum::<Vector3<f64>>() / n as f64;
    for d in &mut t.location_error_m {
        *d -= mean;
    }
    let centroid: Vector3<f64> =
        array.array.accelerometers().iter().map(|a| a.position_m).sum::<Vector3<f64>>() / n as f64;
    let rel: Vec<Vector3<f64>> = array.array.accelerometers().iter().map(|a| a.position_m - centroid).collect();
    let num: f64 = rel.iter().zip(&t.location_error_m).map(|(r, d)| r.dot(d)).sum();
    let den: f64 = rel.iter().map(|r| r.norm_squared()).sum();
    for (d, r) in t.location_error_m.iter_mut().zip(&rel) {
        *d -= r * (num / den);
    }
    // The rotation gauge does not touch the locations: `drawn`'s tilts are the old truth's.
    t
}

/// Digests of the generator as it was before the vibration, the clocks and the filters (commit
/// d650946), on the tests' protocol and on a faster one (250 Hz, motion to 12 Hz): with the new
/// physics off a recording must stay the same bit for bit (so must every test and Monte Carlo run
/// built on it).
#[test]
fn with_the_new_physics_off_the_generator_is_unchanged_bit_for_bit() {
    let array = mimu_array();
    let n = array.array.len();
    let truth = truth_in_the_single_translation_gauge(&array);
    let sim = simulate(&array, &truth, &protocol(n), &mut trial_rng(5, 1)).expect("simulated");
    let mut fast = protocol(n);
    fast.sample_rate_hz = 250.0;
    fast.motion_band_hz = [0.3, 12.0];
    fast.poses = 6;
    fast.dynamic_s = 12.0;
    let sim_fast = simulate(&array, &truth, &fast, &mut trial_rng(6, 1)).expect("simulated");
    eprintln!("digests {:#018x} {:#018x}", digest(&sim), digest(&sim_fast));
    // measured on commit d650946 (its generator, the same protocols and seeds)
    assert_eq!(digest(&sim), 0x005f_8538_f3d1_cfe2);
    assert_eq!(digest(&sim_fast), 0x8d7e_2dc6_1f09_886d);
}

// ---------------------------------------------------------------------------------------------
// Measures of a rotation phase, computed from a recording's outputs alone, the same way on the
// real recordings and on simulated ones (docs/real-hardware.md's match table).

use gfcal::array::wiring::RecordingArray;
use gfcal::mc::config::McConfig;
use gfcal::mc::protocol::ProtocolCell;
use gfcal::selfcal::calibrate::{CalibrateSettings, Calibration, calibrate, prepare_dynamic};
use gfcal::selfcal::clock::SampleClock;
use gfcal::selfcal::clocked::corrected_dynamic;
use gfcal::selfcal::drift::BiasDriftSpread;
use gfcal::selfcal::model::{PER_ACCEL, SensorSet, sensors};
use gfcal::selfcal::recording::Recording;
use gfcal::selfcal::sampling::{ClockSpread, Spread};
use gfcal::selfcal::simulate::{FINE_STEP_S, Protocol, SensorBursts, Vibration};
use gfcal::sensor::misalignment::tilt_axis;
use nalgebra::{DMatrix, DVector, Vector3};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

fn repo() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The gyroscope-free rate of a calibration of `sim` against the simulator's true rate: the
/// relative RMS difference over the rotation phase's samples, %.
pub fn rate_error_percent(cal: &Calibration, sim: &Simulated) -> f64 {
    let (mut e, mut r) = (0.0, 0.0);
    for (k, &i) in cal.dynamic_index.iter().enumerate() {
        e += (cal.rate_motion()[k].omega_rad_s - sim.motion[i].omega_rad_s).norm_squared();
        r += sim.motion[i].omega_rad_s.norm_squared();
    }
    100.0 * (e / r).sqrt()
}

/// The matched protocol of the shipped config (configs/mimu4444_protocol.toml), with its array.
pub fn matched_cell() -> ProtocolCell {
    let cfg = McConfig::load(&repo().join("configs/mimu4444_protocol.toml")).expect("shipped config");
    cfg.cells[0].protocol.clone().expect("a [protocol] config")
}

/// The array with its packages' clocks not declared (every part read at the host's instants):
/// what the calibration fitted before the clocks were modelled.
pub fn without_clocks(array: &RecordingArray) -> RecordingArray {
    let mut a = array.clone();
    for p in &mut a.packages {
        p.sample_and_hold = false;
    }
    a
}

/// The nominal position of every package (its first accelerometer's).
pub fn package_positions(array: &RecordingArray) -> Vec<Vector3<f64>> {
    let acc = array.array.accelerometers();
    array.accelerometer_groups().iter().map(|g| acc[g[0]].position_m).collect()
}

/// Every package's specific-force vector (array axes) at `rows`: its accelerometers' outputs
/// corrected by `params` (`s / k - b`), least squares through their tilted axes.
pub fn package_vectors(
    array: &RecordingArray,
    rec: &Recording,
    rows: &[usize],
    params: &SensorSet,
) -> Vec<Vec<Vector3<f64>>> {
    let acc = array.array.accelerometers();
    array
        .accelerometer_groups()
        .iter()
        .map(|g| {
            let a = DMatrix::from_fn(g.len(), 3, |r, c| tilt_axis(&acc[g[r]].axis, &params.tilt_rad[g[r]])[c]);
            let pinv = a.pseudo_inverse(1e-12).expect("axes");
            rows.iter()
                .map(|&i| {
                    let y = DVector::from_fn(g.len(), |r, _| {
                        let j = g[r];
                        rec.outputs[(i, j)] / params.scale_factor[j] - params.bias_m_s2[j]
                    });
                    let v = &pinv * y;
                    Vector3::new(v[0], v[1], v[2])
                })
                .collect()
        })
        .collect()
}

/// The share of a vector signal's power above `cut_hz` (mean removed, axes summed): Welch's
/// periodogram with Hann windows of 512 samples, half overlapping.
pub fn share_above(x: &[Vector3<f64>], fs_hz: f64, cut_hz: f64) -> f64 {
    let seg = 512;
    let mean: Vector3<f64> = x.iter().sum::<Vector3<f64>>() / x.len() as f64;
    let fft = FftPlanner::new().plan_fft_forward(seg);
    let win: Vec<f64> =
        (0..seg).map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / seg as f64).cos()).collect();
    let mut p = vec![0.0; seg / 2 + 1];
    let mut start = 0;
    while start + seg <= x.len() {
        for k in 0..3 {
            let mut buf: Vec<Complex<f64>> =
                (0..seg).map(|i| Complex::new((x[start + i][k] - mean[k]) * win[i], 0.0)).collect();
            fft.process(&mut buf);
            for (f, pf) in p.iter_mut().enumerate() {
                *pf += buf[f].norm_sqr();
            }
        }
        start += seg / 2;
    }
    let df = fs_hz / seg as f64;
    let total: f64 = p.iter().sum();
    let above: f64 = p.iter().enumerate().filter(|(f, _)| *f as f64 * df > cut_hz).map(|(_, v)| v).sum();
    above / total
}

/// Per-sample least squares of the packages' vectors on `s + W r_p` (12 unknowns, nominal
/// positions; every axis of the vectors separately) and, with `ages` (s, per package and row),
/// also on `-(a_p - mean a) s'` (3 more unknowns: the jerk the sample clocks turn into errors).
#[derive(Debug, Clone)]
pub struct RigidFit {
    /// Residual RMS per axis, m/s^2.
    pub residual_rms_m_s2: f64,
    pub rss: f64,
    /// `s'` of every row (zero without ages), m/s^3.
    pub jerk_m_s3: Vec<Vector3<f64>>,
}

pub fn rigid_fit(positions: &[Vector3<f64>], vectors: &[Vec<Vector3<f64>>], ages: Option<&[Vec<f64>]>) -> RigidFit {
    let p = positions.len();
    let rows = vectors[0].len();
    let cols = if ages.is_some() { 5 } else { 4 };
    let (mut rss, mut count) = (0.0, 0usize);
    let mut jerk = vec![Vector3::zeros(); rows];
    for i in 0..rows {
        let mean_age = ages.map_or(0.0, |a| a.iter().map(|a| a[i]).sum::<f64>() / p as f64);
        let x = DMatrix::from_fn(p, cols, |r, c| match c {
            0 => 1.0,
            1..=3 => positions[r][c - 1],
            _ => -(ages.expect("ages")[r][i] - mean_age),
        });
        let svd = x.clone().svd(true, true);
        for k in 0..3 {
            let y = DVector::from_fn(p, |r, _| vectors[r][i][k]);
            let beta = svd.solve(&y, 1e-12).expect("solve");
            rss += (&y - &x * &beta).norm_squared();
            count += p;
            if cols == 5 {
                jerk[i][k] = beta[4];
            }
        }
    }
    RigidFit { residual_rms_m_s2: (rss / count as f64).sqrt(), rss, jerk_m_s3: jerk }
}

pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

pub fn percentile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Pearson correlation of two equally long series.
pub fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt()
}

/// Five-point derivative of samples `dt` apart (zero at the two ends).
pub fn five_point(x: &[Vector3<f64>], dt: f64) -> Vec<Vector3<f64>> {
    let mut d = vec![Vector3::zeros(); x.len()];
    for i in 2..x.len().saturating_sub(2) {
        d[i] = (x[i - 2] - x[i - 1] * 8.0 + x[i + 1] * 8.0 - x[i + 2]) / (12.0 * dt);
    }
    d
}

/// The packages' gyroscopes against one another (the clock report's step 1): each package's
/// rate mapped onto the packages' mean by an affine map (3 x 3 and a constant, least squares:
/// removes scale, misalignment and bias), the disagreement `d_p` with the mapped mean, and its
/// projection on the angular acceleration `y_p = -d_p . alpha / |alpha|^2` (a time offset, s,
/// positive: late), alpha the five-point derivative of the mean.
#[derive(Debug, Clone)]
pub struct GyroTiming {
    /// Rows (into `rows` as given) where no gyroscope clipped within two samples.
    pub valid: Vec<usize>,
    /// Per package: the disagreement's RMS per axis over the valid rows, rad/s.
    pub disagreement_rms_rad_s: Vec<f64>,
    /// Per package and row of `rows`: the offset (NaN where not valid or |alpha| <= `min_alpha`).
    pub offset_s: Vec<Vec<f64>>,
    pub alpha_rad_s2: Vec<Vector3<f64>>,
    /// Per package: the share of the disagreement's power along the angular acceleration (rows
    /// with an offset).
    pub along_alpha: Vec<f64>,
}

pub fn gyro_timing(rec: &Recording, rows: &[usize], min_alpha_rad_s2: f64) -> GyroTiming {
    let dt = rec.t_s[1] - rec.t_s[0];
    let pk = &rec.package_gyro_rate_rad_s;
    let np = pk.len();
    let n = rows.len();
    let valid: Vec<usize> =
        (2..n.saturating_sub(2)).filter(|&r| (r - 2..=r + 2).all(|q| !rec.gyro_clipped[rows[q]])).collect();
    let raw_mean: Vec<Vector3<f64>> =
        rows.iter().map(|&i| pk.iter().map(|w| w[i]).sum::<Vector3<f64>>() / np as f64).collect();
    let mapped: Vec<Vec<Vector3<f64>>> = pk
        .iter()
        .map(|w| {
            let x = DMatrix::from_fn(valid.len(), 4, |r, c| if c == 3 { 1.0 } else { w[rows[valid[r]]][c] });
            let y = DMatrix::from_fn(valid.len(), 3, |r, c| raw_mean[valid[r]][c]);
            let b = x.clone().svd(true, true).solve(&y, 1e-12).expect("map");
            rows.iter()
                .map(|&i| {
                    let v = nalgebra::RowVector4::new(w[i][0], w[i][1], w[i][2], 1.0) * &b;
                    Vector3::new(v[0], v[1], v[2])
                })
                .collect()
        })
        .collect();
    let mean: Vec<Vector3<f64>> =
        (0..n).map(|r| mapped.iter().map(|m| m[r]).sum::<Vector3<f64>>() / np as f64).collect();
    let alpha = five_point(&mean, dt);
    let disagreement_rms_rad_s = mapped
        .iter()
        .map(|m| {
            (valid.iter().map(|&r| (m[r] - mean[r]).norm_squared()).sum::<f64>() / (3 * valid.len()) as f64).sqrt()
        })
        .collect();
    let offset_s = mapped
        .iter()
        .map(|m| {
            let mut y = vec![f64::NAN; n];
            for &r in &valid {
                let a = alpha[r];
                if a.norm() > min_alpha_rad_s2 {
                    y[r] = -(m[r] - mean[r]).dot(&a) / a.norm_squared();
                }
            }
            y
        })
        .collect();
    let along_alpha = mapped
        .iter()
        .map(|m| {
            let (mut along, mut all) = (0.0, 0.0);
            for &r in &valid {
                let a = alpha[r];
                if a.norm() > min_alpha_rad_s2 {
                    let d = m[r] - mean[r];
                    along += d.dot(&a).powi(2) / a.norm_squared();
                    all += d.norm_squared();
                }
            }
            along / all
        })
        .collect();
    GyroTiming { valid, disagreement_rms_rad_s, offset_s, alpha_rad_s2: alpha, along_alpha }
}

/// Standard deviation and lag-1 autocorrelation of a series' finite values (pairs of
/// consecutive finite values for the latter).
pub fn std_and_lag1(y: &[f64]) -> (f64, f64) {
    let v: Vec<f64> = y.iter().copied().filter(|v| v.is_finite()).collect();
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
    let (a, b): (Vec<f64>, Vec<f64>) =
        y.windows(2).filter(|w| w[0].is_finite() && w[1].is_finite()).map(|w| (w[0], w[1])).unzip();
    (var.sqrt(), correlation(&a, &b))
}

/// What the real recordings' rotation phases are measured by (docs/real-hardware.md).
#[derive(Debug, Clone, Default)]
pub struct PhaseStats {
    /// RMS of the specific force's magnitude (packages' mean), m/s^2.
    pub f_rms_m_s2: f64,
    pub share_5: f64,
    pub share_10: f64,
    pub share_20: f64,
    pub gyro_share_10: f64,
    pub rate_rms_rad_s: f64,
    pub rate_p99_rad_s: f64,
    pub alpha_median_rad_s2: f64,
    pub accel_max_m_s2: f64,
    pub accel_clipped_share: f64,
    pub gyro_clipped_share: f64,
    pub diff_jerk_median_m_s3: f64,
    pub gyro_disagreement_rad_s: [f64; 2],
    pub offset_std_ms: [f64; 2],
    pub offset_lag1: [f64; 2],
    pub along_alpha: [f64; 2],
    /// The rigid fit (12 unknowns a sample, nominal positions) of the calibrated outputs.
    pub rigid_residual_m_s2: f64,
    /// The share of its residual variance the packages' ages (3 more unknowns: s') remove, that
    /// share with the ages of the packages permuted (what 3 unknowns remove by chance), the
    /// residual after, and the median |s'|.
    pub ages_removed: f64,
    pub ages_removed_null: f64,
    pub rigid_residual_after_m_s2: f64,
    pub fitted_jerk_median_m_s3: f64,
    /// `gfcal calibrate`'s gyroscope-free fit without the clock model: its dynamic residual RMS.
    pub calibrate_residual_m_s2: f64,
}

/// The measures on `rows` (consecutive, in the rotation phase), the outputs corrected by
/// `params` (the calibration's), the packages' ages at every row given by `clocks`.
pub fn phase_stats(
    array: &RecordingArray,
    rec: &Recording,
    rows: &[usize],
    params: &SensorSet,
    clocks: &[Option<SampleClock>],
) -> PhaseStats {
    let dt = rec.t_s[1] - rec.t_s[0];
    let fs = 1.0 / dt;
    let n = rec.accelerometers();
    let vecs = package_vectors(array, rec, rows, params);
    let mean: Vec<Vector3<f64>> =
        (0..rows.len()).map(|i| vecs.iter().map(|v| v[i]).sum::<Vector3<f64>>() / vecs.len() as f64).collect();
    let w: Vec<Vector3<f64>> = rows.iter().map(|&i| rec.gyro_rate_rad_s[i]).collect();
    let wn: Vec<f64> = w.iter().map(|v| v.norm()).collect();
    let dj = five_point(&mean, dt);
    let gt = gyro_timing(rec, rows, 300.0);
    let (mut off_std, mut off_lag) = ([f64::INFINITY, 0.0], [f64::INFINITY, 0.0]);
    for y in &gt.offset_s {
        let (s, l) = std_and_lag1(y);
        off_std = [off_std[0].min(s * 1e3), off_std[1].max(s * 1e3)];
        off_lag = [off_lag[0].min(l), off_lag[1].max(l)];
    }
    let dis = &gt.disagreement_rms_rad_s;
    // The rigid fits on rows where no output is within 5% of its range (the clock report's cut).
    let near_rail = |i: usize| (0..n).any(|j| rec.outputs[(i, j)].abs() >= 0.95 * array.ranges_m_s2[j]);
    let keep: Vec<usize> = (0..rows.len()).filter(|&r| !near_rail(rows[r])).collect();
    let kept: Vec<Vec<Vector3<f64>>> = vecs.iter().map(|v| keep.iter().map(|&r| v[r]).collect()).collect();
    let positions = package_positions(array);
    let age = |shift: usize| -> Vec<Vec<f64>> {
        let np = clocks.len();
        (0..np)
            .map(|p| {
                let c = clocks[(p + shift) % np].expect("a clock for every package");
                keep.iter().map(|&r| c.age_s(rec.t_s[rows[r]])).collect()
            })
            .collect()
    };
    let before = rigid_fit(&positions, &kept, None);
    let after = rigid_fit(&positions, &kept, Some(&age(0)));
    let null = rigid_fit(&positions, &kept, Some(&age(3)));
    PhaseStats {
        f_rms_m_s2: (mean.iter().map(|v| v.norm_squared()).sum::<f64>() / mean.len() as f64).sqrt(),
        share_5: share_above(&mean, fs, 5.0),
        share_10: share_above(&mean, fs, 10.0),
        share_20: share_above(&mean, fs, 20.0),
        gyro_share_10: share_above(&w, fs, 10.0),
        rate_rms_rad_s: (wn.iter().map(|x| x * x).sum::<f64>() / wn.len() as f64).sqrt(),
        rate_p99_rad_s: percentile(wn.clone(), 0.99),
        alpha_median_rad_s2: median(gt.valid.iter().map(|&r| gt.alpha_rad_s2[r].norm()).collect()),
        accel_max_m_s2: rows.iter().flat_map(|&i| (0..n).map(move |j| rec.outputs[(i, j)].abs())).fold(0.0, f64::max),
        accel_clipped_share: rows.iter().filter(|&&i| (0..n).any(|j| rec.is_clipped(i, j))).count() as f64
            / rows.len() as f64,
        gyro_clipped_share: rows.iter().filter(|&&i| rec.gyro_clipped[i]).count() as f64 / rows.len() as f64,
        diff_jerk_median_m_s3: median(dj[2..dj.len() - 2].iter().map(|a| a.norm()).collect()),
        gyro_disagreement_rad_s: [
            dis.iter().cloned().fold(f64::INFINITY, f64::min),
            dis.iter().cloned().fold(0.0, f64::max),
        ],
        offset_std_ms: off_std,
        offset_lag1: off_lag,
        along_alpha: [
            gt.along_alpha.iter().cloned().fold(f64::INFINITY, f64::min),
            gt.along_alpha.iter().cloned().fold(0.0, f64::max),
        ],
        rigid_residual_m_s2: before.residual_rms_m_s2,
        ages_removed: 1.0 - after.rss / before.rss,
        ages_removed_null: 1.0 - null.rss / before.rss,
        rigid_residual_after_m_s2: after.residual_rms_m_s2,
        fitted_jerk_median_m_s3: median(after.jerk_m_s3.iter().map(|j| j.norm()).collect()),
        calibrate_residual_m_s2: f64::NAN,
    }
}

/// `gfcal calibrate`'s gyroscope-free fit of a recording without the clock model (the array's
/// clocks not declared): its parameters, dynamic residual RMS (as the JSON's
/// `dynamic.residual_rms_m_s2`) and the rows of its rotation phase.
pub fn baseline_calibration(array: &RecordingArray, rec: &Recording) -> (SensorSet, f64, Vec<usize>) {
    let cal = calibrate(rec, &without_clocks(array), &CalibrateSettings::default()).expect("calibrates");
    let v: Vec<f64> = cal.fit.dynamic_residual_rms_m_s2.iter().copied().filter(|v| v.is_finite()).collect();
    let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let iv = cal.segmentation.dynamic_intervals.iter().max_by_key(|iv| iv.len()).expect("a rotation phase");
    (cal.fit.params.clone(), rms, (iv.start..iv.end).collect())
}

/// The rows of a simulated rotation phase after its 2 s ramp and one more second.
pub fn rotation_rows(protocol: &Protocol, rec: &Recording) -> Vec<usize> {
    let start = protocol.rotation_centre_s() - 0.5 * protocol.dynamic_s + 3.0;
    (0..rec.samples()).filter(|&i| rec.t_s[i] >= start).collect()
}

/// The MIMU4444's clocks (recording 1, ppm; tests/gfcal/clock.rs's independent implementation).
pub const BOARD_PPM: [f64; 8] = [-2546.5, -2248.4, -333.4, -2452.3, 827.6, -37.5, 1120.4, -649.1];

/// Board clocks: the eight rate offsets of recording 1, no drift.
pub fn board_clocks() -> ClockSpread {
    ClockSpread {
        rate_offset: Spread::Fixed(BOARD_PPM.iter().map(|x| x * 1e-6).collect()),
        common_rate_offset: Spread::zero(),
        drift_per_s: Spread::zero(),
    }
}

fn shared_recording(k: usize) -> std::path::PathBuf {
    repo().join(format!("../shared/data/mimu4444/recording_{k}.parquet"))
}

/// The matched protocol with overrides from `spec` ("key=value ...": vib, vrate, vband=lo,hi,
/// svib (each accelerometer's own error under the vibration, one axis), sk (its own rate exponent), sburst=duty,mean_s (it in bursts at random times), rband=lo,hi (the angular vibration's band), rorder (its low-pass's order, 2 or 3), order (the translation's), k (the vibration's rate exponent), band=lo,hi, aband=lo,hi (the acceleration's), acc, rate, tau and gtau (the accelerometers'
/// and gyroscopes' anti-alias time constants, ms), clocks=0|1, dynamic, poses): the tuning aid's
/// input.
fn tuned_protocol(spec: &str) -> (ProtocolCell, bool) {
    let mut cell = matched_cell();
    let p = &mut cell.protocol;
    let mut clocks = true;
    for kv in spec.split_whitespace() {
        let (k, v) = kv.split_once('=').expect("key=value");
        let nums: Vec<f64> = v.split(',').map(|x| x.parse().expect("number")).collect();
        match k {
            "vib" => p.vibration.accel_rms_m_s2 = nums[0],
            "vrate" => p.vibration.rate_rms_rad_s = nums[0],
            "vband" => p.vibration.band_hz = [nums[0], nums[1]],
            "rband" => p.vibration.rate_band_hz = Some([nums[0], nums[1]]),
            "band" => p.motion_band_hz = [nums[0], nums[1]],
            "aband" => p.accel_band_hz = Some([nums[0], nums[1]]),
            "acc" => p.accel_rms_m_s2 = nums[0],
            "rate" => p.rate_rms_rad_s = nums[0],
            "tau" => p.anti_alias.accel_time_constant_s = nums[0] * 1e-3,
            "gtau" => p.anti_alias.gyro_time_constant_s = nums[0] * 1e-3,
            "k" => p.vibration.rate_exponent = nums[0],
            "svib" => p.vibration.sensor_rms_m_s2 = nums[0],
            "sk" => p.vibration.sensor_rate_exponent = Some(nums[0]),
            // The sensor error in bursts at random times: duty, mean length (s).
            "sburst" => p.vibration.sensor_bursts = Some(SensorBursts { duty: nums[0], mean_s: nums[1] }),
            "order" => {
                p.vibration.low_pass =
                    gfcal::selfcal::vibration::LowPass::from_order(nums[0] as u32).expect("order 2 or 3")
            }
            "rorder" => {
                p.vibration.rate_low_pass =
                    gfcal::selfcal::vibration::LowPass::from_order(nums[0] as u32).expect("order 2 or 3")
            }
            "clocks" => clocks = nums[0] > 0.0,
            "dynamic" => p.dynamic_s = nums[0],
            "poses" => p.poses = nums[0] as usize,
            _ => panic!("unknown key {k}"),
        }
    }
    if !clocks {
        p.clocks = None;
    }
    (cell, clocks)
}

/// The error distributions of configs/mimu4444_protocol.toml's `[errors]` (scale 3600 ppm, bias
/// 32 mg, tilts 0.2 deg, locations 0.4 mm), drawn for one recording.
pub fn config_truth(array: &RecordingArray, seed: u64) -> SensorSet {
    config_truth_with(array, seed, CONFIG_LOCATION_SIGMA_M)
}

/// configs/mimu4444_protocol.toml's `location_mm` sigma, m.
const CONFIG_LOCATION_SIGMA_M: f64 = 0.4e-3;

fn config_truth_with(array: &RecordingArray, seed: u64, location_sigma_m: f64) -> SensorSet {
    random_truth(&array.array, 3600e-6, 32e-3 * 9.80665, 0.2f64.to_radians(), location_sigma_m, &mut trial_rng(seed, 0))
}

fn range(v: &[f64]) -> String {
    let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let fmt = |x: f64| {
        if x.abs() >= 100.0 {
            format!("{x:.0}")
        } else if x.abs() >= 10.0 {
            format!("{x:.1}")
        } else {
            format!("{x:.3}")
        }
    };
    format!("{}-{}", fmt(lo), fmt(hi))
}

/// The table's rows from a set of measures (name, values per recording).
fn table_rows(stats: &[PhaseStats]) -> Vec<(&'static str, Vec<f64>)> {
    let col = |f: &dyn Fn(&PhaseStats) -> f64| stats.iter().map(f).collect::<Vec<f64>>();
    vec![
        ("specific force: RMS magnitude (m/s^2)", col(&|s| s.f_rms_m_s2)),
        ("specific force: power above 5 Hz (%)", col(&|s| 100.0 * s.share_5)),
        ("specific force: power above 10 Hz (%)", col(&|s| 100.0 * s.share_10)),
        ("specific force: power above 20 Hz (%)", col(&|s| 100.0 * s.share_20)),
        ("gyroscopes: power above 10 Hz (%)", col(&|s| 100.0 * s.gyro_share_10)),
        ("rate RMS (rad/s)", col(&|s| s.rate_rms_rad_s)),
        ("rate, 99th percentile (rad/s)", col(&|s| s.rate_p99_rad_s)),
        ("angular acceleration, median (rad/s^2)", col(&|s| s.alpha_median_rad_s2)),
        ("largest output (m/s^2)", col(&|s| s.accel_max_m_s2)),
        ("samples with an accelerometer clipped (%)", col(&|s| 100.0 * s.accel_clipped_share)),
        ("samples with a gyroscope clipped (%)", col(&|s| 100.0 * s.gyro_clipped_share)),
        ("jerk from 5-point differences, median (m/s^3)", col(&|s| s.diff_jerk_median_m_s3)),
        ("gyroscopes' disagreement per axis, RMS (rad/s), lowest package", col(&|s| s.gyro_disagreement_rad_s[0])),
        ("gyroscopes' disagreement per axis, RMS (rad/s), highest package", col(&|s| s.gyro_disagreement_rad_s[1])),
        ("gyroscopes' disagreement: power along alpha (%), lowest package", col(&|s| 100.0 * s.along_alpha[0])),
        ("gyroscopes' disagreement: power along alpha (%), highest package", col(&|s| 100.0 * s.along_alpha[1])),
        ("gyroscope time offsets, std (ms), lowest package", col(&|s| s.offset_std_ms[0])),
        ("gyroscope time offsets, std (ms), highest package", col(&|s| s.offset_std_ms[1])),
        ("gyroscope time offsets, lag-1 autocorrelation, lowest", col(&|s| s.offset_lag1[0])),
        ("gyroscope time offsets, lag-1 autocorrelation, highest", col(&|s| s.offset_lag1[1])),
        ("rigid fit (12 unknowns a sample), residual RMS (m/s^2)", col(&|s| s.rigid_residual_m_s2)),
        ("share of it the clocks' ages remove (+3 unknowns: jerk) (%)", col(&|s| 100.0 * s.ages_removed)),
        ("the same with the ages permuted among packages (%)", col(&|s| 100.0 * s.ages_removed_null)),
        ("rigid fit with the ages, residual RMS (m/s^2)", col(&|s| s.rigid_residual_after_m_s2)),
        ("fitted jerk s', median magnitude (m/s^3)", col(&|s| s.fitted_jerk_median_m_s3)),
        (
            "gfcal calibrate (gyroscope-free, no clock model): dynamic residual RMS (m/s^2)",
            col(&|s| s.calibrate_residual_m_s2),
        ),
    ]
}

/// The measures of simulated recordings of a protocol (truth from the config's `[errors]`),
/// with the true jerk's median and its correlation with the 5-point differences.
fn simulated_stats(
    cell: &ProtocolCell,
    seeds: std::ops::Range<u64>,
    location_sigma_m: f64,
) -> (Vec<PhaseStats>, Vec<f64>, Vec<f64>) {
    let (mut stats, mut jerk, mut corr) = (Vec::new(), Vec::new(), Vec::new());
    for seed in seeds {
        let truth = config_truth_with(&cell.array, seed, location_sigma_m);
        let t0 = std::time::Instant::now();
        let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        eprintln!("seed {seed}: simulated in {:.2} s", t0.elapsed().as_secs_f64());
        let (params, resid, rows) = baseline_calibration(&cell.array, &sim.recording);
        let clocks: Vec<Option<SampleClock>> = if sim.clocks.iter().all(Option::is_some) {
            sim.clocks.clone()
        } else {
            // no clocks: zero ages (the "ages" rows then measure nothing)
            vec![
                Some(SampleClock { nominal_hz: 1000.0, rate_offset: 0.0, drift_per_s: 0.0, phase_s: 0.0, t_ref_s: 0.0 });
                cell.array.packages.len()
            ]
        };
        let mut st = phase_stats(&cell.array, &sim.recording, &rows, &params, &clocks);
        st.calibrate_residual_m_s2 = resid;
        stats.push(st);
        jerk.push(median(rows.iter().map(|&i| sim.jerk_m_s3[i].norm()).collect()));
        let dt = 1.0 / cell.protocol.sample_rate_hz;
        let fmean: Vec<Vector3<f64>> = rows.iter().map(|&i| sim.motion[i].f_m_s2).collect();
        let dj = five_point(&fmean, dt);
        let (a, b): (Vec<f64>, Vec<f64>) = (2..rows.len() - 2)
            .flat_map(|k| (0..3).map(move |c| (k, c)))
            .map(|(k, c)| (sim.jerk_m_s3[rows[k]][c], dj[k][c]))
            .unzip();
        corr.push(correlation(&a, &b));
    }
    (stats, jerk, corr)
}

/// Tuning aid (not a check): the measures of simulated rotation phases of the matched protocol,
/// overridden by `GFCAL_SIM` (see [`tuned_protocol`]), e.g. `GFCAL_SIM="vib=30 vband=2,40"`;
/// `GFCAL_SEEDS=3` recordings, `GFCAL_LOC_MM=0.5` the truth's location sigma.
#[test]
#[ignore = "tuning aid: prints the measures of simulated recordings"]
fn print_the_measures_of_simulated_rotation_phases() {
    let spec = std::env::var("GFCAL_SIM").unwrap_or_default();
    let seeds: u64 = std::env::var("GFCAL_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(2);
    let (cell, _) = tuned_protocol(&spec);
    eprintln!("{:?}", cell.protocol.vibration);
    let loc_mm: f64 =
        std::env::var("GFCAL_LOC_MM").ok().and_then(|s| s.parse().ok()).unwrap_or(CONFIG_LOCATION_SIGMA_M * 1e3);
    let (stats, jerk, corr) = simulated_stats(&cell, 1..1 + seeds, loc_mm * 1e-3);
    for (name, v) in table_rows(&stats) {
        eprintln!("{name:<80} {}", range(&v));
    }
    eprintln!("{:<80} {}", "true jerk at the sample instants, median (m/s^3)", range(&jerk));
    eprintln!("{:<80} {}", "its correlation with the 5-point differences", range(&corr));
}

/// The match table of docs/real-hardware.md: every measure on the six real recordings and on
/// three simulated recordings of configs/mimu4444_protocol.toml, by the same code. The real
/// recordings' ages come from their gyroscopes' clocks (tests/gfcal/clock.rs), the simulated
/// ones' from their truth.
#[test]
#[ignore = "real data, 6 recordings and 3 simulated ones: prints the match table (a few minutes)"]
fn print_the_match_table_of_the_real_recordings_and_the_matched_protocol() {
    let array = mimu_array();
    let real: Vec<PhaseStats> = (1..=6)
        .map(|k| {
            let rec = Recording::read(&shared_recording(k), &array).expect("recording");
            let (params, resid, rows) = baseline_calibration(&array, &rec);
            let clocks: Vec<Option<SampleClock>> = super::clock::gyro_clocks(k).iter().map(|f| Some(f.clock)).collect();
            let mut st = phase_stats(&array, &rec, &rows, &params, &clocks);
            st.calibrate_residual_m_s2 = resid;
            eprintln!("recording {k}: {st:?}");
            st
        })
        .collect();
    let (sim, jerk, corr) = simulated_stats(&matched_cell(), 1..4, CONFIG_LOCATION_SIGMA_M);
    println!("| measure (rotation phase) | real, 6 recordings | simulated, 3 recordings |\n|---|---|---|");
    for ((name, r), (_, s)) in table_rows(&real).into_iter().zip(table_rows(&sim)) {
        println!("| {name} | {} | {} |", range(&r), range(&s));
    }
    println!("| true jerk at the sample instants, median (m/s^3) | - | {} |", range(&jerk));
    println!("| its correlation with the 5-point differences | - | {} |", range(&corr));
}

// ---------------------------------------------------------------------------------------------
// The generator's own checks (issue 28, item 2), each against an oracle independent of it.

/// Per row, the affine field `v_p = s + W r_p` of the packages' vectors (exact for a rigid body):
/// `(s, W, residual RMS)`.
fn affine_field(
    positions: &[Vector3<f64>],
    vectors: &[Vec<Vector3<f64>>],
    i: usize,
) -> (Vector3<f64>, nalgebra::Matrix3<f64>, f64) {
    let p = positions.len();
    let x = DMatrix::from_fn(p, 4, |r, c| if c == 0 { 1.0 } else { positions[r][c - 1] });
    let svd = x.clone().svd(true, true);
    let mut s = Vector3::zeros();
    let mut w = nalgebra::Matrix3::zeros();
    let mut ss = 0.0;
    for k in 0..3 {
        let y = DVector::from_fn(p, |r, _| vectors[r][i][k]);
        let b = svd.solve(&y, 1e-12).expect("solve");
        ss += (&y - &x * &b).norm_squared();
        s[k] = b[0];
        for c in 0..3 {
            w[(k, c)] = b[c + 1];
        }
    }
    (s, w, (ss / (3 * p) as f64).sqrt())
}

/// A short protocol at a host rate high enough to differentiate the vibration numerically:
/// 2 poses of 1 s, then 4 s of rotation (its first 2 s the ramp), vibration translational and
/// angular, no noise, no clocks.
fn fast_vibrating_protocol(n: usize, rate_hz: f64) -> Protocol {
    let mut p = protocol(n);
    p.poses = 2;
    p.pose_s = 1.0;
    p.transition_s = 0.5;
    p.dynamic_s = 4.0;
    p.sample_rate_hz = rate_hz;
    p.noise_sigma_m_s2 = vec![0.0; n];
    p.gyro_noise_sigma_rad_s = 0.0;
    p.vibration = Vibration {
        accel_rms_m_s2: 40.0,
        rate_rms_rad_s: 3.0,
        band_hz: [2.0, 40.0],
        rate_band_hz: Some([2.0, 20.0]),
        low_pass: gfcal::selfcal::vibration::LowPass::Second,
        rate_low_pass: gfcal::selfcal::vibration::LowPass::Third,
        rate_exponent: 1.0,
        sensor_rms_m_s2: 0.0,
        sensor_rate_exponent: None,
        sensor_bursts: None,
    };
    p
}

/// With the vibration on (translational and angular, following the rate) and no clocks, the
/// generator is a rigid body. Oracles: (i) the packages' noise-free outputs are an affine field
/// of position (a rigid body's specific force is `f + W r` exactly); (ii) W's symmetric part is
/// `w w^T - |w|^2 I` with w the gyroscopes' rate; (iii) its antisymmetric part is the angular
/// acceleration: the gyroscopes' rate moves by its integral; (iv) f moves by the integral of the
/// generator's jerk truth, so the attitude turns with the rate the gyroscopes read (a wrong one
/// would add (w - w') x f). The vibration's drive is held over each 0.1 ms step of the fine grid,
/// so the angular acceleration and the jerk are continuous but kinked at its points: the
/// integrals are taken by Simpson's rule over one grid step (host samples at twice the grid's
/// rate, an interval's ends on grid points), where every signal is smooth (error of order
/// `(2 pi f h)^4 / 2880`, below 1e-9 relative at 40 Hz); central differences across the kinks
/// would only converge as `sqrt(h)` (9% at 10 kHz).
#[test]
fn with_vibration_and_no_clocks_the_generator_is_a_rigid_body() {
    let array = mimu_array();
    let n = array.array.len();
    let p = fast_vibrating_protocol(n, 2.0 / FINE_STEP_S);
    let sim = simulate(&array, &SensorSet::nominal(n), &p, &mut trial_rng(11, 1)).expect("simulated");
    let rec = &sim.recording;
    let rows = rotation_rows(&p, rec);
    let vecs = package_vectors(&array, rec, &rows, &SensorSet::nominal(n));
    let pos = package_positions(&array);
    let h = FINE_STEP_S;
    let start = p.rotation_centre_s() - 0.5 * p.dynamic_s;
    let fields: Vec<_> = (0..rows.len()).map(|r| affine_field(&pos, &vecs, r)).collect();
    let clipped = |r: usize| rec.gyro_clipped[rows[r]] || (0..n).any(|j| rec.is_clipped(rows[r], j));
    let (mut worst_affine, mut worst_sym, mut scale_f) = (0.0_f64, 0.0_f64, 0.0_f64);
    let (mut alpha_err, mut alpha_ss, mut jerk_err, mut jerk_ss) = (0.0, 0.0, 0.0, 0.0);
    let mut checked = 0;
    let alpha_of = |w: &nalgebra::Matrix3<f64>| {
        let asym = (w - w.transpose()) * 0.5;
        Vector3::new(asym[(2, 1)], asym[(0, 2)], asym[(1, 0)])
    };
    let simpson = |a: Vector3<f64>, m: Vector3<f64>, b: Vector3<f64>| (a + m * 4.0 + b) * (h / 6.0);
    for r in 0..rows.len() - 2 {
        let k = ((rec.t_s[rows[r]] - start) / (0.5 * h)).round() as i64;
        if k % 2 != 0 || clipped(r) || clipped(r + 1) || clipped(r + 2) {
            continue;
        }
        checked += 1;
        let (f, w, rms) = fields[r];
        scale_f = scale_f.max(f.norm());
        worst_affine = worst_affine.max(rms);
        let om = rec.gyro_rate_rad_s[rows[r]];
        let sym = (w + w.transpose()) * 0.5;
        let cent = om * om.transpose() - nalgebra::Matrix3::identity() * om.norm_squared();
        worst_sym = worst_sym.max((sym - cent).abs().max() / om.norm_squared().max(1.0));
        let dw = rec.gyro_rate_rad_s[rows[r + 2]] - om;
        let int_alpha = simpson(alpha_of(&w), alpha_of(&fields[r + 1].1), alpha_of(&fields[r + 2].1));
        alpha_err += (int_alpha - dw).norm_squared();
        alpha_ss += dw.norm_squared();
        let df = fields[r + 2].0 - f;
        let j = |q: usize| sim.jerk_m_s3[rows[q]];
        jerk_err += (simpson(j(r), j(r + 1), j(r + 2)) - df).norm_squared();
        jerk_ss += df.norm_squared();
    }
    let (alpha_rel, jerk_rel) = ((alpha_err / alpha_ss).sqrt(), (jerk_err / jerk_ss).sqrt());
    eprintln!(
        "{checked} grid steps: affine residual {worst_affine:.2e} m/s^2 (|f| up to {scale_f:.0}); centripetal {worst_sym:.2e}; alpha {alpha_rel:.2e}; jerk {jerk_rel:.2e} (RMS {:.0} m/s^3)",
        (jerk_ss / checked as f64).sqrt() / h
    );
    assert!(checked > rows.len() / 4, "{checked} of {} rows", rows.len());
    // rounding of outputs of up to 150 m/s^2 through an 8 x 4 least squares
    assert!(worst_affine < 1e-9, "not an affine field: {worst_affine:e} m/s^2");
    assert!(worst_sym < 1e-9, "W's symmetric part is not the gyroscopes' centripetal term: {worst_sym:e}");
    assert!(alpha_rel < 1e-5, "the gyroscopes' rate does not move by W's angular acceleration: {alpha_rel:e}");
    assert!(jerk_rel < 1e-5, "f does not move by the jerk truth: {jerk_rel:e}");
}

/// The fast vibrating protocol over 6 s, its rigid vibration stationary (exactly affine in the
/// packages' positions), with each accelerometer's own error of `sensor_rms_m_s2`.
fn sensor_error_protocol(n: usize, sensor_rms_m_s2: f64) -> Protocol {
    let mut p = fast_vibrating_protocol(n, 0.5 / FINE_STEP_S);
    p.dynamic_s = 6.0;
    p.vibration.rate_exponent = 0.0;
    p.vibration.sensor_rms_m_s2 = sensor_rms_m_s2;
    p
}

/// Each accelerometer's own error under the vibration (`Vibration::sensor_rms_m_s2`) is not a
/// rigid motion: with it on, stationary (no envelope), no clocks and no noise, the packages'
/// outputs leave an affine field (exact for the rigid part, the test above) by the error alone. An
/// independent error of RMS `s` on each of the 8 packages' 3 outputs leaves a least-squares fit of 4
/// unknowns per component a mean square of `s^2 (8 - 4) / 8`. Over 3 s of a 2-40 Hz process
/// (about 240 independent values per output, 24 outputs) the RMS is within 5%; 15% allowed.
#[test]
fn each_accelerometers_own_vibration_error_is_not_a_rigid_motion_and_has_its_rms() {
    let array = mimu_array();
    let n = array.array.len();
    let sensor_rms_m_s2 = 0.5;
    let mut p = sensor_error_protocol(n, sensor_rms_m_s2);
    let sim = simulate(&array, &SensorSet::nominal(n), &p, &mut trial_rng(12, 1)).expect("simulated");
    let rec = &sim.recording;
    let rows = rotation_rows(&p, rec);
    let vecs = package_vectors(&array, rec, &rows, &SensorSet::nominal(n));
    let pos = package_positions(&array);
    let mut ms = 0.0;
    let mut used = 0;
    for (r, &row) in rows.iter().enumerate() {
        if rec.gyro_clipped[row] || (0..n).any(|j| rec.is_clipped(row, j)) {
            continue;
        }
        ms += affine_field(&pos, &vecs, r).2.powi(2);
        used += 1;
    }
    assert!(used > rows.len() / 2, "{used} of {} rows", rows.len());
    let rms = (ms / used as f64 / 0.5).sqrt();
    eprintln!("{used} rows: the error's RMS from the affine field's residual {rms:.4} m/s^2 (set {sensor_rms_m_s2})");
    assert!((rms / sensor_rms_m_s2 - 1.0).abs() < 0.15, "{rms} against {sensor_rms_m_s2}");
    // Off, the same protocol is a rigid body to rounding (the sensor error is all of it).
    p.vibration.sensor_rms_m_s2 = 0.0;
    let sim = simulate(&array, &SensorSet::nominal(n), &p, &mut trial_rng(12, 1)).expect("simulated");
    let vecs = package_vectors(&array, &sim.recording, &rows, &SensorSet::nominal(n));
    let worst = (0..rows.len()).map(|r| affine_field(&pos, &vecs, r).2).fold(0.0, f64::max);
    assert!(worst < 1e-9, "{worst}");
}

/// The accelerometers' own error follows the rotation's rate to its own power
/// (`Vibration::sensor_rate_exponent`), the rigid vibration to its own. Oracles: the envelope is
/// `G^k` with `G` the same at a given instant for every `k`, and the error's process is drawn the
/// same whatever `k`, so with the rigid part exactly affine (no clocks, no noise) each row's
/// non-rigid residual at `k = 4` is its residual at `k = 2` times the ratio of that to `k = 0`'s,
/// to rounding; an unset exponent is the rigid vibration's, bit for bit; and without the sensor
/// error the exponent changes nothing.
#[test]
fn each_accelerometers_own_error_follows_the_rate_to_its_own_power() {
    let array = mimu_array();
    let n = array.array.len();
    let p = sensor_error_protocol(n, 0.5);
    let run = |p: &Protocol| simulate(&array, &SensorSet::nominal(n), p, &mut trial_rng(12, 1)).expect("simulated");
    let rows = rotation_rows(&p, &run(&p).recording);
    let pos = package_positions(&array);
    // Each row's non-rigid residual, NaN where an output is clipped.
    let residuals = |p: &Protocol| -> Vec<f64> {
        let rec = run(p).recording;
        let vecs = package_vectors(&array, &rec, &rows, &SensorSet::nominal(n));
        (0..rows.len())
            .map(|r| if (0..n).any(|j| rec.is_clipped(rows[r], j)) { f64::NAN } else { affine_field(&pos, &vecs, r).2 })
            .collect()
    };
    let with = |k: Option<f64>| Protocol {
        vibration: Vibration { sensor_rate_exponent: k, ..p.vibration.clone() },
        ..p.clone()
    };
    let (r0, r2, r4) = (residuals(&with(Some(0.0))), residuals(&with(Some(2.0))), residuals(&with(Some(4.0))));
    let mut spread = (f64::INFINITY, 0.0_f64);
    let mut checked = 0;
    for r in (0..rows.len()).filter(|&r| r0[r].is_finite() && r2[r].is_finite() && r4[r].is_finite()) {
        checked += 1;
        let g2 = r2[r] / r0[r];
        spread = (spread.0.min(g2), spread.1.max(g2));
        assert!((r4[r] / r0[r] - g2 * g2).abs() < 1e-6 * g2 * g2, "row {r}: {} against {}", r4[r] / r0[r], g2 * g2);
    }
    assert!(checked > rows.len() / 2, "{checked} of {} rows", rows.len());
    // The envelope does move over the rows (else the check above says nothing).
    assert!(spread.1 > 2.0 * spread.0, "G^2 over the rows {spread:?}");
    // Unset: the rigid vibration's exponent (0 here), bit for bit.
    assert_eq!(run(&with(None)).recording.outputs, run(&with(Some(0.0))).recording.outputs);
    // Without the sensor error the exponent changes nothing.
    let mut quiet = with(Some(8.0));
    quiet.vibration.sensor_rms_m_s2 = 0.0;
    let mut plain = p.clone();
    plain.vibration.sensor_rms_m_s2 = 0.0;
    assert_eq!(run(&quiet).recording.outputs, run(&plain).recording.outputs);
}

/// The accelerometers' own error in bursts at random times (`Vibration::sensor_bursts`). Oracles,
/// with no clocks (every package reads at one instant) and no noise: a row is either a rigid body
/// to rounding (the affine field's residual under 1e-9, as with the error off) or clearly not
/// (above 1e-3 m/s^2), and both kinds occur; at a duty of 1 the error is the stationary one
/// (`sensor_rate_exponent` 0) bit for bit; inside the bursts its RMS is `sensor_rms / sqrt(duty)`
/// (from the affine field's residual as in the test above: bursts of 0.1 s on average, about 0.9 s
/// of them in the 3 s of rows, some 800 residual degrees of freedom of a 2-40 Hz process on 24
/// outputs, the RMS within about 2.5%; 15% allowed).
#[test]
fn each_accelerometers_own_error_in_bursts_at_random_times_is_zero_between_them() {
    let array = mimu_array();
    let n = array.array.len();
    let sensor_rms_m_s2 = 0.5;
    let p = sensor_error_protocol(n, sensor_rms_m_s2);
    let run = |p: &Protocol| simulate(&array, &SensorSet::nominal(n), p, &mut trial_rng(12, 1)).expect("simulated");
    let with = |duty: f64| Protocol {
        vibration: Vibration { sensor_bursts: Some(SensorBursts { duty, mean_s: 0.1 }), ..p.vibration.clone() },
        ..p.clone()
    };
    let duty = 0.3;
    let rec = run(&with(duty)).recording;
    let rows = rotation_rows(&p, &rec);
    let vecs = package_vectors(&array, &rec, &rows, &SensorSet::nominal(n));
    let pos = package_positions(&array);
    let (mut rigid, mut inside, mut ms) = (0, 0, 0.0);
    for (r, &row) in rows.iter().enumerate() {
        if rec.gyro_clipped[row] || (0..n).any(|j| rec.is_clipped(row, j)) {
            continue;
        }
        let residual = affine_field(&pos, &vecs, r).2;
        assert!(!(1e-9..=1e-3).contains(&residual), "row {r}: {residual} m/s^2, neither rigid nor in a burst");
        if residual < 1e-9 {
            rigid += 1;
        } else {
            inside += 1;
            ms += residual * residual;
        }
    }
    let rms = (ms / inside as f64 / 0.5).sqrt();
    let expected = sensor_rms_m_s2 / duty.sqrt();
    eprintln!("{rigid} rigid rows, {inside} in bursts: the error's RMS there {rms:.4} m/s^2 (expected {expected:.4})");
    assert!(rigid > 0 && inside > 100, "{rigid} rigid, {inside} in bursts");
    assert!((rms / expected - 1.0).abs() < 0.15, "{rms} against {expected}");
    let mut stationary = p.clone();
    stationary.vibration.sensor_rate_exponent = Some(0.0);
    assert_eq!(run(&with(1.0)).recording.outputs, run(&stationary).recording.outputs);
}

/// The matched protocol shortened for a test: 4 poses of 8 s in random directions, `dynamic_s` of
/// rotation, and no bias drift (the board's 20-pose sequence and its drift are the static phase's,
/// which a shortened protocol does not keep: its first 4 directions all lie below y = 0).
pub fn short_matched(dynamic_s: f64) -> ProtocolCell {
    let mut cell = matched_cell();
    cell.protocol.poses = 4;
    cell.protocol.pose_s = 8.0;
    cell.protocol.dynamic_s = dynamic_s;
    cell.protocol.pose_up = None;
    cell.protocol.bias_drift = None;
    cell
}

/// With the matched vibration on and the clocks off, the noisy outputs fit a rigid body to the
/// noise: the per-sample rigid fit (12 unknowns, 24 axes) leaves `sigma sqrt(12 / 24)` per axis
/// (the residual degrees of freedom of white noise); with the clocks on, the same motion leaves
/// tens of times more (the effect the generator exists for).
#[test]
fn with_the_matched_vibration_and_no_clocks_the_outputs_fit_a_rigid_body_to_the_noise() {
    let cell = short_matched(30.0);
    let array = &cell.array;
    let n = array.array.len();
    let truth = SensorSet::nominal(n);
    let mut p = cell.protocol.clone();
    assert!(p.vibration.is_on() && p.clocks.is_some(), "the shipped protocol vibrates and has clocks");
    // The rigid vibration alone: the config's sensor error in bursts is not a rigid body (its own
    // test, `each_accelerometers_own_error_in_bursts_at_random_times_is_zero_between_them`).
    assert!(p.vibration.sensor_bursts.is_some(), "the shipped protocol has the sensor error in bursts");
    p.vibration.sensor_rms_m_s2 = 0.0;
    let with_clocks = simulate(array, &truth, &p, &mut trial_rng(21, 1)).expect("simulated");
    p.clocks = None;
    let rigid = simulate(array, &truth, &p, &mut trial_rng(21, 1)).expect("simulated");
    let sigma = p.noise_sigma_m_s2[0];
    let expected = sigma * (12.0_f64 / 24.0).sqrt();
    let pos = package_positions(array);
    let fit = |sim: &Simulated| {
        let rec = &sim.recording;
        let rows: Vec<usize> =
            rotation_rows(&p, rec).into_iter().filter(|&i| !(0..n).any(|j| rec.is_clipped(i, j))).collect();
        let vecs = package_vectors(array, rec, &rows, &truth);
        (rigid_fit(&pos, &vecs, None).residual_rms_m_s2, rows.len())
    };
    let (r0, rows0) = fit(&rigid);
    let (r1, _) = fit(&with_clocks);
    eprintln!("rigid fit residual: no clocks {r0:.4} m/s^2 ({rows0} rows; noise alone {expected:.4}); clocks {r1:.3}");
    // 12 x rows residual degrees of freedom: the RMS's relative sigma is 1 / sqrt(24 rows) < 0.5%
    assert!((r0 / expected - 1.0).abs() < 0.03, "no clocks: {r0} against the noise's {expected}");
    assert!(r1 > 10.0 * expected, "clocks: {r1}");
}

/// With the clocks on, on a noise-free recording of the matched protocol (gyroscopes without
/// their anti-alias filter), each package's
/// gyroscope disagreement with the packages' mean, projected on the angular acceleration, is the
/// package's age less the packages' mean: its clock's sawtooth (correlation > 0.95, regression
/// slope within 5% of 1, with the true angular acceleration at the host's instant; the same
/// measure with the five-point derivative of the mean rate, as on the real recordings, is
/// printed: the vibration's angular acceleration above 10 Hz dilutes it there). The same ages,
/// with a jerk per sample, explain the accelerometers' departure from a rigid body (more than 80%
/// of it; the ages of other packages: less than 40%, what 3 unknowns a sample remove by chance),
/// so a package's accelerometers sample at its gyroscope's instants.
#[test]
fn with_clocks_the_gyroscopes_disagreement_is_the_clocks_sawtooth() {
    let cell = short_matched(30.0);
    let array = &cell.array;
    let n = array.array.len();
    let truth = SensorSet::nominal(n);
    let mut p = cell.protocol.clone();
    p.noise_sigma_m_s2 = vec![0.0; n];
    p.gyro_noise_sigma_rad_s = 0.0;
    // the gyroscopes unfiltered, so that their rate's derivative is the true angular acceleration
    p.anti_alias.gyro_time_constant_s = 0.0;
    let sim = simulate(array, &truth, &p, &mut trial_rng(31, 1)).expect("simulated");
    let rec = &sim.recording;
    let clocks: Vec<SampleClock> = sim.clocks.iter().map(|c| c.expect("every package has a clock")).collect();
    assert_eq!(clocks.len(), 8);
    let centre = p.rotation_centre_s();
    for c in &clocks {
        assert_eq!(c.t_ref_s, centre, "clocks given at the rotation phase's centre");
        assert!(c.phase_s >= 0.0 && c.phase_s < 1e-3);
    }
    let rows = rotation_rows(&p, rec);
    let pk = &rec.package_gyro_rate_rad_s;
    let relative_age = |q: usize, t: f64| clocks[q].age_s(t) - clocks.iter().map(|c| c.age_s(t)).sum::<f64>() / 8.0;
    let gt = gyro_timing(rec, &rows, 300.0);
    let mut worst: f64 = 1.0;
    for q in 0..8 {
        let (mut y, mut y5, mut age, mut age5) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (r, &i) in rows.iter().enumerate() {
            let alpha = sim.motion[i].alpha_rad_s2;
            if !rec.gyro_clipped[i] && alpha.norm() > 300.0 {
                let mean = pk.iter().map(|w| w[i]).sum::<Vector3<f64>>() / 8.0;
                y.push(-(pk[q][i] - mean).dot(&alpha) / alpha.norm_squared());
                age.push(relative_age(q, rec.t_s[i]));
            }
            if gt.offset_s[q][r].is_finite() {
                y5.push(gt.offset_s[q][r]);
                age5.push(relative_age(q, rec.t_s[i]));
            }
        }
        let r = correlation(&y, &age);
        let slope = y.iter().zip(&age).map(|(x, a)| x * a).sum::<f64>() / age.iter().map(|a| a * a).sum::<f64>();
        eprintln!(
            "package {}: {} offsets, correlation {r:.4}, slope {slope:.4}; five-point alpha: correlation {:.3}; rate offset {:.0} ppm",
            q + 1,
            y.len(),
            correlation(&y5, &age5),
            clocks[q].rate_offset * 1e6
        );
        assert!(y.len() > 500, "package {}: {} offsets", q + 1, y.len());
        assert!(r > 0.95 && (slope - 1.0).abs() < 0.05, "package {}: correlation {r}, slope {slope}", q + 1);
        worst = worst.min(r);
    }
    // The accelerometers: the rigid fit with the packages' true ages (and a jerk per sample).
    let some: Vec<Option<SampleClock>> = clocks.iter().map(|&c| Some(c)).collect();
    let st = phase_stats(array, rec, &rows, &truth, &some);
    eprintln!(
        "worst gyroscope correlation {worst:.4}; accelerometers: rigid residual {:.3} m/s^2, the ages remove {:.1}% (permuted {:.1}%)",
        st.rigid_residual_m_s2,
        100.0 * st.ages_removed,
        100.0 * st.ages_removed_null
    );
    assert!(st.ages_removed > 0.8, "the ages remove {}", st.ages_removed);
    assert!(st.ages_removed_null < 0.4, "permuted ages remove {}", st.ages_removed_null);
}

/// The matched protocol's rotation phase has the real recordings' spectrum. On the six real
/// recordings, by this measure (the packages' mean specific force, calibrated, Welch): 38.0-40.7%
/// of the power above 10 Hz, 19.9-21.5% above 20 Hz, the gyroscopes 2.0-2.3% above 10 Hz, rates of
/// 28.0-30.1 rad/s RMS (docs/real-hardware.md). One simulated recording of 40 s must fall within
/// 3 points (1 for the gyroscopes, 3 rad/s) of that range: what 40 s of a random motion scatters.
#[test]
fn the_matched_protocol_has_the_real_recordings_spectrum() {
    let cell = short_matched(40.0);
    let truth = config_truth(&cell.array, 41);
    let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(41, 1)).expect("simulated");
    let rec = &sim.recording;
    let rows = rotation_rows(&cell.protocol, rec);
    let fs = cell.protocol.sample_rate_hz;
    let vecs = package_vectors(&cell.array, rec, &rows, &truth);
    let mean: Vec<Vector3<f64>> =
        (0..rows.len()).map(|i| vecs.iter().map(|v| v[i]).sum::<Vector3<f64>>() / vecs.len() as f64).collect();
    let w: Vec<Vector3<f64>> = rows.iter().map(|&i| rec.gyro_rate_rad_s[i]).collect();
    let (s10, s20, g10) = (share_above(&mean, fs, 10.0), share_above(&mean, fs, 20.0), share_above(&w, fs, 10.0));
    let rate = (w.iter().map(|v| v.norm_squared()).sum::<f64>() / w.len() as f64).sqrt();
    eprintln!("above 10 Hz {s10:.3}, above 20 Hz {s20:.3}; gyroscopes above 10 Hz {g10:.3}; rate RMS {rate:.1} rad/s");
    assert!((0.35..=0.44).contains(&s10), "specific force above 10 Hz: {s10}");
    assert!((0.17..=0.245).contains(&s20), "specific force above 20 Hz: {s20}");
    assert!((0.01..=0.033).contains(&g10), "gyroscopes above 10 Hz: {g10}");
    assert!((25.0..=33.0).contains(&rate), "rate RMS {rate}");
}

/// Only packages that declare `sample_clock_hz` and `sample_and_hold` get a clock: with none
/// declared, a protocol with clocks gives no clock and the very recording of a protocol without
/// (fixed rate offsets draw nothing at random).
#[test]
fn packages_that_declare_no_clock_are_read_at_the_hosts_instants() {
    let array = without_clocks(&mimu_array());
    let n = array.array.len();
    let mut p = fast_vibrating_protocol(n, 62.5);
    p.dynamic_s = 3.0;
    p.clocks = Some(board_clocks());
    let a = simulate(&array, &SensorSet::nominal(n), &p, &mut trial_rng(51, 1)).expect("simulated");
    assert!(a.clocks.iter().all(Option::is_none));
    p.clocks = None;
    let b = simulate(&array, &SensorSet::nominal(n), &p, &mut trial_rng(51, 1)).expect("simulated");
    assert_eq!(digest(&a), digest(&b));
    let with = simulate(
        &mimu_array(),
        &SensorSet::nominal(n),
        &Protocol { clocks: Some(board_clocks()), ..p.clone() },
        &mut trial_rng(51, 1),
    )
    .expect("simulated");
    assert!(with.clocks.iter().all(Option::is_some));
    assert_ne!(digest(&with), digest(&b), "declared clocks change the recording");
}

/// Poses placed on listed up directions are held there: the simulator's own up direction at the
/// middle of every pose is the listed one (normalised), on the smooth generator and on the fine
/// grid (vibration on), and the gravity the outputs see is along it.
#[test]
fn poses_on_listed_directions_hold_them() {
    let array = mimu_array();
    let n = array.array.len();
    let listed = [
        Vector3::new(0.0, -0.9342, 0.3568),
        Vector3::new(1.0, -1.0, 1.0),
        Vector3::new(0.0, 0.0, -2.0),
        Vector3::new(0.0, 0.0, 1.0),
    ];
    let mut fine = fast_vibrating_protocol(n, 62.5);
    fine.pose_s = 2.0;
    for mut p in [protocol(n), fine] {
        p.poses = listed.len();
        p.pose_up = Some(listed.to_vec());
        let sim = simulate(&array, &SensorSet::nominal(n), &p, &mut trial_rng(71, 1)).expect("simulated");
        let t = &sim.recording.t_s;
        for (k, want) in listed.iter().enumerate() {
            let mid_s = k as f64 * (p.pose_s + p.transition_s) + 0.5 * p.pose_s;
            let i = t.iter().position(|&ti| ti >= mid_s).expect("the pose's middle is sampled");
            let (up, want) = (sim.up[i], want.normalize());
            assert!((up - want).norm() < 1e-12, "pose {k}: up {up:?}, listed {want:?}");
            // Still: the specific force is gravity, up.
            let f = sim.motion[i].f_m_s2;
            assert!((f - want * p.gravity_m_s2).norm() < 1e-9, "pose {k}: specific force {f:?}");
        }
    }
}

/// A bias drift adds `rate_j (t - t_mid)` to every output, `t_mid` halfway through the recording,
/// and nothing else: fixed rates draw nothing at random, so the noise is the same draw with and
/// without it. On the smooth generator and on the fine grid (vibration on), for drift rates that
/// differ per accelerometer plus a common one; clipped outputs are left out.
#[test]
fn a_bias_drift_adds_its_line_about_the_recordings_middle() {
    let array = mimu_array();
    let n = array.array.len();
    let truth = SensorSet::nominal(n);
    let own: Vec<f64> = (0..n).map(|j| (j as f64 - 10.0) * 1e-4).collect();
    let drift = BiasDriftSpread { own: Spread::Fixed(own.clone()), common: Spread::Fixed(vec![3e-4]) };
    let mut fine = fast_vibrating_protocol(n, 62.5);
    fine.noise_sigma_m_s2 = vec![0.04; n];
    for p in [protocol(n), fine] {
        let a = simulate(&array, &truth, &p, &mut trial_rng(61, 1)).expect("simulated");
        let with = Protocol { bias_drift: Some(drift.clone()), ..p.clone() };
        let b = simulate(&array, &truth, &with, &mut trial_rng(61, 1)).expect("simulated");
        let (ra, rb) = (&a.recording, &b.recording);
        assert_eq!(ra.t_s, rb.t_s);
        let t = &ra.t_s;
        let t_mid = 0.5 * (t[0] + t[t.len() - 1]);
        let mut checked = 0;
        for (i, t_i) in t.iter().enumerate() {
            for (j, own_j) in own.iter().enumerate() {
                if ra.is_clipped(i, j) || rb.is_clipped(i, j) {
                    continue;
                }
                let expected = (own_j + 3e-4) * (t_i - t_mid);
                let moved = rb.outputs[(i, j)] - ra.outputs[(i, j)];
                assert!((moved - expected).abs() < 1e-12, "sample {i}, accelerometer {j}: {moved} vs {expected}");
                checked += 1;
            }
        }
        assert!(checked > ra.samples() * n * 9 / 10);
    }
}

/// The folder an environment variable names for a writing aid, created; `None` (and a hint)
/// where it is not set.
fn output_folder(var: &str) -> Option<std::path::PathBuf> {
    let Ok(dir) = std::env::var(var) else {
        eprintln!("set {var} to a folder");
        return None;
    };
    let dir = std::path::PathBuf::from(dir);
    std::fs::create_dir_all(&dir).expect("output folder");
    Some(dir)
}

/// For checking an estimator of the clocks by hand: writes one simulated recording of the
/// matched protocol (configs/mimu4444_protocol.toml, full length) as `recording.csv` (the
/// array file's columns: `t_s`, the accelerometers, the gyroscopes) and its truth as
/// `truth.json` (every package's clock, 1-based as in `gfcal calibrate --json`'s
/// `sample_clocks`, with `rate_offset_ppm`, `drift_ppm_per_s`, `phase_s` at `t_ref_s`, the
/// rotation phase's centre; every accelerometer's parameters) into `GFCAL_SIM_OUT`, seed
/// `GFCAL_SIM_SEED` (default 1):
///
/// ```sh
/// GFCAL_SIM_OUT=/tmp/sim1 cargo test --locked --test gfcal simulate::write -- --ignored
/// gfcal calibrate /tmp/sim1/recording.csv --array configs/arrays/mimu4444_corners.toml --json /tmp/sim1/cal.json
/// ```
#[test]
#[ignore = "writes a simulated recording and its truth into GFCAL_SIM_OUT"]
fn write_a_simulated_recording_of_the_matched_protocol_with_its_truth() {
    let Some(dir) = output_folder("GFCAL_SIM_OUT") else {
        return;
    };
    let seed: u64 = std::env::var("GFCAL_SIM_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let cell = matched_cell();
    let array = &cell.array;
    let truth = config_truth(array, seed);
    let sim = simulate(array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
    let rec = &sim.recording;
    // The gyroscopes' columns from each package's rate (its three axes span it exactly); a value
    // at its range is written as the range itself, as the simulator clipped it.
    let gyro_column = |g: usize, i: usize| -> f64 {
        let gy = &array.gyroscopes[g];
        let w = match gy.package {
            Some(p) if !rec.package_gyro_rate_rad_s.is_empty() => rec.package_gyro_rate_rad_s[p][i],
            _ => rec.gyro_rate_rad_s[i],
        };
        let v = gy.axis.dot(&w);
        if v.abs() >= gy.range_rad_s * (1.0 - 1e-9) { gy.range_rad_s.copysign(v) } else { v }
    };
    let mut csv = String::from("t_s");
    for c in array.accelerometer_columns.iter().chain(array.gyroscopes.iter().map(|g| &g.column)) {
        csv.push(',');
        csv.push_str(c);
    }
    csv.push('\n');
    for i in 0..rec.samples() {
        csv.push_str(&format!("{}", rec.t_s[i]));
        for j in 0..rec.accelerometers() {
            csv.push_str(&format!(",{}", rec.outputs[(i, j)]));
        }
        for g in 0..array.gyroscopes.len() {
            csv.push_str(&format!(",{}", gyro_column(g, i)));
        }
        csv.push('\n');
    }
    std::fs::write(dir.join("recording.csv"), csv).expect("recording.csv");
    let clocks: Vec<serde_json::Value> = sim
        .clocks
        .iter()
        .enumerate()
        .filter_map(|(p, c)| {
            c.map(|c| {
                serde_json::json!({
                    "package": p + 1,
                    "name": array.packages[p].name,
                    "nominal_hz": c.nominal_hz,
                    "rate_offset_ppm": c.rate_offset * 1e6,
                    "drift_ppm_per_s": c.drift_per_s * 1e6,
                    "phase_s": c.phase_s,
                    "t_ref_s": c.t_ref_s,
                })
            })
        })
        .collect();
    let accelerometers: Vec<serde_json::Value> = (0..array.array.len())
        .map(|j| {
            serde_json::json!({
                "accelerometer": j + 1,
                "scale_factor": truth.scale_factor[j],
                "bias_m_s2": truth.bias_m_s2[j],
                "tilt_u_rad": truth.tilt_rad[j][0],
                "tilt_w_rad": truth.tilt_rad[j][1],
                "dx_m": truth.location_error_m[j].x,
                "dy_m": truth.location_error_m[j].y,
                "dz_m": truth.location_error_m[j].z,
            })
        })
        .collect();
    let json = serde_json::json!({
        "config": "configs/mimu4444_protocol.toml",
        "seed": seed,
        "rotation_start_s": cell.protocol.rotation_centre_s() - 0.5 * cell.protocol.dynamic_s,
        "rotation_centre_s": cell.protocol.rotation_centre_s(),
        "clocks": clocks,
        "accelerometers": accelerometers,
    });
    std::fs::write(dir.join("truth.json"), serde_json::to_string_pretty(&json).expect("json")).expect("truth.json");
    // The file reads back as the recording it was written from.
    let back = Recording::read(&dir.join("recording.csv"), array).expect("reads back");
    assert_eq!(back.outputs, rec.outputs);
    assert_eq!(back.gyro_clipped, rec.gyro_clipped);
    eprintln!("wrote {} and truth.json ({} samples)", dir.join("recording.csv").display(), rec.samples());
}

/// Every used rotation-phase output's residual of `cal` as `(sample, accelerometer, residual)`,
/// in sample order: against the outputs the calibration fitted (corrected by its clocks, where it
/// has them), gyroscope-free.
fn rotation_residuals(array: &RecordingArray, rec: &Recording, cal: &Calibration) -> Vec<(usize, usize, f64)> {
    let d = prepare_dynamic(rec, &cal.segmentation, false, cal.gyro_bias_rad_s).data.expect("a rotation phase");
    let outputs = match cal.clocks.as_ref() {
        Some(c) => corrected_dynamic(array, &cal.fit, &d, c).outputs,
        None => d.outputs.clone(),
    };
    let sens = sensors(&array.array, &cal.fit.params);
    let n = sens.len();
    let mut residuals = Vec::new();
    for i in 0..d.samples() {
        let m = &cal.fit.motion[i];
        for (j, s) in sens.iter().enumerate() {
            if d.used[i * n + j] {
                residuals.push((i, j, outputs[(i, j)] - s.output(&m.specific_force_m_s2(&s.position_m))));
            }
        }
    }
    residuals
}

/// Each sample's sum of squared residuals, its number of residuals and its index, from a rotation
/// phase's residuals (sample, accelerometer, residual; in the order of their samples), the largest
/// sum first.
fn samples_by_misfit(residuals: &[(usize, usize, f64)]) -> Vec<(f64, usize, usize)> {
    let mut per_sample: Vec<(f64, usize, usize)> = Vec::new();
    for &(i, _, r) in residuals {
        if per_sample.last().is_none_or(|x| x.2 != i) {
            per_sample.push((0.0, 0, i));
        }
        if let Some(last) = per_sample.last_mut() {
            last.0 += r * r;
            last.1 += 1;
        }
    }
    per_sample.sort_by(|a, b| b.0.total_cmp(&a.0));
    per_sample
}

/// How many of `n` samples make the worst fraction `q` of them.
fn worst_count(n: usize, q: f64) -> usize {
    ((n as f64) * q).ceil() as usize
}

/// The RMS of a rotation phase's residuals without the 5% of samples with the largest sums of
/// squares (`per_sample` as [`samples_by_misfit`] gives it): the bulk that Huber's weights leave in
/// the fit.
fn bulk_rms_m_s2(per_sample: &[(f64, usize, usize)]) -> f64 {
    let rest = &per_sample[worst_count(per_sample.len(), 0.05)..];
    (rest.iter().map(|x| x.0).sum::<f64>() / rest.iter().map(|x| x.1).sum::<usize>() as f64).sqrt()
}

/// The median rate (rad/s, the calibration's fitted motion) of the 1% of samples with the largest
/// sums of squared residuals, and of every sample with a residual (`per_sample` as
/// [`samples_by_misfit`] gives it).
fn worst_percent_rate_rad_s(per_sample: &[(f64, usize, usize)], cal: &Calibration) -> (f64, f64) {
    let rate = |v: &[(f64, usize, usize)]| median(v.iter().map(|x| cal.fit.motion[x.2].omega_rad_s.norm()).collect());
    (rate(&per_sample[..worst_count(per_sample.len(), 0.01)]), rate(per_sample))
}

/// How the rotation phase's residual of a calibration spreads over its samples: RMS, kurtosis of
/// the outputs' residuals, the shares of the squares the worst 1% and 5% of the samples carry, the
/// RMS without the worst 5%, and the median rate of the worst 1% against all samples'. The
/// residual is taken against the outputs the calibration fitted (corrected by its clocks, where it
/// has them).
fn residual_tail(array: &RecordingArray, rec: &Recording) -> String {
    let cal = calibrate(rec, array, &CalibrateSettings::default()).expect("calibrates");
    let residuals = rotation_residuals(array, rec, &cal);
    let count = residuals.len() as f64;
    let m2 = residuals.iter().map(|x| x.2 * x.2).sum::<f64>() / count;
    let m4 = residuals.iter().map(|x| x.2.powi(4)).sum::<f64>() / count;
    let per_sample = samples_by_misfit(&residuals);
    let total: f64 = per_sample.iter().map(|x| x.0).sum();
    let share = |q: f64| per_sample[..worst_count(per_sample.len(), q)].iter().map(|x| x.0).sum::<f64>() / total;
    let rest_rms = bulk_rms_m_s2(&per_sample);
    let (worst_rate, all_rate) = worst_percent_rate_rad_s(&per_sample, &cal);
    format!(
        "RMS {:.3} m/s^2, kurtosis {:.0}, worst 1% of samples {:.1}% of the squares, worst 5% {:.1}%, RMS without the worst 5% {:.3} m/s^2; median rate of the worst 1% {:.1} rad/s (all {:.1})",
        m2.sqrt(),
        m4 / (m2 * m2),
        100.0 * share(0.01),
        100.0 * share(0.05),
        rest_rms,
        worst_rate,
        all_rate
    )
}

/// Where the rotation phase's residual sits (docs/sample-clocks.md, "What the clocks leave"): the
/// six real recordings calibrated gyroscope-free with the clocks and without them, and three
/// simulated recordings of configs/mimu4444_protocol.toml with them (about 2.5 minutes).
#[test]
#[ignore = "real data, 12 calibrations and 3 simulated ones: prints where the residual sits"]
fn print_where_the_rotation_phase_residual_sits() {
    let array = mimu_array();
    for k in 1..=6 {
        let rec = Recording::read(&shared_recording(k), &array).expect("recording");
        println!("recording {k}, clocks: {}", residual_tail(&array, &rec));
        println!("recording {k}, no clock model: {}", residual_tail(&without_clocks(&array), &rec));
    }
    let cell = matched_cell();
    for seed in 1..=3 {
        let truth = config_truth(&cell.array, seed);
        let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        println!("simulated {seed}, clocks: {}", residual_tail(&cell.array, &sim.recording));
    }
}

/// For `results/mimu4444/residual_repeat.py` (docs/sample-clocks.md, "What the clocks leave"):
/// each real recording calibrated gyroscope-free as `gfcal calibrate` does, its rotation phase's
/// residual after the clocks per sample and accelerometer written to
/// `GFCAL_RESIDUAL_OUT/residual_K.csv` (`sample`, `accelerometer` and `package` 0-based,
/// `residual_m_s2`, and `output_m_s2`, the recorded output before the clocks' correction):
///
/// ```sh
/// GFCAL_RESIDUAL_OUT=/tmp/residuals cargo test --locked --test gfcal simulate::write_the_rotation -- --ignored
/// python3 results/mimu4444/residual_repeat.py /tmp/residuals
/// ```
#[test]
#[ignore = "real data, 6 calibrations: writes the rotation phase's residuals into GFCAL_RESIDUAL_OUT"]
fn write_the_rotation_phase_residual_of_each_real_recording() {
    let Some(dir) = output_folder("GFCAL_RESIDUAL_OUT") else {
        return;
    };
    let array = mimu_array();
    for k in 1..=6 {
        let rec = Recording::read(&shared_recording(k), &array).expect("recording");
        let cal = calibrate(&rec, &array, &CalibrateSettings::default()).expect("calibrates");
        let d = prepare_dynamic(&rec, &cal.segmentation, false, cal.gyro_bias_rad_s).data.expect("a rotation phase");
        let mut csv = String::from("sample,accelerometer,package,residual_m_s2,output_m_s2\n");
        for (i, j, r) in rotation_residuals(&array, &rec, &cal) {
            let package = array.package_of[j].unwrap_or(0);
            csv.push_str(&format!("{i},{j},{package},{r:e},{:e}\n", d.outputs[(i, j)]));
        }
        std::fs::write(dir.join(format!("residual_{k}.csv")), csv).expect("residual csv");
    }
}

/// Per choice of `tau^2` (the own, then each null), the shares of the squares the snap and the snap
/// with the angular snap remove.
type Shares = Vec<(f64, f64)>;

/// The shares of a calibration's rotation-phase residual (after its clocks) that the timing's
/// second-order term would remove: per sample, the residual regressed on the columns already
/// fitted (the motion's `f`, `alpha`, `omega` and the first-order timing's jerk and angular jerk,
/// each `tau k a . x`), then also on `tau^2 / 2 k a` (the snap, 3 unknowns), then also on
/// `tau^2 / 2 k a . (r x .)` (the angular snap, 3 more). Returned: the share of the residual's
/// squares each adds to the already-fitted columns', with each package's `tau^2` its own, and the
/// same with `tau^2` handed on to the package `shift` places further (the nulls: the same number of
/// unknowns, the wrong packages). Over every sample with all 24 outputs, and over the bulk (those
/// samples less the 5% with the largest squares). `None` without clocks.
fn second_order_timing_shares(array: &RecordingArray, rec: &Recording, shifts: &[usize]) -> Option<(Shares, Shares)> {
    let cal = calibrate(rec, array, &CalibrateSettings::default()).expect("calibrates");
    let clocks = cal.clocks.as_ref()?;
    let d = prepare_dynamic(rec, &cal.segmentation, false, cal.gyro_bias_rad_s).data.expect("a rotation phase");
    let package_of: Vec<usize> = array.package_of.iter().map(|p| p.unwrap_or(0)).collect();
    let packages = package_of.iter().max().map_or(1, |m| m + 1);
    let ages = gfcal::selfcal::timing::accelerometer_ages(&d, &clocks.clocks, &package_of);
    let sens = sensors(&array.array, &cal.fit.params);
    let residuals = rotation_residuals(array, rec, &cal);
    // Every sample's outputs: (accelerometer, residual).
    let mut by_sample: Vec<Vec<(usize, f64)>> = vec![Vec::new(); d.samples()];
    for (i, j, r) in residuals {
        by_sample[i].push((j, r));
    }
    // The residual's sum of squares left by a per-sample least-squares fit on `cols` columns.
    let left = |x: &DMatrix<f64>, r: &DVector<f64>| -> f64 {
        let svd = x.clone().svd(true, true);
        let sol = svd.solve(r, 1e-12).expect("solves");
        (r - x * sol).norm_squared()
    };
    // (0) own tau^2; (1..) the shifted nulls.
    let choices: Vec<usize> = std::iter::once(0).chain(shifts.iter().copied()).collect();
    // Per sample: its squares, and what each choice's snap and both terms remove.
    let mut per_sample: Vec<(f64, Vec<(f64, f64)>)> = Vec::new();
    for (i, outs) in by_sample.iter().enumerate() {
        if outs.len() < 24 {
            continue;
        }
        let m = &cal.fit.motion[i];
        // Package p's tau^2, handed on by `shift`.
        let tau_of_package = |p: usize| {
            let j = package_of.iter().position(|&q| q == p).expect("every package has an accelerometer");
            ages[(i, j)]
        };
        let r = DVector::from_iterator(outs.len(), outs.iter().map(|o| o.1));
        let base_cols = 15;
        let row = |j: usize, c2: f64| -> [f64; 21] {
            let s = &sens[j];
            let (a, rj, w) = (s.axis * s.k, &s.position_m, &m.omega_rad_s);
            let tau = ages[(i, j)];
            let rxa = rj.cross(&a);
            let dw = a * w.dot(rj) + rj * a.dot(w) - w * (2.0 * a.dot(rj));
            let mut out = [0.0; 21];
            for k in 0..3 {
                out[k] = a[k];
                out[3 + k] = rxa[k];
                out[6 + k] = dw[k];
                out[9 + k] = tau * a[k];
                out[12 + k] = tau * rxa[k];
                out[15 + k] = c2 * a[k];
                out[18 + k] = c2 * rxa[k];
            }
            out
        };
        let base = DMatrix::from_fn(outs.len(), base_cols, |o, c| row(outs[o].0, 0.0)[c]);
        let left_base = left(&base, &r);
        let mut removed = vec![(0.0, 0.0); choices.len()];
        for (slot, &shift) in choices.iter().enumerate() {
            let c2 = |j: usize| {
                let t = tau_of_package((package_of[j] + shift) % packages);
                t * t / 2.0
            };
            let snap = DMatrix::from_fn(outs.len(), base_cols + 3, |o, c| row(outs[o].0, c2(outs[o].0))[c]);
            let both = DMatrix::from_fn(outs.len(), base_cols + 6, |o, c| row(outs[o].0, c2(outs[o].0))[c]);
            removed[slot] = (left_base - left(&snap, &r), left_base - left(&both, &r));
        }
        per_sample.push((r.norm_squared(), removed));
    }
    let shares = |samples: &[(f64, Vec<(f64, f64)>)]| -> Vec<(f64, f64)> {
        let total: f64 = samples.iter().map(|s| s.0).sum();
        (0..choices.len())
            .map(|c| {
                let (a, b) = samples.iter().fold((0.0, 0.0), |acc, s| (acc.0 + s.1[c].0, acc.1 + s.1[c].1));
                (a / total, b / total)
            })
            .collect()
    };
    let all = shares(&per_sample);
    per_sample.sort_by(|a, b| a.0.total_cmp(&b.0));
    let bulk = shares(&per_sample[..per_sample.len() * 95 / 100]);
    Some((all, bulk))
}

/// Whether what the clocks leave is the timing's second-order term (results/mimu4444/EXPECTATIONS.md,
/// 11:39 on 2026-11-29): [`second_order_timing_shares`] on the six real recordings and three
/// simulated ones of configs/mimu4444_protocol.toml (about 2 minutes).
#[test]
#[ignore = "real data, 6 calibrations and 3 simulated ones: prints the second-order timing's shares"]
fn print_whether_what_the_clocks_leave_is_second_order_timing() {
    let shifts = [1, 2, 3, 4, 5];
    let show = |name: String, shares: Option<(Shares, Shares)>| {
        let (all, bulk) = shares.expect("clocks fitted");
        show_one(format!("{name}, all samples"), all);
        show_one(format!("{name}, the bulk"), bulk);
    };
    fn show_one(name: String, shares: Shares) {
        let nulls = &shares[1..];
        let max = |f: fn(&(f64, f64)) -> f64| nulls.iter().map(f).fold(0.0, f64::max);
        println!(
            "{name}: snap {:.1}% (nulls up to {:.1}%), snap and angular snap {:.1}% (nulls up to {:.1}%); nulls {}",
            100.0 * shares[0].0,
            100.0 * max(|x| x.0),
            100.0 * shares[0].1,
            100.0 * max(|x| x.1),
            nulls.iter().map(|x| format!("{:.1}/{:.1}", 100.0 * x.0, 100.0 * x.1)).collect::<Vec<_>>().join(" ")
        );
    }
    let array = mimu_array();
    for k in 1..=6 {
        let rec = Recording::read(&shared_recording(k), &array).expect("recording");
        show(format!("recording {k}"), second_order_timing_shares(&array, &rec, &shifts));
    }
    let cell = matched_cell();
    for seed in 1..=3 {
        let truth = config_truth(&cell.array, seed);
        let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        show(format!("simulated {seed}"), second_order_timing_shares(&cell.array, &sim.recording, &shifts));
    }
}

/// The power of [`print_whether_what_the_clocks_leave_is_second_order_timing`]: real recording 1
/// with a second-order timing term added to its rotation phase, `tau^2 / 2 k a . S` with each
/// package's age from the clocks fitted to the recording as it is and a random snap `S` per
/// sample, scaled to 0.1 and 0.3 m/s^2 RMS (about a tenth of the squares the clocks leave, and
/// about as much as they leave), then the same shares, and what the fit leaves of the term
/// (about 40 s).
#[test]
#[ignore = "real data, 2 calibrations: prints the second-order check's shares with the term injected"]
fn print_the_second_order_checks_power() {
    use rand::RngExt;
    let array = mimu_array();
    let rec_clean = Recording::read(&shared_recording(1), &array).expect("recording");
    let cal = calibrate(&rec_clean, &array, &CalibrateSettings::default()).expect("calibrates");
    let clocks = cal.clocks.as_ref().expect("clocks fitted");
    let d = prepare_dynamic(&rec_clean, &cal.segmentation, false, cal.gyro_bias_rad_s).data.expect("a rotation phase");
    let package_of: Vec<usize> = array.package_of.iter().map(|p| p.unwrap_or(0)).collect();
    let ages = gfcal::selfcal::timing::accelerometer_ages(&d, &clocks.clocks, &package_of);
    let sens = sensors(&array.array, &cal.fit.params);
    let c2 = ages.map(|t| t * t / 2.0);
    let rms_c2 = (c2.iter().map(|c| c * c).sum::<f64>() / c2.len() as f64).sqrt();
    let rms = |v: Vec<(usize, usize, f64)>| (v.iter().map(|x| x.2 * x.2).sum::<f64>() / v.len() as f64).sqrt();
    let clean = rms(rotation_residuals(&array, &rec_clean, &cal));
    for term_rms_m_s2 in [0.1, 0.3] {
        let mut rec = rec_clean.clone();
        let sigma_snap_m_s4 = term_rms_m_s2 / rms_c2;
        let mut rng = trial_rng(77, 0);
        let mut added = 0.0;
        for i in 0..d.samples() {
            let row = rec.t_s.partition_point(|&t| t < d.t_s[i]);
            assert_eq!(rec.t_s[row], d.t_s[i], "the rotation phase's samples are the recording's");
            let snap = Vector3::from_fn(|_, _| sigma_snap_m_s4 * rng.sample::<f64, _>(rand_distr::StandardNormal));
            for (j, s) in sens.iter().enumerate() {
                let term = c2[(i, j)] * s.k * s.axis.dot(&snap);
                rec.outputs[(row, j)] += term;
                added += term * term;
            }
        }
        let added = (added / (d.samples() * sens.len()) as f64).sqrt();
        let injected_cal = calibrate(&rec, &array, &CalibrateSettings::default()).expect("calibrates");
        let injected = rms(rotation_residuals(&array, &rec, &injected_cal));
        println!(
            "injected: snap sigma {sigma_snap_m_s4:.3e} m/s^4 per axis, term RMS {added:.3} m/s^2; the rotation phase's residual after the clocks {clean:.4} m/s^2 as recorded, {injected:.4} with the term (in quadrature {:.4})",
            (clean * clean + added * added).sqrt()
        );
        let (all, bulk) = second_order_timing_shares(&array, &rec, &[1, 2, 3, 4, 5]).expect("clocks fitted");
        for (name, shares) in [("all samples", all), ("the bulk", bulk)] {
            let nulls: Vec<String> =
                shares[1..].iter().map(|x| format!("{:.1}/{:.1}", 100.0 * x.0, 100.0 * x.1)).collect();
            println!(
                "recording 1 with the term, {name}: snap {:.1}%, snap and angular snap {:.1}%; nulls {}",
                100.0 * shares[0].0,
                100.0 * shares[0].1,
                nulls.join(" ")
            );
        }
    }
}

/// A recording calibrated by least squares alone (`plain_least_squares`) and with Huber's weights
/// on the rotation phase (the default, `selfcal::huber`).
fn plain_and_robust(array: &RecordingArray, rec: &Recording) -> (Calibration, Calibration) {
    let plain = CalibrateSettings { plain_least_squares: true, ..CalibrateSettings::default() };
    let plain = calibrate(rec, array, &plain).expect("calibrates by least squares");
    let robust = calibrate(rec, array, &CalibrateSettings::default()).expect("calibrates with Huber's weights");
    (plain, robust)
}

/// The gyroscope-free rate against the bias-corrected gyroscopes, % RMS, overall and above 20 rad/s:
/// the calibration's own check (`GyroCheck`), its rate bands from 20 rad/s up pooled.
pub fn rate_off_gyroscopes(cal: &Calibration) -> (f64, f64) {
    let g = cal.gyro_check.as_ref().expect("the array's gyroscopes are checked");
    let (mut d2, mut r2) = (0.0, 0.0);
    for &(lo, _, count, rms_rad_s, relative) in &g.by_rate {
        if lo >= 20.0 && count > 0 {
            d2 += count as f64 * rms_rad_s * rms_rad_s;
            r2 += count as f64 * (rms_rad_s / relative).powi(2);
        }
    }
    (100.0 * g.relative, 100.0 * (d2 / r2).sqrt())
}

/// What Huber's weights on the rotation phase change (`selfcal::huber`; docs/sample-clocks.md,
/// "The robust rotation phase"), least squares alone against the default: on three simulated
/// recordings of configs/mimu4444_protocol.toml the locations' RMS error against the truth and
/// their RMS z, the clocks' relative rate offsets and the rate against the truth; on the six real
/// recordings the gyroscope-free rate against the gyroscopes, the worst spread of a package's
/// sensing points, and the locations' spread over the six recordings against their printed sigmas
/// (about 6 minutes).
#[test]
#[ignore = "real data, 12 calibrations and 6 simulated ones: prints what Huber's weights change"]
fn print_what_the_robust_rotation_phase_changes() {
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let cell = matched_cell();
    let n = cell.array.array.len();
    for seed in 1..=3 {
        let truth = config_truth(&cell.array, seed);
        let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        let (plain, huber) = plain_and_robust(&cell.array, &sim.recording);
        let error_um = |cal: &Calibration| -> Vec<f64> {
            (0..n)
                .flat_map(|j| (4..PER_ACCEL).map(move |p| (j, p)))
                .map(|(j, p)| (cal.fit.params.get(j, p) - truth.get(j, p)) * 1e6)
                .collect()
        };
        // The clocks' relative rate offsets (each less the packages' mean), ppm.
        let clock_error_ppm = |cal: &Calibration| -> Vec<f64> {
            let c = cal.clocks.as_ref().expect("clocks fitted");
            let est = gfcal::selfcal::timing::relative_rates(&c.clocks);
            let tru = gfcal::selfcal::timing::relative_rates(&sim.clocks);
            est.iter().zip(&tru).filter_map(|(e, t)| Some((e.as_ref()? - t.as_ref()?) * 1e6)).collect()
        };
        let rate_error = |cal: &Calibration| rate_error_percent(cal, &sim);
        // The locations' errors over their printed sigmas.
        let z = |cal: &Calibration| -> Vec<f64> {
            (0..n)
                .flat_map(|j| (4..PER_ACCEL).map(move |p| (j, p)))
                .map(|(j, p)| (cal.fit.params.get(j, p) - truth.get(j, p)) / cal.fit.sigma(j, p))
                .collect()
        };
        println!(
            "simulated {seed}: locations' RMS error {:.1} -> {:.1} um (RMS z {:.2} -> {:.2}); the clocks' relative rate offsets' RMS error {:.3} -> {:.3} ppm; the rate {:.1}% -> {:.1}% off the truth",
            rms(&error_um(&plain)),
            rms(&error_um(&huber)),
            rms(&z(&plain)),
            rms(&z(&huber)),
            rms(&clock_error_ppm(&plain)),
            rms(&clock_error_ppm(&huber)),
            rate_error(&plain),
            rate_error(&huber)
        );
    }
    let array = mimu_array();
    let points = |params: &SensorSet| -> f64 {
        let sens = sensors(&array.array, params);
        let mut worst: f64 = 0.0;
        for a in 0..n {
            for b in 0..n {
                if array.package_of[a] == array.package_of[b] {
                    worst = worst.max((sens[a].position_m - sens[b].position_m).norm() * 1e3);
                }
            }
        }
        worst
    };
    let (mut before, mut after, mut sigmas) = (Vec::new(), Vec::new(), Vec::new());
    for k in 1..=6 {
        let rec = Recording::read(&shared_recording(k), &array).expect("recording");
        let (plain, huber) = plain_and_robust(&array, &rec);
        let ((ra, ra20), (rb, rb20)) = (rate_off_gyroscopes(&plain), rate_off_gyroscopes(&huber));
        println!(
            "recording {k}: rate off the gyroscopes {ra:.1}% -> {rb:.1}% (above 20 rad/s {ra20:.1}% -> {rb20:.1}%); worst spread of a package's sensing points {:.2} -> {:.2} mm",
            points(&plain.fit.params),
            points(&huber.fit.params)
        );
        before.push(plain.fit.params.clone());
        after.push(huber.fit.params.clone());
        sigmas.push((plain.fit.clone(), huber.fit.clone()));
    }
    for (name, p) in [("x", 4), ("y", 5), ("z", 6)] {
        let spread_um = |sets: &[SensorSet]| -> f64 {
            median(
                (0..n)
                    .map(|j| {
                        let v: Vec<f64> = sets.iter().map(|s| s.get(j, p)).collect();
                        let m = v.iter().sum::<f64>() / v.len() as f64;
                        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt() * 1e6
                    })
                    .collect(),
            )
        };
        // The spread over the six recordings over the RMS of the printed sigmas, RMS over the 24.
        let over_sigma = |sets: &[SensorSet], fits: &dyn Fn(usize) -> f64| -> f64 {
            let r: Vec<f64> = (0..n)
                .map(|j| {
                    let v: Vec<f64> = sets.iter().map(|s| s.get(j, p)).collect();
                    let m = v.iter().sum::<f64>() / v.len() as f64;
                    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
                    sd / fits(j)
                })
                .collect();
            rms(&r)
        };
        let sigma_rms = |pick: &dyn Fn(&(gfcal::selfcal::fit::Fit, gfcal::selfcal::fit::Fit)) -> f64| -> f64 {
            (sigmas.iter().map(|f| pick(f).powi(2)).sum::<f64>() / sigmas.len() as f64).sqrt()
        };
        println!(
            "locations {name}: spread over the six recordings {:.1} -> {:.1} um (median over 24); over the printed sigma {:.2} -> {:.2} (RMS over 24)",
            spread_um(&before),
            spread_um(&after),
            over_sigma(&before, &|j| sigma_rms(&|f| f.0.sigma(j, p))),
            over_sigma(&after, &|j| sigma_rms(&|f| f.1.sigma(j, p)))
        );
    }
}

/// What a setting of the simulator does to the estimates (docs/sample-clocks.md, "What the clocks
/// leave"): per seed of `GFCAL_SIM`'s protocol (`GFCAL_SEEDS`, default 3), the rotation phase's
/// residual RMS after the clock model and without it (m/s^2), the locations' RMS error against the
/// truth (um, every location parameter) and their RMS z against their sigmas, and the
/// gyroscope-free rate off the truth (%): the measures that tell a candidate for the real misfit
/// which reproduces its size from one that also harms the estimates as much as it does.
#[test]
#[ignore = "tuning aid: prints what a simulator setting does to the estimates (about 20 s a seed)"]
fn print_what_a_setting_does_to_the_estimates() {
    let spec = std::env::var("GFCAL_SIM").unwrap_or_default();
    let seeds: u64 = std::env::var("GFCAL_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(3);
    let (cell, _) = tuned_protocol(&spec);
    eprintln!("{spec}: {:?}", cell.protocol.vibration);
    let settings = CalibrateSettings { remove_bias_drift: cell.remove_bias_drift, ..CalibrateSettings::default() };
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let mut all_err_um = Vec::new();
    for seed in 1..=seeds {
        let truth = config_truth(&cell.array, seed);
        let sim = simulate(&cell.array, &truth, &cell.protocol, &mut trial_rng(seed, 1)).expect("simulated");
        let cal = calibrate(&sim.recording, &cell.array, &settings).expect("calibrates");
        let after: Vec<f64> = cal.fit.dynamic_residual_rms_m_s2.iter().copied().filter(|v| v.is_finite()).collect();
        let (_, before, _) = baseline_calibration(&cell.array, &sim.recording);
        let per_sample = samples_by_misfit(&rotation_residuals(&cell.array, &sim.recording, &cal));
        let (worst_rate, all_rate) = worst_percent_rate_rad_s(&per_sample, &cal);
        let (mut err_um, mut z, mut sigma_um) = (Vec::new(), Vec::new(), Vec::new());
        for j in 0..cell.array.array.len() {
            for p in 4..PER_ACCEL {
                let e = cal.fit.params.get(j, p) - truth.get(j, p);
                err_um.push(e * 1e6);
                z.push(e / cal.fit.sigma(j, p));
                sigma_um.push(cal.fit.sigma(j, p) * 1e6);
            }
        }
        eprintln!(
            "seed {seed}: after the clocks {:.3} m/s^2 (bulk {:.3}; worst 1% of samples at a median {:.1} rad/s, all {:.1}), no clock model {:.3}; locations RMS error {:.1} um, RMS sigma {:.1} um, RMS z {:.2}; rate off the truth {:.1}%",
            rms(&after),
            bulk_rms_m_s2(&per_sample),
            worst_rate,
            all_rate,
            before,
            rms(&err_um),
            rms(&sigma_um),
            rms(&z),
            rate_error_percent(&cal, &sim)
        );
        if std::env::var("GFCAL_PLAIN").is_ok() {
            // Huber's gain: the locations' RMS sigma by plain least squares over Huber's.
            let plain = CalibrateSettings { plain_least_squares: true, ..settings };
            let lsq = calibrate(&sim.recording, &cell.array, &plain).expect("calibrates");
            let sigma_lsq_um: Vec<f64> = (0..cell.array.array.len())
                .flat_map(|j| (4..PER_ACCEL).map(move |p| (j, p)))
                .map(|(j, p)| lsq.fit.sigma(j, p) * 1e6)
                .collect();
            eprintln!(
                "seed {seed}: plain least squares: locations RMS sigma {:.1} um (Huber's gain {:.2})",
                rms(&sigma_lsq_um),
                rms(&sigma_lsq_um) / rms(&sigma_um)
            );
        }
        all_err_um.extend(err_um);
    }
    eprintln!("locations RMS error over the seeds {:.1} um", rms(&all_err_um));
}
