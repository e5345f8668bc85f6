//! Noise models against their closed-form statistics.

use approx::assert_relative_eq;
use gfcal::sensor::ArrayParams;
use gfcal::sensor::noise::{GaussMarkov, NoiseGenerator, NoiseSpec, WhiteNoise, quantize};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn series(spec: &NoiseSpec, rate_hz: f64, n: usize, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut g = NoiseGenerator::new(spec, 1, rate_hz, &mut rng);
    (0..n).map(|_| g.next_m_s2(&mut rng, 0)).collect()
}

fn mean_var(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (m, x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0))
}

#[test]
fn white_noise_density_and_sigma_forms_agree() {
    let d = WhiteNoise::Density { density_m_s2_per_sqrt_hz: 1e-3 };
    assert_relative_eq!(d.sigma_m_s2(100.0), 1e-2, max_relative = 1e-15);
    // 0.02 m/s^2 per sample at 400 Hz is 0.01 m/s^2 per sample at 100 Hz.
    let s = WhiteNoise::Sigma { sigma_m_s2: 0.02, sample_rate_hz: 400.0 };
    assert_relative_eq!(s.sigma_m_s2(100.0), 0.01, max_relative = 1e-15);
}

#[test]
fn white_noise_has_its_sigma_and_allan_deviation() {
    let density = 2e-3;
    let rate_hz = 100.0;
    let spec = NoiseSpec { white: WhiteNoise::Density { density_m_s2_per_sqrt_hz: density }, ..NoiseSpec::default() };
    let x = series(&spec, rate_hz, 200_000, 1);
    let (m, v) = mean_var(&x);
    let sigma = density * rate_hz.sqrt();
    assert!(m.abs() < 5.0 * sigma / (x.len() as f64).sqrt());
    assert_relative_eq!(v.sqrt(), sigma, max_relative = 0.01); // sd of the estimate: 0.16%
    // Allan variance at tau = m / f for white noise: N^2 / tau.
    let cluster = 100;
    let means: Vec<f64> = x.chunks_exact(cluster).map(|c| c.iter().sum::<f64>() / cluster as f64).collect();
    let avar = means.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>() / (2.0 * (means.len() - 1) as f64);
    let tau = cluster as f64 / rate_hz;
    assert_relative_eq!(avar, density * density / tau, max_relative = 0.1); // 2000 clusters: sd 3%
}

#[test]
fn gauss_markov_has_its_variance_and_correlation() {
    let (sigma, tau, rate_hz) = (1e-3, 0.1, 100.0);
    let spec = NoiseSpec {
        gauss_markov: Some(GaussMarkov { sigma_m_s2: sigma, correlation_time_s: tau }),
        ..NoiseSpec::default()
    };
    let x = series(&spec, rate_hz, 400_000, 2);
    let (_, v) = mean_var(&x);
    assert_relative_eq!(v, sigma * sigma, max_relative = 0.04); // ~20,000 correlation times: sd 1%
    let lag1 = x.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (x.len() - 1) as f64 / v;
    assert_relative_eq!(lag1, (-1.0 / (rate_hz * tau)).exp(), epsilon = 0.005);
}

#[test]
fn random_walk_variance_grows_as_q2_t() {
    let (q, rate_hz, steps) = (1e-4, 100.0, 400);
    let spec = NoiseSpec { random_walk_m_s2_per_sqrt_s: q, ..NoiseSpec::default() };
    let finals: Vec<f64> = (0..4000).map(|seed| *series(&spec, rate_hz, steps + 1, seed).last().unwrap()).collect();
    let mean_sq = finals.iter().map(|v| v * v).sum::<f64>() / finals.len() as f64;
    let t = steps as f64 / rate_hz;
    assert_relative_eq!(mean_sq, q * q * t, max_relative = 0.1); // sd of the estimate: 2.2%
}

#[test]
fn quantization_rounds_outputs_to_the_scaled_step() {
    let cube = gfcal::array::Array::cube(0.1).unwrap();
    let mut params = ArrayParams::nominal(&cube);
    params.sensors[2].scale_factor = 2.5;
    let q = 0.01;
    let spec = NoiseSpec { quantization_m_s2: q, ..NoiseSpec::default() };
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut g = NoiseGenerator::new(&spec, 6, 100.0, &mut rng);
    let clean = [0.123456, -3.21, 9.80665, 0.004999, -0.005001, 1.0];
    let mut out = clean;
    g.apply(&mut rng, &params, &mut out);
    for (j, (o, c)) in out.iter().zip(&clean).enumerate() {
        let step = params.sensors[j].scale_factor * q;
        assert!((o - c).abs() <= step / 2.0 + 1e-15, "{j}: {o} from {c}");
        assert_relative_eq!((o / step).round() * step, *o, epsilon = 1e-12);
    }
    assert_eq!(quantize(0.3, 0.0), 0.3);
}
