//! One rotation-phase sample's share of the joint fit's reduced normal equations: the sample's
//! motion eliminated by the Schur complement, leaving the accelerometer parameters' blocks.
//!
//! The sample's Schur complement `M^T Hll^+ M` is rank 9 but dense over every accelerometer's
//! parameters. Each output depends on its own accelerometer's parameters only, so column
//! `(j, a)` of `M` is `w_j dg_j[a] dl_j`, and the update is `P_jk dg_j dg_k^T` for every pair of
//! accelerometers with `P_jk = w_j w_k dl_j^T Hll^+ dl_k`: 7 x 7 blocks instead of a dense
//! `7 N x 7 N` product. The update is symmetric, so only the blocks on and below the diagonal are
//! summed ([`LowerBlocks`], packed one block after another so that a sample's 300 block updates
//! run through memory in order); [`LowerBlocks::add_to`] adds them to the normal matrix and
//! [`mirror_upper_blocks`] fills the blocks above the diagonal.
//!
//! Every element is summed in the same order, by the same operations, whatever the layout or the
//! instruction set (no fused multiply-add), so the normal matrix is the same to the bit on any
//! processor and any number of threads.

#![allow(clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix};

use super::data::DynamicData;
use super::model::{PER_ACCEL, SampleMotion, Sensor};
use super::motion;

/// Rows of a packed block: the block's 7 rows and one of padding, so that each column starts on
/// a multiple of four values (two 256-bit lanes a column).
const ROWS: usize = 8;
/// Values of a packed block: `PER_ACCEL` columns of [`ROWS`].
const BLOCK: usize = ROWS * PER_ACCEL;

/// The accelerometer blocks on and below the diagonal of a chunk's reduced normal matrix, packed:
/// block `(a, b)` with `b <= a` starts at `(a (a + 1) / 2 + b) BLOCK`, column `q` of it at
/// `q ROWS`, and row `p` of that column is the matrix's element `(7 a + p, 7 b + q)`.
pub(super) struct LowerBlocks {
    accelerometers: usize,
    values: Vec<f64>,
}

impl LowerBlocks {
    pub(super) fn zeros(accelerometers: usize) -> Self {
        let blocks = accelerometers * (accelerometers + 1) / 2;
        Self { accelerometers, values: vec![0.0; blocks * BLOCK] }
    }

    fn offset(a: usize, b: usize) -> usize {
        debug_assert!(b <= a);
        (a * (a + 1) / 2 + b) * BLOCK
    }

    fn block_mut(&mut self, a: usize, b: usize) -> &mut [f64; BLOCK] {
        let start = Self::offset(a, b);
        let slice = &mut self.values[start..start + BLOCK];
        slice.try_into().expect("a packed block holds BLOCK values")
    }

    /// Adds the blocks to those on and below the diagonal of the top-left `7 N x 7 N` corner of
    /// `h`, element by element ([`mirror_upper_blocks`] then fills the others).
    pub(super) fn add_to(&self, h: &mut DMatrix<f64>) {
        let n = self.accelerometers;
        for a in 0..n {
            for b in 0..=a {
                let block = &self.values[Self::offset(a, b)..Self::offset(a, b) + BLOCK];
                for q in 0..PER_ACCEL {
                    let column = &mut h.column_mut(PER_ACCEL * b + q);
                    let column = &mut column.as_mut_slice()[PER_ACCEL * a..PER_ACCEL * (a + 1)];
                    for (v, x) in column.iter_mut().zip(&block[q * ROWS..q * ROWS + PER_ACCEL]) {
                        *v += x;
                    }
                }
            }
        }
    }
}

/// The accelerometers' blocks above the diagonal of the normal matrix set to the mirror of those
/// below it.
pub(super) fn mirror_upper_blocks(h: &mut DMatrix<f64>, accelerometers: usize) {
    for a in 0..accelerometers {
        for b in a + 1..accelerometers {
            for p in 0..PER_ACCEL {
                for q in 0..PER_ACCEL {
                    h[(PER_ACCEL * a + p, PER_ACCEL * b + q)] = h[(PER_ACCEL * b + q, PER_ACCEL * a + p)];
                }
            }
        }
    }
}

