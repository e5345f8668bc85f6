//! Huber's weights for a clocked calibration's rotation phase: the heavy tail the sample clocks
//! leave, down-weighted without taking a sample out of its run.
//!
//! After the clocks the rotation phase's residual is a bulk near 0.1 m/s^2 and a tail of violent
//! samples: on the MIMU4444 recordings the worst 1% of the samples carry 53-72% of the residual's
//! squares (kurtosis 215-5,579; `docs/sample-clocks.md`, "What the clocks leave"). Least squares
//! follows that tail: the locations scatter 44-50 um over six recordings of one board, and the
//! printed sigmas follow the few largest scores. Setting the tail's samples aside is no remedy:
//! it cuts the rotation phase into short runs, and each run's rate sign then rests on its own
//! angular acceleration (the rate's error doubled).
//!
//! Huber's M-estimator minimises `sum rho(r / s)` with `rho` quadratic within `c` and linear
//! beyond. Its fixed point is reached by pseudo-observations (Huber 1981, section 7.8): each used
//! output `y` is replaced by `y - r + psi(r)`, `r` its residual at the current fit and `psi` the
//! clip at `+-c`, and refitted by least squares; at the fixed point the pseudo-observations'
//! normal equations are Huber's estimating equations `sum J^T W psi(r) = 0`. Every output keeps
//! its place, so every sample stays in its run. The clip `c` is [`CLIP_SCALES`] robust scales `s`
//! (1.4826 times the median absolute residual over every used output of the phase), taken afresh
//! at each update.
//!
//! The covariance of an M-estimator is the sandwich `A^-1 B A^-T`: the meat `B` the spread of
//! the scores `J^T W psi(r)` (here over blocks of samples, `selfcal::robust`), the bread `A` the
//! information weighted by `psi'`: 1 within the clip, 0 beyond. A bread with the clipped outputs
//! in at full weight would credit the tail with information its clipped residuals no longer use,
//! and give sigmas too small. But the indicator `|r| <= c` at the fitted residual made the sigmas
//! fragile: the z axes' locations are seen mostly through the fastest samples, the ones the clip
//! takes, so the bread is weak there and moved with which outputs fell just inside the clip. Two
//! calibrations of one real recording whose values differed by under 0.09 sigma printed location
//! sigmas up to 11 times apart (`docs/sample-clocks.md`, "The robust covariance's fragility").
//! So each output's `psi'` is averaged over its accelerometer's white noise about its residual
//! ([`expected_derivative`]): the chance that the output falls within the clip. It is continuous
//! in the residuals; the same two calibrations' sigmas then agree within 0.4%, and the clock
//! Monte Carlo's locations' RMS z fell from 1.73 to 1.53.

use nalgebra::DMatrix;

/// The clip in robust scales of the residual: 2 (95% efficiency at Gaussian residuals is 1.345;
/// 2 gives up less of the bulk, and 3 gave the same locations in the experiment of
/// `docs/sample-clocks.md`).
pub const CLIP_SCALES: f64 = 2.0;

/// The robust scale of a phase's residual: 1.4826 times the median absolute residual (the
/// standard deviation at Gaussian residuals), over every used output.
pub fn robust_scale(residuals: &DMatrix<f64>, used: &[bool]) -> f64 {
    let n = residuals.ncols();
    let mut abs: Vec<f64> = (0..residuals.nrows())
        .flat_map(|i| (0..n).map(move |j| (i, j)))
        .filter(|&(i, j)| used[i * n + j] && residuals[(i, j)].is_finite())
        .map(|(i, j)| residuals[(i, j)].abs())
        .collect();
    if abs.is_empty() {
        return f64::NAN;
    }
    let mid = abs.len() / 2;
    let (_, m, _) = abs.select_nth_unstable_by(mid, f64::total_cmp);
    1.4826 * *m
}

/// A clip that is not a finite non-negative number (no residual to take a scale from) clips
/// nothing.
fn usable(clip: f64) -> f64 {
    if clip.is_finite() && clip >= 0.0 { clip } else { f64::INFINITY }
}

/// The pseudo-observations' shift `psi(r) - r` at residuals `r` (samples x accelerometers) of
/// the outputs as measured, clipped at `clip`; zero where an output is not used.
pub fn shift(residuals: &DMatrix<f64>, used: &[bool], clip: f64) -> DMatrix<f64> {
    let clip = usable(clip);
    let n = residuals.ncols();
    DMatrix::from_fn(residuals.nrows(), n, |i, j| {
        let r = residuals[(i, j)];
        if used[i * n + j] && r.is_finite() { r.clamp(-clip, clip) - r } else { 0.0 }
    })
}

