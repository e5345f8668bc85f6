//! The rows of a fitted recording as blocks for `projected`: one block per static interval (its
//! mean outputs; local nuisance the pose's two tangent angles) and one per dynamic sample (its
//! unclipped outputs; local nuisance the motion, 9 unknowns, or 6 with the reference rate), with
//! the global columns: first the nuisance (`Nuisance`), then the sample clocks' relative
//! parameters where they were fitted (`ClockNuisance`), then each effect's regressor.

use nalgebra::{DMatrix, DVector, Vector3};

use super::effect::{EffectLayout, RecordedEffect, Row};
use super::projected::{Accumulated, Block, Spread, accumulate};
use crate::array::Array;
use crate::selfcal::clock::SampleClock;
use crate::selfcal::data::{DynamicData, StaticData};
use crate::selfcal::model::{PER_ACCEL, SampleMotion, Sensor, SensorSet, sensors};
use crate::selfcal::timing::{TIMING_UNKNOWNS_PER_SAMPLE, timing_directions};
use crate::sensor::misalignment::tilt_basis;

/// The fitted state of one recording.
#[derive(Debug, Clone, Copy)]
pub struct RecordingState<'a> {
    pub array: &'a Array,
    pub params: &'a SensorSet,
    pub stat: &'a StaticData,
    /// Middle time of each static interval, s.
    pub static_t_s: &'a [f64],
    pub up: &'a [Vector3<f64>],
    /// Weight of a static mean: `count / (sigma_j^2 * static_variance_factor)`.
    pub static_variance_factor: f64,
    pub dynamic: Option<&'a DynamicData>,
    pub motion: &'a [SampleMotion],
    /// Weight of one dynamic output per accelerometer.
    pub dynamic_w: &'a [f64],
    /// With the sample clocks fitted: each dynamic output's relative age (samples x
    /// accelerometers, s, `selfcal::timing::accelerometer_ages`). Each sample's timing motion
    /// (jerk and angular jerk, `selfcal::timing`) is then local nuisance too: the outputs were
    /// corrected with the fitted timing motion, which took its share of any effect.
    pub ages_s: Option<&'a DMatrix<f64>>,
    /// Per dynamic output (samples x accelerometers): a factor on its weight.
    pub row_factor: Option<&'a DMatrix<f64>>,
    /// How many columns the layout gives the sample clocks' relative parameters (the fitting
    /// recording's [`ClockNuisance::columns`], on held-out recordings too, so that they share its
    /// layout; 0 without clocks).
    pub clock_columns: usize,
    /// Their values on this recording: `None` leaves them zero (a held-out recording, whose
    /// outputs are not corrected by the fitting recording's clocks).
    pub clocks: Option<ClockNuisance<'a>>,
    pub gravity_m_s2: f64,
    /// The recording's middle time, s.
    pub t_mid_s: f64,
}

/// The sample clocks' relative parameters as global nuisance, on a recording whose outputs were
/// corrected by them (`selfcal::clocked::corrected_dynamic`): per clocked package its rate
/// offset, drift and phase (`SampleClock::age_partials`), in the packages' order. The correction
/// adds `tau_p(t) c_ij` to output `j` of package `p` at sample `i` (`c_ij` its rate of change,
/// [`ClockNuisance::rate_m_s3`]; `tau_p` the package's age less the packages' mean), so a clock
/// parameter `x_q` of package `q` has the column `c_ij (delta(p, q) - 1/P) d age_q / d x_q` (`P`
/// packages, clocked or not), as the clocks' own fit has (`selfcal::timing`). The common part of
/// every clock leaves the relative ages alone: its three directions are null (the clock model's
/// gauge), which the projections' pseudo-inverses leave out.
///
/// Why they are nuisance: between its wraps a package's phase shifts its outputs' age by a
/// constant, which is what a package's sampling delay does; held at the fitted clocks, the
/// library read the delay's sigma as if the phase were known, and read as a delay whatever the
/// calibration's (Huber-weighted) clock fit left along the phase under the library's weights.
#[derive(Debug, Clone, Copy)]
pub struct ClockNuisance<'a> {
    pub clocks: &'a [Option<SampleClock>],
    /// Each accelerometer's package.
    pub package_of: &'a [usize],
    /// Each dynamic output's rate of change (samples x accelerometers, m/s^3,
    /// `selfcal::clocked::corrected_dynamic_and_rates`).
    pub rate_m_s3: &'a DMatrix<f64>,
}

