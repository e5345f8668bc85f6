//! Correlated noise within steps, tested exactly (an F test of cluster means: the Allan-variance
//! comparison without its dependence between adjacent differences).

use nalgebra::{DMatrix, DVector};

use super::data::CalibrationLog;
use crate::stats::f_sf;

/// Test of one accelerometer's within-step samples for correlated noise at a cluster size `m`
/// (model-free): within each step the samples are cut into clusters of `m`, and the variance of
/// the cluster means about their step mean (times `m`) is compared with the variance within
/// clusters. Under white Gaussian noise their ratio is exactly F-distributed with
/// (clusters - steps, samples - clusters) degrees of freedom; noise correlated over about `m`
/// samples (bias instability) makes it larger. This is the Allan-variance comparison done as an
/// exact test (adjacent Allan differences share a cluster and are not independent).
#[derive(Debug, Clone, PartialEq)]
pub struct AllanTest {
    pub accelerometer: usize,
    pub cluster_samples: usize,
    pub cluster_s: f64,
    /// The F ratio: `m var(cluster means) / var(within clusters)`, 1 for white noise.
    pub ratio: f64,
    /// Degrees of freedom of the numerator (cluster means less step means).
    pub differences: usize,
    pub p_value: f64,
    /// Standard deviation of the cluster means in excess of white noise, input-referred, m/s^2.
    pub excess_adev_m_s2: f64,
}

/// The correlated-noise tests of every accelerometer at cluster sizes of 10, 50 and 200 samples
/// (those that fit at least twice in a step).
///
/// Deterministic regressors that vary within a step are tried first: each accelerometer's
/// samples are cleared of their pooled within-step regression on time and (with a temperature
/// column) temperature, each taken about its step mean, before the scatter that is left is tested.
/// A bias that follows the temperature within steps is then the deterministic loop's
/// `bias_temperature`, not correlated noise. The removed regressors vary slowly within a step, so
/// they are charged to the numerator's degrees of freedom.
pub fn allan_tests(log: &CalibrationLog, k: &[f64]) -> Vec<AllanTest> {
    let n = log.n;
    let mut out = Vec::new();
    for (j, kj) in k.iter().enumerate().take(n) {
        let (cleared, removed) = within_step_deterministic_removed(log, j, *kj);
        for m in [10usize, 50, 200] {
            let (mut between, mut within) = (0.0, 0.0);
            let (mut df1, mut df2) = (0usize, 0usize);
            let mut dt = 0.0;
            for (step_index, s) in log.steps.iter().enumerate() {
                let samples = s.samples();
                let clusters = samples / m;
                if clusters < 2 {
                    continue;
                }
                if samples > 1 {
                    dt = (s.t_s[samples - 1] - s.t_s[0]) / (samples - 1) as f64;
                }
                let x = &cleared[step_index][..clusters * m];
                let means: Vec<f64> = x.chunks_exact(m).map(|c| c.iter().sum::<f64>() / m as f64).collect();
                let grand = means.iter().sum::<f64>() / clusters as f64;
                between += means.iter().map(|c| m as f64 * (c - grand).powi(2)).sum::<f64>();
                within += x
                    .chunks_exact(m)
                    .zip(&means)
                    .map(|(c, mu)| c.iter().map(|v| (v - mu).powi(2)).sum::<f64>())
                    .sum::<f64>();
                df1 += clusters - 1;
                df2 += clusters * (m - 1);
            }
            // The deterministic regressors' parameters come out of the cluster means.
            df1 -= removed.min(df1);
            if df1 < 10 || df2 == 0 || within <= 0.0 {
                continue;
            }
            let (mb, mw) = (between / df1 as f64, within / df2 as f64);
            let ratio = mb / mw;
            let p_value = f_sf(ratio, df1 as f64, df2 as f64).unwrap_or(f64::NAN);
            out.push(AllanTest {
                accelerometer: j,
                cluster_samples: m,
                cluster_s: m as f64 * dt,
                ratio,
                differences: df1,
                p_value,
                excess_adev_m_s2: ((mb - mw) / m as f64).max(0.0).sqrt(),
            });
        }
    }
    out
}

/// Accelerometer `j`'s input-referred samples (outputs over `k`) of every step, cleared of their
/// pooled within-step least-squares regression on time and temperature (each about its step
/// mean; regressors that never vary within a step are left out), and how many regressors were
/// removed.
fn within_step_deterministic_removed(log: &CalibrationLog, j: usize, k: f64) -> (Vec<Vec<f64>>, usize) {
    let n = log.n;
    let centred = |v: &[f64]| -> Vec<f64> {
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        v.iter().map(|x| x - mean).collect()
    };
    let x: Vec<Vec<f64>> =
        log.steps.iter().map(|s| (0..s.samples()).map(|i| s.outputs[i * n + j] / k).collect()).collect();
    let mut regressors: Vec<Vec<Vec<f64>>> = vec![log.steps.iter().map(|s| centred(&s.t_s)).collect()];
    if log.has_temperature() {
        regressors.push(log.steps.iter().map(|s| centred(&s.temp_c)).collect());
    }
    // Keep the regressors that vary within steps, and only those the others do not already span.
    let mut kept: Vec<Vec<Vec<f64>>> = Vec::new();
    for r in regressors {
        let energy: f64 = r.iter().flatten().map(|v| v * v).sum();
        if energy.is_nan() || energy <= 0.0 {
            continue;
        }
        kept.push(r);
        let p = kept.len();
        let gram = DMatrix::from_fn(p, p, |a, b| {
            kept[a].iter().flatten().zip(kept[b].iter().flatten()).map(|(u, v)| u * v).sum::<f64>()
        });
        let sv = gram.singular_values();
        if sv.min() <= 1e-10 * sv.max() {
            kept.pop();
        }
    }
    let p = kept.len();
    if p == 0 {
        return (x, 0);
    }
    let gram = DMatrix::from_fn(p, p, |a, b| {
        kept[a].iter().flatten().zip(kept[b].iter().flatten()).map(|(u, v)| u * v).sum::<f64>()
    });
    let rhs =
        DVector::from_fn(p, |a, _| kept[a].iter().flatten().zip(x.iter().flatten()).map(|(u, v)| u * v).sum::<f64>());
    let Some(beta) = gram.lu().solve(&rhs) else { return (x, 0) };
    let cleared = x
        .iter()
        .enumerate()
        .map(|(s, xs)| {
            xs.iter().enumerate().map(|(i, v)| v - (0..p).map(|a| beta[a] * kept[a][s][i]).sum::<f64>()).collect()
        })
        .collect();
    (cleared, p)
}
