//! Diagnosis of a calibration log: the baseline fit, then effects added one at a time while one
//! is significant, each checked by leave-one-step-out prediction.

use nalgebra::{DMatrix, DVector};

use super::allan::{AllanTest, allan_tests};
use super::baseline::{DiagnoseError, fit_baseline};
use super::data::CalibrationLog;
use super::diagnosis::{DiagnoseSettings, Diagnosis, Finding, Stage, Verdict};
use super::extended::{Candidate, Extended, ExtendedFit, candidates, fit_extended, held_out};
use crate::array::Array;
use crate::calib::estimate::CalibError;
use crate::calib::params::{Layout, PER_ACCEL};
use crate::calib::schedule::Schedule;
use crate::sensor::ArrayParams;
use crate::stats::chi2_sf;

fn statics_of(schedule: &Schedule) -> usize {
    schedule.steps().iter().filter(|s| !s.is_spin()).count()
}

/// The standard deviation of parameter `i` of a fit, when its covariance gives one (a singular
/// information matrix gives NaN or a non-positive variance: no sigma).
fn sigma_of(fit: &ExtendedFit, i: usize) -> Option<f64> {
    let v = fit.covariance[(i, i)];
    (v.is_finite() && v > 0.0).then(|| v.sqrt())
}

fn p_chi2(chi2: f64, dof: usize) -> f64 {
    if dof == 0 {
        return f64::NAN;
    }
    chi2_sf(chi2, dof as f64).unwrap_or(f64::NAN)
}

