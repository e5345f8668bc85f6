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
//! - [`fit`]: the joint estimator and its covariance;
//! - [`calibrate`]: the workflow; [`output`]: its JSON.

pub mod calibrate;
pub mod fit;
pub mod model;
pub mod motion;
pub mod output;
pub mod predict;
pub mod recording;
pub mod segment;
pub mod simulate;
pub mod track;
