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
    let mut i = 0;
    while i < n_samples {
        let mut k = i;
        while k < n_samples && still[k] == still[i] {
            k += 1;
        }
        let length_s = rec.t_s[k - 1] - rec.t_s[i];
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
    Ok(Segmentation { static_intervals, dynamic_intervals, short_moving_runs, from_step_column: false })
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
    Ok(Segmentation { static_intervals, dynamic_intervals, short_moving_runs: 0, from_step_column: true })
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

    #[test]
    fn moving_std_of_a_step_and_a_constant() {
        let x: Vec<f64> = (0..20).map(|i| if i < 10 { 5.0 } else { 7.0 }).collect();
        let m = moving_std(&x, 2);
        assert!(m[3].abs() < 1e-12 && m[16].abs() < 1e-12);
        // window [8, 12]: 5, 5, 7, 7, 7 -> sample std sqrt(1.2)
        assert!((m[10] - 1.2_f64.sqrt()).abs() < 1e-12);
    }
}
