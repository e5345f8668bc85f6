//! The joint estimator of a free calibration: every accelerometer's scale factor, bias, tilt
//! angles and location error, with the pose directions and the motion at every dynamic sample as
//! nuisance, by damped Gauss-Newton on the weighted least-squares misfit of both phases.
//!
//! - **Static phase**: the mean output of each static interval, weighted by
//!   `n_p / (sigma_j^2 v_s)` with `sigma_j` the pooled within-interval scatter of accelerometer j
//!   and `v_s = max(1, chi^2/dof)` of the static phase refitted alone (`selfcal::tension`: each
//!   accelerometer's intrinsic parameters fitted to its pose means, the poses held), so a misfit
//!   that white noise cannot explain widens the sigmas instead of being ignored. With a rotation
//!   phase the joint fit's own static chi^2/dof would carry the rotation phase's pull on the
//!   intrinsic parameters, and lower the static weight as the pull grew (a runaway seen on a real
//!   recording: 71 against 2.06 alone); without one the two are the same fit.
//! - **Dynamic phase**: every sample that is not clipped, weighted by `1 / sigma_d,j^2`, where
//!   `sigma_d,j` is re-estimated from the dynamic residuals (a variance component per
//!   accelerometer: a phase whose model is worse weighs less; one for the whole phase, floored at
//!   each accelerometer's static noise, where the sample clocks' timing term spends unknowns of
//!   its own on every sample: [`pooled_dynamic_variance`]).
//! - The motion (9 unknowns a sample; 6 with a reference rate) is eliminated sample by sample by
//!   the Schur complement, so each Gauss-Newton step solves only for the `7 N + 2 P` parameters.
//! - The gauge (`selfcal::model::Gauge`) is fixed by linear constraints in the step's KKT system;
//!   the covariance is the constrained inverse of the Fisher information, i.e. the Cramer-Rao
//!   bound in the stated gauge. Before it is fixed, the Fisher information's null directions are
//!   counted. Any beyond the gauge's are combinations the data cannot see (`selfcal::unseen`):
//!   they are held where the fit starts by constraint rows beside the gauge's, every parameter
//!   with a share in them is unidentified (NaN sigma, listed in [`Fit::unseen`]), and the rest are
//!   calibrated. A geometry or a recording that cannot see everything is named, not refused.

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::{DMatrix, DVector, Vector3};
use rayon::prelude::*;

use super::data::{DynamicData, StaticData};
use super::misfit;
use super::model::{Gauge, PER_ACCEL, SampleMotion, SensorSet, sensors};
use super::motion::{self, SampleData};
use super::schur::{self, LowerBlocks, SampleScratch, mirror_upper_blocks};
use super::tension;
use super::timing_information::{TimingSamples, reduced_information};
use super::track;
use super::unseen::{Combination, NULL_RELATIVE, Unseen, unseen};
use crate::array::Array;
use crate::sensor::misalignment::tilt_basis;

/// Settings of the estimator.
#[derive(Debug, Clone, Copy)]
pub struct FitSettings {
    pub gravity_m_s2: f64,
    pub max_iterations: usize,
    /// One dynamic variance for the whole rotation phase instead of one per accelerometer
    /// ([`pooled_dynamic_variance`]); always so where the data spend unknowns of their own on
    /// each sample.
    pub pooled_dynamic_variance: bool,
    /// Compute every sample's rate sigma ([`Fit::omega_sigma_rad_s`]; left empty without). The
    /// clocks' outer iterations skip it: their refits' sigmas are replaced after the last one.
    pub rate_sigmas: bool,
    /// The rotation phase's variance held at this value (m^2/s^4) instead of taken from the
    /// fitted residuals: Huber's pseudo-observations (`selfcal::huber`) are fitted with the
    /// variance of the outputs as measured, so that clipping the tail does not also shift the
    /// balance between the static and the rotation phase.
    pub held_dynamic_variance_m2_s4: Option<f64>,
    /// A warm start whose own fit saw every combination beyond the gauge is taken to see them
    /// still, and the start's check of what the data cannot see (a normal matrix and an
    /// eigen-decomposition, about a quarter of a warm refit) is skipped; the check at the
    /// solution is made as always. The clocks' outer iterations set it: their refits' data
    /// differ from their start's by the timing correction and Huber's shift, not in what the
    /// motion lets the array see.
    pub trust_start_unseen: bool,
    /// Check the solution (covariance, null directions, unseen space). Without it a warm fit
    /// carries its start's null directions and unseen space and has no covariance (NaN), and
    /// [`check_solution`] adds them later: the clocks' outer iterations need them only at
    /// their end (each check is a normal matrix and three eigen-decompositions, about a quarter
    /// of a warm refit).
    pub solution_check: bool,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            gravity_m_s2: crate::units::STANDARD_GRAVITY_M_S2,
            max_iterations: 50,
            pooled_dynamic_variance: false,
            rate_sigmas: true,
            held_dynamic_variance_m2_s4: None,
            trust_start_unseen: false,
            solution_check: true,
        }
    }
}

