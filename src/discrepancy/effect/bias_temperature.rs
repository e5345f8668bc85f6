//! `bias_temperature`: the bias follows the temperature, `e = C_b (T - T_ref)` (C_b in
//! m/s^2/degC). Regressor: `T - T_ref`. Per accelerometer; needs `temp_c`.

use super::{Effect, SampleContext, Scope};

pub struct BiasTemperature;

impl Effect for BiasTemperature {
    fn name(&self) -> &'static str {
        "bias_temperature"
    }
    fn scope(&self) -> Scope {
        Scope::PerAccelerometer
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        1
    }
    fn unit(&self) -> &'static str {
        "m/s^2/degC"
    }
    fn needs_temperature(&self) -> bool {
        true
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        // The bias follows the temperature.
        sample.bias_m_s2 += p[0] * sample.temp_delta_c;
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        grad[0] = ctx.temp_delta_c;
        p[0] * ctx.temp_delta_c
    }
}
