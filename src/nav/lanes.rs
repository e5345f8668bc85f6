//! Four navigations side by side: the RK4 stages of four compensations (of one trial's outputs or
//! of several trials'), each number four lanes, so that the compiler issues one packed instruction
//! for all four (AVX's four doubles where the processor has it: `navigator`'s dispatch; two SSE2
//! instructions elsewhere).
//!
//! Every lane does exactly the arithmetic of the scalar integrator it replaced (nalgebra's
//! quaternion normalisation and rotations, `Mechanization::solve` on the compensated readings, in
//! their order of operations, zero products included), so a lane's navigation has the same bits as
//! that compensation navigated alone (tested against the scalar form written with nalgebra). No
//! fused multiply-add is ever formed (Rust does not contract), so AVX gives the same bits as SSE2.

use std::ops::{Add, Div, Mul, Neg, Sub};

use nalgebra::{Quaternion, Vector3};

use crate::sensor::params::Compensator;

/// Lanes per number.
pub const LANES: usize = 4;

/// A number in [`LANES`] lanes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct L(pub [f64; LANES]);

impl L {
    #[inline(always)]
    pub fn splat(v: f64) -> Self {
        Self([v; LANES])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Self(self.0.map(f64::sqrt))
    }
}

macro_rules! lane_op {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for L {
            type Output = L;
            #[inline(always)]
            fn $method(self, rhs: L) -> L {
                L(std::array::from_fn(|l| self.0[l] $op rhs.0[l]))
            }
        }
        impl $trait<f64> for L {
            type Output = L;
            #[inline(always)]
            fn $method(self, rhs: f64) -> L {
                L(self.0.map(|x| x $op rhs))
            }
        }
    };
}
lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

impl Neg for L {
    type Output = L;
    #[inline(always)]
    fn neg(self) -> L {
        L(self.0.map(|x| -x))
    }
}

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

/// The navigated state in [`LANES`] lanes, unnormalised; the quaternion in nalgebra's storage order
/// `(i, j, k, w)`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LaneState {
    pub q: [L; 4],
    pub w: V3,
    pub v: V3,
    pub r: V3,
}

impl LaneState {
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
    fn axpy(&self, h: f64, d: &LaneState) -> LaneState {
        let ax = |x: &V3, y: &V3| [x[0] + y[0] * h, x[1] + y[1] * h, x[2] + y[2] * h];
        let q = [self.q[0] + d.q[0] * h, self.q[1] + d.q[1] * h, self.q[2] + d.q[2] * h, self.q[3] + d.q[3] * h];
        LaneState { q, w: ax(&self.w, &d.w), v: ax(&self.v, &d.v), r: ax(&self.r, &d.r) }
    }

