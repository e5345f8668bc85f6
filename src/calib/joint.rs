//! The joint estimator: every parameter of every accelerometer from every step, by nonlinear
//! least squares (Levenberg-Marquardt, from the `levenberg-marquardt` crate).
//!
//! Residual of step s, accelerometer j: `sqrt(T_s) (mean_sj - s_j(x)) / k0_j`, input-referred
//! with the starting scale factor `k0_j` as a fixed weight and `T_s = n_s / r_s` the time the
//! step's `n_s` samples at rate `r_s` span: white noise of density `d` gives a step mean the
//! variance `d^2 / T_s` at any sample rate, so every residual has the standard deviation `d`. The
//! baseline model is separable by accelerometer (each output depends on its own 7 parameters
//! only), so the joint problem is exactly the sum of one 7-parameter problem per accelerometer,
//! and is solved that way (the constant weight `1 / k0_j` of a block does not move its minimum).
//! The covariance is `d^2 (J^T J)^-1` with the residuals referred to the input by the *fitted*
//! scale factor `k_j`, and `d^2` the residual density (within-step scatter plus the misfit of the
//! means, over the degrees of freedom), pooled over accelerometers.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, OMatrix, OVector, Owned, U7};

use super::estimate::{
    CalibError, Estimate, FitStatus, check_shape, outside_small_error_region, residual_density_m_s2_per_sqrt_hz,
    scaled_condition_number,
};
use super::fisher::structurally_unidentifiable;
use super::measure::Measurements;
use super::params::{Form, Layout, PER_ACCEL, StepMotion};
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

/// The residuals of one accelerometer over all steps.
struct BlockProblem<'a> {
    layout: &'a Layout,
    motions: &'a [StepMotion],
    meas: &'a Measurements,
    j: usize,
    inv_k0: f64,
    /// `sqrt(T_s)` of every step (s^0.5).
    root_t: &'a [f64],
    x: OVector<f64, U7>,
}

impl BlockProblem<'_> {
    fn xj(&self) -> [f64; PER_ACCEL] {
        std::array::from_fn(|a| self.x[a])
    }
}

