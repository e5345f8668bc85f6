//! The packages' anti-alias filters in a calibration: the term a first-order filter before an
//! accelerometer's sampling leaves in a rigid body's outputs, which no rigid motion can carry.
//!
//! **Model.** A filter of time constant `tau` (kernel `h(s) = exp(-s / tau) / tau`, mean `tau`,
//! variance `tau^2`) before accelerometer `j` turns its specific force `q_j(t) = f + alpha x r_j +
//! W(w) r_j` (`W(w) = w w^T - |w|^2 I`) into `h * q_j`. The terms linear in the motion filter into
//! the same terms of the filtered motion (`h * f`, `h * alpha`), which the per-sample motion takes
//! as it is. The centripetal term is quadratic in the rate:
//!
//! ```text
//! h * (w w^T) = w_h w_h^T + C,   C = Cov_h(w) = tau^2 alpha alpha^T + O(tau^3)
//! h * q_j = f_h + alpha_h x r_j + W(w_h) r_j + W(tau alpha) r_j
//! ```
//!
//! (`w_h = h * w`; `C` the rate's covariance over the kernel, exact for a rate that changes at a
//! constant angular acceleration.) The filter adds the centripetal term of a rate `tau alpha`: at
//! 2 ms and 800 rad/s^2 a rate of 1.6 rad/s, `a . W r` about 0.03 m/s^2 at 13 mm, the static noise's
//! size on every sample, and with the same sign. Left out, the fit takes it into the lever arms
//! and the rate: on simulated recordings of the MIMU4444 protocol without vibration or clocks, a
//! 2 ms filter left the locations 6.9 times their sigmas off (1.0 without the filter).
//!
//! **In the fit.** The term is known from the motion and the sensing points, so the outputs are
//! corrected by it at the current fit (`s - k a . W(tau alpha) r`) and refitted, as the clocks'
//! timing term is. Its share of the Jacobian (`tau^2 |alpha|^2` of the centripetal term's, a few
//! tenths of a percent) is left out of the sigmas.

use nalgebra::DMatrix;

use super::model::{SampleMotion, Sensor};
use crate::array::wiring::RecordingArray;

/// Every accelerometer's anti-alias time constant (s) from its package, or `None` where no
/// package declares one (a calibration then runs exactly as without this module).
pub fn accelerometer_time_constants(array: &RecordingArray) -> Option<Vec<f64>> {
    let tau: Vec<f64> =
        array.package_of.iter().map(|p| p.map_or(0.0, |p| array.packages[p].anti_alias_time_constant_s)).collect();
    tau.iter().any(|&t| t > 0.0).then_some(tau)
}

/// The filter's term in one output, output units: `k a . W(tau alpha) r`.
pub fn filter_term(s: &Sensor, m: &SampleMotion, tau_s: f64) -> f64 {
    let v = m.alpha_rad_s2 * tau_s;
    let r = &s.position_m;
    s.k * s.axis.dot(&(v * v.dot(r) - r * v.norm_squared()))
}

/// The dynamic outputs (rows: samples, columns: accelerometers) less the filter's term at the
/// fit's sensors and motion.
pub fn filter_corrected(
    outputs: &DMatrix<f64>,
    sensors: &[Sensor],
    motion: &[SampleMotion],
    tau_s: &[f64],
) -> DMatrix<f64> {
    let mut out = outputs.clone();
    for (i, m) in motion.iter().enumerate().take(out.nrows()) {
        for (j, (s, &tau)) in sensors.iter().zip(tau_s).enumerate() {
            if tau > 0.0 {
                out[(i, j)] -= filter_term(s, m, tau);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// The filter's term against the filter itself: an output of a body turning at a constant
    /// angular acceleration, passed through `y' = (x - y) / tau` by RK4 from rest long enough for
    /// the start to die away, against the model at the filtered motion (`w_h = w - tau alpha`,
    /// the same `alpha` and `f`) plus the term.
    #[test]
    fn the_term_is_what_a_first_order_filter_leaves() {
        let tau = 2e-3;
        let alpha = Vector3::new(1500.0, -800.0, 1200.0);
        let w0 = Vector3::new(-12.0, 20.0, 5.0);
        let s = Sensor {
            k: 1.002,
            b_m_s2: 0.0,
            axis: Vector3::new(0.3, -0.5, 0.8).normalize(),
            daxis: [Vector3::zeros(); 2],
            position_m: Vector3::new(0.0095, -0.0095, 0.001),
        };
        let motion =
            |t: f64| SampleMotion { f_m_s2: Vector3::zeros(), alpha_rad_s2: alpha, omega_rad_s: w0 + alpha * t };
        let x = |t: f64| s.output(&motion(t).specific_force_m_s2(&s.position_m));
        let (t0, t1, h) = (-0.06, 0.0, 1e-6);
        let steps = ((t1 - t0) / h) as usize;
        let mut y = x(t0);
        for k in 0..steps {
            let t = t0 + k as f64 * h;
            let d = |t: f64, y: f64| (x(t) - y) / tau;
            let k1 = d(t, y);
            let k2 = d(t + 0.5 * h, y + 0.5 * h * k1);
            let k3 = d(t + 0.5 * h, y + 0.5 * h * k2);
            let k4 = d(t + h, y + h * k3);
            y += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
        }
        let filtered = SampleMotion { omega_rad_s: w0 - alpha * tau, ..motion(t1) };
        let model = s.output(&filtered.specific_force_m_s2(&s.position_m));
        let term = filter_term(&s, &filtered, tau);
        // The term is a few hundredths of a m/s^2; the start's transient (exp(-30)) and RK4 are far below 1e-9.
        assert!(term.abs() > 0.01, "{term}");
        assert!((y - model - term).abs() < 1e-9, "filtered {y}, model {model}, term {term}");
    }
}
