//! The turn-on test: has a parameter refitted on a held-out recording changed from the fitting
//! recording's value by more than both recordings' uncertainties allow?
//!
//! A held-out recording B refits some of the baseline's parameters `r` (its biases, say) with
//! the others `c` carried over from the fitting recording A. Linearised at B's refit, with B's
//! pose angles eliminated, B's refit is `r_B = r_B* - N_rr^-1 N_rc dtheta_c + e_B`: the carried
//! parameters' errors `dtheta_c` move it through B's normal matrix `N` (baseline layout), and B's
//! own noise `e_B` has covariance `N_rr^-1`. The change `d = r_B - r_A` therefore has, under
//! "no change", the error `M dtheta_A + e_B` with `M = [-N_rr^-1 N_rc | -I]` (the `-I` on the
//! tested parameters' own columns), and the covariance
//!
//! `Cov_d = M Cov_A M' + (N_rr^-1)_tt`
//!
//! with `Cov_A` the fitting recording's covariance (in its gauge: B's static refit does not see
//! a gauge move, which the pose absorbs). The test is the Wald statistic `d' Cov_d^-1 d` against
//! chi-square with as many degrees of freedom as tested parameters.
//!
//! Why all of this: the diagonal alone (B's refit sigma and A's own sigma of the same
//! parameter, combined) leaves out how A's scale-factor, tilt and location errors move B's
//! refitted biases, and the 24 changes' correlations; 15 of 100 clean simulated pairs named a
//! turn-on bias with it.

use nalgebra::DMatrix;

use crate::stats::chi2_sf;

/// The change of the tested parameters and its test.
#[derive(Debug, Clone, PartialEq)]
pub struct ChangeTest {
    /// Refit on the held-out recording minus the fitting recording's value, per tested parameter.
    pub change: Vec<f64>,
    /// Square roots of `Cov_d`'s diagonal.
    pub sigma: Vec<f64>,
    /// `d' Cov_d^-1 d`.
    pub wald: f64,
    /// Its chi-square p-value; 1 when it cannot be computed (a singular `N_rr` or `Cov_d`, or a
    /// non-finite change), so that nothing is named on it.
    pub p_value: f64,
}

