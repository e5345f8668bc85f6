//! `scale_factor_quadratic`: a second-order term in the input, `e = K2 u^2` (K2 in 1/(m/s^2);
//! datasheets give it in ug/g^2). Regressor: `u^2`. Per accelerometer.

use super::{Effect, SampleContext, Scope};

pub struct ScaleFactorQuadratic;

impl Effect for ScaleFactorQuadratic {
    fn name(&self) -> &'static str {
        "scale_factor_quadratic"
    }
    fn scope(&self) -> Scope {
        Scope::PerAccelerometer
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        1
    }
    fn unit(&self) -> &'static str {
        "1/(m/s^2)"
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        sample.quadratic_per_m_s2 += p[0];
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        let r = ctx.u_m_s2 * ctx.u_m_s2;
        grad[0] = r;
        p[0] * r
    }
}
