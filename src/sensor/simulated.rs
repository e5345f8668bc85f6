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
    folded: FoldedSensors,
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
            folded: FoldedSensors::default(),
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
            self.folded = FoldedSensors::fold(self.array, self.truth);
        }
        self.begin_step(t_s, h_s);
        for (motion, out) in motions.iter().zip(outputs.iter_mut()) {
            self.folded.outputs(motion, out);
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

/// The accelerometers' true outputs as linear maps of the motion, one array per coefficient (so
/// that the loop over accelerometers runs in packed instructions):
/// `k (b + a . (f0 + alpha x r + w x (w x r))) = k b + (k a) . f0 + (k r x a) . alpha
///  + k ((a . w)(w . r) - |w|^2 a . r)`, with `f0 = a_o - g_b` and `r` the true position.
#[derive(Debug, Clone, Default)]
struct FoldedSensors {
    k: Vec<f64>,
    kb: Vec<f64>,
    k_axis: [Vec<f64>; 3],
    k_r_x_axis: [Vec<f64>; 3],
    axis: [Vec<f64>; 3],
    r: [Vec<f64>; 3],
    axis_r: Vec<f64>,
}

impl FoldedSensors {
    fn is_empty(&self) -> bool {
        self.k.is_empty()
    }

    fn fold(array: &Array, truth: &ArrayParams) -> Self {
        let mut f = Self::default();
        for (s, a) in truth.sensors.iter().zip(array.accelerometers()) {
            let r = a.position_m + s.location_error_m;
            let k = s.scale_factor;
            let (k_axis, k_r_x_axis) = (s.axis * k, r.cross(&s.axis) * k);
            f.k.push(k);
            f.kb.push(k * s.bias_m_s2);
            for c in 0..3 {
                f.k_axis[c].push(k_axis[c]);
                f.k_r_x_axis[c].push(k_r_x_axis[c]);
                f.axis[c].push(s.axis[c]);
                f.r[c].push(r[c]);
            }
            f.axis_r.push(s.axis.dot(&r));
        }
        f
    }

    /// The noise-free outputs for `motion`.
    #[inline]
    fn outputs(&self, motion: &RigidMotion, out: &mut [f64]) {
        let f0 = motion.accel_b_m_s2 - motion.gravity_b_m_s2;
        let (w, al) = (&motion.omega_b_rad_s, &motion.alpha_b_rad_s2);
        let w2 = w.norm_squared();
        let n = out.len().min(self.k.len());
        let (out, k, kb, axis_r) = (&mut out[..n], &self.k[..n], &self.kb[..n], &self.axis_r[..n]);
        let [ka0, ka1, ka2] = [&self.k_axis[0][..n], &self.k_axis[1][..n], &self.k_axis[2][..n]];
        let [kr0, kr1, kr2] = [&self.k_r_x_axis[0][..n], &self.k_r_x_axis[1][..n], &self.k_r_x_axis[2][..n]];
        let [a0, a1, a2] = [&self.axis[0][..n], &self.axis[1][..n], &self.axis[2][..n]];
        let [r0, r1, r2] = [&self.r[0][..n], &self.r[1][..n], &self.r[2][..n]];
        for j in 0..n {
            // Dot products in nalgebra's order, `(a0 b0 + a1 b1) + a2 b2`.
            let k_axis_f0 = ka0[j] * f0.x + ka1[j] * f0.y + ka2[j] * f0.z;
            let k_r_x_axis_alpha = kr0[j] * al.x + kr1[j] * al.y + kr2[j] * al.z;
            let axis_w = a0[j] * w.x + a1[j] * w.y + a2[j] * w.z;
            let r_w = r0[j] * w.x + r1[j] * w.y + r2[j] * w.z;
            out[j] = kb[j] + k_axis_f0 + k_r_x_axis_alpha + k[j] * (axis_w * r_w - w2 * axis_r[j]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav::Trajectory;
    use rand::{RngExt, SeedableRng};

    /// `fill_step`'s folded outputs against `ArrayParams::outputs` (the specific force at each
    /// true position, dotted with the true axis), on random parameters and motions.
    #[test]
    fn folded_outputs_agree_with_the_specific_force_form() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let cube = Array::cube(0.1).expect("cube");
        let trajectory = Trajectory::paper_manoeuvre(1.0);
        for _ in 0..100 {
            let truth = crate::sensor::params::random_params(&cube, &mut rng);
            let mut v = |s: f64| Vector3::from_fn(|_, _| rng.random_range(-s..s));
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
