//! Static intervals and the dynamic phase of a recording, from the accelerometers alone.
//!
//! The detector:
//! 1. For every accelerometer j, the moving standard deviation `m_j(i)` of its output over a
//!    centred window of `window_s` (at least 5 samples).
//! 2. Its noise floor `n_j`: the 10th percentile of `m_j` over the recording (a recording that is
//!    still for at least a tenth of its length, as any calibration recording is).
//! 3. A sample is still when `max_j m_j(i) / n_j < threshold`.
//! 4. A run of still samples lasting at least `min_static_s` is a static interval, after trimming
//!    `trim_s` from each end (the board settling after it was put down, and the hand reaching
//!    for it).
//! 5. A run of moving samples lasting at least `min_dynamic_s` belongs to the dynamic phase;
//!    shorter runs (the board carried from one pose to the next) are left out and counted.
//!
//! A `step` column overrides the detector: rows with a step >= 0 are the static interval of that
//! step (its rows must be contiguous), rows with a negative step are the dynamic phase.
//!
//! When a calibration cannot use what was found, [`describe`] says what it was, with the sample
//! rate the time column implies ([`implied_rate_hz`]) and, when that rate is implausible, the
//! likely unit error ([`time_unit_suspicion`]: a time in milliseconds read as seconds makes the
//! windows a thousand times too long).

use crate::selfcal::recording::{Recording, RecordingError};

/// Settings of the detector (seconds and a ratio).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorSettings {
    pub window_s: f64,
    pub threshold: f64,
    pub min_static_s: f64,
    pub trim_s: f64,
    pub min_dynamic_s: f64,
}

impl Default for DetectorSettings {
    fn default() -> Self {
        Self { window_s: 0.5, threshold: 2.0, min_static_s: 5.0, trim_s: 1.0, min_dynamic_s: 10.0 }
    }
}

/// A half-open range of sample indices `[start, end)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interval {
    pub start: usize,
    pub end: usize,
}

impl Interval {
    pub fn len(&self) -> usize {
        self.end - self.start
    }
    pub fn is_empty(&self) -> bool {
        self.end <= self.start
    }
}

/// The segmentation of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Segmentation {
    pub static_intervals: Vec<Interval>,
    pub dynamic_intervals: Vec<Interval>,
    /// Moving runs shorter than `min_dynamic_s`, left out.
    pub short_moving_runs: usize,
    /// Whether a `step` column gave the segmentation.
    pub from_step_column: bool,
    /// Samples the detector called still (or a `step` column put in a step), kept or not.
    pub still_samples: usize,
    /// The longest run of still and of moving samples, s (the lengths `min_static_s` and
    /// `min_dynamic_s` are compared with).
    pub longest_still_s: f64,
    pub longest_moving_s: f64,
}

impl Segmentation {
    pub fn dynamic_samples(&self) -> usize {
        self.dynamic_intervals.iter().map(Interval::len).sum()
    }
}

