//! A verdict on what to trust in a calibration, per parameter kind, from the tests it already
//! ran: the fit's convergence, the static and rotation-phase misfits against the noise
//! (chi^2/dof), the held-out recordings' static misfit, the parameters the data cannot see, and
//! the gyroscope check. `gfcal calibrate` prints it last and writes it as the JSON's
//! `assessment: [{kind, trustworthy, reason}]`, and the report shows it.
//!
//! The rules (thresholds stated before looking at the recordings):
//! - a misfit up to [`MISFIT_LIMIT`] times the noise (chi^2/dof) is carried by the sigmas (the
//!   static sigmas are widened by its root, the rotation phase's weights are its own residuals);
//!   beyond it the model, not the noise, leaves the residual, and the parameters it drives are
//!   not trustworthy;
//! - a kind with any unidentified parameter is not trustworthy;
//! - scale factors, biases and tilts that the rotation phase pulls from what the static poses say
//!   (`selfcal::tension`, its pull's p-value below [`super::tension::PULL_P_LEVEL`]) are not
//!   trustworthy, whatever the static misfit (that level chosen after the real recording 4 was
//!   seen);
//! - scale factors, biases and tilts are not trustworthy where the biases drift in time
//!   (`selfcal::static_drift`, its test's p-value below [`super::static_drift::DRIFT_P_LEVEL`],
//!   the tension's level, set before the check met a recording): the joint fit does not model the
//!   drift, which goes into them on a pose sequence that moves steadily with time, and the reason
//!   says how much wider the static phase's sigmas are with the drift fitted;
//! - the gyroscope-free rate is trustworthy only when it meets the gyroscopes within
//!   [`RATE_LIMIT`] (RMS difference over RMS rate), when the array has gyroscopes.

#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::calibrate::Calibration;
use super::model::PER_ACCEL;
use super::static_drift::{StaticDrift, moves_in_printed_sigmas, sigma_over_printed};
use super::tension::StaticTension;

/// Misfit (chi^2/dof) above which a phase is not fitted by the model.
pub const MISFIT_LIMIT: f64 = 10.0;
/// Relative RMS difference from the gyroscopes above which the gyroscope-free rate is not
/// trustworthy.
pub const RATE_LIMIT: f64 = 0.05;

/// The verdict on one kind of parameter.
#[derive(Debug, Clone, PartialEq)]
pub struct Verdict {
    /// `scale_factors`, `biases`, `tilts`, `locations` or `rate`.
    pub kind: &'static str,
    pub trustworthy: bool,
    pub reason: String,
}

/// `1,811` for 1811.4: a ratio as the verdicts print it.
fn times(x: f64) -> String {
    if !x.is_finite() {
        return format!("{x}");
    }
    let r = x.round() as i64;
    if r.abs() < 10 {
        return format!("{x:.1}");
    }
    let s = r.abs().to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    if r < 0 { format!("-{out}") } else { out }
}

/// Why the intrinsic kinds are not trustworthy when the rotation phase pulls them (`None` when it
/// does not).
fn pull_reason(t: &StaticTension, static_x: f64) -> Option<String> {
    t.pulls().then(|| {
        format!(
            "not trustworthy: the rotation phase pulls them from what the static poses say (static chi^2/dof {} as fitted, {} refitted alone; pull chi^2 {} on {} dof)",
            times(static_x),
            times(t.chi2_dof_static_only),
            times(t.pull_chi2),
            t.pull_dof
        )
    })
}

/// Why scale factors, biases and tilts are not trustworthy when the biases drift in time (`None`
/// when the test does not reject); `moves` from [`moves_in_printed_sigmas`], `over_printed` from
/// [`sigma_over_printed`].
fn drift_reason(d: &StaticDrift, moves: &[f64; 4], over_printed: &[f64; 4]) -> Option<String> {
    d.drifts().then(|| {
        let list = |v: &[f64; 4]| v.iter().map(|x| times(*x)).collect::<Vec<_>>().join(", ");
        format!(
            "not trustworthy: the biases drift in time (median {:.2e} m/s^2/s; it lowers the static chi^2 by {} on {} dof, p = {:.1e}), which this calibration leaves in; refitted with the drift, the static phase moves scale factor, bias, tilt_u and tilt_w by {} printed sigmas RMS, with sigmas {} times the printed (median); `gfcal calibrate` takes the drift out unless --keep-bias-drift",
            crate::stats::median(&d.rate_m_s2_per_s),
            times(d.test_chi2),
            d.test_dof,
            d.p_value,
            list(moves),
            list(over_printed),
        )
    })
}