/// The result of a fit.
#[derive(Debug, Clone)]
pub struct Fit {
    pub params: SensorSet,
    /// Up direction of every static interval, array axes.
    pub up: Vec<Vector3<f64>>,
    pub motion: Vec<SampleMotion>,
    /// Sigma of each sample's rate given the sensor parameters (rad/s, per axis).
    pub omega_sigma_rad_s: Vec<Vector3<f64>>,
    /// Covariance of `(accelerometer parameters, pose tangents)`, in the gauge; NaN rows for
    /// parameters the data cannot identify (locations without a dynamic phase, and every parameter
    /// with a share in an unseen combination).
    pub covariance: DMatrix<f64>,
    pub locations_identified: bool,
    pub gauge: Gauge,
    /// Null directions of the Fisher information before the gauge is fixed.
    pub null_directions: usize,
    /// The null directions beyond the gauge's: parameter combinations the data cannot see (held
    /// at their start; see `selfcal::unseen`). Empty when the data see everything but the gauge.
    pub unseen: Vec<Combination>,
    /// Per parameter (accelerometer parameters, then pose tangents): it has a share in an unseen
    /// combination, so it has no value and no sigma.
    pub unseen_parameters: Vec<bool>,
    pub static_chi2_dof: f64,
    pub static_residual_rms_m_s2: f64,
    pub static_variance_factor: f64,
    /// Per accelerometer: dynamic residual RMS and the variance component used.
    pub dynamic_residual_rms_m_s2: Vec<f64>,
    pub dynamic_sigma_m_s2: Vec<f64>,
    /// Dynamic misfit against the static noise: sum (r / sigma_j)^2 / dof.
    pub dynamic_chi2_dof: f64,
    pub iterations: usize,
    pub converged: bool,
    /// Every damped Gauss-Newton trial step, in order (for a caller that wants to see the solver
    /// work: the library itself never prints).
    pub trace: Vec<GnTrial>,
    /// The smallest eigenvalues (up to 10, ascending) of the Fisher information scaled by its
    /// diagonal, relative to the largest: the null-direction count's evidence.
    pub smallest_scaled_eigenvalues: Vec<f64>,
}

/// One trial step of the damped Gauss-Newton solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnTrial {
    pub iteration: usize,
    pub lambda: f64,
    /// The cost before the step and at the trial point (a chi-square: weights are inverse
    /// variances).
    pub cost: f64,
    pub trial_cost: f64,
}

impl Fit {
    /// Sigma of parameter `p` of accelerometer `j` (NaN where not identifiable).
    pub fn sigma(&self, j: usize, p: usize) -> f64 {
        self.covariance[(PER_ACCEL * j + p, PER_ACCEL * j + p)].sqrt()
    }
    /// Whether parameter `p` of accelerometer `j` is identified (a finite sigma).
    pub fn identified(&self, j: usize, p: usize) -> bool {
        self.sigma(j, p).is_finite()
    }
    /// Each accelerometer's weight in the rotation phase, `1 / sigma_d,j^2`.
    pub fn dynamic_weights(&self) -> Vec<f64> {
        self.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect()
    }
}

/// Why a fit failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    #[error(
        "{found} static interval(s); a calibration {} needs at least {needed}",
        if *with_dynamic { "with a rotation phase" } else { "from static poses alone (no rotation phase)" }
    )]
    TooFewPoses { found: usize, needed: usize, with_dynamic: bool },
    #[error("the normal equations are singular beyond the gauge: {0}")]
    Singular(String),
}

/// Static poses of unknown direction that a calibration without a rotation phase needs (see
/// `fit`).
pub const STATIC_ONLY_POSES: usize = 9;

/// First guess of each pose's up direction from nominal axes (least squares over the array).
fn initial_up(array: &Array, data: &StaticData) -> Vec<Vector3<f64>> {
    let normal: nalgebra::Matrix3<f64> = array.accelerometers().iter().map(|a| a.axis * a.axis.transpose()).sum();
    let inv = normal.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
    (0..data.means.nrows())
        .map(|p| {
            let b: Vector3<f64> =
                array.accelerometers().iter().enumerate().map(|(j, a)| a.axis * data.means[(p, j)]).sum();
            let v = inv * b;
            if v.norm() > 0.0 { v.normalize() } else { Vector3::z() }
        })
        .collect()
}

pub(super) struct State {
    pub(super) params: SensorSet,
    pub(super) up: Vec<Vector3<f64>>,
    pub(super) motion: Vec<SampleMotion>,
}

pub(super) struct Normal {
    pub(super) h: DMatrix<f64>,
    g: DVector<f64>,
}

pub(super) struct Weights {
    pub(super) static_w: DMatrix<f64>,
    pub(super) dynamic_w: Vec<f64>,
    /// Per rotation-phase output (row-major), a factor on its accelerometer's weight: the robust
    /// covariance's bread (`selfcal::robust`); `None` everywhere else.
    pub(super) dynamic_output_w: Option<Vec<f64>>,
}

impl Weights {
    /// The weights a fit stores: its static variance factor and its dynamic sigmas (each weight
    /// rebuilt from its sigma, to about 1e-16 of itself).
    pub(super) fn stored_in(fit: &Fit, stat: &StaticData) -> Self {
        let (poses, n) = (stat.means.nrows(), fit.params.len());
        Self {
            static_w: DMatrix::from_fn(poses, n, |p, j| {
                stat.counts[p] as f64 / (stat.sigma[j].powi(2) * fit.static_variance_factor)
            }),
            dynamic_w: fit.dynamic_weights(),
            dynamic_output_w: None,
        }
    }
}

/// The parameters a fit estimates (accelerometer parameters, then the poses' tangents): every
/// one, but the locations without a rotation phase.
fn active_parameters(n: usize, poses: usize, with_dynamic: bool) -> Vec<bool> {
    (0..PER_ACCEL * n + 2 * poses).map(|i| with_dynamic || i >= PER_ACCEL * n || i % PER_ACCEL < 4).collect()
}

/// The rotation phase's one dynamic variance, m^2/s^4: `sum_j c_j r_j^2 / sum_j c_j / L_j`, the
/// residuals' sum of squares over the phase's degrees of freedom (`selfcal::misfit`); `None`
/// where it cannot be formed. Used where [`FitSettings::pooled_dynamic_variance`] asks for it or
/// the data spend unknowns of their own on every sample (the sample clocks' timing term).
///
/// Why pooled there. A component per accelerometer, `r_j^2 L_j`, takes the leverage of equal
/// weights. With 12-15 local unknowns among a sample's 24 outputs, an accelerometer weighted
/// above the rest takes a larger share of its samples' local fit than `L_j` allows for: its
/// residual shrinks, its variance with it, and its weight grows at the next refit. The sample
/// clocks' outer iterations ran that away on every real recording (residuals of single
/// accelerometers down to 0.001 m/s^2, a thirtieth of their static noise, and a misfit that rose
/// with each iteration: `docs/sample-clocks.md`). One variance keeps the weights equal (above the
/// static floors), where the equal-weights leverage is the redundancy the estimate needs. With 9
/// or 6 local unknowns the per-accelerometer components do not run away.
pub(super) fn pooled_dynamic_variance(d: &DynamicData, rms: &[f64], counts: &[usize], local: f64) -> Option<f64> {
    let sum_sq: f64 = rms.iter().zip(counts).filter(|(r, _)| r.is_finite()).map(|(r, &c)| r * r * c as f64).sum();
    let dof = misfit::dof(d, local);
    (dof > 0.0 && sum_sq.is_finite()).then_some(sum_sq / dof)
}

