//! `gfcal calibrate`: a recording in, every parameter with its sigma out.
//!
//! Segments the recording, forms the static means and the dynamic samples, fits
//! (`selfcal::fit`), and checks the gyroscope-free angular rate against the reference gyroscopes.
//! Where the array file declares free-running sample clocks (`array::wiring`), the packages'
//! clocks are fitted with the other parameters (`selfcal::timing`): started from the sawtooth of
//! the gyroscopes' time offsets, then the outputs corrected to the mean instant and refitted,
//! the clocks refined on the accelerometers' residuals, three times over.

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::{DMatrix, Vector3};

use super::branch;
use super::clock::{SampleClock, fit_packages, half_differences};
use super::data::{DynamicData, StaticData};
use super::filter::{accelerometer_time_constants, filter_corrected};
use super::fit::{Fit, FitError, FitSettings, check_solution, fit, fit_from, pooled_dynamic_variance};
use super::huber::{self, HuberSummary};
use super::lag::{LaggedGyroscopes, rates_behind};
use super::misfit;
use super::model::{PER_ACCEL, SampleMotion, Sensor, sensors};
use super::recording::Recording;
use super::robust::robust_covariance_with_bread;
use super::segment::{DetectorSettings, Interval, Segmentation, segment};
use super::static_drift::{StaticDrift, static_drift_at, static_times};
use super::tension::{StaticTension, tension_at};
use super::timing::{
    ClockEstimate, ClockProblem, SigmaCheck, TIMING_UNKNOWNS_PER_SAMPLE, accelerometer_ages, gyro_offsets, host_dt_s,
    sawtooth_periods,
};
use crate::array::wiring::RecordingArray;

/// Settings of a calibration.
#[derive(Debug, Clone, Copy, Default)]
pub struct CalibrateSettings {
    pub detector: DetectorSettings,
    pub fit: FitSettings,
    /// Take the angular rate from the reference gyroscopes (the published method) instead of
    /// estimating it from the accelerometers.
    pub use_gyro: bool,
    /// Fit a clocked rotation phase by least squares alone, without Huber's weights on the
    /// heavy tail the clocks leave (`selfcal::huber`; for comparison: the default has them).
    pub plain_least_squares: bool,
    /// Take a bias drift in time out of the recording before calibrating it: each
    /// accelerometer's drift found by `selfcal::static_drift` on a fit of the static phase alone,
    /// removed from every output, `s -= k d (t - t_mid)` ([`without_bias_drift`]), and the
    /// variance its uncertainty adds in the static phase ([`StaticDrift::added_variance`]) added
    /// to each scale factor's, bias's and tilt's (the covariance's diagonal). Needs the
    /// static poses a calibration without a rotation phase needs; with fewer the recording is
    /// calibrated as it is, and [`Calibration::bias_drift_note`] says why.
    pub remove_bias_drift: bool,
}

/// Why a calibration cannot be done.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CalibrateError {
    #[error("{}: {problem}", path.display())]
    Recording { path: std::path::PathBuf, problem: String },
    #[error("{}: {source}", path.display())]
    Fit { path: std::path::PathBuf, source: FitError },
    /// A recording that cannot be read or predicted (its message names it).
    #[error(transparent)]
    Read(#[from] super::recording::RecordingError),
}

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
    /// The rate the fit took as known at every dynamic sample (with `use_gyro`): the
    /// gyroscopes' less their bias, read at the accelerometers' instants where the array file
    /// declares a lag (`selfcal::lag`).
    pub reference_rate_rad_s: Option<Vec<Vector3<f64>>>,
    /// The packages' sample clocks, where the array file declares them and the recording
    /// resolves them.
    pub clocks: Option<ClockEstimate>,
    /// Why declared clocks were not fitted (the fit is then without them).
    pub clock_note: Option<String>,
    /// Gyroscope-free with the clocks: every dynamic sample's motion with its rate on the path
    /// over its branches (`selfcal::branch`: the sign and the thin plane's reflection), the rate
    /// that [`Calibration::rate_motion`] gives and `gyro_check` checks. `fit.motion` stays the
    /// branch the fit was fitted and its outputs corrected with. `None` otherwise.
    pub motion_on_path: Option<Vec<SampleMotion>>,
    /// What would make the parameters the recording cannot identify identifiable, in words
    /// (`selfcal::geometry::remedies`); empty when every parameter is identified.
    pub to_identify: Vec<String>,
    /// The static phase refitted alone against the joint fit (`selfcal::tension`), where a
    /// rotation phase was fitted with the static one.
    pub static_tension: Option<StaticTension>,
    /// The static phase refitted with a bias drift in time (`selfcal::static_drift`), where the
    /// static phase has enough poses for it.
    pub static_drift: Option<StaticDrift>,
    /// The bias drift taken out of the recording before this calibration
    /// ([`CalibrateSettings::remove_bias_drift`]): the check on the static phase alone.
    pub removed_bias_drift: Option<StaticDrift>,
    /// Why a drift asked to be removed was not.
    pub bias_drift_note: Option<String>,
}