/// The verdicts of a calibration (module docs); `held_static_chi2_dof` are the held-out
/// recordings' static misfits.
pub fn assess(cal: &Calibration, held_static_chi2_dof: &[f64]) -> Vec<Verdict> {
    let fit = &cal.fit;
    let n = fit.params.len();
    let unidentified = |p: usize| (0..n).filter(|&j| !fit.identified(j, p)).count();
    let verdict = |kind, trustworthy, reason: String| Verdict { kind, trustworthy, reason };
    let mut out = Vec::new();
    let static_x = fit.static_chi2_dof;
    let drift_reason = cal.static_drift.as_ref().and_then(|d| {
        let printed = |j, p| fit.sigma(j, p);
        drift_reason(d, &moves_in_printed_sigmas(d, &fit.params, &printed), &sigma_over_printed(d, &printed))
    });
    let held_worst = held_static_chi2_dof.iter().copied().filter(|v| v.is_finite()).fold(f64::NAN, f64::max);
    for (kind, ps) in [("scale_factors", &[0][..]), ("biases", &[1][..]), ("tilts", &[2, 3][..])] {
        let missing: usize = ps.iter().map(|&p| unidentified(p)).sum();
        let v = if !fit.converged {
            verdict(kind, false, "not trustworthy: the fit did not converge".into())
        } else if missing > 0 {
            verdict(
                kind,
                false,
                format!(
                    "not trustworthy: {missing} of {} unidentified (combinations the data cannot see)",
                    n * ps.len()
                ),
            )
        } else if let Some(reason) = cal.static_tension.as_ref().and_then(|t| pull_reason(t, static_x)) {
            verdict(kind, false, reason)
        } else if let Some(reason) = drift_reason.clone() {
            verdict(kind, false, reason)
        } else if !(static_x <= MISFIT_LIMIT) {
            verdict(
                kind,
                false,
                format!(
                    "not trustworthy: the static phase misfits by {} times its noise (chi^2/dof; the sigmas carry up to {MISFIT_LIMIT})",
                    times(static_x)
                ),
            )
        } else if held_worst > MISFIT_LIMIT {
            verdict(
                kind,
                false,
                format!(
                    "not trustworthy: a held-out recording's static poses misfit by {} times their noise (chi^2/dof)",
                    times(held_worst)
                ),
            )
        } else {
            verdict(
                kind,
                true,
                format!(
                    "trustworthy: the static phase fits to {} times its noise (chi^2/dof; sigmas widened by its root)",
                    times(static_x)
                ),
            )
        };
        out.push(v);
    }
    let dyn_x = fit.dynamic_chi2_dof;
    let missing = (4..PER_ACCEL).map(unidentified).sum::<usize>();
    out.push(if !fit.locations_identified {
        verdict("locations", false, "not trustworthy: no rotation phase, so the locations are not identified".into())
    } else if !fit.converged {
        verdict("locations", false, "not trustworthy: the fit did not converge".into())
    } else if missing > 0 {
        verdict(
            "locations",
            false,
            format!("not trustworthy: {missing} of {} unidentified (combinations the data cannot see)", 3 * n),
        )
    } else if !(dyn_x <= MISFIT_LIMIT) {
        verdict(
            "locations",
            false,
            format!(
                "not trustworthy: the rotation phase misfits by {} times its noise (rotation-phase chi^2/dof against the static noise)",
                times(dyn_x)
            ),
        )
    } else {
        verdict("locations", true, format!("trustworthy: the rotation phase fits to {} times its noise", times(dyn_x)))
    });
    if fit.locations_identified {
        out.push(if cal.use_gyro {
            verdict("rate", true, "trustworthy: measured by the reference gyroscopes (--use-gyro)".into())
        } else if let Some(g) = &cal.gyro_check {
            if g.relative <= RATE_LIMIT {
                verdict(
                    "rate",
                    true,
                    format!("trustworthy: the gyroscope-free rate meets the gyroscopes to {:.1}% RMS", 100.0 * g.relative),
                )
            } else {
                verdict(
                    "rate",
                    false,
                    format!(
                        "not trustworthy: the gyroscope-free rate differs from the gyroscopes by {:.1}% RMS (limit {:.0}%)",
                        100.0 * g.relative,
                        100.0 * RATE_LIMIT
                    ),
                )
            }
        } else if !(dyn_x <= MISFIT_LIMIT) || missing > 0 || !fit.unseen.is_empty() {
            verdict(
                "rate",
                false,
                "not trustworthy: no gyroscope to check it, and the rotation phase misfits or leaves combinations unseen".into(),
            )
        } else {
            verdict("rate", true, "trustworthy by the fit alone (no gyroscope to check it)".into())
        });
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn ratios_print_with_thousands_separators() {
        assert_eq!(super::times(1811.4), "1,811");
        assert_eq!(super::times(2.04), "2.0");
        assert_eq!(super::times(1234567.0), "1,234,567");
        assert_eq!(super::times(35.2), "35");
    }

    /// A pull below the level names the static misfit as fitted and alone and the test; one above
    /// it gives no reason (the other rules decide).
    #[test]
    fn a_pulled_static_phase_is_said_to_be_pulled() {
        let mut t = super::StaticTension {
            chi2_dof_static_only: 2.06,
            move_sigma: vec![[0.0; 4]; 24],
            move_rms_sigma: 2.0,
            largest: None,
            pull_chi2: 11638.5,
            pull_dof: 96,
            pull_p_value: 0.0,
        };
        let reason = super::pull_reason(&t, 71.21).expect("pulled");
        assert!(reason.contains("pulls them") && reason.contains("71 as fitted, 2.1 refitted alone"), "{reason}");
        assert!(reason.contains("pull chi^2 11,639 on 96 dof"), "{reason}");
        t.pull_p_value = 2.0 * super::super::tension::PULL_P_LEVEL;
        assert_eq!(super::pull_reason(&t, 71.21), None);
    }
}
