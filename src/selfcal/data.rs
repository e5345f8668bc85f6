//! What the estimator, the tracker and the prediction share: the static phase as interval means,
//! the dynamic phase as runs of samples.

use nalgebra::{DMatrix, Vector3};

/// The static phase: one mean per interval and accelerometer.
#[derive(Debug, Clone)]
pub struct StaticData {
    /// Intervals x accelerometers, output units.
    pub means: DMatrix<f64>,
    pub counts: Vec<usize>,
    /// Pooled within-interval standard deviation of one sample, per accelerometer.
    pub sigma: Vec<f64>,
}

/// The dynamic phase: samples in runs of consecutive samples.
#[derive(Debug, Clone)]
pub struct DynamicData {
    pub t_s: Vec<f64>,
    /// Samples x accelerometers.
    pub outputs: DMatrix<f64>,
    /// Samples x accelerometers, row-major: the output is used (not clipped).
    pub used: Vec<bool>,
    /// Start index of each run (the first is 0).
    pub run_starts: Vec<usize>,
    /// Reference rate per sample (array axes), when the rate is taken from gyroscopes.
    pub reference_rate_rad_s: Option<Vec<Vector3<f64>>>,
    /// Unknowns each sample spends beyond its motion (the jerk of the sample clocks' model: 3),
    /// for the degrees of freedom of the dynamic residuals.
    pub extra_unknowns_per_sample: usize,
}

impl DynamicData {
    pub fn samples(&self) -> usize {
        self.t_s.len()
    }
    /// `(start, end)` of every run of consecutive samples.
    pub fn runs(&self) -> Vec<(usize, usize)> {
        let mut v = Vec::new();
        for (i, &s) in self.run_starts.iter().enumerate() {
            let e = self.run_starts.get(i + 1).copied().unwrap_or(self.samples());
            if e > s {
                v.push((s, e));
            }
        }
        v
    }
}