impl Calibration {
    /// Every dynamic sample's motion with the rate as calibrate reports it: on the path over its
    /// branches where there is one ([`Calibration::motion_on_path`]), else the fit's.
    pub fn rate_motion(&self) -> &[SampleMotion] {
        self.motion_on_path.as_deref().unwrap_or(&self.fit.motion)
    }

    /// How many dynamic samples the path put on another branch than the fit's: their rate moved
    /// by more than 3 times the norm of the fitted rate's sigma (a reflection re-solved can come
    /// back to the fitted basin, a few bits away). `None` without a path.
    pub fn samples_on_another_branch(&self) -> Option<usize> {
        let path = self.motion_on_path.as_ref()?;
        let sigma = &self.fit.omega_sigma_rad_s;
        Some(
            path.iter()
                .zip(&self.fit.motion)
                .enumerate()
                .filter(|(k, (a, b))| {
                    let limit = sigma.get(*k).map_or(0.0, |s| 3.0 * s.norm());
                    (a.omega_rad_s - b.omega_rad_s).norm() > limit
                })
                .count(),
        )
    }
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
    if settings.remove_bias_drift {
        let inner = CalibrateSettings { remove_bias_drift: false, ..*settings };
        let (corrected, drift) = bias_drift_taken_out(rec, array, &inner)?;
        let mut cal = calibrate(&corrected, array, &inner)?;
        with_removed_drift(&mut cal, drift);
        return Ok(cal);
    }
    let seg = segment(rec, &settings.detector).map_err(|e| bad(e.to_string()))?;
    let stat = static_data(rec, &seg.static_intervals)
        .map_err(|problem| bad(format!("{problem} (array file {})", array.path.display())))?;
    let gyro_bias_rad_s = gyro_bias(rec, &seg);
    let prepared = prepare_dynamic(rec, &seg, settings.use_gyro, gyro_bias_rad_s);
    let dynamic = prepared.data.as_ref();
    // An array whose packages declare sample clocks pools the dynamic variance in every fit, the
    // clocks' start included: per-accelerometer components there weigh each accelerometer by how
    // hard the unmodelled timing hits it, and the clocks' first linearisation inherits that
    // weighting (real recording 4: a residual of 0.373 m/s^2 at convergence from it, 0.333 from a
    // pooled start; `docs/sample-clocks.md`).
    let fit_settings = FitSettings { pooled_dynamic_variance: array.has_sample_clocks(), ..settings.fit };
    let settings = &CalibrateSettings { fit: fit_settings, ..*settings };
    let (mut fit, mut clocks, mut clock_note) = fit_phases(rec, array, &seg, &stat, dynamic, settings)?;
    // With the accelerometers lagging the gyroscopes, the rate the fit took (the gyroscopes
    // interpolated, `selfcal::lag`) is refined to first order from the fitted angular
    // acceleration, and the recording fitted again with it. One pass does: another moves real
    // recording 1's rotation-phase chi^2/dof by 0.3% (156.07 -> 155.57), a third by 0.004%.
    let mut reference_rate_rad_s = dynamic.and_then(|d| d.reference_rate_rad_s.clone());
    if let (Some(d), Some(b)) = (dynamic, gyro_bias_rad_s)
        && settings.use_gyro
        && rec.accelerometer_lag_s != 0.0
        && fit.motion.len() == prepared.index.len()
    {
        let behind = DynamicData {
            reference_rate_rad_s: Some(rates_behind(rec, &prepared.index, &b, &fit.motion)),
            ..d.clone()
        };
        let refit = fit_phases(rec, array, &seg, &stat, Some(&behind), settings)?;
        // Kept where it fits the rotation phase better: a first fit whose angular acceleration
        // is poor (a flat subset of the board, parameters it cannot see) makes poorer rates.
        if refit.0.dynamic_chi2_dof < fit.dynamic_chi2_dof {
            (fit, clocks, clock_note) = refit;
            reference_rate_rad_s = behind.reference_rate_rad_s;
        }
    }
    // Gyroscope-free with the clocks: each sample's rate on the path over its branches (its sign
    // and the thin plane's reflection, `selfcal::branch`); the fit stays as it is.
    let motion_on_path = match (dynamic, clocks.as_ref()) {
        (Some(d), Some(c)) if !settings.use_gyro => rates_on_path(array, &fit, d, c),
        _ => None,
    };
    let rate_motion = motion_on_path.as_deref().unwrap_or(&fit.motion);
    let gyro_check = match (gyro_bias_rad_s, settings.use_gyro, rate_motion.is_empty()) {
        (Some(b), false, false) => Some(gyro_check(rec, &prepared.index, rate_motion, &b)),
        _ => None,
    };
    let unidentified = fit.unseen_parameters.iter().any(|&u| u);
    let to_identify = if unidentified || !fit.locations_identified {
        crate::selfcal::geometry::remedies(
            &array.array,
            array.gyroscopes.len(),
            settings.use_gyro,
            fit.locations_identified,
            fit.unseen.len(),
        )
    } else {
        Vec::new()
    };
    let static_tension = dynamic.map(|_| {
        tension_at(&array.array, &stat, &fit.params, &fit.up, &|j, p| fit.sigma(j, p), settings.fit.gravity_m_s2)
    });
    let (static_t_s, t_mid_s) = static_times(&rec.t_s, &seg.static_intervals);
    let static_drift =
        static_drift_at(&array.array, &stat, &fit.params, &fit.up, &static_t_s, t_mid_s, settings.fit.gravity_m_s2);
    Ok(Calibration {
        static_tension,
        static_drift,
        removed_bias_drift: None,
        bias_drift_note: None,
        segmentation: seg,
        fit,
        static_data: stat,
        dynamic_index: prepared.index.clone(),
        clipped_outputs: prepared.clipped_outputs,
        dropped_samples: prepared.dropped_samples,
        gyro_bias_rad_s,
        gyro_check,
        use_gyro: settings.use_gyro,
        reference_rate_rad_s,
        clocks,
        clock_note,
        motion_on_path,
        to_identify,
    })
}

