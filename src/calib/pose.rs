//! Pose error: how far each commanded pose and spin axis is from where the fixture puts it.
//!
//! Every step has a commanded direction `d` in body axes: the up direction of a static pose, the
//! table axis of a spin (held vertical, one end up). A real fixture delivers
//! `d(t) = (d + t_1 e_1 + t_2 e_2) / |d + t_1 e_1 + t_2 e_2|`, with `(e_1, e_2)` the tilt basis of
//! `d` (`sensor::misalignment::tilt_basis`) and two small angles `t` (rad) drawn with a prior
//! sigma. For a spin both gravity and the rotation follow the tilted axis:
//! `f(r) = g up(t) + W(t) r`, `up = +-d(t)`, `W = w^2 (d d^T - I)`.
//!
//! One model covers three cases:
//! - sigma 0, a perfect fixture: the commanded directions are exact (every result is the one
//!   without this module, bit for bit: nothing is drawn, no nuisance is added);
//! - a finite sigma, a real rate table's fixture error: the tilts are nuisance parameters with a
//!   Gaussian prior, and the Fisher information of the error parameters is the Schur complement
//!   `F_xx - F_xt (F_tt + I / sigma^2)^-1 F_tx`;
//! - an infinite sigma, a pose placed by hand: the tilts are free (no prior). A schedule of free
//!   poses cannot see a common rotation of every axis and every pose, so the Fisher information
//!   has (at least) three null directions: the gauge of `selfcal`.

#![allow(clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector3};

use super::params::{Layout, PER_ACCEL, StepMotion};
use super::schedule::{Schedule, Step, StepKind};
use crate::sensor::misalignment::tilt_basis;

/// Prior sigma of the tilt angles of static poses and of spin axes, rad (0: perfect fixture;
/// infinite: free, a pose placed by hand).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseError {
    pub static_sigma_rad: f64,
    pub spin_sigma_rad: f64,
}

impl Default for PoseError {
    fn default() -> Self {
        Self::PERFECT
    }
}

impl PoseError {
    /// The perfect fixture of the paper: every commanded direction is exact.
    pub const PERFECT: Self = Self { static_sigma_rad: 0.0, spin_sigma_rad: 0.0 };

    pub fn is_perfect(&self) -> bool {
        self.static_sigma_rad == 0.0 && self.spin_sigma_rad == 0.0
    }

    /// Whether any tilt is free (no prior): such a schedule has a rotation gauge.
    pub fn has_free(&self) -> bool {
        self.static_sigma_rad.is_infinite() || self.spin_sigma_rad.is_infinite()
    }

    /// Prior sigma of the tilt angles of `step`, rad.
    pub fn sigma_rad(&self, step: &Step) -> f64 {
        if step.is_spin() { self.spin_sigma_rad } else { self.static_sigma_rad }
    }

    /// Indices of the steps whose tilts are nuisance (sigma above 0), in schedule order.
    pub fn tilted_steps(&self, schedule: &Schedule) -> Vec<usize> {
        schedule.steps().iter().enumerate().filter(|(_, s)| self.sigma_rad(s) > 0.0).map(|(i, _)| i).collect()
    }
}

/// The commanded direction of a step: the up direction of a pose, the table axis of a spin.
pub fn commanded_direction(step: &Step) -> Vector3<f64> {
    match step.kind {
        StepKind::Static { up_b } => up_b,
        StepKind::Spin { axis_b, .. } => axis_b,
    }
}

/// `step` with its commanded direction tilted by the angles `t` (rad), see the module docs.
pub fn tilted(step: &Step, t: [f64; 2]) -> Step {
    let d = commanded_direction(step);
    let (e1, e2) = tilt_basis(&d);
    let n = (d + e1 * t[0] + e2 * t[1]).normalize();
    let mut out = step.clone();
    out.kind = match step.kind {
        StepKind::Static { .. } => StepKind::Static { up_b: n },
        StepKind::Spin { rate_rad_s, positive_end_up, .. } => StepKind::Spin { axis_b: n, rate_rad_s, positive_end_up },
    };
    out
}

