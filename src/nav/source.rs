//! Where the navigator's outputs come from ([`OutputSource`]), and the simulated array: true
//! parameters, a trajectory and noise give the outputs at any time.

use nalgebra::Vector3;
use rand::Rng;

use super::trajectory::Trajectory;
use crate::array::Array;
use crate::motion::RigidMotion;
use crate::sensor::noise::{NoiseGenerator, quantize};
use crate::sensor::params::ArrayParams;

/// A source of array outputs along the trajectory: `outputs(t, out)` fills the raw outputs at
/// time `t`; `begin_step(t, h)` is called before each step (a noisy source draws its noise there,
/// held over the step).
pub trait OutputSource {
    fn begin_step(&mut self, _t_s: f64, _h_s: f64) {}
    fn outputs(&mut self, t_s: f64, out: &mut [f64]);
}

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
    /// The true parameters one array per quantity, for `fill_step` (built on first use).
    packed: PackedSensors,
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
            packed: PackedSensors::default(),
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
        if self.packed.is_empty() {
            self.packed = PackedSensors::fold(self.array, self.truth);
        }
        self.begin_step(t_s, h_s);
        for (motion, out) in motions.iter().zip(outputs.iter_mut()) {
            self.packed.outputs(motion, out);
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

/// The true parameters one array per quantity, so that the loop over accelerometers runs in
/// packed instructions; the arithmetic is `ArrayParams::outputs`' to the bit:
/// `k (b + a . (((a_o + alpha x r) + w x (w x r)) - g_b))` at the true position `r`.
#[derive(Debug, Clone, Default)]
struct PackedSensors {
    k: Vec<f64>,
    b: Vec<f64>,
    axis: [Vec<f64>; 3],
    r: [Vec<f64>; 3],
}

impl PackedSensors {
    fn is_empty(&self) -> bool {
        self.k.is_empty()
    }

    fn fold(array: &Array, truth: &ArrayParams) -> Self {
        let mut f = Self::default();
        for (r, s) in truth.positions_m(array).iter().zip(&truth.sensors) {
            f.k.push(s.scale_factor);
            f.b.push(s.bias_m_s2);
            for c in 0..3 {
                f.axis[c].push(s.axis[c]);
                f.r[c].push(r[c]);
            }
        }
        f
    }

    /// The noise-free outputs for `motion`.
    #[inline]
    fn outputs(&self, motion: &RigidMotion, out: &mut [f64]) {
        let (ao, al, w, g) =
            (&motion.accel_b_m_s2, &motion.alpha_b_rad_s2, &motion.omega_b_rad_s, &motion.gravity_b_m_s2);
        let n = out.len().min(self.k.len());
        let (out, k, b) = (&mut out[..n], &self.k[..n], &self.b[..n]);
        let [a0, a1, a2] = [&self.axis[0][..n], &self.axis[1][..n], &self.axis[2][..n]];
        let [r0, r1, r2] = [&self.r[0][..n], &self.r[1][..n], &self.r[2][..n]];
        for j in 0..n {
            let r = [r0[j], r1[j], r2[j]];
            // nalgebra's cross and dot products, in their order of operations.
            let cross = |a: [f64; 3], b: [f64; 3]| {
                [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
            };
            let (w, al) = ([w.x, w.y, w.z], [al.x, al.y, al.z]);
            let (alpha_r, w_w_r) = (cross(al, r), cross(w, cross(w, r)));
            let f = [
                ao.x + alpha_r[0] + w_w_r[0] - g.x,
                ao.y + alpha_r[1] + w_w_r[1] - g.y,
                ao.z + alpha_r[2] + w_w_r[2] - g.z,
            ];
            out[j] = k[j] * (b[j] + (a0[j] * f[0] + a1[j] * f[1] + a2[j] * f[2]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav::Trajectory;
    use rand::{RngExt, SeedableRng};

    /// `fill_step`'s outputs against `ArrayParams::outputs` (the specific force at each true
    /// position, dotted with the true axis), bit for bit, on random parameters and motions.
    #[test]
    fn packed_outputs_have_the_bits_of_the_specific_force_form() {
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
                assert_eq!(g, &want);
            }
        }
    }
}
