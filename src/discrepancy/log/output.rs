//! The diagnosis of a log as JSON (`gfcal diagnose LOG --json`): its keys are this module's.

use serde_json::Value;

use super::correlation::{Correlation, RegressorCorrelation};
use super::data::CalibrationLog;
use super::diagnosis::{Diagnosis, Verdict};

/// The diagnosis `d` of the log read from `log_path` (shown as given), with the baseline's
/// regressor correlations.
pub fn to_json(log_path: &str, log: &CalibrationLog, d: &Diagnosis, correlations: &[RegressorCorrelation]) -> Value {
    let b = &d.baseline;
    let verdict_json = |v: &Verdict| match v {
        Verdict::ConfoundedWithModel(with) => serde_json::json!({"confounded_with_model": with}),
        Verdict::Tested { delta_chi2, p_value } => {
            serde_json::json!({"delta_chi2": delta_chi2, "p_value": p_value})
        }
        Verdict::NoSigma => serde_json::json!({"no_sigma": true}),
    };
    serde_json::json!({
        "log": log_path,
        "noise_sigma_m_s2": b.noise_sigma_m_s2,
        "gap_before": d.gap_before,
        "gap_after": d.gap_after,
        "p_value_before": b.p_value,
        "p_value_after": d.p_value_after,
        "held_out_before": d.held_out_before,
        "held_out_after": d.held_out_after,
        "unmodelled_effect_remains": d.unmodelled_effect_remains,
        "explanation": d.explanation().as_str(),
        "effects": d.findings.iter().map(|f| serde_json::json!({
            "name": f.name,
            "accelerometer": f.accelerometer.map(|j| j + 1),
            "value": if f.value.len() == 1 { serde_json::json!(f.value[0]) } else { serde_json::json!(f.value) },
            "sigma": if f.sigma.len() == 1 { serde_json::json!(f.sigma[0]) } else { serde_json::json!(f.sigma) },
            "unit": f.unit,
            "gap_before": f.gap_before,
            "gap_after": f.gap_after,
            "p_value": f.p_value,
            "confounded_with": f.confounded_with,
            "unseen_directions": f.unseen_directions,
        })).collect::<Vec<_>>(),
        "regressor_correlations": correlations.iter().map(|row| match &row.correlation {
            Correlation::PerAccelerometer(r) => serde_json::json!({"regressor": row.regressor, "per_accelerometer": r}),
            Correlation::Constant(v) if row.regressor == "temperature" => serde_json::json!({"regressor": row.regressor, "constant_c": v}),
            Correlation::Constant(v) => serde_json::json!({"regressor": row.regressor, "constant": v}),
        }).collect::<Vec<_>>(),
        "candidates": d.verdicts.iter().map(|(l, v)| serde_json::json!({"candidate": l, "verdict": verdict_json(v)})).collect::<Vec<_>>(),
        "per_step": log.steps.iter().enumerate().map(|(i, s)| serde_json::json!({
            "step": s.step,
            "kind": if s.omega_b_rad_s.norm() > 0.0 { "spin" } else { "static" },
            "whitened_before": b.whitened[i],
            "whitened_after": d.per_step_after[i],
        })).collect::<Vec<_>>(),
    })
}
