//! The motion at every sample of the rotation phase, given the sensor parameters: solved from
//! scratch, re-solved at each step of the joint fit, repaired where a sample left its neighbours'
//! basin, signed by continuity, and its rate's sigma.
//!
//! A sample's own problem (`selfcal::motion::solve`) can have more than one basin: the outputs are
//! quadratic in the rate, and the board's short baselines (18.9 mm across, 2 mm through) make some
//! of the quadratic terms weakly seen. A local solve then stops in a wrong basin with a rate off
//! by about its own magnitude, at moderate rates (5-10 rad/s, 10-25 sigma) in about 0.3% of the
//! samples of a simulated recording. Two checks catch it, and both re-solve the sample from its
//! neighbours' motions carried to its time by their angular accelerations (and from the linear
//! guess where the misfit stands out), keeping the lowest misfit:
//! - **misfit**: more than 5 times the run's median and more than 4 per output;
//! - **continuity**: the rate differs from a neighbour's carried rate (either sign) by more than
//!   5 standard deviations of that difference (`|d|^2 > 25 tr(cov d)`), the covariance from both
//!   samples' motion information. Where the model fits and the motion is smooth over a step, a
//!   correct sample trips it with a probability far below 1e-4. On the real board's hand-held
//!   recordings it flags 2,100-3,700 of 6,323 samples in each repair of the refits with the clocks
//!   (recording 4, 2026-11-27): the carried rate ignores the angular jerk over a 16 ms step, and the
//!   covariance holds white noise only. The re-solves are harmless (the lower misfit is kept) but
//!   cost a third of a refit (`docs/performance.md`).
//!
//! Keeping the lower misfit makes a needless re-solve harmless.

use nalgebra::{DMatrix, DVector, SMatrix, Vector3};
use rayon::prelude::*;

use super::data::DynamicData;
use super::model::{PER_ACCEL, SampleMotion, Sensor, SensorSet, sensors};
use super::motion::{self, SampleData};
use crate::array::Array;

type SVector9 = nalgebra::SVector<f64, 9>;

/// One solved sample: its motion and misfit.
type Solved = (SampleMotion, f64);

/// The motion of every sample of `d` given the sensor parameters, from scratch: the better of the
/// linear guess and the previous sample's motion advanced by its angular acceleration, refined;
/// then repaired and signed as in [`refine`].
pub fn from_scratch(array: &Array, d: &DynamicData, dynamic_w: &[f64], params: &SensorSet) -> Vec<SampleMotion> {
    let sens = sensors(array, params);
    let n = array.len();
    let row = |i: usize| -> Vec<f64> { d.outputs.row(i).iter().copied().collect() };
    let fixed = |i: usize| d.reference_rate_rad_s.as_ref().map(|r| r[i]);
    // The solves from the linear guess need no neighbour: every sample's, side by side.
    let guessed: Vec<Solved> = (0..d.samples())
        .into_par_iter()
        .map(|i| {
            let outputs = row(i);
            let data = SampleData { outputs: &outputs, used: &d.used[i * n..(i + 1) * n], weights: dynamic_w };
            let mut st = motion::linear_guess(&sens, &data);
            if let Some(wr) = fixed(i) {
                st.omega_rad_s = wr;
            }
            motion::solve(&sens, &data, st, fixed(i).is_some())
        })
        .collect();
    let mut motion = vec![SampleMotion::default(); d.samples()];
    for (s, e) in d.runs() {
        for i in s..e {
            let (mut best, best_cost) = guessed[i];
            if i > s {
                let outputs = row(i);
                let data = SampleData { outputs: &outputs, used: &d.used[i * n..(i + 1) * n], weights: dynamic_w };
                let prev = motion[i - 1];
                let dt = d.t_s[i] - d.t_s[i - 1];
                let mut st = SampleMotion { omega_rad_s: prev.omega_rad_s + prev.alpha_rad_s2 * dt, ..prev };
                if let Some(wr) = fixed(i) {
                    st.omega_rad_s = wr;
                }
                let (m, c) = motion::solve(&sens, &data, st, fixed(i).is_some());
                if c < best_cost {
                    best = m;
                }
            }
            motion[i] = best;
        }
    }
    refine(array, d, dynamic_w, params, &motion, true)
}

