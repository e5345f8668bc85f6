//! The library of `recorded_effect` tried on recordings.
//!
//! **On the fitting recording** the owners of the effects (an accelerometer's, a package's, or the
//! shared set's parameters) are selected across the effects, forward one owner at a time, each
//! conditional on those already taken, then backward ([`super::selection`]); each owner's Wald test
//! with the robust covariance is at its effect's level `alpha / (owners x effects tried)`, and an
//! effect of several owners also enters whole at `alpha / effects tried`. The
//! effects with owners kept are then tried, each refitted on its owners by themselves, on top of
//! the effects already named: those that differ between recordings first (on the held-out
//! recordings a property of the hardware is judged on top of what is refitted on each, as on top
//! of the turn-on effects), each group in the order its effects entered the selection; then the
//! rest, for their rank tests.
//!
//! Each effect's rank test (`RankTest`) fits all its owners jointly, on top of the effects named
//! before it; each owner is also fitted **alone** (the baseline re-adjusted, the effect's other
//! owners left out: `value_alone`, `sigma_alone`, the sigma a test of one owner has). After the
//! sample clocks the joint fit pays 1.3-1.9 times that in sigma on the MIMU4444 diagnoses
//! (quadratic scale factor and cross-coupling; each sample's six timing unknowns leave 9 of its
//! 24 outputs' degrees of freedom, in which the owners' columns are collinear; without the clocks
//! 0.94-1.04 for the quadratic scale factor, 0.8-1.3 for the cross-coupling). Until 2026-12-01 the
//! naming tested each owner in the joint fit of its effect, effect by effect in a fixed order;
//! screening each owner alone failed four generator tests (`results/mimu4444/EXPECTATIONS.md`
//! (bv)-(bw)), which the selection passes ((by)).
//!
//! **On the held-out recordings**, what must differ between recordings is refitted there (poses,
//! motion, and the turn-on bias and scale factor if they were named). The fitting recording's
//! extended model is carried over whole: its re-adjusted baseline parameters (an effect's static
//! part moves the scale factors and biases it is fitted with) and the effect itself if it is a
//! property of the hardware, which must then lower the gap on every held-out recording. An effect
//! that differs between recordings (`per_recording`) is refitted on each and must pass its test
//! there too (level `alpha / held-out recordings`).
//! Only then is it named. A named effect joins the model for the effects after it.
//!
//! The gaps after each addition are the linearised ones: the phase's gap times the ratio of its
//! weighted residual sum of squares with the effect to without.

use super::blocks::RecordingNormal;
use super::diagnosis::{Gap, RankTest, RecordedFinding};
use super::effect::{EffectLayout, Owner, RecordedEffect};
use super::projected::{Accumulated, TermFit, fit_terms, fit_terms_given, nuisance_inverse, nuisance_step, ss_with};
use super::selection::{Candidate, Whole, select};
use crate::stats::wald_p;

/// A held-out recording as the trial sees it.
#[derive(Debug, Clone)]
pub struct HeldOutNormal {
    pub normal: RecordingNormal,
    /// Its gap before any effect of the library (after the turn-on effects).
    pub gap: Gap,
}

/// What the library found.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    pub findings: Vec<RecordedFinding>,
    pub not_named: Vec<(String, String)>,
    pub ranks: Vec<RankTest>,
    /// The fitting recording's gap after each named effect.
    pub fitting_after_each: Vec<(String, Gap)>,
    /// Per held-out recording, its gap after each named effect.
    pub held_out_after_each: Vec<Vec<(String, Gap)>>,
}

/// Both phases' weighted sums of squares with the nuisance re-adjusted and `terms` at `theta`.
fn phase_ss(s: &Accumulated, d: &Accumulated, nuisance: &[usize], terms: &[usize], theta: &[f64]) -> (f64, f64) {
    let mut t = s.clone();
    t.merge(d);
    (ss_with(s, &t, nuisance, terms, theta), ss_with(d, &t, nuisance, terms, theta))
}

fn scaled(gap: &Gap, base: (f64, f64), now: (f64, f64)) -> Gap {
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 1.0 };
    Gap {
        static_chi2_dof: gap.static_chi2_dof * ratio(now.0, base.0),
        dynamic: gap.dynamic.map(|g| g * ratio(now.1, base.1)),
    }
}

