//! Each rotation-phase output's weight in the library's tests after the sample clocks: the
//! calibration's weight over its sample's spread, read from the sample's other outputs.
//!
//! What the clocks leave is a heavy tail in a few violent samples (on the MIMU4444 recordings the
//! worst 1% of the samples carry 53-72% of the residual's squares, `docs/sample-clocks.md`), and a
//! violent sample's outputs are large together. Weighting each output by the inverse of its
//! sample's mean weighted square keeps the information of the quiet samples and lets the violent
//! ones count less, as the inverse variances of the rows would. The sample's own output is left
//! out of its factor, so the weight does not select on the residual the test reads (only
//! approximately: the sample's fitted motion spreads a little of each output's residual into the
//! others, symmetrically, which biases nothing). Keeping only the outputs within the calibration's
//! Huber clip did select, and took out the outputs an effect pushes beyond it (a quadratic scale
//! factor hidden in a simulated clocked recording read 12% of its size;
//! `tests/gfcal/clock_recovery.rs`). The tests' sandwich covariance holds whatever the
//! weights, so the factors change how much the test sees, not whether its sigma is honest.

use nalgebra::DMatrix;

/// The smallest spread a sample is given, relative to the phase's mean weighted square: no
/// output counts more than 4 times its calibration weight (the other outputs' mean square of a
/// quiet sample, about 9 degrees of freedom after the motion's 9 and the timing motion's 6
/// unknowns, is itself uncertain by about half).
pub const SPREAD_FLOOR: f64 = 0.25;

/// Per output (samples x accelerometers, the shape of `residuals`), the factor on its weight:
/// `1 / max(v, SPREAD_FLOOR)`, with `v` the mean over the sample's other used outputs of
/// `weights[k] r_k^2`, over that mean across every used output of the phase. 1 where the sample
/// has no other used output or the phase has no spread. `used` is row-major like `residuals`;
/// outputs not used (or not finite) take no part.
pub fn other_outputs_factors(residuals: &DMatrix<f64>, used: &[bool], weights: &[f64]) -> DMatrix<f64> {
    let (m, n) = residuals.shape();
    let square = |i: usize, k: usize| {
        let e = residuals[(i, k)];
        (used[i * n + k] && e.is_finite()).then(|| weights[k] * e * e)
    };
    let (mut total, mut count) = (0.0, 0usize);
    for i in 0..m {
        for v in (0..n).filter_map(|k| square(i, k)) {
            total += v;
            count += 1;
        }
    }
    let mut out = DMatrix::from_element(m, n, 1.0);
    if count == 0 || !total.is_finite() || total <= 0.0 {
        return out;
    }
    let mean = total / count as f64;
    for i in 0..m {
        let squares: Vec<Option<f64>> = (0..n).map(|k| square(i, k)).collect();
        let (sum, used_here) = squares.iter().flatten().fold((0.0, 0usize), |(s, c), v| (s + v, c + 1));
        for (j, own) in squares.iter().enumerate() {
            let (s, c) = match own {
                Some(v) => (sum - v, used_here - 1),
                None => (sum, used_here),
            };
            if c > 0 {
                out[(i, j)] = 1.0 / (s / c as f64 / mean).max(SPREAD_FLOOR);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_violent_sample_counts_less_and_no_output_sets_its_own_weight() {
        // Three samples of three outputs, unit weights. Sample 1 is violent (residuals 3); in
        // sample 2 one output alone is large. The phase's mean square: (3 + 27 + 2 + 100) / 9.
        let r = DMatrix::from_row_slice(3, 3, &[1.0, 1.0, 1.0, 3.0, 3.0, 3.0, 1.0, 1.0, 10.0]);
        let used = vec![true; 9];
        let f = other_outputs_factors(&r, &used, &[1.0; 3]);
        let mean: f64 = (3.0 + 27.0 + 2.0 + 100.0) / 9.0;
        let factor = |others_mean_square: f64| 1.0 / (others_mean_square / mean).max(SPREAD_FLOOR);
        assert!((f[(0, 0)] - factor(1.0)).abs() < 1e-15);
        assert!((f[(1, 2)] - factor(9.0)).abs() < 1e-15);
        // The large output's own factor reads the two quiet ones; theirs read it.
        assert!((f[(2, 2)] - factor(1.0)).abs() < 1e-15);
        assert!((f[(2, 0)] - factor(50.5)).abs() < 1e-15);
        // The floor: a quiet sample counts at most 4 times.
        assert_eq!(f[(0, 0)], 1.0 / SPREAD_FLOOR);
        // An output not used takes no part, in its sample or in the phase's mean (values above the
        // floor: counted in the mean, the large output would floor every factor of sample 2).
        let r = DMatrix::from_row_slice(3, 3, &[2.0, 2.0, 2.0, 3.0, 3.0, 3.0, 2.0, 2.0, 10.0]);
        let mut used = vec![true; 9];
        used[8] = false;
        let g = other_outputs_factors(&r, &used, &[1.0; 3]);
        let mean: f64 = (12.0 + 27.0 + 8.0) / 8.0;
        assert!((g[(2, 0)] - mean / 4.0).abs() < 1e-15, "{}", g[(2, 0)]);
        assert!((g[(2, 2)] - mean / 4.0).abs() < 1e-15, "{}", g[(2, 2)]);
        assert!(mean / 4.0 < 1.0 / SPREAD_FLOOR);
    }
}
