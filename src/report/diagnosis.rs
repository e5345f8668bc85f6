//! `gfcal diagnose LOG --report FILE.html`: how the model's disagreement with a calibration log
//! shrinks as the diagnosis adds each effect.
//!
//! - the gap (chi-square per degree of freedom of the step means) after each addition, against
//!   1 (noise alone) and the test's critical value;
//! - the whitened residual of every step mean of every accelerometer before any addition and
//!   after each one (a missing effect shows as a pattern over steps; a right model leaves noise
//!   of unit variance);
//! - the effects named, with values, sigmas and p-values, and the candidates the log cannot
//!   separate from the model.

use super::ReportError;
use super::html::Page;
use super::plot::{Figure, Item, Panel, render};
use crate::discrepancy::Explanation;
use crate::discrepancy::log::{CalibrationLog, Diagnosis, Verdict};

/// A rendered diagnosis report.
#[derive(Debug, Clone)]
pub struct DiagnosisReport {
    pub html: String,
    pub figures: Vec<Figure>,
}

fn gap_figure(d: &Diagnosis, alpha: f64) -> Result<Figure, ReportError> {
    let names: Vec<String> = d.stages.iter().map(|s| s.label.clone()).collect();
    let pts: Vec<(f64, f64)> = d.stages.iter().enumerate().map(|(i, s)| (i as f64, s.gap)).collect();
    let last = (names.len() as f64 - 1.0).max(0.0);
    let span = |y: f64| vec![(-0.4, y), (last + 0.4, y)];
    let mut panel = Panel::new("model-data gap after each addition", "model", "chi-square per dof [1]")
        .log_y()
        .categorical(names)
        .with(Item::Line { label: Some("chi2/dof".into()), points: pts.clone(), colour: 0, dashed: false })
        .with(Item::Points { label: None, points: pts, colour: 0 })
        .with(Item::Line { label: Some("1: noise alone".into()), points: span(1.0), colour: 2, dashed: true });
    if let Some(s) = d.stages.last()
        && s.dof > 0
        && let Some(quantile) = crate::stats::chi2_quantile(1.0 - alpha, s.dof as f64)
    {
        let critical = quantile / s.dof as f64;
        panel = panel.with(Item::Line {
            label: Some(format!("critical value at alpha = {alpha} ({} dof)", s.dof)),
            points: span(critical),
            colour: 1,
            dashed: true,
        });
    }
    let caption = "Chi-square per degree of freedom of the step means (each accelerometer's mean output over each \
                   step, whitened by its noise) for the baseline model and after each addition. A right model \
                   brings it to about 1; above the critical value the log still disagrees with the model.";
    Ok(render("gap", "Gap after each addition", caption, &[panel], 1, (1000, 380))?)
}

fn residual_figure(d: &Diagnosis, log: &CalibrationLog) -> Result<Figure, ReportError> {
    let mut panels = Vec::new();
    let steps: Vec<f64> = log.steps.iter().map(|s| s.step as f64).collect();
    for stage in &d.stages {
        let mut panel = Panel::new(
            format!("{}: chi2/dof {:.3}", stage.label, stage.gap),
            "step [number]",
            "whitened residual [noise sigma]",
        );
        for j in 0..log.n {
            let pts: Vec<(f64, f64)> = stage.per_step.iter().zip(&steps).map(|(z, &x)| (x, z[j])).collect();
            panel =
                panel.with(Item::Line { label: Some(format!("a{}", j + 1)), points: pts, colour: j, dashed: false });
        }
        let (lo, hi) = (steps.first().copied().unwrap_or(0.0), steps.last().copied().unwrap_or(1.0));
        for y in [-3.0, 3.0] {
            panel = panel.with(Item::Line {
                label: (y > 0.0).then(|| "+-3 sigma".to_string()),
                points: vec![(lo, y), (hi, y)],
                colour: 7,
                dashed: true,
            });
        }
        panels.push(panel);
    }
    let caption = "Whitened residual of every step mean of every accelerometer (measured minus modelled, in units of \
                   its noise sigma), step by step, for the baseline and after each addition. A missing effect shows \
                   as structure across steps (a trend for a drift, a pattern by orientation for a quadratic term); \
                   when the model is right the points scatter within +-3.";
    Ok(render("residuals", "Residuals by step and accelerometer", caption, &panels, 1, (1000, 300))?)
}