/// Per used output (row-major, samples x accelerometers), the chance that its residual falls
/// within the clip, `Phi((c - r) / sigma_j) - Phi((-c - r) / sigma_j)`: the derivative `psi'`
/// averaged over accelerometer `j`'s white noise `sigma_j` about the residual `r` (zero where
/// the output is not used). The bread's weights (module docs): continuous in the residuals where
/// the indicator `|r| <= c` is not.
pub fn expected_derivative(residuals: &DMatrix<f64>, used: &[bool], clip: f64, noise_sigma: &[f64]) -> Vec<f64> {
    let clip = usable(clip);
    let n = residuals.ncols();
    let phi = |x: f64| 0.5 * statrs::function::erf::erfc(-x / std::f64::consts::SQRT_2);
    (0..residuals.nrows() * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            let r = residuals[(i, j)];
            let s = noise_sigma[j];
            if !used[k] || !r.is_finite() {
                0.0
            } else if s.is_nan() || s <= 0.0 || clip.is_infinite() {
                if r.abs() <= clip { 1.0 } else { 0.0 }
            } else {
                (phi((clip - r) / s) - phi((-clip - r) / s)).clamp(0.0, 1.0)
            }
        })
        .collect()
}

/// The share of the used outputs whose residual lies beyond the clip.
pub fn clipped_share(residuals: &DMatrix<f64>, used: &[bool], clip: f64) -> f64 {
    let n = residuals.ncols();
    let (mut beyond, mut total) = (0usize, 0usize);
    for (k, &u) in used.iter().enumerate() {
        if u {
            total += 1;
            beyond += usize::from(residuals[(k / n, k % n)].abs() > clip);
        }
    }
    beyond as f64 / total.max(1) as f64
}

/// How a calibration's rotation phase was down-weighted (reported with its clocks).
#[derive(Debug, Clone, PartialEq)]
pub struct HuberSummary {
    /// The clip at the end, m/s^2 ([`CLIP_SCALES`] robust scales).
    pub clip_m_s2: f64,
    /// The robust scale of the residual after the clocks, m/s^2.
    pub robust_scale_m_s2: f64,
    /// The share of the used outputs beyond the clip.
    pub clipped_share: f64,
    /// Outer iterations run with the weights (after the least-squares ones).
    pub iterations: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The chance of falling within the clip against the normal density integrated by Simpson's
    /// rule (an independent oracle), and its limits: the indicator at zero noise, zero where an
    /// output is not used, symmetric in the residual, near 0 far beyond the clip.
    #[test]
    fn the_expected_derivative_is_the_chance_of_falling_within_the_clip() {
        let (clip, sigma) = (0.1, 0.04);
        let simpson = |a: f64, b: f64| {
            let f = |x: f64| (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt();
            let m = 2000;
            let h = (b - a) / m as f64;
            let inner: f64 = (1..m).map(|k| if k % 2 == 1 { 4.0 } else { 2.0 } * f(a + k as f64 * h)).sum();
            h / 3.0 * (f(a) + inner + f(b))
        };
        let rs = [0.0, 0.03, -0.07, 0.1, 0.13, -0.2, 0.5];
        let r = DMatrix::from_fn(rs.len(), 2, |i, j| if j == 0 { rs[i] } else { -rs[i] });
        let mut used = vec![true; 2 * rs.len()];
        used[13] = false;
        let w = expected_derivative(&r, &used, clip, &[sigma, sigma]);
        for (i, &ri) in rs.iter().enumerate() {
            let oracle = simpson((-clip - ri) / sigma, (clip - ri) / sigma);
            assert!((w[2 * i] - oracle).abs() < 1e-9, "r {ri}: {} against {oracle}", w[2 * i]);
            if 2 * i + 1 != 13 {
                assert!((w[2 * i + 1] - w[2 * i]).abs() < 1e-15, "symmetric in r");
            }
        }
        assert_eq!(w[13], 0.0, "not used");
        assert!(w[12] < 1e-20, "far beyond the clip: {}", w[12]);
        let indicator = expected_derivative(&r, &used, clip, &[0.0, 0.0]);
        for (k, v) in indicator.iter().enumerate() {
            let expected = if used[k] && r[(k / 2, k % 2)].abs() <= clip { 1.0 } else { 0.0 };
            assert_eq!(*v, expected);
        }
    }

    #[test]
    fn the_robust_scale_is_the_standard_deviation_of_gaussian_residuals() {
        // Quantiles of the standard normal at (k + 0.5) / n: their median absolute value is the
        // normal's 75% point, 0.6745, so the scale is 1.4826 * 0.6745 = 1.
        let n = 20_001;
        let values: Vec<f64> = (0..n)
            .map(|k| std::f64::consts::SQRT_2 * statrs::function::erf::erf_inv(2.0 * (k as f64 + 0.5) / n as f64 - 1.0))
            .collect();
        let r = DMatrix::from_row_slice(n, 1, &values);
        let s = robust_scale(&r, &vec![true; n]);
        assert!((s - 1.0).abs() < 1e-3, "scale {s}");
    }

    #[test]
    fn the_shift_clips_and_leaves_unused_outputs_alone() {
        let r = DMatrix::from_row_slice(2, 2, &[0.5, -3.0, 4.0, 9.0]);
        let used = [true, true, true, false];
        let s = shift(&r, &used, 2.0);
        assert_eq!(s, DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -2.0, 0.0]));
        assert_eq!(clipped_share(&r, &used, 2.0), 2.0 / 3.0);
        // No scale (no finite residual): nothing is clipped, and nothing panics.
        assert!(robust_scale(&DMatrix::from_element(1, 1, f64::NAN), &[true]).is_nan());
        assert_eq!(shift(&r, &used, f64::NAN), DMatrix::zeros(2, 2));
    }
}
