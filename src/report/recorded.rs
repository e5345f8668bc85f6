//! The report of `gfcal diagnose RECORDING --array FILE --report FILE.html`: the gap on the fitting
//! and held-out recordings after each addition, the effects named and not named, the rank tests,
//! the sensing points, and the fitting recording's residuals against the rate, the input level and
//! time, the axes out of the board's plane (z) apart from the others.

use super::html::Page;
use super::plot::{Item, Panel, render};
use super::{Figure, ReportError};
use crate::array::wiring::RecordingArray;
use crate::discrepancy::recorded::{Gap, RecordedDiagnosis};
use crate::io::format::significant;
use crate::selfcal::model::sensors;
use crate::selfcal::recording::Recording;

/// Bins of a residual RMS against some quantity: `(sum of squares, count)` per bin of `width`.
struct Bins {
    width: f64,
    sums: Vec<(f64, usize)>,
}

impl Bins {
    fn new(width: f64, count: usize) -> Self {
        Self { width, sums: vec![(0.0, 0); count] }
    }
    fn add(&mut self, x: f64, r: f64) {
        if !(x.is_finite() && r.is_finite()) {
            return;
        }
        let b = ((x.abs() / self.width) as usize).min(self.sums.len() - 1);
        self.sums[b].0 += r * r;
        self.sums[b].1 += 1;
    }
    /// Bin centres and RMS, over bins with at least `min` samples.
    fn rms(&self, min: usize) -> Vec<(f64, f64)> {
        self.sums
            .iter()
            .enumerate()
            .filter(|(_, b)| b.1 >= min)
            .map(|(k, b)| (self.width * (k as f64 + 0.5), (b.0 / b.1 as f64).sqrt()))
            .collect()
    }
}

/// Whether accelerometer `j`'s nominal axis is out of the board's plane (mostly along z).
fn out_of_plane(array: &RecordingArray, j: usize) -> bool {
    let a = &array.array.accelerometers()[j].axis;
    a.z.abs() > a.x.abs().max(a.y.abs())
}

fn show(g: &Gap) -> [String; 2] {
    [format!("{:.3}", g.static_chi2_dof), g.dynamic.map(|v| format!("{v:.1}")).unwrap_or_else(|| "-".into())]
}