/// Builds the report of diagnosis `d` of `log` (named `log_name`) at familywise level `alpha`.
pub fn diagnosis_report(
    log_name: &str,
    log: &CalibrationLog,
    d: &Diagnosis,
    alpha: f64,
) -> Result<DiagnosisReport, ReportError> {
    let mut page = Page::new(&format!("gfcal diagnosis: {log_name}"));
    let b = &d.baseline;
    let held_out = match (d.held_out_before, d.held_out_after) {
        (Some(before), Some(after)) => {
            format!(" Held-out prediction error (1 is noise alone): {before:.3} before, {after:.3} after.")
        }
        _ => " No step can be left out and predicted, so there is no held-out error.".to_string(),
    };
    page.text(&format!(
        "{} steps, {} accelerometers{}; noise within steps {:.4e} m/s^2 per sample. Baseline chi2/dof {:.3} \
         (p = {:.2e}), after the named effects {:.3} (p = {:.2e}).{held_out}",
        log.steps.len(),
        log.n,
        if log.has_temperature() { ", with temperature" } else { "" },
        b.noise_sigma_m_s2,
        d.gap_before,
        b.p_value,
        d.gap_after,
        d.p_value_after,
    ));
    match d.explanation() {
        Explanation::Partial => page.note(
            "A partial explanation: the named effects lower the gap, but what is left is still above the noise. \
             An effect the library does not have remains.",
        ),
        Explanation::Unexplained => page.note(
            "An unmodelled effect remains: the gap is above the noise and no candidate of the library explains it.",
        ),
        Explanation::Complete | Explanation::NothingToExplain => {}
    }
    page.heading(2, "Effects named");
    if d.findings.is_empty() {
        page.text("None: the baseline model explains the log to within its noise.");
    } else {
        let rows: Vec<(Vec<String>, bool)> = d
            .findings
            .iter()
            .map(|f| {
                let vals: Vec<String> =
                    f.value.iter().zip(&f.sigma).map(|(v, s)| format!("{v:.4e} +- {s:.1e}")).collect();
                (
                    vec![
                        f.name.clone(),
                        f.accelerometer.map(|j| format!("a{}", j + 1)).unwrap_or_else(|| "all".into()),
                        vals.join(", "),
                        f.unit.clone(),
                        format!("{:.3}", f.gap_before),
                        format!("{:.3}", f.gap_after),
                        format!("{:.1e}", f.p_value),
                        f.confounded_with.clone().unwrap_or_default(),
                    ],
                    f.confounded_with.is_some(),
                )
            })
            .collect();
        page.table(
            &["effect", "accelerometer", "value +- sigma", "unit", "gap before", "gap after", "p", "confounded with"],
            &rows,
        );
    }
    let figures = vec![gap_figure(d, alpha)?, residual_figure(d, log)?];
    page.heading(2, "Gap");
    page.figure(&figures[0], None);
    page.heading(2, "Residuals");
    page.figure(&figures[1], None);
    let confounded: Vec<(Vec<String>, bool)> = d
        .verdicts
        .iter()
        .filter_map(|(label, v)| match v {
            Verdict::ConfoundedWithModel(with) => Some((vec![label.clone(), with.join(", ")], false)),
            Verdict::Tested { .. } | Verdict::NoSigma => None,
        })
        .collect();
    if !confounded.is_empty() {
        page.heading(2, "Candidates this log cannot separate from the model");
        page.table(&["candidate", "absorbed by"], &confounded);
    }
    Ok(DiagnosisReport { html: page.finish(), figures })
}
