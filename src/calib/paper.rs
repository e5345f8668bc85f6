//! The paper's own procedure (Hung & Lee 2006, Sections 3-4), and the linear first guess that
//! generalises it.
//!
//! 1. For each triad, the six static poses with gravity up and down along each of its three
//!    sensitive axes (Table 3 for triad B = 2, 3, 5; Table 4 for triad A = 1, 4, 6). For each
//!    accelerometer of the triad, eq. (8) reads `s = k b + (k a) . (g up)`: linear in `c = k b`
//!    and `v = k a`, four unknowns from six poses. Scale factor, bias and the two triad angles
//!    follow from `v` (its coefficient on the accelerometer's own axis is `k`).
//! 2. Location errors from the spins (Table 5): with `k, b, a` from step 1,
//!    `s / k - b - a . (g up) - a . (W r) = (W a) . dr`, three equations (one per spin) in three
//!    unknowns. The spin about body axis e_k cannot see `dr` along e_k, so the system is
//!    `[[0, a_y, a_z], [a_x, 0, a_z], [a_x, a_y, 0]] (-w^2)` with determinant `2 a_x a_y a_z`:
//!    every cube axis has one nominal zero component, so one location component of each
//!    accelerometer is seen only through its misalignment.
//!
//! The covariance is propagated from the step means through the whole procedure (delta method,
//! central differences), with the per-sample residual variance.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3, Vector4};

use super::estimate::{CalibError, Estimate, FitStatus, check_shape};
use super::measure::Measurements;
use super::params::{Layout, StepMotion};
use super::schedule::Schedule;
use crate::sensor::params::{ArrayParams, SensorParams};

/// Result of one accelerometer's static fit: `s = c + v . (g up)`.
struct StaticFit {
    c: f64,
    v: Vector3<f64>,
    condition: f64,
}

fn static_fit(schedule: &Schedule, meas: &Measurements, steps: &[usize], j: usize, g_m_s2: f64) -> Option<StaticFit> {
    let mut ata = nalgebra::Matrix4::zeros();
    let mut atb = Vector4::zeros();
    for &s in steps {
        let up = schedule.steps()[s].up_b() * g_m_s2;
        let row = Vector4::new(1.0, up.x, up.y, up.z);
        let w = meas.steps[s].samples as f64;
        ata += row * row.transpose() * w;
        atb += row * (w * meas.steps[s].mean[j]);
    }
    let sv = ata.singular_values();
    let condition = (sv.max() / sv.min()).sqrt();
    if !(condition.is_finite() && condition < 1e12) {
        return None;
    }
    let x = ata.lu().solve(&atb)?;
    Some(StaticFit { c: x[0], v: Vector3::new(x[1], x[2], x[3]), condition })
}

/// Location error from the spins given one accelerometer's scale factor, bias and axis; on a
/// singular system, the unseen components (0 = x, 1 = y, 2 = z).
fn location_fit(
    schedule: &Schedule,
    meas: &Measurements,
    spins: &[usize],
    j: usize,
    sensor: &SensorParams,
    r_nominal_m: &Vector3<f64>,
    g_m_s2: f64,
) -> Result<(Vector3<f64>, f64), Vec<usize>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for &s in spins {
        let motion = StepMotion::new(&schedule.steps()[s], g_m_s2);
        let a = sensor.axis;
        let y = meas.steps[s].mean[j] / sensor.scale_factor
            - sensor.bias_m_s2
            - a.dot(&motion.gravity_up_m_s2)
            - a.dot(&(motion.w2 * r_nominal_m));
        let row = motion.w2 * a;
        let n = meas.steps[s].samples as f64;
        ata += row * row.transpose() * n;
        atb += row * (y * n);
    }
    let eig = nalgebra::SymmetricEigen::new(ata);
    let max = eig.eigenvalues.max();
    let unseen: Vec<usize> = (0..3)
        .filter(|&c| {
            (0..3).any(|k| {
                eig.eigenvalues[k] <= 1e-24 * max.max(f64::MIN_POSITIVE) && eig.eigenvectors[(c, k)].abs() > 0.1
            })
        })
        .collect();
    if max <= 0.0 || !unseen.is_empty() {
        return Err(if max <= 0.0 { vec![0, 1, 2] } else { unseen });
    }
    let dr = ata.lu().solve(&atb).ok_or_else(|| vec![0, 1, 2])?;
    Ok((dr, (max / eig.eigenvalues.min()).sqrt()))
}

