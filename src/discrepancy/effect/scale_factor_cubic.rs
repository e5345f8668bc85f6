//! `scale_factor_cubic`: a third-order term in the input, `e = K3 u^3` (K3 in 1/(m/s^2)^2).
//! Regressor: `u^3`. Per accelerometer.

use super::{Effect, SampleContext, Scope};

pub struct ScaleFactorCubic;

impl Effect for ScaleFactorCubic {
    fn name(&self) -> &'static str {
        "scale_factor_cubic"
    }
    fn scope(&self) -> Scope {
        Scope::PerAccelerometer
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        1
    }
    fn unit(&self) -> &'static str {
        "1/(m/s^2)^2"
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        sample.cubic_per_m2_s4 += p[0];
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        let r = ctx.u_m_s2.powi(3);
        grad[0] = r;
        p[0] * r
    }
}
