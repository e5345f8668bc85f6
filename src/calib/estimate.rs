//! What an estimator returns, and the errors that stop one.

use nalgebra::{DMatrix, DVector};

use super::params::{Form, Layout};
use super::schedule::ScheduleError;
use crate::sensor::misalignment::MisalignmentError;
use crate::sensor::params::ArrayParams;

/// How a fit ended.
#[derive(Debug, Clone, PartialEq)]
pub struct FitStatus {
    pub converged: bool,
    /// Residual evaluations (Levenberg-Marquardt) or linear solves (the paper's procedure).
    pub iterations: usize,
    /// Final cost: half the sum of squared weighted residuals of the step means, (m/s^2)^2.
    pub cost: f64,
    /// Condition number of the Jacobian with columns scaled to unit norm.
    pub condition_number: f64,
    pub message: String,
}

/// Estimated parameters with their covariance.
#[derive(Debug, Clone)]
pub struct Estimate {
    pub form: Form,
    /// Parameter vector in `form` (see [`Layout`]).
    pub x: DVector<f64>,
    pub params: ArrayParams,
    /// Covariance of `x` from the Jacobian and the residual variance, SI units.
    pub covariance: DMatrix<f64>,
    /// Per-sample residual standard deviation, input-referred, m/s^2, at the sample rate of the
    /// schedule's first step (the residual white-noise density times the square root of that
    /// rate: with steps at several rates a per-sample sigma differs from step to step).
    pub residual_sigma_m_s2: f64,
    pub status: FitStatus,
}

impl Estimate {
    /// Standard deviation of each parameter, SI.
    pub fn sigma(&self) -> DVector<f64> {
        DVector::from_iterator(self.x.len(), (0..self.x.len()).map(|i| self.covariance[(i, i)].max(0.0).sqrt()))
    }
}

/// The largest misalignment angle inside the model's small-error region, rad. The triad form is
/// first order in its angles (its axes are not normalised): at 0.1 rad the neglected terms are
/// 0.5%, and real misalignments are milliradians.
pub const SMALL_ERROR_ANGLE_RAD: f64 = 0.1;

/// The model's small-error region (see [`outside_small_error_region`]): per parameter of `layout`
/// the largest magnitude inside, SI: the array's extent for a location, [`SMALL_ERROR_ANGLE_RAD`]
/// for a misalignment, infinite for scale factors and biases (no bound).
pub fn small_error_bounds(layout: &Layout) -> Vec<f64> {
    let extent_m = layout.array().accelerometers().iter().map(|a| a.position_m.norm()).fold(0.0, f64::max);
    (0..layout.len())
        .map(|i| match layout.kind(i) {
            super::params::ParamKind::Location(_) => extent_m,
            super::params::ParamKind::Misalignment(_) => SMALL_ERROR_ANGLE_RAD,
            _ => f64::INFINITY,
        })
        .collect()
}

/// Where an estimate `x` leaves the region in which the error model, linear in small errors
/// about the nominal geometry, holds: a misalignment angle beyond [`SMALL_ERROR_ANGLE_RAD`], or
/// a location error larger than the array itself (the largest distance of a nominal position
/// from the array's centre). A fit that runs off along a weak direction (a location seen only
/// through a small misalignment: a bilinear valley) ends there; it is not an answer, however low
/// its cost. Names the worst offender.
pub fn outside_small_error_region(layout: &Layout, x: &DVector<f64>) -> Option<String> {
    let bounds = small_error_bounds(layout);
    let mut worst: Option<(f64, String)> = None;
    for (i, &b) in bounds.iter().enumerate().take(x.len()) {
        let bound = match layout.kind(i) {
            super::params::ParamKind::Location(_) => format!("the array's extent {b} m"),
            super::params::ParamKind::Misalignment(_) => format!("{b} rad"),
            _ => continue,
        };
        let excess = x[i].abs() / b;
        let beyond = !excess.is_finite() || excess > 1.0;
        if beyond && worst.as_ref().is_none_or(|w| excess > w.0 || excess.is_nan()) {
            worst = Some((
                excess,
                format!("{} = {:.4e} {} exceeds {bound}", layout.name(i), x[i], layout.kind(i).si_unit()),
            ));
        }
    }
    worst.map(|w| w.1)
}

