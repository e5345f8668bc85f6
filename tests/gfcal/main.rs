//! Integration tests of gfcal, one module per domain.

mod anti_alias;
mod bias_drift;
mod calibrate_cli;
mod calibration;
mod cli;
mod clock;
mod clock_recovery;
mod common;
mod discrepancy;
mod lincov;
mod mc;
mod mechanization;
mod misalignment;
mod navigation;
mod noise;
mod pose;
mod protocol;
mod recorded;
mod recorded_generators;
mod reference;
mod report;
mod robust_rotation;
mod sample_rates;
mod selfcal;
mod simulate;
mod static_tension;
