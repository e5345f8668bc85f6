//! Identifiability: Fisher information of a schedule, Cramer-Rao bounds, and the parameter
//! combinations a schedule cannot identify or identifies weakly.
//!
//! With white noise of per-sample standard deviation `sigma` (input-referred, so `k_j sigma` on
//! output j), the Fisher information of the parameters is
//! `F = sum_steps n_s sum_j (1 / (k_j sigma)^2) g_sj g_sj^T`, `g_sj = d s_j / dx` (the step model's
//! gradient), and the Cramer-Rao bound is `F^-1`. To compare parameters of different units, `F` is
//! scaled by per-parameter targets `D` (`F_s = D F D`): an eigenvalue `lambda` of `F_s` is a
//! combination whose Cramer-Rao sigma is `1 / sqrt(lambda)` targets. Eigenvalues below `1e-12`
//! of the largest are unidentifiable directions.

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use super::params::{Layout, PER_ACCEL, ParamKind, StepMotion};
use super::schedule::Schedule;
use crate::units::{M_PER_MM, M_S2_PER_UG, RAD_PER_DEG};

/// Target standard deviations per kind of parameter (display units in the names).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Targets {
    /// Relative to the scale factor, parts per million.
    pub scale_factor_ppm: f64,
    pub bias_ug: f64,
    pub misalignment_deg: f64,
    pub location_mm: f64,
}

impl Default for Targets {
    fn default() -> Self {
        Self { scale_factor_ppm: 100.0, bias_ug: 50.0, misalignment_deg: 0.01, location_mm: 0.1 }
    }
}

impl Targets {
    /// Target sigma of every parameter of `x`, SI.
    pub fn si(&self, layout: &Layout, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_iterator(
            layout.len(),
            (0..layout.len()).map(|i| match layout.kind(i) {
                ParamKind::ScaleFactor => x[i].abs() * self.scale_factor_ppm * 1e-6,
                ParamKind::Bias => self.bias_ug * M_S2_PER_UG,
                ParamKind::Misalignment(_) => self.misalignment_deg * RAD_PER_DEG,
                ParamKind::Location(_) => self.location_mm * M_PER_MM,
            }),
        )
    }
}

/// Fisher information of `schedule` at `x` for input-referred white noise of density
/// `density_m_s2_per_sqrt_hz`. A step of `n` samples at rate `r` has per-sample sigma
/// `k d sqrt(r)` at the output, so its mean carries `n / (k^2 d^2 r) = T / (k^2 d^2)`: a step's
/// information depends on its duration `T`, not on its sample rate.
pub fn fisher_information(
    layout: &Layout,
    x: &DVector<f64>,
    schedule: &Schedule,
    g_m_s2: f64,
    density_m_s2_per_sqrt_hz: f64,
) -> DMatrix<f64> {
    let motions = step_motions(schedule, g_m_s2);
    let mut f = DMatrix::zeros(layout.len(), layout.len());
    for j in 0..layout.array().len() {
        let o = PER_ACCEL * j;
        let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| x[o + a]);
        let block = fisher_block(layout, j, &xj, &motions, density_m_s2_per_sqrt_hz);
        for (a, row) in block.iter().enumerate() {
            for (b, v) in row.iter().enumerate() {
                f[(o + a, o + b)] = *v;
            }
        }
    }
    f
}

/// What each step does to the specific force, with its sampled duration: the same for every
/// accelerometer and every truth ([`fisher_block`]'s input).
pub fn step_motions(schedule: &Schedule, g_m_s2: f64) -> Vec<(StepMotion, f64)> {
    schedule.steps().iter().map(|step| (StepMotion::new(step, g_m_s2), step.sampled_duration_s())).collect()
}

/// Accelerometer `j`'s diagonal block of [`fisher_information`] at its parameters `xj`: the
/// steps' information summed in their order.
pub fn fisher_block(
    layout: &Layout,
    j: usize,
    xj: &[f64; PER_ACCEL],
    motions: &[(StepMotion, f64)],
    density_m_s2_per_sqrt_hz: f64,
) -> [[f64; PER_ACCEL]; PER_ACCEL] {
    let variance = (xj[0] * density_m_s2_per_sqrt_hz).powi(2);
    let mut block = [[0.0; PER_ACCEL]; PER_ACCEL];
    for (motion, duration_s) in motions {
        let (_, gj) = layout.accel_model(j, xj, motion);
        let w = duration_s / variance;
        for (a, row) in block.iter_mut().enumerate() {
            for (b, v) in row.iter_mut().enumerate() {
                *v += w * gj[a] * gj[b];
            }
        }
    }
    block
}

/// A weak or unidentifiable combination of parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Direction {
    /// Cramer-Rao sigma of the combination in units of the targets (infinite: unidentifiable).
    pub sigma_in_targets: f64,
    /// (parameter index, weight) of the unit combination in target-scaled units, largest first;
    /// weights below 0.05 are left out.
    pub components: Vec<(usize, f64)>,
}

/// What a schedule identifies.
#[derive(Debug, Clone)]
pub struct Identifiability {
    pub names: Vec<String>,
    /// Cramer-Rao sigma of every parameter, SI; infinite where unidentifiable.
    pub crb_sigma: DVector<f64>,
    /// Target sigma of every parameter, SI.
    pub target: DVector<f64>,
    /// Eigen-directions whose sigma exceeds one target, weakest first.
    pub weak: Vec<Direction>,
    /// Parameters with a share in an unidentifiable direction.
    pub unidentifiable: Vec<usize>,
    /// Smallest and largest eigenvalue of the target-scaled information.
    pub eigen_range: (f64, f64),
}

