//! Diagnosis of a calibration log: the baseline fit, and where and how much it disagrees with
//! the measurements.
//!
//! The noise level is estimated within steps (pooled sample variance of each output about its
//! step mean, input-referred), independently of the model. Step means are whitened by it:
//! `z_sj = (mean_sj - model_sj) / (k_j sigma / sqrt(n_s))`, and the gap is
//! `chi^2 / dof = sum z^2 / (S N - p)`, which is about 1 when the model explains the means and
//! grows with an unmodelled effect.

use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::log::CalibrationLog;
use crate::array::Array;
use crate::calib::estimate::CalibError;
use crate::calib::joint::{Start, estimate};
use crate::calib::params::{Form, Layout, PER_ACCEL};
use crate::calib::{Estimate, Measurements};
use crate::sensor::ArrayParams;

/// The baseline model fitted to a log, and its disagreement with it.
#[derive(Debug, Clone)]
pub struct BaselineFit {
    pub estimate: Estimate,
    /// Per-sample noise estimated within steps, input-referred, m/s^2.
    pub noise_sigma_m_s2: f64,
    /// Whitened residual of each step mean: `[step][accelerometer]`.
    pub whitened: Vec<Vec<f64>>,
    pub chi2: f64,
    pub dof: usize,
    /// Probability of a chi-square at least this large if the model were right.
    pub p_value: f64,
}

impl BaselineFit {
    pub fn chi2_per_dof(&self) -> f64 {
        self.chi2 / self.dof as f64
    }
}

/// Why a log cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DiagnoseError {
    #[error(
        "the log has {steps} steps; the baseline fit needs at least {needed} (7 parameters per accelerometer and one degree of freedom for the test)"
    )]
    TooShort { steps: usize, needed: usize },
    #[error("the log's steps do not make a schedule: {0}")]
    Schedule(#[from] crate::calib::ScheduleError),
    #[error(transparent)]
    Calib(#[from] CalibError),
    #[error(
        "the log has no within-step scatter to estimate the noise from (every step has one sample, or the outputs are constant)"
    )]
    NoNoise,
}

/// Pooled within-step noise, input-referred with scale factors `k`.
pub fn within_step_sigma(meas: &Measurements, k: &[f64]) -> Option<f64> {
    let (mut ss, mut dof) = (0.0, 0usize);
    for s in &meas.steps {
        if s.samples < 2 {
            continue;
        }
        for (j, v) in s.within_ss.iter().enumerate() {
            ss += v / (k[j] * k[j]);
            dof += s.samples - 1;
        }
    }
    (dof > 0 && ss > 0.0).then(|| (ss / dof as f64).sqrt())
}

/// Fits the baseline model (bias, scale factor, misalignment, location of each accelerometer)
/// to a log and measures the gap. `nominal` gives the starting scale factors.
pub fn fit_baseline(
    log: &CalibrationLog,
    array: &Array,
    nominal: &ArrayParams,
    form: Form,
    g_m_s2: f64,
) -> Result<BaselineFit, DiagnoseError> {
    let needed = PER_ACCEL + 1;
    if log.steps.len() < needed {
        return Err(DiagnoseError::TooShort { steps: log.steps.len(), needed });
    }
    let schedule = log.schedule()?;
    let meas = log.measurements();
    let layout = Layout::new(array, form).map_err(CalibError::from)?;
    let estimate = estimate(&layout, &schedule, &meas, nominal, Start::Linear, g_m_s2)?;
    let k: Vec<f64> = estimate.params.sensors.iter().map(|s| s.scale_factor).collect();
    let sigma = within_step_sigma(&meas, &k).ok_or(DiagnoseError::NoNoise)?;
    let n = array.len();
    let mut out = vec![0.0; n];
    let mut whitened = Vec::with_capacity(schedule.len());
    let mut chi2 = 0.0;
    for (step, m) in schedule.steps().iter().zip(&meas.steps) {
        layout.step_model(&estimate.x, step, g_m_s2, &mut out, None);
        let z: Vec<f64> =
            (0..n).map(|j| (m.mean[j] - out[j]) / (k[j].abs() * sigma / (m.samples as f64).sqrt())).collect();
        chi2 += z.iter().map(|v| v * v).sum::<f64>();
        whitened.push(z);
    }
    let dof = schedule.len() * n - layout.len();
    let p_value = ChiSquared::new(dof as f64).map(|d| d.sf(chi2)).unwrap_or(f64::NAN);
    Ok(BaselineFit { estimate, noise_sigma_m_s2: sigma, whitened, chi2, dof, p_value })
}