/// Fits the model to a recording's static and (optional) dynamic phase.
pub fn fit(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
) -> Result<Fit, FitError> {
    fit_from(array, stat, dynamic, settings, None)
}

/// [`fit`] started from an earlier fit of the same recording (its parameters, poses, motion and
/// variance components), e.g. after the dynamic outputs were corrected: the static-only start
/// and the motion's tracking from scratch are skipped.
pub fn fit_from(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    start: Option<&Fit>,
) -> Result<Fit, FitError> {
    let n = array.len();
    let poses = stat.means.nrows();
    let with_dynamic = dynamic.is_some_and(|d| d.samples() > 0);
    // 4 N static parameters (less 3 of gauge) against N P means with 2 P pose unknowns; and
    // each accelerometer needs its scale factor, bias and two tilts from at least 4 poses.
    // Static poses alone need 9 more: the pose directions can move by `w_p = M u_p + c` (M
    // symmetric, 9 unknowns; the antisymmetric part is the rotation gauge), which every
    // accelerometer's scale factor, bias and tilts absorb, wherever the move stays tangent,
    // `u_p^T M u_p + c . u_p = 0`, at every pose: one equation a pose, so 8 poses or fewer
    // leave a direction unseen. A rotation phase sees those parameters without the poses.
    let counted = 4_usize.max(((4 * n).saturating_sub(3)).div_ceil(n.saturating_sub(2).max(1)) + 1);
    let needed = if with_dynamic { counted } else { counted.max(STATIC_ONLY_POSES) };
    if poses < needed {
        return Err(FitError::TooFewPoses { found: poses, needed, with_dynamic });
    }
    let reference_rate = dynamic.and_then(|d| d.reference_rate_rad_s.as_ref()).is_some();
    let gauge = Gauge::new(array, with_dynamic, reference_rate);
    let active = active_parameters(n, poses, with_dynamic);
    let gauge_constraints = gauge.constraints(array, with_dynamic, 2 * poses);

    let mut state = State {
        params: SensorSet::nominal(n),
        up: initial_up(array, stat),
        motion: dynamic.map(|d| vec![SampleMotion::default(); d.samples()]).unwrap_or_default(),
    };
    let mut weights = Weights {
        static_w: DMatrix::from_fn(poses, n, |p, j| stat.counts[p] as f64 / stat.sigma[j].powi(2)),
        dynamic_w: stat.sigma.iter().map(|s| 1.0 / (s * s)).collect(),
        dynamic_output_w: None,
    };
    let mut static_factor = 1.0;
    let mut iterations = 0;
    let mut converged = false;
    let mut trace = Vec::new();
    if let Some(s) = start.filter(|s| s.motion.len() == dynamic.map_or(0, |d| d.samples())) {
        state = State { params: s.params.clone(), up: s.up.clone(), motion: s.motion.clone() };
        static_factor = s.static_variance_factor;
        weights.static_w =
            DMatrix::from_fn(poses, n, |p, j| stat.counts[p] as f64 / (stat.sigma[j].powi(2) * static_factor));
        if let Some(v) = settings.held_dynamic_variance_m2_s4 {
            weights.dynamic_w = stat.sigma.iter().map(|s| 1.0 / v.max(s * s)).collect();
        } else if s.dynamic_sigma_m_s2.iter().all(|v| v.is_finite() && *v > 0.0) {
            weights.dynamic_w = s.dynamic_sigma_m_s2.iter().map(|v| 1.0 / (v * v)).collect();
        }
    } else {
        fit_start(array, stat, dynamic, settings, &weights, &active, with_dynamic, &mut state, &mut trace);
    }

    // Combinations the data cannot see beyond the gauge are held where they start.
    // (Where the start saw everything, with `trust_start_unseen`, the gauge alone: what `pinned`
    // gives for an empty unseen space.)
    let trusted = start
        .is_some_and(|s| settings.trust_start_unseen && s.unseen.is_empty() && !s.unseen_parameters.iter().any(|&u| u));
    let (constraints, values) = if trusted {
        (gauge_constraints.clone(), DVector::zeros(gauge_constraints.nrows()))
    } else {
        let normal =
            normal_equations(array, stat, dynamic.filter(|_| with_dynamic), settings, &weights, &state, &active);
        let seen = unseen(&normal.h, &gauge_constraints, &active);
        pinned(&gauge_constraints, &seen, &state)
    };
    let warm = start.is_some();
    for round in 0..4 {
        if (round > 0 || warm)
            && let Some(d) = dynamic.filter(|_| with_dynamic)
        {
            state.motion = track::refine(array, d, &weights.dynamic_w, &state.params, &state.motion, true);
        }
        let (it, ok) = gauss_newton(
            array,
            stat,
            dynamic,
            settings,
            &weights,
            &active,
            &constraints,
            &values,
            &mut state,
            settings.max_iterations,
            &mut trace,
        );
        iterations += it;
        converged = ok;
        // Variance components. The static phase's: its scatter about its own best fit
        // (`selfcal::tension::static_only_chi2_dof`, the poses held), not about the joint fit's.
        // Where the rotation phase pulls the intrinsic parameters away from what the static poses
        // say, the joint fit's static chi^2 grows with the pull; taken as the static variance it
        // lowers the static weight, which lets the rotation phase pull further (recording 4 of the
        // MIMU4444 ran to a static chi^2/dof of 71 so, where the static phase alone fits to 2.06).
        let own = if with_dynamic {
            tension::static_only_chi2_dof(array, stat, &state.params, &state.up, settings.gravity_m_s2)
        } else {
            f64::NAN
        };
        let new_factor = if own.is_finite() {
            own
        } else {
            let (chi2, dof) = static_chi2(array, stat, &state, settings);
            chi2 / dof
        }
        .max(1.0);
        let mut changed = (new_factor / static_factor - 1.0).abs() > 0.01;
        static_factor = new_factor;
        weights.static_w =
            DMatrix::from_fn(poses, n, |p, j| stat.counts[p] as f64 / (stat.sigma[j].powi(2) * static_factor));
        if let Some(d) = dynamic.filter(|_| with_dynamic) {
            let (rms, counts) = misfit::residual_rms(array, &state.params, d, &state.motion);
            let local = misfit::local_unknowns(d);
            let pool = settings.pooled_dynamic_variance || d.extra_unknowns_per_sample > 0;
            let pooled = settings
                .held_dynamic_variance_m2_s4
                .or_else(|| pool.then(|| pooled_dynamic_variance(d, &rms, &counts, local)).flatten());
            let leverage = if pooled.is_none() { misfit::leverages(d, local) } else { Vec::new() };
            for j in 0..n {
                let var = match pooled {
                    Some(v) => v,
                    None => rms[j].powi(2) * leverage[j],
                };
                let var = var.max(stat.sigma[j].powi(2));
                let w = 1.0 / var;
                changed |= (w / weights.dynamic_w[j] - 1.0).abs() > 0.01;
                weights.dynamic_w[j] = w;
            }
        }
        if !changed {
            break;
        }
    }

    // Covariance and null directions at the solution (or, without `solution_check`, the start's
    // unseen space and null count carried, and no covariance: `check_solution` adds them).
    let carried = start.filter(|_| !settings.solution_check);
    let check = match carried {
        Some(s) => SolutionCheck {
            covariance: DMatrix::from_element(active.len(), active.len(), f64::NAN),
            null_directions: s.null_directions,
            smallest_scaled_eigenvalues: s.smallest_scaled_eigenvalues.clone(),
            unseen: s.unseen.clone(),
            unseen_parameters: s.unseen_parameters.clone(),
        },
        None => solution_check(
            array,
            stat,
            dynamic.filter(|_| with_dynamic),
            settings,
            &weights,
            &state,
            &active,
            &gauge_constraints,
        )?,
    };
    let SolutionCheck {
        covariance,
        null_directions,
        smallest_scaled_eigenvalues,
        unseen: unseen_combinations,
        unseen_parameters,
    } = check;
    let omega_sigma_rad_s = match dynamic.filter(|_| with_dynamic && settings.rate_sigmas && carried.is_none()) {
        Some(d) => {
            track::rate_sigmas(array, d, &weights.dynamic_w, &state.params, &state.motion, reference_rate, &covariance)
        }
        None => Vec::new(),
    };
    let (chi2, dof) = static_chi2(array, stat, &state, settings);
    let static_residual_rms_m_s2 = static_rms(array, stat, &state, settings);
    let (dyn_rms, dyn_chi2_dof) = match dynamic.filter(|_| with_dynamic) {
        Some(d) => {
            let (rms, _) = misfit::residual_rms(array, &state.params, d, &state.motion);
            let chi2_dof = misfit::chi2_dof(d, &rms, &stat.sigma);
            (rms, chi2_dof)
        }
        None => (vec![f64::NAN; n], f64::NAN),
    };
    Ok(Fit {
        params: state.params,
        up: state.up,
        motion: state.motion,
        omega_sigma_rad_s,
        covariance,
        locations_identified: with_dynamic,
        gauge,
        null_directions,
        unseen: unseen_combinations,
        unseen_parameters,
        static_chi2_dof: chi2 / dof,
        static_residual_rms_m_s2,
        static_variance_factor: static_factor,
        dynamic_sigma_m_s2: weights.dynamic_w.iter().map(|w| 1.0 / w.sqrt()).collect(),
        dynamic_residual_rms_m_s2: dyn_rms,
        dynamic_chi2_dof: dyn_chi2_dof,
        iterations,
        converged,
        trace,
        smallest_scaled_eigenvalues,
    })
}

