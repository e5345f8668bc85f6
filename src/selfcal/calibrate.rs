//! `gfcal calibrate`: a recording in, every parameter with its sigma out.
//!
//! Takes the bias drift in time out first (`selfcal::static_drift`), segments the recording,
//! forms the static means and the dynamic samples, fits (`selfcal::fit`), and checks the
//! gyroscope-free angular rate against the reference gyroscopes (`selfcal::gyro_check`). Where
//! the array file declares free-running sample clocks (`array::wiring`), the packages' clocks are
//! fitted with the other parameters (`selfcal::clocked`), and the gyroscope-free rate is read on
//! the path over its branches (`selfcal::branch`).

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use nalgebra::{DMatrix, Vector3};

use super::clock::{SampleClock, fit_packages};
use super::clocked::{CLOCKED_START_ITERATIONS, ClockFailure, estimate_clocks, rates_on_path, with_filters};
use super::data::{DynamicData, StaticData};
use super::filter::accelerometer_time_constants;
use super::fit::{Fit, FitError, FitSettings, fit, fit_from};
use super::gyro_check::{GyroCheck, gyro_bias, gyro_check};
use super::lag::{LaggedGyroscopes, rates_behind};
use super::model::{PER_ACCEL, SampleMotion};
use super::recording::Recording;
use super::segment::{DetectorSettings, Interval, Segmentation, segment};
use super::static_drift::{StaticDrift, static_drift_at, static_times};
use super::tension::{StaticTension, tension_at};
use super::timing::{ClockEstimate, gyro_offsets, host_dt_s};
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
