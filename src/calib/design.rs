//! Schedule design: add steps from a pool of candidates, greedily, until every parameter's
//! Cramer-Rao sigma is below its target.
//!
//! Each candidate's Fisher information is computed once; information adds over steps. At each
//! round the candidate that most reduces `sum_i max(C_ii, 1)` is added, `C` the target-scaled
//! Cramer-Rao covariance (with a tiny ridge so that unidentifiable parameters count as huge
//! variances and are fixed first): an A-optimal criterion that only rewards progress on
//! parameters still above their targets.

use nalgebra::{DMatrix, DVector, Vector3};

use super::fisher::{Identifiability, Targets, analyse};
use super::params::Layout;
use super::pose::{PoseError, marginal_fisher};
use super::schedule::{Schedule, ScheduleError, Step};

/// The outcome of a design.
#[derive(Debug, Clone)]
pub struct DesignResult {
    pub base: Schedule,
    pub added: Vec<Step>,
    pub schedule: Schedule,
    pub before: Identifiability,
    pub after: Identifiability,
}

impl DesignResult {
    pub fn met(&self) -> bool {
        self.after.meets_targets()
    }
}

fn fmt_dir(v: &Vector3<f64>) -> String {
    format!("[{:.4}, {:.4}, {:.4}]", v.x, v.y, v.z)
}

/// Candidate steps: static poses with up along the 26 directions of the cube's faces, edges and
/// corners, and spins about the 13 axes among them, either end up, at each rate.
pub fn candidate_pool(duration_s: f64, sample_rate_hz: f64, rates_rad_s: &[f64]) -> Vec<Step> {
    let mut dirs = Vec::new();
    for x in -1i32..=1 {
        for y in -1i32..=1 {
            for z in -1i32..=1 {
                if (x, y, z) != (0, 0, 0) {
                    dirs.push(Vector3::new(x as f64, y as f64, z as f64).normalize());
                }
            }
        }
    }
    let mut pool: Vec<Step> = dirs
        .iter()
        .map(|d| Step::static_pose(format!("static up {}", fmt_dir(d)), *d, duration_s, sample_rate_hz))
        .collect();
    // Spin axes: one of each +- pair (the first non-zero component positive).
    let axes: Vec<_> = dirs.iter().filter(|d| d.iter().find(|c| c.abs() > 1e-12).is_some_and(|c| *c > 0.0)).collect();
    for &rate in rates_rad_s {
        for a in &axes {
            for positive in [true, false] {
                pool.push(Step::spin(
                    format!(
                        "spin about {} at {rate:.4} rad/s, {} end up",
                        fmt_dir(a),
                        if positive { "+" } else { "-" }
                    ),
                    **a,
                    rate,
                    positive,
                    duration_s,
                    sample_rate_hz,
                ));
            }
        }
    }
    pool
}

fn score(scaled: &DMatrix<f64>) -> f64 {
    let p = scaled.nrows();
    let ridge = 1e-9;
    let regularised = scaled + DMatrix::identity(p, p) * ridge;
    match regularised.cholesky() {
        Some(ch) => {
            let inv = ch.inverse();
            (0..p).map(|i| inv[(i, i)].max(1.0)).sum()
        }
        None => f64::INFINITY,
    }
}

/// Greedy design (see the module docs). Evaluates the information at `x` for white noise of
/// density `density_m_s2_per_sqrt_hz`; adds at most `max_added` steps.
#[allow(clippy::too_many_arguments)]
pub fn greedy(
    layout: &Layout,
    x: &DVector<f64>,
    base: &Schedule,
    pool: &[Step],
    targets: &Targets,
    density_m_s2_per_sqrt_hz: f64,
    g_m_s2: f64,
    max_added: usize,
    pose: &PoseError,
) -> Result<DesignResult, ScheduleError> {
    let target = targets.si(layout, x);
    let p = layout.len();
    let scale = |f: &DMatrix<f64>| DMatrix::from_fn(p, p, |a, b| f[(a, b)] * target[a] * target[b]);
    // Tilts of different steps do not mix, so the marginal information is a sum over steps.
    let base_fim = marginal_fisher(layout, x, base, g_m_s2, density_m_s2_per_sqrt_hz, pose);
    let before = analyse(layout, x, &base_fim, targets);
    let candidates: Vec<DMatrix<f64>> = pool
        .iter()
        .map(|s| {
            Schedule::new("candidate", vec![s.clone()])
                .map(|one| scale(&marginal_fisher(layout, x, &one, g_m_s2, density_m_s2_per_sqrt_hz, pose)))
        })
        .collect::<Result<_, _>>()?;
    let mut current = scale(&base_fim);
    let mut current_score = score(&current);
    let mut added = Vec::new();
    let mut fim = base_fim;
    while added.len() < max_added && !analyse(layout, x, &fim, targets).meets_targets() {
        let best =
            candidates.iter().enumerate().map(|(i, c)| (i, score(&(&current + c)))).min_by(|a, b| a.1.total_cmp(&b.1));
        let Some((i, s)) = best else { break };
        if s >= current_score {
            break;
        }
        current += &candidates[i];
        current_score = s;
        fim += DMatrix::from_fn(p, p, |a, b| candidates[i][(a, b)] / (target[a] * target[b]));
        added.push(pool[i].clone());
    }
    let schedule = base.extended(format!("{}_augmented", base.name), &added)?;
    let after = analyse(layout, x, &fim, targets);
    Ok(DesignResult { base: base.clone(), added, schedule, before, after })
}