/// What [`fit_from`] finds at its solution beside the parameters: the covariance, the null
/// directions and what the data cannot see beyond the gauge.
struct SolutionCheck {
    covariance: DMatrix<f64>,
    null_directions: usize,
    smallest_scaled_eigenvalues: Vec<f64>,
    unseen: Vec<Combination>,
    unseen_parameters: Vec<bool>,
}

#[allow(clippy::too_many_arguments)]
fn solution_check(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    weights: &Weights,
    state: &State,
    active: &[bool],
    gauge_constraints: &DMatrix<f64>,
) -> Result<SolutionCheck, FitError> {
    let normal = normal_equations(array, stat, dynamic, settings, weights, state, active);
    let (null_directions, smallest_scaled_eigenvalues) = count_null(&normal.h, active);
    let mut seen = unseen(&normal.h, gauge_constraints, active);
    let (all_constraints, _) = pinned(gauge_constraints, &seen, state);
    if !seen.is_empty() {
        // Beside the unseen space (to rounding), a parameter whose variance is not positive is
        // not seen either.
        let mut probe = vec![false; active.len()];
        let cov = constrained_inverse(&normal.h, &all_constraints, active, &probe, true)?;
        for i in 0..active.len() {
            probe[i] = active[i] && !(cov[(i, i)] > 0.0);
            seen.parameters[i] |= probe[i];
        }
    }
    let covariance = constrained_inverse(&normal.h, &all_constraints, active, &seen.parameters, false)?;
    Ok(SolutionCheck {
        covariance,
        null_directions,
        smallest_scaled_eigenvalues,
        unseen: seen.combinations,
        unseen_parameters: seen.parameters,
    })
}

