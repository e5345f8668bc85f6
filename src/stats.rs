//! Shared statistics: the tails of the chi-square and F distributions, the median, the pseudo-inverse of a
//! symmetric positive semi-definite matrix, and the Wald test built from them.
//!
//! Each tail returns `None` where the distribution does not exist (zero or non-finite degrees
//! of freedom); the caller says what that means for it (NaN in a table, 1.0 for "no evidence").

use nalgebra::{DMatrix, DVector};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};

/// `P(X > x)` for `X ~ chi^2(dof)`; `None` when `dof` is not a valid number of degrees of freedom.
pub fn chi2_sf(x: f64, dof: f64) -> Option<f64> {
    ChiSquared::new(dof).ok().map(|d| d.sf(x))
}

/// The `p`-quantile of `chi^2(dof)`; `None` when `dof` is not valid.
pub fn chi2_quantile(p: f64, dof: f64) -> Option<f64> {
    ChiSquared::new(dof).ok().map(|d| d.inverse_cdf(p))
}

/// `P(X > x)` for `X ~ F(df1, df2)`; `None` when the degrees of freedom are not valid.
pub fn f_sf(x: f64, df1: f64, df2: f64) -> Option<f64> {
    FisherSnedecor::new(df1, df2).ok().map(|d| d.sf(x))
}

/// The median of the finite values (the mean of the middle two for an even count); NaN where none
/// is finite.
pub fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

/// Pseudo-inverse of a symmetric positive semi-definite matrix, scaled by its diagonal first so
/// that columns of different units compare; eigenvalues below `tolerance` times the largest are
/// dropped. Returns the pseudo-inverse and the rank.
///
/// A column whose diagonal is below [`NEGLIGIBLE_DIAGONAL`] times the largest is taken as zero:
/// scaled by `1 / sqrt(h_ii)` its inverse's elements overflow. A dynamic sample turning at a rate
/// of almost exactly zero has rate columns near 1e-318 beside specific-force columns near 60, and
/// the pseudo-inverse of its block was infinite, which made a whole diagnosis's accumulation NaN
/// (every effect then read as unseen; found on a simulated clocked recording on 2026-12-01).
pub fn symmetric_pinv(h: &DMatrix<f64>, tolerance: f64) -> (DMatrix<f64>, usize) {
    let n = h.nrows();
    if n == 0 {
        return (DMatrix::zeros(0, 0), 0);
    }
    let largest_diagonal = (0..n).map(|i| h[(i, i)]).fold(0.0f64, f64::max);
    let floor = largest_diagonal * NEGLIGIBLE_DIAGONAL;
    // `floor` is never negative (the fold starts at 0), so this also leaves out non-positive diagonals.
    let d: Vec<f64> = (0..n).map(|i| if h[(i, i)] > floor { 1.0 / h[(i, i)].sqrt() } else { 0.0 }).collect();
    let scaled = DMatrix::from_fn(n, n, |i, j| h[(i, j)] * d[i] * d[j]);
    let eig = scaled.symmetric_eigen();
    let largest = eig.eigenvalues.iter().copied().fold(0.0f64, f64::max);
    let mut inv = DMatrix::zeros(n, n);
    let mut rank = 0;
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > tolerance * largest && l > 0.0 {
            let v = eig.eigenvectors.column(k);
            inv.ger(1.0 / l, &v, &v, 1.0);
            rank += 1;
        }
    }
    (DMatrix::from_fn(n, n, |i, j| inv[(i, j)] * d[i] * d[j]), rank)
}

/// A diagonal below this fraction of the largest is zero in [`symmetric_pinv`] (200 decades: no
/// physical column is that much smaller than another, and above it the scaled inverse stays
/// finite for any tolerance down to 1e-100).
pub const NEGLIGIBLE_DIAGONAL: f64 = 1e-200;

/// The p-value of a Wald test of `value` (zero mean) with covariance `cov`, on its rank.
pub fn wald_p(value: &[f64], cov: &DMatrix<f64>) -> f64 {
    match wald_statistic(value, cov) {
        Some((w, rank)) => chi2_sf(w, rank as f64).filter(|p| p.is_finite()).unwrap_or(1.0),
        None => 1.0,
    }
}

/// The Wald statistic of `value` (zero mean) with covariance `cov` and its degrees of freedom (the
/// covariance's rank); `None` where the rank is zero.
pub fn wald_statistic(value: &[f64], cov: &DMatrix<f64>) -> Option<(f64, usize)> {
    let (inv, rank) = symmetric_pinv(cov, 1e-10);
    if rank == 0 {
        return None;
    }
    let v = DVector::from_column_slice(value);
    Some(((v.transpose() * inv * &v)[(0, 0)], rank))
}

