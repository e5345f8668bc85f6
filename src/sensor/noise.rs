//! Sensor noise: white noise, bias instability (first-order Gauss-Markov, random walk) and
//! quantization, all input-referred (m/s^2) and scaled by each accelerometer's scale factor.
//!
//! White noise is given as a density `N` (m/s^2/sqrt(Hz), the IEEE velocity-random-walk
//! coefficient) or as a per-sample sigma at a stated sample rate; the per-sample sigma at rate
//! `f` is `N sqrt(f)` (the Allan deviation of white noise is `N / sqrt(tau)`).
//! A Gauss-Markov process with stationary sigma `s` and correlation time `tau` is discretised
//! exactly: `x_{k+1} = e^{-dt/tau} x_k + s sqrt(1 - e^{-2 dt/tau}) w_k`. A random walk with
//! coefficient `q` (m/s^2/sqrt(s)) steps by `q sqrt(dt) w_k`. Quantization rounds the output to
//! steps of `k q_m_s2`.

use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use super::params::ArrayParams;

/// White noise level.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum WhiteNoise {
    #[default]
    None,
    /// Density, m/s^2/sqrt(Hz).
    Density { density_m_s2_per_sqrt_hz: f64 },
    /// Per-sample standard deviation at a sample rate.
    Sigma { sigma_m_s2: f64, sample_rate_hz: f64 },
}

impl WhiteNoise {
    /// Density in m/s^2/sqrt(Hz).
    pub fn density_m_s2_per_sqrt_hz(&self) -> f64 {
        match *self {
            WhiteNoise::None => 0.0,
            WhiteNoise::Density { density_m_s2_per_sqrt_hz } => density_m_s2_per_sqrt_hz,
            WhiteNoise::Sigma { sigma_m_s2, sample_rate_hz } => sigma_m_s2 / sample_rate_hz.sqrt(),
        }
    }
    /// Per-sample standard deviation at `sample_rate_hz`, m/s^2.
    pub fn sigma_m_s2(&self, sample_rate_hz: f64) -> f64 {
        self.density_m_s2_per_sqrt_hz() * sample_rate_hz.sqrt()
    }
}

/// First-order Gauss-Markov bias instability.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GaussMarkov {
    /// Stationary standard deviation, m/s^2.
    pub sigma_m_s2: f64,
    /// Correlation time, s.
    pub correlation_time_s: f64,
}

/// Noise of every accelerometer of an array (the same levels for all).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NoiseSpec {
    pub white: WhiteNoise,
    pub gauss_markov: Option<GaussMarkov>,
    /// Random-walk coefficient, m/s^2/sqrt(s); 0 for none.
    pub random_walk_m_s2_per_sqrt_s: f64,
    /// Quantization step (input-referred), m/s^2; 0 for none.
    pub quantization_m_s2: f64,
}

impl NoiseSpec {
    pub fn is_zero(&self) -> bool {
        self.white.density_m_s2_per_sqrt_hz() == 0.0
            && self.gauss_markov.is_none_or(|g| g.sigma_m_s2 == 0.0)
            && self.random_walk_m_s2_per_sqrt_s == 0.0
            && self.quantization_m_s2 == 0.0
    }
}

/// Generates the noise of an array's outputs sample by sample.
#[derive(Debug, Clone)]
pub struct NoiseGenerator {
    /// The rate the generator steps at.
    sample_rate_hz: f64,
    white_sigma_m_s2: f64,
    gm_phi: f64,
    gm_drive_m_s2: f64,
    rw_step_m_s2: f64,
    quantization_m_s2: f64,
    gm_m_s2: Vec<f64>,
    rw_m_s2: Vec<f64>,
}

