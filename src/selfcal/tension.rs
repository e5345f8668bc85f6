//! The static phase against the joint fit: how far the rotation phase pulls the parameters the
//! static poses determine.
//!
//! The joint fit weighs the rotation phase by its residuals' scatter as if they were white. Where
//! the rotation phase carries a model gap (on the MIMU4444 a chi^2/dof of hundreds or thousands)
//! it can move each accelerometer's bias, scale factor and tilts away from what the static pose
//! means say, and the static chi^2/dof then grows for a reason that is not in the static phase.
//! The check refits every accelerometer's `(k, b, tilt_u, tilt_w)` to its static pose means alone,
//! the poses held at the joint fit's, and reports the static chi^2/dof after it (the same degrees
//! of freedom as the fitted one, so the two compare directly) and the move of each parameter in
//! its printed sigmas. A static chi^2/dof that falls far with the refit says the rotation phase
//! pulls those parameters; one that stays says the misfit is the static phase's own (a bias drift
//! in time, say).
//!
//! It found a defect of the joint fit: on recording 4 of the MIMU4444 the static chi^2/dof was
//! 71.2 and 2.06 refitted alone (the tilts pulled by 2.8 sigmas RMS; `results/mimu4444/
//! static_tension.md`, from an independent script). The static variance component was taken from
//! the joint fit's static chi^2, so a pull lowered the static weight and the rotation phase pulled
//! further. The fit now takes it from [`static_only_chi2_dof`], recording 4 calibrates to 2.22, and
//! no real recording is flagged; the check stays as the guard.

use nalgebra::{Matrix4, Vector3, Vector4};

use super::data::StaticData;
use super::model::{SensorSet, sensors};
use crate::array::Array;

/// The check's outcome (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct StaticTension {
    /// The static chi^2/dof with each accelerometer's intrinsic parameters refitted to the static
    /// pose means alone (poses held; the fitted chi^2/dof's degrees of freedom).
    pub chi2_dof_static_only: f64,
    /// Per accelerometer, the move `static-only - joint` of `(k, b, tilt_u, tilt_w)` over the
    /// parameter's printed sigma (NaN where a sigma is not finite or the refit is singular).
    pub move_sigma: Vec<[f64; 4]>,
    /// RMS of the finite moves, in printed sigmas.
    pub move_rms_sigma: f64,
    /// The largest move: accelerometer (0-based), parameter index (`selfcal::model::NAMES`), sigmas.
    pub largest: Option<(usize, usize, f64)>,
    /// The static chi^2 the joint fit adds to the static-only refit's, over the refit's chi^2/dof
    /// (at least 1: the static phase's own excess scatter), and its degrees of freedom (4 a
    /// refitted accelerometer). Were the joint fit's intrinsic parameters the static-only ones
    /// moved by the rotation phase's noise alone, it would be a sum of `pull_dof` chi^2(1) terms
    /// with weights in `[0, 1]` (`1 -` the eigenvalues of the joint covariance over the static-only
    /// one), so `chi^2(pull_dof)` bounds it and `pull_p_value` is conservative.
    pub pull_chi2: f64,
    pub pull_dof: usize,
    pub pull_p_value: f64,
}

impl StaticTension {
    /// Whether the rotation phase pulls the static parameters beyond its noise.
    pub fn pulls(&self) -> bool {
        self.pull_p_value < PULL_P_LEVEL
    }
}

/// The pull's p-value below which the rotation phase is said to pull the static parameters (the
/// text and `selfcal::assessment`; chosen after the real recording 4 was seen, see the module docs).
pub const PULL_P_LEVEL: f64 = 1e-3;

/// Gauss-Newton steps of each accelerometer's static refit (the model is linear in `k` and `b`
/// and nearly so in the tilts, a few mrad: three steps reach rounding).
const STEPS: usize = 4;