/// `ln P(X > x)` for `X ~ chi^2(dof)`: to compare statistics of different degrees of freedom where
/// their tails underflow (a p-value of 0 orders nothing). The tail itself where it is above 1e-300;
/// beyond, its leading asymptotic term `ln((x/2)^(dof/2 - 1) e^(-x/2) / Gamma(dof/2))`, whose
/// relative error there is below `dof / x` (x above about 1,300).
pub fn chi2_log_sf(x: f64, dof: f64) -> f64 {
    match chi2_sf(x, dof) {
        Some(p) if p > 1e-300 => p.ln(),
        _ => {
            let h = 0.5 * x.max(f64::MIN_POSITIVE);
            (0.5 * dof - 1.0) * h.ln() - h - statrs::function::gamma::ln_gamma(0.5 * dof)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_column_hundreds_of_decades_below_the_others_is_taken_as_zero() {
        // The block of a sample turning at almost zero rate: a well-scaled 2 x 2 part and a
        // subnormal third column. Its pseudo-inverse is the 2 x 2 inverse, the third row and
        // column zero, rank 2 (before: infinite elements).
        let mut h = DMatrix::from_row_slice(3, 3, &[60.0, 3.0, 0.0, 3.0, 2.0, 0.0, 0.0, 0.0, 4.66e-318]);
        h[(0, 2)] = 1e-160;
        h[(2, 0)] = 1e-160;
        let (inv, rank) = symmetric_pinv(&h, 1e-12);
        assert_eq!(rank, 2);
        let det = 60.0 * 2.0 - 9.0;
        let want = [[2.0 / det, -3.0 / det], [-3.0 / det, 60.0 / det]];
        for (i, row) in want.iter().enumerate() {
            for (j, w) in row.iter().enumerate() {
                assert!((inv[(i, j)] - w).abs() < 1e-14, "{i} {j}: {} against {w}", inv[(i, j)]);
            }
        }
        assert!((0..3).all(|k| inv[(2, k)] == 0.0 && inv[(k, 2)] == 0.0));
    }

    #[test]
    fn tails_match_closed_forms() {
        // chi^2(2) has the tail exp(-x/2); chi^2(1) at 3.841459 is the 5% point.
        for x in [0.1, 1.0, 4.0, 12.5] {
            let p = chi2_sf(x, 2.0).expect("dof 2");
            assert!((p - (-x / 2.0f64).exp()).abs() < 1e-12, "x {x}: {p}");
        }
        assert!((chi2_sf(3.841458820694124, 1.0).expect("dof 1") - 0.05).abs() < 1e-9);
        assert!((chi2_quantile(0.95, 1.0).expect("dof 1") - 3.841458820694124).abs() < 1e-6);
        assert!(chi2_sf(1.0, 0.0).is_none());
        // F(2, inf) -> chi^2(2)/2; F(1, 1) at 1 is 1/2 by symmetry.
        assert!((f_sf(1.0, 1.0, 1.0).expect("F(1,1)") - 0.5).abs() < 1e-12);
    }

    #[test]
    fn the_pseudo_inverse_inverts_the_seen_directions_and_counts_them() {
        // A rank-2 matrix in 3 dimensions, columns of very different scales.
        let a = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1e3, 1.0, 1e3]);
        let h = &a * a.transpose();
        let (p, rank) = symmetric_pinv(&h, 1e-12);
        assert_eq!(rank, 2);
        // Moore-Penrose: H P H = H.
        let hph = &h * &p * &h;
        assert!((hph - &h).norm() < 1e-9 * h.norm());
        let full = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let (inv, r) = symmetric_pinv(&full, 1e-12);
        assert_eq!(r, 2);
        assert!((inv * &full - DMatrix::identity(2, 2)).norm() < 1e-12);
    }

    #[test]
    fn the_wald_test_of_a_one_sigma_value_is_the_chi2_1_tail_at_1() {
        let cov = DMatrix::from_row_slice(1, 1, &[4.0]);
        let p = wald_p(&[2.0], &cov);
        assert!((p - 0.3173105078629141).abs() < 1e-9, "{p}");
        assert_eq!(wald_p(&[1.0], &DMatrix::zeros(1, 1)), 1.0);
    }

    #[test]
    fn the_log_tail_is_the_tail_s_log_and_its_asymptote_beyond() {
        for dof in [1.0, 2.0, 9.0] {
            // Where the tail is representable, its logarithm.
            let p = chi2_sf(100.0, dof).expect("tail");
            assert_eq!(chi2_log_sf(100.0, dof), p.ln());
            // The asymptote against the tail near the switch (x about 1,300-1,380), where both exist.
            for x in [1200.0, 1300.0] {
                let exact = chi2_sf(x, dof).expect("tail").ln();
                let h = 0.5 * x;
                let asymptote = (0.5 * dof - 1.0) * f64::ln(h) - h - statrs::function::gamma::ln_gamma(0.5 * dof);
                assert!(((asymptote - exact) / exact).abs() < dof / x, "{dof} {x}: {asymptote} {exact}");
            }
            // Beyond, finite and decreasing.
            assert!(chi2_log_sf(2000.0, dof).is_finite() && chi2_log_sf(2000.0, dof) < chi2_log_sf(1900.0, dof));
        }
    }
}