/// The joint fit of a recording's two phases (`dynamic` its rotation phase, prepared): with the
/// packages' clocks where the array file declares them and the recording resolves them, and the
/// anti-alias filters' refits where it declares filters and no clocks; the clocks' estimate, or
/// why they were not fitted.
fn fit_phases(
    rec: &Recording,
    array: &RecordingArray,
    seg: &Segmentation,
    stat: &StaticData,
    dynamic: Option<&DynamicData>,
    settings: &CalibrateSettings,
) -> Result<(Fit, Option<ClockEstimate>, Option<String>), CalibrateError> {
    let fit_error = |source: FitError| CalibrateError::Fit { path: rec.path.clone(), source };
    // With the clocks, the fit without them is only the start of their refits (and the residual
    // before them): three Gauss-Newton iterations a round do (recording 4: 1.70 -> 1.0 s, every
    // parameter of the six calibrations within 0.09 sigma, `docs/performance.md`). Where the
    // clocks are not resolved it is run again, uncapped, from the same cold start: a warm refit
    // from the capped fit ends elsewhere (real recording 4: 0.1 sigma from the cold fit's end).
    let clocked = dynamic.is_some() && array.has_sample_clocks();
    let start_settings = FitSettings {
        max_iterations: if clocked {
            CLOCKED_START_ITERATIONS.min(settings.fit.max_iterations)
        } else {
            settings.fit.max_iterations
        },
        ..settings.fit
    };
    let fit = fit(&array.array, stat, dynamic, &start_settings).map_err(fit_error)?;
    let (fit, clocks, clock_note) = match dynamic.filter(|_| clocked) {
        Some(d) => {
            check_clock_rates(rec, array)?;
            let robust = !settings.plain_least_squares;
            match estimate_clocks(rec, array, seg, stat, d, &settings.fit, &fit, robust) {
                Ok((f, c)) => (f, Some(c), None),
                Err(ClockFailure::NotResolved(why)) => {
                    (fit_from(&array.array, stat, dynamic, &settings.fit, None).map_err(fit_error)?, None, Some(why))
                }
                Err(ClockFailure::Fit(source)) => return Err(fit_error(source)),
            }
        }
        None => (fit, None, None),
    };
    // Without the clocks' refits, the anti-alias filters' term gets refits of its own.
    let fit = match (dynamic, &clocks) {
        (Some(d), None) if accelerometer_time_constants(array).is_some() => {
            refit_with_filters(array, stat, d, &settings.fit, fit).map_err(fit_error)?
        }
        _ => fit,
    };
    Ok((fit, clocks, clock_note))
}