/// The location step alone (Table 5) for accelerometer `j` with given scale factor, bias and axis.
pub fn location_only(
    schedule: &Schedule,
    meas: &Measurements,
    spins: &[usize],
    j: usize,
    sensor: &SensorParams,
    r_nominal_m: &Vector3<f64>,
    g_m_s2: f64,
) -> Result<Vector3<f64>, Vec<usize>> {
    location_fit(schedule, meas, spins, j, sensor, r_nominal_m, g_m_s2).map(|(dr, _)| dr)
}

fn is_along(up: &Vector3<f64>, axis: &Vector3<f64>) -> Option<bool> {
    let d = up.dot(axis);
    if d > 1.0 - 1e-9 {
        Some(true)
    } else if d < -1.0 + 1e-9 {
        Some(false)
    } else {
        None
    }
}

/// The static steps of each triad's procedure (up = +-theta_j for j in the triad).
fn triad_poses(layout: &Layout, schedule: &Schedule) -> Result<Vec<Vec<usize>>, CalibError> {
    let array = layout.array();
    if array.triads().is_empty() {
        return Err(CalibError::PaperProcedure { what: "an array with triads of accelerometers".into() });
    }
    let mut out = Vec::new();
    for tr in array.triads() {
        let mut steps = Vec::new();
        let mut missing = Vec::new();
        for &j in tr {
            let axis = array.accelerometers()[j].axis;
            for (positive, sign) in [(true, "+"), (false, "-")] {
                let found: Vec<usize> = schedule
                    .steps()
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| !s.is_spin() && is_along(&s.up_b(), &axis) == Some(positive))
                    .map(|(i, _)| i)
                    .collect();
                if found.is_empty() {
                    missing.push(format!("up = {sign}theta_{}", j + 1));
                }
                steps.extend(found);
            }
        }
        if !missing.is_empty() {
            return Err(CalibError::PaperProcedure {
                what: format!(
                    "static poses with gravity along each axis of triad ({}); missing: {}",
                    tr.iter().map(|j| (j + 1).to_string()).collect::<Vec<_>>().join(", "),
                    missing.join(", ")
                ),
            });
        }
        out.push(steps);
    }
    Ok(out)
}

fn spins(schedule: &Schedule) -> Vec<usize> {
    schedule.steps().iter().enumerate().filter(|(_, s)| s.is_spin()).map(|(i, _)| i).collect()
}

