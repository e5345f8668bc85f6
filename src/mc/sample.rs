//! Error-parameter distributions and the sampling of one true parameter set.
//!
//! Each kind of parameter has a distribution in display units: bias in mg, scale factor as a
//! deviation from the nominal in ppm, misalignment in deg (the two angles of the configured form),
//! location error in mm (each axis). `normal` (mean, sigma), `uniform` (mean +- half_width) or
//! `fixed` (value); each of mean, sigma, half_width and value is one number for every
//! accelerometer or one per accelerometer.

use nalgebra::DVector;
use rand::Rng;
use rand_distr::{Distribution, Normal, Uniform};

use crate::calib::params::{Layout, PER_ACCEL};

/// A distribution of one kind of parameter, SI; `mean`, `sigma` and `half_width` hold one value
/// per accelerometer.
#[derive(Debug, Clone, PartialEq)]
pub enum Dist {
    Normal {
        mean: Vec<f64>,
        sigma: Vec<f64>,
    },
    Uniform {
        mean: Vec<f64>,
        half_width: Vec<f64>,
    },
    /// Values per accelerometer and component (row j: its components).
    Fixed(Vec<Vec<f64>>),
}

impl Dist {
    fn draw<R: Rng + ?Sized>(&self, rng: &mut R, j: usize, c: usize) -> f64 {
        match self {
            Dist::Normal { mean, sigma } => {
                let (m, s) = (mean[j], sigma[j]);
                if s > 0.0 { Normal::new(m, s).map(|d| d.sample(rng)).unwrap_or(m) } else { m }
            }
            Dist::Uniform { mean, half_width } => {
                let (m, h) = (mean[j], half_width[j]);
                if h > 0.0 { Uniform::new(m - h, m + h).map(|d| d.sample(rng)).unwrap_or(m) } else { m }
            }
            Dist::Fixed(v) => v[j][c],
        }
    }

    /// Standard deviation for accelerometer `j` (0 for fixed values), SI.
    pub fn sigma(&self, j: usize) -> f64 {
        match self {
            Dist::Normal { sigma, .. } => sigma[j],
            Dist::Uniform { half_width, .. } => half_width[j] / 3f64.sqrt(),
            Dist::Fixed(_) => 0.0,
        }
    }
}

/// The distributions of a true error set.
#[derive(Debug, Clone, PartialEq)]
pub struct ErrorModel {
    /// Nominal (design) scale factors.
    pub nominal_scale_factor: Vec<f64>,
    pub bias_m_s2: Dist,
    /// Relative deviation of the scale factor from nominal (1 = 100%).
    pub scale_factor_rel: Dist,
    pub misalignment_rad: Dist,
    pub location_m: Dist,
}

impl ErrorModel {
    /// Draws a true parameter vector in the layout's form. The draw order is fixed (accelerometer
    /// by accelerometer: scale factor, bias, two angles, three location components).
    pub fn sample<R: Rng + ?Sized>(&self, layout: &Layout, rng: &mut R) -> DVector<f64> {
        let n = layout.array().len();
        let mut x = DVector::zeros(layout.len());
        for j in 0..n {
            let o = PER_ACCEL * j;
            x[o] = self.nominal_scale_factor[j] * (1.0 + self.scale_factor_rel.draw(rng, j, 0));
            x[o + 1] = self.bias_m_s2.draw(rng, j, 0);
            x[o + 2] = self.misalignment_rad.draw(rng, j, 0);
            x[o + 3] = self.misalignment_rad.draw(rng, j, 1);
            for c in 0..3 {
                x[o + 4 + c] = self.location_m.draw(rng, j, c);
            }
        }
        x
    }
}
