//! The navigation's error dynamics linearised along the reference trajectory, integrated on the
//! navigator's own steps (see the module docs of [`super`] for the derivation): the sensitivity
//! of the 12 error states to every compensation parameter, and the covariance the navigation's
//! white noise leaves, at each horizon.
//!
//! Error states, in this order: attitude `phi` (body axes, rad: `q_nav = q_true (1, phi / 2)`),
//! rate `d omega` (body, rad/s), velocity `d v` (inertial, m/s), position `d r` (inertial, m).

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crate::array::Array;
use crate::calib::params::{Layout, PER_ACCEL};
use crate::motion::RigidMotion;
use crate::nav::Plan;
use crate::nav::trajectory::Trajectory;
use crate::sensor::params::Compensator;

/// Error states: attitude, rate, velocity, position (3 each).
pub const STATES: usize = 12;

/// One error state vector (or one column of a sensitivity matrix).
pub type Column = [f64; STATES];

/// Offset of each drift metric's block in the error state, in `mc::trial::DRIFT_METRICS`'
/// order (rate, attitude, velocity, position).
pub const METRIC_OFFSETS: [usize; 4] = [3, 0, 6, 9];

/// Why a linearisation cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LinearisationError {
    #[error("the reference parameters give {0}")]
    Geometry(#[from] crate::array::RankError),
    #[error("the reference parameters have a zero or non-finite scale factor (accelerometer {0})")]
    ScaleFactor(usize),
}

/// The linearised navigation at each horizon.
#[derive(Debug, Clone)]
pub struct Linearisation {
    pub horizons_s: Vec<f64>,
    /// Per horizon, the sensitivity `d error / d x_compensation`: one [`Column`] per parameter
    /// of the layout (12 x 7N).
    pub sensitivity: Vec<Vec<Column>>,
    /// Per horizon, the covariance of the error state from the navigation's white noise at unit
    /// density (1 m/s^2/sqrt(Hz)): scale by the density squared. `None` when not asked for.
    pub noise_unit: Option<Vec<[Column; STATES]>>,
}

impl Linearisation {
    /// The block `metric` (index into [`METRIC_OFFSETS`]) of the sensitivity at horizon `h`, as
    /// a 3 x 7N matrix.
    pub fn block(&self, h: usize, metric: usize) -> DMatrix<f64> {
        let o = METRIC_OFFSETS[metric];
        let s = &self.sensitivity[h];
        DMatrix::from_fn(3, s.len(), |r, c| s[c][o + r])
    }

    /// `S_b u` for a parameter-space vector `u`, metric `metric`, horizon `h`.
    pub fn apply(&self, h: usize, metric: usize, u: &DVector<f64>) -> Vector3<f64> {
        let o = METRIC_OFFSETS[metric];
        let mut out = Vector3::zeros();
        for (col, ui) in self.sensitivity[h].iter().zip(u.iter()) {
            for r in 0..3 {
                out[r] += col[o + r] * ui;
            }
        }
        out
    }

    /// The unit-density noise covariance of metric `metric` at horizon `h` (zero without noise).
    pub fn noise_block(&self, h: usize, metric: usize) -> Matrix3<f64> {
        let o = METRIC_OFFSETS[metric];
        match &self.noise_unit {
            Some(q) => Matrix3::from_fn(|r, c| q[h][o + c][o + r]),
            None => Matrix3::zeros(),
        }
    }
}

/// What the reference compensation does at one time: the coefficients of the error dynamics
/// `x' = A x + b`, with `A` in 3 x 3 blocks and `b` per parameter (and per accelerometer for
/// the noise).
struct Stage {
    omega: Vector3<f64>,
    /// `d omega' = w_phi phi + w_w d omega + f_alpha`.
    w_phi: Matrix3<f64>,
    w_w: Matrix3<f64>,
    /// `d v' = v_phi phi + v_w d omega + C f_a`.
    v_phi: Matrix3<f64>,
    v_w: Matrix3<f64>,
    /// Body to inertial.
    c: Matrix3<f64>,
}