    /// Whether each lane's rate, velocity, position and quaternion norm are finite.
    pub fn finite(&self) -> [bool; LANES] {
        std::array::from_fn(|l| {
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

/// The solves of [`LANES`] compensations (`Mechanization::solve` after
/// `Compensator::reading_m_s2`), lane by lane: per accelerometer its position, axis and column of
/// the pseudo-inverse.
#[derive(Debug, Clone)]
pub struct LaneSolve {
    inv_scale: Vec<L>,
    bias_m_s2: Vec<L>,
    position_m: Vec<V3>,
    axis: Vec<V3>,
    pinv: Vec<[L; 6]>,
}

impl LaneSolve {
    pub fn new(lanes: [&Compensator; LANES]) -> Self {
        let n = lanes[0].mechanization().len();
        let mut solve = Self {
            inv_scale: vec![L::default(); n],
            bias_m_s2: vec![L::default(); n],
            position_m: vec![[L::default(); 3]; n],
            axis: vec![[L::default(); 3]; n],
            pinv: vec![[L::default(); 6]; n],
        };
        for (l, comp) in lanes.iter().enumerate() {
            let mech = comp.mechanization();
            let p = mech.pseudo_inverse();
            for j in 0..n {
                solve.inv_scale[j].0[l] = comp.inv_scale()[j];
                solve.bias_m_s2[j].0[l] = comp.bias_m_s2()[j];
                for a in 0..3 {
                    solve.position_m[j][a].0[l] = mech.positions_m()[j][a];
                    solve.axis[j][a].0[l] = mech.axes()[j][a];
                }
                for k in 0..6 {
                    solve.pinv[j][k].0[l] = p[(k, j)];
                }
            }
        }
        solve
    }

    pub fn len(&self) -> usize {
        self.pinv.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pinv.is_empty()
    }

    /// Each lane's readings `s_j (1 / k_j) - b_j` of its raw outputs (`outputs[l]` for lane `l`):
    /// they do not depend on the state, so they are computed once per distinct time.
    #[inline(always)]
    pub fn readings(&self, outputs: [&[f64]; LANES], readings: &mut [L]) {
        for (j, ((m, k), b)) in readings.iter_mut().zip(&self.inv_scale).zip(&self.bias_m_s2).enumerate() {
            *m = L(outputs.map(|o| o[j])) * *k - *b;
        }
    }

    /// The state's derivative in every lane, from each lane's readings and gravity in inertial
    /// axes, in the scalar navigation's order of operations: the quaternion normalised, gravity
    /// rotated into body axes by its conjugate, `Mechanization::solve`, the acceleration rotated
    /// back (nalgebra's `UnitQuaternion * Vector3`), `q (0, w) / 2` on the unnormalised quaternion.
    #[inline(always)]
    pub fn derivative(&self, x: &LaneState, readings: &[L], gravity_i_m_s2: &Vector3<f64>) -> LaneState {
        let n = norm4(&x.q);
        let (s, u) = (x.q[3] / n, [x.q[0] / n, x.q[1] / n, x.q[2] / n]);
        let g = [L::splat(gravity_i_m_s2.x), L::splat(gravity_i_m_s2.y), L::splat(gravity_i_m_s2.z)];
        let gravity_b = rotate(&[-u[0], -u[1], -u[2]], s, &g);
        let w = &x.w;
        let mut acc = [L::splat(0.0); 6];
        for (((m, r), th), p) in readings.iter().zip(&self.position_m).zip(&self.axis).zip(&self.pinv) {
            let centripetal = dot(th, &cross(w, &cross(w, r)));
            let y = *m - centripetal + dot(th, &gravity_b);
            for k in 0..6 {
                acc[k] = acc[k] + p[k] * y;
            }
        }
        let accel_i = rotate(&u, s, &[acc[3], acc[4], acc[5]]);
        // q (0, w) / 2, nalgebra's product with the zero products kept.
        let q = &x.q;
        let zero = L::splat(0.0);
        let dq = [
            (q[3] * w[0] + q[0] * zero + q[1] * w[2] - q[2] * w[1]) * 0.5,
            (q[3] * w[1] - q[0] * w[2] + q[1] * zero + q[2] * w[0]) * 0.5,
            (q[3] * w[2] + q[0] * w[1] - q[1] * w[0] + q[2] * zero) * 0.5,
            (q[3] * zero - q[0] * w[0] - q[1] * w[1] - q[2] * w[2]) * 0.5,
        ];
        LaneState { q: dq, w: [acc[0], acc[1], acc[2]], v: accel_i, r: x.v }
    }

    /// One RK4 step of `h` from `x`, with each lane's readings at the step's start, midpoint and
    /// end; the quaternion normalised at the end.
    #[inline(always)]
    pub fn step(&self, x: &LaneState, readings: &[Vec<L>; 3], h: f64, gravity_i_m_s2: &Vector3<f64>) -> LaneState {
        let k1 = self.derivative(x, &readings[0], gravity_i_m_s2);
        let k2 = self.derivative(&x.axpy(0.5 * h, &k1), &readings[1], gravity_i_m_s2);
        let k3 = self.derivative(&x.axpy(0.5 * h, &k2), &readings[1], gravity_i_m_s2);
        let k4 = self.derivative(&x.axpy(h, &k3), &readings[2], gravity_i_m_s2);
        let h6 = h / 6.0;
        let comb = |x: L, a: L, b: L, c: L, d: L| x + (a + b * 2.0 + c * 2.0 + d) * h6;
        let v3 = |x: &V3, a: &V3, b: &V3, c: &V3, d: &V3| {
            [comb(x[0], a[0], b[0], c[0], d[0]), comb(x[1], a[1], b[1], c[1], d[1]), comb(x[2], a[2], b[2], c[2], d[2])]
        };
        let qc = |i: usize| comb(x.q[i], k1.q[i], k2.q[i], k3.q[i], k4.q[i]);
        let q = [qc(0), qc(1), qc(2), qc(3)];
        let n = norm4(&q);
        LaneState {
            q: [q[0] / n, q[1] / n, q[2] / n, q[3] / n],
            w: v3(&x.w, &k1.w, &k2.w, &k3.w, &k4.w),
            v: v3(&x.v, &k1.v, &k2.v, &k3.v, &k4.v),
            r: v3(&x.r, &k1.r, &k2.r, &k3.r, &k4.r),
        }
    }
}

/// nalgebra's `UnitQuaternion * Vector3` for the unit quaternion `(s, u)`:
/// `t = 2 (u x v)`, then `(t s + u x t) + v`.
#[inline(always)]
fn rotate(u: &V3, s: L, v: &V3) -> V3 {
    let c = cross(u, v);
    let t = [c[0] * 2.0, c[1] * 2.0, c[2] * 2.0];
    let ut = cross(u, &t);
    [t[0] * s + ut[0] + v[0], t[1] * s + ut[1] + v[1], t[2] * s + ut[2] + v[2]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::Array;
    use crate::sensor::params::random_params;
    use nalgebra::UnitQuaternion;
    use rand::{RngExt, SeedableRng};

    /// The scalar integrator the pair replaced (the navigator before issue 14), written with
    /// nalgebra's quaternion and vector operations: the oracle for the lanes' bits.
    #[derive(Clone, Copy)]
    struct Raw {
        q: Quaternion<f64>,
        w: Vector3<f64>,
        v: Vector3<f64>,
        r: Vector3<f64>,
    }

    fn derivative(x: &Raw, outputs: &[f64], comp: &Compensator, g: &Vector3<f64>) -> Raw {
        let q = UnitQuaternion::new_normalize(x.q);
        let gravity_b = q.inverse_transform_vector(g);
        let acc = comp.rigid_accel(outputs, &x.w, &gravity_b);
        Raw {
            q: x.q * Quaternion::from_imag(x.w) * 0.5,
            w: acc.alpha_b_rad_s2,
            v: q.transform_vector(&acc.accel_b_m_s2),
            r: x.v,
        }
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

    /// Four compensations stepped in the lanes, each on its own outputs (as two trials in
    /// lockstep), give bit for bit what each gives alone in the scalar nalgebra form, over 100
    /// steps from random states, outputs and parameters.
    #[test]
    fn each_lane_has_the_bits_of_the_scalar_integrator() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let cube = Array::cube(0.1).expect("cube");
        let g = Vector3::new(0.0, 0.0, -9.80665);
        for _ in 0..20 {
            let comps: Vec<Compensator> = (0..LANES)
                .map(|_| Compensator::new(&cube, &random_params(&cube, &mut rng)).expect("full rank"))
                .collect();
            let mut v = |s: f64| Vector3::from_fn(|_, _| rng.random_range(-s..s));
            let solve = LaneSolve::new(std::array::from_fn(|l| &comps[l]));
            let mut scalar: Vec<Raw> = (0..LANES)
                .map(|_| Raw { q: Quaternion::from_parts(1.0 + v(0.3).x, v(0.3)), w: v(3.0), v: v(2.0), r: v(1.0) })
                .collect();
            let mut lanes = LaneState::default();
            for (l, x) in scalar.iter().enumerate() {
                lanes.set_lane(l, &x.q, &x.w, &x.v, &x.r);
            }
            for _ in 0..100 {
                // Lanes 0-1 share one trial's outputs, lanes 2-3 another's.
                let outputs: [[Vec<f64>; 3]; 2] =
                    std::array::from_fn(|_| std::array::from_fn(|_| (0..6).map(|_| v(20.0).x).collect()));
                let h = 0.01;
                let readings = [0, 1, 2].map(|t| {
                    let mut m = vec![L::default(); solve.len()];
                    solve.readings(std::array::from_fn(|l| outputs[l / 2][t].as_slice()), &mut m);
                    m
                });
                lanes = solve.step(&lanes, &readings, h, &g);
                for (l, x) in scalar.iter_mut().enumerate() {
                    *x = rk4(x, &outputs[l / 2], &comps[l], h, &g);
                    let (q, w, v, r) = lanes.lane(l);
                    assert_eq!((q, w, v, r), (x.q, x.w, x.v, x.r), "lane {l}");
                }
            }
            assert_eq!(lanes.finite(), [true; LANES]);
        }
    }
}
