//! `spin_rate_error`: the table turns at `(1 + eps)` times the commanded rate, so `W` becomes
//! `(1 + eps)^2 W`: `e = ((1 + eps)^2 - 1) a . W (r + dr)`. Regressor at `eps = 0`:
//! `2 a . W (r + dr)`. Shared; zero in static poses.

use super::{Effect, SampleContext, Scope};

pub struct SpinRateError;

impl Effect for SpinRateError {
    fn name(&self) -> &'static str {
        "spin_rate_error"
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
        // The table spins faster by the fraction p.
        sample.omega_b_rad_s *= 1.0 + p[0];
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        let c = ctx.axis.dot(&(ctx.w2 * ctx.position_m));
        grad[0] = 2.0 * (1.0 + p[0]) * c;
        ((1.0 + p[0]).powi(2) - 1.0) * c
    }
}