impl LeastSquaresProblem<f64, Dyn, U7> for BlockProblem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, U7>;
    type ParameterStorage = Owned<f64, U7>;

    fn set_params(&mut self, x: &OVector<f64, U7>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> OVector<f64, U7> {
        self.x
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let xj = self.xj();
        let r = DVector::from_iterator(
            self.motions.len(),
            self.motions.iter().zip(&self.meas.steps).zip(self.root_t).map(|((m, st), rt)| {
                let (s, _) = self.layout.accel_model(self.j, &xj, m);
                rt * (st.mean[self.j] - s) * self.inv_k0
            }),
        );
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U7>> {
        let xj = self.xj();
        let mut jm = OMatrix::<f64, Dyn, U7>::zeros(self.motions.len());
        for (row, (m, rt)) in self.motions.iter().zip(self.root_t).enumerate() {
            let (_, d) = self.layout.accel_model(self.j, &xj, m);
            let w = -rt * self.inv_k0;
            for (a, v) in d.iter().enumerate() {
                jm[(row, a)] = w * v;
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
    let motions: Vec<StepMotion> = schedule.steps().iter().map(|s| StepMotion::new(s, g_m_s2)).collect();
    let root_t: Vec<f64> = schedule.steps().iter().map(|s| s.sampled_duration_s().sqrt()).collect();
    let n = layout.array().len();
    let p = layout.len();
    let mut x = x0.clone();
    let mut jtj = DMatrix::zeros(p, p);
    let (mut misfit, mut iterations, mut condition) = (0.0, 0, 1.0f64);
    let mut converged = true;
    let mut messages = Vec::new();
    let mut dead = Vec::new();
    for j in 0..n {
        let o = PER_ACCEL * j;
        let inv_k0 = 1.0 / nominal.sensors[j].scale_factor;
        let x_block = OVector::<f64, U7>::from_fn(|a, _| x0[o + a]);
        let problem = BlockProblem { layout, motions: &motions, meas, j, inv_k0, root_t: &root_t, x: x_block };
        let (problem, report) = LevenbergMarquardt::new().with_patience(200).minimize(problem);
        iterations += report.number_of_evaluations;
        x.rows_mut(o, PER_ACCEL).copy_from(&problem.x);
        match (problem.residuals(), problem.jacobian()) {
            (Some(r), Some(jac)) => {
                // Referred to the input by the fitted scale factor: residuals and Jacobian scale
                // by k0 / k.
                let refer = (problem.x[0] * inv_k0).recip().powi(2);
                misfit += r.norm_squared() * refer;
                jtj.view_mut((o, o), (PER_ACCEL, PER_ACCEL)).copy_from(&(jac.transpose() * &jac * refer));
                let dyn_jac = DMatrix::from_iterator(jac.nrows(), PER_ACCEL, jac.iter().copied());
                condition = condition.max(scaled_condition_number(&dyn_jac));
            }
            _ => {
                misfit = f64::NAN;
                condition = f64::INFINITY;
            }
        }
        if !report.termination.was_successful() {
            converged = false;
            messages.push(format!("accelerometer {}: {:?}", j + 1, report.termination));
        }
        let k = problem.x[0];
        if !k.is_finite() || k.abs() <= 1e-6 / inv_k0.abs() {
            dead.push((j + 1).to_string());
        }
    }
    let inv_k: Vec<f64> = (0..n).map(|j| 1.0 / x[PER_ACCEL * j]).collect();
    let density = residual_density_m_s2_per_sqrt_hz(schedule, meas, &inv_k, misfit, p);
    let covariance = block_inverse(&jtj, n)
        .map(|inv| inv * density.powi(2))
        .unwrap_or_else(|| DMatrix::from_element(p, p, f64::NAN));
    let rate0 = schedule.steps().first().map(|s| s.sample_rate_hz).unwrap_or(1.0);
    let finite = x.iter().all(|v| v.is_finite()) && misfit.is_finite();
    let mut message = if messages.is_empty() { "converged".to_string() } else { messages.join("; ") };
    // A solution where an accelerometer's scale factor collapses (a dead or disconnected channel),
    // or where the Jacobian is singular, is not an answer.
    if !dead.is_empty() {
        converged = false;
        message =
            format!("scale factor fitted to zero for accelerometer(s) {} (dead channel?); {message}", dead.join(", "));
    } else if !condition.is_finite() {
        converged = false;
        message = format!("singular Jacobian at the solution; {message}");
    } else if let Some(why) = outside_small_error_region(layout, &x) {
        converged = false;
        message = if messages.is_empty() {
            format!("left the small-error region of the model: {why}")
        } else {
            format!("left the small-error region of the model: {why}; {message}")
        };
    }
    let status = FitStatus {
        converged: converged && finite,
        iterations,
        cost: 0.5 * misfit,
        condition_number: condition,
        message,
    };
    Ok(Estimate {
        form: layout.form(),
        params: layout.unpack(&x),
        x,
        covariance,
        residual_sigma_m_s2: density * rate0.sqrt(),
        status,
    })
}

/// Inverse of a block-diagonal matrix with `n` blocks of 7.
fn block_inverse(m: &DMatrix<f64>, n: usize) -> Option<DMatrix<f64>> {
    let p = m.nrows();
    let mut inv = DMatrix::zeros(p, p);
    for j in 0..n {
        let o = PER_ACCEL * j;
        let block = m.view((o, o), (PER_ACCEL, PER_ACCEL)).clone_owned().try_inverse()?;
        inv.view_mut((o, o), (PER_ACCEL, PER_ACCEL)).copy_from(&block);
    }
    Some(inv)
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
