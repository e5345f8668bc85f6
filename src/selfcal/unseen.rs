//! The parameter combinations a calibration cannot see: the Fisher information's null directions
//! beyond the gauge.
//!
//! The gauge (`selfcal::model::Gauge`) is a choice, fixed by constraints `C x = 0`. Any further
//! null direction `v` of the information (`H v = 0` with `C v = 0`) is a combination of parameters
//! that the data leave free: its value is not measured, and every parameter with a share in it has
//! no value and no sigma. [`unseen`] finds them: the information is scaled by its diagonal, its
//! eigenvectors below [`NULL_RELATIVE`] of the largest eigenvalue span its null space, and the part
//! of that space the gauge's rows do not fix is the unseen space. Its basis is reduced (Gauss-Jordan
//! with full pivoting) so that each combination leads with one parameter of its own, as `gfcal
//! identify` lists weak combinations. The estimator holds the unseen combinations where they start
//! (extra constraint rows beside the gauge's) and calibrates everything else.

#![allow(clippy::neg_cmp_op_on_partial_ord)]

use nalgebra::{DMatrix, SymmetricEigen};

use super::model::{NAMES, PER_ACCEL};

/// Scaled eigenvalue, relative to the largest, below which a direction is null (the count of
/// `Fit::null_directions`).
pub const NULL_RELATIVE: f64 = 1e-9;

/// Share above which a parameter takes part in the unseen space: the norm of its row of the
/// orthonormal basis in scaled coordinates (1 when the parameter alone is unseen). On real
/// recordings the null spectrum runs on continuously to the threshold (gyroscope-free, the
/// four top IMUs of the MIMU4444: scaled eigenvalues from 1e-16 to 1e-9 and on), so the null
/// eigenvectors mix every parameter a little; a parameter with less than 1% of the unseen space
/// keeps its value and its sigma (the unseen combinations held where the fit starts).
pub const SHARE_TOLERANCE: f64 = 1e-2;

/// Weight below which a component is left out of a printed combination.
pub const PRINT_WEIGHT: f64 = 0.05;

/// One unseen combination: `(parameter index, weight)` of the unit combination with every
/// parameter scaled by the square root of its own information (the diagonal), largest first.
/// Indices run over the accelerometer parameters (`PER_ACCEL` per accelerometer, in
/// [`NAMES`] order) and then two pose tangents per static pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Combination {
    pub components: Vec<(usize, f64)>,
}

/// What a calibration cannot see.
#[derive(Debug, Clone, PartialEq)]
pub struct Unseen {
    /// Basis of the unseen space in the parameters' own units, one column per combination
    /// (zero on inactive parameters).
    pub basis: DMatrix<f64>,
    /// Per parameter: it has a share in an unseen combination.
    pub parameters: Vec<bool>,
    pub combinations: Vec<Combination>,
    /// The weakest combinations the data do see (up to 3, weakest first), with their scaled
    /// eigenvalue relative to the largest: how close the calibration is to not seeing them.
    pub weakest: Vec<(f64, Combination)>,
}

impl Unseen {
    pub fn is_empty(&self) -> bool {
        self.combinations.is_empty()
    }
    /// The unseen combinations as constraint rows (one per combination).
    pub fn rows(&self) -> DMatrix<f64> {
        self.basis.transpose()
    }
}

/// The name of parameter `index` of an array of `n` accelerometers: `a3.dz` or `pose2.tangent_1`.
pub fn name(index: usize, n: usize) -> String {
    if index < PER_ACCEL * n {
        format!("a{}.{}", index / PER_ACCEL + 1, NAMES[index % PER_ACCEL])
    } else {
        let k = index - PER_ACCEL * n;
        format!("pose{}.tangent_{}", k / 2 + 1, k % 2 + 1)
    }
}

/// A combination as text: `0.707 a1.dz - 0.707 a4.dz`.
pub fn describe(c: &Combination, n: usize) -> String {
    let mut s = String::new();
    for (k, (i, w)) in c.components.iter().enumerate() {
        let sign = if *w < 0.0 {
            "- "
        } else if k > 0 {
            "+ "
        } else {
            ""
        };
        if k > 0 {
            s.push(' ');
        }
        s.push_str(&format!("{sign}{:.3} {}", w.abs(), name(*i, n)));
    }
    s
}

