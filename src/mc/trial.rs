//! One Monte Carlo trial: draw a true error set, simulate the calibration, estimate, compute the
//! Cramer-Rao sigmas, and navigate with each compensation.

use std::sync::Arc;

use nalgebra::{DVector, Vector3};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::config::{Cell, Compensation};
use crate::calib::estimate::CalibError;
use crate::calib::joint::check_identifiable;
use crate::calib::joint_pose::estimate_with_poses;
use crate::calib::measure::simulate;
use crate::calib::pose::{self, marginal_fisher, tilted_schedule};
use crate::calib::{Estimate, paper};
use crate::config::calibration::Estimator;
use crate::nav::SimulatedArray;
use crate::nav::navigator::StepFill;
use crate::nav::{MotionGrid, NavGroup, PlanStep, Route, navigate_groups};
use crate::rng::trial_rng;
use crate::sensor::noise::NoiseGenerator;
use crate::sensor::{ArrayParams, Compensator};

/// Salt of the navigation-noise streams: trial `i` navigates with `trial_rng(seed ^ NAV_SALT, i)`,
/// the same realisation for every compensation.
pub const NAV_SALT: u64 = 0x6e61_765f_6e6f_6973;
/// Salt of the fixture-tilt streams: trial `i` draws its pose tilts from
/// `trial_rng(seed ^ POSE_SALT, i)`, and only when the fixture is not perfect, so a perfect
/// fixture leaves every other stream as it was.
pub const POSE_SALT: u64 = 0x706f_7365_7469_6c74;

/// The drift metrics recorded at each horizon, with their units.
pub const DRIFT_METRICS: [(&str, &str); 4] =
    [("rate_err_rad_s", "rad/s"), ("attitude_err_rad", "rad"), ("velocity_err_m_s", "m/s"), ("position_err_m", "m")];

/// What a trial produced.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialRecord {
    pub trial: u64,
    pub cell: u32,
    pub converged: bool,
    pub iterations: u32,
    pub cost: f64,
    pub condition_number: f64,
    pub residual_sigma_m_s2: f64,
    pub message: String,
    /// Compensation-major, then horizon, then metric (see [`DRIFT_METRICS`]).
    pub drift: Vec<f64>,
    /// Per parameter, in the layout's order, SI.
    pub truth: Vec<f64>,
    pub estimated: Vec<f64>,
    pub crb_sigma: Vec<f64>,
    pub estimated_sigma: Vec<f64>,
}

/// Per-cell work done once before its trials.
#[derive(Debug, Clone)]
pub struct Prepared {
    nominal: ArrayParams,
    /// The true motion along the cell's navigation (shared by cells that navigate alike).
    grid: Arc<MotionGrid>,
    /// Why no trial of this cell can be estimated (an unidentifiable schedule), if so.
    refusal: Option<String>,
    white_density_m_s2_per_sqrt_hz: f64,
}

impl Prepared {
    /// The preparation of every cell; cells with the same trajectory, step, horizons and gravity
    /// share one motion grid.
    pub fn for_cells(cells: &[Cell]) -> Vec<Self> {
        let mut prepared: Vec<Self> = Vec::with_capacity(cells.len());
        for cell in cells {
            let same = cells.iter().zip(&prepared).find(|(other, _)| {
                other.navigation.trajectory == cell.navigation.trajectory
                    && other.navigation.step_s == cell.navigation.step_s
                    && other.navigation.horizons_s == cell.navigation.horizons_s
                    && other.calibration.gravity_m_s2 == cell.calibration.gravity_m_s2
            });
            let grid = same.map(|(_, p)| p.grid.clone());
            prepared.push(Self::with_grid(cell, grid));
        }
        prepared
    }

    pub fn new(cell: &Cell) -> Self {
        Self::with_grid(cell, None)
    }

    fn with_grid(cell: &Cell, grid: Option<Arc<MotionGrid>>) -> Self {
        let grid = grid.unwrap_or_else(|| {
            let nav = &cell.navigation;
            let gravity_i = Vector3::new(0.0, 0.0, -cell.calibration.gravity_m_s2);
            Arc::new(MotionGrid::new(&nav.trajectory, &gravity_i, nav.step_s, &nav.horizons_s))
        });
        let nominal = ArrayParams::nominal_with_scale_factors(&cell.array, &cell.errors.nominal_scale_factor);
        // A protocol's identifiability is that of each simulated recording (the gauge is fixed by
        // the calibration), not of the placeholder schedule.
        let refusal = match &cell.protocol {
            Some(_) => None,
            None => check_identifiable(&cell.layout, &cell.schedule, &nominal, cell.calibration.gravity_m_s2)
                .err()
                .map(|e| e.to_string()),
        };
        Self { nominal, grid, refusal, white_density_m_s2_per_sqrt_hz: cell.noise.white.density_m_s2_per_sqrt_hz() }
    }
}

