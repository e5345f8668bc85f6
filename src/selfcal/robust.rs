//! A calibration's covariance that does not rest on white residuals: the sandwich
//! `K (M_static + sum_b s_b s_b^T) K` over blocks of consecutive rotation-phase samples.
//!
//! The fit's covariance (`selfcal::fit`) is the constrained inverse `K` of the Fisher information:
//! right when every output's residual is white noise of the variance its weight assumes. Where a
//! model leaves a residual that is correlated across the accelerometers of a sample and over
//! neighbouring samples (the rotation phase of a real board after its sample clocks: about 15
//! times the static noise, driven by the motion), `K` is too small. Here the spread of the
//! scores is measured instead of assumed: `s_b` is the reduced score (the gradient of the
//! weighted misfit with every sample's motion eliminated, as the fit's normal equations form it)
//! summed over block `b` of [`BLOCK_SAMPLES`] consecutive samples, so that a residual correlated
//! within a block (and across a sample's accelerometers) is counted as it is. The static
//! intervals keep their model information (their residuals are near white; their weights already
//! carry the static chi^2/dof). With white residuals `sum_b s_b s_b^T` tends to the dynamic
//! information and the sandwich to `K` (`K H K = K` in the gauge). In a clocked calibration the
//! information and the scores also eliminate each sample's timing motion
//! (`selfcal::timing_information`), which the fit corrected the outputs with and then held.

use nalgebra::DMatrix;
use rayon::prelude::*;

use super::data::{DynamicData, StaticData};
use super::fit::{Fit, FitError, FitSettings, State, Weights, constrained_inverse, normal_equations, pinned};
use super::model::{PER_ACCEL, sensors};
use super::schur::{self, SampleScratch};
use super::timing_information::{TimingSamples, reduced_information, reduced_score};
use super::unseen::unseen;
use crate::array::Array;

/// Samples per block: 0.26 s at the MIMU4444's 62.5 Hz, several times the time over which its
/// rotation phase's residual stays correlated (the clocks' offsets have a lag-1 autocorrelation of
/// 0.5-0.75), and about 375 blocks in a 100 s rotation phase.
pub const BLOCK_SAMPLES: usize = 16;

/// A fit's information at its solution with `weights`: the whole and the static phase's alone,
/// with the gauge's constraints (what [`robust_covariance`] and [`timing_free_sigma_ratios`]
/// invert).
struct AtSolution {
    normal: DMatrix<f64>,
    static_normal: DMatrix<f64>,
    constraints: DMatrix<f64>,
    active: Vec<bool>,
}

impl AtSolution {
    /// The constrained inverse of `information` (the fit's unseen parameters NaN).
    fn inverse(&self, information: &DMatrix<f64>, fit: &Fit) -> Result<DMatrix<f64>, FitError> {
        constrained_inverse(information, &self.constraints, &self.active, &fit.unseen_parameters, true)
    }

    /// The constrained inverse of the static information with `dynamic` (the accelerometer
    /// parameters' dynamic information, formed another way) in its top-left block.
    fn inverse_with_dynamic(&self, dynamic: &DMatrix<f64>, fit: &Fit) -> Result<DMatrix<f64>, FitError> {
        let mut information = self.static_normal.clone();
        let mut top = information.view_mut((0, 0), (dynamic.nrows(), dynamic.ncols()));
        top += dynamic;
        self.inverse(&information, fit)
    }
}

/// The information at `fit`'s solution (its covariance to about 1e-6 of a sigma with its stored
/// weights: the weights go through the stored sigmas).
fn at_solution(
    array: &Array,
    stat: &StaticData,
    dynamic: &DynamicData,
    weights: &Weights,
    settings: &FitSettings,
    fit: &Fit,
) -> AtSolution {
    let poses = stat.means.nrows();
    let active = vec![true; PER_ACCEL * array.len() + 2 * poses];
    let state = State { params: fit.params.clone(), up: fit.up.clone(), motion: fit.motion.clone() };
    let normal = normal_equations(array, stat, Some(dynamic), settings, weights, &state, &active);
    let static_normal = normal_equations(array, stat, None, settings, weights, &state, &active);
    let gauge = fit.gauge.constraints(array, true, 2 * poses);
    let seen = unseen(&normal.h, &gauge, &active);
    let (constraints, _) = pinned(&gauge, &seen, &state);
    AtSolution { normal: normal.h, static_normal: static_normal.h, constraints, active }
}

/// The robust covariance of `fit` (module docs), in the fit's gauge and with its unseen
/// parameters NaN, as `Fit::covariance`. `dynamic`: the data the fit was fitted to.
pub fn robust_covariance(
    array: &Array,
    stat: &StaticData,
    dynamic: &DynamicData,
    settings: &FitSettings,
    fit: &Fit,
) -> Result<DMatrix<f64>, FitError> {
    robust_covariance_with_bread(array, stat, dynamic, None, None, settings, fit)
}