/// The residual figures of the fitting recording (baseline fit: its own biases, scale factors and
/// geometry; the library's effects are linearised and not applied sample by sample).
fn residual_figure(
    d: &RecordedDiagnosis,
    rec: &Recording,
    array: &RecordingArray,
    gravity_m_s2: f64,
) -> Result<Figure, ReportError> {
    let cal = &d.calibration;
    let fit = &cal.fit;
    let sens = sensors(&array.array, &fit.params);
    let n = sens.len();
    // [in plane, out of plane] for each of rate, reading, time.
    let mut by_rate = [Bins::new(5.0, 12), Bins::new(5.0, 12)];
    let mut by_reading = [Bins::new(10.0, 16), Bins::new(10.0, 16)];
    let t0 = rec.t_s.first().copied().unwrap_or(0.0);
    let span_s = rec.t_s.last().copied().unwrap_or(0.0) - t0;
    let per_s = (span_s / 60.0).ceil().max(1.0);
    let mut by_time = [Bins::new(per_s, 61), Bins::new(per_s, 61)];
    let mut dynamic_time = Vec::new();
    for (k, &i) in cal.dynamic_index.iter().enumerate() {
        let m = &fit.motion[k];
        for (j, s) in sens.iter().enumerate() {
            if rec.is_clipped(i, j) {
                continue;
            }
            let z = usize::from(out_of_plane(array, j));
            let r = rec.outputs[(i, j)] - s.output(&m.specific_force_m_s2(&s.position_m));
            by_rate[z].add(m.omega_rad_s.norm(), r);
            by_reading[z].add(rec.outputs[(i, j)], r);
            by_time[z].add(rec.t_s[i] - t0, r);
        }
        dynamic_time.push(rec.t_s[i] - t0);
    }
    let noise_rms = (cal.static_data.sigma.iter().map(|s| s * s).sum::<f64>() / n.max(1) as f64).sqrt();
    let labels = ["axes in the board's plane (x, y)", "axes out of the plane (z)"];
    let noise_line = |xs: &[(f64, f64)]| -> Item {
        let lo = xs.first().map_or(0.0, |p| p.0);
        let hi = xs.last().map_or(1.0, |p| p.0);
        Item::Line {
            label: Some("static noise (one sample)".into()),
            points: vec![(lo, noise_rms), (hi, noise_rms)],
            colour: 7,
            dashed: true,
        }
    };
    let mut panels = Vec::new();
    for (title, x_label, bins) in [
        ("dynamic residual RMS against the rate", "|omega| (rad/s)", &by_rate),
        ("dynamic residual RMS against the input level", "|output| (m/s^2)", &by_reading),
    ] {
        let mut p = Panel::new(title, x_label, "residual RMS (m/s^2)").log_y();
        for (z, b) in bins.iter().enumerate() {
            p.items.push(Item::Line { label: Some(labels[z].into()), points: b.rms(20), colour: z + 1, dashed: false });
        }
        let all = bins[0].rms(20);
        p.items.push(noise_line(&all));
        panels.push(p);
    }
    // Time: the static intervals' whitened residual means, and the dynamic residual RMS.
    let mut p =
        Panel::new("static interval means against time", "time from the start (s)", "residual / sigma of the mean");
    let mut pts = [Vec::new(), Vec::new()];
    let pose_sens = &sens;
    for (pidx, iv) in cal.segmentation.static_intervals.iter().enumerate() {
        let t_mid = 0.5 * (rec.t_s[iv.start] + rec.t_s[iv.end - 1]) - t0;
        let up = fit.up.get(pidx).copied();
        let Some(up) = up else { continue };
        let q = up * gravity_m_s2;
        for (j, s) in pose_sens.iter().enumerate() {
            let r = cal.static_data.means[(pidx, j)] - s.output(&q);
            let sigma = cal.static_data.sigma[j] / (cal.static_data.counts[pidx] as f64).sqrt();
            if sigma > 0.0 {
                pts[usize::from(out_of_plane(array, j))].push((t_mid, r / sigma));
            }
        }
    }
    for (z, v) in pts.into_iter().enumerate() {
        p.items.push(Item::Points { label: Some(labels[z].into()), points: v, colour: z + 1 });
    }
    panels.push(p);
    let mut p =
        Panel::new("dynamic residual RMS against time", "time from the start (s)", "residual RMS (m/s^2)").log_y();
    for (z, b) in by_time.iter().enumerate() {
        p.items.push(Item::Points { label: Some(labels[z].into()), points: b.rms(20), colour: z + 1 });
    }
    panels.push(p);
    Ok(render(
        "recorded_residuals",
        "Residuals of the fitting recording",
        "The baseline fit of the fitting recording (its own biases, scale factors, misalignments and locations; the \
         library's effects are tested linearised and not applied here). Dynamic residuals (measured minus modelled output) \
         binned by the rate magnitude, the output and time (bins of at least 20 outputs), the axes out of the board's plane \
         apart; the dashed line is the static noise of one sample. Static: each interval's mean residual over the sigma of \
         the mean, at the interval's middle time: a drift shows as a trend, a missing orientation term as spread by pose.",
        &panels,
        2,
        (560, 360),
    )?)
}

