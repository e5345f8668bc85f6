//! The joint estimator with pose error: every error parameter of every accelerometer and the two
//! tilt angles of every step whose fixture is not perfect (`calib::pose`), by damped Gauss-Newton.
//!
//! Residuals: `sqrt(T_s) (mean_sj - s_j(x, t_s)) / k0_j` for every step and accelerometer
//! (input-referred, `T_s` the time the step's samples span, as in `calib::joint`), and
//! `t_s,c (sigma / sigma_t)` for every tilt angle with a finite prior sigma `sigma_t` (a Gaussian
//! prior written as a pseudo-observation; `sigma` the white-noise density). The tilts couple the accelerometers, so the problem is solved whole
//! (`7 N + 2 S` unknowns), starting from the per-accelerometer fit of `calib::joint` with every
//! tilt at zero. The covariance is `sigma^2 (J^T J)^-1` of the whole problem, its parameter block
//! reported: the Cramer-Rao bound of `pose::marginal_fisher` at the solution.
//!
//! The iterations are bounded (100) on purpose. Where a weak location component is seen only
//! through a small misalignment, the cost has a bilinear valley (location x misalignment fixed)
//! that runs off to metres; the tilts make it easier to slide along. A trust-region
//! Levenberg-Marquardt (the crate's) followed it to locations of metres and called that converged;
//! this one stops and reports the fit as not converged.

#![allow(clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector};

use super::estimate::{CalibError, Estimate, FitStatus, check_shape, scaled_condition_number};
use super::joint::{Start, estimate_unchecked};
use super::measure::Measurements;
use super::params::{Layout, PER_ACCEL};
use super::pose::{PoseError, motion_and_partials, output_by_motion};
use super::schedule::Schedule;
use crate::sensor::params::ArrayParams;

/// The smallest noise density used to weigh the tilt priors, m/s^2/sqrt(Hz) (noise-free data
/// would give the priors no weight at all and leave a free rotation unresolved).
const DENSITY_FLOOR_M_S2_PER_SQRT_HZ: f64 = 1e-12;

