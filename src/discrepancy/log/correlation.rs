//! Where the baseline's residuals line up: their correlation with simple regressors per
//! accelerometer.

use super::baseline::BaselineFit;
use super::data::CalibrationLog;
use crate::array::Array;
use crate::calib::params::{Form, Layout, PER_ACCEL, StepMotion};

/// What one regressor shows in the baseline's residuals.
#[derive(Debug, Clone, PartialEq)]
pub enum Correlation {
    /// Correlation with each accelerometer's whitened step residuals (`None` where that
    /// accelerometer's regressor or residuals do not vary).
    PerAccelerometer(Vec<Option<f64>>),
    /// The regressor has this one value in every step (e.g. a temperature column that never
    /// changes): the log says nothing about it.
    Constant(f64),
}

/// One row of [`regressor_correlations`].
#[derive(Debug, Clone, PartialEq)]
pub struct RegressorCorrelation {
    pub regressor: String,
    pub correlation: Correlation,
}

/// Correlation of the baseline's whitened step residuals with simple regressors, per
/// accelerometer: where the disagreement lines up (a large |r| on `input^2` points at a quadratic
/// scale factor, on `time` at a drift, on `rate^2` at a spin effect). A regressor with one value
/// in every step is reported as constant.
pub fn regressor_correlations(
    log: &CalibrationLog,
    array: &Array,
    fit: &BaselineFit,
    form: Form,
    g_m_s2: f64,
) -> Vec<RegressorCorrelation> {
    let Ok(layout) = Layout::new(array, form) else { return vec![] };
    let Ok(schedule) = log.schedule() else { return vec![] };
    let n = array.len();
    let mut u = vec![vec![0.0; n]; schedule.len()];
    for (s, step) in schedule.steps().iter().enumerate() {
        let motion = StepMotion::new(step, g_m_s2);
        for (j, uj) in u[s].iter_mut().enumerate() {
            let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| fit.estimate.x[PER_ACCEL * j + a]);
            let (axis, _) = layout.axis(j, [xj[2], xj[3]]);
            let r = array.accelerometers()[j].position_m + nalgebra::Vector3::new(xj[4], xj[5], xj[6]);
            *uj = axis.dot(&(motion.gravity_up_m_s2 + motion.w2 * r));
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let t: Vec<f64> = log.steps.iter().map(|s| mean(&s.t_s)).collect();
    let temp: Vec<f64> =
        log.steps.iter().map(|s| if s.temp_c.is_empty() { f64::NAN } else { mean(&s.temp_c) }).collect();
    let w2: Vec<f64> = log.steps.iter().map(|s| s.omega_b_rad_s.norm_squared()).collect();
    let corr = |x: &[f64], y: &[f64]| {
        let (mx, my) = (mean(x), mean(y));
        let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
        let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
        let syy: f64 = y.iter().map(|b| (b - my).powi(2)).sum();
        (sxx > 0.0 && syy > 0.0).then(|| sxy / (sxx * syy).sqrt()).filter(|r| r.is_finite())
    };
    let mut rows = Vec::new();
    type Regressor<'r> = Box<dyn Fn(usize, usize) -> f64 + 'r>;
    let regressors: Vec<(&str, Regressor)> = vec![
        ("input", Box::new(|s, j| u[s][j])),
        ("input^2", Box::new(|s, j| u[s][j].powi(2))),
        ("input^3", Box::new(|s, j| u[s][j].powi(3))),
        ("time", Box::new(|s, _| t[s])),
        ("temperature", Box::new(|s, _| temp[s])),
        ("rate^2", Box::new(|s, _| w2[s])),
    ];
    for (name, f) in regressors {
        if name == "temperature" && !log.has_temperature() {
            continue;
        }
        let first = f(0, 0);
        // One value throughout (to rounding: step means of a constant column).
        let tolerance = 1e-9 * first.abs().max(1.0);
        let constant = (0..schedule.len()).all(|s| (0..n).all(|j| (f(s, j) - first).abs() <= tolerance));
        let correlation = if constant {
            Correlation::Constant(first)
        } else {
            Correlation::PerAccelerometer(
                (0..n)
                    .map(|j| {
                        let x: Vec<f64> = (0..schedule.len()).map(|s| f(s, j)).collect();
                        let z: Vec<f64> = fit.whitened.iter().map(|z| z[j]).collect();
                        corr(&x, &z)
                    })
                    .collect(),
            )
        };
        rows.push(RegressorCorrelation { regressor: name.to_string(), correlation });
    }
    rows
}
