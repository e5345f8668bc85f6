//! A bias drift in time in a simulated recording ([`super::simulate`]): each accelerometer's bias
//! moves linearly in time, `b_j(t) = b_j + (c + d_j) (t - t_mid)`, with `c` common to the
//! recording's accelerometers (a warm-up of the whole board) and `d_j` each one's own, drawn per
//! recording. The drift is taken about the recording's middle `t_mid`, so the truth's bias is the
//! bias at mid-recording, the one a calibration over the whole recording can find. Off by default;
//! the calibration does not model it (as on the real board: `gfcal diagnose` tests for it).

use rand::Rng;

use super::sampling::Spread;

/// The distributions of the accelerometers' bias drift in one recording, m/s^2/s.
#[derive(Debug, Clone, PartialEq)]
pub struct BiasDriftSpread {
    /// Each accelerometer's own drift rate.
    pub own: Spread,
    /// A drift rate common to every accelerometer of a recording.
    pub common: Spread,
}

impl BiasDriftSpread {
    /// One recording's drift rates of `n` accelerometers, m/s^2/s: the common part first, then
    /// each accelerometer's own (in the array file's order).
    pub fn draw<R: Rng + ?Sized>(&self, n: usize, rng: &mut R) -> Vec<f64> {
        let common = self.common.draw(0, rng);
        (0..n).map(|j| common + self.own.draw(j, rng)).collect()
    }
}

/// One recording's drift: the rates and the middle they are taken about.
#[derive(Debug, Clone, PartialEq)]
pub struct BiasDrift {
    rates_m_s2_per_s: Vec<f64>,
    t_mid_s: f64,
}

impl BiasDrift {
    /// `rates_m_s2_per_s` per accelerometer (empty: none) about the middle of the sample times
    /// `t_s` (halfway between the first and the last).
    pub fn new(rates_m_s2_per_s: Vec<f64>, t_s: &[f64]) -> Self {
        let t_mid_s = match (t_s.first(), t_s.last()) {
            (Some(a), Some(b)) => 0.5 * (a + b),
            _ => 0.0,
        };
        Self { rates_m_s2_per_s, t_mid_s }
    }

    /// The drift's part of accelerometer `j`'s output at time `t_s`, m/s^2.
    pub fn m_s2(&self, j: usize, t_s: f64) -> f64 {
        self.rates_m_s2_per_s.get(j).map_or(0.0, |r| r * (t_s - self.t_mid_s))
    }

    /// `output_m_s2` with the drift added; untouched without a drift (not even `-0.0` becomes
    /// `0.0`: a recording without it is the same bits).
    pub fn added(&self, j: usize, t_s: f64, output_m_s2: f64) -> f64 {
        if self.rates_m_s2_per_s.is_empty() { output_m_s2 } else { output_m_s2 + self.m_s2(j, t_s) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::trial_rng;

    /// The drift is zero at mid-recording and grows linearly either side; the draws' mean and
    /// spread are the common and own parts' (100,000 recordings of two accelerometers).
    #[test]
    fn the_drift_is_linear_about_the_middle_and_draws_its_spreads() {
        let f = BiasDrift::new(vec![2.0, -1.0], &[10.0, 12.0, 20.0, 30.0]);
        assert_eq!(f.m_s2(0, 10.0), -20.0);
        assert_eq!(f.m_s2(0, 20.0), 0.0);
        assert_eq!(f.m_s2(1, 30.0), -10.0);
        assert_eq!(f.m_s2(1, 12.0), 8.0);
        assert_eq!(BiasDrift::new(vec![], &[0.0, 1.0]).m_s2(3, 7.0), 0.0);
        let spread = BiasDriftSpread {
            own: Spread::Normal { mean: 0.0, sigma: 3.0 },
            common: Spread::Normal { mean: -1.0, sigma: 2.0 },
        };
        let mut rng = trial_rng(9, 0);
        let n = 100_000;
        let (mut sum, mut sq, mut cross) = ([0.0; 2], [0.0; 2], 0.0);
        for _ in 0..n {
            let r = spread.draw(2, &mut rng);
            for j in 0..2 {
                sum[j] += r[j];
                sq[j] += r[j] * r[j];
            }
            cross += (r[0] + 1.0) * (r[1] + 1.0);
        }
        let nf = n as f64;
        for j in 0..2 {
            let mean = sum[j] / nf;
            let var = sq[j] / nf - mean * mean;
            // Mean -1 (sd of the mean 0.011); variance 4 + 9 = 13 (sd about 0.06).
            assert!((mean + 1.0).abs() < 0.05, "mean {mean}");
            assert!((var - 13.0).abs() < 0.3, "variance {var}");
        }
        // The two accelerometers share the common part: covariance 4 (sd about 0.04).
        assert!((cross / nf - 4.0).abs() < 0.2, "covariance {}", cross / nf);
    }
}
