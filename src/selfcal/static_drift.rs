//! The static phase refitted with a bias drift in time: whether the biases drift, and the scale
//! factors, biases and tilts with the drift fitted.
//!
//! A hand-held calibration places its poses one after another, so the pose sequence is also a
//! time sequence. Where the poses' directions move steadily with time (the MIMU4444's recordings
//! visit the same 20 directions in the same order, up_y rising from -0.93 to +0.93), a bias that
//! drifts linearly in time is almost a combination of each accelerometer's static columns
//! (`1, up_x, up_y, up_z`): on the real board only 8-9% of its square is left outside them. The
//! joint fit then puts the drift into the scale factors and tilts, the static misfit hardly shows
//! it, and the printed sigmas, which do not know of it, are several times too small (3.8-5.7 times
//! in simulation, `results/mimu4444/README.md`).
//!
//! The check refits every accelerometer's `(k, b, tilt_u, tilt_w)` and a drift rate `d_j` to its
//! static pose means, `s_pj = k_j (b_j + d_j (t_p - t_mid) + a_j . g u_p)`, the poses held at the
//! joint fit's, `t_p` the interval's middle sample and `t_mid` the recording's middle (as
//! `gfcal diagnose` takes them: the bias is the bias at mid-recording). Its outputs:
//! - the **test**: the static chi^2 the drift removes from the same refit without it
//!   (`selfcal::tension`), over the drift refit's chi^2/dof where above 1 (the static phase's own
//!   excess scatter), against chi^2 on one degree of freedom a refitted accelerometer. With white
//!   noise and no drift it is that chi^2 exactly for a linear model with known noise (the unit
//!   tests check its mean and its false alarms);
//! - the **drift-refitted parameters** with their sigmas: the inverse of each accelerometer's
//!   5 x 5 information, widened by the refit's chi^2/dof where above 1 (as the joint fit widens
//!   its static sigmas). They are the static phase's answer with the drift in the model; holding
//!   the poses leaves out their own uncertainty, which the 24 accelerometers share (a small part).
//!
//! The joint fit does not model the drift; where the test rejects, `selfcal::assessment` says the
//! printed scale factors, biases and tilts are not to be trusted and points here.

use nalgebra::{Matrix4, SMatrix, SVector, Vector3};

use super::data::StaticData;
use super::model::{SensorSet, sensors};
use super::tension::{refit_static, static_chi2};
use crate::array::Array;

/// The test's p-value below which the biases are said to drift (`selfcal::assessment`; the
/// static tension's level, chosen before the check met a recording).
pub const DRIFT_P_LEVEL: f64 = 1e-3;

/// Gauss-Newton steps of each accelerometer's refit (linear in `k`, `b` and `d` but for their
/// product with `k`, nearly so in the tilts: as `selfcal::tension`).
const STEPS: usize = 4;

/// The check's outcome (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct StaticDrift {
    /// Per accelerometer the drift rate, m/s^2/s, and its sigma (NaN where not refitted).
    pub rate_m_s2_per_s: Vec<f64>,
    pub rate_sigma_m_s2_per_s: Vec<f64>,
    /// The parameters refitted with the drift: `(k, b, tilt_u, tilt_w)` from the refit, the
    /// locations the joint fit's; an accelerometer not refitted keeps the joint fit's.
    pub params: SensorSet,
    /// Sigmas of `(k, b, tilt_u, tilt_w)` with the drift fitted (NaN where not refitted).
    pub sigma: Vec<[f64; 4]>,
    /// The same parameters' sigmas from the same information with the drift held (its column
    /// left out), on the same scale: `sigma^2 - sigma_drift_held^2` is the variance the drift's
    /// own uncertainty adds ([`StaticDrift::added_variance`]).
    pub sigma_drift_held: Vec<[f64; 4]>,
    /// The static chi^2/dof with the drift, on `N P - (5 N + 2 P - 3)` degrees of freedom.
    pub chi2_dof: f64,
    /// The static chi^2/dof of the same refit without the drift (`selfcal::tension`'s).
    pub chi2_dof_without: f64,
    /// The test (module docs): statistic, degrees of freedom (refitted accelerometers), p-value.
    pub test_chi2: f64,
    pub test_dof: usize,
    pub p_value: f64,
    /// The time the drift is taken about (the bias is the bias then), s.
    pub t_mid_s: f64,
}

