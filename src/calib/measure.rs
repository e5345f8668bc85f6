//! Simulated calibration measurements, summarised per step.

use rand::Rng;

use super::schedule::Schedule;
use crate::array::Array;
use crate::sensor::noise::{NoiseGenerator, NoiseSpec, quantize};
use crate::sensor::params::ArrayParams;

/// Mean and within-step scatter of every output in one step.
#[derive(Debug, Clone, PartialEq)]
pub struct StepStats {
    pub samples: usize,
    /// Mean output of each accelerometer, output units.
    pub mean: Vec<f64>,
    /// Sum of squared deviations from the step mean, output units squared.
    pub within_ss: Vec<f64>,
}

impl StepStats {
    /// No samples yet, for `n` outputs.
    pub fn empty(n: usize) -> Self {
        Self { samples: 0, mean: vec![0.0; n], within_ss: vec![0.0; n] }
    }

    /// Adds one sample of every output (Welford's running mean and sum of squares). The mean's
    /// update divides by the count: multiplying by its reciprocal saved under 2% of a quickstart
    /// trial and moved the estimates' last bits (issue 14 asks for the outputs kept).
    pub fn push(&mut self, values: &[f64]) {
        self.samples += 1;
        let count = self.samples as f64;
        for ((v, m), ss) in values.iter().zip(&mut self.mean).zip(&mut self.within_ss) {
            let delta = v - *m;
            *m += delta / count;
            *ss += delta * (v - *m);
        }
    }
}

/// A schedule's measurements, one [`StepStats`] per step, in schedule order.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurements {
    pub steps: Vec<StepStats>,
}

/// Noise-free step means of `params` over `schedule` (output units).
pub fn noise_free(array: &Array, params: &ArrayParams, schedule: &Schedule, g_m_s2: f64) -> Measurements {
    let n = array.len();
    let steps = schedule
        .steps()
        .iter()
        .map(|step| {
            let mut mean = vec![0.0; n];
            params.outputs(array, &step.motion(g_m_s2), &mut mean);
            StepStats { samples: step.samples(), mean, within_ss: vec![0.0; n] }
        })
        .collect();
    Measurements { steps }
}

/// Simulates every sample of every step (true parameters, noise from `spec`, bias-instability
/// states running on across steps) and summarises each step.
pub fn simulate<R: Rng + ?Sized>(
    array: &Array,
    truth: &ArrayParams,
    schedule: &Schedule,
    spec: &NoiseSpec,
    g_m_s2: f64,
    rng: &mut R,
) -> Measurements {
    let clean = noise_free(array, truth, schedule, g_m_s2);
    if spec.is_zero() {
        return clean;
    }
    let n = array.len();
    let rate_hz = schedule.steps().first().map(|s| s.sample_rate_hz).unwrap_or(1.0);
    let mut generator = NoiseGenerator::new(spec, n, rate_hz, rng);
    let mut steps = Vec::with_capacity(schedule.len());
    for (step, c) in schedule.steps().iter().zip(&clean.steps) {
        generator = generator.at_rate(spec, step.sample_rate_hz);
        let mut stats = StepStats::empty(n);
        let mut sample = vec![0.0; n];
        for _ in 0..step.samples() {
            for (j, v) in sample.iter_mut().enumerate() {
                let k = truth.sensors[j].scale_factor;
                *v = quantize(c.mean[j] + k * generator.next_m_s2(rng, j), k.abs() * spec.quantization_m_s2);
            }
            stats.push(&sample);
        }
        steps.push(stats);
    }
    Measurements { steps }
}
