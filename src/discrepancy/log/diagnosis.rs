//! What a diagnosis of a log holds: each candidate's verdict, the named effects, the gap at each
//! stage, and the settings.

use super::baseline::BaselineFit;
use crate::calib::params::Form;
use crate::discrepancy::Explanation;

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
