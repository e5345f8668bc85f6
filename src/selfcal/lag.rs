//! The accelerometers' lag behind the reference gyroscopes (an array file's
//! `accelerometer_lag_ms`, `L`): with `--use-gyro` the rate the fit takes as known must be the rate
//! where the accelerometers sample, `w(t - L)`, not the gyroscopes' `w(t)`.
//!
//! Two readings, in turn:
//! - [`LaggedGyroscopes`]: the gyroscopes' samples interpolated `L` earlier (four-point Lagrange).
//!   Hand-held motion has rate content the host's samples do not resolve (angular vibration at
//!   3-25 Hz, aliased at 62.5 Hz), so this takes only part of the lag's cost: on a simulated
//!   recording of the board 28% of it (`tests/gfcal/gyro_lag.rs`). It is the first pass's rate.
//! - [`rates_behind`]: to first order from the angular acceleration the accelerometers
//!   themselves measure at their instant, `w(t - L) = w(t) - L alpha(t - L) + O(L^2 dalpha/dt)`: the
//!   angular acceleration is a per-sample unknown of the fit, so a first pass gives it, and the
//!   second pass fits with these rates. The error left is `L^2 / 2` times the angular jerk
//!   (about 0.05 rad/s at the board's 1.6 ms) plus `L` times the fitted angular acceleration's
//!   error.

use nalgebra::Vector3;

use super::model::SampleMotion;
use super::recording::Recording;

/// The reference rate (bias `bias_rad_s` removed) of each dynamic sample `index[k]` at the
/// accelerometers' instant, `w_gyro - bias - L alpha_k`, from the angular acceleration of
/// `motion[k]` (a fit's, at the accelerometers' instants), `L` the recording's
/// `accelerometer_lag_s`.
pub fn rates_behind(
    rec: &Recording,
    index: &[usize],
    bias_rad_s: &Vector3<f64>,
    motion: &[SampleMotion],
) -> Vec<Vector3<f64>> {
    let lag_s = rec.accelerometer_lag_s;
    index.iter().zip(motion).map(|(&i, m)| rec.gyro_rate_rad_s[i] - bias_rad_s - m.alpha_rad_s2 * lag_s).collect()
}

/// The reference gyroscopes' rate at `t - accelerometer_lag_s` (where the accelerometers sample),
/// by four-point (cubic) Lagrange interpolation on the host's median step: four samples, so that
/// a gyroscope's rail spoils few neighbours. A sample whose four read a railed gyroscope keeps the
/// rate at its own instant (as without a lag); a railed sample itself is dropped as before.
pub(super) struct LaggedGyroscopes {
    /// The lag in host steps.
    steps: f64,
}

impl LaggedGyroscopes {
    /// `None` without gyroscopes, without a lag, or without a host step.
    pub(super) fn new(rec: &Recording) -> Option<Self> {
        if rec.accelerometer_lag_s == 0.0 || rec.gyro_rate_rad_s.is_empty() {
            return None;
        }
        let dt = super::timing::host_dt_s(&rec.t_s)?;
        Some(Self { steps: rec.accelerometer_lag_s / dt })
    }