/// The check [`fit_from`] skips without `solution_check`, made at `fit`'s solution: its
/// covariance, null directions and unseen space, with the weights the fit stores (its
/// variance components; `dynamic` the data it was fitted to).
pub fn check_solution(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    fit: &mut Fit,
) -> Result<(), FitError> {
    let (n, poses) = (array.len(), stat.means.nrows());
    let with_dynamic = dynamic.is_some_and(|d| d.samples() > 0);
    let active = active_parameters(n, poses, with_dynamic);
    let weights = Weights::stored_in(fit, stat);
    let state = State { params: fit.params.clone(), up: fit.up.clone(), motion: fit.motion.clone() };
    let gauge_constraints = fit.gauge.constraints(array, with_dynamic, 2 * poses);
    let check = solution_check(
        array,
        stat,
        dynamic.filter(|_| with_dynamic),
        settings,
        &weights,
        &state,
        &active,
        &gauge_constraints,
    )?;
    fit.covariance = check.covariance;
    fit.null_directions = check.null_directions;
    fit.smallest_scaled_eigenvalues = check.smallest_scaled_eigenvalues;
    fit.unseen = check.unseen;
    fit.unseen_parameters = check.unseen_parameters;
    Ok(())
}

/// The cold start of [`fit_from`]: the static phase alone (locations held), then the motion of
/// every dynamic sample tracked from scratch.
#[allow(clippy::too_many_arguments)]
fn fit_start(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    weights: &Weights,
    active: &[bool],
    with_dynamic: bool,
    state: &mut State,
    trace: &mut Vec<GnTrial>,
) {
    let (n, poses, dim) = (array.len(), stat.means.nrows(), active.len());
    // First the static phase alone (locations held), then both phases.
    let static_only_active: Vec<bool> =
        (0..dim).map(|i| active[i] && (i >= PER_ACCEL * n || i % PER_ACCEL < 4)).collect();
    let static_gauge = Gauge { rotation: true, translation: false, scale: false, translation_groups: 1 };
    let static_constraints = static_gauge.constraints(array, false, 2 * poses);
    let zeros = DVector::zeros(static_constraints.nrows());
    gauss_newton(
        array,
        stat,
        None,
        settings,
        weights,
        &static_only_active,
        &static_constraints,
        &zeros,
        state,
        30,
        trace,
    );

    if let Some(d) = dynamic.filter(|_| with_dynamic) {
        state.motion = track::from_scratch(array, d, &weights.dynamic_w, &state.params);
    }
}

