//! The `[noise]` section: the same noise levels for every accelerometer, input-referred.
//!
//! ```toml
//! [noise]
//! seed = 1                                  # the noise stream (same seed, same noise)
//! white_density_ug_per_sqrt_hz = 50.0       # or: white_sigma_mg and white_sample_rate_hz
//! gauss_markov_sigma_ug = 10.0              # bias instability, first-order Gauss-Markov
//! gauss_markov_correlation_time_s = 100.0
//! random_walk_ug_per_sqrt_s = 1.0           # bias random walk
//! quantization_ug = 10.0                    # output step, input-referred
//! ```

use serde::Deserialize;

use super::{Bad, finite, positive};
use crate::sensor::noise::{GaussMarkov, NoiseSpec, WhiteNoise};
use crate::units::{M_S2_PER_MG, M_S2_PER_UG};

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSection {
    pub seed: Option<u64>,
    pub white_density_ug_per_sqrt_hz: Option<f64>,
    pub white_sigma_mg: Option<f64>,
    pub white_sample_rate_hz: Option<f64>,
    pub gauss_markov_sigma_ug: Option<f64>,
    pub gauss_markov_correlation_time_s: Option<f64>,
    pub random_walk_ug_per_sqrt_s: Option<f64>,
    pub quantization_ug: Option<f64>,
}

fn non_negative(key: &str, v: f64) -> Result<f64, Bad> {
    if finite(key, v)? >= 0.0 { Ok(v) } else { Err(Bad::new(key, format!("must not be negative, got {v}"))) }
}

impl NoiseSection {
    /// The noise levels in SI and the seed (0 when not given).
    pub fn resolve(&self) -> Result<(NoiseSpec, u64), Bad> {
        let white = match (self.white_density_ug_per_sqrt_hz, self.white_sigma_mg, self.white_sample_rate_hz) {
            (Some(_), Some(_), _) => {
                return Err(Bad::new(
                    "noise.white_sigma_mg",
                    "give either `white_density_ug_per_sqrt_hz` or `white_sigma_mg`, not both",
                ));
            }
            (Some(d), None, None) => WhiteNoise::Density {
                density_m_s2_per_sqrt_hz: non_negative("noise.white_density_ug_per_sqrt_hz", d)? * M_S2_PER_UG,
            },
            (Some(_), None, Some(_)) => {
                return Err(Bad::new("noise.white_sample_rate_hz", "goes with `white_sigma_mg`, not with a density"));
            }
            (None, Some(s), Some(f)) => WhiteNoise::Sigma {
                sigma_m_s2: non_negative("noise.white_sigma_mg", s)? * M_S2_PER_MG,
                sample_rate_hz: positive("noise.white_sample_rate_hz", f)?,
            },
            (None, Some(_), None) => {
                return Err(Bad::new(
                    "noise.white_sample_rate_hz",
                    "a per-sample sigma needs the sample rate it was measured at",
                ));
            }
            (None, None, Some(_)) => {
                return Err(Bad::new("noise.white_sample_rate_hz", "goes with `white_sigma_mg`"));
            }
            (None, None, None) => WhiteNoise::None,
        };
        let gauss_markov = match (self.gauss_markov_sigma_ug, self.gauss_markov_correlation_time_s) {
            (Some(s), Some(t)) => Some(GaussMarkov {
                sigma_m_s2: non_negative("noise.gauss_markov_sigma_ug", s)? * M_S2_PER_UG,
                correlation_time_s: positive("noise.gauss_markov_correlation_time_s", t)?,
            }),
            (None, None) => None,
            (Some(_), None) => {
                return Err(Bad::new("noise.gauss_markov_correlation_time_s", "needed with `gauss_markov_sigma_ug`"));
            }
            (None, Some(_)) => {
                return Err(Bad::new("noise.gauss_markov_sigma_ug", "needed with `gauss_markov_correlation_time_s`"));
            }
        };
        let spec = NoiseSpec {
            white,
            gauss_markov,
            random_walk_m_s2_per_sqrt_s: non_negative(
                "noise.random_walk_ug_per_sqrt_s",
                self.random_walk_ug_per_sqrt_s.unwrap_or(0.0),
            )? * M_S2_PER_UG,
            quantization_m_s2: non_negative("noise.quantization_ug", self.quantization_ug.unwrap_or(0.0))?
                * M_S2_PER_UG,
        };
        Ok((spec, self.seed.unwrap_or(0)))
    }
}
