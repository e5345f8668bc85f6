//! Parameters of every accelerometer of an array: true, nominal or estimated.

use nalgebra::Vector3;

use crate::array::{Array, FoldedSolve, Mechanization, RankError};
use crate::motion::RigidMotion;

/// Error parameters of one accelerometer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorParams {
    /// Scale factor `k`, output units per m/s^2.
    pub scale_factor: f64,
    /// Bias `b`, m/s^2 (input-referred: the output is `k (b + ...)`).
    pub bias_m_s2: f64,
    /// True sensitive axis in body axes. Unit length in the tilt form; in the paper's triad form it
    /// is `C_a^a' C_b^a`'s row, which is not normalised.
    pub axis: Vector3<f64>,
    /// Location error `dr` (true position minus nominal), body axes, m.
    pub location_error_m: Vector3<f64>,
}

/// Parameters of all N accelerometers, in array order.
#[derive(Debug, Clone, PartialEq)]
pub struct ArrayParams {
    pub sensors: Vec<SensorParams>,
}

impl ArrayParams {
    /// Nominal parameters: scale factor 1, no bias, nominal axes and positions.
    pub fn nominal(array: &Array) -> Self {
        Self::nominal_with_scale_factors(array, &vec![1.0; array.len()])
    }

    /// Nominal parameters with the given (datasheet) scale factors.
    pub fn nominal_with_scale_factors(array: &Array, scale_factors: &[f64]) -> Self {
        assert_eq!(scale_factors.len(), array.len());
        let sensors = array
            .accelerometers()
            .iter()
            .zip(scale_factors)
            .map(|(a, &k)| SensorParams {
                scale_factor: k,
                bias_m_s2: 0.0,
                axis: a.axis,
                location_error_m: Vector3::zeros(),
            })
            .collect();
        Self { sensors }
    }

    pub fn len(&self) -> usize {
        self.sensors.len()
    }
    pub fn is_empty(&self) -> bool {
        self.sensors.is_empty()
    }

    /// True (or estimated) positions `r_j + dr_j`, m.
    pub fn positions_m(&self, array: &Array) -> Vec<Vector3<f64>> {
        array.accelerometers().iter().zip(&self.sensors).map(|(a, s)| a.position_m + s.location_error_m).collect()
    }

    /// Noise-free outputs for a motion, in output units: `k_j (b_j + theta'_j . f(r_j + dr_j))`.
    pub fn outputs(&self, array: &Array, motion: &RigidMotion, out: &mut [f64]) {
        debug_assert_eq!(out.len(), self.len());
        for ((o, s), a) in out.iter_mut().zip(&self.sensors).zip(array.accelerometers()) {
            let f = motion.specific_force_m_s2(&(a.position_m + s.location_error_m));
            *o = s.scale_factor * (s.bias_m_s2 + s.axis.dot(&f));
        }
    }
}

/// Compensation of raw outputs with a set of parameters: removes scale factor and bias and solves
/// for the rigid-body accelerations with the parameters' axes and positions.
#[derive(Debug, Clone)]
pub struct Compensator {
    mechanization: Mechanization,
    /// The solve folded with the scale factors and biases (one linear map; `array::folded`).
    folded: FoldedSolve,
}

impl Compensator {
    /// Fails when the parameters' geometry is degenerate (or a scale factor is zero).
    pub fn new(array: &Array, params: &ArrayParams) -> Result<Self, RankError> {
        let axes: Vec<_> = params.sensors.iter().map(|s| s.axis).collect();
        let mechanization = Mechanization::new(&params.positions_m(array), &axes)?;
        let scale: Vec<f64> = params.sensors.iter().map(|s| s.scale_factor).collect();
        let bias: Vec<f64> = params.sensors.iter().map(|s| s.bias_m_s2).collect();
        let folded = FoldedSolve::new(&mechanization, &scale, &bias);
        Ok(Self { mechanization, folded })
    }

    /// The folded solve of this compensation (one linear map; `array::folded`).
    pub fn folded(&self) -> &FoldedSolve {
        &self.folded
    }

    pub fn mechanization(&self) -> &Mechanization {
        &self.mechanization
    }
}

/// Random parameters near `array`'s nominal ones (scale factors within 1e-3 of 1, biases within
/// 0.05 m/s^2, axes tilted by up to about 0.01, locations within 2 mm), for tests.
#[cfg(test)]
pub(crate) fn random_params(array: &Array, rng: &mut impl rand::Rng) -> ArrayParams {
    use rand::RngExt;
    let mut v = |s: f64| Vector3::from_fn(|_, _| rng.random_range(-s..s));
    let sensors = array
        .accelerometers()
        .iter()
        .map(|a| SensorParams {
            scale_factor: 1.0 + v(1e-3).x,
            bias_m_s2: v(0.05).y,
            axis: (a.axis + v(0.01)).normalize(),
            location_error_m: v(2e-3),
        })
        .collect();
    ArrayParams { sensors }
}