/// [`robust_covariance`] of an M-estimator: the scores from `dynamic` (the data the fit was fitted
/// to), `K` from the information of the same outputs, each weighted by its factor in `bread`
/// (row-major, samples x accelerometers: the weight's derivative averaged over the noise,
/// `selfcal::huber::expected_derivative`; `None`: every factor 1). With `ages` (each
/// accelerometer's relative age at every sample, s: a clocked calibration whose outputs
/// `dynamic` were corrected with a fitted timing motion) the dynamic information and the scores
/// eliminate each sample's timing motion too (`selfcal::timing_information`): the covariance
/// does not hold the timing motion as known.
pub fn robust_covariance_with_bread(
    array: &Array,
    stat: &StaticData,
    dynamic: &DynamicData,
    bread: Option<&[f64]>,
    ages: Option<&DMatrix<f64>>,
    settings: &FitSettings,
    fit: &Fit,
) -> Result<DMatrix<f64>, FitError> {
    let n = array.len();
    let na = PER_ACCEL * n;
    // The bread's factors weigh the dynamic information only; the scores below take the plain
    // weights (`output_w: None`).
    let weights = Weights { dynamic_output_w: bread.map(<[f64]>::to_vec), ..Weights::stored_in(fit, stat) };
    let at = at_solution(array, stat, dynamic, &weights, settings, fit);
    let dim = at.active.len();
    let sens = sensors(array, &fit.params);
    let fixed = dynamic.reference_rate_rad_s.is_some();
    let timing = ages.map(|ages| TimingSamples {
        output_w: bread,
        ..TimingSamples::clocked(&sens, dynamic, &fit.motion, &weights.dynamic_w, ages)
    });
    let k = match &timing {
        Some(t) => at.inverse_with_dynamic(&reduced_information(t), fit)?,
        None => at.inverse(&at.normal, fit)?,
    };
    // The dynamic scores, block by block (each block's sum in order: the same bits on any
    // number of threads).
    let samples = schur::Samples {
        sens: &sens,
        data: dynamic,
        motion: &fit.motion,
        weights: &weights.dynamic_w,
        output_w: None,
        fixed,
        rate_curvature: false,
    };
    let blocks = dynamic.samples().div_ceil(BLOCK_SAMPLES);
    let scores: Vec<nalgebra::DVector<f64>> = (0..blocks)
        .into_par_iter()
        .map(|b| {
            let mut g = nalgebra::DVector::zeros(na);
            let mut scratch = SampleScratch::default();
            let range = b * BLOCK_SAMPLES..((b + 1) * BLOCK_SAMPLES).min(dynamic.samples());
            if let Some(t) = &timing {
                return reduced_score(&TimingSamples { output_w: None, ..*t }, range);
            }
            schur::accumulate_samples(&samples, range, None, &mut g, &mut scratch);
            g
        })
        .collect();
    let mut meat = at.static_normal;
    {
        let mut top = meat.view_mut((0, 0), (na, na));
        for s in &scores {
            top.ger(1.0, s, s, 1.0);
        }
    }
    let finite = k.map(|v| if v.is_finite() { v } else { 0.0 });
    let mut cov = &finite * meat * &finite;
    for i in 0..dim {
        if !k[(i, i)].is_finite() {
            cov.row_mut(i).fill(f64::NAN);
            cov.column_mut(i).fill(f64::NAN);
        }
    }
    Ok(cov)
}

/// The parameters' sigmas of a clocked calibration with each sample's timing motion eliminated
/// over those with it held as known (`selfcal::timing_information`), from the information at
/// `fit`'s solution with its stored weights (no scores: the model's covariance), per accelerometer
/// parameter (`PER_ACCEL` per accelerometer, in order; NaN where the fit does not see it).
/// `dynamic`: the rotation phase the fit was fitted to; `ages`: each accelerometer's relative age
/// at every sample (`selfcal::timing::accelerometer_ages` of the fitted clocks).
pub fn timing_free_sigma_ratios(
    array: &Array,
    stat: &StaticData,
    dynamic: &DynamicData,
    settings: &FitSettings,
    fit: &Fit,
    ages: &DMatrix<f64>,
) -> Result<Vec<f64>, FitError> {
    let na = PER_ACCEL * array.len();
    let weights = Weights::stored_in(fit, stat);
    let at = at_solution(array, stat, dynamic, &weights, settings, fit);
    let sens = sensors(array, &fit.params);
    let samples = TimingSamples::clocked(&sens, dynamic, &fit.motion, &weights.dynamic_w, ages);
    let (held, free) = (at.inverse(&at.normal, fit)?, at.inverse_with_dynamic(&reduced_information(&samples), fit)?);
    Ok((0..na).map(|i| (free[(i, i)] / held[(i, i)]).sqrt()).collect())
}