/// Segments a recording (see the module docs).
pub fn segment(rec: &Recording, settings: &DetectorSettings) -> Result<Segmentation, RecordingError> {
    if let Some(step) = &rec.step {
        return from_steps(rec, step);
    }
    let n_samples = rec.samples();
    let duration_s = rec.t_s[n_samples - 1] - rec.t_s[0];
    let dt_s = duration_s / (n_samples - 1) as f64;
    let half = ((settings.window_s / dt_s / 2.0).round() as usize).max(2);
    let mut ratio_max = vec![0.0_f64; n_samples];
    for j in 0..rec.accelerometers() {
        let col = rec.outputs.column(j);
        let m = moving_std(col.as_slice(), half);
        let mut sorted: Vec<f64> = m.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f64::total_cmp);
        let floor = sorted.get(sorted.len() / 10).copied().unwrap_or(0.0);
        // A channel with no scatter at all (quantised to one level when still) cannot be
        // compared with its floor; it still counts when it moves.
        let floor = if floor > 0.0 { floor } else { sorted.iter().copied().find(|v| *v > 0.0).unwrap_or(1.0) };
        for (r, v) in ratio_max.iter_mut().zip(&m) {
            *r = r.max(v / floor);
        }
    }
    let still: Vec<bool> = ratio_max.iter().map(|&r| r < settings.threshold).collect();
    let mut static_intervals = Vec::new();
    let mut dynamic_intervals = Vec::new();
    let mut short_moving_runs = 0;
    let (mut longest_still_s, mut longest_moving_s) = (0.0f64, 0.0f64);
    let mut i = 0;
    while i < n_samples {
        let mut k = i;
        while k < n_samples && still[k] == still[i] {
            k += 1;
        }
        let length_s = rec.t_s[k - 1] - rec.t_s[i];
        let longest = if still[i] { &mut longest_still_s } else { &mut longest_moving_s };
        *longest = longest.max(length_s);
        if still[i] {
            if length_s >= settings.min_static_s {
                let trim = (settings.trim_s / dt_s).round() as usize;
                let (s, e) = (i + trim, k.saturating_sub(trim));
                if e > s + 1 {
                    static_intervals.push(Interval { start: s, end: e });
                }
            }
        } else if length_s >= settings.min_dynamic_s {
            dynamic_intervals.push(Interval { start: i, end: k });
        } else {
            short_moving_runs += 1;
        }
        i = k;
    }
    Ok(Segmentation {
        static_intervals,
        dynamic_intervals,
        short_moving_runs,
        from_step_column: false,
        still_samples: still.iter().filter(|&&s| s).count(),
        longest_still_s,
        longest_moving_s,
    })
}

fn from_steps(rec: &Recording, step: &[i64]) -> Result<Segmentation, RecordingError> {
    let mut static_intervals = Vec::new();
    let mut dynamic_intervals = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut i = 0;
    while i < step.len() {
        let mut k = i;
        while k < step.len() && step[k] == step[i] {
            k += 1;
        }
        if step[i] >= 0 {
            if !seen.insert(step[i]) {
                return Err(RecordingError::Value {
                    path: rec.path.clone(),
                    row: i + 1,
                    column: "step".into(),
                    problem: format!(
                        "step {} appears again after other steps (a step's rows must be contiguous)",
                        step[i]
                    ),
                });
            }
            static_intervals.push(Interval { start: i, end: k });
        } else if let Some(last) = dynamic_intervals.last_mut().filter(|d: &&mut Interval| d.end == i) {
            last.end = k;
        } else {
            dynamic_intervals.push(Interval { start: i, end: k });
        }
        i = k;
    }
    let span = |iv: &Interval| rec.t_s[iv.end - 1] - rec.t_s[iv.start];
    let longest = |ivs: &[Interval]| ivs.iter().map(span).fold(0.0, f64::max);
    Ok(Segmentation {
        still_samples: static_intervals.iter().map(Interval::len).sum(),
        longest_still_s: longest(&static_intervals),
        longest_moving_s: longest(&dynamic_intervals),
        static_intervals,
        dynamic_intervals,
        short_moving_runs: 0,
        from_step_column: true,
    })
}

/// The sample rates a calibration recording plausibly has, Hz. Outside them the time column is
/// likely not in seconds: 62.5 Hz with the time in milliseconds reads as 0.0625 Hz.
pub const PLAUSIBLE_RATE_HZ: (f64, f64) = (5.0, 100_000.0);

/// The sample rate the time column implies: one over the median interval between samples, Hz
/// (NaN with fewer than two samples).
pub fn implied_rate_hz(t_s: &[f64]) -> f64 {
    let mut dt: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    if dt.is_empty() {
        return f64::NAN;
    }
    let mid = dt.len() / 2;
    let (_, median, _) = dt.select_nth_unstable_by(mid, f64::total_cmp);
    1.0 / *median
}

