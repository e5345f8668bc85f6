//! The packages' sample clocks fitted with a calibration: the outer iterations of `gfcal
//! calibrate` where the array file declares free-running sample clocks (`array::wiring`).
//!
//! Started from the sawtooth of the gyroscopes' time offsets, the outputs are corrected to the
//! packages' mean instant and the calibration refitted (`selfcal::fit`), then the clocks refined
//! on the accelerometers' residuals (`selfcal::timing`), until the rotation phase's residual
//! settles; then with Huber's weights (`selfcal::huber`). Also what the fitted clocks give the
//! rest of the calibration: the corrected rotation phase and the rate on the path over its
//! branches (`selfcal::branch`).

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::DMatrix;

use super::branch;
use super::clock::{SampleClock, fit_packages, half_differences};
use super::data::{DynamicData, StaticData};
use super::filter::{accelerometer_time_constants, filter_corrected};
use super::fit::{Fit, FitError, FitSettings, check_solution, fit_from, pooled_dynamic_variance};
use super::huber::{self, HuberSummary};
use super::misfit;
use super::model::{PER_ACCEL, SampleMotion, Sensor, sensors};
use super::recording::Recording;
use super::robust::robust_covariance_with_bread;
use super::segment::Segmentation;
use super::timing::{
    ClockEstimate, ClockProblem, SigmaCheck, TIMING_UNKNOWNS_PER_SAMPLE, accelerometer_ages, gyro_offsets, host_dt_s,
    sawtooth_periods,
};
use crate::array::wiring::RecordingArray;

/// A calibration's dynamic data with the outputs corrected to the packages' mean instant by its
/// clocks and timing motion (what the fit with clocks was fitted to), and by the anti-alias
/// filters' term where the array file declares filters (`selfcal::filter`).
pub fn corrected_dynamic(array: &RecordingArray, fit: &Fit, d: &DynamicData, clocks: &ClockEstimate) -> DynamicData {
    corrected_dynamic_and_rates(array, fit, d, clocks).0
}

/// [`corrected_dynamic`], and each dynamic output's rate of change that its age multiplies in the
/// correction (samples x accelerometers, m/s^3, `ClockProblem::output_rates_m_s3`): what a clock
/// parameter's column is made of.
pub fn corrected_dynamic_and_rates(
    array: &RecordingArray,
    fit: &Fit,
    d: &DynamicData,
    clocks: &ClockEstimate,
) -> (DynamicData, DMatrix<f64>) {
    let (package_of, sens, weights) = timing_inputs(array, fit);
    let problem = ClockProblem::new(&sens, d, &fit.motion, &weights, &package_of);
    let rates = problem.output_rates_m_s3(&clocks.timing);
    let outputs = problem.corrected_at_rates(&d.outputs, &clocks.clocks, &rates, clocks.timing.len());
    let corrected = DynamicData {
        outputs: with_filters(array, fit, outputs),
        extra_unknowns_per_sample: TIMING_UNKNOWNS_PER_SAMPLE,
        ..d.clone()
    };
    (corrected, rates)
}

/// What a clock problem at `fit` reads: each accelerometer's package, the sensors, and the
/// outputs' inverse variances in the rotation phase.
fn timing_inputs(array: &RecordingArray, fit: &Fit) -> (Vec<usize>, Vec<Sensor>, Vec<f64>) {
    let package_of = array.package_indices();
    let weights = fit.dynamic_weights();
    (package_of, sensors(&array.array, &fit.params), weights)
}

/// A clocked calibration's motion with every sample's rate on the path over its branches
/// (`selfcal::branch`), `d` the rotation phase as read.
pub(super) fn rates_on_path(
    array: &RecordingArray,
    fit: &Fit,
    d: &DynamicData,
    clocks: &ClockEstimate,
) -> Option<Vec<SampleMotion>> {
    let (package_of, sens, weights) = timing_inputs(array, fit);
    let fitted = corrected_dynamic(array, fit, d, clocks);
    branch::on_path(&sens, d, &fitted, &fit.motion, &weights, &package_of, &clocks.clocks)
}

/// `outputs` less the anti-alias filters' term at `fit` (unchanged where no filter is declared).
pub(super) fn with_filters(array: &RecordingArray, fit: &Fit, outputs: DMatrix<f64>) -> DMatrix<f64> {
    match accelerometer_time_constants(array) {
        Some(tau) => filter_corrected(&outputs, &sensors(&array.array, &fit.params), &fit.motion, &tau),
        None => outputs,
    }
}

