//! The library's rotation-phase weights after the sample clocks at the fixed point of a Huber
//! M-estimate of the model extended by every effect of the library.
//!
//! What the clocks leave in the rotation phase is heavy-tailed: on the MIMU4444 recordings the
//! weighted residuals the library's tests read (after `sample_spread`'s weights) have an RMS
//! 1.5-2.1 times their MAD scale, kurtosis 7-11. Least squares spends its sigma on that tail; a
//! Huber M-estimate's sigma on these residuals is 0.66-0.88 of it
//! (`results/mimu4444/EXPECTATIONS.md`, (bp)).
//!
//! Weights that read an output's own residual select on it, and an effect pushes the outputs that
//! carry it into the tail: the library tried on the outputs within the calibration's clip read a
//! quadratic scale factor hidden in a simulated clocked recording at 12% of itself
//! (`sample_spread`). An M-estimate avoids that by forming its weights from the residuals with
//! the effect in the model. So the weights here are those of the model extended by **every**
//! effect of the library at once (with the baseline's parameters and each sample's local
//! unknowns refitted), iterated to their fixed point (iteratively reweighted least squares):
//! each output's Huber weight `min(1, c s / |u|)` of its weighted residual `u`, with `s` the
//! phase's MAD scale of `u`. Each effect's test on these weights is then the M-estimate's
//! linearised step from the baseline (the other effects left out of it, which moves its weights
//! only by what they explain).
//!
//! The test's robust covariance is the M-estimate's sandwich: the scores' spread (`psi` of each
//! output, which the reweighted residuals are) between breads weighted by `psi'` (1 within the
//! clip, 0 beyond it), not by the reweighting's weights, which would be too much information
//! (`projected::Accumulated::bread`).

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::blocks::{DynamicRows, Nuisance, RecordingNormal, RecordingState, accumulate_recording};
use super::effect::RecordedEffect;
use crate::stats::symmetric_pinv;

/// Huber's tuning constant, in MAD scales: 95% efficiency where the residuals are Gaussian.
pub const HUBER_C: f64 = 1.345;

/// Largest change of any output's weight between two iterations at which the weights are fixed.
pub const WEIGHT_TOLERANCE: f64 = 1e-2;

/// Iterations after which the weights are taken as they are.
pub const MAX_ITERATIONS: usize = 30;

/// The M-estimate's fixed point.
#[derive(Debug, Clone)]
pub struct HuberFixedPoint {
    /// The recording's accumulation at the fixed point's weights, with the M-estimate's bread in
    /// its dynamic phase.
    pub normal: RecordingNormal,
    /// Share of the used rotation-phase outputs beyond the clip.
    pub clipped_share: f64,
    /// The MAD scale of the weighted residuals (1: the weights' own scale).
    pub scale: f64,
    pub iterations: usize,
    pub converged: bool,
}

/// Iterates the weights of `state`'s rotation-phase outputs, after each sample's local nuisance
/// is eliminated with `state`'s own weights, to the fixed point of the Huber M-estimate of the
/// baseline extended by `effects`. `start` is `state`'s own accumulation with `effects` (the first
/// iteration's). `None` when the recording has no dynamic phase.
pub fn huber_fixed_point(
    state: &RecordingState,
    effects: &[RecordedEffect],
    start: RecordingNormal,
) -> Option<HuberFixedPoint> {
    let d = state.dynamic.filter(|_| !state.motion.is_empty())?;
    let (m, n) = (d.samples(), state.array.len());
    let mut huber = DMatrix::from_element(m, n, 1.0);
    let mut iterations = 0;
    let mut normal = start;
    loop {
        iterations += 1;
        if iterations > 1 {
            let weighted = RecordingState { projected_factor: Some(&huber), ..*state };
            normal = accumulate_recording(&weighted, Nuisance::Baseline, None, effects);
        }
        let total = normal.total();
        let (inverse, _) = symmetric_pinv(&total.normal, 1e-11);
        let global = inverse * &total.score;
        let u = weighted_residuals(state, effects, &global);
        let scale = mad_scale(&u);
        let next = u.map(|v| if v.is_finite() && scale > 0.0 { (HUBER_C * scale / v.abs()).min(1.0) } else { 1.0 });
        let change = (&next - &huber).abs().max();
        let converged = change < WEIGHT_TOLERANCE;
        if converged || iterations >= MAX_ITERATIONS || !scale.is_finite() || scale <= 0.0 {
            return Some(finish(state, effects, normal, &u, scale, iterations, converged));
        }
        huber = next;
    }
}

/// The fixed point's accumulation with its bread: the projected rows weighted by `psi'` (1 within
/// the clip, 0 beyond it).
fn finish(
    state: &RecordingState,
    effects: &[RecordedEffect],
    mut normal: RecordingNormal,
    u: &DMatrix<f64>,
    scale: f64,
    iterations: usize,
    converged: bool,
) -> HuberFixedPoint {
    let within = u.map(|v| if !v.is_finite() || v.abs() <= HUBER_C * scale { 1.0 } else { 0.0 });
    let used = u.iter().filter(|v| v.is_finite()).count();
    let clipped = u.iter().filter(|v| v.is_finite() && v.abs() > HUBER_C * scale).count();
    let bread_state = RecordingState { projected_factor: Some(&within), ..*state };
    let bread = accumulate_recording(&bread_state, Nuisance::Baseline, None, effects);
    normal.dynamics.bread = Some(bread.dynamics.normal);
    HuberFixedPoint {
        normal,
        clipped_share: if used > 0 { clipped as f64 / used as f64 } else { 0.0 },
        scale,
        iterations,
        converged,
    }
}

/// Each used rotation-phase output's weighted residual with the global columns at `global` and
/// each sample's local unknowns refitted (samples x accelerometers; NaN where not used).
fn weighted_residuals(state: &RecordingState, effects: &[RecordedEffect], global: &DVector<f64>) -> DMatrix<f64> {
    let n = state.array.len();
    let Some(rows) = DynamicRows::new(state, Nuisance::Baseline, effects) else {
        return DMatrix::zeros(0, n);
    };
    let per_sample: Vec<Vec<f64>> = (0..rows.samples())
        .into_par_iter()
        .map(|i| match rows.block(i) {
            Some(b) => {
                let e = b.weighted_residual(global);
                (0..n).map(|j| if b.weight[j] > 0.0 { e[j] } else { f64::NAN }).collect()
            }
            None => vec![f64::NAN; n],
        })
        .collect();
    DMatrix::from_fn(per_sample.len(), n, |i, j| per_sample[i][j])
}

/// `1.4826` times the median absolute value of the finite entries (0 when there are none).
fn mad_scale(u: &DMatrix<f64>) -> f64 {
    let mut a: Vec<f64> = u.iter().filter(|v| v.is_finite()).map(|v| v.abs()).collect();
    if a.is_empty() {
        return 0.0;
    }
    let mid = a.len() / 2;
    let (_, median, _) = a.select_nth_unstable_by(mid, f64::total_cmp);
    1.4826 * *median
}