/// If `rate_hz` (from [`implied_rate_hz`]) lies outside [`PLAUSIBLE_RATE_HZ`], the likely unit
/// error of the time column in words: milliseconds, microseconds or nanoseconds read as seconds,
/// a sample counter, or a time that is not in seconds at all.
pub fn time_unit_suspicion(rate_hz: f64, t_s: &[f64]) -> Option<String> {
    use crate::io::format::significant as sig;
    let (low, high) = PLAUSIBLE_RATE_HZ;
    if !rate_hz.is_finite() || (low..=high).contains(&rate_hz) {
        return None;
    }
    let not = format!("which no accelerometer array records at (plausible: {low} Hz to {} kHz)", high / 1e3);
    if rate_hz < low {
        if t_s.windows(2).all(|w| w[1] - w[0] == 1.0) {
            return Some(format!("{not}: it counts samples (every step is 1), it is not a time in seconds"));
        }
        for (unit, factor) in [("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9)] {
            if (low..=high).contains(&(rate_hz * factor)) {
                return Some(format!(
                    "{not}: the time looks like {unit} ({} Hz if so); gfcal reads it in seconds: divide the \
                     column by {}",
                    sig(rate_hz * factor, 3),
                    factor as u64
                ));
            }
        }
    }
    Some(format!("{not}: is the time in seconds?"))
}

/// What the segmentation of `rec` found, in words, for a message when a calibration cannot use
/// it: the sample rate the time column `column` implies (and the likely unit error when it is
/// implausible), then the static intervals and the moving runs against the settings.
pub fn describe(rec: &Recording, seg: &Segmentation, settings: &DetectorSettings, column: &str) -> String {
    use crate::io::format::significant as sig;
    let n = rec.samples();
    let duration_s = rec.t_s[n - 1] - rec.t_s[0];
    let rate_hz = implied_rate_hz(&rec.t_s);
    let mut out = format!(
        "The time column `{column}` implies a sample rate of {} Hz ({n} samples over {} s)",
        sig(rate_hz, 3),
        sig(duration_s, 4)
    );
    if let Some(suspicion) = time_unit_suspicion(rate_hz, &rec.t_s) {
        out.push_str(&format!(", {suspicion}"));
    }
    let dynamic_s: f64 = seg.dynamic_intervals.iter().map(|iv| rec.t_s[iv.end - 1] - rec.t_s[iv.start]).sum();
    if seg.from_step_column {
        out.push_str(&format!(
            ". The `step` column gives {} static interval(s) and {} rotation run(s) ({} s).",
            seg.static_intervals.len(),
            seg.dynamic_intervals.len(),
            sig(dynamic_s, 3)
        ));
        return out;
    }
    let share = |k: usize| 100.0 * k as f64 / n.max(1) as f64;
    out.push_str(&format!(
        ". The segmentation found {} static interval(s) (still runs of at least {} s; the longest still run \
         {} s) and {} rotation run(s), {} s in all (moving runs of at least {} s; {} shorter moving run(s) left \
         out, the longest {} s); {:.0}% of the samples still, {:.0}% moving (still: every accelerometer's scatter \
         over {} s below {} times its noise floor, the quietest tenth of its scatter).",
        seg.static_intervals.len(),
        settings.min_static_s,
        sig(seg.longest_still_s, 3),
        seg.dynamic_intervals.len(),
        sig(dynamic_s, 3),
        settings.min_dynamic_s,
        seg.short_moving_runs,
        sig(seg.longest_moving_s, 3),
        share(seg.still_samples),
        share(n - seg.still_samples),
        settings.window_s,
        settings.threshold
    ));
    out
}

/// The message for a calibration of `rec` that found `found` static intervals where it needs
/// `needed` (`with_dynamic`: whether it had a rotation phase to fit): what the segmentation found
/// ([`describe`]). Without a rotation phase it says why there was none; and a recording that
/// alternates between still and moving more often than it has static intervals (as one that is
/// all rotation does: the detector calls its calmer stretches still) is told that a calibration
/// needs it to rest, not that it does not rotate.
pub fn too_few_poses(
    rec: &Recording,
    settings: &DetectorSettings,
    column: &str,
    found: usize,
    needed: usize,
    with_dynamic: bool,
) -> String {
    let seg = segment(rec, settings);
    let how = if with_dynamic {
        "with a rotation phase".to_string()
    } else {
        match &seg {
            Ok(s) if !s.dynamic_intervals.is_empty() => format!(
                "from static poses alone (its {} rotation run(s) have no sample with enough unclipped outputs)",
                s.dynamic_intervals.len()
            ),
            Ok(s) if s.from_step_column => "from static poses alone (the `step` column has no negative step)".into(),
            _ => format!(
                "from static poses alone (the segmentation kept no rotation run: no moving run lasts {} s, \
                 --min-dynamic-s)",
                settings.min_dynamic_s
            ),
        }
    };
    let mut out = format!("{found} static interval(s) found; a calibration {how} needs at least {needed}");
    if let Ok(s) = &seg {
        out.push_str(&format!(". {}", describe(rec, s, settings, column)));
        if !s.from_step_column && s.short_moving_runs > s.static_intervals.len().max(1) * 4 {
            out.push_str(&format!(
                " The recording moves in {} short runs against {} static interval(s): does it rest at all? A \
                 calibration recording rests in static poses (several seconds each), then rotates; the detector \
                 takes each accelerometer's quietest tenth as its noise floor, so in a recording that never rests \
                 (all rotation) it calls the calmer stretches of the motion still.",
                s.short_moving_runs,
                s.static_intervals.len()
            ));
        }
    }
    out
}

/// Standard deviation over the centred window `[i - half, i + half]` (clipped at the ends), by
/// running sums of the values minus the first value (stable for offsets much larger than the
/// scatter).
fn moving_std(x: &[f64], half: usize) -> Vec<f64> {
    let n = x.len();
    let x0 = x[0];
    let mut s1 = vec![0.0; n + 1];
    let mut s2 = vec![0.0; n + 1];
    for i in 0..n {
        let v = x[i] - x0;
        s1[i + 1] = s1[i] + v;
        s2[i + 1] = s2[i] + v * v;
    }
    (0..n)
        .map(|i| {
            let a = i.saturating_sub(half);
            let b = (i + half + 1).min(n);
            let m = (b - a) as f64;
            let mean = (s1[b] - s1[a]) / m;
            let var = ((s2[b] - s2[a]) / m - mean * mean) * m / (m - 1.0);
            var.max(0.0).sqrt()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit a time column is likely in, from the rate it implies read as seconds.
    #[test]
    fn an_implausible_rate_names_the_likely_unit() {
        let times = |dt: f64| (0..100).map(|i| i as f64 * dt).collect::<Vec<f64>>();
        let said = |dt: f64| {
            let t = times(dt);
            time_unit_suspicion(implied_rate_hz(&t), &t)
        };
        // 62.5 Hz, 1 kHz and 20 kHz in seconds: plausible.
        for dt in [0.016, 1e-3, 5e-5] {
            assert_eq!(said(dt), None, "{dt}");
        }
        let ms = said(16.0).expect("milliseconds");
        assert!(ms.contains("milliseconds (62.5 Hz if so)") && ms.contains("by 1000"), "{ms}");
        let us = said(16_000.0).expect("microseconds");
        assert!(us.contains("microseconds (62.5 Hz if so)"), "{us}");
        let counter = said(1.0).expect("a counter");
        assert!(counter.contains("counts samples"), "{counter}");
        let fast = said(1e-7).expect("10 MHz");
        assert!(fast.contains("is the time in seconds?"), "{fast}");
    }

    #[test]
    fn moving_std_of_a_step_and_a_constant() {
        let x: Vec<f64> = (0..20).map(|i| if i < 10 { 5.0 } else { 7.0 }).collect();
        let m = moving_std(&x, 2);
        assert!(m[3].abs() < 1e-12 && m[16].abs() < 1e-12);
        // window [8, 12]: 5, 5, 7, 7, 7 -> sample std sqrt(1.2)
        assert!((m[10] - 1.2_f64.sqrt()).abs() < 1e-12);
    }
}