/// What every sample of a run of samples shares in [`accumulate_samples`].
pub(super) struct Samples<'a> {
    pub sens: &'a [Sensor],
    pub data: &'a DynamicData,
    pub motion: &'a [SampleMotion],
    pub weights: &'a [f64],
    /// Per output (row-major, samples x accelerometers), a factor on its accelerometer's weight
    /// (the robust covariance's bread, `selfcal::robust`); `None`: every factor 1.
    pub output_w: Option<&'a [f64]>,
    /// The rate is the reference gyroscopes' (6 motion unknowns a sample, not 9).
    pub fixed: bool,
    /// The rate blocks with the residual's curvature, as `motion::solve` solves the motion.
    pub rate_curvature: bool,
}

/// [`accumulate_sample`] over samples `range`, in order.
pub(super) fn accumulate_samples(
    samples: &Samples,
    range: std::ops::Range<usize>,
    blocks: Option<&mut LowerBlocks>,
    g: &mut DVector<f64>,
    scratch: &mut SampleScratch,
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, the only feature the copy is compiled for.
        unsafe { accumulate_samples_avx(samples, range, blocks, g, scratch) };
        return;
    }
    accumulate_samples_any(samples, range, blocks, g, scratch);
}

/// [`accumulate_samples_any`] compiled for AVX (four lanes; no fused multiply-add, so the same
/// bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn accumulate_samples_avx(
    samples: &Samples,
    range: std::ops::Range<usize>,
    blocks: Option<&mut LowerBlocks>,
    g: &mut DVector<f64>,
    scratch: &mut SampleScratch,
) {
    accumulate_samples_any(samples, range, blocks, g, scratch);
}

#[inline(always)]
fn accumulate_samples_any(
    samples: &Samples,
    range: std::ops::Range<usize>,
    mut blocks: Option<&mut LowerBlocks>,
    g: &mut DVector<f64>,
    scratch: &mut SampleScratch,
) {
    for i in range {
        accumulate_sample(samples, i, blocks.as_deref_mut(), g, scratch);
    }
}

