//! A clocked calibration's dynamic information and scores with each sample's timing motion
//! eliminated.
//!
//! With the packages' sample clocks (`selfcal::timing`) an output also depends on its package's
//! relative age `tau` times the sample's jerk and angular jerk (6 unknowns a sample). The
//! calibration fits that timing motion apart, on the residuals with the motion held, corrects the
//! outputs with it and holds it while the parameters and the motion are refitted; the rounds
//! alternate until the misfit settles, so the solution is (near) the joint optimum of the motion,
//! the timing motion and the parameters. The joint fit's normal equations (`selfcal::schur`)
//! eliminate only the 9 motion unknowns of a sample (6 with the gyroscopes' rate): as a
//! covariance they would treat the timing motion as known. Here each sample's local design `L`
//! also has the 6 timing columns, the specific force's and the angular acceleration's columns
//! scaled by each output's age, and the information is `G^T W G - G^T W L (L^T W L)^+ L^T W G`
//! summed over the samples, with `G` each output's own accelerometer's 7 derivatives.
//!
//! **Form.** As in `selfcal::schur`, the update of a sample is `P_jk dg_j dg_k^T` for every pair
//! of outputs, with `P_jk = w_j w_k dl_j^T (L^T W L)^+ dl_k`: 7 x 7 blocks, not a dense product.
//! The timing columns are about `1e-4` of the motion's (ages of a few tenths of a millisecond), so
//! `L^T W L` is scaled to a unit diagonal before its inverse ([`local_inverse`]: Cholesky, or the
//! eigenvalues above 1e-12 of the largest where a sample does not fix every unknown, as a rate
//! column that vanishes at zero rate).
//!
//! **Size.** On the matched protocol's simulated recordings the locations' and the static kinds'
//! sigmas grow by a median of about 1.3 with the timing motion free, which is the Monte Carlo's
//! floor of the locations' errors against the sigmas that held it (RMS z 1.35 with no vibration,
//! `results/mimu4444/EXPECTATIONS.md` (ac)). Until 2026-11-30 a defect in the ages
//! (`timing::accelerometer_ages`) made this growth look like 8-15.

use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use rayon::prelude::*;

use super::data::DynamicData;
use super::model::{PER_ACCEL, SampleMotion, Sensor};
use super::schur::mirror_upper_blocks;

/// The motion's unknowns in a sample's local design.
const MOTION_UNKNOWNS: usize = 9;
/// The timing motion's: jerk and angular jerk (`selfcal::timing::TIMING_UNKNOWNS_PER_SAMPLE`).
const TIMING_UNKNOWNS: usize = 6;
/// Samples summed apart before the chunks are added in order (the same bits on any number of
/// threads).
const CHUNK_SAMPLES: usize = 256;

/// What every sample shares in the reduction.
#[derive(Clone, Copy)]
pub struct TimingSamples<'a> {
    pub sens: &'a [Sensor],
    pub data: &'a DynamicData,
    pub motion: &'a [SampleMotion],
    /// Each accelerometer's inverse variance.
    pub weights: &'a [f64],
    /// Per output (row-major, samples x accelerometers), a factor on its accelerometer's weight
    /// (the robust covariance's bread); `None`: every factor 1.
    pub output_w: Option<&'a [f64]>,
    /// The rate is the reference gyroscopes' (not an unknown).
    pub fixed: bool,
    /// Each accelerometer's relative age at every sample (samples x accelerometers, s:
    /// `selfcal::timing::accelerometer_ages`); `None`: the motion alone is eliminated.
    pub ages: Option<&'a DMatrix<f64>>,
}

impl<'a> TimingSamples<'a> {
    /// A clocked rotation phase's: every sample's timing motion eliminated at `ages`, the rate an
    /// unknown unless `data` takes it from the gyroscopes, every output at its accelerometer's
    /// weight.
    pub fn clocked(
        sens: &'a [Sensor],
        data: &'a DynamicData,
        motion: &'a [SampleMotion],
        weights: &'a [f64],
        ages: &'a DMatrix<f64>,
    ) -> Self {
        let fixed = data.reference_rate_rad_s.is_some();
        Self { sens, data, motion, weights, output_w: None, fixed, ages: Some(ages) }
    }