/// The unseen space of the information `h` given the gauge's rows `constraints` (see the module
/// docs); `active` marks the parameters estimated at all. The information is scaled by its
/// diagonal and restricted to the directions the gauge leaves free (`C v = 0`); its eigenvectors
/// there below [`NULL_RELATIVE`] of the largest eigenvalue are the unseen combinations, and the
/// next few are the weakest seen ones ([`Unseen::weakest`]).
pub fn unseen(h: &DMatrix<f64>, constraints: &DMatrix<f64>, active: &[bool]) -> Unseen {
    let dim = h.nrows();
    let idx: Vec<usize> = (0..dim).filter(|&i| active[i]).collect();
    let m = idx.len();
    let empty = Unseen {
        basis: DMatrix::zeros(dim, 0),
        parameters: vec![false; dim],
        combinations: Vec::new(),
        weakest: Vec::new(),
    };
    if m == 0 {
        return empty;
    }
    let scale: Vec<f64> = idx.iter().map(|&i| h[(i, i)].max(1e-300).sqrt()).collect();
    let s = DMatrix::from_fn(m, m, |a, b| h[(idx[a], idx[b])] / (scale[a] * scale[b]));
    let max = s.symmetric_eigenvalues().iter().cloned().fold(0.0, f64::max);
    // The directions the gauge leaves free, in scaled coordinates: C D^-1 v = 0.
    let c = DMatrix::from_fn(constraints.nrows(), m, |r, a| constraints[(r, idx[a])] / scale[a]);
    let q = if c.nrows() == 0 {
        DMatrix::identity(m, m)
    } else {
        let ce = SymmetricEigen::new(c.transpose() * &c);
        let cmax = ce.eigenvalues.iter().cloned().fold(0.0, f64::max);
        let free: Vec<usize> = (0..m).filter(|&k| !(ce.eigenvalues[k] > 1e-12 * cmax)).collect();
        DMatrix::from_fn(m, free.len(), |a, k| ce.eigenvectors[(a, free[k])])
    };
    if q.ncols() == 0 {
        return empty;
    }
    let reduced = SymmetricEigen::new(q.transpose() * &s * &q);
    let mut order: Vec<usize> = (0..q.ncols()).collect();
    order.sort_by(|&a, &b| reduced.eigenvalues[a].total_cmp(&reduced.eigenvalues[b]));
    let null: Vec<usize> = order.iter().copied().filter(|&k| reduced.eigenvalues[k] < NULL_RELATIVE * max).collect();
    let direction = |k: usize| &q * reduced.eigenvectors.column(k);
    let weakest: Vec<(f64, Combination)> = order
        .iter()
        .copied()
        .filter(|k| !null.contains(k))
        .take(3)
        .map(|k| (reduced.eigenvalues[k] / max, combination(direction(k).as_slice(), &idx)))
        .collect();
    if null.is_empty() {
        return Unseen { weakest, ..empty };
    }
    let b_scaled = DMatrix::from_fn(m, null.len(), |a, k| direction(null[k])[a]); // orthonormal columns
    let r = null.len();
    let mut parameters = vec![false; dim];
    for (a, &i) in idx.iter().enumerate() {
        parameters[i] = b_scaled.row(a).norm() > SHARE_TOLERANCE;
    }
    let reduced_rows = reduce(&b_scaled.transpose());
    let mut basis = DMatrix::zeros(dim, r);
    let mut combinations = Vec::with_capacity(r);
    for k in 0..r {
        let row: Vec<f64> = reduced_rows.row(k).iter().copied().collect();
        let norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        combinations.push(combination(&row, &idx));
        for a in 0..m {
            basis[(idx[a], k)] = row[a] / norm / scale[a];
        }
    }
    Unseen { basis, parameters, combinations, weakest }
}

/// A direction over the active parameters `idx` (scaled coordinates) as a unit combination.
fn combination(v: &[f64], idx: &[usize]) -> Combination {
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-300);
    let mut components: Vec<(usize, f64)> =
        (0..v.len()).filter(|&a| (v[a] / norm).abs() >= PRINT_WEIGHT).map(|a| (idx[a], v[a] / norm)).collect();
    components.sort_by(|p, q| q.1.abs().total_cmp(&p.1.abs()).then(p.0.cmp(&q.0)));
    if components.first().is_some_and(|c| c.1 < 0.0) {
        components.iter_mut().for_each(|c| c.1 = -c.1);
    }
    Combination { components }
}

/// Gauss-Jordan elimination with full pivoting of the rows of `a` (r x m, rank r): each row ends
/// with a pivot column of its own, 1 there and 0 in the other rows.
fn reduce(a: &DMatrix<f64>) -> DMatrix<f64> {
    let mut a = a.clone();
    let (r, m) = a.shape();
    let mut used = vec![false; m];
    for k in 0..r {
        // The largest remaining entry among rows k.. and unused columns.
        let mut best = (k, 0, -1.0);
        for i in k..r {
            for c in 0..m {
                if !used[c] && a[(i, c)].abs() > best.2 {
                    best = (i, c, a[(i, c)].abs());
                }
            }
        }
        let (pi, pc, pv) = best;
        if !(pv > 0.0) {
            break;
        }
        a.swap_rows(k, pi);
        used[pc] = true;
        let p = a[(k, pc)];
        for c in 0..m {
            a[(k, c)] /= p;
        }
        for i in 0..r {
            if i != k {
                let f = a[(i, pc)];
                if f != 0.0 {
                    for c in 0..m {
                        a[(i, c)] -= f * a[(k, c)];
                    }
                }
            }
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3-parameter information that sees only `x0 + x1` and `x2`, with no gauge: the unseen
    /// combination is `x0 - x1` (equal weights at equal scales), and x2 is identified.
    #[test]
    fn a_difference_the_information_does_not_see_is_found_and_x2_is_not_in_it() {
        let g = nalgebra::DVector::from_vec(vec![1.0, 1.0, 0.0]);
        let mut h = &g * g.transpose();
        h[(2, 2)] = 4.0;
        let u = unseen(&h, &DMatrix::zeros(0, 3), &[true; 3]);
        assert_eq!(u.combinations.len(), 1);
        assert_eq!(u.parameters, vec![true, true, false]);
        let c = &u.combinations[0].components;
        assert_eq!(c.len(), 2);
        assert!((c[0].1 - 0.5_f64.sqrt()).abs() < 1e-12 && (c[1].1 + 0.5_f64.sqrt()).abs() < 1e-12, "{c:?}");
        // H times the basis is zero.
        assert!((&h * &u.basis).norm() < 1e-12);
        // The same null direction fixed by a gauge row is not unseen.
        let gauge = DMatrix::from_row_slice(1, 3, &[1.0, 0.0, 0.0]);
        assert!(unseen(&h, &gauge, &[true; 3]).is_empty());
    }
}