/// `rec` with its bias drift taken out as [`calibrate`] takes it out under
/// `CalibrateSettings::remove_bias_drift` (fitted to the static phase alone,
/// [`static_phase_drift`], then [`without_bias_drift`]), and that drift; where there is none to
/// take out, `rec` as it is and why not.
pub fn bias_drift_taken_out(
    rec: &Recording,
    array: &RecordingArray,
    settings: &CalibrateSettings,
) -> Result<(Recording, Result<StaticDrift, String>), CalibrateError> {
    Ok(match static_phase_drift(rec, array, settings)? {
        Ok(drift) => (without_bias_drift(rec, &drift), Ok(drift)),
        Err(why) => (rec.clone(), Err(why)),
    })
}

/// Records on `cal` (a calibration of the recording with `drift` taken out, or of the recording
/// as it is where the drift is `Err(why)`) what was taken out: the drift taken out is an
/// estimate, so the variance its uncertainty adds to each scale factor, bias and tilt in the
/// static phase goes on their diagonal.
pub fn with_removed_drift(cal: &mut Calibration, drift: Result<StaticDrift, String>) {
    match drift {
        Ok(drift) => {
            for j in 0..cal.fit.params.len() {
                for p in 0..4 {
                    cal.fit.covariance[(PER_ACCEL * j + p, PER_ACCEL * j + p)] += drift.added_variance(j, p);
                }
            }
            cal.removed_bias_drift = Some(drift);
        }
        Err(why) => cal.bias_drift_note = Some(why),
    }
}

/// The bias drift of a recording's static phase (`selfcal::static_drift`) at a fit of the static
/// phase alone (no rotation phase: its pull and its own gaps kept out of the drift); the inner
/// `Err` says why there is none (too few poses for a fit without a rotation phase, or for the
/// drift's five parameters an accelerometer).
fn static_phase_drift(
    rec: &Recording,
    array: &RecordingArray,
    settings: &CalibrateSettings,
) -> Result<Result<StaticDrift, String>, CalibrateError> {
    let bad = |problem: String| CalibrateError::Recording { path: rec.path.clone(), problem };
    let seg = segment(rec, &settings.detector).map_err(|e| bad(e.to_string()))?;
    let stat = static_data(rec, &seg.static_intervals)
        .map_err(|problem| bad(format!("{problem} (array file {})", array.path.display())))?;
    let static_only = match fit(&array.array, &stat, None, &settings.fit) {
        Ok(f) => f,
        Err(e) => {
            return Ok(Err(format!("the bias drift was not removed: its fit of the static phase alone failed ({e})")));
        }
    };
    let (static_t_s, t_mid_s) = static_times(&rec.t_s, &seg.static_intervals);
    Ok(static_drift_at(
        &array.array,
        &stat,
        &static_only.params,
        &static_only.up,
        &static_t_s,
        t_mid_s,
        settings.fit.gravity_m_s2,
    )
    .ok_or_else(|| "the bias drift was not removed: the static phase has too few poses to fit it".to_string()))
}