impl ClockNuisance<'_> {
    /// Three a clocked package.
    pub fn columns(&self) -> usize {
        3 * self.clocks.iter().filter(|c| c.is_some()).count()
    }

    /// Output `j`'s row at sample `i` (time `t_s`) of the clocks' columns, into `out` (one
    /// element a column).
    pub fn regress(&self, i: usize, j: usize, t_s: f64, out: &mut [f64]) {
        let packages = self.clocks.len() as f64;
        let rate = self.rate_m_s3[(i, j)];
        for (c, (q, clock)) in self.clocks.iter().enumerate().filter_map(|(q, c)| c.map(|c| (q, c))).enumerate() {
            let share = if q == self.package_of[j] { 1.0 } else { 0.0 } - 1.0 / packages;
            let partials = clock.age_partials(t_s);
            for a in 0..3 {
                out[3 * c + a] = rate * share * partials[a];
            }
        }
    }
}

/// The global nuisance re-adjusted with the effects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Nuisance {
    /// Nothing (a held-out recording with only its poses and motion refitted).
    Nothing,
    /// Every parameter of the baseline (`PER_ACCEL` per accelerometer, `selfcal::model` order):
    /// the fitting recording.
    Baseline,
    /// Each accelerometer's bias: a held-out recording with a turn-on bias.
    Bias,
    /// Each accelerometer's bias, then each one's scale factor.
    BiasAndScale,
}

/// What a held-out recording refits of the baseline's parameters (their columns in the
/// [`Nuisance::Baseline`] layout, which held-out recordings are accumulated with too, so that the
/// fitting recording's change of every parameter can be carried over to them).
pub fn refitted_columns(refit: Nuisance, n: usize) -> Vec<usize> {
    match refit {
        Nuisance::Baseline => (0..PER_ACCEL * n).collect(),
        Nuisance::Nothing => Vec::new(),
        Nuisance::Bias => (0..n).map(|j| PER_ACCEL * j + 1).collect(),
        Nuisance::BiasAndScale => (0..n).flat_map(|j| [PER_ACCEL * j + 1, PER_ACCEL * j]).collect(),
    }
}

impl Nuisance {
    pub fn columns(&self, n: usize) -> usize {
        match self {
            Self::Nothing => 0,
            Self::Baseline => PER_ACCEL * n,
            Self::Bias => n,
            Self::BiasAndScale => 2 * n,
        }
    }

    fn regress(
        &self,
        j: usize,
        n: usize,
        s: &Sensor,
        q: &Vector3<f64>,
        d_location: Option<Vector3<f64>>,
        out: &mut [f64],
    ) {
        let d = s.d_intrinsic(q);
        match self {
            Self::Nothing => {}
            Self::Baseline => {
                out[PER_ACCEL * j..PER_ACCEL * j + 4].copy_from_slice(&d);
                if let Some(l) = d_location {
                    out[PER_ACCEL * j + 4..PER_ACCEL * j + 7].copy_from_slice(l.as_slice());
                }
            }
            Self::Bias => out[j] = d[1],
            Self::BiasAndScale => {
                out[j] = d[1];
                out[n + j] = d[0];
            }
        }
    }
}

/// The accumulations of a recording, the static and the dynamic phase apart, and each effect's
/// first column (after the nuisance's).
#[derive(Debug, Clone)]
pub struct RecordingNormal {
    pub statics: Accumulated,
    pub dynamics: Accumulated,
    pub offsets: Vec<usize>,
    pub nuisance_columns: usize,
    /// The nuisance columns refitted on this recording (all of them on the fitting recording).
    pub refit: Vec<usize>,
}

impl RecordingNormal {
    /// Both phases together.
    pub fn total(&self) -> Accumulated {
        let mut t = self.statics.clone();
        t.merge(&self.dynamics);
        t
    }
    /// The column indices refitted on this recording.
    pub fn nuisance(&self) -> Vec<usize> {
        self.refit.clone()
    }
    /// The column indices of effect `e` (its index in the list accumulated).
    pub fn effect_columns(&self, e: usize, parameters: usize) -> Vec<usize> {
        (self.offsets[e]..self.offsets[e] + parameters).collect()
    }
}

