//! `scale_factor_temperature`: the scale factor follows the temperature,
//! `e = C_k (T - T_ref) u` (C_k in 1/degC). Regressor: `(T - T_ref) u`. Per accelerometer;
//! needs `temp_c`.

use super::{Effect, SampleContext, Scope};

pub struct ScaleFactorTemperature;

impl Effect for ScaleFactorTemperature {
    fn name(&self) -> &'static str {
        "scale_factor_temperature"
    }
    fn scope(&self) -> Scope {
        Scope::PerAccelerometer
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        1
    }
    fn unit(&self) -> &'static str {
        "1/degC"
    }
    fn needs_temperature(&self) -> bool {
        true
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        // The sensitivity to the input follows the temperature.
        sample.gain *= 1.0 + p[0] * sample.temp_delta_c;
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        let r = ctx.temp_delta_c * ctx.u_m_s2;
        grad[0] = r;
        p[0] * r
    }
}