/// `rec` with the bias drift `drift` taken out of every output, `s -= k d (t - t_mid)` (`k` the
/// drift refit's scale factor; an accelerometer without a drift is left as it is). Which outputs
/// are clipped is the recording's, not recomputed.
pub fn without_bias_drift(rec: &Recording, drift: &StaticDrift) -> Recording {
    let mut out = rec.clone();
    for (j, rate) in drift.rate_m_s2_per_s.iter().enumerate().filter(|(_, r)| r.is_finite()) {
        let k = drift.params.scale_factor[j];
        for (i, t) in rec.t_s.iter().enumerate() {
            out.outputs[(i, j)] -= k * rate * (t - drift.t_mid_s);
        }
    }
    out
}

/// The clocks of a recording's packages as their own gyroscopes measure them (the start of
/// [`estimate_clocks`], no calibration): per package its clock (`None` without a free-running
/// clock), referred to the centre of the rotation phase. `Err` says why a recording does not
/// resolve them.
pub fn gyroscope_clocks(
    rec: &Recording,
    array: &RecordingArray,
    settings: &CalibrateSettings,
) -> Result<Vec<Option<SampleClock>>, String> {
    let seg = segment(rec, &settings.detector).map_err(|e| e.to_string())?;
    let dt = host_dt_s(&rec.t_s).ok_or("the recording has no time step")?;
    let dynamic_rows: Vec<usize> = seg.dynamic_intervals.iter().flat_map(|iv| iv.start..iv.end).collect();
    let static_rows: Vec<usize> = seg.static_intervals.iter().flat_map(|iv| iv.start..iv.end).collect();
    let (Some(&first), Some(&last)) = (dynamic_rows.first(), dynamic_rows.last()) else {
        return Err("no rotation phase".into());
    };
    let t_ref_s = 0.5 * (rec.t_s[first] + rec.t_s[last]);
    let offsets = gyro_offsets(rec, &dynamic_rows, &static_rows).ok_or("no gyroscope in every package")?;
    let nominal: Vec<f64> = array.packages.iter().map(|p| p.sample_clock_hz.unwrap_or(1.0 / dt)).collect();
    let fits =
        fit_packages(&offsets, &nominal, dt, t_ref_s, 5e-3).ok_or("too few samples with angular acceleration")?;
    Ok(array.packages.iter().zip(&fits).map(|(p, f)| p.free_running().then_some(f.clock)).collect())
}

/// A calibration's dynamic data with the outputs corrected to the packages' mean instant by its
/// clocks and timing motion (what the fit with clocks was fitted to), and by the anti-alias
/// filters' term where the array file declares filters (`selfcal::filter`).
pub fn corrected_dynamic(array: &RecordingArray, fit: &Fit, d: &DynamicData, clocks: &ClockEstimate) -> DynamicData {
    let (package_of, sens, weights) = timing_inputs(array, fit);
    let problem = ClockProblem::new(&sens, d, &fit.motion, &weights, &package_of);
    let outputs = problem.corrected(&d.outputs, &clocks.clocks, &clocks.timing);
    DynamicData {
        outputs: with_filters(array, fit, outputs),
        extra_unknowns_per_sample: TIMING_UNKNOWNS_PER_SAMPLE,
        ..d.clone()
    }
}