/// Accumulates `state`'s rows with the `nuisance` and the `effects` columns; `refit` says which
/// nuisance columns this recording refits (`None`: all).
pub fn accumulate_recording(
    state: &RecordingState,
    nuisance: Nuisance,
    refit: Option<Vec<usize>>,
    effects: &[RecordedEffect],
) -> RecordingNormal {
    let array = state.array;
    let n = array.len();
    let layout = EffectLayout::new(array);
    let sens = sensors(array, state.params);
    let nominal: Vec<Vector3<f64>> = array.accelerometers().iter().map(|a| a.axis).collect();
    debug_assert!(state.clocks.is_none_or(|c| c.columns() == state.clock_columns));
    let clock_offset = nuisance.columns(n);
    let g0 = clock_offset + state.clock_columns;
    let mut offsets = Vec::with_capacity(effects.len());
    let mut cols = g0;
    for e in effects {
        offsets.push(cols);
        cols += e.parameters(&layout);
    }
    let regress_effects = |row: &Row, out: &mut [f64]| {
        for (e, &o) in effects.iter().zip(&offsets) {
            let p = e.parameters(&layout);
            e.regress(row, &layout, &mut out[o..o + p]);
        }
    };
    let g = state.gravity_m_s2;
    let stat = state.stat;
    let mut statics = accumulate(stat.means.nrows(), cols, Spread::Model, |p| {
        let u = state.up[p];
        let (e1, e2) = tilt_basis(&u);
        let q = u * g;
        let mut local = DMatrix::zeros(n, 2);
        let mut columns = DMatrix::zeros(n, cols);
        let mut residual = DVector::zeros(n);
        let mut weight = DVector::zeros(n);
        let mut buf = vec![0.0; cols];
        for (j, s) in sens.iter().enumerate() {
            local[(j, 0)] = s.k * g * s.axis.dot(&e1);
            local[(j, 1)] = s.k * g * s.axis.dot(&e2);
            buf.iter_mut().for_each(|v| *v = 0.0);
            nuisance.regress(j, n, s, &q, None, &mut buf);
            let row = Row {
                j,
                k: s.k,
                axis: s.axis,
                nominal_axis: nominal[j],
                q_m_s2: q,
                dq_dt_m_s3: Vector3::zeros(),
                t_from_mid_s: state.static_t_s[p] - state.t_mid_s,
                d_omega: None,
                reference_rate_rad_s: None,
            };
            regress_effects(&row, &mut buf);
            columns.row_mut(j).copy_from_slice(&buf);
            residual[j] = stat.means[(p, j)] - s.output(&q);
            weight[j] = stat.counts[p] as f64 / (stat.sigma[j].powi(2) * state.static_variance_factor);
        }
        Some(Block { local, columns, residual, weight })
    });
    statics.variance_factor = state.static_variance_factor;
    let dynamics = match state.dynamic {
        Some(d) if !state.motion.is_empty() => {
            let reference = d.reference_rate_rad_s.as_ref();
            let nmotion = if reference.is_some() { 6 } else { 9 };
            let nlocal = nmotion + if state.ages_s.is_some() { TIMING_UNKNOWNS_PER_SAMPLE } else { 0 };
            let df_all = derivatives(d, |i| state.motion[i].f_m_s2);
            let dalpha_all = derivatives(d, |i| state.motion[i].alpha_rad_s2);
            // The rate's derivative inside the centripetal term's derivative: with `--use-gyro`, the
            // gyroscopes' rate's, the rate the term is formed from. (The fitted angular acceleration is
            // a free parameter of each sample, pulled by whatever the model leaves out: on the real
            // recordings a delay of the gyroscopes by 1.2 ms moved the delay read with it by
            // 0.33-0.51 ms, and with the gyroscopes' derivative by 1.19-1.38 ms.)
            let omega_dot = reference.map(|r| derivatives(d, |i| r[i]));
            let banded = whole_differentiator(d);
            let directions: Vec<_> = sens.iter().map(timing_directions).collect();
            accumulate(d.samples(), cols, Spread::Sandwich, |i| {
                let m = &state.motion[i];
                let (df, dalpha) = (df_all[i], dalpha_all[i]);
                let mut local = DMatrix::zeros(n, nlocal);
                let mut columns = DMatrix::zeros(n, cols);
                let mut residual = DVector::zeros(n);
                let mut weight = DVector::zeros(n);
                let mut buf = vec![0.0; cols];
                let w = &m.omega_rad_s;
                let al = omega_dot.as_ref().map_or(&m.alpha_rad_s2, |r| &r[i]);
                for (j, s) in sens.iter().enumerate() {
                    if !d.used[i * n + j] {
                        continue;
                    }
                    let r = &s.position_m;
                    let q = m.specific_force_m_s2(r);
                    // The delay's column only where the derivatives are band-limited (see
                    // `whole_differentiator`); elsewhere the row carries no delay information.
                    let dq = if banded[i] {
                        df + dalpha.cross(r) + al * w.dot(r) + w * al.dot(r) - r * (2.0 * w.dot(al))
                    } else {
                        Vector3::zeros()
                    };
                    let dm = s.d_motion(m);
                    for c in 0..nmotion {
                        local[(j, c)] = dm[c];
                    }
                    if let Some(ages) = state.ages_s {
                        // The timing term's columns (`selfcal::timing`): `tau k a` for the jerk,
                        // `tau k (r x a)` for the angular jerk.
                        let g = s.k * ages[(i, j)];
                        let (a, ra) = &directions[j];
                        for c in 0..3 {
                            local[(j, nmotion + c)] = g * a[c];
                            local[(j, nmotion + 3 + c)] = g * ra[c];
                        }
                    }
                    buf.iter_mut().for_each(|v| *v = 0.0);
                    nuisance.regress(j, n, s, &q, Some(s.d_location(m)), &mut buf);
                    if let Some(c) = &state.clocks {
                        c.regress(i, j, d.t_s[i], &mut buf[clock_offset..g0]);
                    }
                    let row = Row {
                        j,
                        k: s.k,
                        axis: s.axis,
                        nominal_axis: nominal[j],
                        q_m_s2: q,
                        dq_dt_m_s3: dq,
                        t_from_mid_s: d.t_s[i] - state.t_mid_s,
                        d_omega: Some([dm[6], dm[7], dm[8]]),
                        reference_rate_rad_s: reference.map(|r| r[i]),
                    };
                    regress_effects(&row, &mut buf);
                    columns.row_mut(j).copy_from_slice(&buf);
                    residual[j] = d.outputs[(i, j)] - s.output(&q);
                    weight[j] = state.dynamic_w[j] * state.row_factor.map_or(1.0, |f| f[(i, j)]);
                }
                Some(Block { local, columns, residual, weight })
            })
        }
        _ => Accumulated::zeros(cols),
    };
    RecordingNormal {
        statics,
        dynamics,
        offsets,
        nuisance_columns: g0,
        refit: refit.unwrap_or_else(|| (0..g0).collect()),
    }
}

