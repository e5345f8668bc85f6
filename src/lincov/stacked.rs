//! Every metric block's `S C S^T` at once, for a block-diagonal parameter covariance `C` (a
//! perfect fixture: one `PER_ACCEL x PER_ACCEL` block per accelerometer).
//!
//! A mixture propagates each of its truths' covariances through the same blocks `S_b` (3 x P,
//! one per horizon and metric). ParamBlock by block, `S_b C S_b^T` is a sum over accelerometers of
//! 3 x 7 by 7 x 7 products: short columns that leave the processor's vector lanes mostly empty.
//! Here the blocks are stacked with the block index fastest, `t[j][c][r][b] = S_b[r, 7 j + c]`,
//! so each accelerometer's `S C` for every block is one run of long vector updates, and so is
//! the sum of its outer products. Each element on and above the diagonal is summed in the order
//! the block-by-block product sums it (over the accelerometers, within one over `k` for `S C` and
//! over the columns for the outer products, each sum started from its first product), so it is
//! the same to the last bit; the elements below the diagonal are their mirror (the product is
//! symmetric; the block-by-block one only to rounding), which saves a third of the outer
//! products. The AVX copy uses no fused multiply-add, so it gives the same bits as the other.

use nalgebra::{DMatrix, Matrix3};

use super::sources::ParamBlock;
use crate::calib::params::PER_ACCEL;

/// The metric blocks stacked for [`StackedBlocks::covariances`].
#[derive(Debug, Clone)]
pub struct StackedBlocks {
    blocks: usize,
    accelerometers: usize,
    /// `t[((j * PER_ACCEL + c) * 3 + r) * blocks + b] = S_b[r, PER_ACCEL j + c]`.
    t: Vec<f64>,
}

impl StackedBlocks {
    /// Stacks the 3 x P blocks `s` (P a whole number of accelerometers' parameters, the same for
    /// every block); `None` otherwise or for no block.
    pub fn new(s: &[&DMatrix<f64>]) -> Option<Self> {
        let p = s.first()?.ncols();
        if p == 0 || p % PER_ACCEL != 0 || s.iter().any(|m| m.nrows() != 3 || m.ncols() != p) {
            return None;
        }
        let blocks = s.len();
        let mut t = vec![0.0; 3 * p * blocks];
        for (b, m) in s.iter().enumerate() {
            for col in 0..p {
                for r in 0..3 {
                    t[(col * 3 + r) * blocks + b] = m[(r, col)];
                }
            }
        }
        Some(Self { blocks, accelerometers: p / PER_ACCEL, t })
    }