impl Stage {
    /// `A x + b` for one column; `b` holds the forcing in `(alpha, a_o)` (body axes).
    #[inline(always)]
    fn derivative(&self, x: &Column, b: &[f64; 6]) -> Column {
        let phi = Vector3::new(x[0], x[1], x[2]);
        let dw = Vector3::new(x[3], x[4], x[5]);
        let dphi = dw - self.omega.cross(&phi);
        let ddw = self.w_phi * phi + self.w_w * dw + Vector3::new(b[0], b[1], b[2]);
        let ddv = self.v_phi * phi + self.v_w * dw + self.c * Vector3::new(b[3], b[4], b[5]);
        [dphi.x, dphi.y, dphi.z, ddw.x, ddw.y, ddw.z, ddv.x, ddv.y, ddv.z, x[6], x[7], x[8]]
    }
}

/// The reference compensation: its solve, positions and axes (and derivatives of the axes by the
/// two misalignment angles), scale factors and biases.
struct Reference {
    /// 6 x N pseudo-inverse, as columns `P[:, j]`.
    pinv: Vec<[f64; 6]>,
    positions_m: Vec<Vector3<f64>>,
    axes: Vec<Vector3<f64>>,
    axis_derivatives: Vec<[Vector3<f64>; 2]>,
    scale: Vec<f64>,
    bias_m_s2: Vec<f64>,
}

impl Reference {
    fn new(array: &Array, layout: &Layout, x: &DVector<f64>) -> Result<Self, LinearisationError> {
        let params = layout.unpack(x);
        let comp = Compensator::new(array, &params)?;
        let p = comp.mechanization().pseudo_inverse();
        let n = array.len();
        let mut axis_derivatives = Vec::with_capacity(n);
        for j in 0..n {
            let o = PER_ACCEL * j;
            axis_derivatives.push(layout.axis(j, [x[o + 2], x[o + 3]]).1);
            if !(x[o].is_finite() && x[o] != 0.0) {
                return Err(LinearisationError::ScaleFactor(j + 1));
            }
        }
        Ok(Self {
            pinv: (0..n).map(|j| std::array::from_fn(|k| p[(k, j)])).collect(),
            positions_m: params.positions_m(array),
            axes: params.sensors.iter().map(|s| s.axis).collect(),
            axis_derivatives,
            scale: params.sensors.iter().map(|s| s.scale_factor).collect(),
            bias_m_s2: params.sensors.iter().map(|s| s.bias_m_s2).collect(),
        })
    }

    fn len(&self) -> usize {
        self.pinv.len()
    }