#[allow(clippy::too_many_arguments)]
fn gauss_newton(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    w: &Weights,
    active: &[bool],
    constraints: &DMatrix<f64>,
    values: &DVector<f64>,
    state: &mut State,
    max_iterations: usize,
    trace: &mut Vec<GnTrial>,
) -> (usize, bool) {
    let dynamic = dynamic.filter(|d| d.samples() > 0);
    let mut lambda = UNDAMPED_LAMBDA;
    let mut cost = total_cost(array, stat, dynamic, settings, w, state);
    for it in 0..max_iterations {
        let normal = normal_equations_with(array, stat, dynamic, settings, w, state, active, true);
        let mut accepted = false;
        for _ in 0..12 {
            let Some(step) = kkt_step(&normal, constraints, values, active, state, lambda, array.len()) else {
                lambda *= 10.0;
                continue;
            };
            let trial = apply_step(array, dynamic, w, state, &step);
            let trial_cost = total_cost(array, stat, dynamic, settings, w, &trial);
            trace.push(GnTrial { iteration: it, lambda, cost, trial_cost });
            if trial_cost > cost && lambda <= UNDAMPED_LAMBDA && predicted_fall(&normal, &step) < 1.0 {
                // The undamped step, predicted to lower the chi^2 by less than 1, raised it: the
                // point is already within every parameter's one-sigma interval (a chi^2 rise of
                // 1) of the quadratic model's minimum, and the cost is not that smooth (each
                // sample's motion is re-solved, and a clock's sawtooth wraps); raising the
                // damping would only find falls of that size, at a re-solve of every motion each.
                return (it + 1, true);
            }
            if trial_cost <= cost {
                let decrease = cost - trial_cost;
                *state = trial;
                // The cost is a chi^2 (weights are inverse variances): a decrease below 0.01, or a
                // millionth of the cost when the model leaves a large misfit, is no progress.
                let done = decrease <= 0.01_f64.max(1e-6 * cost);
                cost = trial_cost;
                // Marquardt damping relative to the diagonal: below 1e-6 the step is the
                // Gauss-Newton step to working precision, and a lower floor only costs refits
                // climbing back after a rejected step.
                lambda = (lambda * 0.1).max(UNDAMPED_LAMBDA);
                accepted = true;
                if done {
                    return (it + 1, true);
                }
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            // No step lowers the cost: at the minimum to working precision.
            return (it + 1, true);
        }
    }
    (max_iterations, false)
}

/// The damping of [`gauss_newton`]'s first try, and its floor: Marquardt damping relative to the
/// diagonal, below which the step is the Gauss-Newton step to working precision.
const UNDAMPED_LAMBDA: f64 = 1e-6;

/// The fall of the chi^2 that the quadratic model predicts for `step`: `2 g^T s - s^T H s`.
fn predicted_fall(normal: &Normal, step: &DVector<f64>) -> f64 {
    2.0 * normal.g.dot(step) - step.dot(&(&normal.h * step))
}

fn apply_step(array: &Array, dynamic: Option<&DynamicData>, w: &Weights, state: &State, step: &DVector<f64>) -> State {
    let n = array.len();
    let mut params = state.params.clone();
    for j in 0..n {
        for p in 0..PER_ACCEL {
            params.add(j, p, step[PER_ACCEL * j + p]);
        }
    }
    let up = state
        .up
        .iter()
        .enumerate()
        .map(|(p, u)| {
            let (e1, e2) = tilt_basis(u);
            (u + e1 * step[PER_ACCEL * n + 2 * p] + e2 * step[PER_ACCEL * n + 2 * p + 1]).normalize()
        })
        .collect();
    let motion = match dynamic {
        Some(d) => track::refine(array, d, &w.dynamic_w, &params, &state.motion, false),
        None => state.motion.clone(),
    };
    State { params, up, motion }
}

fn total_cost(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    w: &Weights,
    state: &State,
) -> f64 {
    let sens = sensors(array, &state.params);
    let mut c = 0.0;
    for (p, u) in state.up.iter().enumerate() {
        let q = u * settings.gravity_m_s2;
        for (j, s) in sens.iter().enumerate() {
            let r = stat.means[(p, j)] - s.output(&q);
            c += w.static_w[(p, j)] * r * r;
        }
    }
    if let Some(d) = dynamic {
        let n = array.len();
        c += (0..d.samples())
            .into_par_iter()
            .map(|i| {
                let row: Vec<f64> = d.outputs.row(i).iter().copied().collect();
                let data = SampleData { outputs: &row, used: &d.used[i * n..(i + 1) * n], weights: &w.dynamic_w };
                motion::cost(&sens, &data, &state.motion[i])
            })
            .collect::<Vec<f64>>()
            .iter()
            .sum::<f64>();
    }
    c
}

/// Normal equations of the parameters with the motion eliminated (Schur complement).
pub(super) fn normal_equations(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    w: &Weights,
    state: &State,
    active: &[bool],
) -> Normal {
    normal_equations_with(array, stat, dynamic, settings, w, state, active, false)
}

/// [`normal_equations`] with `rate_curvature`: the samples' motions eliminated with the residual's
/// curvature in their rate blocks, as `motion::solve` solves them (the Gauss-Newton steps' model
/// of the cost). Without it the information is the Fisher information (the covariance's).
#[allow(clippy::too_many_arguments)]
fn normal_equations_with(
    array: &Array,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &FitSettings,
    w: &Weights,
    state: &State,
    active: &[bool],
    rate_curvature: bool,
) -> Normal {
    let n = array.len();
    let na = PER_ACCEL * n;
    let dim = na + 2 * state.up.len();
    let sens = sensors(array, &state.params);
    let mut h = DMatrix::zeros(dim, dim);
    let mut g = DVector::zeros(dim);
    for (p, u) in state.up.iter().enumerate() {
        let q = u * settings.gravity_m_s2;
        let (e1, e2) = tilt_basis(u);
        for (j, s) in sens.iter().enumerate() {
            let r = stat.means[(p, j)] - s.output(&q);
            let d4 = s.d_intrinsic(&q);
            let dpose = [s.k * settings.gravity_m_s2 * s.axis.dot(&e1), s.k * settings.gravity_m_s2 * s.axis.dot(&e2)];
            let idx: [usize; 6] =
                [PER_ACCEL * j, PER_ACCEL * j + 1, PER_ACCEL * j + 2, PER_ACCEL * j + 3, na + 2 * p, na + 2 * p + 1];
            let val = [d4[0], d4[1], d4[2], d4[3], dpose[0], dpose[1]];
            let wt = w.static_w[(p, j)];
            for a in 0..6 {
                g[idx[a]] += wt * val[a] * r;
                for b in 0..6 {
                    h[(idx[a], idx[b])] += wt * val[a] * val[b];
                }
            }
        }
    }
    if let Some(d) = dynamic {
        let samples = schur::Samples {
            sens: &sens,
            data: d,
            motion: &state.motion,
            weights: &w.dynamic_w,
            output_w: w.dynamic_output_w.as_deref(),
            fixed: d.reference_rate_rad_s.is_some(),
            rate_curvature,
        };
        let chunk = 256;
        let parts: Vec<(LowerBlocks, DVector<f64>)> = (0..d.samples().div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let mut ha = LowerBlocks::zeros(n);
                let mut ga = DVector::zeros(na);
                let mut scratch = SampleScratch::default();
                let range = c * chunk..((c + 1) * chunk).min(d.samples());
                schur::accumulate_samples(&samples, range, Some(&mut ha), &mut ga, &mut scratch);
                (ha, ga)
            })
            .collect();
        for (ha, ga) in parts {
            ha.add_to(&mut h);
            let mut gv = g.rows_mut(0, na);
            gv += &ga;
        }
        mirror_upper_blocks(&mut h, n);
    }
    for i in 0..dim {
        if !active[i] {
            h.row_mut(i).fill(0.0);
            h.column_mut(i).fill(0.0);
            g[i] = 0.0;
        }
    }
    Normal { h, g }
}

/// The gauge's rows and the unseen combinations' rows, with the values that hold them: zero for
/// the gauge, the current value for an unseen combination.
pub(super) fn pinned(gauge: &DMatrix<f64>, seen: &Unseen, state: &State) -> (DMatrix<f64>, DVector<f64>) {
    let (ng, dim) = gauge.shape();
    let rows = seen.rows();
    let mut c = DMatrix::zeros(ng + rows.nrows(), dim);
    c.view_mut((0, 0), (ng, dim)).copy_from(gauge);
    c.view_mut((ng, 0), (rows.nrows(), dim)).copy_from(&rows);
    let x = parameter_vector(state, dim);
    let mut values = &c * x;
    values.rows_mut(0, ng).fill(0.0);
    (c, values)
}

/// The accelerometer parameters' values, then zeros for the pose tangents (`dim` in all).
fn parameter_vector(state: &State, dim: usize) -> DVector<f64> {
    let mut x = DVector::zeros(dim);
    for j in 0..state.params.len() {
        for p in 0..PER_ACCEL {
            x[PER_ACCEL * j + p] = state.params.get(j, p);
        }
    }
    x
}

