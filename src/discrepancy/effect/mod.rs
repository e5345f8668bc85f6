//! The effect library. Every effect is evaluated on a [`SampleContext`] and returns its
//! input-referred term (m/s^2) and, through `grad`, the term's derivatives by its parameters.

pub mod bias_temperature;
pub mod bias_time_drift;
pub mod gravity_magnitude;
pub mod pose_misalignment;
pub mod scale_factor_cubic;
pub mod scale_factor_quadratic;
pub mod scale_factor_temperature;
pub mod spin_axis_offset;
pub mod spin_rate_error;

use nalgebra::{Matrix3, Vector3};

/// What an effect sees of one sample of one accelerometer.
#[derive(Debug, Clone, Copy)]
pub struct SampleContext {
    /// Index of the step in the log.
    pub step: usize,
    /// Index of the step among the static steps (static steps only).
    pub static_index: Option<usize>,
    /// Index of the step among the spins (spins only).
    pub spin_index: Option<usize>,
    /// Time since the start of the log, s.
    pub t_s: f64,
    /// Temperature minus the reference, deg C (0 without a temperature column).
    pub temp_delta_c: f64,
    /// The accelerometer's reading of the baseline model, `a . f`, m/s^2.
    pub u_m_s2: f64,
    /// Its true axis (unnormalised in the triad form) and position `r + dr`, m.
    pub axis: Vector3<f64>,
    pub position_m: Vector3<f64>,
    /// Commanded up direction and `W = [omega x]^2`.
    pub up_b: Vector3<f64>,
    pub w2: Matrix3<f64>,
    pub g_m_s2: f64,
}

/// One sample of one accelerometer in the simulator's truth model: the physical motion and
/// sensor that an effect's generator changes (rather than adding its fitted term), so that a
/// test of the diagnosis does not take its truth from the term it fits.
#[derive(Debug, Clone, Copy)]
pub struct TruthSample {
    /// Index of the step among the static steps (static steps only), or among the spins.
    pub static_index: Option<usize>,
    pub spin_index: Option<usize>,
    pub t_s: f64,
    pub temp_delta_c: f64,
    /// The true up direction (unit, body axes), angular rate (rad/s) and gravity (m/s^2).
    pub up_b: Vector3<f64>,
    pub omega_b_rad_s: Vector3<f64>,
    pub g_m_s2: f64,
    /// The accelerometer's position relative to the point the array spins about, m.
    pub position_m: Vector3<f64>,
    /// Input-referred bias, m/s^2.
    pub bias_m_s2: f64,
    /// The sensor's response to its input `u`: `gain u + quadratic u^2 + cubic u^3`.
    pub gain: f64,
    pub quadratic_per_m_s2: f64,
    pub cubic_per_m2_s4: f64,
}

impl TruthSample {
    /// The input-referred reading (without noise) of an accelerometer with true axis `axis`:
    /// `bias + response(axis . f)`, `f = g up + omega x (omega x r)`.
    pub fn reading_m_s2(&self, axis: &Vector3<f64>) -> f64 {
        let w = self.omega_b_rad_s;
        let f = self.up_b * self.g_m_s2 + w.cross(&w.cross(&self.position_m));
        let u = axis.dot(&f);
        self.bias_m_s2 + self.gain * u + self.quadratic_per_m_s2 * u * u + self.cubic_per_m2_s4 * u * u * u
    }
}

/// Who owns an effect's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// One set per accelerometer.
    PerAccelerometer,
    /// One set for the whole log (the rate table, the site).
    Shared,
}

/// One physical effect.
pub trait Effect: Sync + Send {
    /// The library name (e.g. `scale_factor_quadratic`).
    fn name(&self) -> &'static str;
    fn scope(&self) -> Scope;
    /// Parameters per owner (per accelerometer, or for the log), given the log's step counts.
    fn parameters(&self, statics: usize, spins: usize) -> usize;
    /// Unit of the parameters (SI).
    fn unit(&self) -> &'static str;
    /// Whether the log needs a temperature column.
    fn needs_temperature(&self) -> bool {
        false
    }
    /// The term (m/s^2) for parameters `p`; `grad` (same length as `p`) receives its derivatives.
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64;
    /// The effect in the simulator's truth model: changes the physical sample (the motion or the
    /// sensor) for parameters `p`, independently of [`Effect::term`] (which is its first-order
    /// model).
    fn generate(&self, sample: &mut TruthSample, p: &[f64]);
}

/// Every effect of the library with a deterministic term, by name.
pub fn library() -> Vec<Box<dyn Effect>> {
    vec![
        Box::new(scale_factor_quadratic::ScaleFactorQuadratic),
        Box::new(scale_factor_cubic::ScaleFactorCubic),
        Box::new(bias_time_drift::BiasTimeDrift),
        Box::new(bias_temperature::BiasTemperature),
        Box::new(scale_factor_temperature::ScaleFactorTemperature),
        Box::new(spin_axis_offset::SpinAxisOffset),
        Box::new(spin_rate_error::SpinRateError),
        Box::new(gravity_magnitude::GravityMagnitude),
        Box::new(pose_misalignment::PoseMisalignment),
    ]
}

/// The effect of the library called `name`.
pub fn by_name(name: &str) -> Option<Box<dyn Effect>> {
    library().into_iter().find(|e| e.name() == name)
}
