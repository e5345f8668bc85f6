//! Linear covariance analysis (LinCov): the drift a calibration leaves, without Monte Carlo.
//!
//! The navigation's error is propagated to first order along the reference trajectory, once,
//! and every source of error (the residual calibration errors, the fixture's pose errors as they
//! enter the calibration, the navigation's white noise) enters through the same linear map. A
//! drift metric is then the norm of a Gaussian 3-vector, whose distribution is computed exactly
//! ([`norm`]).
//!
//! # The error dynamics
//!
//! The navigator (`nav`) integrates `q' = q (0, omega) / 2`, `omega' = alpha`, `v' = C a_o`,
//! `r' = v` with `(alpha, a_o) = P y` solved from the compensated readings,
//! `y_j = m_j - a_j . (omega x (omega x r_j)) + a_j . g_b`, `m_j = s_j / k_j - b_j`, where
//! `a_j`, `r_j`, `k_j`, `b_j` and the pseudo-inverse `P` come from the compensation's parameters
//! and `omega`, `g_b = C^T g_i` from the navigated state. Let the compensation be `x + dx` while
//! the outputs come from an array with parameters `x` (the reference, where the navigation is
//! exact). The errors are `phi` (body axes: `q_nav = q (1, phi / 2)`, so the attitude metric is
//! `|phi|`), `d omega`, `d v`, `d r`. With `z = (alpha, a_o)` the true accelerations, the solve
//! of a consistent right-hand side `y = M z` moves by `dz = P (dy - dM z)` (also for N > 6:
//! `dP y = -P dM z` because `(I - M P) M = 0`), and row j of `dy - dM z` is the derivative of
//! the reading residual `e_j = s_j / k_j - b_j - a_j . f(r_j)` (`f` the specific force the
//! navigation assumes). To first order:
//!
//! ```text
//! phi'     = d omega - omega x phi
//! d omega' = P_alpha (E(t) dx + n - K d omega + G phi)
//! d v'     = C (P_a (E(t) dx + n - K d omega + G phi) - a_o x phi)
//! d r'     = d v
//! ```
//!
//! with `n` the navigation's white noise (input-referred), and rows
//! `K_j = a_j^T ((omega . r_j) I + omega r_j^T - 2 r_j omega^T)` (the centripetal term's
//! derivative by the rate), `G_j = (a_j x g_b)^T` (gravity rotated by the attitude error:
//! `d g_b = g_b x phi`) and `E_j(t) = d e_j / d x_j`:
//!
//! ```text
//! d e/d k = -(b + a . f) / k    d e/d b = -1    d e/d m_i = -(d a/d m_i) . f
//! d e/d dr = -(a x alpha + (a . omega) omega - |omega|^2 a)
//! ```
//!
//! (`d a / d m_i` from the layout's misalignment form, so the triad form's coupling of angle and
//! scale factor is carried.) Since `P M = I`, `P_alpha G = 0`: at the reference an attitude error
//! moves no angular acceleration, only the linear one (`P_a G phi = g_b x phi`).
//!
//! **Variational equations, on the navigator's own steps.** These equations are integrated by the
//! navigator's RK4 on the navigator's steps (`nav::Plan`: the same stage times, the midpoint's
//! motion used twice), for the sensitivity `S = d error / d dx` (12 x 7N, one column per
//! parameter) and, with noise, for the covariance `Q_{k+1} = Phi_k Q_k Phi_k^T + sigma^2 Gamma_k
//! Gamma_k^T` of the noise held over each step (`sigma^2 = density^2 / step_s`, as the
//! navigator's noisy source draws it). RK4 applied to the linearised equations is the derivative
//! of RK4 applied to the nonlinear ones (Runge-Kutta methods commute with linearisation), so `S`
//! is the navigator's own sensitivity up to the quaternion's renormalisation (a fifth-order
//! difference per step); the tests check it against central differences of the navigator.
//! A sensitivity matrix built by finite differences would cost 2 x 7N navigations and carry their
//! truncation error; the variational equations cost about one navigation of 7N + 12 columns.
//!
//! # Growth laws: one bias on the cube at rest
//!
//! At rest with `omega = 0`, `a_o = 0`, a compensation bias off by `db` on accelerometer j makes
//! `e_j = -db`, so with `c_alpha = P_alpha[:, j]`, `c_a = P_a[:, j]` and attitude `C`:
//!
//! ```text
//! d omega(t) = -db c_alpha t                      phi(t) = -db c_alpha t^2 / 2
//! d v(t) = -db C (c_a t + g_b x c_alpha t^3 / 6)   d r(t) = -db C (c_a t^2 / 2 + g_b x c_alpha t^4 / 24)
//! ```
//!
//! so the rate, attitude, velocity and position errors grow as t, t^2, t^3 and t^4 (the last two
//! once the gravity term dominates) and, for `db ~ N(0, s^2)`, their mean squares are
//! `s^2 |c_alpha|^2 t^2`, `s^2 |c_alpha|^2 t^4 / 4`, `s^2 |c_a t + g_b x c_alpha t^3 / 6|^2` and
//! `s^2 |c_a t^2 / 2 + g_b x c_alpha t^4 / 24|^2`. On the paper's cube (rho = 0.1 m) `|c_alpha|`
//! is 5.0 rad/s^2 per m/s^2 for every accelerometer (docs/model.md's constant). The error system
//! is then nilpotent with constant forcing, its solution a polynomial of degree 4 in t, and RK4 is
//! exact for it: the test asserts these laws to 1e-9.
//!
//! # From covariance to drift
//!
//! A compensation's error is `S dx (+ noise)` with `dx` Gaussian by assumption:
//! - `nominal`: `dx = x_nominal - x_true`, mean and covariance from the error distributions
//!   (a uniform one enters by its mean and variance);
//! - `estimated`: `dx = x_estimated - x_true ~ N(0, F(x_true)^-1)`, the Cramer-Rao covariance of
//!   the schedule at the true errors with the fixture's tilts marginalised under their prior
//!   (`calib::pose::marginal_fisher`, as `gfcal identify` does). It depends on the truth, so
//!   when the errors are random the drift is a mixture over drawn truths, each
//!   weighted by the chance that its fit stays in the model's small-error region (the Monte
//!   Carlo refuses the fits that leave it) and with the covariance of the fits that stay
//!   (`analysis`);
//! - `true`: no parameter error, only the navigation's noise (when `navigation.noise` is on).
//!
//! The sensitivity is evaluated at the centre of the error distributions (the reference); its
//! change across truths is second order in the errors and belongs to the nonlinearity index.

pub mod analysis;
pub mod compare;
pub mod design;
pub mod dynamics;
pub mod nonlinearity;
pub mod norm;
pub mod output;
pub mod ranking;
pub mod run;
pub mod sources;
pub mod stacked;