/// Solves the damped, constrained step (`C (x + step) = values`); `None` when singular.
fn kkt_step(
    normal: &Normal,
    constraints: &DMatrix<f64>,
    values: &DVector<f64>,
    active: &[bool],
    state: &State,
    lambda: f64,
    n: usize,
) -> Option<DVector<f64>> {
    let dim = normal.h.nrows();
    let nc = constraints.nrows();
    let mut k = DMatrix::zeros(dim + nc, dim + nc);
    let mut rhs = DVector::zeros(dim + nc);
    k.view_mut((0, 0), (dim, dim)).copy_from(&normal.h);
    for i in 0..dim {
        if active[i] {
            k[(i, i)] += lambda * normal.h[(i, i)].max(1e-300);
        } else {
            k[(i, i)] = 1.0;
        }
    }
    k.view_mut((dim, 0), (nc, dim)).copy_from(constraints);
    k.view_mut((0, dim), (dim, nc)).copy_from(&constraints.transpose());
    rhs.rows_mut(0, dim).copy_from(&normal.g);
    // Constraint on the values: C (x + step) = values.
    debug_assert_eq!(state.params.len(), n);
    let x = parameter_vector(state, dim);
    let cx = constraints * &x;
    rhs.rows_mut(dim, nc).copy_from(&(values - cx));
    let sol = k.lu().solve(&rhs)?;
    let step = sol.rows(0, dim).into_owned();
    step.iter().all(|v| v.is_finite()).then_some(step)
}

/// Covariance in the gauge: the top-left block of the inverse KKT matrix, NaN on the inactive
/// parameters and on those of an unseen combination (`unseen`, held by rows of `constraints`).
/// `lenient`: an active, seen parameter whose variance is not positive is no error.
pub fn constrained_inverse(
    h: &DMatrix<f64>,
    constraints: &DMatrix<f64>,
    active: &[bool],
    unseen: &[bool],
    lenient: bool,
) -> Result<DMatrix<f64>, FitError> {
    let dim = h.nrows();
    let nc = constraints.nrows();
    let mut k = DMatrix::zeros(dim + nc, dim + nc);
    k.view_mut((0, 0), (dim, dim)).copy_from(h);
    for i in 0..dim {
        if !active[i] {
            k[(i, i)] = 1.0;
        }
    }
    k.view_mut((dim, 0), (nc, dim)).copy_from(constraints);
    k.view_mut((0, dim), (dim, nc)).copy_from(&constraints.transpose());
    let inv = k.try_inverse().ok_or_else(|| FitError::Singular("the constrained Fisher information".into()))?;
    let mut cov = inv.view((0, 0), (dim, dim)).into_owned();
    for i in 0..dim {
        if !active[i] || unseen[i] {
            cov.row_mut(i).fill(f64::NAN);
            cov.column_mut(i).fill(f64::NAN);
        }
    }
    if !lenient && (0..dim).any(|i| active[i] && !unseen[i] && !(cov[(i, i)] > 0.0)) {
        return Err(FitError::Singular("a parameter's variance is not positive".into()));
    }
    Ok(cov)
}

/// Null directions of the (active part of the) Fisher information, after scaling by its diagonal,
/// and its smallest scaled eigenvalues relative to the largest (up to 10, ascending).
fn count_null(h: &DMatrix<f64>, active: &[bool]) -> (usize, Vec<f64>) {
    let idx: Vec<usize> = (0..h.nrows()).filter(|&i| active[i]).collect();
    let m = idx.len();
    let scale: Vec<f64> = idx.iter().map(|&i| h[(i, i)].max(1e-300).sqrt()).collect();
    let s = DMatrix::from_fn(m, m, |a, b| h[(idx[a], idx[b])] / (scale[a] * scale[b]));
    let eig = s.symmetric_eigenvalues();
    let max = eig.iter().cloned().fold(0.0, f64::max);
    let mut smallest: Vec<f64> = eig.iter().map(|e| e / max).collect();
    smallest.sort_by(f64::total_cmp);
    smallest.truncate(10);
    (eig.iter().filter(|&&e| e < NULL_RELATIVE * max).count(), smallest)
}

/// The joint fit's static chi^2 and its degrees of freedom (`selfcal::tension`'s, at the state).
fn static_chi2(array: &Array, stat: &StaticData, state: &State, settings: &FitSettings) -> (f64, f64) {
    let chi2 = tension::static_chi2(array, stat, &state.params, &state.up, settings.gravity_m_s2);
    (chi2, tension::static_dof(array.len(), state.up.len()))
}

fn static_rms(array: &Array, stat: &StaticData, state: &State, settings: &FitSettings) -> f64 {
    let sens = sensors(array, &state.params);
    let mut s = 0.0;
    let mut c = 0.0;
    for (p, u) in state.up.iter().enumerate() {
        let q = u * settings.gravity_m_s2;
        for (j, sn) in sens.iter().enumerate() {
            s += (stat.means[(p, j)] - sn.output(&q)).powi(2);
            c += 1.0;
        }
    }
    (s / c).sqrt()
}

