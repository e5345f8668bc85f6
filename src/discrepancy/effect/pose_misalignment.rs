//! `pose_misalignment`: each static pose is off its commanded direction by a small rotation
//! `delta` (two angles per static step, about the directions `u`, `w` orthogonal to the commanded
//! up, as for the tilt form): the true up is `up + delta x up` to first order, so
//! `e = g a . (tilt(up, t) - up)` ~ `g a . (t1 u + t2 w)`, with `(u, w)` from [`crate::sensor::misalignment::tilt_basis`].
//! Regressors: `g a . u`, `g a . w` of that step. Shared (the fixture), zero in spins.

use super::{Effect, SampleContext, Scope};
use crate::sensor::misalignment::tilt_axis_with_derivatives;

pub struct PoseMisalignment;

impl Effect for PoseMisalignment {
    fn name(&self) -> &'static str {
        "pose_misalignment"
    }
    fn scope(&self) -> Scope {
        Scope::Shared
    }
    fn parameters(&self, statics: usize, _: usize) -> usize {
        2 * statics
    }
    fn unit(&self) -> &'static str {
        "rad"
    }
    fn generate(&self, sample: &mut super::TruthSample, p: &[f64]) {
        // The pose is rotated (exactly) by the rotation vector t1 (up x u) + t2 (up x w), which
        // carries up toward u by t1 and toward w by t2.
        let Some(i) = sample.static_index else { return };
        let (u, w) = crate::sensor::misalignment::tilt_basis(&sample.up_b);
        let rotation = sample.up_b.cross(&u) * p[2 * i] + sample.up_b.cross(&w) * p[2 * i + 1];
        sample.up_b = nalgebra::Rotation3::from_scaled_axis(rotation) * sample.up_b;
    }
    fn term(&self, ctx: &SampleContext, p: &[f64], grad: &mut [f64]) -> f64 {
        grad.iter_mut().for_each(|g| *g = 0.0);
        let Some(i) = ctx.static_index else { return 0.0 };
        // The true up is the commanded one tilted by (t1, t2); at zero the regressors are
        // g a . u and g a . w.
        let (up, d) = tilt_axis_with_derivatives(&ctx.up_b, &[p[2 * i], p[2 * i + 1]]);
        grad[2 * i] = ctx.g_m_s2 * ctx.axis.dot(&d[0]);
        grad[2 * i + 1] = ctx.g_m_s2 * ctx.axis.dot(&d[1]);
        ctx.g_m_s2 * ctx.axis.dot(&(up - ctx.up_b))
    }
}