    /// Adds sample `i`'s share of the reduced information (into `h`, when given) and of the
    /// reduced gradient (into `g`, when given: the score, `G^T W r` less its part along the local
    /// design).
    fn accumulate(&self, i: usize, h: Option<&mut DMatrix<f64>>, mut g: Option<&mut DVector<f64>>) {
        let n = self.sens.len();
        let m = &self.motion[i];
        let mut hll = Local::zeros();
        let mut gl = LocalVector::zeros();
        let mut rows: Vec<(usize, f64, LocalVector, [f64; PER_ACCEL])> = Vec::with_capacity(n);
        for (j, s) in self.sens.iter().enumerate() {
            if !self.data.used[i * n + j] {
                continue;
            }
            let q = m.specific_force_m_s2(&s.position_m);
            let wt = self.weights[j] * self.output_w.map_or(1.0, |f| f[i * n + j]);
            let motion = s.d_motion(m);
            let mut dl = LocalVector::zeros();
            for (c, v) in motion.iter().enumerate() {
                dl[c] = if self.fixed && c >= 6 { 0.0 } else { *v };
            }
            if let Some(ages) = self.ages {
                for c in 0..TIMING_UNKNOWNS {
                    dl[MOTION_UNKNOWNS + c] = ages[(i, j)] * motion[c];
                }
            }
            let d4 = s.d_intrinsic(&q);
            let dloc = s.d_location(m);
            let dg = [d4[0], d4[1], d4[2], d4[3], dloc.x, dloc.y, dloc.z];
            hll.ger(wt, &dl, &dl, 1.0);
            if let Some(g) = g.as_deref_mut() {
                let r = self.data.outputs[(i, j)] - s.output(&q);
                gl.axpy(wt * r, &dl, 1.0);
                for (a, v) in dg.iter().enumerate() {
                    g[PER_ACCEL * j + a] += wt * v * r;
                }
            }
            rows.push((j, wt, dl * wt, dg));
        }
        let inv = local_inverse(&hll);
        if let Some(g) = g {
            let y = inv * gl;
            for (j, _, wdl, dg) in &rows {
                let f = wdl.dot(&y);
                for (a, v) in dg.iter().enumerate() {
                    g[PER_ACCEL * j + a] -= v * f;
                }
            }
        }
        let Some(h) = h else { return };
        for (a, (j, wa, wdla, dga)) in rows.iter().enumerate() {
            for (p, x) in dga.iter().enumerate() {
                for (q, z) in dga.iter().enumerate() {
                    h[(PER_ACCEL * j + p, PER_ACCEL * j + q)] += wa * x * z;
                }
            }
            let ya = inv * wdla;
            for (k, _, wdlb, dgb) in &rows[..=a] {
                let pab = ya.dot(wdlb);
                for (q, z) in dgb.iter().enumerate() {
                    let column = &mut h.column_mut(PER_ACCEL * k + q);
                    let column = &mut column.as_mut_slice()[PER_ACCEL * j..PER_ACCEL * (j + 1)];
                    for (v, x) in column.iter_mut().zip(dga) {
                        *v -= pab * x * z;
                    }
                }
            }
        }
    }
}

/// A sample's local unknowns: the motion's 9, then the timing motion's 6 (their columns zero
/// where the rate is not an unknown or the timing motion is not eliminated).
type Local = SMatrix<f64, 15, 15>;
type LocalVector = SVector<f64, 15>;