/// Each accelerometer's `(k, b, tilt_u, tilt_w)` refitted to its static pose means alone, the
/// poses `up` held, from `joint`; with, per accelerometer, whether the static phase fixed them (an
/// accelerometer it cannot fix alone keeps `joint`'s values).
pub fn refit_static(
    array: &Array,
    stat: &StaticData,
    joint: &SensorSet,
    up: &[Vector3<f64>],
    gravity_m_s2: f64,
) -> (SensorSet, Vec<bool>) {
    let n = array.len();
    let mut params = joint.clone();
    let mut solved = vec![true; n];
    for _ in 0..STEPS {
        // One accelerometer's step reads only its own sensor: the sensors built once a step.
        let sens = sensors(array, &params);
        for (j, s) in sens.iter().enumerate() {
            if !solved[j] {
                continue;
            }
            let weight = |p: usize| stat.counts[p] as f64 / stat.sigma[j].powi(2);
            let mut h = Matrix4::<f64>::zeros();
            let mut g = Vector4::<f64>::zeros();
            for (p, u) in up.iter().enumerate() {
                let q: Vector3<f64> = u * gravity_m_s2;
                let r = stat.means[(p, j)] - s.output(&q);
                let d = Vector4::from(s.d_intrinsic(&q));
                h.ger(weight(p), &d, &d, 1.0);
                g.axpy(weight(p) * r, &d, 1.0);
            }
            match solve_scaled(&h, &g) {
                Some(step) => {
                    for (p, d) in step.iter().enumerate() {
                        params.add(j, p, *d);
                    }
                }
                None => solved[j] = false,
            }
        }
    }
    for j in (0..n).filter(|&j| !solved[j]) {
        for p in 0..4 {
            params.add(j, p, joint.get(j, p) - params.get(j, p));
        }
    }
    (params, solved)
}

/// The static phase's degrees of freedom: `N P` means less `4 N + 2 P - 3` parameters (as the
/// joint fit counts them), at least 1.
pub(super) fn static_dof(n: usize, poses: usize) -> f64 {
    static_dof_with(n, poses, 4)
}

/// [`static_dof`] with `per_accelerometer` parameters an accelerometer: `N P - (k N + 2 P - 3)`.
pub(super) fn static_dof_with(n: usize, poses: usize, per_accelerometer: usize) -> f64 {
    ((n * poses) as f64 - (per_accelerometer * n + 2 * poses) as f64 + 3.0).max(1.0)
}

/// The static chi^2/dof with [`refit_static`]'s parameters: the static phase's scatter about its
/// own best fit (the joint fit's degrees of freedom), NaN where no accelerometer is refitted.
pub fn static_only_chi2_dof(
    array: &Array,
    stat: &StaticData,
    joint: &SensorSet,
    up: &[Vector3<f64>],
    gravity_m_s2: f64,
) -> f64 {
    let (params, solved) = refit_static(array, stat, joint, up, gravity_m_s2);
    if !solved.iter().any(|&s| s) {
        return f64::NAN;
    }
    static_chi2(array, stat, &params, up, gravity_m_s2) / static_dof(array.len(), up.len())
}

