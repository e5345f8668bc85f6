//! `bias_time_drift`: the bias drifts linearly over the log, `e = D t` (D in m/s^2/s).
//! Regressor: `t`. Per accelerometer.

use super::{Effect, SampleContext, Scope};

pub struct BiasTimeDrift;

impl Effect for BiasTimeDrift {
    fn name(&self) -> &'static str {
        "bias_time_drift"
    }
    fn scope(&self) -> Scope {
        Scope::PerAccelerometer
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        1
    }
    fn unit(&self) -> &'static str {
        "m/s^2/s"
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        // The bias drifts with time.
        sample.bias_m_s2 += p[0] * sample.t_s;
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        grad[0] = ctx.t_s;
        p[0] * ctx.t_s
    }
}
