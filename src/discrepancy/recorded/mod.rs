//! Diagnosis of real recordings (free hand-held calibrations): the baseline model's gap on the
//! fitting and held-out recordings, and the per-recording effects that close part of it.
//!
//! - [`diagnose`]: the workflow; [`diagnosis`]: what it finds;
//! - [`effect`]: the library of real-recording effects and their regressors;
//! - [`blocks`]: each recording's normal equations with the effects' columns;
//! - [`projected`]: terms fitted on top of the eliminated nuisance; [`selection`]: the owners the
//!   fitting recording holds, selected across the effects; [`trial`]: each effect's rank test and
//!   held-out trial; [`change`]: the test of a per-recording parameter's change;
//! - [`sample_spread`]: each rotation-phase output's weight after the sample clocks;
//! - [`sensing`]: the sensing points of each package's axes.

pub mod blocks;
pub mod change;
pub mod diagnose;
pub mod diagnosis;
pub mod effect;
pub mod output;
pub mod projected;
pub mod sample_spread;
pub mod selection;
pub mod sensing;
pub mod trial;

pub use diagnose::diagnose_recordings;
pub use diagnosis::{GAP_ABOVE_NOISE, Gap, HeldOutScore, RankTest, RecordedDiagnosis, RecordedError, RecordedFinding};