/// The residual white-noise density of a fit, m/s^2/sqrt(Hz), pooled over steps and
/// accelerometers: the within-step scatter of each step divided by its sample rate (a per-sample
/// variance at rate `r` is `d^2 r`), plus `misfit`, the weighted squared misfit of the step
/// means already in density units (each mean weighted by the time its samples span), over the
/// degrees of freedom left by `parameters`. `inv_k[j]` refers accelerometer j's output to its
/// input. NaN when no degree of freedom is left (as many parameters as samples): such a fit
/// passes through its data and says nothing of the noise (it used to divide by 1).
pub fn residual_density_m_s2_per_sqrt_hz(
    schedule: &super::schedule::Schedule,
    meas: &super::measure::Measurements,
    inv_k: &[f64],
    misfit: f64,
    parameters: usize,
) -> f64 {
    let within: f64 = schedule
        .steps()
        .iter()
        .zip(&meas.steps)
        .map(|(step, m)| m.within_ss.iter().zip(inv_k).map(|(ss, ik)| ss * ik * ik).sum::<f64>() / step.sample_rate_hz)
        .sum();
    let samples: usize = meas.steps.iter().map(|m| m.samples * inv_k.len()).sum();
    match samples.checked_sub(parameters) {
        Some(dof) if dof > 0 => ((within + misfit) / dof as f64).sqrt(),
        _ => f64::NAN,
    }
}

/// Why an estimator could not answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CalibError {
    #[error("the schedule cannot identify {}: {}", if parameters.len() == 1 { "this parameter" } else { "these parameters" }, parameters.join(", "))]
    Unidentifiable { parameters: Vec<String> },
    #[error(transparent)]
    Schedule(#[from] ScheduleError),
    #[error(transparent)]
    Misalignment(#[from] MisalignmentError),
    #[error("the paper's procedure needs {what}")]
    PaperProcedure { what: String },
    #[error("measurements do not fit the schedule: {problem}")]
    Measurements { problem: String },
}

/// Condition number of `j` after scaling its columns to unit norm (infinite when a column or a
/// direction is zero).
pub fn scaled_condition_number(j: &DMatrix<f64>) -> f64 {
    let mut js = j.clone();
    for mut c in js.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    let sv = js.singular_values();
    let (max, min) = (sv.max(), sv.min());
    if min > 0.0 { max / min } else { f64::INFINITY }
}

/// Checks that measurements have one entry per step and per accelerometer.
pub fn check_shape(layout: &Layout, steps: usize, m: &super::Measurements) -> Result<(), CalibError> {
    let n = layout.array().len();
    if m.steps.len() != steps {
        return Err(CalibError::Measurements {
            problem: format!("{} steps measured, schedule has {steps}", m.steps.len()),
        });
    }
    if let Some((i, s)) = m.steps.iter().enumerate().find(|(_, s)| s.mean.len() != n || s.within_ss.len() != n) {
        return Err(CalibError::Measurements {
            problem: format!("step {} has {} outputs, the array has {n}", i + 1, s.mean.len()),
        });
    }
    if let Some(i) = m.steps.iter().position(|s| s.mean.iter().chain(&s.within_ss).any(|v| !v.is_finite())) {
        return Err(CalibError::Measurements { problem: format!("step {} has a non-finite value", i + 1) });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::residual_density_m_s2_per_sqrt_hz;
    use crate::calib::measure::{Measurements, StepStats};
    use crate::calib::schedule::{Schedule, Step};

    /// Issue 30: with as many parameters as samples no degree of freedom is left and the residual
    /// density is NaN (it used to divide by 1); one degree of freedom divides by 1.
    #[test]
    fn no_residual_density_without_degrees_of_freedom() {
        let step = Step::static_pose("up", nalgebra::Vector3::z(), 0.02, 100.0);
        let schedule = Schedule::new("one", vec![step]).expect("a schedule");
        let mut stats = StepStats::empty(1);
        for v in [1.0, 3.0] {
            stats.push(&[v]);
        }
        // Two samples with scatter 2 (sum of squares about the mean): the within-step variance
        // at 100 Hz is 2 / 100 in density units.
        let meas = Measurements { steps: vec![stats] };
        let one = residual_density_m_s2_per_sqrt_hz(&schedule, &meas, &[1.0], 0.0, 1);
        assert!((one - (2.0f64 / 100.0).sqrt()).abs() < 1e-15, "{one}");
        assert!(residual_density_m_s2_per_sqrt_hz(&schedule, &meas, &[1.0], 0.0, 2).is_nan());
        assert!(residual_density_m_s2_per_sqrt_hz(&schedule, &meas, &[1.0], 0.0, 7).is_nan());
    }
}
