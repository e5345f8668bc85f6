//! The parameter errors each compensation navigates with, as LinCov models them: their mean and
//! covariance in the layout's parameter vector (SI).
//!
//! - `nominal`: `x_nominal - x_true`, with `x_true` from the error distributions (mean and
//!   variance of each; a uniform one by its mean and `half_width^2 / 3`);
//! - `estimated`: `x_estimated - x_true ~ N(0, F(x_true)^-1)`, `F` the schedule's Fisher
//!   information at the true errors for the cell's white noise, with the fixture's tilts
//!   marginalised under their prior (`calib::pose::marginal_fisher`). The part of that
//!   covariance the fixture adds, `F^-1 - F_perfect^-1` (positive semi-definite: marginalising
//!   only removes information), is kept apart for the error budget.

use nalgebra::allocator::Allocator;
use nalgebra::{DMatrix, DVector, DefaultAllocator, Dim, OMatrix, SMatrix, SymmetricEigen};

use crate::calib::fisher::{NULL_TOLERANCE, Targets, fisher_block, fisher_information};
use crate::calib::params::{Layout, PER_ACCEL, StepMotion};
use crate::calib::pose::marginal_fisher;
use crate::mc::Cell;
use crate::rng::trial_rng;
use crate::sensor::params::ArrayParams;
use rand::RngExt;
use rayon::prelude::*;

/// Salt of the stream that draws the truths of a mixture when there are too many varying
/// parameters for the Sobol sequence.
const TRUTH_SALT: u64 = 0x6c69_6e63_6f76_7472;

/// The centre of the error distributions (means, fixed values), layout form: the reference the
/// navigation is linearised about.
pub fn reference(cell: &Cell) -> DVector<f64> {
    cell.errors.at(&cell.layout, |_| None)
}

/// What nominal compensation assumes, in layout form (the nominal scale factors, every other
/// error 0).
pub fn nominal_parameters(cell: &Cell) -> DVector<f64> {
    let nominal = ArrayParams::nominal_with_scale_factors(&cell.array, &cell.errors.nominal_scale_factor);
    // The nominal geometry converts to either form exactly.
    cell.layout.pack(&nominal).unwrap_or_else(|_| DVector::zeros(cell.layout.len()))
}

/// The nominal compensation's parameter error `x_nominal - x_true`: mean and variance of each
/// parameter (independent).
pub fn nominal_errors(cell: &Cell) -> (DVector<f64>, DVector<f64>) {
    let e = &cell.errors;
    let mean = nominal_parameters(cell) - reference(cell);
    let mut variance = DVector::zeros(cell.layout.len());
    for j in 0..cell.array.len() {
        let o = PER_ACCEL * j;
        let sd = [
            e.nominal_scale_factor[j] * e.scale_factor_rel.sigma(j),
            e.bias_m_s2.sigma(j),
            e.misalignment_rad.sigma(j),
            e.misalignment_rad.sigma(j),
            e.location_m.sigma(j),
            e.location_m.sigma(j),
            e.location_m.sigma(j),
        ];
        for (a, s) in sd.iter().enumerate() {
            variance[o + a] = s * s;
        }
    }
    (mean, variance)
}

/// The truths a mixture is drawn over: `count` points of the varying parameters'
/// distributions (Owen-scrambled Sobol points through each distribution's quantile function,
/// up to 256 varying parameters; independent draws beyond), or the reference alone when no
/// parameter varies.
pub fn truths(cell: &Cell, seed: u64, count: usize) -> Vec<DVector<f64>> {
    let varying = cell.errors.varying(&cell.layout);
    if varying.is_empty() {
        return vec![reference(cell)];
    }
    let scramble = (seed & 0xffff_ffff) as u32 ^ 0x6c63_7674;
    // Each parameter's place among the varying ones.
    let mut place = vec![None; cell.layout.len()];
    for (k, &i) in varying.iter().enumerate() {
        place[i] = Some(k);
    }
    (0..count)
        .into_par_iter()
        .map(|m| {
            let u: Vec<f64> = if varying.len() <= 256 {
                (0..varying.len()).map(|d| sobol_burley::sample(m as u32, d as u32, scramble) as f64).collect()
            } else {
                let mut rng = trial_rng(seed ^ TRUTH_SALT, m as u64);
                (0..varying.len()).map(|_| rng.random::<f64>()).collect()
            };
            cell.errors.at(&cell.layout, |i| place[i].map(|k: usize| u[k].clamp(1e-9, 1.0 - 1e-9)))
        })
        .collect()
}

