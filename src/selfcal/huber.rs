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
//! information of the outputs where `psi' = 1`, i.e. the unclipped ones only. A bread with the
//! clipped outputs in would credit the tail with information its clipped residuals no longer
//! use, and give sigmas too small.

use nalgebra::DMatrix;

use super::data::DynamicData;

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

/// `d` with only the outputs whose residual lies within the clip used: the data of the
/// sandwich's bread (module docs).
pub fn within_clip(d: &DynamicData, residuals: &DMatrix<f64>, clip: f64) -> DynamicData {
    let clip = usable(clip);
    let n = d.outputs.ncols();
    let used = d.used.iter().enumerate().map(|(k, &u)| u && residuals[(k / n, k % n)].abs() <= clip).collect();
    DynamicData { used, ..d.clone() }
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