/// Why the clocks were not fitted.
pub(super) enum ClockFailure {
    /// The recording cannot resolve them (said in the calibration's note).
    NotResolved(String),
    Fit(FitError),
}

/// The packages' clocks fitted with the calibration (module docs); `fit0` is the fit without them.
/// `robust`: once the least-squares iterations settle, go on with Huber's weights
/// (`selfcal::huber`).
#[allow(clippy::too_many_arguments)]
pub(super) fn estimate_clocks(
    rec: &Recording,
    array: &RecordingArray,
    seg: &Segmentation,
    stat: &StaticData,
    d: &DynamicData,
    settings: &FitSettings,
    fit0: &Fit,
    robust: bool,
) -> Result<(Fit, ClockEstimate), ClockFailure> {
    let not = |why: String| ClockFailure::NotResolved(why);
    let dt = host_dt_s(&rec.t_s).ok_or_else(|| not("the recording has no time step".into()))?;
    let package_of = array.package_indices();
    let span_s = d.t_s.last().copied().unwrap_or(0.0) - d.t_s.first().copied().unwrap_or(0.0);
    let t_ref_s = d.t_s.first().copied().unwrap_or(0.0) + 0.5 * span_s;
    // The sawtooth's step a host sample is at most R eps_max periods; a clock whose beat the
    // rotation phase cannot hold a few times over is not resolved.
    if span_s < 10.0 || d.samples() < 200 {
        return Err(not(format!(
            "the rotation phase ({span_s:.1} s, {} samples) is too short to resolve the packages' sample clocks (at least 10 s and 200 samples)",
            d.samples()
        )));
    }
    let dynamic_rows: Vec<usize> = seg.dynamic_intervals.iter().flat_map(|iv| iv.start..iv.end).collect();
    let static_rows: Vec<usize> = seg.static_intervals.iter().flat_map(|iv| iv.start..iv.end).collect();
    let offsets = gyro_offsets(rec, &dynamic_rows, &static_rows).ok_or_else(|| {
        not("the clocks are started from the packages' own gyroscopes, and this recording or array file has no gyroscope in every package (the accelerometers alone do not tell a fast clock from a slow one)".into())
    })?;
    let nominal: Vec<f64> = array.packages.iter().map(|p| p.sample_clock_hz.unwrap_or(1.0 / dt)).collect();
    let gyro = fit_packages(&offsets, &nominal, dt, t_ref_s, 5e-3)
        .ok_or_else(|| not("too few samples with angular acceleration to measure the gyroscopes' offsets".into()))?;
    // The gyroscopes must show the sawtooth on every clocked package
    // (`clock::OffsetFit::shows_sawtooth`), else this recording does not resolve the clocks (or the
    // board has no such effect) and the fit goes without them. Not on a package whose clock runs
    // so near a whole multiple of the host's rate that its sawtooth does not complete a period in
    // the rotation phase: its age is a ramp without a wrap, whose scale the offsets cannot
    // measure (`clock::fit_packages` holds it at the others'); it is refined alone below. At
    // least one package must show the sawtooth.
    let slow = |p: usize| sawtooth_periods(&gyro[p].clock, &d.t_s, dt) < 1.0;
    if !(0..gyro.len()).any(|p| array.packages[p].free_running() && !slow(p)) {
        return Err(not(
            "no package's sawtooth completes a period in the rotation phase: the clocks are not resolved".into()
        ));
    }
    if let Some((p, g)) =
        gyro.iter().enumerate().find(|&(p, g)| array.packages[p].free_running() && !slow(p) && !g.shows_sawtooth())
    {
        return Err(not(format!(
            "package {} ({}): its gyroscope's time offsets show no sawtooth of its clock (scale on the fitted ages {:.3} +- {:.3}; a clock read by sample-and-hold gives about 1)",
            p + 1,
            array.packages[p].name,
            g.amplitude,
            g.amplitude_sigma
        )));
    }
    let start: Vec<Option<SampleClock>> =
        array.packages.iter().zip(&gyro).map(|(p, g)| p.free_running().then_some(g.clock)).collect();
    // The common part (the gauge of the accelerometers' model) stays where the gyroscopes put it;
    // its sigma: the halves' spread of the gyroscopes' clocks, over the root of the packages (the
    // common part is their mean).
    let halves = half_differences(&offsets, &gyro, t_ref_s);
    let clocked: Vec<usize> = (0..start.len()).filter(|&p| start[p].is_some()).collect();
    let common_sigma = [0, 1, 2].map(|a| {
        let ms = clocked.iter().map(|&p| (0.5 * halves[p][a]).powi(2)).sum::<f64>() / clocked.len().max(1) as f64;
        (ms / clocked.len().max(1) as f64).sqrt()
    });
    // A floor under the relative part's sigmas: the gyroscopes' halves' spread per package (the
    // accelerometers refine the clocks, but their linearised sigmas rest on white residuals,
    // and the misfit is V-shaped at the wraps).
    let gyro_relative_sigma = [0, 1, 2].map(|a| {
        let ms = clocked.iter().map(|&p| (0.5 * halves[p][a]).powi(2)).sum::<f64>() / clocked.len().max(1) as f64;
        ms.sqrt()
    });
    let mut clocks = start.clone();
    let mut fit = fit0.clone();
    let before = dynamic_rms(fit0);
    let all = 0..d.samples();
    let problem_at = |fit: &Fit, d: &DynamicData| {
        let sens = sensors(&array.array, &fit.params);
        let weights = fit.dynamic_weights();
        ClockProblem::new(&sens, d, &fit.motion, &weights, &package_of)
    };
    // A package whose sawtooth does not complete a period in the rotation phase keeps the
    // gyroscopes' start under the joint steps (blocked by the other packages' wraps; the
    // gyroscopes' own fit, whose sawtooth scale is free, trades that package's rate with its drift
    // along the one ramp): it is refined alone after them, its misfit smooth with the others held.
    let refine_alone = |problem: &ClockProblem, mut clocks: Vec<Option<SampleClock>>| {
        for p in 0..clocks.len() {
            if clocks[p].is_some_and(|c| sawtooth_periods(&c, &d.t_s, dt) < 1.0) {
                clocks = problem.package_steps(&clocks, all.clone(), p, 8).0;
            }
        }
        clocks
    };
    let mut fitted_to: DynamicData;
    // What the iterations fit: the outputs as measured, then (`robust`) Huber's
    // pseudo-observations `d + shift`; `fitted_shift` is the shift `fitted_to` carries.
    let mut data = d.clone();
    let mut shift = DMatrix::zeros(d.samples(), d.outputs.ncols());
    let mut fitted_shift = shift.clone();
    let mut huber: Option<HuberSummary> = None;
    let mut previous_params = fit0.params.clone();
    let mut held_variance: Option<f64> = None;
    // The sigmas that scale Huber's stopping rule (the refit's where they start), per
    // accelerometer parameter.
    let mut stop_sigma: Vec<f64> = Vec::new();
    // The outer iterations run until the rotation phase's residual settles (a relative change
    // under OUTER_TOLERANCE), at most MAX_OUTER_ITERATIONS. With the dynamic variance pooled
    // (`selfcal::fit`) each one lowers the misfit; with a component per accelerometer they ran
    // away, which is why this once stopped at two. If `robust`, Huber's iterations start once an
    // iteration changes the residual by under HUBER_START_TOLERANCE, and run until no parameter
    // moves by HUBER_TOLERANCE_SIGMA of its sigma (at most MAX_HUBER_ITERATIONS).
    // The settings of the outer iterations' refits: the rate's sigmas, the unseen check and the
    // solution's check left to the end, the dynamic variance as held (Huber's) or refitted.
    let refit_settings = |held_dynamic_variance_m2_s4: Option<f64>, max_iterations: usize| FitSettings {
        rate_sigmas: false,
        held_dynamic_variance_m2_s4,
        trust_start_unseen: true,
        solution_check: false,
        max_iterations,
        ..*settings
    };
    let mut iterations = 0;
    let mut previous_rms = before;
    loop {
        iterations += 1;
        let problem = problem_at(&fit, &data);
        // Huber's iterations hold the clocks where least squares put them: their information
        // lies in the violent samples the clip takes; stepping them on the clipped outputs left
        // their errors as they were (simulated, 6 seeds) and took a tenth more time.
        if huber.is_none() {
            clocks = problem.relative_steps(&clocks, all.clone(), 3).0;
            clocks = refine_alone(&problem, clocks);
        }
        let timing = problem.timing(&clocks);
        let corrected = DynamicData {
            outputs: with_filters(array, &fit, problem.corrected(&data.outputs, &clocks, &timing)),
            extra_unknowns_per_sample: TIMING_UNKNOWNS_PER_SAMPLE,
            ..d.clone()
        };
        // Huber's refits take HUBER_REFIT_ITERATIONS Gauss-Newton iterations a round: their
        // loop is what converges (the last refit is run to its end after it).
        let max_iterations = match huber {
            Some(_) => HUBER_REFIT_ITERATIONS.min(settings.max_iterations),
            None => settings.max_iterations,
        };
        let refit = refit_settings(held_variance, max_iterations);
        fit = fit_from(&array.array, stat, Some(&corrected), &refit, Some(&fit)).map_err(ClockFailure::Fit)?;
        fitted_to = corrected;
        fitted_shift.clone_from(&shift);
        let rms = dynamic_rms(&fit);
        // The outer iterations are a descent from the fit without the clocks: a refit that leaves
        // the misfit above where it started has left the clocks (a flat subset of a board, whose
        // rate is not resolved, ran from 0.8 to 33 m/s^2 on its first and to 1e28 on its ninth,
        // 57 s in all), and the final check would refuse it anyway.
        if !(rms <= before) {
            return Err(not(worse_with_clocks(before, rms, &format!(" at its refit {iterations}"))));
        }
        let change = (previous_rms - rms).abs() / previous_rms;
        previous_rms = rms;
        if !robust {
            if change <= OUTER_TOLERANCE || iterations >= MAX_OUTER_ITERATIONS {
                break;
            }
            continue;
        }
        if huber.is_none() && change > HUBER_START_TOLERANCE && iterations < MAX_OUTER_ITERATIONS {
            continue;
        }
        // Huber's iterations stop when no parameter moved by HUBER_TOLERANCE_SIGMA of its
        // sigma (the refit's own where they start: the refits leave the covariance out) over the
        // last one.
        if stop_sigma.is_empty() {
            check_solution(&array.array, stat, Some(&fitted_to), settings, &mut fit).map_err(ClockFailure::Fit)?;
            stop_sigma = (0..array.array.len())
                .flat_map(|j| (0..PER_ACCEL).map(move |p| (j, p)))
                .map(|(j, p)| fit.sigma(j, p))
                .collect();
        }
        let moved_sigma = (0..array.array.len())
            .flat_map(|j| (0..PER_ACCEL).map(move |p| (j, p)))
            .map(|(j, p)| (fit.params.get(j, p) - previous_params.get(j, p)).abs() / stop_sigma[PER_ACCEL * j + p])
            .filter(|v| v.is_finite())
            .fold(0.0_f64, f64::max);
        previous_params.clone_from(&fit.params);
        if let Some(h) = &huber
            && (moved_sigma <= HUBER_TOLERANCE_SIGMA || h.iterations >= MAX_HUBER_ITERATIONS)
        {
            break;
        }
        // Huber's update: the residuals of the outputs as measured (the fitted pseudo-observations
        // less their shift), their robust scale, the new shift.
        let residual = misfit::residuals(&array.array, &fit.params, &fitted_to, &fit.motion) - &fitted_shift;
        let scale = huber::robust_scale(&residual, &d.used);
        let clip = huber::CLIP_SCALES * scale;
        shift = huber::shift(&residual, &d.used, clip);
        // The pseudo-observations are weighted with the variance of the outputs as measured.
        let measured = DynamicData { outputs: &fitted_to.outputs - &fitted_shift, ..fitted_to.clone() };
        let (rms_measured, counts) = misfit::residual_rms(&array.array, &fit.params, &measured, &fit.motion);
        held_variance = pooled_dynamic_variance(&measured, &rms_measured, &counts, misfit::local_unknowns(&measured));
        data.outputs = &d.outputs + &shift;
        let h = huber.get_or_insert(HuberSummary {
            clip_m_s2: clip,
            robust_scale_m_s2: scale,
            clipped_share: 0.0,
            iterations: 0,
        });
        h.iterations += 1;
        h.clip_m_s2 = clip;
        h.robust_scale_m_s2 = scale;
        h.clipped_share = huber::clipped_share(&residual, &d.used, clip);
    }
    // Huber's last refit run to its end (its weights, shift and clocks as they were), so that
    // the fit's convergence is its own.
    if huber.is_some() {
        let last = refit_settings(held_variance, settings.max_iterations);
        fit = fit_from(&array.array, stat, Some(&fitted_to), &last, Some(&fit)).map_err(ClockFailure::Fit)?;
    }
    // The refits left their solution's check out (`FitSettings::solution_check`).
    check_solution(&array.array, stat, Some(&fitted_to), settings, &mut fit).map_err(ClockFailure::Fit)?;
    // The residual as measured, for every figure reported (the pseudo-observations' residual is
    // what the weights made of it).
    let measured = DynamicData { outputs: &fitted_to.outputs - &fitted_shift, ..fitted_to.clone() };
    let (rms, _) = misfit::residual_rms(&array.array, &fit.params, &measured, &fit.motion);
    fit.dynamic_chi2_dof = misfit::chi2_dof(&measured, &rms, &stat.sigma);
    fit.dynamic_residual_rms_m_s2 = rms;
    // The parameters' covariance from the scores' spread over blocks of samples: the residual
    // the clock model leaves is not white (selfcal::robust). With Huber's weights the bread
    // weighs each output by the chance that its residual falls within the clip under its
    // accelerometer's noise (`selfcal::huber`). The rate's sigmas follow it.
    let bread = huber.as_ref().map(|h| {
        let residual = misfit::residuals(&array.array, &fit.params, &measured, &fit.motion);
        huber::expected_derivative(&residual, &fitted_to.used, h.clip_m_s2, &stat.sigma)
    });
    // Each sample's timing motion eliminated too (`selfcal::timing_information`): at the clocks
    // the outputs were corrected with.
    let ages = accelerometer_ages(&fitted_to, &clocks, &package_of);
    fit.covariance =
        robust_covariance_with_bread(&array.array, stat, &fitted_to, bread.as_deref(), Some(&ages), settings, &fit)
            .map_err(ClockFailure::Fit)?;
    fit.omega_sigma_rad_s = crate::selfcal::track::rate_sigmas(
        &array.array,
        &fitted_to,
        &fit.dynamic_weights(),
        &fit.params,
        &fit.motion,
        fitted_to.reference_rate_rad_s.is_some(),
        &fit.covariance,
    );
    // The relative part's sigmas: the linearised normal matrix at the final parameters, checked
    // on the two halves of the rotation phase: the RMS of their relative rate offsets' difference
    // over its sigma (the Birge ratio) inflates every sigma where it exceeds 1.
    let problem = problem_at(&fit, d);
    clocks = problem.relative_steps(&clocks, all.clone(), 1).0;
    clocks = refine_alone(&problem, clocks);
    let normal = problem.relative_information(&clocks, all.clone());
    let timing = problem.timing(&clocks);
    let split = d.t_s.partition_point(|&t| t < t_ref_s);
    // Each half's optimum as linearised at the final clocks. A half fitted by steps that must
    // lower its misfit barely moves (the misfit is V-shaped at the wraps), which made the check
    // vacuous (Birge ratios 0.02-0.09 on simulated recordings, `docs/sample-clocks.md`); the
    // linearised optimum is where the smooth part of the half's misfit puts its clocks, and the
    // two halves' difference has the covariance of their linearisations summed.
    let (c1, n1) = problem.linearised_optimum(&clocks, 0..split);
    let (c2, n2) = problem.linearised_optimum(&clocks, split..d.samples());
    let relative_rate = |c: &[Option<SampleClock>]| -> Vec<f64> {
        let mean = clocked.iter().filter_map(|&p| c[p].map(|c| c.rate_offset)).sum::<f64>() / clocked.len() as f64;
        clocked.iter().map(|&p| c[p].map_or(0.0, |c| c.rate_offset) - mean).collect()
    };
    let relative_cov = |n: &DMatrix<f64>| -> DMatrix<f64> { crate::stats::symmetric_pinv(n, 1e-12).0 };
    let (cov, cov1, cov2) = (relative_cov(&normal), relative_cov(&n1), relative_cov(&n2));
    let (r1, r2) = (relative_rate(&c1), relative_rate(&c2));
    let k = clocked.len();
    let mut z2 = 0.0;
    let mut d2 = 0.0;
    let mut formed = k > 0;
    for c in 0..k {
        let diff = r1[c] - r2[c];
        let var = cov1[(3 * c, 3 * c)].max(0.0) + cov2[(3 * c, 3 * c)].max(0.0);
        formed &= var > 0.0;
        z2 += diff * diff / var;
        d2 += diff * diff;
    }
    // No ratio (NaN, null in the JSON) where it cannot be formed (no clocked package, or a half
    // that does not fix a package's rate): the sigmas then rest on the linearisation and the
    // gyroscopes' floor alone.
    let birge_ratio = (z2 / k.max(1) as f64).sqrt();
    let birge_ratio = if formed && birge_ratio.is_finite() { birge_ratio } else { f64::NAN };
    let inflation = if birge_ratio.is_finite() { birge_ratio.max(1.0) } else { 1.0 };
    let sigma_check = SigmaCheck { birge_ratio, inflation, half_difference_rms: (d2 / k.max(1) as f64).sqrt() };
    let mut c = 0;
    let sigma = clocks
        .iter()
        .map(|cl| {
            cl.map(|_| {
                let s = [0, 1, 2].map(|a| {
                    let linear = cov[(3 * c + a, 3 * c + a)].max(0.0).sqrt() * inflation;
                    linear.max(gyro_relative_sigma[a]).hypot(common_sigma[a])
                });
                c += 1;
                s
            })
        })
        .collect();
    let after = dynamic_rms(&fit);
    if !(after <= before) {
        // A timing model that makes the misfit worse did not converge to the clocks (a subset of
        // a board, say, whose calibration is not identifiable): it is left out, saying so.
        return Err(not(worse_with_clocks(before, after, "")));
    }
    // The null: the same clocks read later by 1/100 ... 99/100 of the rotation phase (ages with
    // the clocks' statistics, decorrelated from the samples).
    let shifts: Vec<f64> = (1..=NULL_SHIFTS).map(|k| span_s * k as f64 / (NULL_SHIFTS + 1) as f64).collect();
    let (share_removed, null_shares_removed) = problem.shares_removed(&clocks, &shifts);
    let estimate = ClockEstimate {
        share_removed,
        null_shares_removed,
        clocks,
        sigma,
        common_sigma,
        sigma_check,
        timing,
        start: "the sawtooth of the packages' own gyroscopes' time offsets",
        gyroscope_clocks: Some(start),
        residual_rms_before_m_s2: before,
        residual_rms_after_m_s2: after,
        iterations,
        huber,
    };
    Ok((fit, estimate))
}