/// The estimated compensation's parameter-error covariance at one truth.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// `F^-1` with the fixture's tilts marginalised (the pseudo-inverse on the identifiable part).
    pub covariance: DMatrix<f64>,
    /// The part of `covariance` the fixture's prior adds (empty, 0 x 0, for a perfect fixture:
    /// it adds nothing).
    pub fixture: DMatrix<f64>,
    /// Parameter-space directions the schedule cannot identify (unit length in target units,
    /// mapped back to SI), with the parameters that share in them.
    pub null: Vec<(DVector<f64>, Vec<usize>)>,
}

/// The Cramer-Rao covariance of `cell`'s schedule at truth `x` for white noise of density
/// `density_m_s2_per_sqrt_hz` (see the module docs), with its null directions.
pub fn calibration(cell: &Cell, x: &DVector<f64>, density_m_s2_per_sqrt_hz: f64) -> Calibration {
    calibration_with(cell, x, density_m_s2_per_sqrt_hz, true)
}

/// [`calibration`]; without `find_null`, a positive definite information is inverted by Cholesky
/// (the eigen-decomposition only where that fails), for the many truths of a mixture.
pub fn calibration_with(cell: &Cell, x: &DVector<f64>, density_m_s2_per_sqrt_hz: f64, find_null: bool) -> Calibration {
    let p = cell.layout.len();
    if density_m_s2_per_sqrt_hz <= 0.0 {
        // Noise-free: every identifiable parameter is estimated exactly; the null directions do not
        // depend on the noise's scale.
        let null = if find_null { calibration_with(cell, x, 1.0, true).null } else { vec![] };
        let q = if cell.calibration.pose.is_perfect() { 0 } else { p };
        return Calibration { covariance: DMatrix::zeros(p, p), fixture: DMatrix::zeros(q, q), null };
    }
    let g = cell.calibration.gravity_m_s2;
    let pose = &cell.calibration.pose;
    let fim = marginal_fisher(&cell.layout, x, &cell.schedule, g, density_m_s2_per_sqrt_hz, pose);
    let invert = |fim: &DMatrix<f64>, coupled: bool| match (find_null, cholesky_inverse(fim, coupled)) {
        (false, Some(inv)) => (inv, vec![]),
        _ => pseudo_inverse(&cell.layout, x, fim, coupled),
    };
    let (covariance, null) = invert(&fim, !pose.is_perfect());
    let fixture = if pose.is_perfect() {
        DMatrix::zeros(0, 0)
    } else {
        let perfect = fisher_information(&cell.layout, x, &cell.schedule, g, density_m_s2_per_sqrt_hz);
        let (perfect, _) = invert(&perfect, false);
        let d = &covariance - perfect;
        (&d + d.transpose()) * 0.5
    };
    Calibration { covariance, fixture, null }
}

/// The inverse of a positive definite Fisher information by Cholesky (block by block unless
/// `coupled`), after scaling to unit diagonal; `None` where a block is not positive definite or
/// is numerically singular (its scaled pivots below 1e-12 of the largest).
fn cholesky_inverse(fim: &DMatrix<f64>, coupled: bool) -> Option<DMatrix<f64>> {
    let p = fim.nrows();
    let mut out = DMatrix::zeros(p, p);
    if coupled {
        let d: Vec<f64> = (0..p).map(|i| fim[(i, i)]).collect();
        let scaled = DMatrix::from_fn(p, p, |r, c| fim[(r, c)] / (d[r] * d[c]).sqrt());
        let inv = scaled_cholesky_inverse(scaled, &d)?;
        for c in 0..p {
            for r in 0..p {
                out[(r, c)] = inv[(r, c)] / (d[r] * d[c]).sqrt();
            }
        }
        return Some(out);
    }
    // ParamBlock by block at a fixed size (the same arithmetic, without the heap).
    for o in (0..p).step_by(PER_ACCEL) {
        let inv = invert_block(&ParamBlock::from_fn(|r, c| fim[(o + r, o + c)]))?;
        for c in 0..PER_ACCEL {
            for r in 0..PER_ACCEL {
                out[(o + r, o + c)] = inv[(r, c)];
            }
        }
    }
    Some(out)
}

