//! The accelerometer array: nominal geometry, the mechanization derived from it, and the array
//! file's wiring (columns, ranges, reference gyroscopes).
//!
//! Accelerometer `j` sits at `r_j` (body frame, m) with unit sensitive axis `theta_j`. An ideal
//! accelerometer reads `theta_j . f(r_j)`; stacking N readings gives a linear system in the
//! angular acceleration `alpha` and the origin's acceleration `a_o` whose N x 6 matrix has rows
//! `[(r_j x theta_j)^T, theta_j^T]` (see [`mechanization`]).

pub mod geometry;
pub mod mechanization;
pub mod wiring;

pub use geometry::{Accelerometer, Array, ArrayError};
pub use mechanization::{Mechanization, RankError, RigidAccel};
