//! Linearised tests of extra terms on a fitted model, one recording at a time.
//!
//! At a fit's solution the residuals `r` are first order in any term the model leaves out. A term
//! with regressor columns `E` (the derivatives of the outputs by its parameters) is tested by one
//! Gauss-Newton step of the extended model from the solution: the local nuisance of every block
//! of rows (a static pose's two tangent angles, a dynamic sample's motion) is eliminated block by
//! block, then the global nuisance `G` (the model's own parameters, or what a held-out recording
//! refits), by the Schur complement
//!
//! ```text
//! S = E'WE - E'WG (G'WG)^+ G'WE,   b = E'Wr - E'WG (G'WG)^+ G'Wr,   theta = S^+ b
//! ```
//!
//! **Rank test.** `S` scaled by `diag(E'WE)` has eigenvalues between 0 (a direction of the term
//! that the nuisance absorbs exactly: no recording of this kind can see it) and 1 (a direction
//! the nuisance does not touch). Directions below [`UNSEEN`] are reported as unseen and left out
//! of `theta` (the minimum-norm solution over the seen ones).
//!
//! **Two covariances.** `S^+` is the model covariance: right if the weights are the inverse
//! variances of the rows. Real residuals are not (the rotation phase's grow with the reading), so
//! a robust covariance `S^+ L M L' S^+` is also formed, with `L = [-E'WG (G'WG)^+, I]` and `M` the
//! spread of the scores, added block by block in one of two ways ([`Spread`]):
//! - **sandwich** (the dynamic samples): the outer product of each block's score. Right for any
//!   variance as long as blocks are independent (a recording's dynamic residuals are white in
//!   time: `results/mimu4444/discrepancy/`), and only with many blocks: thousands of samples.
//! - **model** (the static intervals): the block's information `X'X`, times the factor by which
//!   the extended model lowers these blocks' weighted sum of squares (their weights carry the
//!   baseline's variance factor, which the term may explain in part), never below the noise. A
//!   recording has 12-40 static intervals: a sandwich over so few blocks, each with residuals
//!   shrunk by the many parameters fitted to them, underestimated a simulated drift's variance
//!   7-fold (sigma 1.5e-5 against the model's 4e-5 and the scatter's 4e-5).
//!
//! Tests name terms by the robust one.
//!
//! Accumulation runs over fixed chunks of blocks in parallel and adds the chunks in order, so the
//! result does not depend on the number of threads.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use crate::stats::symmetric_pinv;

/// A direction of a term whose scaled Schur eigenvalue is below this is unseen (absorbed).
pub const UNSEEN: f64 = 1e-9;

/// How a block's spread enters the robust covariance (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Spread {
    Model,
    Sandwich,
}

/// One block of rows sharing local nuisance unknowns.
#[derive(Debug, Clone)]
pub struct Block {
    /// Rows x local unknowns (may have no columns).
    pub local: DMatrix<f64>,
    /// Rows x global columns (the global nuisance and the terms, in the accumulation's order).
    pub columns: DMatrix<f64>,
    pub residual: DVector<f64>,
    /// Weight of each row (0: not used).
    pub weight: DVector<f64>,
    /// A factor on each row's weight applied after the local nuisance is eliminated (an
    /// M-estimate's weights on the projected rows, `huber_fixed_point`); `None`: 1.
    pub projected_factor: Option<DVector<f64>>,
}

impl Block {
    /// The weighted global columns and residual projected off the weighted local columns, and the
    /// local columns' rank.
    pub fn projected(&self) -> (DMatrix<f64>, DVector<f64>, usize) {
        let sw = self.weight.map(|w| w.max(0.0).sqrt());
        let scale = |m: &DMatrix<f64>| {
            let mut m = m.clone();
            for (i, mut row) in m.row_iter_mut().enumerate() {
                row *= sw[i];
            }
            m
        };
        let mut x = scale(&self.columns);
        let mut y = self.residual.component_mul(&sw);
        let mut rank = 0;
        if self.local.ncols() > 0 {
            // Project the weighted rows off the weighted local columns (thin QR is not needed:
            // the local columns are few and well conditioned after scaling).
            let l = scale(&self.local);
            let h = l.tr_mul(&l);
            let (inv, r) = symmetric_pinv(&h, 1e-12);
            let px = &l * (&inv * l.tr_mul(&x));
            let py = &l * (&inv * l.tr_mul(&y));
            x -= px;
            y -= py;
            rank = r;
        }
        if let Some(f) = &self.projected_factor {
            for (i, mut row) in x.row_iter_mut().enumerate() {
                let sf = f[i].max(0.0).sqrt();
                row *= sf;
                y[i] *= sf;
            }
        }
        (x, y, rank)
    }

