//! Parameters of every accelerometer of an array: true, nominal or estimated.

use nalgebra::Vector3;

use crate::array::{Array, Mechanization, RankError, RigidAccel};
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
    inv_scale: Vec<f64>,
    bias_m_s2: Vec<f64>,
    mechanization: Mechanization,
}

impl Compensator {
    /// Fails when the parameters' geometry is degenerate (or a scale factor is zero).
    pub fn new(array: &Array, params: &ArrayParams) -> Result<Self, RankError> {
        let axes: Vec<_> = params.sensors.iter().map(|s| s.axis).collect();
        let mechanization = Mechanization::new(&params.positions_m(array), &axes)?;
        Ok(Self {
            inv_scale: params.sensors.iter().map(|s| 1.0 / s.scale_factor).collect(),
            bias_m_s2: params.sensors.iter().map(|s| s.bias_m_s2).collect(),
            mechanization,
        })
    }

    /// The reading of output `s` of accelerometer `j`, `s / k_j - b_j` (m/s^2), as `s (1 / k_j) - b_j`.
    #[inline(always)]
    pub fn reading_m_s2(&self, j: usize, output: f64) -> f64 {
        output * self.inv_scale[j] - self.bias_m_s2[j]
    }

    /// `(alpha, a_o)` in body axes from raw outputs, current body rate and gravity in body axes.
    pub fn rigid_accel(
        &self,
        outputs: &[f64],
        omega_b_rad_s: &Vector3<f64>,
        gravity_b_m_s2: &Vector3<f64>,
    ) -> RigidAccel {
        let readings: Vec<f64> = outputs.iter().enumerate().map(|(j, s)| self.reading_m_s2(j, *s)).collect();
        self.mechanization.solve(&readings, omega_b_rad_s, gravity_b_m_s2)
    }

    /// `1 / k_j` per accelerometer.
    pub fn inv_scale(&self) -> &[f64] {
        &self.inv_scale
    }

    pub fn bias_m_s2(&self) -> &[f64] {
        &self.bias_m_s2
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