/// Adds sample `i`'s contribution to the reduced normal equations of the accelerometer
/// parameters (the module's docs). Without `blocks` only the reduced gradient is added (the
/// scores of `selfcal::robust`).
#[inline(always)]
fn accumulate_sample(
    samples: &Samples,
    i: usize,
    mut blocks: Option<&mut LowerBlocks>,
    g: &mut DVector<f64>,
    scratch: &mut SampleScratch,
) {
    let Samples { sens, data: d, motion: motions, weights, output_w, fixed, rate_curvature } = *samples;
    let m = &motions[i];
    let n = sens.len();
    let mut hll = SMatrix::<f64, 9, 9>::zeros();
    let mut gl = SVector9::zeros();
    scratch.wdl.clear();
    scratch.dg.clear();
    scratch.index.clear();
    let with_curvature = rate_curvature && !fixed;
    let mut curvature = Matrix3::zeros();
    for (j, s) in sens.iter().enumerate() {
        if !d.used[i * n + j] {
            continue;
        }
        let q = m.specific_force_m_s2(&s.position_m);
        let r = d.outputs[(i, j)] - s.output(&q);
        let wt = match output_w {
            Some(f) => weights[j] * f[i * n + j],
            None => weights[j],
        };
        if with_curvature {
            curvature += motion::rate_curvature(s, wt * r);
        }
        let mut dl = SVector9::from(s.d_motion(m));
        if fixed {
            for k in 6..9 {
                dl[k] = 0.0;
            }
        }
        let d4 = s.d_intrinsic(&q);
        let dloc = s.d_location(m);
        let dg = [d4[0], d4[1], d4[2], d4[3], dloc.x, dloc.y, dloc.z];
        hll.ger(wt, &dl, &dl, 1.0);
        gl.axpy(wt * r, &dl, 1.0);
        let base = PER_ACCEL * j;
        for a in 0..PER_ACCEL {
            g[base + a] += wt * dg[a] * r;
        }
        if let Some(blocks) = blocks.as_deref_mut() {
            // Each element once, as `wt dg_a dg_b`.
            let block = blocks.block_mut(j, j);
            for b in 0..PER_ACCEL {
                for a in 0..PER_ACCEL {
                    block[b * ROWS + a] += wt * dg[a] * dg[b];
                }
            }
        }
        scratch.wdl.push(dl * wt);
        scratch.dg.push(dg);
        scratch.index.push(j);
    }
    if fixed {
        for k in 6..9 {
            hll[(k, k)] = 1.0;
        }
    } else if with_curvature {
        // The rate's block with the residual's curvature, as the sample's motion is solved
        // (`motion::solve`): at a low rate the Gauss-Newton block alone lets the rate absorb a
        // share of a parameter step that no re-solved motion can (`motion::solve`'s docs).
        let block = hll.fixed_view::<3, 3>(6, 6).into_owned();
        if let (Some(newton), _) = motion::newton_rate_block(&block, &curvature) {
            hll.fixed_view_mut::<3, 3>(6, 6).copy_from(&newton);
        }
    }
    // H -= M^T Hll^+ M; g -= M^T Hll^+ g_l (a pseudo-inverse where the sample does not fix its
    // whole motion: at zero rate the centripetal terms, and with them the rate, vanish).
    let inv = motion::information_inverse(&hll);
    let y = inv * gl;
    let m_used = scratch.index.len();
    for a in 0..m_used {
        let base_a = PER_ACCEL * scratch.index[a];
        let ga = scratch.wdl[a].dot(&y);
        let dga = scratch.dg[a];
        for p in 0..PER_ACCEL {
            g[base_a + p] -= dga[p] * ga;
        }
        let Some(blocks) = blocks.as_deref_mut() else { continue };
        let ya = inv * scratch.wdl[a];
        // The blocks on and below the diagonal (`b <= a`, the used outputs in increasing order).
        for b in 0..=a {
            let pab = ya.dot(&scratch.wdl[b]);
            let dgb = scratch.dg[b];
            // The padding row's factor is 0: it stays 0 and is never read.
            let f: [f64; ROWS] = std::array::from_fn(|p| if p < PER_ACCEL { pab * dga[p] } else { 0.0 });
            let block = blocks.block_mut(scratch.index[a], scratch.index[b]);
            // Each element once, as `(pab dga_p) dgb_q`.
            for (q, dq) in dgb.iter().enumerate() {
                let column = &mut block[q * ROWS..(q + 1) * ROWS];
                for (v, fp) in column.iter_mut().zip(&f) {
                    *v -= fp * dq;
                }
            }
        }
    }
}

/// Per-sample buffers of [`accumulate_samples`], reused across the samples of a chunk.
#[derive(Default)]
pub(super) struct SampleScratch {
    /// `w_j dl_j` of every used output.
    wdl: Vec<SVector9>,
    dg: Vec<[f64; PER_ACCEL]>,
    index: Vec<usize>,
}

