//! Mechanization: the rigid-body accelerations from N accelerometer readings, derived from geometry.
//!
//! An accelerometer at `r` with axis `theta` (any length: a true, misaligned axis need not be a
//! unit vector) reads `theta . f(r)` with `f(r) = a_o + alpha x r + omega x (omega x r) - g_b`.
//! Since `theta . (alpha x r) = (r x theta) . alpha`,
//!
//! ```text
//! theta_j . f(r_j) - theta_j . (omega x (omega x r_j)) + theta_j . g_b = [(r_j x theta_j)^T, theta_j^T] [alpha; a_o]
//! ```
//!
//! The N x 6 matrix `M` of these rows must have full column rank; the solve is the least-squares
//! pseudo-inverse `P = (M^T M)^-1 M^T` (6 x N), exact for N = 6. For the cube of Hung & Lee (2006)
//! `P = [S / (2 rho); T / 2]` with their S and T (eq. 3-4).

use nalgebra::{DMatrix, SVD, Vector3, Vector6};

/// Angular acceleration of the body and inertial acceleration of its origin, both in body axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidAccel {
    pub alpha_b_rad_s2: Vector3<f64>,
    pub accel_b_m_s2: Vector3<f64>,
}

/// The array cannot sense some rigid-body motion: `M` lacks full column rank.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("degenerate array: the accelerometers cannot sense {}", describe_all(.unseen))]
pub struct RankError {
    /// Unit directions in (alpha, a_o) space that produce no reading on any accelerometer.
    pub unseen: Vec<Vector6<f64>>,
    /// Smallest over largest singular value of the length-normalised matrix.
    pub singular_value_ratio: f64,
}

/// Length-normalised singular values below this fraction of the largest count as zero.
const RANK_TOLERANCE: f64 = 1e-9;

/// The solve of an array (nominal or calibrated geometry).
#[derive(Debug, Clone)]
pub struct Mechanization {
    /// N x 6 matrix, rows `[(r_j x theta_j)^T, theta_j^T]`.
    matrix: DMatrix<f64>,
    /// 6 x N pseudo-inverse, row-major for a cache-friendly solve.
    pinv_rows: Vec<[f64; 6]>,
    positions_m: Vec<Vector3<f64>>,
    axes: Vec<Vector3<f64>>,
    singular_value_ratio: f64,
}

impl Mechanization {
    /// Derives the solve from positions (m) and axes; refuses geometry that cannot see all of
    /// `(alpha, a_o)`, naming the motions it cannot see.
    pub fn new(positions_m: &[Vector3<f64>], axes: &[Vector3<f64>]) -> Result<Self, RankError> {
        let n = positions_m.len();
        assert_eq!(n, axes.len(), "one axis per position");
        let mut matrix = DMatrix::zeros(n, 6);
        for (j, (r, th)) in positions_m.iter().zip(axes).enumerate() {
            let rxt = r.cross(th);
            for k in 0..3 {
                matrix[(j, k)] = rxt[k];
                matrix[(j, 3 + k)] = th[k];
            }
        }
        // Normalise the alpha columns by a characteristic length so the rank test is unit-free.
        let length_m =
            (positions_m.iter().map(|r| r.norm_squared()).sum::<f64>() / n.max(1) as f64).sqrt().max(f64::MIN_POSITIVE);
        let mut scaled = matrix.clone();
        for k in 0..3 {
            scaled.column_mut(k).scale_mut(1.0 / length_m);
        }
        let svd = SVD::new(scaled, false, true);
        let sv = &svd.singular_values;
        let sv_max = sv.max();
        let sv_min = if n >= 6 { sv.min() } else { 0.0 };
        let ratio = if sv_max > 0.0 { sv_min / sv_max } else { 0.0 };
        if n < 6 || ratio < RANK_TOLERANCE {
            let v_t = svd.v_t.as_ref().expect("V^T was requested");
            let mut unseen = Vec::new();
            for (i, s) in sv.iter().enumerate() {
                if *s <= RANK_TOLERANCE * sv_max || sv_max == 0.0 {
                    unseen.push(unscale(Vector6::from_iterator(v_t.row(i).iter().copied()), length_m));
                }
            }
            // With fewer rows than columns the thin SVD omits the null space: complete it.
            if unseen.is_empty() || n < 6 {
                unseen = null_space_basis(&matrix, length_m);
            }
            return Err(RankError { unseen, singular_value_ratio: ratio });
        }
        let mtm = matrix.transpose() * &matrix;
        let inv = mtm
            .try_inverse()
            .ok_or_else(|| RankError { unseen: null_space_basis(&matrix, length_m), singular_value_ratio: ratio })?;
        let pinv = inv * matrix.transpose();
        let pinv_rows = (0..n).map(|j| std::array::from_fn(|k| pinv[(k, j)])).collect();
        Ok(Self {
            matrix,
            pinv_rows,
            positions_m: positions_m.to_vec(),
            axes: axes.to_vec(),
            singular_value_ratio: ratio,
        })
    }

