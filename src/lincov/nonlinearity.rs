//! The nonlinearity index: how far the navigator itself departs from the linear prediction at the
//! points that make a row's upper quantiles.
//!
//! For a compensation whose parameter error is `dx ~ N(m, C)` and a metric block `S_b` at the
//! last horizon, the direction that moves the metric most per unit of probability is
//! `u = C S_b^T w / sqrt(lambda)`, `(lambda, w)` the largest eigenpair of `S_b C S_b^T` (so
//! `S_b u = sqrt(lambda) w`, one standard deviation along the metric's principal axis). The real
//! navigator (`nav::navigate_groups`, the Monte Carlo's) is run with `dx = m + k u` and
//! `dx = m - k u` (`k` = [`SIGMA_POINT`]: the 95th percentile of a normal's magnitude), and at
//! every horizon `h`
//!
//! ```text
//! nonlinearity = max over the two points of | |e_h(dx)| - |S_h dx| | / max(|S_h dx|, k sigma_h)
//! ```
//!
//! with `sigma_h` the metric's largest standard deviation at `h` (of the probed component): the
//! error of the linear prediction relative to the spread the quantiles are made of. Where the
//! expansion holds this is about the second-order term's size relative to the first at `k`
//! standard deviations (`||a| - |b|| <= |a - b|`); it is infinite where the navigation diverges.
//! For the estimated compensation only the direction of the last horizon is used, so one pair of
//! navigations per metric (sharing one truth's outputs) serves every horizon; at an earlier horizon
//! that direction may move the metric little, and relative to `|S_h dx|` alone a small
//! second-order term would then look large: hence the spread in the denominator. The nominal
//! compensation's errors are large and its metrics' principal axes turn with the horizon, so it
//! is probed along each horizon's own directions. For a mixture the probed truth's navigation is
//! also linearised again (`analysis`), and the change of each metric's RMS from the reference's
//! counts in the index (the sensitivity's change across truths).
//! Sensor noise is not in the sigma points (its effect on the rate
//! equation is of second order in the noise-driven rate error, small beside the calibration
//! residuals in every shipped config).

use nalgebra::{DMatrix, DVector, SymmetricEigen, Vector3};

use crate::array::Array;
use crate::calib::params::Layout;
use crate::nav::navigator::StepFill;
use crate::nav::{MotionGrid, NavGroup, PlanStep, Route, SimulatedArray, navigate_groups};
use crate::sensor::params::Compensator;

/// Standard deviations along the principal direction at which the navigator is compared with
/// the linear prediction (the 95th percentile of `|N(0, 1)|`).
pub const SIGMA_POINT: f64 = 1.96;

/// One navigation to run: the outputs of an array with parameters `truth`, compensated with
/// `compensation` (both layout form).
#[derive(Debug, Clone)]
pub struct Probe {
    pub truth: DVector<f64>,
    pub compensation: DVector<f64>,
}