impl StaticDrift {
    /// Whether the biases drift beyond the static phase's scatter.
    pub fn drifts(&self) -> bool {
        self.p_value < DRIFT_P_LEVEL
    }

    /// The variance that the drift's own uncertainty adds to parameter `p` (0..4: `k, b,
    /// tilt_u, tilt_w`) of accelerometer `j` in the static phase, `sigma^2 - sigma_drift_held^2`
    /// (0 where not finite): what a calibration that takes this drift out as known leaves out of
    /// its sigmas.
    pub fn added_variance(&self, j: usize, p: usize) -> f64 {
        let v = self.sigma[j][p].powi(2) - self.sigma_drift_held[j][p].powi(2);
        if v.is_finite() { v.max(0.0) } else { 0.0 }
    }
}

/// Per parameter `(k, b, tilt_u, tilt_w)`, the median over the accelerometers of the
/// drift-refitted sigma over the printed one `printed(j, p)` (NaN where none is finite).
pub fn sigma_over_printed(d: &StaticDrift, printed: &dyn Fn(usize, usize) -> f64) -> [f64; 4] {
    let mut out = [f64::NAN; 4];
    for (p, o) in out.iter_mut().enumerate() {
        let ratios: Vec<f64> =
            (0..d.sigma.len()).map(|j| d.sigma[j][p] / printed(j, p)).filter(|r| r.is_finite() && *r > 0.0).collect();
        *o = crate::stats::median(&ratios);
    }
    out
}

/// Per parameter `(k, b, tilt_u, tilt_w)`, the RMS over the accelerometers of the drift refit's
/// move from the joint fit's value `joint` in its printed sigma `printed(j, p)` (NaN where none
/// is finite).
pub fn moves_in_printed_sigmas(d: &StaticDrift, joint: &SensorSet, printed: &dyn Fn(usize, usize) -> f64) -> [f64; 4] {
    let mut out = [f64::NAN; 4];
    for (p, o) in out.iter_mut().enumerate() {
        let moves: Vec<f64> = (0..d.sigma.len())
            .filter(|&j| d.sigma[j][p].is_finite())
            .map(|j| (d.params.get(j, p) - joint.get(j, p)) / printed(j, p))
            .filter(|m| m.is_finite())
            .collect();
        if !moves.is_empty() {
            *o = (moves.iter().map(|m| m * m).sum::<f64>() / moves.len() as f64).sqrt();
        }
    }
    out
}

/// The time of each static interval (its middle sample) and the recording's middle, s, as
/// `gfcal diagnose` takes them.
pub fn static_times(t_s: &[f64], intervals: &[super::segment::Interval]) -> (Vec<f64>, f64) {
    let times = intervals.iter().map(|iv| t_s[(iv.start + iv.end) / 2]).collect();
    let middle = match (t_s.first(), t_s.last()) {
        (Some(a), Some(b)) => 0.5 * (a + b),
        _ => 0.0,
    };
    (times, middle)
}