/// Gauss-Newton iterations a round of the fit without the clocks, where that fit only starts the
/// clocks' refits ([`calibrate`](super::calibrate::calibrate)).
pub const CLOCKED_START_ITERATIONS: usize = 3;

/// Gauss-Newton iterations a round of each of Huber's refits. Huber's iterations are what
/// converges; a refit's second Gauss-Newton iteration only confirmed its first (real recordings
/// 1, 4 and 6: every parameter within 0.02 sigma of refits run to their end, in about 0.94 of the
/// time, `docs/performance.md`). The last refit is run to its end. The least-squares outer
/// iterations keep their refits whole: the clocks are stepped from them, and capped there the
/// clocks moved by a hundredth of their sigma on a simulated recording.
pub const HUBER_REFIT_ITERATIONS: usize = 1;

/// The most outer iterations (clocks, then the calibration refitted) the clocks' estimate runs.
pub const MAX_OUTER_ITERATIONS: usize = 8;

/// The most outer iterations with Huber's weights, after the least-squares ones.
pub const MAX_HUBER_ITERATIONS: usize = 12;

/// Huber's iterations stop when no parameter moves by more than this share of its sigma (the
/// refit's own, below the robust one).
pub const HUBER_TOLERANCE_SIGMA: f64 = 0.05;