/// One accelerometer's `PER_ACCEL x PER_ACCEL` block of a parameter covariance or information.
pub type ParamBlock = SMatrix<f64, PER_ACCEL, PER_ACCEL>;

/// The inverse of one accelerometer's block of a positive definite information by Cholesky, after
/// scaling to unit diagonal (`None` as [`scaled_cholesky_inverse`]), written out at its fixed
/// size: the factor `L`, its inverse `M`, then `M^T M` (each truth of a mixture inverts one such
/// block per accelerometer; nalgebra's general inverse took 7.5% of a quickstart cell).
#[allow(clippy::needless_range_loop)] // triangular index ranges read as the algebra does
fn invert_block(fim: &ParamBlock) -> Option<ParamBlock> {
    const N: usize = PER_ACCEL;
    let d: [f64; N] = std::array::from_fn(|i| fim[(i, i)]);
    if d.iter().any(|v| v.is_nan() || *v <= 0.0) {
        return None;
    }
    let root: [f64; N] = std::array::from_fn(|i| d[i].sqrt());
    let mut l = [[0.0_f64; N]; N];
    for j in 0..N {
        let mut pivot = fim[(j, j)] / (root[j] * root[j]);
        for k in 0..j {
            pivot -= l[j][k] * l[j][k];
        }
        if pivot.is_nan() || pivot <= 0.0 {
            return None;
        }
        let ljj = pivot.sqrt();
        l[j][j] = ljj;
        for i in j + 1..N {
            let mut v = fim[(i, j)] / (root[i] * root[j]);
            for k in 0..j {
                v -= l[i][k] * l[j][k];
            }
            l[i][j] = v / ljj;
        }
    }
    let (lo, hi) = (0..N).map(|i| l[i][i]).fold((f64::INFINITY, 0.0_f64), |a, v| (a.0.min(v), a.1.max(v)));
    if lo * lo < 1e-12 * hi * hi {
        return None;
    }
    let mut m = [[0.0_f64; N]; N];
    for j in 0..N {
        m[j][j] = 1.0 / l[j][j];
        for i in j + 1..N {
            let mut v = 0.0;
            for k in j..i {
                v -= l[i][k] * m[k][j];
            }
            m[i][j] = v / l[i][i];
        }
    }
    let mut out = ParamBlock::zeros();
    for c in 0..N {
        for r in c..N {
            let mut v = 0.0;
            for k in r..N {
                v += m[k][r] * m[k][c];
            }
            let v = v / (root[r] * root[c]);
            out[(r, c)] = v;
            out[(c, r)] = v;
        }
    }
    Some(out)
}

/// [`calibration_with`] without its null search, for a perfect fixture: the covariance as one
/// block per accelerometer, on the stack (the same arithmetic, so the same bits). `motions` are
/// the schedule's ([`crate::calib::fisher::step_motions`]). `None` without noise, with a fixture error, or where a
/// block is not positive definite: [`calibration_with`] then finds the null directions.
pub fn block_covariances(
    cell: &Cell,
    x: &DVector<f64>,
    density_m_s2_per_sqrt_hz: f64,
    motions: &[(StepMotion, f64)],
) -> Option<Vec<ParamBlock>> {
    if density_m_s2_per_sqrt_hz <= 0.0 || !cell.calibration.pose.is_perfect() {
        return None;
    }
    (0..cell.array.len())
        .map(|j| {
            let o = PER_ACCEL * j;
            let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| x[o + a]);
            let f = fisher_block(&cell.layout, j, &xj, motions, density_m_s2_per_sqrt_hz);
            invert_block(&ParamBlock::from_fn(|r, c| f[r][c]))
        })
        .collect()
}

/// The inverse of `scaled` (a block of the information scaled to unit diagonal by `d`, its
/// diagonal before) by Cholesky; `None` where `d` is not positive, the block not positive
/// definite or numerically singular (its pivots below 1e-12 of the largest).
fn scaled_cholesky_inverse<D>(scaled: OMatrix<f64, D, D>, d: &[f64]) -> Option<OMatrix<f64, D, D>>
where
    D: Dim,
    DefaultAllocator: Allocator<D, D>,
{
    if d.iter().any(|v| v.is_nan() || *v <= 0.0) {
        return None;
    }
    let chol = scaled.cholesky()?;
    let l = chol.l_dirty();
    let n = d.len();
    let (lo, hi) = (0..n).map(|i| l[(i, i)]).fold((f64::INFINITY, 0.0_f64), |a, v| (a.0.min(v), a.1.max(v)));
    if lo * lo < 1e-12 * hi * hi {
        return None;
    }
    Some(chol.inverse())
}

