//! The joint estimator: every parameter of every accelerometer from every step, by nonlinear
//! least squares (Levenberg-Marquardt, from the `levenberg-marquardt` crate).
//!
//! Residual of step s, accelerometer j: `sqrt(n_s) (mean_sj - s_j(x)) / k0_j`, input-referred
//! (m/s^2) with the starting scale factor `k0_j` as a fixed weight, so the cost is the per-sample
//! least-squares cost up to the within-step scatter. The covariance is
//! `sigma^2 (J^T J)^-1`, `sigma^2` the per-sample residual variance (within-step scatter plus the
//! misfit of the means, over the degrees of freedom).

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

use super::estimate::{CalibError, Estimate, FitStatus, check_shape, scaled_condition_number};
use super::fisher::structurally_unidentifiable;
use super::measure::Measurements;
use super::params::{Form, Layout, PER_ACCEL};
use super::schedule::Schedule;
use crate::sensor::params::ArrayParams;

/// Where the joint fit starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// The nominal parameters given.
    Nominal,
    /// A linear first guess: per accelerometer, `s = c + v . (g up)` on the static steps, then the
    /// location errors from the spins (the paper's procedure, generalised); nominal if the
    /// schedule does not allow it.
    Linear,
}

struct Problem<'a> {
    layout: &'a Layout,
    schedule: &'a Schedule,
    meas: &'a Measurements,
    g_m_s2: f64,
    inv_k0: Vec<f64>,
    x: DVector<f64>,
}

impl Problem<'_> {
    fn rows(&self) -> usize {
        self.schedule.len() * self.layout.array().len()
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let n = self.layout.array().len();
        let mut r = DVector::zeros(self.rows());
        let mut out = vec![0.0; n];
        for (s, (step, m)) in self.schedule.steps().iter().zip(&self.meas.steps).enumerate() {
            self.layout.step_model(&self.x, step, self.g_m_s2, &mut out, None);
            let w = (m.samples as f64).sqrt();
            for j in 0..n {
                r[s * n + j] = w * (m.mean[j] - out[j]) * self.inv_k0[j];
            }
        }
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let n = self.layout.array().len();
        let mut jm = DMatrix::zeros(self.rows(), self.layout.len());
        let mut out = vec![0.0; n];
        let mut jac = vec![[0.0; PER_ACCEL]; n];
        for (s, (step, m)) in self.schedule.steps().iter().zip(&self.meas.steps).enumerate() {
            self.layout.step_model(&self.x, step, self.g_m_s2, &mut out, Some(&mut jac));
            let w = (m.samples as f64).sqrt();
            for (j, gj) in jac.iter().enumerate() {
                for (a, v) in gj.iter().enumerate() {
                    jm[(s * n + j, PER_ACCEL * j + a)] = -w * v * self.inv_k0[j];
                }
            }
        }
        jm.iter().all(|v| v.is_finite()).then_some(jm)
    }
}

/// Fits every parameter (see the module docs). `nominal` gives the starting point (and the
/// weights); refuses a schedule that cannot identify some parameter, naming it.
pub fn estimate(
    layout: &Layout,
    schedule: &Schedule,
    meas: &Measurements,
    nominal: &ArrayParams,
    start: Start,
    g_m_s2: f64,
) -> Result<Estimate, CalibError> {
    check_shape(layout, schedule.len(), meas)?;
    check_identifiable(layout, schedule, nominal, g_m_s2)?;
    estimate_unchecked(layout, schedule, meas, nominal, start, g_m_s2)
}

/// Refuses a schedule that cannot identify some parameter, naming it (see
/// [`structurally_unidentifiable`]).
pub fn check_identifiable(
    layout: &Layout,
    schedule: &Schedule,
    nominal: &ArrayParams,
    g_m_s2: f64,
) -> Result<(), CalibError> {
    let x_nominal = layout.pack(nominal)?;
    let unidentifiable = structurally_unidentifiable(layout, &x_nominal, schedule, g_m_s2);
    if unidentifiable.is_empty() {
        Ok(())
    } else {
        Err(CalibError::Unidentifiable { parameters: unidentifiable.iter().map(|&i| layout.name(i)).collect() })
    }
}

