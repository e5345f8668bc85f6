//! Error-parameter distributions and the sampling of one true parameter set.
//!
//! Each kind of parameter has a distribution in display units: bias in mg, scale factor as a
//! deviation from the nominal in ppm, misalignment in deg (the two angles of the configured form),
//! location error in mm (each axis). `normal` (mean, sigma), `uniform` (mean +- half_width) or
//! `fixed` (value); each of mean, sigma, half_width and value is one number for every
//! accelerometer or one per accelerometer.

use nalgebra::DVector;
use rand::{Rng, RngExt};
use rand_distr::{Distribution, Normal, Uniform};
use statrs::distribution::{ContinuousCDF, Normal as StdNormal};

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

    /// The value at probability `u` in (0, 1) for accelerometer `j`, component `c` (the inverse
    /// of the distribution function; a fixed value whatever `u`).
    fn quantile(&self, u: f64, j: usize, c: usize) -> f64 {
        match self {
            Dist::Normal { mean, sigma } => {
                let z = StdNormal::standard().inverse_cdf(u.clamp(1e-15, 1.0 - 1e-15));
                mean[j] + sigma[j] * z
            }
            Dist::Uniform { mean, half_width } => mean[j] + half_width[j] * (2.0 * u - 1.0),
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

/// The Saltelli design of a cell (first-order and total Sobol' indices of the varying error
/// parameters): `base_samples` blocks of `inputs.len() + 2` consecutive trials. In block `j`,
/// row 0 draws every input from matrix A, row 1 from matrix B, and row `2 + i` from A except
/// input `i`, taken from B. A and B are independent uniform draws mapped through each
/// parameter's distribution, from the stream of block `j` (`trial_rng(seed ^ SALTELLI_SALT,
/// first_trial + j)`), so the design does not depend on threads or shards.
#[derive(Debug, Clone, PartialEq)]
pub struct Saltelli {
    pub base_samples: u64,
    /// Indices (in the layout) of the parameters that vary: the inputs.
    pub inputs: Vec<usize>,
    /// Trial id of the cell's first trial.
    pub first_trial: u64,
}

/// Salt of the Saltelli design's streams.
pub const SALTELLI_SALT: u64 = 0x7361_6c74_656c_6c69;

/// A row's matrix in the Saltelli design.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SaltelliRow {
    A,
    B,
    /// A with input `i` (index into [`Saltelli::inputs`]) from B.
    AB(usize),
}

impl Saltelli {
    pub fn rows_per_sample(&self) -> u64 {
        self.inputs.len() as u64 + 2
    }

    /// Base sample and row of trial `trial` (of this cell).
    pub fn role(&self, trial: u64) -> (u64, SaltelliRow) {
        let local = trial - self.first_trial;
        let (j, r) = (local / self.rows_per_sample(), (local % self.rows_per_sample()) as usize);
        (
            j,
            match r {
                0 => SaltelliRow::A,
                1 => SaltelliRow::B,
                _ => SaltelliRow::AB(r - 2),
            },
        )
    }

    /// The stream of a trial's noise (calibration and navigation): the trial of its block's A
    /// row for A and AB rows, its own for the B row. An AB row then differs from its A row only
    /// in input `i`, and the noise is one more input of the design (held, never swapped), so it
    /// does not leak into every input's total index.
    pub fn noise_stream(&self, trial: u64) -> u64 {
        let (j, row) = self.role(trial);
        self.first_trial + j * self.rows_per_sample() + u64::from(row == SaltelliRow::B)
    }

    /// The true parameters of trial `trial` of the cell under master seed `seed`.
    pub fn sample(&self, errors: &ErrorModel, layout: &Layout, seed: u64, trial: u64) -> DVector<f64> {
        let (j, row) = self.role(trial);
        let mut rng = crate::rng::trial_rng(seed ^ SALTELLI_SALT, self.first_trial + j);
        let d = self.inputs.len();
        let ab: Vec<f64> = (0..2 * d).map(|_| rng.random::<f64>()).collect();
        let (a, b) = ab.split_at(d);
        let u: Vec<f64> = (0..d)
            .map(|k| match row {
                SaltelliRow::A => a[k],
                SaltelliRow::B => b[k],
                SaltelliRow::AB(i) => {
                    if i == k {
                        b[k]
                    } else {
                        a[k]
                    }
                }
            })
            .collect();
        errors.at(layout, |i| self.inputs.iter().position(|&p| p == i).map(|k| u[k]))
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

    /// Indices (in the layout) of the parameters whose distribution is not a single value.
    pub fn varying(&self, layout: &Layout) -> Vec<usize> {
        let mut out = Vec::new();
        for j in 0..layout.array().len() {
            let o = PER_ACCEL * j;
            let spread = [
                self.scale_factor_rel.sigma(j),
                self.bias_m_s2.sigma(j),
                self.misalignment_rad.sigma(j),
                self.misalignment_rad.sigma(j),
                self.location_m.sigma(j),
                self.location_m.sigma(j),
                self.location_m.sigma(j),
            ];
            out.extend((0..PER_ACCEL).filter(|&a| spread[a] > 0.0).map(|a| o + a));
        }
        out
    }

    /// The parameter vector with parameter `i` at probability `u(i)` of its distribution, or at
    /// its centre (mean or fixed value) where `u(i)` is `None`.
    pub fn at(&self, layout: &Layout, u: impl Fn(usize) -> Option<f64>) -> DVector<f64> {
        let n = layout.array().len();
        let mut x = DVector::zeros(layout.len());
        for j in 0..n {
            let o = PER_ACCEL * j;
            let p = |a: usize| u(o + a).unwrap_or(0.5);
            x[o] = self.nominal_scale_factor[j] * (1.0 + self.scale_factor_rel.quantile(p(0), j, 0));
            x[o + 1] = self.bias_m_s2.quantile(p(1), j, 0);
            x[o + 2] = self.misalignment_rad.quantile(p(2), j, 0);
            x[o + 3] = self.misalignment_rad.quantile(p(3), j, 1);
            for c in 0..3 {
                x[o + 4 + c] = self.location_m.quantile(p(4 + c), j, c);
            }
        }
        x
    }
}
