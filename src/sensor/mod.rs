//! The error model of each accelerometer and its noise.
//!
//! `s_j = k_j (b_j + theta'_j . f(r_j + dr_j)) + noise` (Hung & Lee 2006, eq. 8, without the
//! integration into pulses): `k_j` scale factor (output units per m/s^2), `b_j` bias (m/s^2),
//! `theta'_j` true sensitive axis (not necessarily unit: see [`misalignment`]), `dr_j` location
//! error (m).

pub mod misalignment;
pub mod noise;
pub mod params;

pub use misalignment::{Misalignment, TriadAngles};
pub use noise::{NoiseGenerator, NoiseSpec, WhiteNoise};
pub use params::{ArrayParams, Compensator, SensorParams};