/// A null direction of a Fisher information and the parameters it reaches.
pub type NullDirection = (DVector<f64>, Vec<usize>);

/// The pseudo-inverse of a Fisher information, in target-scaled units (so that parameters of
/// different units compare), and its null directions. ParamBlock by block (7 x 7 per accelerometer)
/// unless `coupled`.
pub fn pseudo_inverse(
    layout: &Layout,
    x: &DVector<f64>,
    fim: &DMatrix<f64>,
    coupled: bool,
) -> (DMatrix<f64>, Vec<NullDirection>) {
    let p = layout.len();
    let target = Targets::default().si(layout, x);
    let blocks: Vec<Vec<usize>> = if coupled {
        vec![(0..p).collect()]
    } else {
        (0..layout.array().len()).map(|j| (PER_ACCEL * j..PER_ACCEL * (j + 1)).collect()).collect()
    };
    let mut cov = DMatrix::zeros(p, p);
    let mut null = Vec::new();
    for block in blocks {
        let n = block.len();
        let scaled = DMatrix::from_fn(n, n, |a, b| fim[(block[a], block[b])] * target[block[a]] * target[block[b]]);
        // A well-conditioned block inverts by Cholesky; otherwise by eigenvalues, keeping the
        // identifiable part.
        let sym = (&scaled + scaled.transpose()) * 0.5;
        let eig = SymmetricEigen::new(sym);
        let max = eig.eigenvalues.max().max(f64::MIN_POSITIVE);
        for (k, &lambda) in eig.eigenvalues.iter().enumerate() {
            let v = eig.eigenvectors.column(k);
            if lambda <= NULL_TOLERANCE * max {
                let mut dir = DVector::zeros(p);
                let mut who = Vec::new();
                for (a, &i) in block.iter().enumerate() {
                    dir[i] = v[a] * target[i];
                    if v[a].abs() > 1e-6 {
                        who.push(i);
                    }
                }
                null.push((dir, who));
                continue;
            }
            for (a, &i) in block.iter().enumerate() {
                for (b, &j) in block.iter().enumerate() {
                    cov[(i, j)] += v[a] * v[b] / lambda * target[i] * target[j];
                }
            }
        }
    }
    (cov, null)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// The written-out inverse against nalgebra's LU inverse (an independent route) on random
    /// positive definite blocks scaled over twelve decades, and `None` where nalgebra's Cholesky
    /// fails or the block is singular.
    #[test]
    fn the_written_out_block_inverse_matches_lu() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let a = ParamBlock::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let scale = ParamBlock::from_diagonal(&nalgebra::SVector::<f64, PER_ACCEL>::from_fn(|_, _| {
                10f64.powf(rng.random_range(-6.0..6.0))
            }));
            let fim = scale * (a * a.transpose() + ParamBlock::identity() * 1e-3) * scale;
            let ours = invert_block(&fim).expect("positive definite");
            let lu = fim.lu().try_inverse().expect("invertible");
            for r in 0..PER_ACCEL {
                for c in 0..PER_ACCEL {
                    let tol = 1e-9 * (lu[(r, r)] * lu[(c, c)]).sqrt();
                    assert!((ours[(r, c)] - lu[(r, c)]).abs() <= tol, "{r} {c}: {} {}", ours[(r, c)], lu[(r, c)]);
                }
            }
        }
        let mut singular = ParamBlock::identity();
        singular[(3, 3)] = 0.0;
        assert!(invert_block(&singular).is_none());
        let mut indefinite = ParamBlock::identity();
        indefinite[(0, 1)] = 2.0;
        indefinite[(1, 0)] = 2.0;
        assert!(invert_block(&indefinite).is_none());
        let mut nearly = ParamBlock::identity();
        nearly[(0, 1)] = 1.0 - 1e-14;
        nearly[(1, 0)] = 1.0 - 1e-14;
        assert!(invert_block(&nearly).is_none(), "a pivot below 1e-12 of the largest");
    }
}