/// Cramer-Rao sigma of every parameter of `cell` at `x`, SI, with the fixture's pose tilts
/// marginalised under their prior (`calib::pose`; per-accelerometer blocks with a perfect fixture).
pub fn crb_sigma(cell: &Cell, x: &DVector<f64>, density_m_s2_per_sqrt_hz: f64) -> Vec<f64> {
    let p = cell.layout.len();
    if density_m_s2_per_sqrt_hz <= 0.0 {
        return vec![0.0; p];
    }
    let pose = &cell.calibration.pose;
    let g = cell.calibration.gravity_m_s2;
    let fim = marginal_fisher(&cell.layout, x, &cell.schedule, g, density_m_s2_per_sqrt_hz, pose);
    pose::crb_sigma(&fim, cell.array.len(), pose.is_perfect())
}

/// Runs trial `trial` of `cell` under master seed `seed`.
pub fn run_trial(cell: &Cell, prepared: &Prepared, seed: u64, trial: u64) -> TrialRecord {
    run_trials(cell, prepared, seed, trial..trial + 1).pop().expect("one trial")
}

/// Runs trials `trials` of `cell` under master seed `seed`: each is calibrated on its own, then
/// they navigate in lockstep (`nav::navigate_groups`, their compensations side by side in packed
/// lanes). Each record is the one [`run_trial`] gives.
pub fn run_trials(cell: &Cell, prepared: &Prepared, seed: u64, trials: std::ops::Range<u64>) -> Vec<TrialRecord> {
    let calibrated: Vec<Calibrated> = trials.map(|t| calibrate_trial(cell, prepared, seed, t)).collect();
    navigate_and_record(cell, prepared, seed, &calibrated)
}

/// A trial calibrated, not yet navigated.
struct Calibrated {
    stream: u64,
    trial: u64,
    x_true: DVector<f64>,
    truth: ArrayParams,
    estimate: Result<Estimate, String>,
    crb_sigma: Vec<f64>,
}

/// Draws trial `trial`'s error set, simulates its calibration and estimates.
fn calibrate_trial(cell: &Cell, prepared: &Prepared, seed: u64, trial: u64) -> Calibrated {
    let layout = &cell.layout;
    let g = cell.calibration.gravity_m_s2;
    // A Saltelli design shares noise between a block's A and AB rows (see `noise_stream`).
    let stream = cell.saltelli.as_ref().map(|s| s.noise_stream(trial)).unwrap_or(trial);
    let mut rng = trial_rng(seed, stream);
    let x_true = match &cell.saltelli {
        Some(design) => design.sample(&cell.errors, layout, seed, trial),
        None => cell.errors.sample(layout, &mut rng),
    };
    if let Some(protocol) = &cell.protocol {
        let x_true = super::protocol::truth_in_gauge(protocol, &x_true);
        let truth = layout.unpack(&x_true);
        let (estimate, crb_sigma) = super::protocol::calibrate_one(protocol, layout, &x_true, &mut rng);
        return Calibrated { stream, trial, x_true, truth, estimate, crb_sigma };
    }
    let truth = layout.unpack(&x_true);
    let pose = &cell.calibration.pose;
    let meas = if pose.is_perfect() {
        simulate(&cell.array, &truth, &cell.schedule, &cell.noise, g, &mut rng)
    } else {
        // The fixture's tilts, from their own stream: each step tilted by N(0, sigma) per angle.
        let mut pose_rng = trial_rng(seed ^ POSE_SALT, stream);
        let tilts: Vec<[f64; 2]> = cell
            .schedule
            .steps()
            .iter()
            .map(|s| {
                let sigma = pose.sigma_rad(s);
                let mut draw = || sigma * pose_rng.sample::<f64, _>(StandardNormal);
                [draw(), draw()]
            })
            .collect();
        let delivered = tilted_schedule(&cell.schedule, &tilts);
        simulate(&cell.array, &truth, &delivered, &cell.noise, g, &mut rng)
    };
    let estimate: Result<Estimate, String> = match &prepared.refusal {
        Some(why) => Err(why.clone()),
        None => match cell.calibration.estimator {
            Estimator::Joint => {
                let (start, density) = (cell.calibration.start, prepared.white_density_m_s2_per_sqrt_hz);
                estimate_with_poses(layout, &cell.schedule, &meas, &prepared.nominal, start, g, pose, density)
            }
            Estimator::Paper => paper::estimate(layout, &cell.schedule, &meas, g),
        }
        .map_err(|e: CalibError| e.to_string()),
    };
    let crb_sigma = crb_sigma(cell, &x_true, prepared.white_density_m_s2_per_sqrt_hz);
    Calibrated { stream, trial, x_true, truth, estimate, crb_sigma }
}