/// Diagnoses a log (see the module docs): the baseline fit, then effects added one at a time
/// while one is significant.
pub fn diagnose(
    log: &CalibrationLog,
    array: &Array,
    nominal: &ArrayParams,
    s: &DiagnoseSettings,
) -> Result<Diagnosis, DiagnoseError> {
    let baseline = fit_baseline(log, array, nominal, s.form, s.g_m_s2)?;
    let schedule = log.schedule()?;
    let meas = log.measurements();
    let layout = Layout::new(array, s.form).map_err(CalibError::from)?;
    // The noise model first: correlated noise within steps (an Allan-variance excess over white
    // noise, per accelerometer, Bonferroni over all tests) is named, and the accelerometer's step
    // means are weighted with the variance it implies (the ratio at the largest significant
    // cluster), before any deterministic effect is tested against that noise.
    let k: Vec<f64> = (0..array.len()).map(|j| baseline.estimate.x[PER_ACCEL * j]).collect();
    let tests = allan_tests(log, &k);
    let allan_threshold = s.alpha / tests.len().max(1) as f64;
    let mut inflation = vec![1.0; array.len()];
    let mut noise_findings = Vec::new();
    for (j, inflation_j) in inflation.iter_mut().enumerate() {
        let significant: Vec<&AllanTest> =
            tests.iter().filter(|t| t.accelerometer == j && t.p_value < allan_threshold).collect();
        let Some(best) = significant.iter().max_by_key(|t| t.cluster_samples) else { continue };
        let strongest = significant.iter().map(|t| t.p_value).fold(f64::INFINITY, f64::min);
        *inflation_j = best.ratio.max(1.0);
        noise_findings.push(Finding {
            name: "bias_instability".into(),
            accelerometer: Some(j),
            value: vec![best.excess_adev_m_s2],
            sigma: vec![
                best.excess_adev_m_s2 * (0.5 / best.differences as f64).sqrt() * best.ratio
                    / (best.ratio - 1.0).max(1e-9),
            ],
            unit: format!("m/s^2 (Allan deviation over white noise at {:.2} s)", best.cluster_s),
            gap_before: baseline.chi2_per_dof(),
            gap_after: f64::NAN,
            p_value: strongest,
            confounded_with: None,
            unseen_directions: 0,
        });
    }
    let sigma_owned: Vec<f64> = inflation.iter().map(|f| baseline.noise_sigma_m_s2 * f.sqrt()).collect();
    let sigma = sigma_owned.as_slice();
    let mut pool = candidates(array.len(), log.has_temperature());
    let mut included: Vec<usize> = Vec::new();
    let mut current = fit_extended(&layout, &schedule, log, &meas, &[], &baseline.estimate.x, sigma, s);
    let gap_before = baseline.chi2_per_dof();
    let n = array.len();
    let per_step = |w: &DVector<f64>| -> Vec<Vec<f64>> {
        (0..schedule.len()).map(|st| (0..n).map(|j| w[st * n + j]).collect()).collect()
    };
    let mut stages = vec![Stage {
        label: "baseline".into(),
        gap: gap_before,
        dof: baseline.dof,
        per_step: baseline.whitened.clone(),
    }];
    if !noise_findings.is_empty() {
        let on: Vec<String> =
            noise_findings.iter().filter_map(|f| f.accelerometer).map(|j| format!("a{}", j + 1)).collect();
        stages.push(Stage {
            label: format!("noise model: bias_instability on {}", on.join(", ")),
            gap: current.chi2 / current.dof as f64,
            dof: current.dof,
            per_step: per_step(&current.whitened),
        });
    }
    for f in &mut noise_findings {
        f.gap_after = current.chi2 / current.dof as f64;
    }
    let mut findings = noise_findings;
    let mut verdicts = Vec::new();
    loop {
        let effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
        // The current model's Jacobian, for the rank tests.
        let mut model = Extended::new(
            &layout,
            &schedule,
            log,
            &meas,
            &effects,
            &current.x.rows(0, layout.len()).into_owned(),
            sigma,
            s.temp_ref_c,
            s.g_m_s2,
        );
        model.x.copy_from(&current.x);
        let jm = model.jacobian_at(&current.x);
        let svd = jm.clone().svd(true, false);
        let tol = 1e-9 * svd.singular_values.max();
        let u = svd.u.as_ref().map(|u| {
            let keep: Vec<usize> = (0..svd.singular_values.len()).filter(|&i| svd.singular_values[i] > tol).collect();
            DMatrix::from_fn(u.nrows(), keep.len(), |r, c| u[(r, keep[c])])
        });
        let Some(u) = u else { break };
        let names: Vec<String> = (0..current.x.len())
            .map(|i| if i < layout.len() { layout.name(i) } else { "an included effect".to_string() })
            .collect();
        // Each remaining candidate's regressors, with the current model's span removed.
        let mut residual_regs: Vec<(usize, DMatrix<f64>, f64)> = Vec::new();
        verdicts.clear();
        let mut bases: Vec<(usize, Option<DMatrix<f64>>)> = Vec::new();
        for (ci, c) in pool.iter().enumerate() {
            if included.contains(&ci) {
                continue;
            }
            let c_full = c.full();
            let one = [&c_full];
            let probe = Extended::new(
                &layout,
                &schedule,
                log,
                &meas,
                &one,
                &current.x.rows(0, layout.len()).into_owned(),
                sigma,
                s.temp_ref_c,
                s.g_m_s2,
            );
            let mut regs = Vec::new();
            let mut xp = probe.x.clone();
            xp.rows_mut(0, layout.len()).copy_from(&current.x.rows(0, layout.len()));
            probe.evaluate(&xp, Some(&mut regs));
            let rmat = DMatrix::from_fn(regs[0].len(), regs.len(), |r, k| regs[k][r]);
            let norm = rmat.norm();
            if norm == 0.0 {
                verdicts
                    .push((c.label(), Verdict::ConfoundedWithModel(vec!["nothing: the log never excites it".into()])));
                continue;
            }
            // The unexplained part of its unit-normalised regressors: with no direction left
            // (largest singular value below 1e-6) the effect is confounded with the model; with
            // some directions inside the model's span (a common rotation of every pose), only the
            // others are fitted (the basis below). Before, a 24-parameter pose effect with such a
            // direction was fitted whole, with sigmas of tens of radians.
            let unit = DMatrix::from_fn(rmat.nrows(), rmat.ncols(), |r, k| {
                let c = rmat.column(k).norm();
                if c > 0.0 { rmat[(r, k)] / c } else { 0.0 }
            });
            let perp = &rmat - &u * (u.transpose() * &rmat);
            let unit_perp = &unit - &u * (u.transpose() * &unit);
            let svd_perp = unit_perp.clone().svd(false, true);
            let ratio = svd_perp.singular_values.max();
            if ratio < 1e-6 {
                // Name what absorbs it: the least-squares coefficients on the model's columns.
                let beta = jm
                    .clone()
                    .svd(true, true)
                    .solve(&rmat, 1e-12)
                    .unwrap_or_else(|_| DMatrix::zeros(jm.ncols(), rmat.ncols()));
                let scale: Vec<f64> = (0..jm.ncols()).map(|i| beta.row(i).norm() * jm.column(i).norm()).collect();
                let total: f64 = scale.iter().sum();
                let mut idx: Vec<usize> = (0..scale.len()).filter(|&i| scale[i] > 0.02 * total).collect();
                idx.sort_by(|a, b| scale[*b].total_cmp(&scale[*a]));
                let with: Vec<String> = idx.iter().take(8).map(|&i| names[i].clone()).collect();
                verdicts.push((c.label(), Verdict::ConfoundedWithModel(with)));
                continue;
            }
            // The directions the model absorbs (in parameter units: the columns were scaled by
            // their norms) are left out of the fit; the rest is tested.
            let basis = svd_perp.v_t.as_ref().and_then(|vt| {
                let seen: Vec<usize> =
                    (0..svd_perp.singular_values.len()).filter(|&i| svd_perp.singular_values[i] >= 1e-6).collect();
                if seen.len() == rmat.ncols() {
                    return None;
                }
                let scale = |r: usize| {
                    let c = rmat.column(r).norm();
                    if c > 0.0 { 1.0 / c } else { 0.0 }
                };
                let b = DMatrix::from_fn(rmat.ncols(), seen.len(), |r, i| vt[(seen[i], r)] * scale(r));
                // Orthonormal, so that the reported parameters are the least-norm ones.
                Some(b.qr().q())
            });
            bases.push((ci, basis));
            residual_regs.push((ci, perp, ratio));
        }
        drop(model);
        for (ci, basis) in bases {
            pool[ci].basis = basis;
        }
        // Test every separable candidate.
        let mut tested: Vec<(usize, ExtendedFit, f64, f64)> = Vec::new();
        for (ci, _, _) in &residual_regs {
            let mut effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
            effects.push(&pool[*ci]);
            let fit = fit_extended(&layout, &schedule, log, &meas, &effects, &current.x, sigma, s);
            let dp = fit.x.len() - current.x.len();
            if !(0..dp).all(|i| sigma_of(&fit, current.x.len() + i).is_some()) {
                verdicts.push((pool[*ci].label(), Verdict::NoSigma));
                continue;
            }
            let delta = (current.chi2 - fit.chi2).max(0.0);
            let p = p_chi2(delta, dp);
            verdicts.push((pool[*ci].label(), Verdict::Tested { delta_chi2: delta, p_value: p }));
            tested.push((*ci, fit, delta, p));
        }
        let threshold = s.alpha / tested.len().max(1) as f64;
        let Some(best) =
            tested.iter().filter(|t| t.3 < threshold).min_by(|a, b| a.3.total_cmp(&b.3).then(b.2.total_cmp(&a.2)))
        else {
            break;
        };
        let (ci, fit, _, p) = best.clone();
        // Another candidate whose unexplained part is parallel to the best one's explains the
        // same gap: the log cannot tell them apart.
        let best_perp = residual_regs.iter().find(|r| r.0 == ci).map(|r| r.1.clone());
        let confounded_with = best_perp.and_then(|bp| {
            residual_regs.iter().filter(|r| r.0 != ci && r.1.ncols() == 1 && bp.ncols() == 1).find_map(|r| {
                let cos = (bp.column(0).dot(&r.1.column(0)) / (bp.norm() * r.1.norm())).abs();
                (cos > 0.999).then(|| pool[r.0].label())
            })
        });
        let off = current.x.len();
        let q = fit.x.len() - off;
        let c = &pool[ci];
        // The effect's parameters (the seen directions mapped back through the basis) and their sigmas.
        let fitted = fit.x.rows(off, q).into_owned();
        let cov = fit.covariance.view((off, off), (q, q)).into_owned();
        let (value, variance): (Vec<f64>, Vec<f64>) = match &c.basis {
            None => (fitted.iter().copied().collect(), (0..q).map(|i| cov[(i, i)]).collect()),
            Some(b) => {
                let v = b * &fitted;
                let full = b * cov * b.transpose();
                (v.iter().copied().collect(), (0..b.nrows()).map(|i| full[(i, i)]).collect())
            }
        };
        findings.push(Finding {
            name: c.effect.name().to_string(),
            accelerometer: c.accelerometer,
            value,
            sigma: variance.iter().map(|v| if v.is_finite() && *v > 0.0 { v.sqrt() } else { f64::NAN }).collect(),
            unseen_directions: c.unseen(statics_of(&schedule), schedule.len() - statics_of(&schedule)),
            unit: c.effect.unit().to_string(),
            gap_before: current.chi2 / current.dof as f64,
            gap_after: fit.chi2 / fit.dof as f64,
            p_value: p,
            confounded_with,
        });
        stages.push(Stage {
            label: format!("+ {}", c.label()),
            gap: fit.chi2 / fit.dof as f64,
            dof: fit.dof,
            per_step: per_step(&fit.whitened),
        });
        included.push(ci);
        current = fit;
    }
    let held_out_before = held_out(&layout, &schedule, log, &meas, &[], &baseline.estimate.x, sigma, s);
    let effects: Vec<&Candidate> = included.iter().map(|&i| &pool[i]).collect();
    let held_out_after = held_out(&layout, &schedule, log, &meas, &effects, &current.x, sigma, s);
    let p_value_after = p_chi2(current.chi2, current.dof);
    let per_step_after = per_step(&current.whitened);
    Ok(Diagnosis {
        gap_before,
        gap_after: current.chi2 / current.dof as f64,
        p_value_after,
        held_out_before,
        held_out_after,
        unmodelled_effect_remains: p_value_after < s.alpha,
        findings,
        verdicts,
        baseline,
        per_step_after,
        stages,
    })
}
