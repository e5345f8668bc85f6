//! The nonlinearity index: how far the navigator itself departs from the linear prediction at the
//! points that make a row's upper quantiles.
//!
//! For a compensation whose parameter error is `dx ~ N(m, C)` and a metric block `S_b` at the
//! last horizon, the direction that moves the metric most per unit of probability is
//! `u = C S_b^T w / sqrt(lambda)`, `(lambda, w)` the largest eigenpair of `S_b C S_b^T` (so
//! `S_b u = sqrt(lambda) w`, one standard deviation along the metric's principal axis). The real
//! navigator (`nav::navigate_groups`, the Monte Carlo's) is run with `dx = m + k u` and
//! `dx = m - k u`, and at every horizon `h`, with `d+` and `d-` the two navigated norms'
//! departures from their linear predictions `|S_h dx|`,
//!
//! ```text
//! nonlinearity = max(|d+ + d-| / (2 r), (|d+ - d-| / (2 r))^2),
//! r = max(mean of the two |S_h dx|, k sigma_h)
//! ```
//!
//! ([`pair_index`]) with `sigma_h` the metric's largest standard deviation at `h` (of the probed
//! component): the error of the linear prediction relative to the spread the quantiles are made
//! of. The even part (the norm larger, or smaller, on both sides: a quadratic term along the
//! metric's own direction) moves the quantiles at first order; the odd part (larger on one side,
//! smaller on the other) only widens the distribution about the same centre, which moves a
//! quantile at second order, hence its square (tested against the exact quantiles of
//! one-dimensional quadratic and cubic maps: at an odd part of 0.3 the p95 moves by 5.1%, under
//! its index of 0.09). It is infinite where the navigation diverges.
//!
//! The nominal compensation's errors are large and its metrics' principal axes turn with the
//! horizon, so it is probed at `k` = [`SIGMA_POINT`] (the 95th percentile of a normal's
//! magnitude) along each horizon's own directions, and its mean `m` alone by
//! `| |e| - |S m| | / max(|S m|, k sigma_h)` ([`index`]). For the estimated compensation only
//! the direction of the last horizon is used, so one pair of navigations per metric (sharing one
//! truth's outputs) serves every horizon; at an earlier horizon that direction may move the
//! metric little, and relative to `|S_h dx|` alone a small second-order term would then look
//! large: hence the spread in `r`. Its probes lie as far out as the metric's p95 at the last
//! horizon (`k = p95 / |S u|`, the parameters' part of it, without the noise), where the row's own
//! upper quantile is made (at `SIGMA_POINT` where that p95 is infinite). For a mixture the
//! probed truth is the one at the weighted 95th percentile of the last horizon's position
//! variance; its navigation is also linearised again (`analysis`), the probes' linear
//! predictions are taken from that linearisation (so they measure the navigator's departure at
//! that truth), and the change of each metric's RMS from the reference's counts in the index as
//! the truth index (the sensitivity's change across truths).
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

/// The index from a pair of probes at `c + k u` and `c - k u` (navigated norms and their linear
/// predictions), against the same reference as [`index`] (the larger of the pair's mean linear
/// norm and `scale`). With `d+` and `d-` the two departures from the linear prediction, their
/// mean `(d+ + d-) / 2` (even in `u`: a quadratic term that makes the norm larger, or smaller, on
/// both sides) moves the metric's quantiles at first order; their half difference (odd in `u`:
/// the norm larger on one side and smaller on the other) only widens the distribution about the
/// same centre, which moves a quantile at second order. So the index is
/// `max(|mean| / reference, (|half difference| / reference)^2)`. Infinite where either navigation
/// diverged; a NaN norm counts as no evidence (the other probe alone, by [`index`]).
pub fn pair_index(navigated: [f64; 2], linear: [f64; 2], scale: f64) -> f64 {
    if navigated.iter().any(|e| e.is_nan()) {
        return index(navigated[0], linear[0], scale).max(index(navigated[1], linear[1], scale));
    }
    if navigated.iter().any(|e| e.is_infinite()) {
        return f64::INFINITY;
    }
    let reference = (0.5 * (linear[0] + linear[1])).max(scale);
    let (d_plus, d_minus) = (navigated[0] - linear[0], navigated[1] - linear[1]);
    if reference > 0.0 {
        let even = (0.5 * (d_plus + d_minus)).abs() / reference;
        let odd = (0.5 * (d_plus - d_minus)).abs() / reference;
        even.max(odd * odd)
    } else if navigated.iter().any(|&e| e > 0.0) {
        f64::INFINITY
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The standard normal's distribution function (an oracle independent of the crate's norms).
    fn phi(x: f64) -> f64 {
        0.5 * statrs::function::erf::erfc(-x / std::f64::consts::SQRT_2)
    }

    /// The p95 of `|y|` for `y = g(x)`, `x ~ N(0, 1)`, from its distribution function `f`, by
    /// bisection.
    fn p95(f: impl Fn(f64) -> f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 100.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if f(mid) < 0.95 { lo = mid } else { hi = mid }
        }
        lo
    }

    /// Closed forms in one dimension, probes at `x = +-k` (`k` the p95 of `|x|`):
    /// - an odd departure, `y = a x + b x^2`: the pair's half difference is `b k / a` and its mean 0;
    ///   the exact p95 of `|y|` (from the roots of the quadratic) moves by less than the index
    ///   `(b k / a)^2`, and at `b k / a = 0.3` (5.1%) the pair is `linear` where one probe alone
    ///   (0.3) would flag it;
    /// - an even departure, `y = a x (1 + c x^2)` (monotone in `|x|`): the index is the p95's exact
    ///   relative change `c k^2`;
    /// - a diverged navigation is infinite, a NaN one no evidence.
    #[test]
    fn the_pair_index_against_exact_quantiles_in_one_dimension() {
        let k = 1.959963984540054;
        let a = 1.0;
        for r in [0.1, 0.2, 0.3, 0.5] {
            let b = r * a / k;
            let below = |t: f64| {
                let d = a * a + 4.0 * b * t;
                if d < 0.0 {
                    return 0.0;
                }
                phi((-a + d.sqrt()) / (2.0 * b)) - phi((-a - d.sqrt()) / (2.0 * b))
            };
            let exact = p95(|q| below(q) - below(-q)) / (a * k) - 1.0;
            let navigated = [(a * k + b * k * k).abs(), (-a * k + b * k * k).abs()];
            let idx = pair_index(navigated, [a * k, a * k], 0.0);
            assert!((idx - r * r).abs() < 1e-12, "r {r}: index {idx}");
            assert!(exact.abs() <= idx, "r {r}: the p95 moves by {exact}, more than the index {idx}");
            assert!(index(navigated[0], a * k, 0.0) >= r - 1e-12);
        }
        let c = 0.02;
        let exact = k * (1.0 + c * k * k) / k - 1.0;
        let e = a * k * (1.0 + c * k * k);
        let idx = pair_index([e, e], [a * k, a * k], 0.0);
        assert!((idx - exact).abs() < 1e-12, "{idx} vs {exact}");
        assert!(pair_index([f64::INFINITY, 1.0], [1.0, 1.0], 0.0).is_infinite());
        assert_eq!(pair_index([f64::NAN, 1.1], [1.0, 1.0], 0.0), index(1.1, 1.0, 0.0));
    }
}
