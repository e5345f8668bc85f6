//! Unit conversions used at the edges (config parsing, report writing), never inside the physics.

/// Standard gravity, m/s^2 (the default local gravity unless a config gives one).
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;
/// One milli-g in m/s^2 (standard gravity).
pub const M_S2_PER_MG: f64 = STANDARD_GRAVITY_M_S2 * 1e-3;
/// One micro-g in m/s^2 (standard gravity).
pub const M_S2_PER_UG: f64 = STANDARD_GRAVITY_M_S2 * 1e-6;
/// One millimetre in metres.
pub const M_PER_MM: f64 = 1e-3;
/// One arc second in radians.
pub const RAD_PER_ARCSEC: f64 = std::f64::consts::PI / (180.0 * 3600.0);
/// One degree in radians.
pub const RAD_PER_DEG: f64 = std::f64::consts::PI / 180.0;