    /// `S_b C S_b^T` for every block `b`, in the order the blocks were given. `cov` holds `C`'s
    /// diagonal blocks, one per accelerometer.
    pub fn covariances(&self, cov: &[ParamBlock]) -> Vec<Matrix3<f64>> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor has AVX, the only feature the copy is compiled for.
            return unsafe { self.covariances_avx(cov) };
        }
        self.covariances_any(cov)
    }

    /// [`Self::covariances_any`] compiled for AVX (four lanes; no fused multiply-add, so the
    /// same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn covariances_avx(&self, cov: &[ParamBlock]) -> Vec<Matrix3<f64>> {
        self.covariances_any(cov)
    }

    #[inline(always)]
    fn covariances_any(&self, cov: &[ParamBlock]) -> Vec<Matrix3<f64>> {
        let nb = self.blocks;
        let run = 3 * nb;
        // acc[(r * 3 + q) * nb + b] = (S_b C S_b^T)[r, q], for r <= q (the product is symmetric)
        let mut acc = vec![0.0; 9 * nb];
        // u[(c * 3 + r) * nb + b] = (S_b C_j)[r, c]
        let mut u = vec![0.0; PER_ACCEL * run];
        for (j, c_j) in cov.iter().enumerate().take(self.accelerometers) {
            let o = j * PER_ACCEL;
            let t_j = &self.t[o * run..(o + PER_ACCEL) * run];
            for c in 0..PER_ACCEL {
                let u_c = &mut u[c * run..(c + 1) * run];
                let c0 = c_j[(0, c)];
                for (u, t) in u_c.iter_mut().zip(&t_j[..run]) {
                    *u = t * c0;
                }
                for k in 1..PER_ACCEL {
                    let ck = c_j[(k, c)];
                    for (u, t) in u_c.iter_mut().zip(&t_j[k * run..(k + 1) * run]) {
                        *u += t * ck;
                    }
                }
            }
            for c in 0..PER_ACCEL {
                let (u_c, t_c) = (&u[c * run..(c + 1) * run], &t_j[c * run..(c + 1) * run]);
                for r in 0..3 {
                    for q in r..3 {
                        let out = &mut acc[(r * 3 + q) * nb..(r * 3 + q + 1) * nb];
                        for ((a, x), y) in
                            out.iter_mut().zip(&u_c[r * nb..(r + 1) * nb]).zip(&t_c[q * nb..(q + 1) * nb])
                        {
                            *a += x * y;
                        }
                    }
                }
            }
        }
        (0..nb).map(|b| Matrix3::from_fn(|r, q| acc[(r.min(q) * 3 + r.max(q)) * nb + b])).collect()
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::SMatrix;
    use rand::RngExt;

    use super::*;
    use crate::rng::trial_rng;

    /// The block-by-block product it replaces, written out (an independent implementation:
    /// nalgebra's 3 x 7 by 7 x 7 product, then the outer products summed over the columns).
    fn by_blocks(s: &DMatrix<f64>, cov: &DMatrix<f64>) -> Matrix3<f64> {
        let p = s.ncols();
        let mut out = [[0.0; 3]; 3];
        for o in (0..p).step_by(PER_ACCEL) {
            let s_j = SMatrix::<f64, 3, PER_ACCEL>::from_fn(|r, c| s[(r, o + c)]);
            let c_j = SMatrix::<f64, PER_ACCEL, PER_ACCEL>::from_fn(|r, c| cov[(o + r, o + c)]);
            let sc = s_j * c_j;
            for col in 0..PER_ACCEL {
                for r in 0..3 {
                    for q in 0..3 {
                        out[r][q] += sc[(r, col)] * s_j[(q, col)];
                    }
                }
            }
        }
        Matrix3::from_fn(|r, q| out[r][q])
    }

    /// The same bits as the block-by-block product on and above the diagonal, and exactly
    /// symmetric, on random blocks and a random block-diagonal covariance (the product's
    /// off-diagonal blocks filled with values it must not read), for a block count that fills no
    /// whole set of vector lanes.
    #[test]
    fn every_block_matches_the_block_by_block_product_bit_for_bit() {
        let mut rng = trial_rng(11, 0);
        let (accels, blocks) = (6, 13);
        let p = accels * PER_ACCEL;
        let s: Vec<DMatrix<f64>> =
            (0..blocks).map(|_| DMatrix::from_fn(3, p, |_, _| rng.random_range(-3.0..3.0))).collect();
        let a = DMatrix::from_fn(p, p, |_, _| rng.random_range(-1.0..1.0));
        let full = &a * a.transpose();
        let cov = DMatrix::from_fn(p, p, |r, c| if r / PER_ACCEL == c / PER_ACCEL { full[(r, c)] } else { f64::NAN });
        let diagonal: Vec<ParamBlock> =
            (0..accels).map(|j| ParamBlock::from_fn(|r, c| cov[(PER_ACCEL * j + r, PER_ACCEL * j + c)])).collect();
        let stacked = StackedBlocks::new(&s.iter().collect::<Vec<_>>()).expect("whole accelerometers");
        let covs = stacked.covariances(&diagonal);
        assert_eq!(covs.len(), blocks);
        for (b, m) in s.iter().enumerate() {
            let expected = by_blocks(m, &cov);
            for r in 0..3 {
                for q in r..3 {
                    assert_eq!(covs[b][(r, q)].to_bits(), expected[(r, q)].to_bits(), "block {b}, element {r}, {q}");
                    assert_eq!(covs[b][(q, r)].to_bits(), covs[b][(r, q)].to_bits(), "block {b}: symmetric");
                }
            }
        }
    }

    #[test]
    fn blocks_that_are_not_whole_accelerometers_are_refused() {
        let odd = DMatrix::<f64>::zeros(3, PER_ACCEL + 1);
        assert!(StackedBlocks::new(&[&odd]).is_none());
        assert!(StackedBlocks::new(&[]).is_none());
        let (a, b) = (DMatrix::<f64>::zeros(3, PER_ACCEL), DMatrix::<f64>::zeros(3, 2 * PER_ACCEL));
        assert!(StackedBlocks::new(&[&a, &b]).is_none());
    }
}
