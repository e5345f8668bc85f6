//! Schedule design for drift (`gfcal design` with drift targets): add steps from the candidate
//! pool, greedily, until LinCov's drift of the estimated compensation meets every target.
//!
//! The navigation is linearised once at the config's error parameters (the sensitivity does not
//! depend on the schedule); a schedule enters only through its Fisher information, which adds over
//! steps (with the fixture's tilts marginalised step by step, as `calib::design` does). Each round
//! adds the candidate that most reduces `sum_t max(q_t / target_t, 1)`, `q_t` the target's
//! quantile of the metric's distribution (one Gaussian: the truth is the config's), so only the
//! targets still missed pull; a schedule that cannot identify a parameter reaching a target's
//! metric makes that quantile infinite.

use nalgebra::{DMatrix, DVector, Vector3};

use super::dynamics::{Linearisation, LinearisationError, linearise};
use super::norm::GaussNorm;
use super::sources::pseudo_inverse;
use crate::calib::Layout;
use crate::calib::pose::{PoseError, marginal_fisher};
use crate::calib::schedule::{Schedule, ScheduleError, Step};
use crate::config::calibration::{DriftNavigation, DriftTarget};

/// The problem a drift design solves.
pub struct DriftProblem<'a> {
    pub layout: &'a Layout,
    /// The true error parameters (layout form).
    pub x: &'a DVector<f64>,
    pub base: &'a Schedule,
    pub pool: &'a [Step],
    pub targets: &'a [DriftTarget],
    pub navigation: &'a DriftNavigation,
    pub density_m_s2_per_sqrt_hz: f64,
    pub g_m_s2: f64,
    pub pose: &'a PoseError,
    pub max_added: usize,
}

/// Why a drift design could not run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DriftDesignError {
    #[error(transparent)]
    Linearisation(#[from] LinearisationError),
    #[error(transparent)]
    Schedule(#[from] ScheduleError),
}

/// The outcome: the steps added, and each target's quantile before and after.
#[derive(Debug, Clone)]
pub struct DriftDesign {
    pub added: Vec<Step>,
    pub schedule: Schedule,
    pub before: Vec<f64>,
    pub after: Vec<f64>,
}

impl DriftDesign {
    pub fn met(&self, targets: &[DriftTarget]) -> bool {
        self.after.iter().zip(targets).all(|(q, t)| *q <= t.value)
    }
}

/// Each target's quantile for a schedule of Fisher information `fim`.
pub fn drift_quantiles(
    layout: &Layout,
    x: &DVector<f64>,
    lin: &Linearisation,
    targets: &[DriftTarget],
    fim: &DMatrix<f64>,
    coupled: bool,
) -> Vec<f64> {
    let (cov, null) = pseudo_inverse(layout, x, fim, coupled);
    targets
        .iter()
        .map(|t| {
            let h = lin.horizons_s.iter().position(|&h| h == t.horizon_s).unwrap_or(0);
            let s = lin.block(h, t.metric);
            let scale = s.column_iter().map(|c| c.norm()).fold(0.0, f64::max);
            // An unidentifiable direction that moves this metric leaves it unbounded.
            if null.iter().any(|(dir, _)| (&s * dir).norm() > 1e-9 * scale * dir.norm().max(f64::MIN_POSITIVE)) {
                return f64::INFINITY;
            }
            let p = &s * &cov * s.transpose();
            GaussNorm::new(&Vector3::zeros(), &nalgebra::Matrix3::from_fn(|r, c| p[(r, c)])).quantile(t.quantile)
        })
        .collect()
}

fn score(q: &[f64], targets: &[DriftTarget]) -> f64 {
    q.iter().zip(targets).map(|(q, t)| (q / t.value).max(1.0)).sum()
}

/// Greedy design for drift (see the module docs).
pub fn greedy_drift(problem: &DriftProblem<'_>) -> Result<DriftDesign, DriftDesignError> {
    let DriftProblem {
        layout, x, base, pool, targets, navigation, density_m_s2_per_sqrt_hz: d, g_m_s2: g, pose, ..
    } = *problem;
    let mut horizons: Vec<f64> = targets.iter().map(|t| t.horizon_s).collect();
    horizons.sort_by(f64::total_cmp);
    horizons.dedup();
    let lin = linearise(layout, x, &navigation.trajectory, g, navigation.step_s, &horizons, false)?;
    let coupled = !pose.is_perfect();
    let mut fim = marginal_fisher(layout, x, base, g, d, pose);
    let before = drift_quantiles(layout, x, &lin, targets, &fim, coupled);
    let candidates: Vec<DMatrix<f64>> = pool
        .iter()
        .map(|s| Schedule::new("candidate", vec![s.clone()]).map(|one| marginal_fisher(layout, x, &one, g, d, pose)))
        .collect::<Result<_, _>>()?;
    let mut current = before.clone();
    let mut added = Vec::new();
    while added.len() < problem.max_added && current.iter().zip(targets).any(|(q, t)| *q > t.value) {
        let best = candidates
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let q = drift_quantiles(layout, x, &lin, targets, &(&fim + c), coupled);
                (i, score(&q, targets), q)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let Some((i, s, q)) = best else { break };
        if s >= score(&current, targets) {
            break;
        }
        fim += &candidates[i];
        current = q;
        added.push(pool[i].clone());
    }
    let schedule = base.extended(format!("{}_drift", base.name), &added)?;
    Ok(DriftDesign { added, schedule, before, after: current })
}