type SVector9 = nalgebra::SVector<f64, 9>;

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector, SMatrix, Vector3};

    use super::*;

    /// Eight packages of three tilted axes at the corners of a 20 x 20 x 2 mm board, with scale
    /// factors and biases off their nominal values.
    fn board() -> Vec<Sensor> {
        let mut out = Vec::new();
        for (p, &(x, y, z)) in [(1.0, 1.0, 1.0), (-1.0, 1.0, -1.0), (-1.0, -1.0, 1.0), (1.0, -1.0, -1.0)]
            .iter()
            .flat_map(|c| [c, c])
            .enumerate()
        {
            let side = if p % 2 == 0 { 1.0 } else { -1.0 };
            let position_m = Vector3::new(0.01 * x * side, 0.01 * y, 0.001 * z * side);
            for (e, axis) in [Vector3::x(), Vector3::y(), Vector3::z()].into_iter().enumerate() {
                let j = (3 * p + e) as f64;
                let axis = (axis + Vector3::new(0.01 * (j * 0.7).sin(), 0.01 * (j * 1.3).cos(), 0.005)).normalize();
                let daxis = [axis.cross(&Vector3::new(0.3, 1.0, 0.2)), axis.cross(&Vector3::new(1.0, -0.4, 0.1))];
                let (k, b_m_s2) = (1.0 + 1e-3 * (j * 0.9).sin(), 0.05 * (j * 0.4).cos());
                out.push(Sensor { k, b_m_s2, axis, daxis, position_m });
            }
        }
        out
    }

    /// Three samples of outputs off any rigid motion (so the residuals are not zero), one output
    /// clipped, and their motions.
    fn recording(n: usize) -> (DynamicData, Vec<SampleMotion>) {
        let samples = 3;
        let outputs = DMatrix::from_fn(samples, n, |i, j| 4.0 * ((i * n + j) as f64 * 0.37).sin() + 2.0);
        let mut used = vec![true; samples * n];
        used[n + 4] = false;
        let data = DynamicData {
            t_s: vec![0.0, 0.016, 0.032],
            outputs,
            used,
            run_starts: vec![0],
            reference_rate_rad_s: None,
            extra_unknowns_per_sample: 0,
        };
        let motion = (0..samples)
            .map(|i| {
                let s = i as f64;
                SampleMotion {
                    f_m_s2: Vector3::new(1.0 + s, -2.0, 9.0 - s),
                    alpha_rad_s2: Vector3::new(40.0, 10.0 * s, -25.0),
                    omega_rad_s: Vector3::new(12.0 - 3.0 * s, -4.0, 7.0 + s),
                }
            })
            .collect();
        (data, motion)
    }

    /// The reduced normal matrix and gradient written out densely: `H = D^T W D - M^T Hll^-1 M`,
    /// `g = D^T W r - M^T Hll^-1 L^T W r`, with `D` every output's parameter gradients (7 per
    /// accelerometer), `L` its motion gradients (the rate's columns zero when `fixed`, and the
    /// rate's block of `Hll` then the identity) and `M = L^T W D`.
    fn dense(samples: &Samples) -> (DMatrix<f64>, DVector<f64>) {
        let n = samples.sens.len();
        let na = PER_ACCEL * n;
        let (mut h, mut g) = (DMatrix::zeros(na, na), DVector::zeros(na));
        for (i, m) in samples.motion.iter().enumerate() {
            let rows: Vec<usize> = (0..n).filter(|&j| samples.data.used[i * n + j]).collect();
            let mut d = DMatrix::zeros(rows.len(), na);
            let mut l = DMatrix::zeros(rows.len(), 9);
            let mut w = DMatrix::zeros(rows.len(), rows.len());
            let mut r = DVector::zeros(rows.len());
            for (row, &j) in rows.iter().enumerate() {
                let s = &samples.sens[j];
                let q = m.specific_force_m_s2(&s.position_m);
                let d4 = s.d_intrinsic(&q);
                let dloc = s.d_location(m);
                for (a, v) in [d4[0], d4[1], d4[2], d4[3], dloc.x, dloc.y, dloc.z].into_iter().enumerate() {
                    d[(row, PER_ACCEL * j + a)] = v;
                }
                let dl = s.d_motion(m);
                for k in 0..if samples.fixed { 6 } else { 9 } {
                    l[(row, k)] = dl[k];
                }
                w[(row, row)] = samples.weights[j] * samples.output_w.map_or(1.0, |f| f[i * n + j]);
                r[row] = samples.data.outputs[(i, j)] - s.output(&q);
            }
            let mut hll: SMatrix<f64, 9, 9> = SMatrix::from_iterator((l.transpose() * &w * &l).iter().copied());
            if samples.fixed {
                for k in 6..9 {
                    hll[(k, k)] = 1.0;
                }
            }
            let inv = DMatrix::from_iterator(9, 9, hll.try_inverse().expect("the motion is resolved").iter().copied());
            let mm = l.transpose() * &w * &d;
            h += d.transpose() * &w * &d - mm.transpose() * &inv * &mm;
            g += d.transpose() * &w * &r - mm.transpose() * &inv * (l.transpose() * &w * &r);
        }
        (h, g)
    }

    fn packed(samples: &Samples, portable: bool) -> (DMatrix<f64>, DVector<f64>) {
        let n = samples.sens.len();
        let mut blocks = LowerBlocks::zeros(n);
        let mut g = DVector::zeros(PER_ACCEL * n);
        let mut scratch = SampleScratch::default();
        let range = 0..samples.motion.len();
        if portable {
            accumulate_samples_any(samples, range, Some(&mut blocks), &mut g, &mut scratch);
        } else {
            accumulate_samples(samples, range, Some(&mut blocks), &mut g, &mut scratch);
        }
        let mut h = DMatrix::zeros(PER_ACCEL * n, PER_ACCEL * n);
        blocks.add_to(&mut h);
        mirror_upper_blocks(&mut h, n);
        (h, g)
    }

    /// The packed blocks, added and mirrored, against the Schur complement written out densely,
    /// with the rate free and with it given, and with a weight factor per output; and the gradient
    /// alone (no blocks) the same.
    #[test]
    fn the_packed_update_is_the_dense_schur_complement() {
        let sens = board();
        let (data, motion) = recording(sens.len());
        let weights: Vec<f64> = (0..sens.len()).map(|j| 1e3 * (1.0 + 0.1 * j as f64)).collect();
        // A factor per output (the robust covariance's bread), some of them zero, as `dense` reads it.
        let factors: Vec<f64> = (0..data.used.len()).map(|k| ((k * 7) % 5) as f64 / 4.0).collect();
        for (fixed, output_w) in [(false, None), (true, None), (false, Some(factors.as_slice()))] {
            let samples = Samples {
                sens: &sens,
                data: &data,
                motion: &motion,
                weights: &weights,
                output_w,
                fixed,
                rate_curvature: false,
            };
            let (h, g) = packed(&samples, false);
            let (h_dense, g_dense) = dense(&samples);
            let scale = h_dense.amax();
            assert!((&h - &h_dense).amax() < 1e-9 * scale, "fixed {fixed}: {:e} of {scale:e}", (&h - &h_dense).amax());
            assert!((&g - &g_dense).amax() < 1e-9 * g_dense.amax(), "fixed {fixed}");
            let mut g_alone = DVector::zeros(PER_ACCEL * sens.len());
            accumulate_samples(&samples, 0..motion.len(), None, &mut g_alone, &mut SampleScratch::default());
            assert_eq!(g_alone, g);
        }
    }

    /// The copy compiled for AVX gives the portable copy's bits (no fused multiply-add), with the
    /// rate's curvature in the elimination as the fit's steps use it.
    #[test]
    fn the_avx_copy_gives_the_portable_bits() {
        let sens = board();
        let (data, motion) = recording(sens.len());
        let weights: Vec<f64> = (0..sens.len()).map(|j| 1e3 * (1.0 + 0.1 * j as f64)).collect();
        let samples = Samples {
            sens: &sens,
            data: &data,
            motion: &motion,
            weights: &weights,
            output_w: None,
            fixed: false,
            rate_curvature: true,
        };
        let (h_any, g_any) = packed(&samples, true);
        let (h, g) = packed(&samples, false);
        let bits = |m: &DMatrix<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&h), bits(&h_any));
        assert_eq!(
            g.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            g_any.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }
}