/// The time derivative at every sample of `x` (one vector per sample of `d`), by a band-limited
/// differentiator within each run of samples: the derivative of the sinc interpolant (taps
/// `(-1)^(k+1) / k`), Hann-windowed over up to [`DIFFERENTIATOR_HALF`] neighbours each side (fewer
/// near a run's ends) and normalised to be exact on a straight line; one-sided at a run's first
/// and last sample, zero for a run of one.
///
/// Why not a central difference: hand-held rotation has power up to the Nyquist frequency of
/// 62.5 Hz samples, where a central difference reads the slope short (`sin(w h) / (w h)`: 0.64
/// at half the Nyquist) and a delay through it long: a 0.4 ms delay injected into real recordings
/// 2 and 3 read 0.55-0.6 ms. Why only four neighbours: the tracked motion is noisy near the
/// Nyquist frequency, and a regressor's noise biases its coefficient towards zero. With 16
/// neighbours (flat to 0.4 of the sample rate) the same injection read 0.36 ms; with 4 (flat
/// within 2% to 0.3, 0.77 at 0.4) 0.41 ms. The spread, about 10%, is the delay's systematic
/// uncertainty on real motion.
fn derivatives(d: &DynamicData, x: impl Fn(usize) -> Vector3<f64>) -> Vec<Vector3<f64>> {
    let mut out = vec![Vector3::zeros(); d.samples()];
    for (s, e) in d.runs() {
        if e - s < 2 {
            continue;
        }
        let dt = (d.t_s[e - 1] - d.t_s[s]) / (e - 1 - s) as f64;
        if dt <= 0.0 {
            continue;
        }
        for (i, slot) in out.iter_mut().enumerate().take(e).skip(s) {
            let half = DIFFERENTIATOR_HALF.min(i - s).min(e - 1 - i);
            if half == 0 {
                let (a, b) = if i == s { (i, i + 1) } else { (i - 1, i) };
                *slot = (x(b) - x(a)) / dt;
                continue;
            }
            let taps = crate::signal::differentiator(half);
            let mut dx = Vector3::zeros();
            for (k, c) in taps.iter().enumerate() {
                let k = k + 1;
                dx += (x(i + k) - x(i - k)) * *c;
            }
            *slot = dx / dt;
        }
    }
    out
}

/// Whether each sample's run holds the whole differentiator ([`DIFFERENTIATOR_HALF`] neighbours
/// each side). Nearer a run's end [`derivatives`] shortens it, down to a one-sided difference,
/// which is the slope half a sample away. With `--use-gyro` the rows where a gyroscope rails are
/// dropped and split the rotation phase into short runs: on real recordings 2 and 3 only a third
/// of the rows hold the whole differentiator, the others sit next to the rails where the motion is
/// fastest, and with their shortened derivatives in the delay's column a 1.2 ms advance of every
/// accelerometer read 1.07-1.08 ms (1.18-1.19 ms with the column on the whole-differentiator rows
/// only, printed sigma 0.065 ms).
pub fn whole_differentiator(d: &DynamicData) -> Vec<bool> {
    let mut out = vec![false; d.samples()];
    for (s, e) in d.runs() {
        for (i, slot) in out.iter_mut().enumerate().take(e).skip(s) {
            *slot = i - s >= DIFFERENTIATOR_HALF && e - 1 - i >= DIFFERENTIATOR_HALF;
        }
    }
    out
}

/// Neighbours each side of the band-limited differentiator.
pub const DIFFERENTIATOR_HALF: usize = 4;
