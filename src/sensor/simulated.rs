//! A simulated array: true parameters, a trajectory and noise give the outputs at any time.

use nalgebra::Vector3;
use rand::Rng;

use super::noise::{NoiseGenerator, quantize};
use super::params::ArrayParams;
use crate::array::Array;
use crate::motion::RigidMotion;
use crate::nav::navigator::OutputSource;
use crate::nav::trajectory::Trajectory;

/// Outputs of an array with true parameters moving along a trajectory. Noise (when given) is
/// drawn once per navigation step and held over it, as for outputs averaged over the sample
/// interval.
pub struct SimulatedArray<'a, R: Rng> {
    array: &'a Array,
    truth: &'a ArrayParams,
    trajectory: &'a Trajectory,
    gravity_i_m_s2: Vector3<f64>,
    noise: Option<(NoiseGenerator, R, f64)>,
    step_noise_m_s2: Vec<f64>,
    /// The true parameters folded for `fill_step` (built on first use).
    folded: Vec<FoldedSensor>,
    step_mid_s: f64,
}

impl<'a, R: Rng> SimulatedArray<'a, R> {
    pub fn new(
        array: &'a Array,
        truth: &'a ArrayParams,
        trajectory: &'a Trajectory,
        gravity_i_m_s2: Vector3<f64>,
    ) -> Self {
        Self {
            array,
            truth,
            trajectory,
            gravity_i_m_s2,
            noise: None,
            step_noise_m_s2: vec![0.0; array.len()],
            folded: Vec::new(),
            step_mid_s: 0.0,
        }
    }

    /// Adds noise from `generator`, drawing from `rng`; quantization step (input-referred) in m/s^2.
    pub fn with_noise(mut self, generator: NoiseGenerator, rng: R, quantization_m_s2: f64) -> Self {
        self.noise = Some((generator, rng, quantization_m_s2));
        self
    }
}

impl<R: Rng> OutputSource for SimulatedArray<'_, R> {
    fn begin_step(&mut self, t_s: f64, h_s: f64) {
        self.step_mid_s = t_s + 0.5 * h_s;
        if let Some((generator, rng, _)) = &mut self.noise {
            for (j, n) in self.step_noise_m_s2.iter_mut().enumerate() {
                *n = generator.next_m_s2(rng, j);
            }
        }
    }

    fn outputs(&mut self, t_s: f64, out: &mut [f64]) {
        let motion = self.trajectory.truth_in_segment_of(t_s, self.step_mid_s).motion(&self.gravity_i_m_s2);
        self.outputs_for(&motion, out);
    }
}

impl<R: Rng> SimulatedArray<'_, R> {
    /// The outputs of one step of a precomputed grid (the motion at the step's start, midpoint and
    /// end, as `MotionGrid` holds them): the same numbers as `begin_step` then `outputs` at the
    /// three times, without evaluating the trajectory.
    pub fn fill_step(&mut self, motions: &[RigidMotion; 3], t_s: f64, h_s: f64, outputs: &mut [Vec<f64>; 3]) {
        if self.folded.is_empty() {
            self.folded = FoldedSensor::fold(self.array, self.truth);
        }
        self.begin_step(t_s, h_s);
        for (motion, out) in motions.iter().zip(outputs.iter_mut()) {
            let f0 = motion.accel_b_m_s2 - motion.gravity_b_m_s2;
            let w = &motion.omega_b_rad_s;
            let w2 = w.norm_squared();
            for (o, f) in out.iter_mut().zip(&self.folded) {
                *o = f.kb
                    + f.k_axis.dot(&f0)
                    + f.k_r_x_axis.dot(&motion.alpha_b_rad_s2)
                    + f.k * (f.axis.dot(w) * f.r.dot(w) - w2 * f.axis_r);
            }
            self.add_noise(out);
        }
    }

    fn outputs_for(&self, motion: &RigidMotion, out: &mut [f64]) {
        self.truth.outputs(self.array, motion, out);
        self.add_noise(out);
    }

    fn add_noise(&self, out: &mut [f64]) {
        if let Some((_, _, q_m_s2)) = &self.noise {
            for ((o, s), n) in out.iter_mut().zip(&self.truth.sensors).zip(&self.step_noise_m_s2) {
                *o = quantize(*o + s.scale_factor * n, s.scale_factor.abs() * q_m_s2);
            }
        }
    }
}

/// One accelerometer's true output as a linear map of the motion:
/// `k (b + a . (f0 + alpha x r + w x (w x r))) = k b + (k a) . f0 + (k r x a) . alpha
///  + k ((a . w)(w . r) - |w|^2 a . r)`, with `f0 = a_o - g_b` and `r` the true position.
#[derive(Debug, Clone, Copy)]
struct FoldedSensor {
    k: f64,
    kb: f64,
    k_axis: Vector3<f64>,
    k_r_x_axis: Vector3<f64>,
    axis: Vector3<f64>,
    r: Vector3<f64>,
    axis_r: f64,
}

impl FoldedSensor {
    fn fold(array: &Array, truth: &ArrayParams) -> Vec<Self> {
        truth
            .sensors
            .iter()
            .zip(array.accelerometers())
            .map(|(s, a)| {
                let r = a.position_m + s.location_error_m;
                let k = s.scale_factor;
                Self {
                    k,
                    kb: k * s.bias_m_s2,
                    k_axis: s.axis * k,
                    k_r_x_axis: r.cross(&s.axis) * k,
                    axis: s.axis,
                    r,
                    axis_r: s.axis.dot(&r),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav::Trajectory;
    use crate::sensor::SensorParams;
    use rand::{RngExt, SeedableRng};

    /// `fill_step`'s folded outputs against `ArrayParams::outputs` (the specific force at each
    /// true position, dotted with the true axis), on random parameters and motions.
    #[test]
    fn folded_outputs_agree_with_the_specific_force_form() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let cube = Array::cube(0.1).expect("cube");
        let trajectory = Trajectory::paper_manoeuvre(1.0);
        for _ in 0..100 {
            let mut v = |s: f64| Vector3::from_fn(|_, _| rng.random_range(-s..s));
            let sensors = cube
                .accelerometers()
                .iter()
                .map(|a| SensorParams {
                    scale_factor: 1.0 + v(1e-3).x,
                    bias_m_s2: v(0.05).y,
                    axis: (a.axis + v(0.01)).normalize(),
                    location_error_m: v(2e-3),
                })
                .collect();
            let truth = ArrayParams { sensors };
            let motion = |v: &mut dyn FnMut(f64) -> Vector3<f64>| RigidMotion {
                accel_b_m_s2: v(20.0),
                alpha_b_rad_s2: v(5.0),
                omega_b_rad_s: v(10.0),
                gravity_b_m_s2: v(9.8),
            };
            let motions = [motion(&mut v), motion(&mut v), motion(&mut v)];
            let mut sim = SimulatedArray::<rand_chacha::ChaCha8Rng>::new(&cube, &truth, &trajectory, Vector3::zeros());
            let mut got = [vec![0.0; 6], vec![0.0; 6], vec![0.0; 6]];
            sim.fill_step(&motions, 0.0, 0.01, &mut got);
            for (m, g) in motions.iter().zip(&got) {
                let mut want = vec![0.0; 6];
                truth.outputs(&cube, m, &mut want);
                for (a, b) in g.iter().zip(&want) {
                    assert!((a - b).abs() < 1e-12 * (1.0 + b.abs()), "{a} vs {b}");
                }
            }
        }
    }
}