    /// Each row's weighted residual with the global columns at `global` and the local unknowns
    /// refitted (weighted least squares): `sqrt(w) (r - X global - L local)`, before any
    /// `projected_factor`.
    pub fn weighted_residual(&self, global: &DVector<f64>) -> DVector<f64> {
        let sw = self.weight.map(|w| w.max(0.0).sqrt());
        let e = (&self.residual - &self.columns * global).component_mul(&sw);
        if self.local.ncols() == 0 {
            return e;
        }
        let mut l = self.local.clone();
        for (i, mut row) in l.row_iter_mut().enumerate() {
            row *= sw[i];
        }
        let (inv, _) = symmetric_pinv(&l.tr_mul(&l), 1e-12);
        &e - &l * (&inv * l.tr_mul(&e))
    }
}

/// The normal equations of the global columns after the local nuisance is eliminated.
#[derive(Debug, Clone, PartialEq)]
pub struct Accumulated {
    pub normal: DMatrix<f64>,
    pub score: DVector<f64>,
    /// Weighted residual sum of squares after the local elimination.
    pub ss: f64,
    /// Sum over the sandwich blocks of `s_i s_i'`, `s_i` the block's score.
    pub meat: DMatrix<f64>,
    /// The model blocks' own normal matrix, score and weighted sum of squares (their part of the
    /// three above), and the variance factor already in their weights.
    pub model_normal: DMatrix<f64>,
    pub model_score: DVector<f64>,
    pub model_ss: f64,
    pub variance_factor: f64,
    /// Rows with a positive weight, and local unknowns eliminated.
    pub rows: usize,
    pub local: usize,
    /// With weights at an M-estimate's fixed point (`huber_fixed_point`): the normal matrix with
    /// each row weighted by the derivative of its psi-function instead (the M-estimate's
    /// sensitivity to its parameters), the bread of the robust covariance. `None`: `normal`.
    pub bread: Option<DMatrix<f64>>,
}

impl Accumulated {
    pub fn zeros(columns: usize) -> Self {
        Self {
            normal: DMatrix::zeros(columns, columns),
            score: DVector::zeros(columns),
            ss: 0.0,
            meat: DMatrix::zeros(columns, columns),
            model_normal: DMatrix::zeros(columns, columns),
            model_score: DVector::zeros(columns),
            model_ss: 0.0,
            variance_factor: 1.0,
            rows: 0,
            local: 0,
            bread: None,
        }
    }

    /// The bread of the robust covariance (see `bread`).
    pub fn bread_normal(&self) -> &DMatrix<f64> {
        self.bread.as_ref().unwrap_or(&self.normal)
    }

    /// Adds one block, its spread counted as `spread` says.
    pub fn add(&mut self, b: &Block, spread: Spread) {
        let (x, y, rank) = b.projected();
        self.local += rank;
        let s = x.tr_mul(&y);
        self.normal.gemm_tr(1.0, &x, &x, 1.0);
        self.score += &s;
        self.ss += y.norm_squared();
        match spread {
            Spread::Sandwich => self.meat.ger(1.0, &s, &s, 1.0),
            Spread::Model => {
                self.model_normal.gemm_tr(1.0, &x, &x, 1.0);
                self.model_score += &s;
                self.model_ss += y.norm_squared();
            }
        }
        self.rows += b.weight.iter().filter(|w| **w > 0.0).count();
    }

    /// The accumulation of the residuals less the columns `cols` times `theta` (a term held at a
    /// known value). The sandwich blocks' scores are not kept, so `meat` is left as it was: a
    /// test on the shifted accumulation uses the unshifted sandwich blocks' spread.
    pub fn shifted(&self, cols: &[usize], theta: &[f64]) -> Self {
        let mut out = self.clone();
        if cols.is_empty() {
            return out;
        }
        let th = DVector::from_column_slice(theta);
        let ncols = DMatrix::from_fn(self.normal.nrows(), cols.len(), |i, j| self.normal[(i, cols[j])]);
        out.score -= &ncols * &th;
        let sc = subv(&self.score, cols);
        out.ss = self.ss - 2.0 * th.dot(&sc) + (th.transpose() * sub(&self.normal, cols, cols) * &th)[(0, 0)];
        let mcols = DMatrix::from_fn(self.model_normal.nrows(), cols.len(), |i, j| self.model_normal[(i, cols[j])]);
        out.model_score -= &mcols * &th;
        out.model_ss = self.model_ss - 2.0 * th.dot(&subv(&self.model_score, cols))
            + (th.transpose() * sub(&self.model_normal, cols, cols) * &th)[(0, 0)];
        out
    }

