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
        }
    }

    /// Adds one block, its spread counted as `spread` says.
    pub fn add(&mut self, b: &Block, spread: Spread) {
        let sw = b.weight.map(|w| w.max(0.0).sqrt());
        let scale = |m: &DMatrix<f64>| {
            let mut m = m.clone();
            for (i, mut row) in m.row_iter_mut().enumerate() {
                row *= sw[i];
            }
            m
        };
        let mut x = scale(&b.columns);
        let mut y = b.residual.component_mul(&sw);
        if b.local.ncols() > 0 {
            // Project the weighted rows off the weighted local columns (thin QR is not needed:
            // the local columns are few and well conditioned after scaling).
            let l = scale(&b.local);
            let h = l.tr_mul(&l);
            let (inv, rank) = symmetric_pinv(&h, 1e-12);
            let px = &l * (&inv * l.tr_mul(&x));
            let py = &l * (&inv * l.tr_mul(&y));
            x -= px;
            y -= py;
            self.local += rank;
        }
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
    fit_terms_given(acc, &nuisance_inverse(acc, nuisance), nuisance, terms)
}

/// The pseudo-inverse of the nuisance's normal matrix, for [`fit_terms_given`] (many terms
/// fitted against one nuisance).
pub fn nuisance_inverse(acc: &Accumulated, nuisance: &[usize]) -> DMatrix<f64> {
    symmetric_pinv(&sub(&acc.normal, nuisance, nuisance), 1e-11).0
}

/// [`fit_terms`] with the nuisance's pseudo-inverse `pg` formed once ([`nuisance_inverse`]).
pub fn fit_terms_given(acc: &Accumulated, pg: &DMatrix<f64>, nuisance: &[usize], terms: &[usize]) -> TermFit {
    let neg = sub(&acc.normal, terms, nuisance);
    let k = &neg * pg;
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
    let nuisance_change = pg * (subv(&acc.score, nuisance) - sub(&acc.normal, nuisance, terms) * &theta);
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
    let meat = &l * meat_all * l.transpose();
    let robust = &sinv * meat * &sinv;
    TermFit {
        value: theta.iter().copied().collect(),
        sigma_model: (0..e).map(|i| sinv[(i, i)].max(0.0).sqrt()).collect(),
        sigma_robust: (0..e).map(|i| robust[(i, i)].max(0.0).sqrt()).collect(),
        covariance_robust: robust,
        unseen,
        nuisance_change,
    }
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