/// The check at the joint fit's parameters `joint` and poses `up`; `static_t_s` and `t_mid_s` from
/// [`static_times`]. `None` with fewer than 6 poses (five parameters an accelerometer and one
/// degree of freedom).
pub fn static_drift_at(
    array: &Array,
    stat: &StaticData,
    joint: &SensorSet,
    up: &[Vector3<f64>],
    static_t_s: &[f64],
    t_mid_s: f64,
    gravity_m_s2: f64,
) -> Option<StaticDrift> {
    let (n, poses) = (array.len(), up.len());
    if poses < 6 || static_t_s.len() != poses {
        return None;
    }
    let tau: Vec<f64> = static_t_s.iter().map(|t| t - t_mid_s).collect();
    let mut params = joint.clone();
    let mut rate = vec![0.0; n];
    let mut solved = vec![true; n];
    let mut information = vec![SMatrix::<f64, 5, 5>::zeros(); n];
    let weight = |p: usize, j: usize| stat.counts[p] as f64 / stat.sigma[j].powi(2);
    // One more pass than the steps: the last only forms the information at the solution.
    for step in 0..=STEPS {
        let sens = sensors(array, &params);
        for (j, s) in sens.iter().enumerate() {
            if !solved[j] {
                continue;
            }
            let mut h = SMatrix::<f64, 5, 5>::zeros();
            let mut g = SVector::<f64, 5>::zeros();
            for (p, u) in up.iter().enumerate() {
                let q: Vector3<f64> = u * gravity_m_s2;
                let drift = rate[j] * tau[p];
                let r = stat.means[(p, j)] - s.output(&q) - s.k * drift;
                let [dk, db, du, dw] = s.d_intrinsic(&q);
                let d = SVector::<f64, 5>::from([dk + drift, db, du, dw, s.k * tau[p]]);
                h.ger(weight(p, j), &d, &d, 1.0);
                g.axpy(weight(p, j) * r, &d, 1.0);
            }
            information[j] = h;
            if step == STEPS {
                continue;
            }
            match solve_scaled(&h, &g) {
                Some(x) => {
                    for p in 0..4 {
                        params.add(j, p, x[p]);
                    }
                    rate[j] += x[4];
                }
                None => solved[j] = false,
            }
        }
    }
    for j in (0..n).filter(|&j| !solved[j]) {
        for p in 0..4 {
            params.add(j, p, joint.get(j, p) - params.get(j, p));
        }
        rate[j] = 0.0;
    }
    let refitted = solved.iter().filter(|&&s| s).count();
    if refitted == 0 {
        return None;
    }
    // The static chi^2 with the drift: the intrinsic model's residual less each drift.
    let sens = sensors(array, &params);
    let mut chi2 = 0.0;
    for (p, u) in up.iter().enumerate() {
        let q = u * gravity_m_s2;
        for (j, s) in sens.iter().enumerate() {
            let r = stat.means[(p, j)] - s.output(&q) - s.k * rate[j] * tau[p];
            chi2 += r * r * weight(p, j);
        }
    }
    let chi2_dof = chi2 / super::tension::static_dof_with(n, poses, 5);
    let (without, _) = refit_static(array, stat, joint, up, gravity_m_s2);
    let chi2_without = static_chi2(array, stat, &without, up, gravity_m_s2);
    let scale = chi2_dof.max(1.0);
    let test_chi2 = (chi2_without - chi2).max(0.0) / scale;
    let p_value = crate::stats::chi2_sf(test_chi2, refitted as f64).unwrap_or(f64::NAN);
    let mut sigma = vec![[f64::NAN; 4]; n];
    let mut sigma_drift_held = vec![[f64::NAN; 4]; n];
    let mut rate_sigma = vec![f64::NAN; n];
    for j in (0..n).filter(|&j| solved[j]) {
        if let Some(cov) = inverse_scaled(&information[j]) {
            for p in 0..4 {
                sigma[j][p] = (cov[(p, p)] * scale).sqrt();
            }
            rate_sigma[j] = (cov[(4, 4)] * scale).sqrt();
        }
        let held: Matrix4<f64> = information[j].fixed_view::<4, 4>(0, 0).into_owned();
        if let Some(cov) = held.try_inverse() {
            for p in 0..4 {
                sigma_drift_held[j][p] = (cov[(p, p)] * scale).sqrt();
            }
        }
    }
    Some(StaticDrift {
        rate_m_s2_per_s: (0..n).map(|j| if solved[j] { rate[j] } else { f64::NAN }).collect(),
        rate_sigma_m_s2_per_s: rate_sigma,
        params,
        sigma,
        sigma_drift_held,
        chi2_dof,
        chi2_dof_without: chi2_without / super::tension::static_dof(n, poses),
        test_chi2,
        test_dof: refitted,
        p_value,
        t_mid_s,
    })
}

/// `h` scaled to a unit diagonal and factored; `None` where a pivot falls below `1e-10` (a
/// direction the static poses do not fix, to rounding). Returns the scaling and the factor.
fn factor_scaled(h: &SMatrix<f64, 5, 5>) -> Option<(SVector<f64, 5>, nalgebra::Cholesky<f64, nalgebra::Const<5>>)> {
    let d = h.diagonal().map(|v| if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 });
    if d.iter().any(|&v| v == 0.0) {
        return None;
    }
    let scaled = SMatrix::<f64, 5, 5>::from_fn(|i, j| d[i] * h[(i, j)] * d[j]);
    let chol = scaled.cholesky()?;
    if chol.l().diagonal().iter().any(|&l| l * l < 1e-10) {
        return None;
    }
    Some((d, chol))
}

/// `h x = g` ([`factor_scaled`]).
fn solve_scaled(h: &SMatrix<f64, 5, 5>, g: &SVector<f64, 5>) -> Option<SVector<f64, 5>> {
    let (d, chol) = factor_scaled(h)?;
    Some(chol.solve(&g.component_mul(&d)).component_mul(&d))
}

