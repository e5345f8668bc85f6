//! The owners of the library's effects that the fitting recording holds, selected across the
//! effects: forward, one owner at a time, then backward.
//!
//! A candidate is one owner's parameters of one effect (an accelerometer's, a package's, or the
//! shared set's); an effect of several owners is also a candidate whole. **Forward:** each round
//! fits every candidate not yet taken alone (an effect whole: its owners not yet taken, together),
//! with the baseline re-adjusted and every owner already taken (of any effect) fitted with it, and
//! tests it against zero by a Wald test with the robust covariance; of those below their level it
//! takes the most significant (the smallest tail, compared as `ln p` so that the tails of
//! different degrees of freedom stay ordered where they underflow; an effect whole takes all its
//! owners not yet taken); it stops when none is below.
//! **Backward:** the owners taken are fitted jointly, and while any fails its level the one least
//! held (the largest `p / level`) is dropped and the rest refitted.
//!
//! Why not the joint fit of every owner of an effect: after the sample clocks it pays 1.3-1.9 times
//! a single owner's sigma on the MIMU4444 recordings (each sample's six timing unknowns leave the
//! owners' columns collinear), which hides an effect of one owner. Why not each owner alone: a
//! large effect leaks into the other owners' single fits (a delay of one package through the
//! direction the motion absorbs), and effects tried in a fixed order take each other's signal (a
//! quadratic scale factor read first as its accelerometer's bias drift in time). Conditioning on
//! what is taken stops the leaks; taking the most significant first, across the effects, lets
//! the true regressor in before its look-alikes; the backward step drops what an owner taken later
//! explains (`results/mimu4444/EXPECTATIONS.md` (bv)-(by)). And an effect present on every owner
//! but weak in each alone (a delay common to every package, injected into real recordings with
//! `--use-gyro`: 17 sigma each in the joint fit, no package below its level alone) enters whole, its
//! owners then kept by their tests in the joint fit, as the naming did before ((bz)-(ca)). A
//! whole taken whose every owner the backward step drops is a diffuse effect: present as a whole,
//! held by no owner (`Selection::wholes_taken`; the diagnosis says so where it is not named).

use super::projected::{Accumulated, fit_terms_given, nuisance_inverse};
use crate::stats::{chi2_log_sf, chi2_sf, wald_statistic};

/// One owner's parameters of one effect.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Index of the effect in the list tried.
    pub effect: usize,
    /// The owner's index within the effect.
    pub owner: usize,
    /// Its columns in the recording's normal equations.
    pub columns: Vec<usize>,
    /// Its test's level (its effect's share of the familywise level).
    pub level: f64,
}

/// An effect entered whole: its owners (indices into the candidates) fitted together.
#[derive(Debug, Clone, PartialEq)]
pub struct Whole {
    pub members: Vec<usize>,
    /// Its test's level (the effect's share of the familywise level).
    pub level: f64,
}

/// What the selection kept, and the evidence of what it did not.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// The candidates kept, in the order they were taken.
    pub kept: Vec<usize>,
    /// Per candidate not kept, the p-value of its test given the owners kept (1 where the model
    /// absorbs it); per candidate kept, its test in their joint fit.
    pub p_given_kept: Vec<f64>,
    /// The candidates taken forward and dropped by the backward step.
    pub dropped: Vec<usize>,
    /// Per whole taken forward (index into the wholes), its test's p-value when it was taken.
    pub wholes_taken: Vec<(usize, f64)>,
}

/// The tail and its logarithm of a Wald test of `columns`' values at `positions` of a fit.
fn tested(value: &[f64], cov: &nalgebra::DMatrix<f64>, positions: &[usize]) -> (f64, f64) {
    let v: Vec<f64> = positions.iter().map(|&i| value[i]).collect();
    let c = nalgebra::DMatrix::from_fn(positions.len(), positions.len(), |i, j| cov[(positions[i], positions[j])]);
    match wald_statistic(&v, &c) {
        Some((w, rank)) => {
            let dof = rank as f64;
            (chi2_sf(w, dof).filter(|p| p.is_finite()).unwrap_or(1.0), chi2_log_sf(w, dof))
        }
        None => (1.0, 0.0),
    }
}