/// The check at parameters `joint` and poses `up`, with the printed sigmas `sigma(j, p)` (for a
/// joint fit `fit`: `&fit.params`, `&fit.up`, `|j, p| fit.sigma(j, p)`); `gravity_m_s2` as the
/// fit used it.
pub fn tension_at(
    array: &Array,
    stat: &StaticData,
    joint: &SensorSet,
    up: &[Vector3<f64>],
    sigma: &dyn Fn(usize, usize) -> f64,
    gravity_m_s2: f64,
) -> StaticTension {
    let n = array.len();
    let poses = up.len();
    let (params, solved) = refit_static(array, stat, joint, up, gravity_m_s2);
    let mut move_sigma = vec![[f64::NAN; 4]; n];
    for (j, moves) in move_sigma.iter_mut().enumerate().filter(|(j, _)| solved[*j]) {
        for (p, m) in moves.iter_mut().enumerate() {
            let sigma = sigma(j, p);
            if sigma.is_finite() && sigma > 0.0 {
                *m = (params.get(j, p) - joint.get(j, p)) / sigma;
            }
        }
    }
    let chi2 = static_chi2(array, stat, &params, up, gravity_m_s2);
    let dof = static_dof(n, poses);
    let refitted = solved.iter().filter(|&&s| s).count();
    let pull_chi2 = (static_chi2(array, stat, joint, up, gravity_m_s2) - chi2) / (chi2 / dof).max(1.0);
    let pull_dof = 4 * refitted;
    let pull_p_value = crate::stats::chi2_sf(pull_chi2.max(0.0), pull_dof as f64).unwrap_or(f64::NAN);
    let finite: Vec<f64> = move_sigma.iter().flatten().copied().filter(|m| m.is_finite()).collect();
    let move_rms_sigma = (finite.iter().map(|m| m * m).sum::<f64>() / finite.len().max(1) as f64).sqrt();
    let largest = move_sigma
        .iter()
        .enumerate()
        .flat_map(|(j, m)| m.iter().enumerate().map(move |(p, v)| (j, p, *v)))
        .filter(|(_, _, v)| v.is_finite())
        .max_by(|a, b| a.2.abs().total_cmp(&b.2.abs()));
    StaticTension {
        chi2_dof_static_only: if refitted == 0 { f64::NAN } else { chi2 / dof },
        move_sigma,
        move_rms_sigma: if finite.is_empty() { f64::NAN } else { move_rms_sigma },
        largest,
        pull_chi2: if refitted == 0 { f64::NAN } else { pull_chi2 },
        pull_dof,
        pull_p_value,
    }
}

/// `h x = g` by Cholesky on `h` scaled to a unit diagonal, `None` where a pivot falls below
/// `1e-10` (a direction the static poses do not fix, to rounding).
fn solve_scaled(h: &Matrix4<f64>, g: &Vector4<f64>) -> Option<Vector4<f64>> {
    let d = h.diagonal().map(|v| if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 });
    if d.iter().any(|&v| v == 0.0) {
        return None;
    }
    let scaled = Matrix4::from_fn(|i, j| d[i] * h[(i, j)] * d[j]);
    let chol = scaled.cholesky()?;
    if chol.l().diagonal().iter().any(|&l| l * l < 1e-10) {
        return None;
    }
    let y = chol.solve(&g.component_mul(&d));
    Some(y.component_mul(&d))
}

