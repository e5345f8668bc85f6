//! Calibration of a real accelerometer array from a free recording: poses placed by hand (of
//! unknown attitude), then free rotation by hand, with no rate table and no gyroscope. The
//! angular rate comes from the accelerometers' centripetal terms (the gyroscope-free idea of
//! Hung & Lee 2006); reference gyroscopes, where a recording has them, only check the result
//! (or, with `use_gyro`, supply the rate as in Carlsson, Skog & Jalden 2021).
//!
//! - [`recording`]: the table and the array file's columns, ranges and reference gyroscopes;
//! - [`segment`]: static intervals and the dynamic phase from the accelerometers alone;
//! - [`model`]: parameters, the output model and its derivatives, the gauge;
//! - [`motion`]: the motion of one sample (rate sign by continuity);
//! - [`track`]: the motion of every sample of the rotation phase (basins repaired, signed, sigmas);
//! - [`branch`]: a clocked rotation phase's rate branches (sign, the thin plane's reflection) on a path;
//! - [`data`]: the two phases' data, shared by the estimator, the tracker and the prediction;
//! - [`fit`]: the joint estimator and its covariance; [`robust`]: the covariance from the scores' spread
//!   over blocks of samples (a clocked calibration's); [`huber`]: the weights that keep a clocked
//!   rotation phase's heavy tail from leading it; [`unseen`]: what it cannot see beyond the
//!   gauge; [`geometry`]: what an array's geometry cannot see, on synthetic data;
//! - [`timing_information`]: a clocked calibration's dynamic information and scores with each
//!   sample's timing motion eliminated (what [`robust`] inverts for a clocked calibration);
//! - [`lag`]: the accelerometers' lag behind the reference gyroscopes (the rate `--use-gyro` takes);
//! - [`misfit`]: the rotation phase's chi^2/dof, one metric for calibrate and diagnose;
//! - [`tension`]: the static phase refitted alone, against the joint fit; [`static_drift`]: the
//!   static phase refitted with a bias drift in time, and its test;
//! - [`clocked`]: the packages' sample clocks fitted with the calibration (its outer iterations);
//! - [`gyro_check`]: the gyroscope-free rate against the reference gyroscopes;
//! - [`calibrate`]: the workflow; [`output`]: its JSON; [`assessment`]: what to trust in it.

pub mod assessment;
pub mod branch;
pub mod calibrate;
pub mod clock;
pub mod clocked;
pub mod data;
pub mod drift;
pub mod filter;
pub mod fit;
pub mod geometry;
pub mod gyro_check;
pub mod huber;
pub mod lag;
pub mod misfit;
pub mod model;
pub mod motion;
pub mod output;
pub mod predict;
pub mod recording;
pub mod robust;
pub mod sampling;
mod schur;
pub mod segment;
pub mod simulate;
pub mod static_drift;
pub mod tension;
pub mod timing;
pub mod timing_information;
pub mod track;
pub mod unseen;
pub mod vibration;
