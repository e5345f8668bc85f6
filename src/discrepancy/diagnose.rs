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
    /// For an effect of several parameters some directions of which the model absorbs (a common
    /// rotation of every pose is a rotation of the array frame): an orthonormal basis of the
    /// directions the log can see, `parameters = basis * fitted`. `None`: every direction.
    pub basis: Option<DMatrix<f64>>,
}

impl Candidate {
    /// The same effect on the same accelerometer, with every direction.
    fn full(&self) -> Candidate {
        let effect = super::effect::by_name(self.effect.name()).unwrap_or_else(|| unreachable!("a library effect"));
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
    fn evaluate(&self, x: &DVector<f64>, mut regressors: Option<&mut Vec<Vec<f64>>>) -> DVector<f64> {
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
    /// Fitted, but its parameters have no finite standard deviation (the extended model's
    /// information is singular there): never named.
    NoSigma,
}

/// How much of the gap the named effects explain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Explanation {
    /// Nothing named, and the baseline's gap is what noise explains.
    NothingToExplain,
    /// Effects named, and what is left is what noise explains.
    Complete,
    /// Effects named, but the gap left is still above the noise: they are part of the answer.
    Partial,
    /// Nothing named, and the gap is above the noise.
    Unexplained,
}

impl Explanation {
    pub fn as_str(&self) -> &'static str {
        match self {
            Explanation::NothingToExplain => "nothing to explain",
            Explanation::Complete => "complete",
            Explanation::Partial => "partial",
            Explanation::Unexplained => "unexplained",
        }
    }
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
    /// Directions of the effect's parameters that the model absorbs (not fitted; the values are
    /// the effect with none of them). 0 for most effects.
    pub unseen_directions: usize,
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
    /// and after the named effects (steps the model cannot do without are skipped; `None` when no
    /// step can be left out).
    pub held_out_before: Option<f64>,
    pub held_out_after: Option<f64>,
    /// The gap is still above the noise and no candidate helps.
    pub unmodelled_effect_remains: bool,
    pub per_step_after: Vec<Vec<f64>>,
    /// The model before and after each addition, in order.
    pub stages: Vec<Stage>,
}