/// Re-solves every sample's motion from its current value (in parallel), re-solves the samples
/// that fail the misfit check, and with `repair` the continuity check (module docs), from other
/// starts, then signs the rates by continuity (`selfcal::motion::orient_run`).
///
/// The joint fit's line search calls it without `repair`, so that the misfit it compares is a
/// smooth function of the step; the repair runs once at the start of every round of the fit.
pub fn refine(
    array: &Array,
    d: &DynamicData,
    dynamic_w: &[f64],
    params: &SensorSet,
    motion_in: &[SampleMotion],
    repair: bool,
) -> Vec<SampleMotion> {
    let sens = sensors(array, params);
    let n = array.len();
    let fixed = d.reference_rate_rad_s.is_some();
    let row = |i: usize| -> Vec<f64> { d.outputs.row(i).iter().copied().collect() };
    let first: Vec<Solved> = (0..d.samples())
        .into_par_iter()
        .map(|i| {
            let outputs = row(i);
            let data = SampleData { outputs: &outputs, used: &d.used[i * n..(i + 1) * n], weights: dynamic_w };
            motion::solve(&sens, &data, motion_in[i], fixed)
        })
        .collect();
    let mut costs: Vec<f64> = first.iter().map(|f| f.1).collect();
    let mid = costs.len() / 2;
    let median = if costs.is_empty() { 0.0 } else { *costs.select_nth_unstable_by(mid, f64::total_cmp).1 };
    let run_of = run_of_sample(d);
    let neighbours = &|i: usize| -> Vec<usize> {
        [i.wrapping_sub(1), i + 1].into_iter().filter(|&k| k < d.samples() && run_of[k] == run_of[i]).collect()
    };
    // The rate covariance of each sample (omega block of its motion information's inverse), for
    // the continuity check; not needed when the rate is given.
    let rate_var: Vec<(f64, f64)> = if fixed || !repair {
        Vec::new()
    } else {
        first
            .par_iter()
            .enumerate()
            .map(|(i, (m, _))| {
                let y =
                    motion::information_inverse(&motion::information(&sens, &d.used[i * n..(i + 1) * n], dynamic_w, m));
                ((6..9).map(|c| y[(c, c)]).sum(), (3..6).map(|c| y[(c, c)]).sum())
            })
            .collect()
    };
    let breaks_continuity = &|i: usize| -> bool {
        if fixed {
            return false;
        }
        let (wi, ai) = (first[i].0.omega_rad_s, first[i].0.alpha_rad_s2);
        neighbours(i).into_iter().any(|k| {
            let dt = d.t_s[i] - d.t_s[k];
            let carried = first[k].0.omega_rad_s + (first[k].0.alpha_rad_s2 + ai) * (0.5 * dt);
            let miss = (wi - carried).norm_squared().min((wi + carried).norm_squared());
            let var = rate_var[i].0 + rate_var[k].0 + 0.25 * dt * dt * (rate_var[i].1 + rate_var[k].1);
            miss > 25.0 * var
        })
    };
    let mut out: Vec<SampleMotion> = (0..d.samples())
        .into_par_iter()
        .map(|i| {
            let (mut best, mut best_cost) = first[i];
            let used = d.used[i * n..(i + 1) * n].iter().filter(|&&u| u).count() as f64;
            let stands_out = best_cost > 5.0 * median && best_cost > 4.0 * used;
            let suspect = stands_out || (repair && breaks_continuity(i));
            if !suspect {
                return best;
            }
            let outputs = row(i);
            let data = SampleData { outputs: &outputs, used: &d.used[i * n..(i + 1) * n], weights: dynamic_w };
            // A sample that only breaks continuity is re-solved from its neighbours; one whose
            // misfit stands out also from the linear guess.
            let mut starts = if stands_out { vec![motion::linear_guess(&sens, &data)] } else { Vec::new() };
            for k in neighbours(i) {
                let nb = first[k].0;
                let dt = d.t_s[i] - d.t_s[k];
                starts.push(SampleMotion { omega_rad_s: nb.omega_rad_s + nb.alpha_rad_s2 * dt, ..nb });
            }
            for mut st in starts {
                if let Some(r) = &d.reference_rate_rad_s {
                    st.omega_rad_s = r[i];
                }
                let (m, c) = motion::solve(&sens, &data, st, fixed);
                if c < best_cost {
                    best = m;
                    best_cost = c;
                }
            }
            best
        })
        .collect();
    if !fixed {
        for (s, e) in d.runs() {
            motion::orient_run(&d.t_s[s..e], &mut out[s..e]);
        }
    }
    out
}

