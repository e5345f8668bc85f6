//! Two navigations side by side: the RK4 stages of two compensations of the same outputs, each
//! number a pair of lanes, so that the compiler issues one packed instruction for both
//! (SSE2's two doubles, on any x86-64).
//!
//! Every lane does exactly the arithmetic of the scalar integrator it replaced (nalgebra's
//! quaternion product, dot and cross products and normalisation, in their order of operations,
//! zero products included), so a lane's navigation has the same bits as that compensation
//! navigated alone (tested against the scalar form written with nalgebra).

use std::ops::{Add, Div, Mul, Sub};

use nalgebra::{Quaternion, Vector3};

use crate::sensor::params::Compensator;

/// A number in two lanes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct L(pub [f64; 2]);

impl L {
    #[inline(always)]
    pub fn splat(v: f64) -> Self {
        Self([v, v])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Self([self.0[0].sqrt(), self.0[1].sqrt()])
    }
}

macro_rules! lane_op {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for L {
            type Output = L;
            #[inline(always)]
            fn $method(self, rhs: L) -> L {
                L([self.0[0] $op rhs.0[0], self.0[1] $op rhs.0[1]])
            }
        }
        impl $trait<f64> for L {
            type Output = L;
            #[inline(always)]
            fn $method(self, rhs: f64) -> L {
                L([self.0[0] $op rhs, self.0[1] $op rhs])
            }
        }
    };
}
lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

type V3 = [L; 3];