    /// Adds another accumulation.
    pub fn merge(&mut self, o: &Self) {
        // The bread first: without its own, each side's is its normal matrix before the merge.
        if self.bread.is_some() || o.bread.is_some() {
            self.bread = Some(self.bread_normal() + o.bread_normal());
        }
        self.normal += &o.normal;
        self.score += &o.score;
        self.meat += &o.meat;
        self.ss += o.ss;
        self.model_normal += &o.model_normal;
        self.model_score += &o.model_score;
        self.model_ss += o.model_ss;
        self.variance_factor = self.variance_factor.max(o.variance_factor);
        self.rows += o.rows;
        self.local += o.local;
    }
}

/// Accumulates `count` blocks made by `block` (`None`: skipped), in parallel over fixed chunks,
/// added in order, their spread counted as `spread` says.
pub fn accumulate(
    count: usize,
    columns: usize,
    spread: Spread,
    block: impl Fn(usize) -> Option<Block> + Sync,
) -> Accumulated {
    const CHUNK: usize = 64;
    let chunks: Vec<Accumulated> = (0..count.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut acc = Accumulated::zeros(columns);
            for i in c * CHUNK..((c + 1) * CHUNK).min(count) {
                if let Some(b) = block(i) {
                    acc.add(&b, spread);
                }
            }
            acc
        })
        .collect();
    let mut total = Accumulated::zeros(columns);
    for c in &chunks {
        total.merge(c);
    }
    total
}

/// A term fitted on top of the nuisance.
#[derive(Debug, Clone, PartialEq)]
pub struct TermFit {
    /// The term's parameters (minimum norm over its seen directions).
    pub value: Vec<f64>,
    pub sigma_model: Vec<f64>,
    pub sigma_robust: Vec<f64>,
    pub covariance_robust: DMatrix<f64>,
    /// Directions of the term that the nuisance absorbs.
    pub unseen: usize,
    /// The global nuisance's change with the term (so that the pair is the extended model's
    /// solution).
    pub nuisance_change: DVector<f64>,
}

/// The submatrix of `m` at `rows` x `cols`.
fn sub(m: &DMatrix<f64>, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(rows.len(), cols.len(), |i, j| m[(rows[i], cols[j])])
}

fn subv(v: &DVector<f64>, rows: &[usize]) -> DVector<f64> {
    DVector::from_fn(rows.len(), |i, _| v[rows[i]])
}