/// The index of the run each sample belongs to.
fn run_of_sample(d: &DynamicData) -> Vec<usize> {
    let mut v = vec![0; d.samples()];
    for (r, (s, e)) in d.runs().into_iter().enumerate() {
        v[s..e].fill(r);
    }
    v
}

/// `cov u_c` for the three vectors at once, in one pass over `cov`: each element summed as a
/// matrix-vector product sums it (`cov[i, 0] u[0]`, then `+ cov[i, k] u[k]` in column order), so
/// the same bits as three products, for a third of the reads of `cov`.
fn covariance_times(cov: &DMatrix<f64>, u: &[DVector<f64>; 3]) -> [DVector<f64>; 3] {
    let n = cov.nrows();
    if n == 0 {
        return std::array::from_fn(|_| DVector::zeros(0));
    }
    let (mut o0, mut o1, mut o2) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for (k, column) in cov.as_slice().chunks_exact(n).enumerate() {
        let (x0, x1, x2) = (u[0][k], u[1][k], u[2][k]);
        let rows = column.iter().zip(o0.iter_mut().zip(o1.iter_mut().zip(o2.iter_mut())));
        if k == 0 {
            for (a, (o0, (o1, o2))) in rows {
                *o0 = a * x0;
                *o1 = a * x1;
                *o2 = a * x2;
            }
        } else {
            for (a, (o0, (o1, o2))) in rows {
                *o0 += a * x0;
                *o1 += a * x1;
                *o2 += a * x2;
            }
        }
    }
    [DVector::from_vec(o0), DVector::from_vec(o1), DVector::from_vec(o2)]
}

/// Sigma of every sample's rate (per axis): the sample's own noise (`Hll^-1`) and the
/// uncertainty of the accelerometer parameters carried into it,
/// `Y + Y M Sigma_x M^T Y` with `Y = Hll^-1`, `M` the sample's motion-parameter information and
/// `Sigma_x` the parameters' covariance in the gauge (the rate's estimate moves by `-Y M dx`).
/// Zero where the rate is given (`fixed`); infinite on an axis a sample does not observe.
pub fn rate_sigmas(
    array: &Array,
    d: &DynamicData,
    dynamic_w: &[f64],
    params: &SensorSet,
    motion: &[SampleMotion],
    fixed: bool,
    covariance: &nalgebra::DMatrix<f64>,
) -> Vec<Vector3<f64>> {
    let sens: Vec<Sensor> = sensors(array, params);
    let n = array.len();
    let na = PER_ACCEL * n;
    let cov = covariance.view((0, 0), (na, na)).map(|v| if v.is_finite() { v } else { 0.0 });
    (0..d.samples())
        .into_par_iter()
        .map(|i| {
            if fixed {
                return Vector3::zeros();
            }
            let m = &motion[i];
            let mut hll = SMatrix::<f64, 9, 9>::zeros();
            let mut parts: Vec<(usize, SVector9, [f64; PER_ACCEL])> = Vec::with_capacity(n);
            for (j, s) in sens.iter().enumerate() {
                if !d.used[i * n + j] {
                    continue;
                }
                let q = m.specific_force_m_s2(&s.position_m);
                let dl = SVector9::from(s.d_motion(m));
                let d4 = s.d_intrinsic(&q);
                let dloc = s.d_location(m);
                hll.ger(dynamic_w[j], &dl, &dl, 1.0);
                parts.push((j, dl * dynamic_w[j], [d4[0], d4[1], d4[2], d4[3], dloc.x, dloc.y, dloc.z]));
            }
            let y = motion::information_inverse(&hll);
            let u: [DVector<f64>; 3] = std::array::from_fn(|c| {
                let row = y.row(6 + c);
                // Column (j, a) of (Y M)[6 + c, :] is (row . w_j dl_j) dg_j[a].
                let mut u = DVector::zeros(na);
                for (j, wdl, dg) in &parts {
                    let f = row.dot(&wdl.transpose());
                    for (a, g) in dg.iter().enumerate() {
                        u[PER_ACCEL * j + a] = f * g;
                    }
                }
                u
            });
            let cov_u = covariance_times(&cov, &u);
            // A rate axis the sample does not observe (its rate collapsed to zero: the
            // pseudo-inverse leaves it out, `motion::information_inverse`) has no bound.
            let seen = motion::observed(&hll);
            Vector3::from_fn(|c, _| {
                if seen[6 + c] { (y[(6 + c, 6 + c)] + cov_u[c].dot(&u[c]).max(0.0)).sqrt() } else { f64::INFINITY }
            })
        })
        .collect()
}
