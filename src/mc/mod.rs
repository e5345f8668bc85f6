//! The Monte Carlo batch engine: config-driven sweeps of calibration trials, run in parallel,
//! streamed to Parquet.
//!
//! A run is a function of its config and seed. Trial `i` draws everything (error parameters,
//! calibration noise) from `trial_rng(seed, i)` and its navigation noise from
//! `trial_rng(seed ^ NAV_SALT, i)` (on a Saltelli design the error parameters come from the
//! block's stream and the noise from its A or B row's: see [`sample::Saltelli`]), so the results
//! are the same on any number of threads and when the trials are split into shards. Trials are
//! grouped into parts of a fixed size; a part is written whole (temporary name, then rename), so
//! an interrupted run resumes by running the parts that are missing.

pub mod claim;
pub mod config;
pub mod design;
pub mod outcome;
pub mod output;
pub mod protocol;
pub mod runner;
pub mod sample;
pub mod sensitivity;
pub mod sobol;
pub mod summary;
pub mod trial;

pub use config::{Cell, McConfig};
pub use runner::{Observer, RunOptions, RunOutcome, Silent, run};