/// What a clock problem at `fit` reads: each accelerometer's package, the sensors, and the
/// outputs' inverse variances in the rotation phase.
fn timing_inputs(array: &RecordingArray, fit: &Fit) -> (Vec<usize>, Vec<Sensor>, Vec<f64>) {
    let package_of: Vec<usize> = array.package_of.iter().map(|p| p.unwrap_or(0)).collect();
    let weights: Vec<f64> = fit.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect();
    (package_of, sensors(&array.array, &fit.params), weights)
}

/// A clocked calibration's motion with every sample's rate on the path over its branches
/// (`selfcal::branch`), `d` the rotation phase as read.
fn rates_on_path(
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
fn with_filters(array: &RecordingArray, fit: &Fit, outputs: DMatrix<f64>) -> DMatrix<f64> {
    match accelerometer_time_constants(array) {
        Some(tau) => filter_corrected(&outputs, &sensors(&array.array, &fit.params), &fit.motion, &tau),
        None => outputs,
    }
}

/// Refits of a calibration without clocks, each to the outputs less the filters' term at the
/// fit before (the term is a few tenths of a percent of the centripetal term: two refits leave
/// its error far below the noise).
fn refit_with_filters(
    array: &RecordingArray,
    stat: &StaticData,
    d: &DynamicData,
    settings: &FitSettings,
    mut fit: Fit,
) -> Result<Fit, FitError> {
    for _ in 0..2 {
        let corrected = DynamicData { outputs: with_filters(array, &fit, d.outputs.clone()), ..d.clone() };
        fit = fit_from(&array.array, stat, Some(&corrected), settings, Some(&fit))?;
    }
    Ok(fit)
}

/// A declared sample clock must tick faster than the host samples (else "the latest sample"
/// is no sample-and-hold of a faster clock): refused naming the array file's key.
fn check_clock_rates(rec: &Recording, array: &RecordingArray) -> Result<(), CalibrateError> {
    let Some(dt) = host_dt_s(&rec.t_s) else { return Ok(()) };
    for (i, p) in array.packages.iter().enumerate() {
        if let Some(f0) = p.sample_clock_hz.filter(|_| p.sample_and_hold)
            && f0 * dt <= 1.0
        {
            return Err(CalibrateError::Recording {
                path: array.path.clone(),
                problem: format!(
                    "key `package[{i}].sample_clock_hz`: {f0} Hz is not above the recording's sample rate ({:.4} Hz, from {}): a sample-and-hold clock must tick faster than the host reads",
                    1.0 / dt,
                    rec.path.display()
                ),
            });
        }
    }
    Ok(())
}

/// Why the clocks were not fitted.
enum ClockFailure {
    /// The recording cannot resolve them (said in the calibration's note).
    NotResolved(String),
    Fit(FitError),
}

/// The packages' clocks fitted with the calibration (module docs); `fit0` is the fit without them.
/// `robust`: once the least-squares iterations settle, go on with Huber's weights
/// (`selfcal::huber`).
#[allow(clippy::too_many_arguments)]
fn estimate_clocks(
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
    let package_of: Vec<usize> = array.package_of.iter().map(|p| p.unwrap_or(0)).collect();
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
        let weights: Vec<f64> = fit.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect();
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
        &fit.dynamic_sigma_m_s2.iter().map(|s| 1.0 / (s * s)).collect::<Vec<_>>(),
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
/// clocks' refits ([`calibrate`]).
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
    // The gyroscopes read at the accelerometers' instants: `accelerometer_lag_s` earlier.
    let lagged = use_gyro.then(|| LaggedGyroscopes::new(rec)).flatten();
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
            match &lagged {
                Some(l) => index.iter().map(|&i| l.rate_rad_s(rec, i) - b).collect(),
                None => index.iter().map(|&i| rec.gyro_rate_rad_s[i] - b).collect(),
            }
        }),
        extra_unknowns_per_sample: 0,
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

fn gyro_check(rec: &Recording, index: &[usize], motion: &[SampleMotion], bias: &Vector3<f64>) -> GyroCheck {
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