/// The test of `change` (the `tested` columns, a subset of `refit`, in that order) against
/// the held-out recording's static `normal` matrix (baseline layout, pose angles eliminated) and
/// the fitting recording's `fitted_covariance` (at least the baseline's columns; NaN entries in
/// columns that the held-out refit does not depend on are skipped).
pub fn change_test(
    normal: &DMatrix<f64>,
    refit: &[usize],
    tested: &[usize],
    change: Vec<f64>,
    fitted_covariance: &DMatrix<f64>,
) -> ChangeTest {
    let undecided =
        |change: Vec<f64>| ChangeTest { sigma: vec![f64::NAN; change.len()], change, wald: f64::NAN, p_value: 1.0 };
    let p = normal.nrows();
    let usable = p <= fitted_covariance.nrows()
        && p == normal.ncols()
        && change.len() == tested.len()
        && refit.iter().chain(tested).all(|&c| c < p)
        && tested.iter().all(|t| refit.contains(t));
    if !usable || change.iter().any(|c| !c.is_finite()) {
        return undecided(change);
    }
    let carried: Vec<usize> = (0..p).filter(|c| !refit.contains(c)).collect();
    let n_rr = normal.select_rows(refit).select_columns(refit);
    let n_rc = normal.select_rows(refit).select_columns(&carried);
    let Some(n_rr_inverse) = n_rr.cholesky().map(|c| c.inverse()) else {
        return undecided(change);
    };
    let sensitivity = -(&n_rr_inverse * n_rc);
    // M: one row per tested parameter, one column per baseline parameter.
    let t = tested.len();
    let mut m = DMatrix::zeros(t, p);
    let mut own = DMatrix::zeros(t, t);
    for (i, &col) in tested.iter().enumerate() {
        let r = refit.iter().position(|&c| c == col).unwrap_or(0);
        for (k, &c) in carried.iter().enumerate() {
            m[(i, c)] = sensitivity[(r, k)];
        }
        m[(i, col)] -= 1.0;
        for (i2, &col2) in tested.iter().enumerate() {
            let r2 = refit.iter().position(|&c| c == col2).unwrap_or(0);
            own[(i, i2)] = n_rr_inverse[(r, r2)];
        }
    }
    // Only the columns M uses: the fitting recording's covariance has NaN rows for what it could
    // not identify (locations without a rotation phase), which B's static refit does not see.
    let used: Vec<usize> = (0..p).filter(|&c| m.column(c).iter().any(|v| *v != 0.0)).collect();
    let m_used = m.select_columns(&used);
    let cov_used = fitted_covariance.select_rows(&used).select_columns(&used);
    let covariance = &m_used * cov_used * m_used.transpose() + own;
    let sigma: Vec<f64> = (0..t).map(|i| covariance[(i, i)].sqrt()).collect();
    let d = nalgebra::DVector::from_vec(change.clone());
    let wald = covariance.clone().cholesky().map(|c| d.dot(&c.solve(&d)));
    let p_value = wald.filter(|w| w.is_finite()).and_then(|w| chi2_sf(w, t as f64)).unwrap_or(1.0);
    ChangeTest { change, sigma, wald: wald.unwrap_or(f64::NAN), p_value }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed form: two parameters, `y = r + c x` observed at `x = 1` on B with weight `w`
    /// (r refitted, c carried), so `N = w [1 1; 1 1]`: `r_B = y - c_A`, hence `d r_B / d c = -1`;
    /// with `Cov_A = diag(s_r^2, s_c^2)`,
    /// `Var(r_B - r_A) = s_c^2 + s_r^2 + 1 / w`.
    #[test]
    fn the_change_variance_has_the_carried_parameters_part() {
        let w = 4.0;
        let normal = DMatrix::from_row_slice(2, 2, &[w, w, w, w]);
        let cov_a = DMatrix::from_row_slice(2, 2, &[0.09, 0.0, 0.0, 0.16]);
        let t = change_test(&normal, &[0], &[0], vec![1.0], &cov_a);
        let var: f64 = 0.16 + 0.09 + 0.25;
        assert!((t.sigma[0] - var.sqrt()).abs() < 1e-12, "{t:?}");
        assert!((t.wald - 1.0 / var).abs() < 1e-12);
        assert!((t.p_value - chi2_sf(1.0 / var, 1.0).expect("dof 1")).abs() < 1e-12);
    }

    /// Correlated changes: two refitted parameters sharing one carried one; the Wald statistic of
    /// a change along the shared direction is smaller than the diagonal sum would say.
    #[test]
    fn correlations_of_the_changes_enter_the_wald_statistic() {
        // Columns: r1, r2, c. y1 = r1 + c, y2 = r2 + c, weight 1 each.
        let normal = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 2.0]);
        let mut cov_a = DMatrix::zeros(3, 3);
        cov_a[(2, 2)] = 100.0;
        // The NaN of an unidentified parameter that M does not use is skipped.
        let mut padded = DMatrix::from_element(4, 4, f64::NAN);
        padded.view_mut((0, 0), (3, 3)).copy_from(&cov_a);
        let t = change_test(&normal, &[0, 1], &[0, 1], vec![10.0, 10.0], &padded);
        // Cov_d = 100 [1 1; 1 1] + I: d = (10, 10) along the shared direction: 200 / 201.
        assert!((t.wald - 200.0 / 201.0).abs() < 1e-9, "{t:?}");
        assert!((t.sigma[0] - 101f64.sqrt()).abs() < 1e-12);
        // The diagonal sum would have been 2 * 100 / 101, about the same here; opposite changes
        // are what the correlation makes loud: (10, -10) gives 200 / 1.
        let t = change_test(&normal, &[0, 1], &[0, 1], vec![10.0, -10.0], &padded);
        assert!((t.wald - 200.0).abs() < 1e-9, "{t:?}");
    }

    #[test]
    fn a_singular_refit_decides_nothing() {
        let normal = DMatrix::zeros(2, 2);
        let t = change_test(&normal, &[0], &[0], vec![1.0], &DMatrix::identity(2, 2));
        assert_eq!(t.p_value, 1.0);
        assert!(t.sigma[0].is_nan());
    }
}
