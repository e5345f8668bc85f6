//! What became of a trial's fit: `estimated` (a converged fit, navigated with), or the reason it
//! has no estimate to navigate with. The summary counts them per cell (`summary.csv`'s `fits`
//! rows), from the trials table's `converged` and `message` columns and its estimated drift.
//!
//! | outcome | the trial |
//! | --- | --- |
//! | `estimated` | converged; the estimated compensation (if the run navigates it) was navigated |
//! | `left_small_error_region` | the fit ran beyond the model's small-error region (an angle above 0.1 rad, a location error larger than the array): not an answer, however low its cost |
//! | `dead_channel` | an accelerometer's scale factor was fitted to zero |
//! | `singular_jacobian` | the Jacobian at the solution is singular |
//! | `unidentifiable` | the schedule cannot identify every parameter (no fit was tried) |
//! | `not_converged` | the solver stopped without converging |
//! | `failed` | no estimate at all (the simulation or the calibration failed; the message says why) |
//! | `no_compensation` | converged, but the estimate gives no compensation to navigate with |
//!
//! The parameter rows of the summary use every trial with an estimate, converged or not (all but
//! `unidentifiable` and `failed`); the estimated compensation's drift rows use the `estimated`
//! trials only.

/// The outcomes, in the order the summary lists them.
pub const OUTCOMES: [&str; 8] = [
    "estimated",
    "left_small_error_region",
    "dead_channel",
    "singular_jacobian",
    "unidentifiable",
    "not_converged",
    "failed",
    "no_compensation",
];

/// The outcome of a trial: whether its fit converged, its message (the trials table's
/// `message`), whether it has an estimate at all (a failed fit has no iterations and no cost),
/// and whether its estimated drift is missing (`None` when the run does not navigate the
/// estimated compensation).
pub fn outcome(
    converged: bool,
    message: &str,
    has_estimate: bool,
    estimated_drift_missing: Option<bool>,
) -> &'static str {
    if converged {
        return if estimated_drift_missing == Some(true) { "no_compensation" } else { "estimated" };
    }
    if message.contains("left the small-error region") {
        "left_small_error_region"
    } else if message.contains("scale factor fitted to zero") {
        "dead_channel"
    } else if message.contains("singular Jacobian") {
        "singular_jacobian"
    } else if message.contains("cannot identify") {
        "unidentifiable"
    } else if has_estimate {
        "not_converged"
    } else {
        "failed"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The messages the estimators write (`calib::joint`, `calib::joint_pose`, `calib::estimate`)
    /// map to their outcomes.
    #[test]
    fn messages_map_to_their_outcomes() {
        let cases = [
            (true, "converged", true, Some(false), "estimated"),
            (true, "converged", true, None, "estimated"),
            (true, "converged", true, Some(true), "no_compensation"),
            (
                false,
                "left the small-error region of the model: a5.dy = -7.9e2 m exceeds ...",
                true,
                Some(true),
                "left_small_error_region",
            ),
            (
                false,
                "scale factor fitted to zero for accelerometer(s) 3 (dead channel?); converged",
                true,
                None,
                "dead_channel",
            ),
            (false, "singular Jacobian at the solution; converged", true, None, "singular_jacobian"),
            (false, "the schedule cannot identify these parameters: a1.dz, a2.dy", false, Some(true), "unidentifiable"),
            (false, "pose fit did not converge in 100 iterations", true, Some(true), "not_converged"),
            (false, "accelerometer 2: NoImprovementPossible", true, None, "not_converged"),
            (false, "calibration: no static interval", false, Some(true), "failed"),
        ];
        for (converged, message, has_estimate, missing, want) in cases {
            let got = outcome(converged, message, has_estimate, missing);
            assert_eq!(got, want, "{message}");
            assert!(OUTCOMES.contains(&got));
        }
    }
}
