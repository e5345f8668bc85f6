//! The report of `gfcal calibrate --report FILE.html`: segmentation, every parameter with its
//! sigma, the fit's residuals against the noise, the gyroscope-free rate against the reference
//! gyroscopes, and held-out prediction.

#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord, clippy::useless_vec)]

use std::path::PathBuf;

use super::display_unit;
use super::html::Page;
use super::plot::{Item, Panel, render};
use crate::array::wiring::RecordingArray;
use crate::io::format::significant;
use crate::selfcal::calibrate::Calibration;
use crate::selfcal::model::{NAMES, PER_ACCEL, UNITS, sensors};
use crate::selfcal::predict::HeldOut;
use crate::selfcal::recording::Recording;

/// Renders the report page.
pub fn render_page(cal: &Calibration, rec: &Recording, array: &RecordingArray, held: &[(PathBuf, HeldOut)]) -> String {
    let fit = &cal.fit;
    let mut page = Page::new(&format!("gfcal calibrate: {}", rec.path.display()));
    page.text(&format!(
        "Array {} ({} accelerometers). Rate from {}. {} static interval(s), {} dynamic sample(s) ({} clipped outputs left out, {} samples dropped). Fit {} in {} iterations. Fisher information null directions before the gauge is fixed: {} (the gauge has {}).",
        array.path.display(),
        rec.accelerometers(),
        if cal.use_gyro { "the reference gyroscopes" } else { "the accelerometers (gyroscope-free)" },
        cal.segmentation.static_intervals.len(),
        cal.dynamic_index.len(),
        cal.clipped_outputs,
        cal.dropped_samples,
        if fit.converged { "converged" } else { "did not converge" },
        fit.iterations,
        fit.null_directions,
        fit.gauge.null_count()
    ));
    for c in fit.gauge.describe() {
        page.text(&format!("Gauge, {c}."));
    }
    page.heading(2, "Parameters");
    let mut header = vec!["accelerometer".to_string()];
    for p in 0..PER_ACCEL {
        let (u, _) = display_unit(UNITS[p]);
        header.push(format!("{} ({u})", NAMES[p]));
        header.push(format!("sigma ({u})"));
    }
    let header_ref: Vec<&str> = header.iter().map(String::as_str).collect();
    let rows: Vec<(Vec<String>, bool)> = (0..rec.accelerometers())
        .map(|j| {
            let mut cells = vec![format!("{}", j + 1)];
            for p in 0..PER_ACCEL {
                let (_, f) = display_unit(UNITS[p]);
                if !fit.identified(j, p) {
                    cells.push("unidentified".into());
                    cells.push("-".into());
                    continue;
                }
                let v = fit.params.get(j, p);
                cells.push(significant(v * f, if p == 0 { 6 } else { 4 }));
                cells.push(significant(fit.sigma(j, p) * f, 2));
            }
            (cells, false)
        })
        .collect();
    page.table(&header_ref, &rows);
    page.text("Units: SI, as in the JSON. Scale factor shown as its value (dimensionless), as the text and the JSON show it. Bias is input-referred; tilts are the tilt-form misalignment angles; dx, dy, dz are location errors (true minus nominal position).");
    if !fit.unseen.is_empty() {
        page.heading(2, "Combinations the recording cannot see");
        page.text(&format!(
            "The Fisher information has {} null directions, {} beyond the gauge's {}: these parameter combinations are not measured, so every parameter with a share in them is unidentified (no value, no sigma) and the rest are calibrated. Weights are those of the unit combination with each parameter scaled by its own information.",
            fit.null_directions,
            fit.unseen.len(),
            fit.gauge.null_count()
        ));
        for c in &fit.unseen {
            page.text(&crate::selfcal::unseen::describe(c, rec.accelerometers()));
        }
    }
    if !cal.to_identify.is_empty() {
        page.text(&format!("What would make them identifiable: {}.", cal.to_identify.join("; ")));
    }

    page.heading(2, "Residuals against the noise");
    page.text(&format!(
        "Static: chi2/dof {:.2}, residual RMS {} m/s^2 (sigmas widened by sqrt({:.2})). Dynamic: residual RMS by accelerometer below, rotation-phase chi2/dof {:.1} (against the static noise).",
        fit.static_chi2_dof,
        significant(fit.static_residual_rms_m_s2, 3),
        fit.static_variance_factor,
        fit.dynamic_chi2_dof
    ));
    let mut panels = Vec::new();
    let resid: Vec<(f64, f64)> = fit
        .dynamic_residual_rms_m_s2
        .iter()
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .map(|(j, v)| ((j + 1) as f64, *v))
        .collect();
    let noise: Vec<(f64, f64)> = cal.static_data.sigma.iter().enumerate().map(|(j, v)| ((j + 1) as f64, *v)).collect();
    if !resid.is_empty() {
        let mut p = Panel::new("dynamic residual RMS and static noise", "accelerometer", "m/s^2").log_y();
        p.items.push(Item::Points { label: Some("dynamic residual RMS".into()), points: resid, colour: 1 });
        p.items.push(Item::Points { label: Some("static noise (one sample)".into()), points: noise, colour: 0 });
        panels.push(p);
        // Residuals against the rate magnitude.
        let sens = sensors(&array.array, &fit.params);
        let mut bins = vec![(0.0, 0usize); 12];
        for (k, &i) in cal.dynamic_index.iter().enumerate() {
            let m = &fit.motion[k];
            let b = ((m.omega_rad_s.norm() / 5.0) as usize).min(bins.len() - 1);
            for (j, s) in sens.iter().enumerate() {
                if !rec.is_clipped(i, j) {
                    let r = rec.outputs[(i, j)] - s.output(&m.specific_force_m_s2(&s.position_m));
                    bins[b].0 += r * r;
                    bins[b].1 += 1;
                }
            }
        }
        let pts: Vec<(f64, f64)> = bins
            .iter()
            .enumerate()
            .filter(|(_, b)| b.1 > 0)
            .map(|(k, b)| (5.0 * k as f64 + 2.5, (b.0 / b.1 as f64).sqrt()))
            .collect();
        let mut p = Panel::new("dynamic residual RMS against the rate", "|omega| (rad/s)", "m/s^2");
        p.items.push(Item::Line { label: Some("all accelerometers".into()), points: pts, colour: 1, dashed: false });
        panels.push(p);
    }
    if let Some(g) = &cal.gyro_check {
        page.heading(2, "Gyroscope-free rate against the gyroscopes");
        page.text(&format!(
            "{} samples with no gyroscope clipped: RMS difference {} rad/s against an RMS rate of {} rad/s ({:.1}%). After the best rotation between the two frames ({} rad): {} rad/s. Median magnitude ratio {:.4}.",
            g.samples,
            significant(g.rms_rad_s, 3),
            significant(g.rms_reference_rad_s, 3),
            100.0 * g.relative,
            significant(g.frame_rotation_rad, 3),
            significant(g.aligned_rms_rad_s, 3),
            g.median_magnitude_ratio
        ));
        page.text(&format!(
            "With the gyroscopes' rate delayed by the accelerometers' best lag, {:.1} ms (a band-limited fractional delay, searched over +-{:.0} ms in 0.1 ms steps): RMS difference {} rad/s.",
            g.accelerometer_lag_s * 1e3,
            crate::selfcal::gyro_check::LAG_SEARCH_S * 1e3,
            significant(g.rms_at_lag_rad_s, 3)
        ));
        let rows: Vec<(Vec<String>, bool)> = g
            .by_rate
            .iter()
            .map(|(lo, hi, c, d, r)| {
                (vec![format!("{lo}-{hi}"), c.to_string(), significant(*d, 3), format!("{:.1}%", 100.0 * r)], false)
            })
            .collect();
        page.table(&["reference rate (rad/s)", "samples", "RMS difference (rad/s)", "relative"], &rows);
        let bias = cal.gyro_bias_rad_s.unwrap_or_default();
        let mut by_axis = Vec::new();
        for axis in 0..3 {
            let pts: Vec<(f64, f64)> = cal
                .dynamic_index
                .iter()
                .enumerate()
                .filter(|(_, i)| !rec.gyro_clipped[**i])
                .map(|(k, &i)| (rec.gyro_rate_rad_s[i][axis] - bias[axis], cal.rate_motion()[k].omega_rad_s[axis]))
                .step_by(3)
                .collect();
            let mut p =
                Panel::new(format!("omega_{}", ["x", "y", "z"][axis]), "gyroscopes (rad/s)", "gyroscope-free (rad/s)");
            let lim = pts.iter().map(|(a, _)| a.abs()).fold(1.0, f64::max);
            p.items.push(Item::Points { label: None, points: pts, colour: axis });
            p.items.push(Item::Line {
                label: Some("equal".into()),
                points: vec![(-lim, -lim), (lim, lim)],
                colour: 7,
                dashed: true,
            });
            by_axis.push(p);
        }
        if let Ok(fig) = render(
            "gyro_check",
            "Gyroscope-free rate against the gyroscopes",
            "Every third unclipped dynamic sample; the dashed line is equality.",
            &by_axis,
            3,
            (420, 380),
        ) {
            page.figure(&fig, None);
        }
    }
    if !panels.is_empty()
        && let Ok(fig) = render(
            "residuals",
            "Dynamic residuals",
            "Residual RMS of the dynamic fit by accelerometer against the static noise of one sample, and against the rate magnitude.",
            &panels,
            2,
            (600, 380),
        )
    {
        page.figure(&fig, None);
    }
    if !held.is_empty() {
        page.heading(2, "Held-out recordings");
        // Where the array declares sample clocks: the share of each held-out rotation phase's misfit
        // that its own gyroscopes' clocks remove (`selfcal::predict::HeldOut`).
        let clocked = held.iter().any(|(_, h)| h.own_clocks_share_removed.is_some());
        let rows: Vec<(Vec<String>, bool)> = held
            .iter()
            .map(|(p, h)| {
                let mut row = vec![
                    p.display().to_string(),
                    h.static_intervals.to_string(),
                    significant(h.static_residual_rms_m_s2, 3),
                    significant(h.static_noise_rms_m_s2, 3),
                    format!("{:.1}", h.static_chi2_dof),
                    h.dynamic_samples.to_string(),
                    significant(h.dynamic_residual_rms_m_s2, 3),
                    significant(h.dynamic_noise_rms_m_s2, 3),
                ];
                if clocked {
                    row.push(h.own_clocks_share_removed.map_or("-".into(), |v| format!("{:.1}%", 100.0 * v)));
                }
                (row, false)
            })
            .collect();
        let mut header = vec![
            "recording",
            "static intervals",
            "static residual RMS (m/s^2)",
            "static noise RMS (m/s^2)",
            "static chi2/dof",
            "dynamic samples",
            "dynamic residual RMS (m/s^2)",
            "noise RMS (m/s^2)",
        ];
        if clocked {
            header.push("its own clocks remove (of the dynamic misfit)");
        }
        page.table(&header, &rows);
    }
    page.heading(2, "Segmentation");
    let t = &rec.t_s;
    let rows: Vec<(Vec<String>, bool)> = cal
        .segmentation
        .static_intervals
        .iter()
        .zip(&fit.up)
        .enumerate()
        .map(|(k, (iv, u))| {
            (
                vec![
                    format!("static {}", k + 1),
                    format!("{:.2}", t[iv.start]),
                    format!("{:.2}", t[iv.end - 1]),
                    iv.len().to_string(),
                    format!("({:.4}, {:.4}, {:.4})", u.x, u.y, u.z),
                ],
                false,
            )
        })
        .chain(cal.segmentation.dynamic_intervals.iter().map(|iv| {
            (
                vec![
                    "dynamic".into(),
                    format!("{:.2}", t[iv.start]),
                    format!("{:.2}", t[iv.end - 1]),
                    iv.len().to_string(),
                    String::new(),
                ],
                false,
            )
        }))
        .collect();
    page.table(&["interval", "start (s)", "end (s)", "samples", "up (array axes)"], &rows);
    page.heading(2, "Assessment: what to trust");
    super::verdict_table(&mut page, crate::selfcal::output::verdicts(cal, held));
    page.finish()
}