impl Diagnosis {
    /// Whether the named effects are the answer, part of it, or there was nothing to name.
    pub fn explanation(&self) -> Explanation {
        match (self.findings.is_empty(), self.unmodelled_effect_remains) {
            (true, false) => Explanation::NothingToExplain,
            (true, true) => Explanation::Unexplained,
            (false, true) => Explanation::Partial,
            (false, false) => Explanation::Complete,
        }
    }
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

fn statics_of(schedule: &Schedule) -> usize {
    schedule.steps().iter().filter(|s| !s.is_spin()).count()
}

/// The standard deviation of parameter `i` of a fit, when its covariance gives one (a singular
/// information matrix gives NaN or a non-positive variance: no sigma).
fn sigma_of(fit: &ExtendedFit, i: usize) -> Option<f64> {
    let v = fit.covariance[(i, i)];
    (v.is_finite() && v > 0.0).then(|| v.sqrt())
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
            unseen_directions: 0,
        });
    }
    let sigma_owned: Vec<f64> = inflation.iter().map(|f| baseline.noise_sigma_m_s2 * f.sqrt()).collect();
    let sigma = sigma_owned.as_slice();
    let mut pool = candidates(array.len(), log.has_temperature());
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
        let mut bases: Vec<(usize, Option<DMatrix<f64>>)> = Vec::new();
        for (ci, c) in pool.iter().enumerate() {
            if included.contains(&ci) {
                continue;
            }
            let c_full = c.full();
            let one = [&c_full];
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
            // The unexplained part of its unit-normalised regressors: with no direction left
            // (largest singular value below 1e-6) the effect is confounded with the model; with
            // some directions inside the model's span (a common rotation of every pose), only the
            // others are fitted (the basis below). Before, a 24-parameter pose effect with such a
            // direction was fitted whole, with sigmas of tens of radians.
            let unit = DMatrix::from_fn(rmat.nrows(), rmat.ncols(), |r, k| {
                let c = rmat.column(k).norm();
                if c > 0.0 { rmat[(r, k)] / c } else { 0.0 }
            });
            let perp = &rmat - &u * (u.transpose() * &rmat);
            let unit_perp = &unit - &u * (u.transpose() * &unit);
            let svd_perp = unit_perp.clone().svd(false, true);
            let ratio = svd_perp.singular_values.max();
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
            // The directions the model absorbs (in parameter units: the columns were scaled by
            // their norms) are left out of the fit; the rest is tested.
            let basis = svd_perp.v_t.as_ref().and_then(|vt| {
                let seen: Vec<usize> =
                    (0..svd_perp.singular_values.len()).filter(|&i| svd_perp.singular_values[i] >= 1e-6).collect();
                if seen.len() == rmat.ncols() {
                    return None;
                }
                let scale = |r: usize| {
                    let c = rmat.column(r).norm();
                    if c > 0.0 { 1.0 / c } else { 0.0 }
                };
                let b = DMatrix::from_fn(rmat.ncols(), seen.len(), |r, i| vt[(seen[i], r)] * scale(r));
                // Orthonormal, so that the reported parameters are the least-norm ones.
                Some(b.qr().q())
            });
            bases.push((ci, basis));
            residual_regs.push((ci, perp, ratio));
        }
        drop(model);
        for (ci, basis) in bases {
            pool[ci].basis = basis;
        }
        // Test every separable candidate.
        let mut tested: Vec<(usize, ExtendedFit, f64, f64)> = Vec::new();
        for (ci, _, _) in &residual_regs {
            let mut effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
            effects.push(&pool[*ci]);
            let fit = fit_extended(&layout, &schedule, log, &meas, &effects, &current.x, sigma, s);
            let dp = fit.x.len() - current.x.len();
            if !(0..dp).all(|i| sigma_of(&fit, current.x.len() + i).is_some()) {
                verdicts.push((pool[*ci].label(), Verdict::NoSigma));
                continue;
            }
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
        let q = fit.x.len() - off;
        let c = &pool[ci];
        // The effect's parameters (the seen directions mapped back through the basis) and their sigmas.
        let fitted = fit.x.rows(off, q).into_owned();
        let cov = fit.covariance.view((off, off), (q, q)).into_owned();
        let (value, variance): (Vec<f64>, Vec<f64>) = match &c.basis {
            None => (fitted.iter().copied().collect(), (0..q).map(|i| cov[(i, i)]).collect()),
            Some(b) => {
                let v = b * &fitted;
                let full = b * cov * b.transpose();
                (v.iter().copied().collect(), (0..b.nrows()).map(|i| full[(i, i)]).collect())
            }
        };
        findings.push(Finding {
            name: c.effect.name().to_string(),
            accelerometer: c.accelerometer,
            value,
            sigma: variance.iter().map(|v| if v.is_finite() && *v > 0.0 { v.sqrt() } else { f64::NAN }).collect(),
            unseen_directions: c.unseen(statics_of(&schedule), schedule.len() - statics_of(&schedule)),
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
///
/// Deterministic regressors that vary within a step are tried first: each accelerometer's
/// samples are cleared of their pooled within-step regression on time and (with a temperature
/// column) temperature, each taken about its step mean, before the scatter that is left is tested.
/// A bias that follows the temperature within steps is then the deterministic loop's
/// `bias_temperature`, not correlated noise. The removed regressors vary slowly within a step, so
/// they are charged to the numerator's degrees of freedom.
pub fn allan_tests(log: &CalibrationLog, k: &[f64]) -> Vec<AllanTest> {
    use statrs::distribution::FisherSnedecor;
    let n = log.n;
    let mut out = Vec::new();
    for (j, kj) in k.iter().enumerate().take(n) {
        let (cleared, removed) = within_step_deterministic_removed(log, j, *kj);
        for m in [10usize, 50, 200] {
            let (mut between, mut within) = (0.0, 0.0);
            let (mut df1, mut df2) = (0usize, 0usize);
            let mut dt = 0.0;
            for (step_index, s) in log.steps.iter().enumerate() {
                let samples = s.samples();
                let clusters = samples / m;
                if clusters < 2 {
                    continue;
                }
                if samples > 1 {
                    dt = (s.t_s[samples - 1] - s.t_s[0]) / (samples - 1) as f64;
                }
                let x = &cleared[step_index][..clusters * m];
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
            // The deterministic regressors' parameters come out of the cluster means.
            df1 -= removed.min(df1);
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

/// Accelerometer `j`'s input-referred samples (outputs over `k`) of every step, cleared of their
/// pooled within-step least-squares regression on time and temperature (each about its step
/// mean; regressors that never vary within a step are left out), and how many regressors were
/// removed.
fn within_step_deterministic_removed(log: &CalibrationLog, j: usize, k: f64) -> (Vec<Vec<f64>>, usize) {
    let n = log.n;
    let centred = |v: &[f64]| -> Vec<f64> {
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        v.iter().map(|x| x - mean).collect()
    };
    let x: Vec<Vec<f64>> =
        log.steps.iter().map(|s| (0..s.samples()).map(|i| s.outputs[i * n + j] / k).collect()).collect();
    let mut regressors: Vec<Vec<Vec<f64>>> = vec![log.steps.iter().map(|s| centred(&s.t_s)).collect()];
    if log.has_temperature() {
        regressors.push(log.steps.iter().map(|s| centred(&s.temp_c)).collect());
    }
    // Keep the regressors that vary within steps, and only those the others do not already span.
    let mut kept: Vec<Vec<Vec<f64>>> = Vec::new();
    for r in regressors {
        let energy: f64 = r.iter().flatten().map(|v| v * v).sum();
        if energy.is_nan() || energy <= 0.0 {
            continue;
        }
        kept.push(r);
        let p = kept.len();
        let gram = DMatrix::from_fn(p, p, |a, b| {
            kept[a].iter().flatten().zip(kept[b].iter().flatten()).map(|(u, v)| u * v).sum::<f64>()
        });
        let sv = gram.singular_values();
        if sv.min() <= 1e-10 * sv.max() {
            kept.pop();
        }
    }
    let p = kept.len();
    if p == 0 {
        return (x, 0);
    }
    let gram = DMatrix::from_fn(p, p, |a, b| {
        kept[a].iter().flatten().zip(kept[b].iter().flatten()).map(|(u, v)| u * v).sum::<f64>()
    });
    let rhs =
        DVector::from_fn(p, |a, _| kept[a].iter().flatten().zip(x.iter().flatten()).map(|(u, v)| u * v).sum::<f64>());
    let Some(beta) = gram.lu().solve(&rhs) else { return (x, 0) };
    let cleared = x
        .iter()
        .enumerate()
        .map(|(s, xs)| {
            xs.iter().enumerate().map(|(i, v)| v - (0..p).map(|a| beta[a] * kept[a][s][i]).sum::<f64>()).collect()
        })
        .collect();
    (cleared, p)
}

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