    pub fn len(&self) -> usize {
        self.positions_m.len()
    }
    pub fn is_empty(&self) -> bool {
        self.positions_m.is_empty()
    }
    /// The N x 6 matrix `M`.
    pub fn matrix(&self) -> &DMatrix<f64> {
        &self.matrix
    }
    /// The 6 x N pseudo-inverse `P`: rows 0-2 give `alpha`, rows 3-5 give `a_o`.
    pub fn pseudo_inverse(&self) -> DMatrix<f64> {
        DMatrix::from_fn(6, self.len(), |k, j| self.pinv_rows[j][k])
    }
    /// Smallest over largest singular value of the length-normalised matrix (1 is ideal).
    pub fn singular_value_ratio(&self) -> f64 {
        self.singular_value_ratio
    }
    pub fn positions_m(&self) -> &[Vector3<f64>] {
        &self.positions_m
    }
    pub fn axes(&self) -> &[Vector3<f64>] {
        &self.axes
    }

    /// `theta_j . (omega x (omega x r_j))` for every accelerometer, m/s^2.
    pub fn centripetal_m_s2(&self, omega_b_rad_s: &Vector3<f64>, out: &mut [f64]) {
        for ((o, r), th) in out.iter_mut().zip(&self.positions_m).zip(&self.axes) {
            *o = th.dot(&omega_b_rad_s.cross(&omega_b_rad_s.cross(r)));
        }
    }

    /// Solves for `(alpha, a_o)` from readings `m_j = theta_j . f(r_j)` (m/s^2, bias and scale
    /// already removed), the current body rate and gravity in body axes.
    pub fn solve(
        &self,
        readings_m_s2: &[f64],
        omega_b_rad_s: &Vector3<f64>,
        gravity_b_m_s2: &Vector3<f64>,
    ) -> RigidAccel {
        debug_assert_eq!(readings_m_s2.len(), self.len());
        let w = omega_b_rad_s;
        let mut x = [0.0; 6];
        for (((m, r), th), p) in readings_m_s2.iter().zip(&self.positions_m).zip(&self.axes).zip(&self.pinv_rows) {
            let centripetal = th.dot(&w.cross(&w.cross(r)));
            let y = m - centripetal + th.dot(gravity_b_m_s2);
            for k in 0..6 {
                x[k] += p[k] * y;
            }
        }
        RigidAccel { alpha_b_rad_s2: Vector3::new(x[0], x[1], x[2]), accel_b_m_s2: Vector3::new(x[3], x[4], x[5]) }
    }
}

fn unscale(mut v: Vector6<f64>, length_m: f64) -> Vector6<f64> {
    for k in 0..3 {
        v[k] /= length_m;
    }
    let n = v.norm();
    if n > 0.0 { v / n } else { v }
}

/// Orthonormal basis (after unscaling) of the null space of `M`, from the eigenvectors of `M^T M`.
fn null_space_basis(matrix: &DMatrix<f64>, length_m: f64) -> Vec<Vector6<f64>> {
    let mut scaled = matrix.clone();
    for k in 0..3 {
        scaled.column_mut(k).scale_mut(1.0 / length_m);
    }
    let mtm = scaled.transpose() * &scaled;
    let eig = nalgebra::SymmetricEigen::new(mtm);
    let max = eig.eigenvalues.max().max(f64::MIN_POSITIVE);
    (0..6)
        .filter(|&i| eig.eigenvalues[i] <= RANK_TOLERANCE * RANK_TOLERANCE * max)
        .map(|i| unscale(Vector6::from_iterator(eig.eigenvectors.column(i).iter().copied()), length_m))
        .collect()
}

fn describe_all(unseen: &[Vector6<f64>]) -> String {
    let parts: Vec<String> = unseen.iter().map(describe_motion).collect();
    match parts.len() {
        0 => "some motion".into(),
        1 => parts[0].clone(),
        k => format!("{k} independent motions: {}", parts.join("; ")),
    }
}

/// Names a direction in `(alpha, a_o)` space in words, e.g. "angular acceleration about z".
pub fn describe_motion(v: &Vector6<f64>) -> String {
    let alpha = Vector3::new(v[0], v[1], v[2]);
    let accel = Vector3::new(v[3], v[4], v[5]);
    let fmt = |u: &Vector3<f64>| {
        if !(u.norm() > 0.0 && u.norm().is_finite()) {
            return "an undetermined direction".to_string();
        }
        let u = u / u.norm();
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            if u[k].abs() > 1.0 - 1e-9 {
                return (*name).to_string();
            }
        }
        format!("({:.3}, {:.3}, {:.3})", u[0], u[1], u[2])
    };
    let small = 1e-9;
    match (alpha.norm() > small, accel.norm() > small) {
        (true, false) => format!("angular acceleration about {}", fmt(&alpha)),
        (false, true) => format!("linear acceleration along {}", fmt(&accel)),
        (false, false) => "a motion too small to name (a null direction of zero length)".into(),
        _ => format!(
            "angular acceleration about {} combined with linear acceleration along {} (ratio {:.3} m)",
            fmt(&alpha),
            fmt(&accel),
            accel.norm() / alpha.norm()
        ),
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector6;

    /// Issue 13: a message about a degenerate array never prints NaN.
    #[test]
    fn motions_are_named_without_nan() {
        for v in [
            Vector6::zeros(),
            Vector6::new(1e-12, 0.0, 0.0, 0.0, 0.0, 1e-12),
            Vector6::new(0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
        ] {
            let d = super::describe_motion(&v);
            assert!(!d.contains("NaN") && !d.contains("nan"), "{d}");
        }
    }
}
