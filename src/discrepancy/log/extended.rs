//! The extended model of a log's step means: the baseline parameters plus the parameters of the
//! candidate effects included so far, fitted by Levenberg-Marquardt; and the candidates of a log.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

use super::data::CalibrationLog;
use super::diagnosis::DiagnoseSettings;
use crate::calib::Measurements;
use crate::calib::params::{Layout, PER_ACCEL, StepMotion};
use crate::calib::schedule::Schedule;
use crate::discrepancy::effect::{Effect, SampleContext, Scope, library};

/// One candidate: an effect, and the accelerometer it belongs to (per-accelerometer effects are
/// tested one accelerometer at a time).
pub struct Candidate {
    pub effect: Box<dyn Effect>,
    pub accelerometer: Option<usize>,
    /// For an effect of several parameters some directions of which the model absorbs (a common
    /// rotation of every pose is a rotation of the array frame): an orthonormal basis of the
    /// directions the log can see, `parameters = basis * fitted`. `None`: every direction.
    pub basis: Option<DMatrix<f64>>,
}

impl Candidate {
    /// The same effect on the same accelerometer, with every direction.
    pub(super) fn full(&self) -> Candidate {
        let effect =
            crate::discrepancy::effect::by_name(self.effect.name()).unwrap_or_else(|| unreachable!("a library effect"));
        Candidate { effect, accelerometer: self.accelerometer, basis: None }
    }

    /// Parameters fitted: the seen directions' count.
    fn fitted(&self, statics: usize, spins: usize) -> usize {
        self.basis.as_ref().map_or_else(|| self.effect.parameters(statics, spins), |b| b.ncols())
    }

    /// Directions the model absorbs (not fitted).
    pub fn unseen(&self, statics: usize, spins: usize) -> usize {
        self.effect.parameters(statics, spins) - self.fitted(statics, spins)
    }

    pub fn label(&self) -> String {
        match self.accelerometer {
            Some(j) => format!("{} (accelerometer {})", self.effect.name(), j + 1),
            None => self.effect.name().to_string(),
        }
    }
}

/// Step-level context of the log: means of time and temperature per step.
struct StepInfo {
    t_mean_s: f64,
    temp_delta_c: f64,
}

/// The model of step means: baseline parameters plus the parameters of the included effects.
pub(super) struct Extended<'a> {
    layout: &'a Layout,
    schedule: &'a Schedule,
    motions: Vec<StepMotion>,
    info: Vec<StepInfo>,
    meas: &'a Measurements,
    effects: &'a [&'a Candidate],
    /// Offsets of each effect's parameters after the baseline's.
    offsets: Vec<usize>,
    statics: usize,
    spins: usize,
    g_m_s2: f64,
    /// Whitening: 1 / (k_j sigma_j / sqrt(n_s)), by step and accelerometer (sigma_j includes any
    /// correlated-noise inflation).
    weight: Vec<Vec<f64>>,
    pub(super) x: DVector<f64>,
}

