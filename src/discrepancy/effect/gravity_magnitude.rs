//! `gravity_magnitude`: local gravity is `(1 + gamma)` times the value assumed,
//! `e = gamma g a . up`. Regressor: `g a . up`. Shared.

use super::{Effect, SampleContext, Scope};

pub struct GravityMagnitude;

impl Effect for GravityMagnitude {
    fn name(&self) -> &'static str {
        "gravity_magnitude"
    }
    fn scope(&self) -> Scope {
        Scope::Shared
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        1
    }
    fn unit(&self) -> &'static str {
        "1"
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        // Local gravity differs from the assumed value by the fraction p.
        sample.g_m_s2 *= 1.0 + p[0];
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        let r = ctx.g_m_s2 * ctx.axis.dot(&ctx.up_b);
        grad[0] = r;
        p[0] * r
    }
}