impl Identifiability {
    /// Whether every parameter's Cramer-Rao sigma is at or below its target.
    pub fn meets_targets(&self) -> bool {
        self.crb_sigma.iter().zip(self.target.iter()).all(|(s, t)| s <= t)
    }

    /// Formats a combination as `0.99 a1.dz - 0.12 a1.alpha_xz`.
    pub fn describe(&self, d: &Direction) -> String {
        let mut s = String::new();
        for (k, (i, w)) in d.components.iter().enumerate() {
            let sign = if *w < 0.0 {
                "-"
            } else if k > 0 {
                "+"
            } else {
                ""
            };
            if k > 0 {
                s.push(' ');
            }
            s.push_str(&format!("{sign}{:.3} {}", w.abs(), self.names[*i]));
        }
        s
    }
}

/// Relative eigenvalue below which a direction is unidentifiable.
pub const NULL_TOLERANCE: f64 = 1e-12;

/// Analyses a Fisher information (see the module docs).
pub fn analyse(layout: &Layout, x: &DVector<f64>, fim: &DMatrix<f64>, targets: &Targets) -> Identifiability {
    let p = layout.len();
    let target = targets.si(layout, x);
    let scaled = DMatrix::from_fn(p, p, |a, b| fim[(a, b)] * target[a] * target[b]);
    let max = SymmetricEigen::new(scaled.clone()).eigenvalues.max().max(f64::MIN_POSITIVE);
    let mut weak = Vec::new();
    let mut null = vec![false; p];
    let mut cov_scaled: DMatrix<f64> = DMatrix::zeros(p, p);
    let mut min = f64::INFINITY;
    // Decompose each connected block of the information on its own (the baseline model is
    // block-diagonal by accelerometer), so that a repeated eigenvalue cannot mix the directions
    // of unrelated parameters.
    for block in connected_blocks(&scaled) {
        let sub = DMatrix::from_fn(block.len(), block.len(), |a, b| scaled[(block[a], block[b])]);
        let eig = SymmetricEigen::new(sub);
        for (k, &lambda) in eig.eigenvalues.iter().enumerate() {
            min = min.min(lambda);
            let v = eig.eigenvectors.column(k);
            let is_null = lambda <= NULL_TOLERANCE * max;
            if is_null {
                for (a, &i) in block.iter().enumerate() {
                    if v[a].abs() > 1e-6 {
                        null[i] = true;
                    }
                }
            } else {
                for (a, &i) in block.iter().enumerate() {
                    for (b, &j) in block.iter().enumerate() {
                        cov_scaled[(i, j)] += v[a] * v[b] / lambda;
                    }
                }
            }
            if is_null || lambda < 1.0 {
                let mut components: Vec<(usize, f64)> =
                    block.iter().enumerate().filter(|(a, _)| v[*a].abs() >= 0.05).map(|(a, &i)| (i, v[a])).collect();
                components.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
                if components.first().is_some_and(|c| c.1 < 0.0) {
                    components.iter_mut().for_each(|c| c.1 = -c.1);
                }
                weak.push(Direction {
                    sigma_in_targets: if is_null { f64::INFINITY } else { 1.0 / lambda.sqrt() },
                    components,
                });
            }
        }
    }
    weak.sort_by(|a, b| b.sigma_in_targets.total_cmp(&a.sigma_in_targets));
    let crb_sigma = DVector::from_iterator(
        p,
        (0..p).map(|i| if null[i] { f64::INFINITY } else { target[i] * cov_scaled[(i, i)].max(0.0).sqrt() }),
    );
    Identifiability {
        names: layout.names(),
        crb_sigma,
        target,
        weak,
        unidentifiable: (0..p).filter(|&i| null[i]).collect(),
        eigen_range: (min, max),
    }
}

/// Groups of parameters linked by non-zero information (connected components), each sorted.
fn connected_blocks(m: &DMatrix<f64>) -> Vec<Vec<usize>> {
    let p = m.nrows();
    let mut seen = vec![false; p];
    let mut blocks = Vec::new();
    for start in 0..p {
        if seen[start] {
            continue;
        }
        let mut block = vec![start];
        seen[start] = true;
        let mut k = 0;
        while k < block.len() {
            let i = block[k];
            for j in 0..p {
                if !seen[j] && (m[(i, j)] != 0.0 || m[(j, i)] != 0.0) {
                    seen[j] = true;
                    block.push(j);
                }
            }
            k += 1;
        }
        block.sort_unstable();
        blocks.push(block);
    }
    blocks
}

/// Structural identifiability: the parameters a schedule cannot identify at a generic point near
/// `x` (small deterministic misalignments and location errors added, so that an identifiability
/// that hinges on exactly zero misalignment is not mistaken for a structural one).
pub fn structurally_unidentifiable(layout: &Layout, x: &DVector<f64>, schedule: &Schedule, g_m_s2: f64) -> Vec<usize> {
    let mut generic = x.clone();
    for i in 0..layout.len() {
        let wiggle = ((i as f64 + 1.0) * 0.618_033_988_75).fract() - 0.5;
        match layout.kind(i) {
            ParamKind::Misalignment(_) => generic[i] += 2e-3 * wiggle,
            ParamKind::Location(_) => generic[i] += 2e-3 * wiggle,
            _ => {}
        }
    }
    let fim = fisher_information(layout, &generic, schedule, g_m_s2, 1.0);
    analyse(layout, &generic, &fim, &Targets::default()).unidentifiable
}