impl<'a> Extended<'a> {
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        layout: &'a Layout,
        schedule: &'a Schedule,
        log: &CalibrationLog,
        meas: &'a Measurements,
        effects: &'a [&'a Candidate],
        x_baseline: &DVector<f64>,
        sigma: &[f64],
        temp_ref_c: f64,
        g_m_s2: f64,
    ) -> Self {
        let statics = schedule.steps().iter().filter(|s| !s.is_spin()).count();
        let spins = schedule.len() - statics;
        let mut offsets = Vec::with_capacity(effects.len());
        let mut p = layout.len();
        for c in effects {
            offsets.push(p);
            p += c.fitted(statics, spins);
        }
        let mut x = DVector::zeros(p);
        x.rows_mut(0, layout.len()).copy_from(x_baseline);
        let info = log
            .steps
            .iter()
            .map(|s| StepInfo {
                t_mean_s: s.t_s.iter().sum::<f64>() / s.samples() as f64,
                temp_delta_c: if s.temp_c.is_empty() {
                    0.0
                } else {
                    s.temp_c.iter().sum::<f64>() / s.samples() as f64 - temp_ref_c
                },
            })
            .collect();
        let weight = meas
            .steps
            .iter()
            .map(|m| {
                (0..layout.array().len())
                    .map(|j| (m.samples as f64).sqrt() / (x_baseline[PER_ACCEL * j].abs() * sigma[j]))
                    .collect()
            })
            .collect();
        Self {
            layout,
            schedule,
            motions: schedule.steps().iter().map(|s| StepMotion::new(s, g_m_s2)).collect(),
            info,
            meas,
            effects,
            offsets,
            statics,
            spins,
            g_m_s2,
            weight,
            x,
        }
    }

    /// Whitened residuals of the step means, and (optionally) each effect's whitened regressors
    /// `[effect parameter][row]` at the current parameters.
    pub(super) fn evaluate(&self, x: &DVector<f64>, mut regressors: Option<&mut Vec<Vec<f64>>>) -> DVector<f64> {
        let n = self.layout.array().len();
        let rows = self.schedule.len() * n;
        let mut r = DVector::zeros(rows);
        if let Some(reg) = regressors.as_deref_mut() {
            *reg = vec![vec![0.0; rows]; x.len() - self.layout.len()];
        }
        let (mut static_index, mut spin_index) = (0, 0);
        // One gradient buffer, sized for the largest effect, reused for every row and effect.
        let widest = self.effects.iter().map(|c| c.effect.parameters(self.statics, self.spins)).max().unwrap_or(0);
        let mut grad_buffer = vec![0.0; widest];
        for (s, step) in self.schedule.steps().iter().enumerate() {
            let motion = &self.motions[s];
            for j in 0..n {
                let o = PER_ACCEL * j;
                let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| x[o + a]);
                let (k, b) = (xj[0], xj[1]);
                let (axis, _) = self.layout.axis(j, [xj[2], xj[3]]);
                let position =
                    self.layout.array().accelerometers()[j].position_m + nalgebra::Vector3::new(xj[4], xj[5], xj[6]);
                let u = axis.dot(&(motion.gravity_up_m_s2 + motion.w2 * position));
                let ctx = SampleContext {
                    step: s,
                    static_index: (!step.is_spin()).then_some(static_index),
                    spin_index: step.is_spin().then_some(spin_index),
                    t_s: self.info[s].t_mean_s,
                    temp_delta_c: self.info[s].temp_delta_c,
                    u_m_s2: u,
                    axis,
                    position_m: position,
                    up_b: step.up_b(),
                    w2: motion.w2,
                    g_m_s2: self.g_m_s2,
                };
                let mut e = 0.0;
                for (c, &off) in self.effects.iter().zip(&self.offsets) {
                    let m = c.effect.parameters(self.statics, self.spins);
                    let q = c.fitted(self.statics, self.spins);
                    let applies = c.accelerometer.is_none_or(|a| a == j);
                    let grad = &mut grad_buffer[..m];
                    grad.iter_mut().for_each(|g| *g = 0.0);
                    let fitted = &x.as_slice()[off..off + q];
                    if applies {
                        e += match &c.basis {
                            None => c.effect.term(&ctx, fitted, grad),
                            Some(b) => {
                                let full: Vec<f64> =
                                    (0..m).map(|r| (0..q).map(|i| b[(r, i)] * fitted[i]).sum()).collect();
                                c.effect.term(&ctx, &full, grad)
                            }
                        };
                    }
                    if let Some(reg) = regressors.as_deref_mut() {
                        for i in 0..q {
                            let gv = match &c.basis {
                                None => grad[i],
                                Some(b) => (0..m).map(|r| grad[r] * b[(r, i)]).sum(),
                            };
                            reg[off - self.layout.len() + i][s * n + j] = self.weight[s][j] * k * gv;
                        }
                    }
                }
                r[s * n + j] = self.weight[s][j] * (self.meas.steps[s].mean[j] - k * (b + u + e));
            }
            if step.is_spin() {
                spin_index += 1;
            } else {
                static_index += 1;
            }
        }
        r
    }

    /// Jacobian of the residuals: the effects' columns from their regressors (analytic), the
    /// baseline's by central differences (steps on each parameter's scale), which also carry the
    /// effects' dependence on the baseline parameters.
    pub(super) fn jacobian_at(&self, x: &DVector<f64>) -> DMatrix<f64> {
        let rows = self.schedule.len() * self.layout.array().len();
        let mut jm = DMatrix::zeros(rows, x.len());
        let mut regs = Vec::new();
        self.evaluate(x, Some(&mut regs));
        for (k, reg) in regs.iter().enumerate() {
            for (r, v) in reg.iter().enumerate() {
                jm[(r, self.layout.len() + k)] = -v;
            }
        }
        let mut xp = x.clone();
        for i in 0..self.layout.len() {
            let h = 1e-6 * [1.0, 1e-2, 1e-2, 1e-2, 1e-3, 1e-3, 1e-3][i % PER_ACCEL] * x[i].abs().clamp(1.0, 10.0);
            xp[i] = x[i] + h;
            let a = self.evaluate(&xp, None);
            xp[i] = x[i] - h;
            let b = self.evaluate(&xp, None);
            xp[i] = x[i];
            jm.set_column(i, &((a - b) / (2.0 * h)));
        }
        jm
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Extended<'_> {
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
        let r = self.evaluate(&self.x, None);
        r.iter().all(|v| v.is_finite()).then_some(r)
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let j = self.jacobian_at(&self.x);
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// A fit of the baseline plus some effects.
#[derive(Debug, Clone)]
pub struct ExtendedFit {
    pub x: DVector<f64>,
    pub chi2: f64,
    pub dof: usize,
    pub covariance: DMatrix<f64>,
    pub whitened: DVector<f64>,
}

/// The candidates for a log: every per-accelerometer effect on every accelerometer, and every
/// shared effect; temperature effects only when the log has `temp_c`.
pub fn candidates(n: usize, has_temperature: bool) -> Vec<Candidate> {
    let mut out = Vec::new();
    for e in library() {
        if e.needs_temperature() && !has_temperature {
            continue;
        }
        match e.scope() {
            Scope::PerAccelerometer => {
                for j in 0..n {
                    if let Some(effect) = crate::discrepancy::effect::by_name(e.name()) {
                        out.push(Candidate { effect, accelerometer: Some(j), basis: None });
                    }
                }
            }
            Scope::Shared => out.push(Candidate { effect: e, accelerometer: None, basis: None }),
        }
    }
    out
}

#[allow(clippy::too_many_arguments)]
pub(super) fn fit_extended(
    layout: &Layout,
    schedule: &Schedule,
    log: &CalibrationLog,
    meas: &Measurements,
    effects: &[&Candidate],
    start: &DVector<f64>,
    sigma: &[f64],
    s: &DiagnoseSettings,
) -> ExtendedFit {
    let mut problem = Extended::new(
        layout,
        schedule,
        log,
        meas,
        effects,
        &start.rows(0, layout.len()).into_owned(),
        sigma,
        s.temp_ref_c,
        s.g_m_s2,
    );
    let p0 = problem.x.len();
    // Start from the previous solution where it has the parameters.
    for i in 0..start.len().min(p0) {
        problem.x[i] = start[i];
    }
    let (problem, _) = LevenbergMarquardt::new().with_patience(20).minimize(problem);
    let r = problem.evaluate(&problem.x, None);
    let j = problem.jacobian_at(&problem.x);
    let covariance = (j.transpose() * &j).try_inverse().unwrap_or_else(|| DMatrix::from_element(p0, p0, f64::NAN));
    ExtendedFit {
        x: problem.x.clone(),
        chi2: r.norm_squared(),
        dof: r.len().saturating_sub(p0),
        covariance,
        whitened: r,
    }
}

/// Leave-one-step-out prediction: each step's means predicted by the model fitted without it,
/// mean squared whitened error per output (about 1 plus p/(S N) for a right model).
#[allow(clippy::too_many_arguments)]
pub(super) fn held_out(
    layout: &Layout,
    schedule: &Schedule,
    log: &CalibrationLog,
    meas: &Measurements,
    effects: &[&Candidate],
    x: &DVector<f64>,
    sigma: &[f64],
    s: &DiagnoseSettings,
) -> Option<f64> {
    let n = layout.array().len();
    let mut total = 0.0;
    let mut count = 0usize;
    for leave in 0..schedule.len() {
        // Zero weight on the left-out step's rows: the fit ignores them, then they are predicted.
        let mut problem = Extended::new(
            layout,
            schedule,
            log,
            meas,
            effects,
            &x.rows(0, layout.len()).into_owned(),
            sigma,
            s.temp_ref_c,
            s.g_m_s2,
        );
        problem.x.copy_from(x);
        let saved = problem.weight[leave].clone();
        problem.weight[leave].iter_mut().for_each(|w| *w = 0.0);
        // A step the model cannot do without (e.g. one of only three spins) cannot be predicted.
        let sv = problem.jacobian_at(&problem.x).singular_values();
        if sv.min() <= 1e-9 * sv.max() {
            continue;
        }
        let (mut problem, _) = LevenbergMarquardt::new().with_patience(50).minimize(problem);
        problem.weight[leave] = saved;
        let r = problem.evaluate(&problem.x.clone(), None);
        for j in 0..n {
            total += r[leave * n + j].powi(2);
            count += 1;
        }
    }
    (count > 0 && total.is_finite()).then(|| total / count as f64)
}