/// Fits the columns `terms` of `acc` with the columns `nuisance` re-adjusted (see the module docs).
pub fn fit_terms(acc: &Accumulated, nuisance: &[usize], terms: &[usize]) -> TermFit {
    let (pg, _) = symmetric_pinv(&sub(&acc.normal, nuisance, nuisance), 1e-11);
    let neg = sub(&acc.normal, terms, nuisance);
    let k = &neg * &pg;
    let s = sub(&acc.normal, terms, terms) - &k * neg.transpose();
    let b = subv(&acc.score, terms) - &k * subv(&acc.score, nuisance);
    // Rank test in units of the term's own information.
    let e = terms.len();
    let d: Vec<f64> =
        terms.iter().map(|&t| if acc.normal[(t, t)] > 0.0 { 1.0 / acc.normal[(t, t)].sqrt() } else { 0.0 }).collect();
    let scaled = DMatrix::from_fn(e, e, |i, j| s[(i, j)] * d[i] * d[j]);
    let eig = scaled.symmetric_eigen();
    let mut sinv = DMatrix::zeros(e, e);
    let mut unseen = 0;
    for (q, &l) in eig.eigenvalues.iter().enumerate() {
        if l > UNSEEN {
            let v = eig.eigenvectors.column(q);
            sinv.ger(1.0 / l, &v, &v, 1.0);
        } else {
            unseen += 1;
        }
    }
    let sinv = DMatrix::from_fn(e, e, |i, j| sinv[(i, j)] * d[i] * d[j]);
    let theta = &sinv * &b;
    // L = [-K, I] over (nuisance, terms).
    let mut all: Vec<usize> = nuisance.to_vec();
    all.extend_from_slice(terms);
    let mut l = DMatrix::zeros(e, all.len());
    l.view_mut((0, 0), (e, nuisance.len())).copy_from(&(-&k));
    for i in 0..e {
        l[(i, nuisance.len() + i)] = 1.0;
    }
    let nuisance_change = &pg * (subv(&acc.score, nuisance) - sub(&acc.normal, nuisance, terms) * &theta);
    // The model blocks' information, scaled by how much the extended model lowers their weighted
    // sum of squares: their weights carry the baseline's variance factor, inflated by any signal
    // of the term itself (never below the noise: the factor times this stays at least 1).
    let mut x_all = DVector::zeros(all.len());
    x_all.rows_mut(0, nuisance.len()).copy_from(&nuisance_change);
    x_all.rows_mut(nuisance.len(), e).copy_from(&theta);
    let mn = sub(&acc.model_normal, &all, &all);
    let model_ss_after =
        acc.model_ss - 2.0 * x_all.dot(&subv(&acc.model_score, &all)) + (x_all.transpose() * &mn * &x_all)[(0, 0)];
    let lowered = if acc.model_ss > 0.0 {
        (model_ss_after / acc.model_ss).clamp(1.0 / acc.variance_factor.max(1.0), 1.0)
    } else {
        1.0
    };
    let meat_all = sub(&acc.meat, &all, &all) + mn * lowered;
    // The bread: with weights at an M-estimate's fixed point, the sensitivity of its estimating
    // equations (rows beyond the clip count nothing in it); otherwise the normal matrix above.
    let (sinv_b, l) = match &acc.bread {
        Some(bread) => {
            let (pg_b, _) = symmetric_pinv(&sub(bread, nuisance, nuisance), 1e-11);
            let k_b = sub(bread, terms, nuisance) * &pg_b;
            let s_b = sub(bread, terms, terms) - &k_b * sub(bread, nuisance, terms);
            let mut l_b = l;
            l_b.view_mut((0, 0), (e, nuisance.len())).copy_from(&(-&k_b));
            (seen_inverse(&s_b, &eig, &d), l_b)
        }
        None => (sinv.clone(), l),
    };
    let meat = &l * meat_all * l.transpose();
    let robust = &sinv_b * meat * &sinv_b;
    TermFit {
        value: theta.iter().copied().collect(),
        sigma_model: (0..e).map(|i| sinv[(i, i)].max(0.0).sqrt()).collect(),
        sigma_robust: (0..e).map(|i| robust[(i, i)].max(0.0).sqrt()).collect(),
        covariance_robust: robust,
        unseen,
        nuisance_change,
    }
}

/// The inverse of `s` on the directions the rank test saw (`eig`: the eigen-decomposition of the
/// test's Schur complement scaled by `d`; eigenvalues above [`UNSEEN`]), in the original units.
fn seen_inverse(s: &DMatrix<f64>, eig: &nalgebra::SymmetricEigen<f64, nalgebra::Dyn>, d: &[f64]) -> DMatrix<f64> {
    let e = d.len();
    let seen: Vec<usize> = (0..e).filter(|&q| eig.eigenvalues[q] > UNSEEN).collect();
    let v = DMatrix::from_fn(e, seen.len(), |i, k| eig.eigenvectors[(i, seen[k])]);
    let scaled = DMatrix::from_fn(e, e, |i, j| s[(i, j)] * d[i] * d[j]);
    let (inner, _) = symmetric_pinv(&(v.transpose() * scaled * &v), 1e-12);
    let full = &v * inner * v.transpose();
    DMatrix::from_fn(e, e, |i, j| full[(i, j)] * d[i] * d[j])
}

/// The change of the nuisance `nuisance` that re-adjusting it alone would make (zero at a fit's
/// exact solution; a fit stopped at its tolerance, or weighted otherwise, leaves a little).
pub fn nuisance_step(acc: &Accumulated, nuisance: &[usize]) -> DVector<f64> {
    let (pg, _) = symmetric_pinv(&sub(&acc.normal, nuisance, nuisance), 1e-11);
    pg * subv(&acc.score, nuisance)
}