/// The paper's procedure without covariance: parameters and the worst sub-system condition number.
fn procedure(
    layout: &Layout,
    schedule: &Schedule,
    meas: &Measurements,
    g_m_s2: f64,
) -> Result<(ArrayParams, f64, usize), CalibError> {
    let array = layout.array();
    let poses = triad_poses(layout, schedule)?;
    let spin_steps = spins(schedule);
    if spin_steps.len() < 3 {
        return Err(CalibError::PaperProcedure {
            what: format!(
                "at least three spins for the location errors (Table 5), the schedule has {}",
                spin_steps.len()
            ),
        });
    }
    let mut sensors = vec![None; array.len()];
    let mut worst: f64 = 1.0;
    let mut solves = 0;
    let mut unseen = Vec::new();
    for (tr, steps) in array.triads().iter().zip(&poses) {
        for &j in tr {
            let fit = static_fit(schedule, meas, steps, j, g_m_s2).ok_or_else(|| CalibError::PaperProcedure {
                what: format!("static poses that separate the bias and axis of accelerometer {}", j + 1),
            })?;
            worst = worst.max(fit.condition);
            solves += 1;
            let raw =
                SensorParams { scale_factor: 1.0, bias_m_s2: fit.c, axis: fit.v, location_error_m: Vector3::zeros() };
            // Triad form: coefficient 1 on the accelerometer's own axis; k and b absorb the rest.
            let sensor = crate::sensor::misalignment::to_triad_axes(array, &single(array, j, raw))?.sensors[j];
            match location_fit(schedule, meas, &spin_steps, j, &sensor, &array.accelerometers()[j].position_m, g_m_s2) {
                Ok((dr, cond)) => {
                    worst = worst.max(cond);
                    solves += 1;
                    sensors[j] = Some(SensorParams { location_error_m: dr, ..sensor });
                }
                Err(components) => {
                    unseen.extend(components.iter().map(|c| format!("a{}.{}", j + 1, ["dx", "dy", "dz"][*c])));
                }
            }
        }
    }
    if !unseen.is_empty() {
        return Err(CalibError::Unidentifiable { parameters: unseen });
    }
    let sensors = sensors
        .into_iter()
        .enumerate()
        .map(|(j, s)| {
            s.ok_or_else(|| CalibError::PaperProcedure { what: format!("accelerometer {} in a triad", j + 1) })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((ArrayParams { sensors }, worst, solves))
}

/// Nominal parameters with one accelerometer replaced (to reuse the array-wide conversions).
fn single(array: &crate::array::Array, j: usize, s: SensorParams) -> ArrayParams {
    let mut p = ArrayParams::nominal(array);
    p.sensors[j] = s;
    p
}

/// The paper's estimator (see the module docs), in the layout's form.
pub fn estimate(
    layout: &Layout,
    schedule: &Schedule,
    meas: &Measurements,
    g_m_s2: f64,
) -> Result<Estimate, CalibError> {
    check_shape(layout, schedule.len(), meas)?;
    let (params, condition, solves) = procedure(layout, schedule, meas, g_m_s2)?;
    let x = layout.pack(&params)?;
    let n = layout.array().len();
    // Per-sample residual variance (input-referred) at the estimate, over all steps.
    let mut out = vec![0.0; n];
    let (mut rss, mut cost) = (0.0, 0.0);
    let mut samples = 0usize;
    for (step, m) in schedule.steps().iter().zip(&meas.steps) {
        layout.step_model(&x, step, g_m_s2, &mut out, None);
        for j in 0..n {
            let k2 = x[7 * j].powi(2);
            let misfit = m.samples as f64 * (m.mean[j] - out[j]).powi(2) / k2;
            rss += m.within_ss[j] / k2 + misfit;
            cost += 0.5 * misfit;
        }
        samples += m.samples * n;
    }
    let sigma2 = rss / samples.saturating_sub(layout.len()).max(1) as f64;
    // Delta method: d x / d mean_sj by central differences, var(mean_sj) = sigma^2 k_j^2 / n_s.
    let p = layout.len();
    let mut g = DMatrix::zeros(p, schedule.len() * n);
    let mut data_var = DVector::zeros(schedule.len() * n);
    let mut perturbed = meas.clone();
    for s in 0..schedule.len() {
        for j in 0..n {
            let col = s * n + j;
            let m0 = meas.steps[s].mean[j];
            let h = 1e-6 * m0.abs().max(1.0);
            perturbed.steps[s].mean[j] = m0 + h;
            let plus =
                procedure(layout, schedule, &perturbed, g_m_s2).ok().and_then(|(pp, _, _)| layout.pack(&pp).ok());
            perturbed.steps[s].mean[j] = m0 - h;
            let minus =
                procedure(layout, schedule, &perturbed, g_m_s2).ok().and_then(|(pp, _, _)| layout.pack(&pp).ok());
            perturbed.steps[s].mean[j] = m0;
            if let (Some(a), Some(b)) = (plus, minus) {
                g.set_column(col, &((a - b) / (2.0 * h)));
            }
            data_var[col] = sigma2 * x[7 * j].powi(2) / meas.steps[s].samples as f64;
        }
    }
    let covariance = &g * DMatrix::from_diagonal(&data_var) * g.transpose();
    Ok(Estimate {
        form: layout.form(),
        params: layout.unpack(&x),
        x,
        covariance,
        residual_sigma_m_s2: sigma2.sqrt(),
        status: FitStatus {
            converged: true,
            iterations: solves,
            cost,
            condition_number: condition,
            message: "closed-form triad and location solves".into(),
        },
    })
}

/// Linear first guess for the joint fit: per accelerometer, `s = c + v . (g up)` on every static
/// step, then the location errors from every spin (zero when there are fewer than three or they
/// do not separate it).
pub fn linear_guess(
    layout: &Layout,
    schedule: &Schedule,
    meas: &Measurements,
    g_m_s2: f64,
) -> Result<ArrayParams, CalibError> {
    let array = layout.array();
    let statics: Vec<usize> =
        schedule.steps().iter().enumerate().filter(|(_, s)| !s.is_spin()).map(|(i, _)| i).collect();
    let spin_steps = spins(schedule);
    let mut sensors = Vec::with_capacity(array.len());
    for j in 0..array.len() {
        let fit = static_fit(schedule, meas, &statics, j, g_m_s2)
            .ok_or_else(|| CalibError::PaperProcedure { what: "static poses spanning three directions".into() })?;
        let k = fit.v.norm();
        let sensor =
            SensorParams { scale_factor: k, bias_m_s2: fit.c / k, axis: fit.v / k, location_error_m: Vector3::zeros() };
        let dr = if spin_steps.len() >= 3 {
            location_fit(schedule, meas, &spin_steps, j, &sensor, &array.accelerometers()[j].position_m, g_m_s2)
                .map(|(dr, _)| dr)
                .unwrap_or_else(|_| Vector3::zeros())
        } else {
            Vector3::zeros()
        };
        sensors.push(SensorParams { location_error_m: dr, ..sensor });
    }
    Ok(ArrayParams { sensors })
}
