//! The mechanization's solve folded with one set of compensation parameters into a single linear
//! map: the navigation's inner loop (8 solves per step per compensation) becomes one dense
//! 6 x (N + 10) matrix-vector product.
//!
//! With readings `m_j = s_j / k_j - b_j` and `omega x (omega x r) = omega (omega . r) - |omega|^2 r`,
//! the solve `x_k = sum_j P_kj (m_j - theta_j . (omega x (omega x r_j)) + theta_j . g_b)` is
//!
//! ```text
//! x_k = sum_j (P_kj / k_j) s_j  -  sum_j P_kj b_j  +  G_k . g_b  -  omega^T A_k omega  +  c_k |omega|^2
//! G_k = sum_j P_kj theta_j,   A_k = sum_j P_kj theta_j r_j^T,   c_k = sum_j P_kj theta_j . r_j
//! ```
//!
//! linear in the outputs, in gravity in body axes, and in the six monomials of the rate
//! `(wx^2, wy^2, wz^2, wx wy, wx wz, wy wz)`. Same algebra as [`Mechanization::solve`], another
//! order of operations: the two agree to rounding (tested).

use nalgebra::Vector3;

use super::mechanization::{Mechanization, RigidAccel};

/// Columns: the N outputs, then `g_b` (3), the rate monomials (6), and the constant.
#[derive(Debug, Clone)]
pub struct FoldedSolve {
    columns: Vec<[f64; 6]>,
    n: usize,
}

impl FoldedSolve {
    /// Folds `mechanization` (the compensation's geometry) with its scale factors and biases.
    pub fn new(mechanization: &Mechanization, scale_factor: &[f64], bias_m_s2: &[f64]) -> Self {
        let n = mechanization.len();
        let p = mechanization.pseudo_inverse();
        let mut columns = vec![[0.0; 6]; n + 10];
        for j in 0..n {
            let th = mechanization.axes()[j];
            let r = mechanization.positions_m()[j];
            for k in 0..6 {
                let pk = p[(k, j)];
                columns[j][k] = pk / scale_factor[j];
                for a in 0..3 {
                    columns[n + a][k] += pk * th[a];
                }
                // -omega^T (th r^T) omega + |omega|^2 (th . r), by monomial.
                let thr = th.dot(&r);
                for a in 0..3 {
                    columns[n + 3 + a][k] += pk * (thr - th[a] * r[a]);
                }
                let pairs = [(0, 1), (0, 2), (1, 2)];
                for (m, &(a, b)) in pairs.iter().enumerate() {
                    columns[n + 6 + m][k] -= pk * (th[a] * r[b] + th[b] * r[a]);
                }
                columns[n + 9][k] -= pk * bias_m_s2[j];
            }
        }
        Self { columns, n }
    }

    /// `(alpha, a_o)` in body axes from raw outputs, the body rate and gravity in body axes. (The
    /// navigation does the same arithmetic two compensations at a time: `nav::pair`.)
    #[inline]
    pub fn solve(&self, outputs: &[f64], omega_b_rad_s: &Vector3<f64>, gravity_b_m_s2: &Vector3<f64>) -> RigidAccel {
        let w = omega_b_rad_s;
        let monomials = [w.x * w.x, w.y * w.y, w.z * w.z, w.x * w.y, w.x * w.z, w.y * w.z];
        let mut x = self.columns[self.n + 9];
        let mut add = |column: &[f64; 6], v: f64| {
            for k in 0..6 {
                x[k] += column[k] * v;
            }
        };
        for (column, s) in self.columns[..self.n].iter().zip(outputs) {
            add(column, *s);
        }
        for (column, g) in self.columns[self.n..self.n + 3].iter().zip(gravity_b_m_s2.iter()) {
            add(column, *g);
        }
        for (column, m) in self.columns[self.n + 3..self.n + 9].iter().zip(&monomials) {
            add(column, *m);
        }
        RigidAccel { alpha_b_rad_s2: Vector3::new(x[0], x[1], x[2]), accel_b_m_s2: Vector3::new(x[3], x[4], x[5]) }
    }

    /// The constant column (the biases' share).
    pub fn constant_column(&self) -> &[f64; 6] {
        &self.columns[self.n + 9]
    }

    /// The outputs' columns, one per accelerometer (`P_kj / k_j`).
    pub fn output_columns(&self) -> &[[f64; 6]] {
        &self.columns[..self.n]
    }

    /// The columns that multiply the state's terms: gravity in body axes (3), then the rate's
    /// monomials `(wx^2, wy^2, wz^2, wx wy, wx wz, wy wz)`; each a column of the 6 unknowns
    /// `(alpha, a_o)`.
    pub fn state_columns(&self) -> &[[f64; 6]] {
        &self.columns[self.n..self.n + 9]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::Array;
    use rand::{RngExt, SeedableRng};

    /// The folded map against the mechanization's own solve (the oracle: readings, cross
    /// products, pseudo-inverse), on random geometry, parameters, rates and gravity.
    #[test]
    fn agrees_with_the_mechanization_solve_to_rounding() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let cube = Array::cube(0.1).expect("cube");
        for _ in 0..200 {
            let positions: Vec<Vector3<f64>> =
                cube.positions_m().iter().map(|r| r + Vector3::from_fn(|_, _| rng.random_range(-2e-3..2e-3))).collect();
            let axes: Vec<Vector3<f64>> =
                cube.axes().iter().map(|a| a + Vector3::from_fn(|_, _| rng.random_range(-0.02..0.02))).collect();
            let mech = Mechanization::new(&positions, &axes).expect("full rank");
            let k: Vec<f64> = (0..6).map(|_| rng.random_range(0.4..2.6)).collect();
            let b: Vec<f64> = (0..6).map(|_| rng.random_range(-0.05..0.05)).collect();
            let folded = FoldedSolve::new(&mech, &k, &b);
            let s: Vec<f64> = (0..6).map(|_| rng.random_range(-30.0..30.0)).collect();
            let w = Vector3::from_fn(|_, _| rng.random_range(-10.0..10.0));
            let g = Vector3::from_fn(|_, _| rng.random_range(-9.8..9.8));
            let readings: Vec<f64> = s.iter().zip(&k).zip(&b).map(|((s, k), b)| s / k - b).collect();
            let want = mech.solve(&readings, &w, &g);
            let got = folded.solve(&s, &w, &g);
            let scale = 1.0 + want.alpha_b_rad_s2.norm() + want.accel_b_m_s2.norm();
            assert!((got.alpha_b_rad_s2 - want.alpha_b_rad_s2).norm() < 1e-12 * scale);
            assert!((got.accel_b_m_s2 - want.accel_b_m_s2).norm() < 1e-12 * scale);
        }
    }
}