/// The weighted residual sum of squares of `acc` after the global nuisance `nuisance` is
/// re-adjusted with the terms `terms` held at `theta` (`theta` empty: the terms left out),
/// the re-adjustment taken from `adjust` (the accumulation of every phase, so that one phase's
/// sum is the part of the whole's solution).
pub fn ss_with(acc: &Accumulated, adjust: &Accumulated, nuisance: &[usize], terms: &[usize], theta: &[f64]) -> f64 {
    let (pg, _) = symmetric_pinv(&sub(&adjust.normal, nuisance, nuisance), 1e-11);
    let th = DVector::from_column_slice(theta);
    let mut rhs = subv(&adjust.score, nuisance);
    if !terms.is_empty() {
        rhs -= sub(&adjust.normal, nuisance, terms) * &th;
    }
    let dg = pg * rhs;
    let mut all: Vec<usize> = nuisance.to_vec();
    let mut x: Vec<f64> = dg.iter().copied().collect();
    if !terms.is_empty() {
        all.extend_from_slice(terms);
        x.extend_from_slice(theta);
    }
    let x = DVector::from_vec(x);
    acc.ss - 2.0 * x.dot(&subv(&acc.score, &all)) + (x.transpose() * sub(&acc.normal, &all, &all) * &x)[(0, 0)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two blocks of three rows, one local unknown each (an offset), a nuisance column and a term.
    fn two_blocks(factor: Option<[f64; 3]>) -> Accumulated {
        let mut acc = Accumulated::zeros(2);
        for (b, r) in [[0.3, -0.1, 0.5], [-0.2, 0.4, 0.1]].iter().enumerate() {
            let block = Block {
                local: DMatrix::from_element(3, 1, 1.0),
                columns: DMatrix::from_row_slice(3, 2, &[1.0, 0.5, 2.0, -1.0 + b as f64, 0.5, 2.0]),
                residual: DVector::from_column_slice(r),
                weight: DVector::from_column_slice(&[1.0, 2.0, 1.0]),
                projected_factor: factor.map(|f| DVector::from_column_slice(&f)),
            };
            acc.add(&block, Spread::Sandwich);
        }
        acc
    }

    #[test]
    fn a_bread_equal_to_the_normal_changes_nothing_and_twice_it_halves_the_robust_sigma() {
        let acc = two_blocks(None);
        let plain = fit_terms(&acc, &[0], &[1]);
        let mut same = acc.clone();
        same.bread = Some(acc.normal.clone());
        let with = fit_terms(&same, &[0], &[1]);
        assert!((with.sigma_robust[0] - plain.sigma_robust[0]).abs() < 1e-14 * plain.sigma_robust[0]);
        assert_eq!(with.value, plain.value);
        // The sandwich B^-1 M B^-1: a bread twice as large halves the sigma; the value and the
        // model sigma are the normal matrix's.
        let mut twice = acc.clone();
        twice.bread = Some(&acc.normal * 2.0);
        let half = fit_terms(&twice, &[0], &[1]);
        assert!((half.sigma_robust[0] - plain.sigma_robust[0] / 2.0).abs() < 1e-14 * plain.sigma_robust[0]);
        assert_eq!(half.value, plain.value);
        assert_eq!(half.sigma_model, plain.sigma_model);
    }

    #[test]
    fn merging_takes_each_sides_bread_or_its_normal_before_the_merge() {
        // The merge once formed the bread after adding the normal matrices, which counted the side
        // with a bread twice: every robust sigma of the library read half its size on a clean
        // simulated recording with Gaussian noise.
        let statics = two_blocks(None);
        let mut dynamics = two_blocks(Some([1.0, 0.5, 0.0]));
        let bread = two_blocks(Some([1.0, 1.0, 0.0])).normal;
        dynamics.bread = Some(bread.clone());
        let mut total = statics.clone();
        total.merge(&dynamics);
        let expected = &statics.normal + &bread;
        assert!((total.bread_normal() - expected).abs().max() < 1e-15);
        assert!((&total.normal - (&statics.normal + &dynamics.normal)).abs().max() < 1e-15);
        // The projected factor weights the rows after the local elimination: a factor of 1 is no
        // factor at all.
        assert_eq!(two_blocks(Some([1.0; 3])).normal, two_blocks(None).normal);
    }
}