/// Navigates calibrated trials of `cell` in lockstep and assembles their records.
fn navigate_and_record(cell: &Cell, prepared: &Prepared, seed: u64, calibrated: &[Calibrated]) -> Vec<TrialRecord> {
    let g = cell.calibration.gravity_m_s2;
    let nav = &cell.navigation;
    let gravity_i = Vector3::new(0.0, 0.0, -g);
    let grid = &prepared.grid;
    // Every compensation of a trial navigates the same outputs (the same noise stream) along the
    // same steps: they go in lockstep over one evaluation of the outputs, on the run's precomputed
    // motion, and with the other trials' compensations in the other lanes.
    let compensators: Vec<Vec<Option<Compensator>>> = calibrated
        .iter()
        .map(|c| {
            let converged = c.estimate.as_ref().ok().filter(|e| e.status.converged);
            nav.compensations
                .iter()
                .map(|comp| {
                    let params = match comp {
                        Compensation::Nominal => Some(&prepared.nominal),
                        Compensation::True => Some(&c.truth),
                        Compensation::Estimated => converged.map(|e| &e.params),
                    };
                    params.and_then(|params| Compensator::new(&cell.array, params).ok())
                })
                .collect()
        })
        .collect();
    let mut sources: Vec<_> = calibrated
        .iter()
        .map(|c| {
            let mut source = SimulatedArray::new(&cell.array, &c.truth, &nav.trajectory, gravity_i);
            if nav.noise && !cell.noise.is_zero() {
                let mut nav_rng = trial_rng(seed ^ NAV_SALT, c.stream);
                let generator = NoiseGenerator::new(&cell.noise, cell.array.len(), 1.0 / nav.step_s, &mut nav_rng);
                source = source.with_noise(generator, nav_rng, cell.noise.quantization_m_s2);
            }
            source
        })
        .collect();
    let mut fills: Vec<Box<StepFill<'_>>> = sources
        .iter_mut()
        .map(|source| {
            Box::new(move |i: usize, step: &PlanStep, outputs: &mut [Vec<f64>; 3]| {
                source.fill_step(&grid.motions[i], step.t_s, step.h_s, outputs);
            }) as Box<StepFill<'_>>
        })
        .collect();
    let mut groups: Vec<NavGroup<'_, '_>> = fills
        .iter_mut()
        .zip(&compensators)
        .map(|(fill, comps)| NavGroup { fill: fill.as_mut(), compensators: comps.iter().flatten().collect() })
        .collect();
    let route = Route {
        plan: &grid.plan,
        initial: &grid.initial,
        record_truths: &grid.record_truths,
        gravity_i_m_s2: &gravity_i,
    };
    let navigated = navigate_groups(&route, &mut groups);
    calibrated
        .iter()
        .zip(&compensators)
        .zip(navigated)
        .map(|((c, comps), navigated)| {
            let mut navigated = navigated.into_iter();
            let mut drift = Vec::with_capacity(nav.compensations.len() * nav.horizons_s.len() * DRIFT_METRICS.len());
            for comp in comps {
                match comp.as_ref().and_then(|_| navigated.next()) {
                    Some(samples) => {
                        for d in samples {
                            drift.extend([d.rate_err_rad_s, d.attitude_err_rad, d.velocity_err_m_s, d.position_err_m]);
                        }
                    }
                    None => drift.extend(std::iter::repeat_n(f64::NAN, nav.horizons_s.len() * DRIFT_METRICS.len())),
                }
            }
            record(cell, c, drift)
        })
        .collect()
}

/// A trial's record from its calibration and its drift.
fn record(cell: &Cell, c: &Calibrated, drift: Vec<f64>) -> TrialRecord {
    let p = cell.layout.len();
    let nan = vec![f64::NAN; p];
    let Calibrated { trial, x_true, estimate, crb_sigma, .. } = c;
    let (estimated, estimated_sigma) = match estimate {
        Ok(e) => (e.x.iter().copied().collect(), e.sigma().iter().copied().collect()),
        Err(_) => (nan.clone(), nan),
    };
    let (converged, iterations, cost, condition_number, residual_sigma_m_s2, message) = match estimate {
        Ok(e) => (
            e.status.converged,
            e.status.iterations as u32,
            e.status.cost,
            e.status.condition_number,
            e.residual_sigma_m_s2,
            e.status.message.clone(),
        ),
        Err(why) => (false, 0, f64::NAN, f64::NAN, f64::NAN, why.clone()),
    };
    TrialRecord {
        trial: *trial,
        cell: cell.index as u32,
        converged,
        iterations,
        cost,
        condition_number,
        residual_sigma_m_s2,
        message,
        drift,
        truth: x_true.iter().copied().collect(),
        estimated,
        crb_sigma: crb_sigma.clone(),
        estimated_sigma,
    }
}
