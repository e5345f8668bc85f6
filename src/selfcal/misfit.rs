//! The rotation phase's misfit: one metric, one name ("rotation-phase chi^2/dof"), for
//! `gfcal calibrate` (the fit's own) and `gfcal diagnose` (the fitting and every held-out
//! recording's gap).
//!
//! For accelerometer `j` with `c_j` used outputs in the rotation phase, residual RMS `r_j` (the
//! output minus the model at each sample's fitted motion) and static noise `sigma_j` (the pooled
//! within-interval standard deviation of one sample):
//!
//! `chi^2/dof = sum_j c_j r_j^2 / sigma_j^2  /  sum_j c_j / L_j`
//!
//! where `L_j = c_j / (c_j - l_j)` is the leverage factor of the per-sample unknowns: every sample
//! spends `k` unknowns on its own motion (9 gyroscope-free: rate, angular acceleration, specific
//! force; 6 with the rate from gyroscopes; plus 3 with the sample clocks' jerk) out of its `m_i`
//! used outputs, so `l_j = sum_i k / m_i` over the samples where `j` is used. A model that
//! explains the rotation phase to the static noise gives 1; the value is how many times the noise
//! variance the model leaves.

use nalgebra::DMatrix;
use rayon::prelude::*;

use super::data::DynamicData;
use super::model::{SampleMotion, SensorSet, sensors};
use crate::array::Array;

/// Unknowns a sample spends on its own motion: 9 gyroscope-free, 6 with the rate from the
/// reference gyroscopes, plus what the data add (the sample clocks' jerk).
pub fn local_unknowns(d: &DynamicData) -> f64 {
    let motion = if d.reference_rate_rad_s.is_some() { 6.0 } else { 9.0 };
    motion + d.extra_unknowns_per_sample as f64
}

/// Per accelerometer, the RMS of the rotation phase's residuals at `motion` (NaN where an
/// accelerometer has no used output), and its count of used outputs.
pub fn residual_rms(
    array: &Array,
    params: &SensorSet,
    d: &DynamicData,
    motion: &[SampleMotion],
) -> (Vec<f64>, Vec<usize>) {
    let sens = sensors(array, params);
    let n = array.len();
    // The accelerometers side by side, each summed over the samples in order.
    let sums: Vec<(f64, usize)> = sens
        .par_iter()
        .enumerate()
        .map(|(j, sn)| {
            let mut s = 0.0;
            let mut c = 0;
            for (i, m) in motion.iter().enumerate().take(d.samples()) {
                if d.used[i * n + j] {
                    s += (d.outputs[(i, j)] - sn.output(&m.specific_force_m_s2(&sn.position_m))).powi(2);
                    c += 1;
                }
            }
            (s, c)
        })
        .collect();
    sums.into_iter().map(|(s, c)| (if c > 0 { (s / c as f64).sqrt() } else { f64::NAN }, c)).unzip()
}

/// Every output's residual (samples x accelerometers; NaN where an output is not used).
pub fn residuals(array: &Array, params: &SensorSet, d: &DynamicData, motion: &[SampleMotion]) -> DMatrix<f64> {
    let sens = sensors(array, params);
    let n = array.len();
    DMatrix::from_fn(d.samples(), n, |i, j| match motion.get(i) {
        Some(m) if d.used[i * n + j] => d.outputs[(i, j)] - sens[j].output(&m.specific_force_m_s2(&sens[j].position_m)),
        _ => f64::NAN,
    })
}

/// The leverage factor `c_j / (c_j - l_j)` of every accelerometer `j` (module docs); infinite
/// where the per-sample unknowns use up its outputs. One pass over the samples, each sample's
/// used outputs counted once.
pub fn leverages(d: &DynamicData, local: f64) -> Vec<f64> {
    let n = d.outputs.ncols();
    let mut count = vec![0.0; n];
    let mut lev = vec![0.0; n];
    for used in d.used.chunks_exact(n.max(1)).take(d.samples()) {
        let m = used.iter().filter(|&&u| u).count() as f64;
        for j in (0..n).filter(|&j| used[j]) {
            count[j] += 1.0;
            lev[j] += local / m;
        }
    }
    count.iter().zip(&lev).map(|(&c, &l)| if c > l { c / (c - l) } else { f64::INFINITY }).collect()
}