/// nalgebra's 3-dot order: `(a0 b0 + a1 b1) + a2 b2`.
#[inline(always)]
fn dot(a: &V3, b: &V3) -> L {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
fn cross(a: &V3, b: &V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// The navigated state in two lanes, unnormalised; the quaternion in nalgebra's storage order
/// `(i, j, k, w)`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PairState {
    pub q: [L; 4],
    pub w: V3,
    pub v: V3,
    pub r: V3,
}

impl PairState {
    /// Lane `l` as (quaternion, rate, velocity, position).
    pub fn lane(&self, l: usize) -> (Quaternion<f64>, Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let v3 = |x: &V3| Vector3::new(x[0].0[l], x[1].0[l], x[2].0[l]);
        let q = &self.q;
        (Quaternion::new(q[3].0[l], q[0].0[l], q[1].0[l], q[2].0[l]), v3(&self.w), v3(&self.v), v3(&self.r))
    }

    /// Sets lane `l` from (quaternion, rate, velocity, position).
    pub fn set_lane(&mut self, l: usize, q: &Quaternion<f64>, w: &Vector3<f64>, v: &Vector3<f64>, r: &Vector3<f64>) {
        for (a, b) in self.q.iter_mut().zip(q.coords.iter()) {
            a.0[l] = *b;
        }
        for (x, y) in [(&mut self.w, w), (&mut self.v, v), (&mut self.r, r)] {
            for (a, b) in x.iter_mut().zip(y.iter()) {
                a.0[l] = *b;
            }
        }
    }

    /// `self + d h`.
    #[inline(always)]
    fn axpy(&self, h: f64, d: &PairState) -> PairState {
        let ax = |x: &V3, y: &V3| [x[0] + y[0] * h, x[1] + y[1] * h, x[2] + y[2] * h];
        let q = [self.q[0] + d.q[0] * h, self.q[1] + d.q[1] * h, self.q[2] + d.q[2] * h, self.q[3] + d.q[3] * h];
        PairState { q, w: ax(&self.w, &d.w), v: ax(&self.v, &d.v), r: ax(&self.r, &d.r) }
    }

    /// Whether each lane's rate, velocity, position and quaternion norm are finite.
    pub fn finite(&self) -> [bool; 2] {
        [0, 1].map(|l| {
            self.w.iter().chain(&self.v).chain(&self.r).all(|x| x.0[l].is_finite()) && norm4(&self.q).0[l].is_finite()
        })
    }
}

/// nalgebra's 4-norm: `sqrt((a0^2 + a2^2) + (a1^2 + a3^2))`.
#[inline(always)]
fn norm4(q: &[L; 4]) -> L {
    let (a, b, c, d) = (q[0] * q[0], q[1] * q[1], q[2] * q[2], q[3] * q[3]);
    ((a + c) + (b + d)).sqrt()
}

/// The folded solves of two compensations (`array::folded`), lane by lane.
#[derive(Debug, Clone)]
pub struct PairSolve {
    constant: [L; 6],
    /// One per accelerometer.
    outputs: Vec<[L; 6]>,
    /// Gravity in body axes (3), then the rate's six monomials.
    state: [[L; 6]; 9],
}

impl PairSolve {
    pub fn new(lanes: [&Compensator; 2]) -> Self {
        let n = lanes[0].folded().output_columns().len();
        let mut solve =
            Self { constant: [L::default(); 6], outputs: vec![[L::default(); 6]; n], state: [[L::default(); 6]; 9] };
        for (l, comp) in lanes.iter().enumerate() {
            let folded = comp.folded();
            let columns = folded.output_columns().iter().zip(solve.outputs.iter_mut());
            let state = folded.state_columns().iter().zip(solve.state.iter_mut());
            for (from, to) in
                std::iter::once((folded.constant_column(), &mut solve.constant)).chain(columns).chain(state)
            {
                for k in 0..6 {
                    to[k].0[l] = from[k];
                }
            }
        }
        solve
    }

    /// The terms that depend on the raw outputs only (the same in both lanes), in
    /// `FoldedSolve::solve`'s order: the constant, then each accelerometer's column.
    #[inline]
    pub fn output_terms(&self, outputs: &[f64]) -> [L; 6] {
        let mut x = self.constant;
        for (column, s) in self.outputs.iter().zip(outputs) {
            for k in 0..6 {
                x[k] = x[k] + column[k] * *s;
            }
        }
        x
    }

    /// The state's derivative in both lanes, from the outputs' terms of each lane's compensation
    /// ([`PairSolve::output_terms`]) and gravity in inertial axes.
    #[inline(always)]
    pub fn derivative(&self, x: &PairState, terms: &[L; 6], gravity_i_m_s2: &Vector3<f64>) -> PairState {
        let s = x.q[3];
        let u = [x.q[0], x.q[1], x.q[2]];
        let uu = dot(&u, &u);
        let inv_n2 = L::splat(1.0) / (s * s + uu);
        let ss_uu = s * s - uu;
        // Gravity in body axes: R(q)^T g_i (the conjugate's rotation: u -> -u).
        let g = [L::splat(gravity_i_m_s2.x), L::splat(gravity_i_m_s2.y), L::splat(gravity_i_m_s2.z)];
        let (ug2, uxg, s2) = (dot(&u, &g) * 2.0, cross(&u, &g), s * 2.0);
        let gb = |a: usize| (g[a] * ss_uu + u[a] * ug2 - uxg[a] * s2) * inv_n2;
        let gravity_b: V3 = [gb(0), gb(1), gb(2)];
        // The folded solve's state terms, in `FoldedSolve::solve`'s order.
        let w = &x.w;
        let monomials = [w[0] * w[0], w[1] * w[1], w[2] * w[2], w[0] * w[1], w[0] * w[2], w[1] * w[2]];
        let mut acc = *terms;
        for (column, v) in self.state.iter().zip(gravity_b.iter().chain(&monomials)) {
            for k in 0..6 {
                acc[k] = acc[k] + column[k] * *v;
            }
        }
        let a = [acc[3], acc[4], acc[5]];
        let (ua2, uxa) = (dot(&u, &a) * 2.0, cross(&u, &a));
        let ai = |c: usize| (a[c] * ss_uu + u[c] * ua2 + uxa[c] * s2) * inv_n2;
        let accel_i: V3 = [ai(0), ai(1), ai(2)];
        // q (0, w) / 2, nalgebra's product with the zero products kept.
        let q = &x.q;
        let zero = L::splat(0.0);
        let dq = [
            (s * w[0] + q[0] * zero + q[1] * w[2] - q[2] * w[1]) * 0.5,
            (s * w[1] - q[0] * w[2] + q[1] * zero + q[2] * w[0]) * 0.5,
            (s * w[2] + q[0] * w[1] - q[1] * w[0] + q[2] * zero) * 0.5,
            (s * zero - q[0] * w[0] - q[1] * w[1] - q[2] * w[2]) * 0.5,
        ];
        PairState { q: dq, w: [acc[0], acc[1], acc[2]], v: accel_i, r: x.v }
    }

    /// One RK4 step of `h` from `x`, with the outputs' terms at the step's start, midpoint and
    /// end; the quaternion normalised at the end.
    #[inline(always)]
    pub fn step(&self, x: &PairState, terms: &[[L; 6]; 3], h: f64, gravity_i_m_s2: &Vector3<f64>) -> PairState {
        let k1 = self.derivative(x, &terms[0], gravity_i_m_s2);
        let k2 = self.derivative(&x.axpy(0.5 * h, &k1), &terms[1], gravity_i_m_s2);
        let k3 = self.derivative(&x.axpy(0.5 * h, &k2), &terms[1], gravity_i_m_s2);
        let k4 = self.derivative(&x.axpy(h, &k3), &terms[2], gravity_i_m_s2);
        let h6 = h / 6.0;
        let comb = |x: L, a: L, b: L, c: L, d: L| x + (a + b * 2.0 + c * 2.0 + d) * h6;
        let v3 = |x: &V3, a: &V3, b: &V3, c: &V3, d: &V3| {
            [comb(x[0], a[0], b[0], c[0], d[0]), comb(x[1], a[1], b[1], c[1], d[1]), comb(x[2], a[2], b[2], c[2], d[2])]
        };
        let qc = |i: usize| comb(x.q[i], k1.q[i], k2.q[i], k3.q[i], k4.q[i]);
        let q = [qc(0), qc(1), qc(2), qc(3)];
        let n = norm4(&q);
        PairState {
            q: [q[0] / n, q[1] / n, q[2] / n, q[3] / n],
            w: v3(&x.w, &k1.w, &k2.w, &k3.w, &k4.w),
            v: v3(&x.v, &k1.v, &k2.v, &k3.v, &k4.v),
            r: v3(&x.r, &k1.r, &k2.r, &k3.r, &k4.r),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::Array;
    use crate::sensor::params::random_params;
    use rand::{RngExt, SeedableRng};

    /// The scalar integrator the pair replaced, written with nalgebra's quaternion and vector
    /// operations (the oracle for the lanes' bits).
    #[derive(Clone, Copy)]
    struct Raw {
        q: Quaternion<f64>,
        w: Vector3<f64>,
        v: Vector3<f64>,
        r: Vector3<f64>,
    }

    fn derivative(x: &Raw, outputs: &[f64], comp: &Compensator, g: &Vector3<f64>) -> Raw {
        let s = x.q.w;
        let u = Vector3::new(x.q.i, x.q.j, x.q.k);
        let inv_n2 = 1.0 / (s * s + u.norm_squared());
        let ss_uu = s * s - u.norm_squared();
        let gravity_b = (g * ss_uu + u * (2.0 * u.dot(g)) - u.cross(g) * (2.0 * s)) * inv_n2;
        let acc = comp.folded().solve(outputs, &x.w, &gravity_b);
        let a = &acc.accel_b_m_s2;
        let accel_i = (a * ss_uu + u * (2.0 * u.dot(a)) + u.cross(a) * (2.0 * s)) * inv_n2;
        Raw { q: x.q * Quaternion::from_imag(x.w) * 0.5, w: acc.alpha_b_rad_s2, v: accel_i, r: x.v }
    }

    fn rk4(x: &Raw, outputs: &[Vec<f64>; 3], comp: &Compensator, h: f64, g: &Vector3<f64>) -> Raw {
        let axpy =
            |x: &Raw, h: f64, d: &Raw| Raw { q: x.q + d.q * h, w: x.w + d.w * h, v: x.v + d.v * h, r: x.r + d.r * h };
        let k1 = derivative(x, &outputs[0], comp, g);
        let k2 = derivative(&axpy(x, 0.5 * h, &k1), &outputs[1], comp, g);
        let k3 = derivative(&axpy(x, 0.5 * h, &k2), &outputs[1], comp, g);
        let k4 = derivative(&axpy(x, h, &k3), &outputs[2], comp, g);
        Raw {
            q: (x.q + (k1.q + k2.q * 2.0 + k3.q * 2.0 + k4.q) * (h / 6.0)).normalize(),
            w: x.w + (k1.w + k2.w * 2.0 + k3.w * 2.0 + k4.w) * (h / 6.0),
            v: x.v + (k1.v + k2.v * 2.0 + k3.v * 2.0 + k4.v) * (h / 6.0),
            r: x.r + (k1.r + k2.r * 2.0 + k3.r * 2.0 + k4.r) * (h / 6.0),
        }
    }

    /// Two compensations stepped in the pair's lanes give, bit for bit, what each gives alone in
    /// the scalar nalgebra form, over 100 steps from random states, outputs and parameters.
    #[test]
    fn each_lane_has_the_bits_of_the_scalar_integrator() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let cube = Array::cube(0.1).expect("cube");
        let g = Vector3::new(0.0, 0.0, -9.80665);
        for _ in 0..20 {
            let comps: Vec<Compensator> =
                (0..2).map(|_| Compensator::new(&cube, &random_params(&cube, &mut rng)).expect("full rank")).collect();
            let mut v = |s: f64| Vector3::from_fn(|_, _| rng.random_range(-s..s));
            let pair = PairSolve::new([&comps[0], &comps[1]]);
            let mut scalar: Vec<Raw> = (0..2)
                .map(|_| Raw { q: Quaternion::from_parts(1.0 + v(0.3).x, v(0.3)), w: v(3.0), v: v(2.0), r: v(1.0) })
                .collect();
            let mut lanes = PairState::default();
            for (l, x) in scalar.iter().enumerate() {
                lanes.set_lane(l, &x.q, &x.w, &x.v, &x.r);
            }
            for _ in 0..100 {
                let outputs = [0, 1, 2].map(|_| (0..6).map(|_| v(20.0).x).collect::<Vec<f64>>());
                let h = 0.01;
                let terms = [0, 1, 2].map(|t| pair.output_terms(&outputs[t]));
                lanes = pair.step(&lanes, &terms, h, &g);
                for (l, x) in scalar.iter_mut().enumerate() {
                    *x = rk4(x, &outputs, &comps[l], h, &g);
                    let (q, w, v, r) = lanes.lane(l);
                    assert_eq!((q, w, v, r), (x.q, x.w, x.v, x.r), "lane {l}");
                }
            }
            assert_eq!(lanes.finite(), [true, true]);
        }
    }
}
