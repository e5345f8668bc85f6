//! The diagnosis of recordings as JSON (`gfcal diagnose RECORDING --json`): its keys are this
//! module's. `bias_drift_removed` is the bias drift taken out of the fitting recording before the
//! diagnosis (`--remove-bias-drift`; as `gfcal calibrate`'s `static.bias_drift_removed`, null
//! otherwise) and `bias_drift_note` why one asked for was not.

use serde_json::Value;

use super::diagnosis::{Gap, RecordedDiagnosis};

/// The diagnosis `d` of the recording `recording` with the array file `array` (both shown as
/// given), at the familywise level `alpha`.
pub fn to_json(recording: &str, array: &str, d: &RecordedDiagnosis, alpha: f64) -> Value {
    let gap = |g: &Gap| {
        serde_json::json!({
            "static_chi2_dof": g.static_chi2_dof,
            "dynamic_gap": g.dynamic,
        })
    };
    let fitting_after = d.fitting_after_each.last().map_or(d.fitting, |(_, g)| *g);
    serde_json::json!({
        "recording": recording,
        "array": array,
        "gap_before": d.fitting.static_chi2_dof,
        "gap_after": fitting_after.static_chi2_dof,
        "dynamic_gap_before": d.fitting.dynamic,
        "dynamic_gap_after": fitting_after.dynamic,
        "fitting": {"before": gap(&d.fitting), "after": gap(&fitting_after)},
        "held_out": d.held_out.iter().map(|h| serde_json::json!({
            "recording": h.recording.display().to_string(),
            "gap_before": h.before.static_chi2_dof,
            "gap_after": h.after.static_chi2_dof,
            "dynamic_gap_before": h.before.dynamic,
            "dynamic_gap_after": h.after.dynamic,
            "bias_change_m_s2": h.bias_change_m_s2,
            "bias_change_sigma_m_s2": h.bias_change_sigma_m_s2,
            "scale_factor_change": h.scale_factor_change,
            "scale_factor_change_sigma": h.scale_factor_change_sigma,
            "bias_change_p_value": h.bias_change_p_value,
            "scale_factor_change_p_value": h.scale_factor_change_p_value,
            "after_each": h.after_each.iter().map(|(name, g)| serde_json::json!({
                "effect": name,
                "gap": g.static_chi2_dof,
                "dynamic_gap": g.dynamic,
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "fitting_after_each": d.fitting_after_each.iter().map(|(name, g)| serde_json::json!({
            "effect": name,
            "gap": g.static_chi2_dof,
            "dynamic_gap": g.dynamic,
        })).collect::<Vec<_>>(),
        "rank_tests": d.ranks.iter().map(|r| serde_json::json!({
            "name": r.name, "parameters": r.parameters, "unseen": r.unseen,
            "value": r.value, "sigma": r.sigma, "p_value_joint": r.p_value_joint,
            "value_alone": r.value_alone, "sigma_alone": r.sigma_alone,
        })).collect::<Vec<_>>(),
        "sensing_points": d.sensing_points.iter().map(|sp| serde_json::json!({
            "package": sp.package + 1,
            "accelerometers": sp.accelerometers.iter().map(|j| j + 1).collect::<Vec<_>>(),
            "difference_m": sp.difference_m,
            "sigma_m": sp.sigma_m,
            "offsets": sp.offsets().iter().map(|o| serde_json::json!({
                "accelerometer": o.accelerometer + 1,
                "minus": o.minus + 1,
                "difference_m": {"x": o.difference_m[0], "y": o.difference_m[1], "z": o.difference_m[2]},
                "sigma_m": {"x": o.sigma_m[0], "y": o.sigma_m[1], "z": o.sigma_m[2]},
            })).collect::<Vec<_>>(),
            "p_value": sp.p_value,
        })).collect::<Vec<_>>(),
        "effects": d.findings.iter().map(|f| serde_json::json!({
            "name": f.name,
            "accelerometer": f.accelerometer.map(|j| j + 1),
            "package": f.package.map(|m| m + 1),
            "value": f.value,
            "sigma": f.sigma,
            "unit": f.unit,
            "what": f.what,
            "p_value_largest": f.p_value_largest,
        })).collect::<Vec<_>>(),
        "not_named": d.not_named.iter().map(|(n, w)| serde_json::json!({"name": n, "why": w})).collect::<Vec<_>>(),
        "bias_drift_removed": d.calibration.removed_bias_drift.as_ref()
            .map(|drift| crate::selfcal::output::bias_drift_json(drift, &d.calibration)),
        "bias_drift_note": d.calibration.bias_drift_note,
        "explanation": d.explanation().as_str(),
        "assessment": d.assessment().iter().map(|v| serde_json::json!({
            "kind": v.kind, "trustworthy": v.trustworthy, "reason": v.reason,
        })).collect::<Vec<_>>(),
        "alpha": alpha,
    })
}