/// The drift norms of each probe at each horizon of the grid (rate, attitude, velocity,
/// position); infinite where the navigation diverged, NaN where the compensation is degenerate.
/// Only the first `reach` horizons are navigated to (the navigator stops at the last of them; its
/// steps up to there are the same): NaN at the others.
pub fn navigate_probes(
    layout: &Layout,
    grid: &MotionGrid,
    g_m_s2: f64,
    probes: &[Probe],
    reach: usize,
) -> Vec<Vec<[f64; 4]>> {
    let array: &Array = layout.array();
    let gravity_i = Vector3::new(0.0, 0.0, -g_m_s2);
    let horizons = grid.plan.records.len();
    // Probes with the same truth share one source of outputs (a group of the navigator, whose
    // compensations go in lockstep on the same outputs).
    let mut truths: Vec<&DVector<f64>> = Vec::new();
    let group_of: Vec<usize> = probes
        .iter()
        .map(|p| match truths.iter().position(|t| **t == p.truth) {
            Some(g) => g,
            None => {
                truths.push(&p.truth);
                truths.len() - 1
            }
        })
        .collect();
    let params: Vec<_> = truths.iter().map(|t| layout.unpack(t)).collect();
    let comps: Vec<Option<Compensator>> =
        probes.iter().map(|p| Compensator::new(array, &layout.unpack(&p.compensation)).ok()).collect();
    // No trajectory is evaluated: every output comes from the grid's motions.
    let trajectory = crate::nav::Trajectory::rest(1.0, nalgebra::UnitQuaternion::identity());
    let mut sources: Vec<_> = params
        .iter()
        .map(|t| SimulatedArray::<rand_chacha::ChaCha8Rng>::new(array, t, &trajectory, gravity_i))
        .collect();
    let mut fills: Vec<Box<StepFill<'_>>> = sources
        .iter_mut()
        .map(|source| {
            Box::new(move |i: usize, step: &PlanStep, outputs: &mut [Vec<f64>; 3]| {
                source.fill_step(&grid.motions[i], step.t_s, step.h_s, outputs);
            }) as Box<StepFill<'_>>
        })
        .collect();
    // Per group, the probes navigated in it (those with a compensator), in order.
    let members: Vec<Vec<usize>> = (0..truths.len())
        .map(|g| (0..probes.len()).filter(|&k| group_of[k] == g && comps[k].is_some()).collect())
        .collect();
    let mut groups: Vec<NavGroup<'_, '_>> = Vec::new();
    let mut navigated_groups = Vec::new();
    for (fill, who) in fills.iter_mut().zip(&members) {
        if who.is_empty() {
            continue;
        }
        navigated_groups.push(who);
        let compensators = who.iter().filter_map(|&k| comps[k].as_ref()).collect();
        groups.push(NavGroup { fill: fill.as_mut(), compensators });
    }
    let reach = reach.clamp(1, horizons.max(1));
    let shortened;
    let plan = if reach < horizons {
        let records = grid.plan.records[..reach].to_vec();
        let steps = grid.plan.steps[..records[reach - 1].0].to_vec();
        shortened = crate::nav::Plan { steps, records };
        &shortened
    } else {
        &grid.plan
    };
    let route = Route {
        plan,
        initial: &grid.initial,
        record_truths: &grid.record_truths[..reach.min(grid.record_truths.len())],
        gravity_i_m_s2: &gravity_i,
    };
    let mut out = vec![vec![[f64::NAN; 4]; horizons]; probes.len()];
    for (who, samples) in navigated_groups.into_iter().zip(navigate_groups(&route, &mut groups)) {
        for (&k, s) in who.iter().zip(samples) {
            for (o, d) in out[k].iter_mut().zip(s) {
                *o = [d.rate_err_rad_s, d.attitude_err_rad, d.velocity_err_m_s, d.position_err_m];
            }
        }
    }
    out
}

/// The principal direction of metric block `s_b` (3 x P) under parameter covariance `cov`: `u`
/// with `s_b u` one standard deviation along the largest axis; `None` without variance.
pub fn principal_direction(s_b: &DMatrix<f64>, cov: &DMatrix<f64>) -> Option<DVector<f64>> {
    let sc = s_b * cov;
    let p = &sc * s_b.transpose();
    let eig = SymmetricEigen::new((&p + p.transpose()) * 0.5);
    let (k, lambda) =
        eig.eigenvalues.iter().enumerate().fold((0, f64::MIN), |a, (k, &l)| if l > a.1 { (k, l) } else { a });
    if lambda.is_nan() || lambda <= 0.0 {
        return None;
    }
    let w = eig.eigenvectors.column(k);
    Some(sc.transpose() * w / lambda.sqrt())
}

/// The index at one horizon from a probe's navigated norm, its linear prediction, and the
/// scale of the metric's spread there (`SIGMA_POINT` standard deviations along its largest axis):
/// `| |e| - |S dx| | / max(|S dx|, scale)`. Infinite where the navigation diverged (or moved
/// without any linear response), 0 where neither moved; a NaN norm (a degenerate compensation)
/// counts as 0 (no evidence).
pub fn index(navigated: f64, linear: f64, scale: f64) -> f64 {
    if navigated.is_nan() {
        return 0.0;
    }
    if navigated.is_infinite() {
        return f64::INFINITY;
    }
    let reference = linear.max(scale);
    if reference > 0.0 {
        (navigated - linear).abs() / reference
    } else if navigated > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}