/// The rotation-phase chi^2/dof (module docs) from the per-accelerometer residual RMS `rms` and
/// the static noise `sigma` of one sample, m/s^2.
pub fn chi2_dof(d: &DynamicData, rms: &[f64], sigma: &[f64]) -> f64 {
    let n = d.outputs.ncols();
    let mut num = 0.0;
    for j in 0..n {
        let count = (0..d.samples()).filter(|&i| d.used[i * n + j]).count() as f64;
        num += rms[j].powi(2) * count / sigma[j].powi(2);
    }
    num / dof(d, local_unknowns(d))
}

/// The rotation phase's degrees of freedom when every sample spends `local` unknowns on itself:
/// `sum_j c_j / L_j`, the denominator of [`chi2_dof`] (module docs).
pub fn dof(d: &DynamicData, local: f64) -> f64 {
    let n = d.outputs.ncols();
    let leverage = leverages(d, local);
    let mut den = 0.0;
    for (j, l) in leverage.iter().enumerate() {
        let count = (0..d.samples()).filter(|&i| d.used[i * n + j]).count() as f64;
        den += count / l;
    }
    den
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    fn data(samples: usize, n: usize, reference: bool, extra: usize) -> DynamicData {
        DynamicData {
            t_s: (0..samples).map(|i| i as f64 * 0.01).collect(),
            outputs: DMatrix::zeros(samples, n),
            used: vec![true; samples * n],
            run_starts: vec![0],
            reference_rate_rad_s: reference.then(|| vec![nalgebra::Vector3::zeros(); samples]),
            extra_unknowns_per_sample: extra,
        }
    }

    #[test]
    fn the_leverage_of_k_unknowns_among_m_outputs_is_m_over_m_minus_k() {
        // Every sample uses all 24 outputs: l_j = c k / 24, so L = 24 / (24 - k).
        for (reference, extra, k) in [(false, 0, 9.0), (true, 0, 6.0), (false, 3, 12.0)] {
            let d = data(1000, 24, reference, extra);
            assert_eq!(local_unknowns(&d), k);
            let l = leverages(&d, k)[5];
            assert!((l - 24.0 / (24.0 - k)).abs() < 1e-12, "{l}");
        }
    }

    #[test]
    fn each_accelerometers_leverage_counts_the_samples_where_it_is_used() {
        // Outputs dropped in a pattern: sample i uses accelerometer j unless (i + j) % 5 == 0 or
        // (j == 3 and i is even). For each j, l_j = sum over its used samples of k / m_i, written
        // out here sample by sample.
        let (samples, n, k) = (200, 24, 9.0);
        let mut d = data(samples, n, false, 0);
        for i in 0..samples {
            for j in 0..n {
                d.used[i * n + j] = (i + j) % 5 != 0 && !(j == 3 && i % 2 == 0);
            }
        }
        let all = leverages(&d, k);
        for (j, &got) in all.iter().enumerate() {
            let (mut c, mut l) = (0.0, 0.0);
            for i in 0..samples {
                if d.used[i * n + j] {
                    let m = (0..n).filter(|&q| d.used[i * n + q]).count() as f64;
                    c += 1.0;
                    l += k / m;
                }
            }
            assert!((got - c / (c - l)).abs() < 1e-12 * got, "accelerometer {j}: {got} vs {}", c / (c - l));
        }
        // Accelerometer 3 is used on half the samples a fifth of which drop it again: fewer than
        // the others.
        assert!(all[3] != all[4]);
        // Unknowns that use up an accelerometer's outputs: infinite.
        assert!(leverages(&d, 24.0).iter().all(|l| l.is_infinite()));
    }

    #[test]
    fn residuals_of_the_noise_alone_with_the_motion_fitted_give_one() {
        // Residual variance (m - k)/m of the noise's (what least squares leaves of white noise
        // after k unknowns a sample) is chi^2/dof 1, whatever each axis's noise.
        let d = data(500, 24, false, 0);
        let sigma: Vec<f64> = (0..24).map(|j| 0.01 * (1.0 + j as f64)).collect();
        let rms: Vec<f64> = sigma.iter().map(|s| s * ((24.0 - 9.0) / 24.0_f64).sqrt()).collect();
        assert!((chi2_dof(&d, &rms, &sigma) - 1.0).abs() < 1e-12);
        // Twice the noise's variance reads 2.
        let rms2: Vec<f64> = rms.iter().map(|r| r * 2.0_f64.sqrt()).collect();
        assert!((chi2_dof(&d, &rms2, &sigma) - 2.0).abs() < 1e-12);
    }
}