/// The schedule with every step tilted by its angles (`tilts[s]`, rad).
pub fn tilted_schedule(schedule: &Schedule, tilts: &[[f64; 2]]) -> Schedule {
    let steps: Vec<Step> = schedule.steps().iter().zip(tilts).map(|(s, t)| tilted(s, *t)).collect();
    // Tilting keeps every direction a unit vector and every other field as it was.
    Schedule::new(schedule.name.clone(), steps).unwrap_or_else(|_| schedule.clone())
}

/// The motion of a step at tilt `t` and its partial derivatives by `t_1` and `t_2`.
pub fn motion_and_partials(step: &Step, t: [f64; 2], g_m_s2: f64) -> (StepMotion, [StepMotion; 2]) {
    let d = commanded_direction(step);
    let (e1, e2) = tilt_basis(&d);
    let v = d + e1 * t[0] + e2 * t[1];
    let norm = v.norm();
    let n = v / norm;
    // d n / d t_i = (e_i - n (n . e_i)) / |v|.
    let dn = [e1, e2].map(|e| (e - n * n.dot(&e)) / norm);
    let motion = StepMotion::new(&tilted(step, t), g_m_s2);
    let partials = dn.map(|dni| match step.kind {
        StepKind::Static { .. } => StepMotion { gravity_up_m_s2: dni * g_m_s2, w2: Matrix3::zeros() },
        StepKind::Spin { rate_rad_s, positive_end_up, .. } => {
            let sign = if positive_end_up { 1.0 } else { -1.0 };
            StepMotion {
                gravity_up_m_s2: dni * (sign * g_m_s2),
                w2: (dni * n.transpose() + n * dni.transpose()) * rate_rad_s.powi(2),
            }
        }
    });
    (motion, partials)
}

/// Derivative of accelerometer `j`'s mean output by a change `dm` of the step's motion (linear in
/// the motion: `k a . (d(g up) + dW (r + dr))`).
pub fn output_by_motion(layout: &Layout, j: usize, xj: &[f64; PER_ACCEL], dm: &StepMotion) -> f64 {
    let [k, _, m1, m2, dx, dy, dz] = *xj;
    let (a, _) = layout.axis(j, [m1, m2]);
    let r = layout.array().accelerometers()[j].position_m + Vector3::new(dx, dy, dz);
    k * a.dot(&(dm.gravity_up_m_s2 + dm.w2 * r))
}

/// The Fisher information of the error parameters `x` with the pose tilts marginalised under
/// their prior (see the module docs), for white noise of density `density_m_s2_per_sqrt_hz`. With
/// a perfect fixture this is [`super::fisher::fisher_information`] itself.
pub fn marginal_fisher(
    layout: &Layout,
    x: &DVector<f64>,
    schedule: &Schedule,
    g_m_s2: f64,
    density_m_s2_per_sqrt_hz: f64,
    pose: &PoseError,
) -> DMatrix<f64> {
    let mut f = super::fisher::fisher_information(layout, x, schedule, g_m_s2, density_m_s2_per_sqrt_hz);
    if pose.is_perfect() {
        return f;
    }
    let n = layout.array().len();
    let p = layout.len();
    let mut out = vec![0.0; n];
    let mut jac = vec![[0.0; PER_ACCEL]; n];
    for s in pose.tilted_steps(schedule) {
        let step = &schedule.steps()[s];
        let (_, partials) = motion_and_partials(step, [0.0, 0.0], g_m_s2);
        layout.step_model(x, step, g_m_s2, &mut out, Some(&mut jac));
        // F_xt (p x 2) and F_tt (2 x 2) of this step; tilts of different steps do not mix.
        let mut fxt = DMatrix::<f64>::zeros(p, 2);
        let mut ftt = Matrix2::zeros();
        for j in 0..n {
            let o = PER_ACCEL * j;
            let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| x[o + a]);
            let w = step.sampled_duration_s() / (x[o] * density_m_s2_per_sqrt_hz).powi(2);
            let gt = [output_by_motion(layout, j, &xj, &partials[0]), output_by_motion(layout, j, &xj, &partials[1])];
            for a in 0..PER_ACCEL {
                for (c, gtc) in gt.iter().enumerate() {
                    fxt[(o + a, c)] += w * jac[j][a] * gtc;
                }
            }
            for a in 0..2 {
                for b in 0..2 {
                    ftt[(a, b)] += w * gt[a] * gt[b];
                }
            }
        }
        let sigma = pose.sigma_rad(step);
        let prior = if sigma.is_finite() { 1.0 / (sigma * sigma) } else { 0.0 };
        ftt[(0, 0)] += prior;
        ftt[(1, 1)] += prior;
        let inv = symmetric_pseudo_inverse2(&ftt);
        let inv = DMatrix::<f64>::from_column_slice(2, 2, inv.as_slice());
        let update: DMatrix<f64> = &fxt * inv * fxt.transpose();
        f -= update;
    }
    // Symmetrise what the subtraction left (rounding only).
    let ft = f.transpose();
    (f + ft) * 0.5
}