/// Fits every parameter and the tilts of every step with pose error. `density_m_s2_per_sqrt_hz`
/// is the white-noise density (input-referred) that weighs the tilt priors against the data: a
/// step mean's residual is weighted by the square root of the time its samples span, so that it
/// has the standard deviation of the density at any sample rate.
/// With a perfect fixture this is [`estimate_unchecked`] itself.
#[allow(clippy::too_many_arguments)]
pub fn estimate_with_poses(
    layout: &Layout,
    schedule: &Schedule,
    meas: &Measurements,
    nominal: &ArrayParams,
    start: Start,
    g_m_s2: f64,
    pose: &PoseError,
    density_m_s2_per_sqrt_hz: f64,
) -> Result<Estimate, CalibError> {
    let first = estimate_unchecked(layout, schedule, meas, nominal, start, g_m_s2)?;
    if pose.is_perfect() {
        return Ok(first);
    }
    check_shape(layout, schedule.len(), meas)?;
    let sigma = density_m_s2_per_sqrt_hz.max(DENSITY_FLOOR_M_S2_PER_SQRT_HZ);
    let n = layout.array().len();
    let p = layout.len();
    let tilted = pose.tilted_steps(schedule);
    let dim = p + 2 * tilted.len();
    let inv_k0: Vec<f64> = nominal.sensors.iter().map(|s| 1.0 / s.scale_factor).collect();
    let mut z = DVector::zeros(dim);
    z.rows_mut(0, p).copy_from(&first.x);

    let evaluate = |z: &DVector<f64>, with_jacobian: bool| -> (DVector<f64>, Option<DMatrix<f64>>) {
        let rows = schedule.len() * n + 2 * tilted.len();
        let mut r = DVector::zeros(rows);
        let mut jm = with_jacobian.then(|| DMatrix::zeros(rows, dim));
        let mut tilt_of = vec![None; schedule.len()];
        for (c, &s) in tilted.iter().enumerate() {
            tilt_of[s] = Some(c);
        }
        for (s, (step, st)) in schedule.steps().iter().zip(&meas.steps).enumerate() {
            let t = tilt_of[s].map(|c| [z[p + 2 * c], z[p + 2 * c + 1]]).unwrap_or([0.0, 0.0]);
            let (motion, partials) = motion_and_partials(step, t, g_m_s2);
            let root_n = (st.samples as f64 / step.sample_rate_hz).sqrt();
            for j in 0..n {
                let o = PER_ACCEL * j;
                let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| z[o + a]);
                let (out, d) = layout.accel_model(j, &xj, &motion);
                let row = s * n + j;
                r[row] = root_n * (st.mean[j] - out) * inv_k0[j];
                if let Some(jm) = jm.as_mut() {
                    let w = -root_n * inv_k0[j];
                    for (a, v) in d.iter().enumerate() {
                        jm[(row, o + a)] = w * v;
                    }
                    if let Some(c) = tilt_of[s] {
                        for (k, dm) in partials.iter().enumerate() {
                            jm[(row, p + 2 * c + k)] = w * output_by_motion(layout, j, &xj, dm);
                        }
                    }
                }
            }
        }
        for (c, &s) in tilted.iter().enumerate() {
            let sigma_t = pose.sigma_rad(&schedule.steps()[s]);
            let weight = if sigma_t.is_finite() { sigma / sigma_t } else { 0.0 };
            for k in 0..2 {
                let row = schedule.len() * n + 2 * c + k;
                r[row] = weight * z[p + 2 * c + k];
                if let Some(jm) = jm.as_mut() {
                    jm[(row, p + 2 * c + k)] = weight;
                }
            }
        }
        (r, jm)
    };

    // Damped Gauss-Newton (Levenberg-Marquardt with a diagonal scaled by J^T J).
    let (mut r, _) = evaluate(&z, false);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-6;
    let mut iterations = 0;
    let mut converged = false;
    for _ in 0..100 {
        iterations += 1;
        let (_, jm) = evaluate(&z, true);
        let Some(jm) = jm else { break };
        let jtj = jm.transpose() * &jm;
        let jtr = jm.transpose() * &r;
        let mut accepted = false;
        for _ in 0..12 {
            let mut a = jtj.clone();
            for i in 0..dim {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-300);
            }
            // A free rotation (infinite prior sigma) leaves the system singular: the pseudo-inverse
            // takes the minimum-norm step.
            let step = match a.clone().cholesky() {
                Some(ch) => ch.solve(&jtr),
                None => a.svd(true, true).solve(&jtr, 1e-12).unwrap_or_else(|_| DVector::zeros(dim)),
            };
            let trial = &z - &step;
            let (rt, _) = evaluate(&trial, false);
            let trial_cost = rt.norm_squared();
            if trial_cost.is_finite() && trial_cost <= cost {
                let decrease = cost - trial_cost;
                z = trial;
                r = rt;
                cost = trial_cost;
                lambda = (lambda * 0.1).max(1e-15);
                accepted = true;
                // The cost is sigma^2 chi^2: a fall of chi^2 below 1e-6 is no progress.
                if decrease <= 1e-6 * sigma * sigma + 1e-14 * cost {
                    converged = true;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            converged = true;
        }
        if converged {
            break;
        }
    }

    let (_, jm) = evaluate(&z, true);
    let jm = jm.unwrap_or_else(|| DMatrix::zeros(0, dim));
    let jtj = jm.transpose() * &jm;
    let full = super::pose::crb_sigma(&jtj, n, false);
    // The covariance of the whole problem, its parameter block; sigma^2 scales J^T J (input-
    // referred residuals) to the Fisher information.
    let covariance = match jtj.clone().try_inverse() {
        Some(inv) => inv.view((0, 0), (p, p)).clone_owned() * (sigma * sigma),
        None => {
            let mut c = DMatrix::from_element(p, p, f64::NAN);
            for i in 0..p {
                if full[i].is_finite() {
                    c[(i, i)] = (full[i] * sigma).powi(2);
                }
            }
            c
        }
    };
    let x = z.rows(0, p).clone_owned();
    let finite = x.iter().all(|v| v.is_finite()) && cost.is_finite();
    let rate0 = schedule.steps().first().map(|s| s.sample_rate_hz).unwrap_or(1.0);
    let residual_sigma =
        super::estimate::residual_density_m_s2_per_sqrt_hz(schedule, meas, &inv_k0, cost, dim) * rate0.sqrt();
    let condition = scaled_condition_number(&jm);
    let region = super::estimate::outside_small_error_region(layout, &x);
    Ok(Estimate {
        form: layout.form(),
        params: layout.unpack(&x),
        x,
        covariance,
        residual_sigma_m_s2: residual_sigma,
        status: FitStatus {
            converged: converged && finite && first.status.converged && region.is_none(),
            iterations: first.status.iterations + iterations,
            cost: 0.5 * cost,
            condition_number: condition,
            message: match (&region, converged, first.status.converged) {
                (Some(why), _, _) => format!("left the small-error region of the model: {why}"),
                (None, true, true) => format!("converged with {} pose tilt(s) as nuisance", 2 * tilted.len()),
                (None, true, false) => format!("first fit (no tilts): {}", first.status.message),
                (None, false, _) => "pose fit did not converge in 100 iterations".into(),
            },
        },
    })
}