/// Each set of candidates tested given `taken`: its members not yet taken fitted together, with
/// every column taken re-adjusted (the tail and its logarithm; 1 and 0 where the model absorbs
/// them), `None` where every member is taken. One nuisance inverse serves every set.
fn sets_given(
    total: &Accumulated,
    nuisance: &[usize],
    candidates: &[Candidate],
    sets: &[Vec<usize>],
    taken: &[usize],
) -> Vec<Option<(f64, f64)>> {
    let mut given = nuisance.to_vec();
    given.extend(taken.iter().flat_map(|&c| candidates[c].columns.iter().copied()));
    let pg = nuisance_inverse(total, &given);
    sets.iter()
        .map(|set| {
            let columns: Vec<usize> = set
                .iter()
                .filter(|c| !taken.contains(c))
                .flat_map(|&c| candidates[c].columns.iter().copied())
                .collect();
            if columns.is_empty() {
                return None;
            }
            let fit = fit_terms_given(total, &pg, &given, &columns);
            Some(if fit.unseen == columns.len() {
                (1.0, 0.0)
            } else {
                tested(&fit.value, &fit.covariance_robust, &(0..columns.len()).collect::<Vec<_>>())
            })
        })
        .collect()
}

/// Selects among `candidates`, and `wholes` of them, on `total` with `nuisance` re-adjusted (see
/// the module docs).
pub fn select(total: &Accumulated, nuisance: &[usize], candidates: &[Candidate], wholes: &[Whole]) -> Selection {
    // Each candidate alone, then each effect whole, with their levels.
    let mut members: Vec<Vec<usize>> = (0..candidates.len()).map(|c| vec![c]).collect();
    members.extend(wholes.iter().map(|w| w.members.clone()));
    let levels: Vec<f64> = candidates.iter().map(|c| c.level).chain(wholes.iter().map(|w| w.level)).collect();
    let mut taken: Vec<usize> = Vec::new();
    let mut wholes_taken = Vec::new();
    loop {
        let mut best: Option<(usize, f64, f64)> = None;
        for (k, t) in sets_given(total, nuisance, candidates, &members, &taken).into_iter().enumerate() {
            if let Some((p, log_p)) = t
                && p < levels[k]
                && best.is_none_or(|(_, _, b)| log_p < b)
            {
                best = Some((k, p, log_p));
            }
        }
        match best {
            Some((k, p, _)) => {
                let new: Vec<usize> = members[k].iter().copied().filter(|c| !taken.contains(c)).collect();
                taken.extend(new);
                if k >= candidates.len() {
                    wholes_taken.push((k - candidates.len(), p));
                }
            }
            None => break,
        }
    }
    let pg = nuisance_inverse(total, nuisance);
    let mut dropped = Vec::new();
    let mut p_given_kept = vec![1.0; candidates.len()];
    while !taken.is_empty() {
        let columns: Vec<usize> = taken.iter().flat_map(|&c| candidates[c].columns.iter().copied()).collect();
        let fit = fit_terms_given(total, &pg, nuisance, &columns);
        let mut at = 0;
        let mut worst: Option<(usize, f64)> = None;
        for (k, &c) in taken.iter().enumerate() {
            let e = candidates[c].columns.len();
            let (p, _) = tested(&fit.value, &fit.covariance_robust, &(at..at + e).collect::<Vec<_>>());
            at += e;
            p_given_kept[c] = p;
            let ratio = p / candidates[c].level;
            if ratio > 1.0 && worst.is_none_or(|(_, r)| ratio > r) {
                worst = Some((k, ratio));
            }
        }
        match worst {
            Some((k, _)) => dropped.push(taken.remove(k)),
            None => break,
        }
    }
    let singles = &members[..candidates.len()];
    for (c, t) in sets_given(total, nuisance, candidates, singles, &taken).into_iter().enumerate() {
        if let Some((p, _)) = t {
            p_given_kept[c] = p;
        }
    }
    Selection { kept: taken, p_given_kept, dropped, wholes_taken }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discrepancy::recorded::projected::{Block, Spread};
    use nalgebra::{DMatrix, DVector};
    use rand_distr::{Distribution, StandardNormal};

    /// Adds one row (`columns`, `residual`, weight 1, no local nuisance) to `total`.
    fn add_row(total: &mut Accumulated, columns: &[f64], residual: f64) {
        let block = Block {
            local: DMatrix::zeros(1, 0),
            columns: DMatrix::from_row_slice(1, columns.len(), columns),
            residual: DVector::from_element(1, residual),
            weight: DVector::from_element(1, 1.0),
        };
        total.add(&block, Spread::Sandwich);
    }

    /// A regression whose truth is known by construction: `y = 0.5 x1 + 0.5 x2 + noise`, with a
    /// look-alike `A = (x1 + x2) / sqrt(2) + 0.5 e` that correlates with the truth more than either
    /// true column does, and a column of pure noise. Forward takes the look-alike first, then both
    /// true columns; the joint fit of the three no longer holds the look-alike, which the backward
    /// step drops. The noise column is not taken.
    #[test]
    fn a_look_alike_taken_first_is_dropped_once_the_true_columns_are_in() {
        let mut rng = crate::rng::trial_rng(11, 0);
        let mut total = Accumulated::zeros(5);
        let mut draw = || -> f64 { StandardNormal.sample(&mut rng) };
        for _ in 0..4000 {
            let (x1, x2, e, noise, column_noise) = (draw(), draw(), draw(), draw(), draw());
            let look_alike = (x1 + x2) / 2f64.sqrt() + 0.5 * e;
            add_row(&mut total, &[1.0, look_alike, x1, x2, column_noise], 0.5 * x1 + 0.5 * x2 + noise);
        }
        let candidate = |effect: usize, owner: usize, column: usize| Candidate {
            effect,
            owner,
            columns: vec![column],
            level: 1e-4,
        };
        let candidates = [candidate(0, 0, 1), candidate(1, 0, 2), candidate(1, 1, 3), candidate(2, 0, 4)];
        let s = select(&total, &[0], &candidates, &[]);
        let mut kept = s.kept.clone();
        kept.sort_unstable();
        assert_eq!(kept, [1, 2], "{s:?}");
        assert_eq!(s.dropped, [0], "{s:?}");
        // The look-alike, refitted with the true columns, and the noise column: not significant.
        assert!(s.p_given_kept[0] > 1e-4 && s.p_given_kept[3] > 1e-4, "{s:?}");
        assert!(s.p_given_kept[1] < 1e-10 && s.p_given_kept[2] < 1e-10, "{s:?}");
    }

    /// Candidates every direction of which the nuisance absorbs are never taken (p = 1), and with
    /// nothing in the residual nothing is.
    #[test]
    fn an_absorbed_candidate_and_a_clean_residual_take_nothing() {
        let mut rng = crate::rng::trial_rng(12, 0);
        let mut total = Accumulated::zeros(3);
        for _ in 0..500 {
            let x: f64 = StandardNormal.sample(&mut rng);
            let noise: f64 = StandardNormal.sample(&mut rng);
            add_row(&mut total, &[x, 2.0 * x, 1.0], 3.0 * x + noise);
        }
        // Column 1 is twice column 0, the nuisance: absorbed whatever the residual says.
        let absorbed = Candidate { effect: 0, owner: 0, columns: vec![1], level: 0.5 };
        let s = select(&total, &[0, 2], &[absorbed], &[]);
        assert!(s.kept.is_empty() && s.dropped.is_empty(), "{s:?}");
        assert_eq!(s.p_given_kept, [1.0]);
    }

    /// A dense effect that no owner shows alone: eight columns `x_i = z_i - 0.12 sum(z)`, the truth
    /// `y = 0.5 sum(x_i) + noise`. Each column alone reads almost nothing (its covariance with the
    /// signal is 0.0014 of its variance), but the eight together are each about 11 sigma. Owner by
    /// owner the selection takes nothing; with the effect as a whole candidate it takes all eight
    /// and the backward step keeps them.
    #[test]
    fn a_dense_effect_no_owner_shows_alone_enters_whole() {
        let mut rng = crate::rng::trial_rng(13, 0);
        let mut total = Accumulated::zeros(9);
        for _ in 0..40_000 {
            let z: Vec<f64> = (0..8).map(|_| StandardNormal.sample(&mut rng)).collect();
            let sum: f64 = z.iter().sum();
            let x: Vec<f64> = z.iter().map(|v| v - 0.12 * sum).collect();
            let noise: f64 = StandardNormal.sample(&mut rng);
            let mut row = vec![1.0];
            row.extend(&x);
            add_row(&mut total, &row, 0.5 * x.iter().sum::<f64>() + noise);
        }
        let candidates: Vec<Candidate> =
            (0..8).map(|o| Candidate { effect: 0, owner: o, columns: vec![o + 1], level: 1e-4 }).collect();
        let alone = select(&total, &[0], &candidates, &[]);
        assert!(alone.kept.is_empty() && alone.wholes_taken.is_empty(), "{alone:?}");
        let whole = Whole { members: (0..8).collect(), level: 1e-3 };
        let s = select(&total, &[0], &candidates, &[whole]);
        let mut kept = s.kept.clone();
        kept.sort_unstable();
        assert_eq!(kept, (0..8).collect::<Vec<_>>(), "{s:?}");
        assert!(s.p_given_kept.iter().all(|&p| p < 1e-10), "{s:?}");
        assert!(s.wholes_taken.len() == 1 && s.wholes_taken[0].0 == 0 && s.wholes_taken[0].1 < 1e-3, "{s:?}");
    }

    /// A diffuse effect: eight independent columns, each with a coefficient of 1.8 sigma. As a
    /// whole (8 degrees of freedom) it passes its level 1e-3; no owner passes 1.25e-4, alone or in
    /// the joint fit. The whole is taken, then every owner dropped: present, held by no owner.
    #[test]
    fn a_diffuse_effect_is_taken_whole_and_held_by_no_owner() {
        let mut rng = crate::rng::trial_rng(17, 0);
        let rows = 40_000;
        let b = 1.8 / (rows as f64).sqrt();
        let mut total = Accumulated::zeros(9);
        for _ in 0..rows {
            let x: Vec<f64> = (0..8).map(|_| StandardNormal.sample(&mut rng)).collect();
            let noise: f64 = StandardNormal.sample(&mut rng);
            let mut row = vec![1.0];
            row.extend(&x);
            add_row(&mut total, &row, b * x.iter().sum::<f64>() + noise);
        }
        let candidates: Vec<Candidate> =
            (0..8).map(|o| Candidate { effect: 0, owner: o, columns: vec![o + 1], level: 1.25e-4 }).collect();
        let whole = Whole { members: (0..8).collect(), level: 1e-3 };
        let s = select(&total, &[0], &candidates, &[whole]);
        assert!(s.kept.is_empty(), "{s:?}");
        assert_eq!(s.dropped.len(), 8, "{s:?}");
        assert!(s.wholes_taken.len() == 1 && s.wholes_taken[0].1 < 1e-3, "{s:?}");
        // No owner passes alone either (the premise).
        assert!(s.p_given_kept.iter().all(|&p| p > 1.25e-4), "{s:?}");
    }
}