/// Inverse of a symmetric 2 x 2 matrix, or its pseudo-inverse when a tilt is not observed.
fn symmetric_pseudo_inverse2(m: &Matrix2<f64>) -> Matrix2<f64> {
    let eig = m.symmetric_eigen();
    let max = eig.eigenvalues.iter().fold(0.0_f64, |a, &b| a.max(b.abs()));
    let mut inv = Matrix2::zeros();
    for (k, &lam) in eig.eigenvalues.iter().enumerate() {
        if lam > 1e-12 * max && lam > 0.0 {
            let v = eig.eigenvectors.column(k);
            inv += v * v.transpose() / lam;
        }
    }
    inv
}

/// Cramer-Rao sigma of every parameter from a (marginal) Fisher information, SI; infinite where a
/// parameter has a share in an unobserved direction. A perfect fixture's information is
/// block-diagonal by accelerometer and is inverted block by block (as before this module);
/// otherwise the pose tilts couple the accelerometers and it is inverted whole.
pub fn crb_sigma(fim: &DMatrix<f64>, n_accel: usize, block_diagonal: bool) -> Vec<f64> {
    let p = fim.nrows();
    let mut out = vec![f64::INFINITY; p];
    if block_diagonal {
        for j in 0..n_accel {
            let o = PER_ACCEL * j;
            let block: DMatrix<f64> = fim.view((o, o), (PER_ACCEL, PER_ACCEL)).clone_owned();
            if let Some(inv) = block.try_inverse() {
                for a in 0..PER_ACCEL {
                    out[o + a] = inv[(a, a)].max(0.0).sqrt();
                }
            }
        }
        return out;
    }
    // Scale to unit diagonal, then eigen-decompose: directions below 1e-12 of the largest are
    // unobserved, and every parameter with a share in one has no finite bound.
    let d: Vec<f64> = (0..p).map(|i| if fim[(i, i)] > 0.0 { 1.0 / fim[(i, i)].sqrt() } else { 0.0 }).collect();
    let scaled = DMatrix::from_fn(p, p, |a, b| fim[(a, b)] * d[a] * d[b]);
    let eig = scaled.symmetric_eigen();
    let max = eig.eigenvalues.iter().fold(0.0_f64, |a, &b| a.max(b));
    let mut var = vec![0.0; p];
    let mut unobserved = vec![false; p];
    for (k, &lam) in eig.eigenvalues.iter().enumerate() {
        let v = eig.eigenvectors.column(k);
        if lam > 1e-12 * max {
            for i in 0..p {
                var[i] += v[i] * v[i] / lam;
            }
        } else {
            for i in 0..p {
                if v[i].abs() > 1e-6 {
                    unobserved[i] = true;
                }
            }
        }
    }
    for i in 0..p {
        if d[i] > 0.0 && !unobserved[i] {
            out[i] = var[i].sqrt() * d[i];
        }
    }
    out
}