/// The static chi^2 of `params` at the poses `up` (per-sample noise over each mean's count).
pub(super) fn static_chi2(
    array: &Array,
    stat: &StaticData,
    params: &SensorSet,
    up: &[Vector3<f64>],
    gravity_m_s2: f64,
) -> f64 {
    let sens = sensors(array, params);
    let mut chi2 = 0.0;
    for (p, u) in up.iter().enumerate() {
        let q = u * gravity_m_s2;
        for (j, s) in sens.iter().enumerate() {
            let r = stat.means[(p, j)] - s.output(&q);
            chi2 += r * r * stat.counts[p] as f64 / stat.sigma[j].powi(2);
        }
    }
    chi2
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// Static means made exactly from known parameters at known poses: from a joint fit whose
    /// tilts, scale factors and biases are off by set amounts, the refit returns the truth (the
    /// static-only chi^2 at rounding), and each move is the set offset over its sigma.
    #[test]
    fn the_refit_returns_the_static_truth_and_the_moves_in_sigmas() {
        let array = Array::cube(0.1).expect("cube");
        let n = array.len();
        let gravity_m_s2 = 9.80665;
        let mut truth = SensorSet::nominal(n);
        for j in 0..n {
            truth.add(j, 0, 1e-3 * (j as f64 - 2.5));
            truth.add(j, 1, 0.05 * (j as f64 - 3.0));
            truth.add(j, 2, 2e-3 * (1.0 + j as f64));
            truth.add(j, 3, -1.5e-3 * j as f64);
        }
        // twelve poses spread over the sphere
        let up: Vec<Vector3<f64>> = (0..12)
            .map(|p| {
                let z = -1.0 + (2.0 * p as f64 + 1.0) / 12.0;
                let phi = 2.399_963_229_728_653 * p as f64;
                let r = (1.0 - z * z).sqrt();
                Vector3::new(r * phi.cos(), r * phi.sin(), z)
            })
            .collect();
        let sens = sensors(&array, &truth);
        let means = DMatrix::from_fn(up.len(), n, |p, j| sens[j].output(&(up[p] * gravity_m_s2)));
        let stat = StaticData { means, counts: vec![1000; up.len()], sigma: vec![0.04; n] };
        let offsets = [2e-4, -3e-3, 1e-3, -2e-3];
        let mut joint = truth.clone();
        for j in 0..n {
            for (p, o) in offsets.iter().enumerate() {
                joint.add(j, p, *o);
            }
        }
        let sigmas = [1e-4, 1e-3, 5e-4, 5e-4];
        let t = tension_at(&array, &stat, &joint, &up, &|_, p| sigmas[p], gravity_m_s2);
        assert!(t.chi2_dof_static_only < 1e-12, "{}", t.chi2_dof_static_only);
        assert!(static_chi2(&array, &stat, &joint, &up, gravity_m_s2) > 1e3);
        for j in 0..n {
            for p in 0..4 {
                let want = -offsets[p] / sigmas[p];
                assert!(
                    (t.move_sigma[j][p] - want).abs() < 1e-6,
                    "accel {j} param {p}: {} vs {want}",
                    t.move_sigma[j][p]
                );
            }
        }
        let rms = (offsets.iter().zip(&sigmas).map(|(o, s)| (o / s).powi(2)).sum::<f64>() / 4.0).sqrt();
        assert!((t.move_rms_sigma - rms).abs() < 1e-6, "{} vs {rms}", t.move_rms_sigma);
        // the joint fit's whole static chi^2 is pull (the refit's is at rounding, so the scale is 1)
        let joint_chi2 = static_chi2(&array, &stat, &joint, &up, gravity_m_s2);
        assert!((t.pull_chi2 - joint_chi2).abs() < 1e-9 * joint_chi2, "{} vs {joint_chi2}", t.pull_chi2);
        assert_eq!(t.pull_dof, 4 * n);
        assert!(t.pull_p_value < 1e-12, "{}", t.pull_p_value);
        let (_, p, v) = t.largest.expect("a largest move");
        assert_eq!(p, 3, "tilt_w moves 4 sigmas, every other parameter 2 or 3");
        assert!((v.abs() - 4.0).abs() < 1e-6, "{v}");
    }

    /// A static phase of three poses cannot fix an accelerometer's four parameters alone: the
    /// refit leaves them, and every move is NaN (no finite move, no number).
    #[test]
    fn too_few_poses_leave_the_parameters_and_say_nothing() {
        let array = Array::cube(0.1).expect("cube");
        let n = array.len();
        let up = vec![Vector3::x(), Vector3::y(), Vector3::z()];
        let stat = StaticData { means: DMatrix::zeros(3, n), counts: vec![100; 3], sigma: vec![0.04; n] };
        let t = tension_at(&array, &stat, &SensorSet::nominal(n), &up, &|_, _| 1e-3, 9.8);
        assert!(t.move_sigma.iter().flatten().all(|m| m.is_nan()));
        assert!(t.chi2_dof_static_only.is_nan() && t.move_rms_sigma.is_nan() && t.largest.is_none());
        assert!(t.pull_chi2.is_nan() && t.pull_dof == 0 && t.pull_p_value.is_nan());
    }
}
