//! gfcal: error analysis and calibration of gyroscope-free inertial navigation arrays.
//!
//! A gyroscope-free inertial measurement unit senses rotation with N >= 6 single-axis
//! accelerometers placed away from the body origin (Chen, Lee & DeBra 1994). gfcal models
//! such an array, its sensor errors (bias, scale factor, misalignment, location) and the
//! navigation that integrates its outputs (Hung & Lee 2006, eq. 1-4), so that calibration
//! schedules and their residual errors can be studied.
//!
//! Conventions (see `docs/model.md`): SI units inside the library, units in every name
//! (`bias_m_s2`, `rate_rad_s`); body frame `b` at the array's geometric centre; inertial frame
//! `i` local, non-rotating, z up, gravity `(0, 0, -g)`. Specific force at a body point `r`:
//! `f(r) = a_o + alpha x r + omega x (omega x r) - g_b`.

pub mod array;
pub mod calib;
pub mod config;
pub mod discrepancy;
pub mod io;
pub mod lincov;
pub mod mc;
pub mod motion;
pub mod nav;
pub mod report;
pub mod rng;
pub mod selfcal;
pub mod sensor;
pub mod signal;
pub mod stats;
pub mod units;
