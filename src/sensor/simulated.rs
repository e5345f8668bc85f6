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
        self.begin_step(t_s, h_s);
        for (motion, out) in motions.iter().zip(outputs.iter_mut()) {
            self.outputs_for(motion, out);
        }
    }

    fn outputs_for(&self, motion: &RigidMotion, out: &mut [f64]) {
        self.truth.outputs(self.array, motion, out);
        if let Some((_, _, q_m_s2)) = &self.noise {
            for ((o, s), n) in out.iter_mut().zip(&self.truth.sensors).zip(&self.step_noise_m_s2) {
                *o = quantize(*o + s.scale_factor * n, s.scale_factor.abs() * q_m_s2);
            }
        }
    }
}