/// The pseudo-inverse of a sample's local information: scaled to a unit diagonal (the timing
/// columns are about 1e-4 of the motion's), a unit where a column is not observed (its diagonal
/// zero or below `stats::NEGLIGIBLE_DIAGONAL` of the largest: an unknown the sample does not
/// have, or a rate at numerically zero, whose columns vanish with it; their inverse's entries are
/// not used), then Cholesky where its smallest pivot clears 1e-12, else the eigenvalues above
/// 1e-12 of the largest (as `selfcal::motion::information_inverse`).
///
/// The floor matters at a rate of about 1e-158 rad/s (a sample the fit left on the saddle at zero
/// rate): the rate's diagonal, about 1e-318, was taken as observed, its scale `1/sqrt` overflowed
/// on the way back, and the one sample made the whole covariance NaN (every parameter of real
/// recording 1 reported unidentified after 50 of Huber's iterations). It is the diagnosis's floor
/// (`stats::symmetric_pinv`), not the motion solve's (`motion::UNOBSERVED_DIAGONAL`, 1e-32): at
/// that one the six real calibrations' sigmas moved by up to 0.9% (their values not at all), so
/// more of their samples sit at rates far below any physical one; which convention is right there
/// was not settled (`docs/status.md`, thirteenth session).
fn local_inverse(hll: &Local) -> Local {
    let largest = (0..15).map(|k| hll[(k, k)]).fold(0.0_f64, f64::max);
    let floor = crate::stats::NEGLIGIBLE_DIAGONAL * largest;
    let d = LocalVector::from_fn(|k, _| if hll[(k, k)] > floor { 1.0 / hll[(k, k)].sqrt() } else { 0.0 });
    let mut scaled = Local::from_fn(|r, c| d[r] * hll[(r, c)] * d[c]);
    for k in 0..15 {
        if d[k] == 0.0 {
            scaled[(k, k)] = 1.0;
        }
    }
    let unscale = |x: &Local| Local::from_fn(|r, c| d[r] * x[(r, c)] * d[c]);
    if let Some(chol) = scaled.cholesky() {
        let smallest = chol.l().diagonal().iter().fold(f64::INFINITY, |a, &b| a.min(b * b));
        if smallest > 1e-12 {
            return unscale(&chol.inverse());
        }
    }
    let eig = scaled.symmetric_eigen();
    let largest = eig.eigenvalues.iter().fold(0.0_f64, |a, &b| a.max(b));
    let mut inv = Local::zeros();
    for (k, &lambda) in eig.eigenvalues.iter().enumerate() {
        if lambda > 1e-12 * largest {
            let v = eig.eigenvectors.column(k);
            inv += v * v.transpose() / lambda;
        }
    }
    unscale(&inv)
}

/// The reduced dynamic information of the accelerometer parameters (`PER_ACCEL` per
/// accelerometer, in order): every sample's motion eliminated and, with `ages`, its timing motion
/// too (module docs).
pub fn reduced_information(s: &TimingSamples) -> DMatrix<f64> {
    let na = PER_ACCEL * s.sens.len();
    let samples = s.data.samples().min(s.motion.len());
    let chunks: Vec<DMatrix<f64>> = (0..samples.div_ceil(CHUNK_SAMPLES))
        .into_par_iter()
        .map(|c| {
            let mut h = DMatrix::zeros(na, na);
            for i in c * CHUNK_SAMPLES..((c + 1) * CHUNK_SAMPLES).min(samples) {
                s.accumulate(i, Some(&mut h), None);
            }
            h
        })
        .collect();
    let mut h = DMatrix::zeros(na, na);
    for c in &chunks {
        h += c;
    }
    // The blocks below the diagonal were summed; mirror them above it.
    mirror_upper_blocks(&mut h, s.sens.len());
    h
}

/// The reduced score (gradient of the weighted misfit with each sample's local unknowns
/// eliminated, as [`reduced_information`] eliminates them) summed over samples `range`, in order.
pub fn reduced_score(s: &TimingSamples, range: std::ops::Range<usize>) -> DVector<f64> {
    let mut g = DVector::zeros(PER_ACCEL * s.sens.len());
    for i in range {
        s.accumulate(i, None, Some(&mut g));
    }
    g
}