/// `h^-1` ([`factor_scaled`]).
fn inverse_scaled(h: &SMatrix<f64, 5, 5>) -> Option<SMatrix<f64, 5, 5>> {
    let (d, chol) = factor_scaled(h)?;
    let inv = chol.inverse();
    Some(SMatrix::<f64, 5, 5>::from_fn(|i, j| d[i] * inv[(i, j)] * d[j]))
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    const GRAVITY_M_S2: f64 = 9.80665;
    const SIGMA_M_S2: f64 = 0.04;
    const COUNT: usize = 100;

    /// Twenty poses whose up_y rises with time as the MIMU4444's do, not quite steadily (a rise
    /// linear in time would make a drift exactly a bias and a tilt), the azimuth turning by the
    /// golden angle, one every 25 s, and the recording's middle.
    fn board_like_poses() -> (Vec<Vector3<f64>>, Vec<f64>, f64) {
        let up = (0..20)
            .map(|p| {
                let y = (-0.8 + 1.6 * p as f64 / 19.0 + 0.12 * (2.1 * p as f64).sin()).clamp(-0.95, 0.95);
                let phi = 2.399_963_229_728_653 * p as f64;
                let r = (1.0 - y * y).sqrt();
                Vector3::new(r * phi.cos(), y, r * phi.sin())
            })
            .collect();
        let t_s: Vec<f64> = (0..20).map(|p| 12.5 + 25.0 * p as f64).collect();
        (up, t_s, 300.0)
    }

    fn truth(n: usize) -> SensorSet {
        let mut s = SensorSet::nominal(n);
        for j in 0..n {
            s.add(j, 0, 1e-3 * (j as f64 - 2.5));
            s.add(j, 1, 0.05 * (j as f64 - 3.0));
            s.add(j, 2, 2e-3 * (1.0 + j as f64));
            s.add(j, 3, -1.5e-3 * j as f64);
        }
        s
    }

    /// The static means of `truth` with drift rates `rate` (input-referred) at the poses, plus
    /// `noise(p, j)`.
    fn means(
        array: &Array,
        truth: &SensorSet,
        rate: &[f64],
        up: &[Vector3<f64>],
        t_s: &[f64],
        t_mid_s: f64,
        noise: &mut dyn FnMut() -> f64,
    ) -> StaticData {
        let sens = sensors(array, truth);
        let means = DMatrix::from_fn(up.len(), array.len(), |p, j| {
            let s = &sens[j];
            s.output(&(up[p] * GRAVITY_M_S2)) + s.k * rate[j] * (t_s[p] - t_mid_s) + noise()
        });
        StaticData { means, counts: vec![COUNT; up.len()], sigma: vec![SIGMA_M_S2; array.len()] }
    }

    /// Means made exactly from known parameters and a drift: the refit from a joint fit that put
    /// the drift elsewhere returns the truth (drift included), the static chi^2 at rounding, and
    /// the test rejects.
    #[test]
    fn the_refit_returns_the_truth_and_its_drift() {
        let array = Array::cube(0.1).expect("cube");
        let n = array.len();
        let (up, t_s, t_mid_s) = board_like_poses();
        let truth = truth(n);
        // large drifts: on these poses most of a drift is absorbed by the static columns, and the
        // test weighs what is left against the noise of the means (4 mm/s^2)
        let rate: Vec<f64> = (0..n).map(|j| -5e-4 + 1e-4 * j as f64).collect();
        let stat = means(&array, &truth, &rate, &up, &t_s, t_mid_s, &mut || 0.0);
        let mut joint = truth.clone();
        for j in 0..n {
            joint.add(j, 0, 2e-4);
            joint.add(j, 2, -1e-3);
        }
        let d = static_drift_at(&array, &stat, &joint, &up, &t_s, t_mid_s, GRAVITY_M_S2).expect("refitted");
        assert!(d.chi2_dof < 1e-12, "{}", d.chi2_dof);
        for j in 0..n {
            assert!(
                (d.rate_m_s2_per_s[j] - rate[j]).abs() < 1e-11,
                "accel {j}: {} vs {}",
                d.rate_m_s2_per_s[j],
                rate[j]
            );
            for p in 0..4 {
                assert!((d.params.get(j, p) - truth.get(j, p)).abs() < 1e-10, "accel {j} param {p}");
            }
        }
        assert!(d.chi2_dof_without > 0.0 && d.test_chi2 > 0.0, "{} {}", d.chi2_dof_without, d.test_chi2);
        assert_eq!(d.test_dof, n);
        assert!(d.drifts() && d.p_value < 1e-12, "{}", d.p_value);
        assert_eq!(d.t_mid_s, t_mid_s);
    }

    /// With white noise of known sigma: the statistic before its scaling by the refit's chi^2/dof
    /// is chi^2 on one degree of freedom an accelerometer (mean and the share above its 95%
    /// quantile over 400 draws without a drift; the scaling only lowers it), and with a drift the
    /// refitted parameters' errors over their sigmas before the same scaling have an RMS of 1.
    /// (The scaling's degrees of freedom count the poses as fitted, as they are in a calibration;
    /// here they are held at the truth, so the refit's chi^2/dof is about 1.7 and the scaling is
    /// left out of the comparison.)
    #[test]
    fn with_noise_the_test_is_chi_square_and_the_sigmas_hold() {
        let array = Array::cube(0.1).expect("cube");
        let n = array.len();
        let (up, t_s, t_mid_s) = board_like_poses();
        let truth = truth(n);
        let mut rng = rand::rngs::StdRng::seed_from_u64(20261129);
        let sigma_mean = SIGMA_M_S2 / (COUNT as f64).sqrt();
        let draws = 400;
        let q95 = crate::stats::chi2_quantile(0.95, n as f64).expect("quantile");
        let (mut sum, mut above, mut above_scaled) = (0.0, 0, 0);
        let mut z2 = [0.0; 5];
        for k in 0..draws {
            let drifting = k % 2 == 1;
            let rate: Vec<f64> = (0..n).map(|j| if drifting { -2e-5 + 4e-6 * j as f64 } else { 0.0 }).collect();
            let mut noise = || sigma_mean * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng);
            let stat = means(&array, &truth, &rate, &up, &t_s, t_mid_s, &mut noise);
            let d = static_drift_at(&array, &stat, &truth, &up, &t_s, t_mid_s, GRAVITY_M_S2).expect("refitted");
            if drifting {
                let unscale = 1.0 / d.chi2_dof.max(1.0).sqrt();
                for j in 0..n {
                    for p in 0..4 {
                        z2[p] += ((d.params.get(j, p) - truth.get(j, p)) / (d.sigma[j][p] * unscale)).powi(2);
                    }
                    z2[4] += ((d.rate_m_s2_per_s[j] - rate[j]) / (d.rate_sigma_m_s2_per_s[j] * unscale)).powi(2);
                }
                continue;
            }
            let unscaled = d.test_chi2 * d.chi2_dof.max(1.0);
            sum += unscaled;
            above += usize::from(unscaled > q95);
            above_scaled += usize::from(d.test_chi2 > q95);
        }
        let null_draws = draws / 2;
        let mean = sum / null_draws as f64;
        let se = (2.0 * n as f64 / null_draws as f64).sqrt();
        assert!((mean - n as f64).abs() < 3.5 * se, "mean {mean} against {n} (se {se})");
        // binomial(200, 0.05): mean 10, sd 3.1
        assert!((1..=21).contains(&above), "{above} of {null_draws} above the 95% quantile");
        assert!(above_scaled <= above);
        for (p, s) in z2.iter().enumerate() {
            let rms = (s / (n * draws / 2) as f64).sqrt();
            // 1,200 errors a parameter: the RMS within about 0.02 of 1
            assert!((0.93..1.07).contains(&rms), "parameter {p}: RMS z {rms}");
        }
    }

    /// The drift is nearly a combination of the static columns on these poses: its sigma with
    /// the drift fitted is several times the scale factor's and tilts' without it (the reason for
    /// the check), and a drift column with no lever (every pose at one time) is refused.
    #[test]
    fn poses_at_one_time_cannot_show_a_drift() {
        let array = Array::cube(0.1).expect("cube");
        let n = array.len();
        let (up, _, _) = board_like_poses();
        let t_s = vec![100.0; up.len()];
        let stat = means(&array, &truth(n), &vec![0.0; n], &up, &t_s, 100.0, &mut || 0.0);
        assert_eq!(static_drift_at(&array, &stat, &truth(n), &up, &t_s, 100.0, GRAVITY_M_S2), None);
        let few = &up[..5];
        assert_eq!(static_drift_at(&array, &stat, &truth(n), few, &t_s[..5], 100.0, GRAVITY_M_S2), None);
    }
}