    /// The stage's dynamics at the true motion `m` with attitude `c` (body to inertial), and the
    /// forcing of every parameter (`P E(t)`: 6 per parameter, in layout order) into `forcing`.
    fn stage(&self, m: &RigidMotion, c: &Matrix3<f64>, forcing: &mut [[f64; 6]]) -> Stage {
        let w = m.omega_b_rad_s;
        let alpha = m.alpha_b_rad_s2;
        let g = m.gravity_b_m_s2;
        let (mut pk, mut pg) = (nalgebra::Matrix6x3::<f64>::zeros(), nalgebra::Matrix6x3::<f64>::zeros());
        for j in 0..self.len() {
            let (r, a, p) = (&self.positions_m[j], &self.axes[j], &self.pinv[j]);
            // Rows of d(reading residual)/d(omega) and d/d(phi) (see the module docs).
            let k_row = a * w.dot(r) + r * a.dot(&w) - w * (2.0 * a.dot(r));
            let g_row = a.cross(&g);
            for i in 0..6 {
                for col in 0..3 {
                    pk[(i, col)] += p[i] * k_row[col];
                    pg[(i, col)] += p[i] * g_row[col];
                }
            }
            // d(reading residual)/d(x_j): scale factor, bias, two angles, location.
            let f = m.specific_force_m_s2(r);
            let af = a.dot(&f);
            let loc = a.cross(&alpha) + w * a.dot(&w) - a * w.norm_squared();
            let d = &self.axis_derivatives[j];
            let grad =
                [-(self.bias_m_s2[j] + af) / self.scale[j], -1.0, -d[0].dot(&f), -d[1].dot(&f), -loc.x, -loc.y, -loc.z];
            for (a_i, gi) in grad.iter().enumerate() {
                forcing[PER_ACCEL * j + a_i] = std::array::from_fn(|i| p[i] * gi);
            }
        }
        let top = |m: &nalgebra::Matrix6x3<f64>| m.fixed_view::<3, 3>(0, 0).into_owned();
        let bottom = |m: &nalgebra::Matrix6x3<f64>| m.fixed_view::<3, 3>(3, 0).into_owned();
        let ao = m.accel_b_m_s2;
        let ao_cross = Matrix3::new(0.0, -ao.z, ao.y, ao.z, 0.0, -ao.x, -ao.y, ao.x, 0.0);
        Stage {
            omega: w,
            w_phi: top(&pg),
            w_w: -top(&pk),
            v_phi: c * (bottom(&pg) - ao_cross),
            v_w: -(c * bottom(&pk)),
            c: *c,
        }
    }
}

/// One RK4 step of `x' = A(t) x + b(t)` on a column, with the stages at the step's start,
/// midpoint (twice) and end, as the navigator takes them.
#[inline(always)]
fn rk4(x: &Column, stages: &[Stage; 3], b: [&[f64; 6]; 3], h: f64) -> Column {
    let axpy = |x: &Column, s: f64, d: &Column| -> Column { std::array::from_fn(|i| x[i] + s * d[i]) };
    let k1 = stages[0].derivative(x, b[0]);
    let k2 = stages[1].derivative(&axpy(x, 0.5 * h, &k1), b[1]);
    let k3 = stages[1].derivative(&axpy(x, 0.5 * h, &k2), b[1]);
    let k4 = stages[2].derivative(&axpy(x, h, &k3), b[2]);
    let h6 = h / 6.0;
    std::array::from_fn(|i| x[i] + (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) * h6)
}