    /// The rate at sample `i` less the lag (the rate at `i` where the four samples it reads run
    /// off the recording or include a rail).
    pub(super) fn rate_rad_s(&self, rec: &Recording, i: usize) -> Vector3<f64> {
        let position = i as f64 - self.steps;
        let base = position.floor();
        let u = position - base;
        let first = base as i64 - 1;
        let len = rec.gyro_rate_rad_s.len() as i64;
        if first < 0 || first + 3 >= len {
            return rec.gyro_rate_rad_s[i];
        }
        let first = first as usize;
        if rec.gyro_clipped[first..first + 4].iter().any(|&c| c) {
            return rec.gyro_rate_rad_s[i];
        }
        let w = [
            -u * (u - 1.0) * (u - 2.0) / 6.0,
            (u + 1.0) * (u - 1.0) * (u - 2.0) / 2.0,
            -(u + 1.0) * u * (u - 2.0) / 2.0,
            (u + 1.0) * u * (u - 1.0) / 6.0,
        ];
        (0..4).map(|k| rec.gyro_rate_rad_s[first + k] * w[k]).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// A recording of `rows` samples 16 ms apart whose gyroscopes read a smooth rate (two
    /// sinusoids and a ramp), with the accelerometers `lag_s` behind them.
    fn recording(rows: usize, lag_s: f64) -> (Recording, impl Fn(f64) -> Vector3<f64>) {
        let rate = |t: f64| {
            let w = 2.0 * std::f64::consts::PI * 5.0;
            Vector3::new(20.0 * (w * t).sin(), 15.0 * (0.6 * w * t).cos(), 3.0 * t)
        };
        let t_s: Vec<f64> = (0..rows).map(|i| 0.016 * i as f64).collect();
        let rec = Recording {
            path: "lagged".into(),
            gyro_rate_rad_s: t_s.iter().map(|&t| rate(t)).collect(),
            gyro_clipped: vec![false; rows],
            t_s,
            outputs: DMatrix::zeros(rows, 1),
            clipped: vec![false; rows],
            step: None,
            package_gyro_rate_rad_s: Vec::new(),
            accelerometer_lag_s: lag_s,
        };
        (rec, rate)
    }

    /// The lagged rate against the closed form at `t - lag` (5 Hz at 62.5 Hz: four-point
    /// Lagrange is good to about 1e-3 of the amplitude, 20 rad/s, there), for lags within a step and beyond
    /// one; a sample whose four neighbours include a rail keeps its own rate; no lag, no copy.
    #[test]
    fn the_gyroscopes_are_read_lag_earlier_by_four_point_interpolation() {
        for lag_s in [1.6e-3, -0.7e-3, 21e-3] {
            let (rec, rate) = recording(200, lag_s);
            let lagged = LaggedGyroscopes::new(&rec).expect("a lag and gyroscopes");
            for i in 5..195 {
                let want = rate(rec.t_s[i] - lag_s);
                let got = lagged.rate_rad_s(&rec, i);
                assert!((got - want).norm() < 5e-2, "lag {lag_s} s, sample {i}: {got} vs {want}");
            }
            // Without the lag the same samples are a step's worth off: the test can fail.
            let off = (rec.gyro_rate_rad_s[100] - rate(rec.t_s[100] - lag_s)).norm();
            assert!(off > 0.1, "lag {lag_s} s: the undelayed rate is off by {off}");
        }
        let (mut rec, _) = recording(50, 1.6e-3);
        rec.gyro_clipped[20] = true;
        let lagged = LaggedGyroscopes::new(&rec).expect("a lag");
        // Sample 21 reads samples 19-22 (rail at 20): its own rate; sample 23 reads 21-24: lagged.
        assert_eq!(lagged.rate_rad_s(&rec, 21), rec.gyro_rate_rad_s[21]);
        assert_ne!(lagged.rate_rad_s(&rec, 23), rec.gyro_rate_rad_s[23]);
        let (rec, _) = recording(50, 0.0);
        assert!(LaggedGyroscopes::new(&rec).is_none());
    }

    /// The first-order reading against the closed form: a rate of 20 rad/s at 5 Hz (angular
    /// acceleration 630 rad/s^2, angular jerk 2e4 rad/s^3) read 1.6 ms behind with the true
    /// angular acceleration at the accelerometers' instant is within `L^2 / 2` times the angular
    /// jerk (0.025 rad/s) of the rate there, where the gyroscopes' own reading is 1 rad/s off.
    #[test]
    fn the_rate_behind_is_the_rate_at_the_accelerometers_instant_to_first_order() {
        let lag_s = 1.6e-3;
        let (rec, rate) = recording(100, lag_s);
        let w = 2.0 * std::f64::consts::PI * 5.0;
        let alpha = |t: f64| Vector3::new(20.0 * w * (w * t).cos(), -15.0 * 0.6 * w * (0.6 * w * t).sin(), 3.0);
        let index: Vec<usize> = (0..100).collect();
        let motion: Vec<SampleMotion> = index
            .iter()
            .map(|&i| SampleMotion {
                f_m_s2: Vector3::zeros(),
                alpha_rad_s2: alpha(rec.t_s[i] - lag_s),
                omega_rad_s: Vector3::zeros(),
            })
            .collect();
        let bias = Vector3::new(0.1, -0.2, 0.3);
        let mut biased = rec.clone();
        for r in &mut biased.gyro_rate_rad_s {
            *r += bias;
        }
        let behind = rates_behind(&biased, &index, &bias, &motion);
        let bound = 0.5 * lag_s * lag_s * 20.0 * w * w;
        let (mut worst, mut worst_raw) = (0.0_f64, 0.0_f64);
        for (k, &i) in index.iter().enumerate() {
            let want = rate(rec.t_s[i] - lag_s);
            worst = worst.max((behind[k] - want).norm());
            worst_raw = worst_raw.max((rec.gyro_rate_rad_s[i] - want).norm());
        }
        assert!(worst <= 1.05 * bound, "first order: {worst} rad/s against L^2/2 jerk {bound}");
        assert!(worst_raw > 0.9, "the gyroscopes at their own instant are off by {worst_raw}");
    }
}
