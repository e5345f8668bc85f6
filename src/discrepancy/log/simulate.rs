//! Simulated calibration logs: true parameters, noise, a schedule, and any effects of the library
//! switched on with their magnitudes (the generator knows them; a fit of the log does not).

use rand::Rng;

use super::data::{CalibrationLog, LogStep};
use crate::array::Array;
use crate::calib::schedule::Schedule;
use crate::discrepancy::effect::{Effect, Scope, TruthSample};
use crate::sensor::noise::{NoiseGenerator, NoiseSpec, quantize};
use crate::sensor::params::ArrayParams;

/// An effect switched on, with its parameters: per accelerometer (owner-major,
/// `values[j * m .. (j + 1) * m]`) or shared (`values[.. m]`), SI.
pub struct ActiveEffect {
    pub effect: Box<dyn Effect>,
    pub values: Vec<f64>,
}

/// A linear temperature ramp over the log, optionally with a sinusoidal wobble (which separates
/// temperature from time), and the reference the effects use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Temperature {
    pub start_c: f64,
    pub end_c: f64,
    pub reference_c: f64,
    /// Amplitude and period of the wobble, deg C and s (0 amplitude: a plain ramp).
    pub wobble_c: f64,
    pub wobble_period_s: f64,
}

impl Temperature {
    /// A plain linear ramp.
    pub fn ramp(start_c: f64, end_c: f64, reference_c: f64) -> Self {
        Self { start_c, end_c, reference_c, wobble_c: 0.0, wobble_period_s: 1.0 }
    }

    /// Temperature at `t_s` of a log lasting `total_s`.
    pub fn at(&self, t_s: f64, total_s: f64) -> f64 {
        let ramp = self.start_c + (self.end_c - self.start_c) * t_s / total_s.max(f64::MIN_POSITIVE);
        ramp + self.wobble_c * (2.0 * std::f64::consts::PI * t_s / self.wobble_period_s).sin()
    }
}

/// What a simulated log is made of.
pub struct LogSimulation<'a> {
    pub array: &'a Array,
    pub truth: &'a ArrayParams,
    pub schedule: &'a Schedule,
    pub noise: NoiseSpec,
    pub effects: &'a [ActiveEffect],
    pub temperature: Option<Temperature>,
    pub g_m_s2: f64,
}

impl LogSimulation<'_> {
    /// The number of parameters per owner of each active effect for this schedule.
    fn counts(&self) -> (usize, usize) {
        let statics = self.schedule.steps().iter().filter(|s| !s.is_spin()).count();
        (statics, self.schedule.len() - statics)
    }

    /// Checks that every active effect has the right number of values.
    pub fn check(&self) -> Result<(), String> {
        let (statics, spins) = self.counts();
        for a in self.effects {
            let m = a.effect.parameters(statics, spins);
            let expected = match a.effect.scope() {
                Scope::PerAccelerometer => m * self.array.len(),
                Scope::Shared => m,
            };
            if a.values.len() != expected {
                return Err(format!("{}: {} values, expected {expected}", a.effect.name(), a.values.len()));
            }
            if a.effect.needs_temperature() && self.temperature.is_none() {
                return Err(format!("{} needs a temperature profile", a.effect.name()));
            }
        }
        Ok(())
    }

    /// Simulates every sample. Steps are numbered from 1; time starts at 0.
    pub fn run<R: Rng + ?Sized>(&self, rng: &mut R) -> CalibrationLog {
        let n = self.array.len();
        let (statics, spins) = self.counts();
        let total_s: f64 = self.schedule.steps().iter().map(|s| s.samples() as f64 / s.sample_rate_hz).sum();
        let rate0 = self.schedule.steps().first().map(|s| s.sample_rate_hz).unwrap_or(1.0);
        let mut generator = NoiseGenerator::new(&self.noise, n, rate0, rng);
        let mut steps = Vec::with_capacity(self.schedule.len());
        let (mut t0, mut static_index, mut spin_index) = (0.0, 0, 0);
        let positions = self.truth.positions_m(self.array);
        for (si, step) in self.schedule.steps().iter().enumerate() {
            generator = generator.at_rate(&self.noise, step.sample_rate_hz);
            let w = step.omega_b_rad_s();
            let up = step.up_b();
            let samples = step.samples();
            let mut log_step = LogStep {
                step: si as i64 + 1,
                up_b: up,
                omega_b_rad_s: w,
                t_s: vec![],
                temp_c: vec![],
                outputs: vec![],
            };
            for i in 0..samples {
                let t = t0 + i as f64 / step.sample_rate_hz;
                let temp_delta = self.temperature.map(|tp| {
                    let temp = tp.at(t, total_s);
                    log_step.temp_c.push(temp);
                    temp - tp.reference_c
                });
                log_step.t_s.push(t);
                for (j, s) in self.truth.sensors.iter().enumerate() {
                    // The effects act on the physical sample (their generators), not through the
                    // terms the diagnosis fits.
                    let mut sample = TruthSample {
                        static_index: (!step.is_spin()).then_some(static_index),
                        spin_index: step.is_spin().then_some(spin_index),
                        t_s: t,
                        temp_delta_c: temp_delta.unwrap_or(0.0),
                        up_b: up,
                        omega_b_rad_s: w,
                        g_m_s2: self.g_m_s2,
                        position_m: positions[j],
                        bias_m_s2: s.bias_m_s2,
                        gain: 1.0,
                        quadratic_per_m_s2: 0.0,
                        cubic_per_m2_s4: 0.0,
                    };
                    for a in self.effects {
                        let m = a.effect.parameters(statics, spins);
                        let p = match a.effect.scope() {
                            Scope::PerAccelerometer => &a.values[j * m..(j + 1) * m],
                            Scope::Shared => &a.values[..m],
                        };
                        a.effect.generate(&mut sample, p);
                    }
                    let k = s.scale_factor;
                    let out = k * (sample.reading_m_s2(&s.axis) + generator.next_m_s2(rng, j));
                    log_step.outputs.push(quantize(out, k.abs() * self.noise.quantization_m_s2));
                }
            }
            t0 += samples as f64 / step.sample_rate_hz;
            if step.is_spin() {
                spin_index += 1;
            } else {
                static_index += 1;
            }
            steps.push(log_step);
        }
        CalibrationLog { n, steps }
    }
}
