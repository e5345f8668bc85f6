//! What a diagnosis of recordings holds: the gap of each recording before and after, the named
//! effects, the rank tests and the sensing points.

use std::path::PathBuf;

use super::sensing::SensingPoint;
use crate::discrepancy::Explanation;
use crate::selfcal::calibrate::{CalibrateError, Calibration};
use crate::selfcal::recording::RecordingError;

/// The gap of one recording, static and dynamic phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Chi-square per degree of freedom of the static interval means.
    pub static_chi2_dof: f64,
    /// `(dynamic residual RMS / static noise RMS)^2`; `None` without a rotation phase.
    pub dynamic: Option<f64>,
}

/// A held-out recording's gap before and after the named effects.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutScore {
    pub recording: PathBuf,
    pub before: Gap,
    pub after: Gap,
    /// The held-out recording's own bias minus the fitting recording's, per accelerometer, m/s^2,
    /// and its sigma.
    pub bias_change_m_s2: Vec<f64>,
    pub bias_change_sigma_m_s2: Vec<f64>,
    /// The held-out recording's own scale factor minus the fitting recording's, and its sigma
    /// (refitted with the biases).
    pub scale_factor_change: Vec<f64>,
    pub scale_factor_change_sigma: Vec<f64>,
    /// The p-values of "no change" of the biases and of the scale factors (Wald tests on the
    /// changes' whole covariance, [`super::change`]).
    pub bias_change_p_value: f64,
    pub scale_factor_change_p_value: f64,
    /// The gap after each named effect, in the order they were added.
    pub after_each: Vec<(String, Gap)>,
}

/// One effect named on recordings.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedFinding {
    pub name: String,
    /// What the values are (for a per-recording effect: the RMS over the held-out recordings of
    /// the change from the fitting recording).
    pub what: String,
    /// `None`: every accelerometer (the values are per accelerometer), or a package's or a shared
    /// effect.
    pub accelerometer: Option<usize>,
    /// The package (IMU, 0-based) of a per-package effect.
    pub package: Option<usize>,
    pub value: Vec<f64>,
    pub sigma: Vec<f64>,
    pub unit: String,
    /// The largest p-value over the held-out recordings of the effect's test (it must pass on
    /// every one).
    pub p_value_largest: f64,
}

/// A gap (static or dynamic) above this is more than the noise.
pub const GAP_ABOVE_NOISE: f64 = 2.0;

/// One effect's rank test on the fitting recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RankTest {
    pub name: String,
    pub parameters: usize,
    /// Directions the baseline (and the effects named before it) absorb.
    pub unseen: usize,
    /// Every parameter as fitted on the fitting recording, with its robust sigma (named or not;
    /// a delay relative to the median package).
    pub value: Vec<f64>,
    pub sigma: Vec<f64>,
    /// Their robust covariance.
    pub covariance: nalgebra::DMatrix<f64>,
    /// Wald test of every parameter against zero at once, with the robust covariance (over the
    /// seen directions): the effect as a whole, before owners are picked.
    pub p_value_joint: f64,
    /// Every parameter fitted with its owner's alone (the effect's other owners left out), with
    /// its robust sigma: the sigma a test of one owner has (`trial`; the naming reads the joint fit).
    /// NaN (JSON null) where the model absorbs every direction of the owner's parameters.
    pub value_alone: Vec<f64>,
    pub sigma_alone: Vec<f64>,
}

/// A whole diagnosis of recordings.
#[derive(Debug, Clone)]
pub struct RecordedDiagnosis {
    pub calibration: Calibration,
    /// The fitting recording's gap (the per-recording effects are fitted there already, so it is
    /// the same after).
    pub fitting: Gap,
    pub held_out: Vec<HeldOutScore>,
    pub findings: Vec<RecordedFinding>,
    /// The fitting recording's gap after each named effect of the library (linearised).
    pub fitting_after_each: Vec<(String, Gap)>,
    /// Effects tried and not named, with why.
    pub not_named: Vec<(String, String)>,
    /// The rank test of every effect of the library tried.
    pub ranks: Vec<RankTest>,
    /// The sensing points of the axes of each package.
    pub sensing_points: Vec<SensingPoint>,
    pub alpha: f64,
}

impl RecordedDiagnosis {
    /// What to trust in the fitting recording's calibration: `calibrate`'s verdicts
    /// ([`crate::selfcal::assessment`]), with the held-out recordings' static gaps before any
    /// named effect (the calibration carried over whole, as `calibrate --held-out` scores them).
    pub fn assessment(&self) -> Vec<crate::selfcal::assessment::Verdict> {
        let held: Vec<f64> = self.held_out.iter().map(|h| h.before.static_chi2_dof).collect();
        crate::selfcal::assessment::assess(&self.calibration, &held)
    }

    /// Whether the named effects explain the gap (to the noise) on the held-out recordings and on
    /// the fitting one, part of it, or nothing was named.
    pub fn explanation(&self) -> Explanation {
        // Above the noise: a residual variance more than twice the noise's, in either phase. (A
        // held-out gap exceeds 1 by the fitting recording's own parameter uncertainty even for a
        // right model, so a chi-square test at the noise alone would always reject it.) Fixed before
        // any recording was diagnosed.
        let above = |g: &Gap| g.static_chi2_dof > GAP_ABOVE_NOISE || g.dynamic.is_some_and(|d| d > GAP_ABOVE_NOISE);
        let fitting = self.fitting_after_each.last().map_or(self.fitting, |(_, g)| *g);
        let remains = above(&fitting) || self.held_out.iter().any(|h| above(&h.after));
        match (self.findings.is_empty(), remains) {
            (true, false) => Explanation::NothingToExplain,
            (true, true) => Explanation::Unexplained,
            (false, true) => Explanation::Partial,
            (false, false) => Explanation::Complete,
        }
    }
}

/// Why recordings cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordedError {
    #[error(transparent)]
    Calibrate(#[from] CalibrateError),
    #[error(transparent)]
    Recording(#[from] RecordingError),
}