/// Tries `effects` in turn (see the module docs).
pub fn try_effects(
    fitting: &RecordingNormal,
    fitting_gap: Gap,
    held_out: &[HeldOutNormal],
    effects: &[RecordedEffect],
    layout: &EffectLayout,
    alpha: f64,
) -> TrialOutcome {
    let mut out = TrialOutcome {
        findings: Vec::new(),
        not_named: Vec::new(),
        ranks: Vec::new(),
        fitting_after_each: Vec::new(),
        held_out_after_each: vec![Vec::new(); held_out.len()],
    };
    let total_a = fitting.total();
    // The fitting recording's nuisance grows with each named effect (fitted jointly there).
    let mut nuisance_a = fitting.nuisance();
    // The columns of the named effects refitted per recording (not carried over).
    let mut per_recording_cols: Vec<usize> = Vec::new();
    let base_a = phase_ss(&fitting.statics, &fitting.dynamics, &nuisance_a, &[], &[]);
    // Each held-out recording's accumulations, shifted by the named effects' values.
    let mut current: Vec<(Accumulated, Accumulated)> =
        held_out.iter().map(|h| (h.normal.statics.clone(), h.normal.dynamics.clone())).collect();
    let base_b: Vec<(f64, f64)> = held_out
        .iter()
        .map(|h| phase_ss(&h.normal.statics, &h.normal.dynamics, &h.normal.nuisance(), &[], &[]))
        .collect();
    let tried = effects.len().max(1) as f64;
    // The owners the fitting recording holds, selected across the effects (`selection`).
    let mut candidates = Vec::new();
    for (e_index, effect) in effects.iter().enumerate() {
        if effect.per_recording() && held_out.is_empty() {
            continue;
        }
        let (p, per) = (effect.parameters(layout), effect.per_owner());
        let cols = fitting.effect_columns(e_index, p);
        for owner in 0..p / per {
            candidates.push(Candidate {
                effect: e_index,
                owner,
                columns: cols[owner * per..(owner + 1) * per].to_vec(),
                level: alpha / ((p / per) as f64 * tried),
            });
        }
    }
    // Each effect of several owners also whole, at its share of the familywise level.
    let mut wholes = Vec::new();
    for e_index in 0..effects.len() {
        let members: Vec<usize> = (0..candidates.len()).filter(|&c| candidates[c].effect == e_index).collect();
        if members.len() > 1 {
            wholes.push(Whole { members, level: alpha / tried });
        }
    }
    let selection = select(&total_a, &nuisance_a, &candidates, &wholes);
    // The effects with owners kept: those that differ between recordings first (what is refitted on
    // each recording is in the model before a property of the hardware is judged on it, as the
    // turn-on effects are), each group in the order its effects first entered; then the others.
    let mut order: Vec<usize> = Vec::new();
    for per_recording in [true, false] {
        for &c in &selection.kept {
            let e = candidates[c].effect;
            if effects[e].per_recording() == per_recording && !order.contains(&e) {
                order.push(e);
            }
        }
    }
    order.extend((0..effects.len()).filter(|e| !order.contains(e)).collect::<Vec<_>>());
    // Reported in the library's order whatever the order tried.
    let mut ranks: Vec<Option<RankTest>> = vec![None; effects.len()];
    let mut not_named: Vec<Vec<(String, String)>> = vec![Vec::new(); effects.len()];
    for &e_index in &order {
        let effect = &effects[e_index];
        let name = effect.name().to_string();
        let p = effect.parameters(layout);
        let cols = fitting.effect_columns(e_index, p);
        let pg = nuisance_inverse(&total_a, &nuisance_a);
        let mut tf = fit_terms_given(&total_a, &pg, &nuisance_a, &cols);
        if tf.unseen == 1 && effect.per_owner() == 1 {
            // One direction unseen (a delay common to every package): the values are seen only
            // relative to each other; test each against the median owner (the sparse reading:
            // one package delayed leaves the others at the median).
            relative_to_median(&mut tf);
        }
        let per = effect.per_owner();
        let owners = p / per;
        let owner_columns = |o: usize| (o * per..(o + 1) * per).collect::<Vec<usize>>();
        let alone: Vec<TermFit> = (0..owners)
            .map(|o| {
                let c: Vec<usize> = owner_columns(o).iter().map(|&i| cols[i]).collect();
                fit_terms_given(&total_a, &pg, &nuisance_a, &c)
            })
            .collect();
        ranks[e_index] = Some(RankTest {
            name: name.clone(),
            parameters: p,
            unseen: tf.unseen,
            value: tf.value.clone(),
            sigma: tf.sigma_robust.clone(),
            covariance: tf.covariance_robust.clone(),
            p_value_joint: wald_p(&tf.value, &tf.covariance_robust),
            value_alone: alone.iter().flat_map(|a| seen_or_nan(a, &a.value)).collect(),
            sigma_alone: alone.iter().flat_map(|a| seen_or_nan(a, &a.sigma_robust)).collect(),
        });
        if tf.unseen == p {
            not_named[e_index].push((
                name,
                format!("every one of its {p} directions is absorbed by the model (rank test): no recording of this kind can see it"),
            ));
            continue;
        }
        if effect.per_recording() && held_out.is_empty() {
            not_named[e_index]
                .push((name, "differs between recordings: needs held-out recordings (--held-out)".into()));
            continue;
        }
        // The owners the selection kept, in the owners' order.
        let level = alpha / (owners as f64 * tried);
        let of_effect = |c: &usize| candidates[*c].effect == e_index;
        let mut kept: Vec<usize> =
            selection.kept.iter().filter(|c| of_effect(c)).map(|&c| candidates[c].owner).collect();
        kept.sort_unstable();
        let selected: Vec<usize> = kept.iter().flat_map(|&o| owner_columns(o)).collect();
        if selected.is_empty() {
            let smallest =
                (0..candidates.len()).filter(of_effect).map(|c| selection.p_given_kept[c]).fold(1.0f64, f64::min);
            let dropped = selection.dropped.iter().filter(|c| of_effect(c)).count();
            // Taken whole: the effect as a whole passed its level, yet no owner holds in the
            // joint fit (present, not attributed to an owner).
            let whole = selection
                .wholes_taken
                .iter()
                .find(|(w, _)| wholes[*w].members.first().is_some_and(|&c| candidates[c].effect == e_index));
            let then = match (dropped, whole) {
                (0, _) => String::new(),
                (_, Some((w, p))) => format!(
                    "; taken whole (p = {p:.2e}, level {:.1e}), then {dropped} owners dropped by the backward step: present as a whole, held by no owner",
                    wholes[*w].level
                ),
                _ => format!("; {dropped} taken, then dropped by the backward step"),
            };
            not_named[e_index].push((
                name,
                format!(
                    "no {} passes its test on the fitting recording given the owners kept (smallest p = {smallest:.2e}, level {level:.1e}{then})",
                    owner_word(effect)
                ),
            ));
            continue;
        }
        let sel_a: Vec<usize> = selected.iter().map(|&i| cols[i]).collect();
        let tf_sel = fit_terms_given(&total_a, &pg, &nuisance_a, &sel_a);
        // (The owners kept are fitted by themselves: with a common direction unseen, the others
        // are held at zero, which fixes it.)
        // Held-out recordings (accumulated in the fitting recording's column layout). What the
        // fitting recording's extended model changes is carried over: every baseline parameter and
        // every carried-over effect named before, re-adjusted with this one, and this one too unless
        // it is refitted per recording. Only then is the held-out recording's own part refitted.
        // (The change the term causes: the re-adjustment without it is left out, as the held-out
        // recordings' baseline gaps leave it out.)
        let caused = &tf_sel.nuisance_change - nuisance_step(&total_a, &nuisance_a);
        let mut carried_cols = Vec::new();
        let mut carried_vals = Vec::new();
        for (c, v) in nuisance_a.iter().zip(caused.iter()) {
            if !per_recording_cols.contains(c) {
                carried_cols.push(*c);
                carried_vals.push(*v);
            }
        }
        if !effect.per_recording() {
            carried_cols.extend_from_slice(&sel_a);
            carried_vals.extend_from_slice(&tf_sel.value);
        }
        let mut verdicts = Vec::with_capacity(held_out.len());
        for (h, (s, d)) in held_out.iter().zip(&current) {
            let nb = h.normal.nuisance();
            let before = phase_ss(s, d, &nb, &[], &[]);
            let (s1, d1) = (s.shifted(&carried_cols, &carried_vals), d.shifted(&carried_cols, &carried_vals));
            let (theta, test_p) = if effect.per_recording() {
                let mut t = s1.clone();
                t.merge(&d1);
                let fb: TermFit = fit_terms(&t, &nb, &sel_a);
                let pv = wald_p(&fb.value, &fb.covariance_robust);
                (fb.value, pv)
            } else {
                (Vec::new(), 0.0)
            };
            let own: &[usize] = if effect.per_recording() { &sel_a } else { &[] };
            let after = phase_ss(&s1, &d1, &nb, own, &theta);
            let next = (s1.shifted(own, &theta), d1.shifted(own, &theta));
            verdicts.push((before, after, next, test_p));
        }
        let lowers = verdicts.iter().all(|(b, a, ..)| a.0 + a.1 < b.0 + b.1);
        let held_level = alpha / held_out.len().max(1) as f64;
        let holds = verdicts.iter().all(|v| v.3 < held_level);
        if !(lowers && holds) {
            let why = if !lowers {
                "does not lower the gap on every held-out recording".to_string()
            } else {
                let largest = verdicts.iter().map(|v| v.3).fold(0.0f64, f64::max);
                format!(
                    "refitted on the held-out recordings, fails its test on at least one (largest p = {largest:.2e}, level {held_level:.1e})"
                )
            };
            not_named[e_index].push((
                name,
                format!("{why} ({} of its {} owners pass on the fitting recording)", selected.len() / per, owners),
            ));
            continue;
        }
        // Named: one finding per owner kept.
        for chunk in selected.chunks(per) {
            let pos: Vec<usize> = chunk.iter().map(|i| selected.iter().position(|s| s == i).unwrap_or(0)).collect();
            let (accelerometer, package) = match effect.owner(chunk[0]) {
                Owner::Accelerometer(j) => (Some(j), None),
                Owner::Package(m) => (None, Some(m)),
                Owner::Shared => (None, None),
            };
            out.findings.push(RecordedFinding {
                name: name.clone(),
                what: if effect.per_recording() {
                    "fitted on the fitting recording (refitted on each held-out recording)".into()
                } else if held_out.is_empty() {
                    "fitted on the fitting recording alone (no held-out recording to confirm it)".into()
                } else {
                    "fitted on the fitting recording, carried over to the held-out recordings".into()
                },
                accelerometer,
                package,
                value: pos.iter().map(|&i| tf_sel.value[i]).collect(),
                sigma: pos.iter().map(|&i| tf_sel.sigma_robust[i]).collect(),
                unit: effect.unit().into(),
                p_value_largest: verdicts.iter().map(|v| v.3).fold(0.0f64, f64::max),
            });
        }
        nuisance_a.extend_from_slice(&sel_a);
        if effect.per_recording() {
            per_recording_cols.extend_from_slice(&sel_a);
        }
        let now_a = phase_ss(&fitting.statics, &fitting.dynamics, &nuisance_a, &[], &[]);
        out.fitting_after_each.push((name.clone(), scaled(&fitting_gap, base_a, now_a)));
        for (k, (_, _, next, _)) in verdicts.into_iter().enumerate() {
            current[k] = next;
            let (s, d) = &current[k];
            let now = phase_ss(s, d, &held_out[k].normal.nuisance(), &[], &[]);
            out.held_out_after_each[k].push((name.clone(), scaled(&held_out[k].gap, base_b[k], now)));
        }
    }
    out.ranks = ranks.into_iter().flatten().collect();
    out.not_named = not_named.into_iter().flatten().collect();
    out
}

