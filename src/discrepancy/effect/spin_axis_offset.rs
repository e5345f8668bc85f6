//! `spin_axis_offset`: the rate table's axis misses the array centre by `d` (body axes, m, the
//! same mounting for every spin), so each accelerometer spins about a point offset by `-d`:
//! `e = a . W (-d)`. Regressor: `-W a`. Shared; zero in static poses. The component of `d`
//! along a spin's axis has no effect in that spin.

use super::{Effect, SampleContext, Scope};

pub struct SpinAxisOffset;

impl Effect for SpinAxisOffset {
    fn name(&self) -> &'static str {
        "spin_axis_offset"
    }
    fn scope(&self) -> Scope {
        Scope::Shared
    }
    fn parameters(&self, _: usize, _: usize) -> usize {
        3
    }
    fn unit(&self) -> &'static str {
        "m"
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        // The table spins about the point d: every position is taken from there.
        sample.position_m -= nalgebra::Vector3::new(p[0], p[1], p[2]);
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        let wa = -(ctx.w2 * ctx.axis);
        grad.copy_from_slice(wa.as_slice());
        wa.x * p[0] + wa.y * p[1] + wa.z * p[2]
    }
}
