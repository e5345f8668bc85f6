//! Calibration logs (a schedule's steps with known poses and spins) and their diagnosis:
//!
//! - [`data`]: the log's table and steps; [`simulate`]: a log simulated with hidden effects;
//! - [`baseline`]: the baseline fit and its gap; [`extended`]: the model with candidate effects;
//! - [`diagnose`]: the search for missing effects; [`diagnosis`]: what it finds;
//! - [`allan`]: correlated noise within steps; [`correlation`]: residuals against regressors.

pub mod allan;
pub mod baseline;
pub mod correlation;
pub mod data;
pub mod diagnose;
pub mod diagnosis;
pub mod extended;
pub mod output;
pub mod simulate;

pub use allan::{AllanTest, allan_tests};
pub use baseline::{BaselineFit, DiagnoseError, fit_baseline, within_step_sigma};
pub use correlation::{Correlation, RegressorCorrelation, regressor_correlations};
pub use data::{CalibrationLog, LogError, LogStep};
pub use diagnose::diagnose;
pub use diagnosis::{DiagnoseSettings, Diagnosis, Finding, Stage, Verdict};
pub use extended::{Candidate, ExtendedFit, candidates};
pub use simulate::{ActiveEffect, LogSimulation, Temperature};