/// `v` (one value per parameter of the fit `a`), or NaN for each if the model absorbs every
/// direction of `a` (nothing is estimated: not a value of 0 with a sigma of 0).
fn seen_or_nan(a: &TermFit, v: &[f64]) -> Vec<f64> {
    if a.unseen == v.len() { vec![f64::NAN; v.len()] } else { v.to_vec() }
}

/// Re-expresses one-parameter-per-owner values relative to the owner at their median, with
/// the covariance carried over (`v - v_med`).
fn relative_to_median(tf: &mut TermFit) {
    let e = tf.value.len();
    let mut order: Vec<usize> = (0..e).collect();
    order.sort_by(|a, b| tf.value[*a].total_cmp(&tf.value[*b]));
    let med = order[e / 2];
    let mut d = nalgebra::DMatrix::<f64>::identity(e, e);
    for i in 0..e {
        d[(i, med)] -= 1.0;
    }
    let v = &d * nalgebra::DVector::from_column_slice(&tf.value);
    tf.covariance_robust = &d * &tf.covariance_robust * d.transpose();
    tf.value = v.iter().copied().collect();
    tf.sigma_robust = (0..e).map(|i| tf.covariance_robust[(i, i)].max(0.0).sqrt()).collect();
}

fn owner_word(e: &RecordedEffect) -> &'static str {
    match e.owner(0) {
        Owner::Accelerometer(_) => "accelerometer",
        Owner::Package(_) => "package",
        Owner::Shared => "shared parameter set",
    }
}