/// Linearises the navigation of `array` compensated with parameters `x_ref` (layout form) whose
/// outputs come from an array with the same parameters, along `trajectory` with gravity
/// `g_m_s2`, on the navigator's steps (`nav::Plan`: `step_s`, landing on every horizon and
/// breakpoint). With `noise`, also the covariance of the white noise held over each step, as the
/// navigator's noisy source draws it (per-sample sigma `density sqrt(1 / step_s)`).
pub fn linearise(
    layout: &Layout,
    x_ref: &DVector<f64>,
    trajectory: &Trajectory,
    g_m_s2: f64,
    step_s: f64,
    horizons_s: &[f64],
    noise: bool,
) -> Result<Linearisation, LinearisationError> {
    let array = layout.array();
    let reference = Reference::new(array, layout, x_ref)?;
    let n = reference.len();
    let p = layout.len();
    let gravity_i = Vector3::new(0.0, 0.0, -g_m_s2);
    let plan = Plan::new(trajectory, step_s, horizons_s);
    let mut s: Vec<Column> = vec![[0.0; STATES]; p];
    let mut q = [[0.0; STATES]; STATES];
    let mut forcing = [vec![[0.0; 6]; p], vec![[0.0; 6]; p], vec![[0.0; 6]; p]];
    let mut out = Linearisation {
        horizons_s: plan.records.iter().map(|r| r.1).collect(),
        sensitivity: Vec::with_capacity(plan.records.len()),
        noise_unit: noise.then(Vec::new),
    };
    // Per-sample variance of the held noise at unit density.
    let variance = 1.0 / step_s;
    let mut next_record = 0;
    let mut record = |done: usize, s: &Vec<Column>, q: &[Column; STATES], out: &mut Linearisation| {
        while next_record < plan.records.len() && plan.records[next_record].0 == done {
            out.sensitivity.push(s.clone());
            if let Some(noise) = &mut out.noise_unit {
                noise.push(*q);
            }
            next_record += 1;
        }
    };
    for (i, step) in plan.steps.iter().enumerate() {
        record(i, &s, &q, &mut out);
        let mid_s = step.t_s + 0.5 * step.h_s;
        let stages: [Stage; 3] = {
            let times = step.stage_times_s();
            let mut make = |k: usize| {
                let truth = trajectory.truth_in_segment_of(times[k], mid_s);
                let motion = truth.motion(&gravity_i);
                let c = *truth.q_b_i.to_rotation_matrix().matrix();
                reference.stage(&motion, &c, &mut forcing[k])
            };
            [make(0), make(1), make(2)]
        };
        for (c, col) in s.iter_mut().enumerate() {
            *col = rk4(col, &stages, [&forcing[0][c], &forcing[1][c], &forcing[2][c]], step.h_s);
        }
        if noise {
            // Transition of the step and response to unit noise on each accelerometer, held
            // over the step: Q <- Phi Q Phi^T + sigma^2 Gamma Gamma^T.
            let zero = [0.0; 6];
            let phi: Vec<Column> = (0..STATES)
                .map(|c| {
                    let mut e = [0.0; STATES];
                    e[c] = 1.0;
                    rk4(&e, &stages, [&zero, &zero, &zero], step.h_s)
                })
                .collect();
            let mut next = [[0.0; STATES]; STATES];
            // (Phi Q) then (Phi Q) Phi^T; columns are stored as `m[col][row]`.
            let mut pq = [[0.0; STATES]; STATES];
            for c in 0..STATES {
                for k in 0..STATES {
                    let qkc = q[c][k];
                    if qkc != 0.0 {
                        for r in 0..STATES {
                            pq[c][r] += phi[k][r] * qkc;
                        }
                    }
                }
            }
            for c in 0..STATES {
                for k in 0..STATES {
                    let pkc = phi[k][c];
                    if pkc != 0.0 {
                        for r in 0..STATES {
                            next[c][r] += pq[k][r] * pkc;
                        }
                    }
                }
            }
            for j in 0..n {
                let b = reference.pinv[j];
                let gamma = rk4(&[0.0; STATES], &stages, [&b, &b, &b], step.h_s);
                for c in 0..STATES {
                    for r in 0..STATES {
                        next[c][r] += variance * gamma[r] * gamma[c];
                    }
                }
            }
            q = next;
        }
    }
    record(plan.steps.len(), &s, &q, &mut out);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::Form;
    use crate::nav::{SimulatedArray, navigate};
    use crate::sensor::ArrayParams;
    use nalgebra::UnitQuaternion;
    use rand::{RngExt, SeedableRng};

    const G: f64 = 9.80665;

    /// The cube's solve from Table 1 (physics notes), inverted by LU here: an oracle independent
    /// of `Mechanization` (SVD and normal equations).
    fn cube_inverse(rho: f64) -> DMatrix<f64> {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let p = [[0., 0., -1.], [0., -1., 0.], [-1., 0., 0.], [1., 0., 0.], [0., 1., 0.], [0., 0., 1.]];
        let t = [[1., 1., 0.], [1., 0., 1.], [0., 1., 1.], [0., -1., 1.], [-1., 0., 1.], [-1., 1., 0.]];
        let mut m = DMatrix::zeros(6, 6);
        for j in 0..6 {
            let r = Vector3::from(p[j]) * rho;
            let a = Vector3::from(t[j]) * s;
            let rxa = r.cross(&a);
            for k in 0..3 {
                m[(j, k)] = rxa[k];
                m[(j, 3 + k)] = a[k];
            }
        }
        m.lu().try_inverse().expect("the cube's matrix is invertible")
    }

    /// A single bias on each accelerometer of the cube at rest (at a tilted attitude): the
    /// sensitivity columns and the mean squares of the four metrics follow the growth laws of the
    /// module docs to 1e-9 relative at 1-30 s, with `|c_alpha| = 5.0` rad/s^2 per m/s^2; the
    /// log-log slopes between 10 and 30 s are 1, 2, 3 and 4 within 0.1 (velocity and position once
    /// the gravity term dominates). Breaking the gravity coupling (`G`) or the RK4 weights fails it.
    #[test]
    fn one_bias_at_rest_follows_the_growth_laws() {
        let cube = Array::cube(0.1).expect("cube");
        let inv = cube_inverse(0.1);
        let layout = Layout::new(&cube, Form::Triad).expect("layout");
        let x = layout.pack(&ArrayParams::nominal(&cube)).expect("pack");
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let horizons = [1.0, 2.0, 5.0, 10.0, 30.0];
        let lin = linearise(&layout, &x, &Trajectory::rest(30.0, q), G, 0.01, &horizons, false).expect("linearise");
        let c = *q.to_rotation_matrix().matrix();
        let g_b = c.transpose() * Vector3::new(0.0, 0.0, -G);
        let sigma = 1e-3 * G; // a 1 mg bias
        for j in 0..6 {
            let c_alpha = Vector3::new(inv[(0, j)], inv[(1, j)], inv[(2, j)]);
            let c_a = Vector3::new(inv[(3, j)], inv[(4, j)], inv[(5, j)]);
            assert!((c_alpha.norm() - 5.0).abs() < 1e-12, "|c_alpha| of a{} = {}", j + 1, c_alpha.norm());
            let col = PER_ACCEL * j + 1;
            let mut ms_at = vec![];
            for (h, &t) in horizons.iter().enumerate() {
                let want = [
                    -c_alpha * t,
                    -c_alpha * (t * t / 2.0),
                    -(c * (c_a * t + g_b.cross(&c_alpha) * (t.powi(3) / 6.0))),
                    -(c * (c_a * (t * t / 2.0) + g_b.cross(&c_alpha) * (t.powi(4) / 24.0))),
                ];
                let s = &lin.sensitivity[h][col];
                let mut ms = [0.0; 4];
                for (m, w) in want.iter().enumerate() {
                    let o = METRIC_OFFSETS[m];
                    let got = Vector3::new(s[o], s[o + 1], s[o + 2]);
                    assert!((got - w).norm() <= 1e-9 * w.norm(), "a{} metric {m} at {t} s: {got} vs {w}", j + 1);
                    // Mean square for a bias ~ N(0, sigma^2): sigma^2 |column|^2.
                    let (got_ms, want_ms) = (sigma * sigma * got.norm_squared(), sigma * sigma * w.norm_squared());
                    assert!((got_ms / want_ms - 1.0).abs() < 1e-9, "a{} metric {m} at {t} s", j + 1);
                    ms[m] = got_ms;
                }
                ms_at.push(ms);
            }
            // Slopes of the RMS between 10 and 30 s.
            for (m, want) in [1.0, 2.0, 3.0, 4.0].iter().enumerate() {
                let slope = 0.5 * (ms_at[4][m] / ms_at[3][m]).ln() / 3f64.ln();
                assert!((slope - want).abs() < 0.1, "a{} metric {m}: slope {slope}", j + 1);
            }
        }
    }

    /// The same navigation, compensated with `x + eps u` and `x - eps u` by the real navigator
    /// (`nav::navigate`, which reports norms), against the sensitivity: the central difference
    /// `(|e(+eps u)| + |e(-eps u)|) / (2 eps)` equals `|S_b u|` for every metric and horizon, for
    /// random directions `u` mixing every parameter (so the Gram matrix of each block is checked,
    /// cross terms included), on the paper's manoeuvre (triad form) and on a tumbling segment
    /// trajectory (tilt form, Magnus truth).
    #[test]
    fn sensitivity_matches_central_differences_of_the_navigator() {
        let cube = Array::cube(0.1).expect("cube");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(31);
        let tumbling = Trajectory::new(
            crate::nav::InitialState {
                q_b_i: UnitQuaternion::from_euler_angles(0.1, -0.05, 0.5),
                omega_b_rad_s: Vector3::new(0.5, -0.3, 0.2),
                ..Default::default()
            },
            &[
                crate::nav::Segment {
                    duration_s: 1.2,
                    alpha_b_rad_s2: Vector3::new(0.2, 0.0, 0.4),
                    accel_i_m_s2: Vector3::new(2.0, 0.0, 0.0),
                },
                crate::nav::Segment {
                    duration_s: 1.0,
                    alpha_b_rad_s2: Vector3::new(-0.1, 0.3, 0.0),
                    accel_i_m_s2: Vector3::new(0.0, 1.0, 0.5),
                },
            ],
        );
        let cases = [(Form::Triad, Trajectory::paper_manoeuvre(2.0)), (Form::Tilt, tumbling)];
        let horizons = [0.5, 1.0, 2.0];
        let g_i = Vector3::new(0.0, 0.0, -G);
        let mut worst = 0.0_f64;
        for (form, trajectory) in &cases {
            let layout = Layout::new(&cube, *form).expect("layout");
            // A reference with every kind of error (the quickstart's scale).
            let mut x = layout.pack(&ArrayParams::nominal(&cube)).expect("pack");
            for j in 0..6 {
                let o = PER_ACCEL * j;
                x[o] *= 1.0 + rng.random_range(-5e-4..5e-4);
                x[o + 1] = rng.random_range(-1e-2..1e-2);
                for a in 2..4 {
                    x[o + a] = rng.random_range(-9e-3..9e-3);
                }
                for a in 4..7 {
                    x[o + a] = rng.random_range(-1e-3..1e-3);
                }
            }
            let lin = linearise(&layout, &x, trajectory, G, 0.01, &horizons, false).expect("linearise");
            let truth = layout.unpack(&x);
            let scale = [1e-6, 1e-5, 1e-6, 1e-6, 1e-7, 1e-7, 1e-7];
            for _ in 0..4 {
                let u = DVector::from_fn(layout.len(), |i, _| scale[i % PER_ACCEL] * rng.random_range(-1.0..1.0));
                let drift = |sign: f64| {
                    let comp = Compensator::new(&cube, &layout.unpack(&(&x + &u * sign))).expect("compensator");
                    let mut source = SimulatedArray::<rand_chacha::ChaCha8Rng>::new(&cube, &truth, trajectory, g_i);
                    navigate(trajectory, &mut source, &comp, &g_i, 0.01, &horizons)
                };
                let (plus, minus) = (drift(1.0), drift(-1.0));
                for h in 0..horizons.len() {
                    let fd = [
                        plus[h].rate_err_rad_s + minus[h].rate_err_rad_s,
                        plus[h].attitude_err_rad + minus[h].attitude_err_rad,
                        plus[h].velocity_err_m_s + minus[h].velocity_err_m_s,
                        plus[h].position_err_m + minus[h].position_err_m,
                    ];
                    for (m, fd) in fd.iter().enumerate() {
                        let lin_norm = lin.apply(h, m, &u).norm();
                        let rel = (fd / 2.0 / lin_norm - 1.0).abs();
                        worst = worst.max(rel);
                        assert!(rel < 1e-5, "{form:?} metric {m} at {} s: {} vs {lin_norm}", horizons[h], fd / 2.0);
                    }
                }
            }
        }
        eprintln!("worst relative difference from central differences: {worst:.2e}");
    }
}