/// Renders the page and its figure.
pub fn recorded_report(
    d: &RecordedDiagnosis,
    rec: &Recording,
    array: &RecordingArray,
    gravity_m_s2: f64,
) -> Result<(String, Vec<Figure>), ReportError> {
    let mut page = Page::new(&format!("gfcal diagnose: {}", rec.path.display()));
    page.text(&format!(
        "Array {} ({} accelerometers), rate from {}. {} static interval(s), {} dynamic sample(s). The gap: static \
         chi2/dof of the interval means, and the rotation-phase chi2/dof (the residuals against the static noise, per \
         degree of freedom left by each sample's motion: the number gfcal calibrate prints); 1 is noise alone. Effects are named at the familywise level {} only if they lower the gap on every held-out recording.",
        array.path.display(),
        array.array.len(),
        if d.calibration.use_gyro { "the reference gyroscopes" } else { "the accelerometers (gyroscope-free)" },
        d.calibration.segmentation.static_intervals.len(),
        d.calibration.dynamic_index.len(),
        d.alpha
    ));
    page.heading(2, "Gap after each addition");
    let mut rows: Vec<(Vec<String>, bool)> = Vec::new();
    let mut push = |who: String, step: &str, g: &Gap| {
        let [s, y] = show(g);
        rows.push((vec![who, step.to_string(), s, y], false));
    };
    push("fitting".into(), "baseline", &d.fitting);
    for (name, g) in &d.fitting_after_each {
        push("fitting".into(), &format!("+ {name}"), g);
    }
    for h in &d.held_out {
        let who = h.recording.display().to_string();
        push(who.clone(), "baseline (poses and motion refitted)", &h.before);
        for (name, g) in &h.after_each {
            push(who.clone(), &format!("+ {name}"), g);
        }
    }
    page.table(&["recording", "model", "static chi2/dof", "rotation-phase chi2/dof"], &rows);
    page.heading(2, "Effects named");
    let rows: Vec<(Vec<String>, bool)> = d
        .findings
        .iter()
        .map(|f| {
            let owner = match (f.accelerometer, f.package) {
                (Some(j), _) => format!("accelerometer {}", j + 1),
                (_, Some(m)) => format!("package {}", m + 1),
                _ if f.name == "sample_clock" => "every package".into(),
                _ => "all / shared".into(),
            };
            let values: Vec<String> = f
                .value
                .iter()
                .zip(&f.sigma)
                .map(|(v, s)| format!("{} +- {}", significant(*v, 4), significant(*s, 2)))
                .collect();
            let shown =
                if values.len() > 4 { format!("{} values (see the JSON)", values.len()) } else { values.join(", ") };
            (vec![f.name.clone(), owner, shown, f.unit.clone()], false)
        })
        .collect();
    if rows.is_empty() {
        page.text("None.");
    } else {
        page.table(&["effect", "owner", "value +- sigma", "unit"], &rows);
    }
    let rows: Vec<(Vec<String>, bool)> =
        d.not_named.iter().map(|(n, why)| (vec![n.clone(), why.clone()], false)).collect();
    if !rows.is_empty() {
        page.heading(2, "Tried and not named");
        page.table(&["effect", "why"], &rows);
    }
    page.heading(2, "Rank tests");
    let rows: Vec<(Vec<String>, bool)> = d
        .ranks
        .iter()
        .map(|r| {
            (
                vec![
                    r.name.clone(),
                    r.parameters.to_string(),
                    r.unseen.to_string(),
                    format!("{:.2e}", r.p_value_joint),
                ],
                r.unseen == r.parameters,
            )
        })
        .collect();
    page.table(&["effect", "parameters", "unseen directions", "joint p (all parameters)"], &rows);
    page.heading(2, "Sensing points inside each package");
    let rows: Vec<(Vec<String>, bool)> = d
        .sensing_points
        .iter()
        .map(|sp| {
            let diffs: Vec<String> = sp.offsets().iter().map(|o| o.describe_mm()).collect();
            (vec![(sp.package + 1).to_string(), diffs.join("; "), format!("{:.1e}", sp.p_value)], false)
        })
        .collect();
    page.table(
        &["package", "location error of each further axis minus the package's first (array axes, mm)", "p"],
        &rows,
    );
    page.heading(2, "Assessment: what to trust in the fitting recording's calibration");
    super::verdict_table(&mut page, d.assessment());
    let fig = residual_figure(d, rec, array, gravity_m_s2)?;
    page.heading(2, "Residuals");
    page.figure(&fig, None);
    Ok((page.finish(), vec![fig]))
}
