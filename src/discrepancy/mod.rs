//! Model discrepancy: calibration logs, the library of physical effects the baseline model
//! leaves out, and their diagnosis:
//! [`log`] for calibration logs, [`recorded`] for real recordings, [`inject`] to add a known
//! effect to a recording.
//!
//! The baseline model of a sample of accelerometer j is `s_j = k_j (b_j + u_j)`, with
//! `u_j = a_j . f(r_j + dr_j)` and `f = g up + W r` in a static pose or a spin. An effect adds an
//! input-referred term `e_j(p)` (m/s^2), so `s_j = k_j (b_j + u_j + e_j(p))`; its parameters `p`
//! belong to one accelerometer or are shared by all (a rate-table or gravity effect). Each effect
//! is one module of [`effect`]: its term, its parameters, and its regressor (the gradient of the
//! term by its parameters at zero, which is what a fit of the extended model uses).

pub mod effect;
pub mod explanation;
pub mod inject;
pub mod log;
pub mod recorded;

pub use explanation::Explanation;