/// [`estimate`] without the identifiability check, for many fits of one schedule (check once).
pub fn estimate_unchecked(
    layout: &Layout,
    schedule: &Schedule,
    meas: &Measurements,
    nominal: &ArrayParams,
    start: Start,
    g_m_s2: f64,
) -> Result<Estimate, CalibError> {
    check_shape(layout, schedule.len(), meas)?;
    let x_nominal = layout.pack(nominal)?;
    let x0 = match start {
        Start::Nominal => x_nominal,
        Start::Linear => super::paper::linear_guess(layout, schedule, meas, g_m_s2)
            .ok()
            .and_then(|p| layout.pack(&p).ok())
            .unwrap_or(x_nominal),
    };
    let inv_k0 = (0..layout.array().len()).map(|j| 1.0 / nominal.sensors[j].scale_factor).collect();
    let problem = Problem { layout, schedule, meas, g_m_s2, inv_k0, x: x0 };
    let (problem, report) = LevenbergMarquardt::new().with_patience(200).minimize(problem);
    finish(layout, meas, &problem, report)
}

fn finish(
    layout: &Layout,
    meas: &Measurements,
    problem: &Problem<'_>,
    report: levenberg_marquardt::MinimizationReport<f64>,
) -> Result<Estimate, CalibError> {
    let x = problem.x.clone();
    let residuals = problem.residuals();
    let jac = problem.jacobian();
    let finite = x.iter().all(|v| v.is_finite()) && residuals.is_some() && jac.is_some();
    let p = layout.len();
    let (cov, sigma, cond, cost) = match (residuals, jac) {
        (Some(r), Some(j)) => {
            let n = layout.array().len();
            let within: f64 = meas
                .steps
                .iter()
                .map(|m| (0..n).map(|a| m.within_ss[a] * problem.inv_k0[a].powi(2)).sum::<f64>())
                .sum();
            let samples: usize = meas.steps.iter().map(|m| m.samples * n).sum();
            let dof = samples.saturating_sub(p).max(1) as f64;
            let sigma2 = (within + r.norm_squared()) / dof;
            let jtj = j.transpose() * &j;
            let cov = jtj
                .clone()
                .try_inverse()
                .map(|inv| inv * sigma2)
                .unwrap_or_else(|| DMatrix::from_element(p, p, f64::NAN));
            (cov, sigma2.sqrt(), scaled_condition_number(&j), 0.5 * r.norm_squared())
        }
        _ => (DMatrix::from_element(p, p, f64::NAN), f64::NAN, f64::INFINITY, f64::NAN),
    };
    let mut converged = finite && report.termination.was_successful();
    let mut message = format!("{:?}", report.termination);
    // A solution where an accelerometer's scale factor collapses (a dead or disconnected channel),
    // or where the Jacobian is singular, is not an answer.
    let dead: Vec<String> = (0..layout.array().len())
        .filter(|&j| {
            let k = x[PER_ACCEL * j];
            !k.is_finite() || k.abs() <= 1e-6 / problem.inv_k0[j].abs()
        })
        .map(|j| (j + 1).to_string())
        .collect();
    if !dead.is_empty() {
        converged = false;
        message =
            format!("scale factor fitted to zero for accelerometer(s) {} (dead channel?); {message}", dead.join(", "));
    } else if !cond.is_finite() {
        converged = false;
        message = format!("singular Jacobian at the solution; {message}");
    }
    let status =
        FitStatus { converged, iterations: report.number_of_evaluations, cost, condition_number: cond, message };
    Ok(Estimate {
        form: layout.form(),
        params: layout.unpack(&x),
        x,
        covariance: cov,
        residual_sigma_m_s2: sigma,
        status,
    })
}

/// The form-independent convenience: a layout for `form` and a joint fit.
pub fn estimate_in_form(
    array: &crate::array::Array,
    form: Form,
    schedule: &Schedule,
    meas: &Measurements,
    nominal: &ArrayParams,
    start: Start,
    g_m_s2: f64,
) -> Result<Estimate, CalibError> {
    let layout = Layout::new(array, form)?;
    estimate(&layout, schedule, meas, nominal, start, g_m_s2)
}