/// The Cramer-Rao bound in the gauge at a known state: the constrained inverse of the Fisher
/// information for static means of `counts` samples and dynamic samples of `dynamic`, with white
/// noise `sigma` per sample and accelerometer. With `ages` (each accelerometer's relative age at
/// every dynamic sample, s: an array whose packages' sample clocks the calibration models) each
/// sample's timing motion is eliminated too, as the calibration's covariance eliminates it. Also
/// returns the null directions before the gauge.
#[allow(clippy::too_many_arguments)]
pub fn cramer_rao(
    array: &Array,
    counts: &[usize],
    sigma: &[f64],
    up: &[Vector3<f64>],
    dynamic: Option<&DynamicData>,
    motion: &[SampleMotion],
    params: &SensorSet,
    gravity_m_s2: f64,
    ages: Option<&DMatrix<f64>>,
) -> Result<(DMatrix<f64>, usize), FitError> {
    let n = array.len();
    let poses = up.len();
    let with_dynamic = dynamic.is_some_and(|d| d.samples() > 0);
    let reference_rate = dynamic.and_then(|d| d.reference_rate_rad_s.as_ref()).is_some();
    let gauge = Gauge::new(array, with_dynamic, reference_rate);
    let dim = PER_ACCEL * n + 2 * poses;
    let active: Vec<bool> = (0..dim).map(|i| with_dynamic || i >= PER_ACCEL * n || i % PER_ACCEL < 4).collect();
    let stat = StaticData { means: DMatrix::zeros(poses, n), counts: counts.to_vec(), sigma: sigma.to_vec() };
    let weights = Weights {
        static_w: DMatrix::from_fn(poses, n, |p, j| counts[p] as f64 / sigma[j].powi(2)),
        dynamic_w: sigma.iter().map(|s| 1.0 / (s * s)).collect(),
        dynamic_output_w: None,
    };
    let state = State { params: params.clone(), up: up.to_vec(), motion: motion.to_vec() };
    let settings = FitSettings { gravity_m_s2, ..FitSettings::default() };
    let timing = ages.zip(dynamic).filter(|_| with_dynamic);
    // With the timing motion the dynamic information is formed below (`selfcal::timing_information`).
    let dynamic_normal = dynamic.filter(|_| with_dynamic && timing.is_none());
    let mut normal = normal_equations(array, &stat, dynamic_normal, &settings, &weights, &state, &active);
    if let Some((ages, d)) = timing {
        // Each sample's timing motion eliminated with its motion.
        let na = PER_ACCEL * n;
        let sens = sensors(array, params);
        let samples = TimingSamples::clocked(&sens, d, motion, &weights.dynamic_w, ages);
        let mut top = normal.h.view_mut((0, 0), (na, na));
        top += reduced_information(&samples);
    }
    let (null, _) = count_null(&normal.h, &active);
    let constraints = gauge.constraints(array, with_dynamic, 2 * poses);
    Ok((constrained_inverse(&normal.h, &constraints, &active, &vec![false; dim], false)?, null))
}

/// What the Fisher information at a known state (as [`cramer_rao`]) cannot see: its null
/// directions before the gauge, the gauge, and the combinations beyond the gauge's.
#[allow(clippy::too_many_arguments)]
pub fn unseen_at(
    array: &Array,
    counts: &[usize],
    sigma: &[f64],
    up: &[Vector3<f64>],
    dynamic: Option<&DynamicData>,
    motion: &[SampleMotion],
    params: &SensorSet,
    gravity_m_s2: f64,
) -> (usize, Gauge, Unseen) {
    let n = array.len();
    let poses = up.len();
    let with_dynamic = dynamic.is_some_and(|d| d.samples() > 0);
    let reference_rate = dynamic.and_then(|d| d.reference_rate_rad_s.as_ref()).is_some();
    let gauge = Gauge::new(array, with_dynamic, reference_rate);
    let dim = PER_ACCEL * n + 2 * poses;
    let active: Vec<bool> = (0..dim).map(|i| with_dynamic || i >= PER_ACCEL * n || i % PER_ACCEL < 4).collect();
    let stat = StaticData { means: DMatrix::zeros(poses, n), counts: counts.to_vec(), sigma: sigma.to_vec() };
    let weights = Weights {
        static_w: DMatrix::from_fn(poses, n, |p, j| counts[p] as f64 / sigma[j].powi(2)),
        dynamic_w: sigma.iter().map(|s| 1.0 / (s * s)).collect(),
        dynamic_output_w: None,
    };
    let state = State { params: params.clone(), up: up.to_vec(), motion: motion.to_vec() };
    let settings = FitSettings { gravity_m_s2, ..FitSettings::default() };
    let normal = normal_equations(array, &stat, dynamic.filter(|_| with_dynamic), &settings, &weights, &state, &active);
    let (null, _) = count_null(&normal.h, &active);
    let constraints = gauge.constraints(array, with_dynamic, 2 * poses);
    (null, gauge, unseen(&normal.h, &constraints, &active))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// White noise of one variance, left by least squares with `k` unknowns a sample among `m`
    /// outputs, has residual RMS `sigma sqrt((m - k) / m)` on every accelerometer: the pooled
    /// variance is `sigma^2`, whatever the counts. With unequal noise it is their mean variance
    /// (equal counts), and with an accelerometer left out of every sample (NaN residual) the rest.
    #[test]
    fn the_pooled_dynamic_variance_of_white_residuals_is_the_noise_variance() {
        let (samples, n) = (400, 24);
        let mut d = DynamicData {
            t_s: (0..samples).map(|i| i as f64 * 0.016).collect(),
            outputs: DMatrix::zeros(samples, n),
            used: vec![true; samples * n],
            run_starts: vec![0],
            reference_rate_rad_s: None,
            extra_unknowns_per_sample: 6,
        };
        let local = misfit::local_unknowns(&d);
        assert_eq!(local, 15.0);
        let kept = ((n as f64 - local) / n as f64).sqrt();
        let counts = vec![samples; n];
        let rms = vec![0.3 * kept; n];
        let v = pooled_dynamic_variance(&d, &rms, &counts, local).expect("formed");
        assert!((v - 0.09).abs() < 1e-12 * 0.09, "{v}");
        let sigma: Vec<f64> = (0..n).map(|j| 0.1 + 0.02 * j as f64).collect();
        let rms: Vec<f64> = sigma.iter().map(|s| s * kept).collect();
        let mean = sigma.iter().map(|s| s * s).sum::<f64>() / n as f64;
        let v = pooled_dynamic_variance(&d, &rms, &counts, local).expect("formed");
        assert!((v - mean).abs() < 1e-12 * mean, "{v} against {mean}");
        // Accelerometer 0 never used: 23 outputs a sample, `k` unknowns among them.
        for i in 0..samples {
            d.used[i * n] = false;
        }
        let kept23 = ((23.0 - local) / 23.0).sqrt();
        let mut rms: Vec<f64> = vec![0.3 * kept23; n];
        rms[0] = f64::NAN;
        let mut counts = counts;
        counts[0] = 0;
        let v = pooled_dynamic_variance(&d, &rms, &counts, local).expect("formed");
        assert!((v - 0.09).abs() < 1e-12 * 0.09, "{v}");
    }
}