// ---------------------------------------------------------------------------------------------
// The extended model and the search for missing effects.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

use super::effect::{Effect, SampleContext, Scope, library};
use crate::calib::params::StepMotion;
use crate::calib::schedule::Schedule;

/// One candidate: an effect, and the accelerometer it belongs to (per-accelerometer effects are
/// tested one accelerometer at a time).
pub struct Candidate {
    pub effect: Box<dyn Effect>,
    pub accelerometer: Option<usize>,
}

impl Candidate {
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
struct Extended<'a> {
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
    x: DVector<f64>,
}

impl<'a> Extended<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(
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
            p += c.effect.parameters(statics, spins);
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
    fn evaluate(&self, x: &DVector<f64>, mut regressors: Option<&mut Vec<Vec<f64>>>) -> DVector<f64> {
        let n = self.layout.array().len();
        let rows = self.schedule.len() * n;
        let mut r = DVector::zeros(rows);
        if let Some(reg) = regressors.as_deref_mut() {
            *reg = vec![vec![0.0; rows]; x.len() - self.layout.len()];
        }
        let (mut static_index, mut spin_index) = (0, 0);
        // One gradient buffer, sized for the largest effect, reused for every row and effect.
        let mut grad_buffer = vec![0.0; x.len() - self.layout.len()];
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
                    let applies = c.accelerometer.is_none_or(|a| a == j);
                    let grad = &mut grad_buffer[..m];
                    grad.iter_mut().for_each(|g| *g = 0.0);
                    if applies {
                        e += c.effect.term(&ctx, &x.as_slice()[off..off + m], grad);
                    }
                    if let Some(reg) = regressors.as_deref_mut() {
                        for (i, gv) in grad.iter().enumerate() {
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
    fn jacobian_at(&self, x: &DVector<f64>) -> DMatrix<f64> {
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

/// The outcome of testing one candidate against the current model.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// The log cannot separate it from the current model; what it is confounded with.
    ConfoundedWithModel(Vec<String>),
    /// Fitted: the fall in chi-square, its p-value, and the held-out gain.
    Tested { delta_chi2: f64, p_value: f64 },
}

/// One named effect of a diagnosis.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    pub name: String,
    pub accelerometer: Option<usize>,
    /// Values and sigmas (SI), one per parameter.
    pub value: Vec<f64>,
    pub sigma: Vec<f64>,
    pub unit: String,
    pub gap_before: f64,
    pub gap_after: f64,
    pub p_value: f64,
    /// Another candidate that explains the same gap equally well, if any.
    pub confounded_with: Option<String>,
}

/// The model at one point of a diagnosis: the baseline, then after the noise model, then after
/// each named effect.
#[derive(Debug, Clone, PartialEq)]
pub struct Stage {
    /// `baseline`, `noise model: bias_instability on a2`, `+ quadratic_coefficient on a3`, ...
    pub label: String,
    /// chi-square per degree of freedom of the step means, and the degrees of freedom.
    pub gap: f64,
    pub dof: usize,
    /// Whitened residual of each step's mean, per accelerometer.
    pub per_step: Vec<Vec<f64>>,
}

/// A whole diagnosis.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub baseline: BaselineFit,
    pub findings: Vec<Finding>,
    /// The last round's verdict on every candidate.
    pub verdicts: Vec<(String, Verdict)>,
    pub gap_before: f64,
    pub gap_after: f64,
    pub p_value_after: f64,
    /// Mean squared whitened error of each step's mean predicted with that step left out, before
    /// and after the named effects (steps the model cannot do without are skipped).
    pub held_out_before: f64,
    pub held_out_after: f64,
    /// The gap is still above the noise and no candidate helps.
    pub unmodelled_effect_remains: bool,
    pub per_step_after: Vec<Vec<f64>>,
    /// The model before and after each addition, in order.
    pub stages: Vec<Stage>,
}

/// Settings of a diagnosis.
#[derive(Debug, Clone, Copy)]
pub struct DiagnoseSettings {
    /// Familywise level of the effect tests (Bonferroni over the candidates of a round).
    pub alpha: f64,
    /// Reference temperature of the temperature effects, deg C.
    pub temp_ref_c: f64,
    pub g_m_s2: f64,
    pub form: Form,
}

impl Default for DiagnoseSettings {
    fn default() -> Self {
        Self { alpha: 0.01, temp_ref_c: 25.0, g_m_s2: crate::units::STANDARD_GRAVITY_M_S2, form: Form::Triad }
    }
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
                    if let Some(effect) = super::effect::by_name(e.name()) {
                        out.push(Candidate { effect, accelerometer: Some(j) });
                    }
                }
            }
            Scope::Shared => out.push(Candidate { effect: e, accelerometer: None }),
        }
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn fit_extended(
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

fn p_chi2(chi2: f64, dof: usize) -> f64 {
    if dof == 0 {
        return f64::NAN;
    }
    ChiSquared::new(dof as f64).map(|d| d.sf(chi2)).unwrap_or(f64::NAN)
}

/// Diagnoses a log (see the module docs): the baseline fit, then effects added one at a time
/// while one is significant.
pub fn diagnose(
    log: &CalibrationLog,
    array: &Array,
    nominal: &ArrayParams,
    s: &DiagnoseSettings,
) -> Result<Diagnosis, DiagnoseError> {
    let baseline = fit_baseline(log, array, nominal, s.form, s.g_m_s2)?;
    let schedule = log.schedule()?;
    let meas = log.measurements();
    let layout = Layout::new(array, s.form).map_err(CalibError::from)?;
    // The noise model first: correlated noise within steps (an Allan-variance excess over white
    // noise, per accelerometer, Bonferroni over all tests) is named, and the accelerometer's step
    // means are weighted with the variance it implies (the ratio at the largest significant
    // cluster), before any deterministic effect is tested against that noise.
    let k: Vec<f64> = (0..array.len()).map(|j| baseline.estimate.x[PER_ACCEL * j]).collect();
    let tests = allan_tests(log, &k);
    let allan_threshold = s.alpha / tests.len().max(1) as f64;
    let mut inflation = vec![1.0; array.len()];
    let mut noise_findings = Vec::new();
    for (j, inflation_j) in inflation.iter_mut().enumerate() {
        let significant: Vec<&AllanTest> =
            tests.iter().filter(|t| t.accelerometer == j && t.p_value < allan_threshold).collect();
        let Some(best) = significant.iter().max_by_key(|t| t.cluster_samples) else { continue };
        let strongest = significant.iter().map(|t| t.p_value).fold(f64::INFINITY, f64::min);
        *inflation_j = best.ratio.max(1.0);
        noise_findings.push(Finding {
            name: "bias_instability".into(),
            accelerometer: Some(j),
            value: vec![best.excess_adev_m_s2],
            sigma: vec![
                best.excess_adev_m_s2 * (0.5 / best.differences as f64).sqrt() * best.ratio
                    / (best.ratio - 1.0).max(1e-9),
            ],
            unit: format!("m/s^2 (Allan deviation over white noise at {:.2} s)", best.cluster_s),
            gap_before: baseline.chi2_per_dof(),
            gap_after: f64::NAN,
            p_value: strongest,
            confounded_with: None,
        });
    }
    let sigma_owned: Vec<f64> = inflation.iter().map(|f| baseline.noise_sigma_m_s2 * f.sqrt()).collect();
    let sigma = sigma_owned.as_slice();
    let pool = candidates(array.len(), log.has_temperature());
    let mut included: Vec<usize> = Vec::new();
    let mut current = fit_extended(&layout, &schedule, log, &meas, &[], &baseline.estimate.x, sigma, s);
    let gap_before = baseline.chi2_per_dof();
    let n = array.len();
    let per_step = |w: &DVector<f64>| -> Vec<Vec<f64>> {
        (0..schedule.len()).map(|st| (0..n).map(|j| w[st * n + j]).collect()).collect()
    };
    let mut stages = vec![Stage {
        label: "baseline".into(),
        gap: gap_before,
        dof: baseline.dof,
        per_step: baseline.whitened.clone(),
    }];
    if !noise_findings.is_empty() {
        let on: Vec<String> =
            noise_findings.iter().filter_map(|f| f.accelerometer).map(|j| format!("a{}", j + 1)).collect();
        stages.push(Stage {
            label: format!("noise model: bias_instability on {}", on.join(", ")),
            gap: current.chi2 / current.dof as f64,
            dof: current.dof,
            per_step: per_step(&current.whitened),
        });
    }
    for f in &mut noise_findings {
        f.gap_after = current.chi2 / current.dof as f64;
    }
    let mut findings = noise_findings;
    let mut verdicts = Vec::new();
    loop {
        let effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
        // The current model's Jacobian, for the rank tests.
        let mut model = Extended::new(
            &layout,
            &schedule,
            log,
            &meas,
            &effects,
            &current.x.rows(0, layout.len()).into_owned(),
            sigma,
            s.temp_ref_c,
            s.g_m_s2,
        );
        model.x.copy_from(&current.x);
        let jm = model.jacobian_at(&current.x);
        let svd = jm.clone().svd(true, false);
        let tol = 1e-9 * svd.singular_values.max();
        let u = svd.u.as_ref().map(|u| {
            let keep: Vec<usize> = (0..svd.singular_values.len()).filter(|&i| svd.singular_values[i] > tol).collect();
            DMatrix::from_fn(u.nrows(), keep.len(), |r, c| u[(r, keep[c])])
        });
        let Some(u) = u else { break };
        let names: Vec<String> = (0..current.x.len())
            .map(|i| if i < layout.len() { layout.name(i) } else { "an included effect".to_string() })
            .collect();
        // Each remaining candidate's regressors, with the current model's span removed.
        let mut residual_regs: Vec<(usize, DMatrix<f64>, f64)> = Vec::new();
        verdicts.clear();
        for (ci, c) in pool.iter().enumerate() {
            if included.contains(&ci) {
                continue;
            }
            let one = [c];
            let probe = Extended::new(
                &layout,
                &schedule,
                log,
                &meas,
                &one,
                &current.x.rows(0, layout.len()).into_owned(),
                sigma,
                s.temp_ref_c,
                s.g_m_s2,
            );
            let mut regs = Vec::new();
            let mut xp = probe.x.clone();
            xp.rows_mut(0, layout.len()).copy_from(&current.x.rows(0, layout.len()));
            probe.evaluate(&xp, Some(&mut regs));
            let rmat = DMatrix::from_fn(regs[0].len(), regs.len(), |r, k| regs[k][r]);
            let norm = rmat.norm();
            if norm == 0.0 {
                verdicts
                    .push((c.label(), Verdict::ConfoundedWithModel(vec!["nothing: the log never excites it".into()])));
                continue;
            }
            let perp = &rmat - &u * (u.transpose() * &rmat);
            let ratio = perp.norm() / norm;
            if ratio < 1e-6 {
                // Name what absorbs it: the least-squares coefficients on the model's columns.
                let beta = jm
                    .clone()
                    .svd(true, true)
                    .solve(&rmat, 1e-12)
                    .unwrap_or_else(|_| DMatrix::zeros(jm.ncols(), rmat.ncols()));
                let scale: Vec<f64> = (0..jm.ncols()).map(|i| beta.row(i).norm() * jm.column(i).norm()).collect();
                let total: f64 = scale.iter().sum();
                let mut idx: Vec<usize> = (0..scale.len()).filter(|&i| scale[i] > 0.02 * total).collect();
                idx.sort_by(|a, b| scale[*b].total_cmp(&scale[*a]));
                let with: Vec<String> = idx.iter().take(8).map(|&i| names[i].clone()).collect();
                verdicts.push((c.label(), Verdict::ConfoundedWithModel(with)));
                continue;
            }
            residual_regs.push((ci, perp, ratio));
        }
        // Test every separable candidate.
        let mut tested: Vec<(usize, ExtendedFit, f64, f64)> = Vec::new();
        for (ci, _, _) in &residual_regs {
            let mut effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
            effects.push(&pool[*ci]);
            let fit = fit_extended(&layout, &schedule, log, &meas, &effects, &current.x, sigma, s);
            let dp = fit.x.len() - current.x.len();
            let delta = (current.chi2 - fit.chi2).max(0.0);
            let p = p_chi2(delta, dp);
            verdicts.push((pool[*ci].label(), Verdict::Tested { delta_chi2: delta, p_value: p }));
            tested.push((*ci, fit, delta, p));
        }
        let threshold = s.alpha / tested.len().max(1) as f64;
        let Some(best) =
            tested.iter().filter(|t| t.3 < threshold).min_by(|a, b| a.3.total_cmp(&b.3).then(b.2.total_cmp(&a.2)))
        else {
            break;
        };
        let (ci, fit, _, p) = best.clone();
        // Another candidate whose unexplained part is parallel to the best one's explains the
        // same gap: the log cannot tell them apart.
        let best_perp = residual_regs.iter().find(|r| r.0 == ci).map(|r| r.1.clone());
        let confounded_with = best_perp.and_then(|bp| {
            residual_regs.iter().filter(|r| r.0 != ci && r.1.ncols() == 1 && bp.ncols() == 1).find_map(|r| {
                let cos = (bp.column(0).dot(&r.1.column(0)) / (bp.norm() * r.1.norm())).abs();
                (cos > 0.999).then(|| pool[r.0].label())
            })
        });
        let off = current.x.len();
        let m = fit.x.len() - off;
        let c = &pool[ci];
        findings.push(Finding {
            name: c.effect.name().to_string(),
            accelerometer: c.accelerometer,
            value: fit.x.rows(off, m).iter().copied().collect(),
            sigma: (0..m).map(|i| fit.covariance[(off + i, off + i)].max(0.0).sqrt()).collect(),
            unit: c.effect.unit().to_string(),
            gap_before: current.chi2 / current.dof as f64,
            gap_after: fit.chi2 / fit.dof as f64,
            p_value: p,
            confounded_with,
        });
        stages.push(Stage {
            label: format!("+ {}", c.label()),
            gap: fit.chi2 / fit.dof as f64,
            dof: fit.dof,
            per_step: per_step(&fit.whitened),
        });
        included.push(ci);
        current = fit;
    }
    let held_out_before = held_out(&layout, &schedule, log, &meas, &[], &baseline.estimate.x, sigma, s);
    let effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
    let held_out_after = held_out(&layout, &schedule, log, &meas, &effects, &current.x, sigma, s);
    let p_value_after = p_chi2(current.chi2, current.dof);
    let per_step_after = per_step(&current.whitened);
    Ok(Diagnosis {
        gap_before,
        gap_after: current.chi2 / current.dof as f64,
        p_value_after,
        held_out_before,
        held_out_after,
        unmodelled_effect_remains: p_value_after < s.alpha,
        findings,
        verdicts,
        baseline,
        per_step_after,
        stages,
    })
}

/// Leave-one-step-out prediction: each step's means predicted by the model fitted without it,
/// mean squared whitened error per output (about 1 plus p/(S N) for a right model).
#[allow(clippy::too_many_arguments)]
fn held_out(
    layout: &Layout,
    schedule: &Schedule,
    log: &CalibrationLog,
    meas: &Measurements,
    effects: &[&Candidate],
    x: &DVector<f64>,
    sigma: &[f64],
    s: &DiagnoseSettings,
) -> f64 {
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
    if count == 0 { f64::NAN } else { total / count as f64 }
}

/// Test of one accelerometer's within-step samples for correlated noise at a cluster size `m`
/// (model-free): within each step the samples are cut into clusters of `m`, and the variance of
/// the cluster means about their step mean (times `m`) is compared with the variance within
/// clusters. Under white Gaussian noise their ratio is exactly F-distributed with
/// (clusters - steps, samples - clusters) degrees of freedom; noise correlated over about `m`
/// samples (bias instability) makes it larger. This is the Allan-variance comparison done as an
/// exact test (adjacent Allan differences share a cluster and are not independent).
#[derive(Debug, Clone, PartialEq)]
pub struct AllanTest {
    pub accelerometer: usize,
    pub cluster_samples: usize,
    pub cluster_s: f64,
    /// The F ratio: `m var(cluster means) / var(within clusters)`, 1 for white noise.
    pub ratio: f64,
    /// Degrees of freedom of the numerator (cluster means less step means).
    pub differences: usize,
    pub p_value: f64,
    /// Standard deviation of the cluster means in excess of white noise, input-referred, m/s^2.
    pub excess_adev_m_s2: f64,
}

/// The correlated-noise tests of every accelerometer at cluster sizes of 10, 50 and 200 samples
/// (those that fit at least twice in a step).
pub fn allan_tests(log: &CalibrationLog, k: &[f64]) -> Vec<AllanTest> {
    use statrs::distribution::FisherSnedecor;
    let n = log.n;
    let mut out = Vec::new();
    for (j, kj) in k.iter().enumerate().take(n) {
        for m in [10usize, 50, 200] {
            let (mut between, mut within) = (0.0, 0.0);
            let (mut df1, mut df2) = (0usize, 0usize);
            let mut dt = 0.0;
            for s in &log.steps {
                let samples = s.samples();
                let clusters = samples / m;
                if clusters < 2 {
                    continue;
                }
                if samples > 1 {
                    dt = (s.t_s[samples - 1] - s.t_s[0]) / (samples - 1) as f64;
                }
                let x: Vec<f64> = (0..clusters * m).map(|i| s.outputs[i * n + j] / kj).collect();
                let means: Vec<f64> = x.chunks_exact(m).map(|c| c.iter().sum::<f64>() / m as f64).collect();
                let grand = means.iter().sum::<f64>() / clusters as f64;
                between += means.iter().map(|c| m as f64 * (c - grand).powi(2)).sum::<f64>();
                within += x
                    .chunks_exact(m)
                    .zip(&means)
                    .map(|(c, mu)| c.iter().map(|v| (v - mu).powi(2)).sum::<f64>())
                    .sum::<f64>();
                df1 += clusters - 1;
                df2 += clusters * (m - 1);
            }
            if df1 < 10 || df2 == 0 || within <= 0.0 {
                continue;
            }
            let (mb, mw) = (between / df1 as f64, within / df2 as f64);
            let ratio = mb / mw;
            let p_value = FisherSnedecor::new(df1 as f64, df2 as f64).map(|f| f.sf(ratio)).unwrap_or(f64::NAN);
            out.push(AllanTest {
                accelerometer: j,
                cluster_samples: m,
                cluster_s: m as f64 * dt,
                ratio,
                differences: df1,
                p_value,
                excess_adev_m_s2: ((mb - mw) / m as f64).max(0.0).sqrt(),
            });
        }
    }
    out
}

/// Correlation of the baseline's whitened step residuals with simple regressors, per
/// accelerometer: where the disagreement lines up (a large |r| on `input^2` points at a quadratic
/// scale factor, on `time` at a drift, on `rate^2` at a spin effect). Rows: (regressor,
/// correlation per accelerometer); NaN where the regressor does not vary.
pub fn regressor_correlations(
    log: &CalibrationLog,
    array: &Array,
    fit: &BaselineFit,
    form: Form,
    g_m_s2: f64,
) -> Vec<(String, Vec<f64>)> {
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
        if sxx > 0.0 && syy > 0.0 { sxy / (sxx * syy).sqrt() } else { f64::NAN }
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
        let per_accel = (0..n)
            .map(|j| {
                let x: Vec<f64> = (0..schedule.len()).map(|s| f(s, j)).collect();
                let z: Vec<f64> = fit.whitened.iter().map(|z| z[j]).collect();
                corr(&x, &z)
            })
            .collect();
        rows.push((name.to_string(), per_accel));
    }
    rows
}