impl NoiseGenerator {
    /// A generator for `n` accelerometers sampled at `sample_rate_hz`. Gauss-Markov states start
    /// from their stationary distribution, random walks from zero.
    pub fn new<R: Rng + ?Sized>(spec: &NoiseSpec, n: usize, sample_rate_hz: f64, rng: &mut R) -> Self {
        let dt_s = 1.0 / sample_rate_hz;
        let (gm_phi, gm_sigma) = match spec.gauss_markov {
            Some(g) if g.sigma_m_s2 > 0.0 => ((-dt_s / g.correlation_time_s).exp(), g.sigma_m_s2),
            _ => (0.0, 0.0),
        };
        let gm_m_s2 = (0..n)
            .map(|_| if gm_sigma > 0.0 { gm_sigma * rng.sample::<f64, _>(StandardNormal) } else { 0.0 })
            .collect();
        Self {
            sample_rate_hz,
            white_sigma_m_s2: spec.white.sigma_m_s2(sample_rate_hz),
            gm_phi,
            gm_drive_m_s2: gm_sigma * (1.0 - gm_phi * gm_phi).sqrt(),
            rw_step_m_s2: spec.random_walk_m_s2_per_sqrt_s * dt_s.sqrt(),
            quantization_m_s2: spec.quantization_m_s2,
            gm_m_s2,
            rw_m_s2: vec![0.0; n],
        }
    }

    /// The rate the generator steps at, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        self.sample_rate_hz
    }

    /// The same generator stepping at `sample_rate_hz`, its bias-instability states kept: itself
    /// when it already runs at that rate. Call it at every step of a schedule whose steps may
    /// differ in rate.
    pub fn at_rate(self, spec: &NoiseSpec, sample_rate_hz: f64) -> Self {
        if sample_rate_hz == self.sample_rate_hz { self } else { self.resampled(spec, sample_rate_hz) }
    }

    /// The same generator, its bias-instability states kept, stepping at another sample rate.
    pub fn resampled(mut self, spec: &NoiseSpec, sample_rate_hz: f64) -> Self {
        self.sample_rate_hz = sample_rate_hz;
        let dt_s = 1.0 / sample_rate_hz;
        if let Some(g) = spec.gauss_markov.filter(|g| g.sigma_m_s2 > 0.0) {
            self.gm_phi = (-dt_s / g.correlation_time_s).exp();
            self.gm_drive_m_s2 = g.sigma_m_s2 * (1.0 - self.gm_phi * self.gm_phi).sqrt();
        }
        self.white_sigma_m_s2 = spec.white.sigma_m_s2(sample_rate_hz);
        self.rw_step_m_s2 = spec.random_walk_m_s2_per_sqrt_s * dt_s.sqrt();
        self
    }

    /// The input-referred noise of accelerometer `j` for the next sample (m/s^2), advancing its
    /// bias-instability states.
    pub fn next_m_s2<R: Rng + ?Sized>(&mut self, rng: &mut R, j: usize) -> f64 {
        let mut n = 0.0;
        if self.white_sigma_m_s2 > 0.0 {
            n += self.white_sigma_m_s2 * rng.sample::<f64, _>(StandardNormal);
        }
        if self.gm_drive_m_s2 > 0.0 {
            n += self.gm_m_s2[j];
            self.gm_m_s2[j] = self.gm_phi * self.gm_m_s2[j] + self.gm_drive_m_s2 * rng.sample::<f64, _>(StandardNormal);
        }
        if self.rw_step_m_s2 > 0.0 {
            n += self.rw_m_s2[j];
            self.rw_m_s2[j] += self.rw_step_m_s2 * rng.sample::<f64, _>(StandardNormal);
        }
        n
    }

    /// Adds one sample of noise to noise-free outputs (output units) and quantizes them.
    pub fn apply<R: Rng + ?Sized>(&mut self, rng: &mut R, params: &ArrayParams, outputs: &mut [f64]) {
        for (j, (o, s)) in outputs.iter_mut().zip(&params.sensors).enumerate() {
            *o += s.scale_factor * self.next_m_s2(rng, j);
            *o = quantize(*o, s.scale_factor.abs() * self.quantization_m_s2);
        }
    }
}

/// Rounds `value` to the nearest multiple of `step` (no-op for a zero step).
pub fn quantize(value: f64, step: f64) -> f64 {
    if step > 0.0 { (value / step).round() * step } else { value }
}