/// Huber's iterations start once an outer iteration changes the residual RMS by less than this
/// share of itself (or at MAX_OUTER_ITERATIONS).
pub const HUBER_START_TOLERANCE: f64 = 0.05;

/// The outer iterations stop when the rotation phase's residual RMS changes by less than this
/// share of itself.
pub const OUTER_TOLERANCE: f64 = 0.01;

/// The number of time shifts of the clocks' null: the fitted clocks' share ranks among them
/// with a p-value down to `1 / (NULL_SHIFTS + 1)` = 0.01.
pub const NULL_SHIFTS: usize = 99;

/// Why a clock model is not used that leaves the rotation phase's misfit at `after` (m/s^2 RMS),
/// not below `before` (without it); `when` says at which refit, or nothing for the final fit.
fn worse_with_clocks(before: f64, after: f64, when: &str) -> String {
    format!(
        "the clock model made the rotation phase's misfit worse ({before:.3} -> {after:.3} m/s^2 RMS{when}), so it is not used"
    )
}

/// The RMS over accelerometers of a fit's dynamic residual RMS.
fn dynamic_rms(fit: &Fit) -> f64 {
    let v: Vec<f64> = fit.dynamic_residual_rms_m_s2.iter().copied().filter(|v| v.is_finite()).collect();
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}
