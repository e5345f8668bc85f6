//! The packages' sample clocks in a calibration: their per-sample time offsets measured by the
//! reference gyroscopes, the jerk that turns an age into an output error, and the outputs
//! corrected to a common instant.
//!
//! **Model.** With the packages' clocks (`selfcal::clock`) an output of accelerometer `j` in
//! package `p` at dynamic sample `i` is
//!
//! ```text
//! s_j = k_j (b_j + a_j . [q_j - tau_p,i (J_i + dalpha_i/dt x r'_j + D_i r'_j)])
//! D_i r = alpha_i (w_i . r) + w_i (alpha_i . r) - 2 (w_i . alpha_i) r
//! ```
//!
//! with `tau_p,i` the package's age less the mean age of the packages at that sample, `J_i` the
//! jerk (the time derivative of the specific force at the origin) and `dalpha_i/dt` the angular
//! jerk: 6 unknowns a sample ([`TIMING_UNKNOWNS_PER_SAMPLE`]). They live at the aliased high
//! frequencies of hand-held motion, so they are not derivatives of the sampled motion (a jerk
//! from differences of the 16 ms samples makes the misfit worse). `D_i r` is the derivative of
//! the centripetal term, known from the motion. The motion is that of the mean instant: the
//! per-sample motion absorbs a shift common to every package. With `--use-gyro` the reference
//! rate is the least-squares combination of every package's gyroscope, each read at its own
//! package's instant; with equal weight per package its instant is the mean instant to first
//! order, which is the instant the motion is referred to.
//!
//! **Gauge.** A change common to every package's clock (its phase, rate or drift) moves every
//! age alike, and the ages enter only relative to their mean: the linearised model does not
//! see it (3 null directions). Only where a package's sawtooth wraps does the common part move
//! the relative ages; the common part is taken from the gyroscopes' sawtooth fit (their own
//! offsets are relative too, but a rising sawtooth of a 1 ms wrap fixes it), and only the
//! relative part is fitted to the accelerometers. Without gyroscopes the outputs are also
//! unchanged by the mirror `age -> period - age` (every rate offset's sign flipped) with the
//! timing motion's sign flipped: a gyroscope-free recording cannot tell a fast clock from a
//! slow one.

use std::ops::Range;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector3, Vector6};

use super::clock::{Offsets, SampleClock, relative_ages};
use super::data::DynamicData;
use super::model::{SampleMotion, Sensor};
use super::recording::Recording;

/// The gyroscopes' measure of every package's time offset in the rotation phase: each package's
/// rate (bias from the static intervals removed, then mapped onto the packages' mean by a 3 x 3
/// least-squares map, which removes its scale and misalignment), less the mean, projected on the
/// angular acceleration (five-point derivative of the mean rate) and divided by its magnitude:
/// `offset_p = -(w_p - w_mean) . alpha / |alpha|^2`, positive when the package is late. Samples
/// whose gyroscopes clip within two samples, or where `|alpha|` is below 100 rad/s^2, are left
/// out; weights `min(|alpha|, 1500)^2` (the offsets' inverse variance up to a constant).
///
/// `dynamic`: the recording's rows of the rotation phase (runs of consecutive rows); `statics`:
/// rows of the static intervals. `None` without a gyroscope in every package.
pub fn gyro_offsets(rec: &Recording, dynamic: &[usize], statics: &[usize]) -> Option<Vec<Offsets>> {
    let packages = rec.package_gyro_rate_rad_s.len();
    if packages < 2 || rec.package_gyro_rate_rad_s.iter().any(Vec::is_empty) || statics.is_empty() {
        return None;
    }
    let dt = host_dt_s(&rec.t_s)?;
    let rates = &rec.package_gyro_rate_rad_s;
    let bias: Vec<Vector3<f64>> =
        rates.iter().map(|r| statics.iter().map(|&i| r[i]).sum::<Vector3<f64>>() / statics.len() as f64).collect();
    let ok = |i: usize| i >= 2 && i + 2 < rec.t_s.len() && (i - 2..=i + 2).all(|k| !rec.gyro_clipped[k]);
    let rows: Vec<usize> = dynamic.iter().copied().filter(|&i| !rec.gyro_clipped[i]).collect();
    // Maps of each package onto the mean (twice: the mean of the mapped rates the second time).
    let mut maps = vec![Matrix3::identity(); packages];
    for _ in 0..2 {
        let mean = |i: usize, maps: &[Matrix3<f64>]| -> Vector3<f64> {
            (0..packages).map(|p| maps[p] * (rates[p][i] - bias[p])).sum::<Vector3<f64>>() / packages as f64
        };
        let mut new = Vec::with_capacity(packages);
        for p in 0..packages {
            let mut xx = Matrix3::zeros();
            let mut yx = Matrix3::zeros();
            for &i in &rows {
                let x = rates[p][i] - bias[p];
                xx += x * x.transpose();
                yx += mean(i, &maps) * x.transpose();
            }
            new.push(xx.try_inverse().map_or(Matrix3::identity(), |inv| yx * inv));
        }
        maps = new;
    }
    let mapped = |p: usize, i: usize| maps[p] * (rates[p][i] - bias[p]);
    let mean = |i: usize| (0..packages).map(|p| mapped(p, i)).sum::<Vector3<f64>>() / packages as f64;
    let in_dynamic: std::collections::HashSet<usize> = dynamic.iter().copied().collect();
    let mut out: Vec<Offsets> = (0..packages)
        .map(|_| Offsets { sample: Vec::new(), t_s: Vec::new(), offset_s: Vec::new(), weight: Vec::new() })
        .collect();
    let t0 = rec.t_s[0];
    for &i in dynamic {
        if !ok(i) || !(i - 2..=i + 2).all(|k| in_dynamic.contains(&k)) {
            continue;
        }
        let alpha = (mean(i - 2) - mean(i - 1) * 8.0 + mean(i + 1) * 8.0 - mean(i + 2)) / (12.0 * dt);
        let a2 = alpha.norm_squared();
        if a2 < 100.0 * 100.0 {
            continue;
        }
        let w = a2.sqrt().min(1500.0).powi(2);
        let m = mean(i);
        for (p, o) in out.iter_mut().enumerate() {
            o.sample.push(((rec.t_s[i] - t0) / dt).round() as i64);
            o.t_s.push(rec.t_s[i]);
            o.offset_s.push(-(mapped(p, i) - m).dot(&alpha) / a2);
            o.weight.push(w);
        }
    }
    (out[0].t_s.len() >= 16).then_some(out)
}

/// The host's sample period: the median step of the time stamps.
pub fn host_dt_s(t_s: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// Each accelerometer's relative age at every dynamic sample (samples x accelerometers), from
/// the clocks of the packages and the package of each accelerometer.
pub fn accelerometer_ages(d: &DynamicData, clocks: &[Option<SampleClock>], package_of: &[usize]) -> DMatrix<f64> {
    let mut tau = vec![0.0; clocks.len()];
    let mut ages = DMatrix::zeros(d.samples(), package_of.len());
    for i in 0..d.samples() {
        relative_ages(clocks, d.t_s[i], &mut tau);
        for (j, &p) in package_of.iter().enumerate() {
            ages[(i, j)] = tau[p];
        }
    }
    ages
}

/// The centripetal term's time derivative at `r`: `D r` of the module docs.
pub fn centripetal_rate(m: &SampleMotion, r: &Vector3<f64>) -> Vector3<f64> {
    let (a, w) = (&m.alpha_rad_s2, &m.omega_rad_s);
    a * w.dot(r) + w * a.dot(r) - r * (2.0 * w.dot(a))
}

/// The directions an output reads the timing motion along, before its scale factor and age:
/// its axis for the jerk, `r x a` for the angular jerk (`a . (dalpha/dt x r) = dalpha/dt . (r x a)`).
pub fn timing_directions(s: &Sensor) -> (Vector3<f64>, Vector3<f64>) {
    (s.axis, s.position_m.cross(&s.axis))
}

/// Unknowns a sample spends on the timing model: the jerk and the angular jerk.
pub const TIMING_UNKNOWNS_PER_SAMPLE: usize = 6;

/// The timing motion of one sample: jerk (m/s^3) and angular jerk (rad/s^3).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TimingMotion {
    pub jerk_m_s3: Vector3<f64>,
    pub angular_jerk_rad_s3: Vector3<f64>,
}

impl TimingMotion {
    fn from_vector(u: &Vector6<f64>) -> Self {
        Self { jerk_m_s3: Vector3::new(u[0], u[1], u[2]), angular_jerk_rad_s3: Vector3::new(u[3], u[4], u[5]) }
    }

    fn vector(&self) -> Vector6<f64> {
        let (j, a) = (&self.jerk_m_s3, &self.angular_jerk_rad_s3);
        Vector6::new(j[0], j[1], j[2], a[0], a[1], a[2])
    }
}

/// The timing term of an output's model at one sample, in output units:
/// `k a . (J + dalpha/dt x r + D r)`, which the output loses times the accelerometer's relative
/// age.
pub fn timing_gain(s: &Sensor, m: &SampleMotion, timing: &TimingMotion) -> f64 {
    let r = &s.position_m;
    s.k * s.axis.dot(&(timing.jerk_m_s3 + timing.angular_jerk_rad_s3.cross(r) + centripetal_rate(m, r)))
}

/// The clocks fitted with a calibration, and what they explain.
#[derive(Debug, Clone)]
pub struct ClockEstimate {
    /// Per package: its clock (`None` for a package without a free-running clock).
    pub clocks: Vec<Option<SampleClock>>,
    /// Per package: sigmas of `(rate_offset, drift_per_s, phase_s)` (see `sigma_check`).
    pub sigma: Vec<Option<[f64; 3]>>,
    /// The common part's sigmas alone (rate offset, drift, phase): from the gyroscopes' fit.
    pub common_sigma: [f64; 3],
    /// How the sigmas were checked: the two halves of the rotation phase fitted apart, their
    /// relative rate offsets compared with the sigmas (Birge ratio, and the factor applied).
    pub sigma_check: SigmaCheck,
    /// The timing motion at every dynamic sample.
    pub timing: Vec<TimingMotion>,
    /// How the clocks were first found.
    pub start: &'static str,
    /// The clocks the gyroscopes alone measure (their offsets' sawtooth), where they were used.
    pub gyroscope_clocks: Option<Vec<Option<SampleClock>>>,
    /// Dynamic residual RMS (all unclipped outputs) before the clocks and after, m/s^2.
    pub residual_rms_before_m_s2: f64,
    pub residual_rms_after_m_s2: f64,
    /// Outer iterations (corrected outputs refitted).
    pub iterations: usize,
    /// How the rotation phase's heavy tail was down-weighted (`None`: least squares alone).
    pub huber: Option<crate::selfcal::huber::HuberSummary>,
    /// The share of the rotation phase's weighted misfit (at the final parameters and motion)
    /// that the timing model removes with the fitted clocks, and with the clocks read at
    /// shifted times (the null: [`ClockProblem::shares_removed`]).
    pub share_removed: f64,
    pub null_shares_removed: Vec<f64>,
}

impl ClockEstimate {
    /// The rank p-value of the fitted clocks' share among the null's: `(1 + #{null >= share}) /
    /// (1 + nulls)`.
    pub fn null_p_value(&self) -> f64 {
        let above = self.null_shares_removed.iter().filter(|&&v| v >= self.share_removed).count();
        (1 + above) as f64 / (1 + self.null_shares_removed.len()) as f64
    }

    /// Each clocked package's rate offset less the clocked packages' mean (1), with its sigma.
    pub fn relative_rate_offsets(&self) -> Vec<Option<(f64, f64)>> {
        relative_rates(&self.clocks).into_iter().zip(&self.sigma).map(|(r, s)| r.zip(s.map(|s| s[0]))).collect()
    }
}

/// The motion's unknowns a sample (`f`, `alpha`, `omega`).
const MOTION_UNKNOWNS: usize = 9;

/// `|r - A x|^2` at the least-squares `x`, on the columns of `a` the data resolve: the columns
/// scaled to unit norm (zero columns left out), then the components of `r` along the left
/// singular vectors whose singular values exceed `1e-5` of the largest removed.
fn least_squares_misfit(mut a: DMatrix<f64>, r: &DVector<f64>) -> f64 {
    for mut column in a.column_iter_mut() {
        let norm = column.norm();
        if norm > 0.0 {
            column /= norm;
        }
    }
    let total = r.norm_squared();
    let svd = a.svd(true, false);
    let (Some(u), largest) = (svd.u.as_ref(), svd.singular_values.max()) else { return total };
    let explained: f64 = svd
        .singular_values
        .iter()
        .enumerate()
        .filter(|&(_, &s)| s > 1e-5 * largest)
        .map(|(k, _)| u.column(k).dot(r).powi(2))
        .sum();
    (total - explained).max(0.0)
}

/// Each clocked package's rate offset less the clocked packages' mean (1).
pub fn relative_rates(clocks: &[Option<SampleClock>]) -> Vec<Option<f64>> {
    let rates: Vec<f64> = clocks.iter().flatten().map(|c| c.rate_offset).collect();
    let mean = rates.iter().sum::<f64>() / rates.len().max(1) as f64;
    clocks.iter().map(|c| c.map(|c| c.rate_offset - mean)).collect()
}

/// The sigmas' check on the two halves of the rotation phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SigmaCheck {
    /// RMS over the clocked packages of the halves' relative rate-offset difference over its
    /// linearised sigma (1 when the sigmas are right).
    pub birge_ratio: f64,
    /// The factor every linearised sigma was multiplied by: `max(1, birge_ratio)`.
    pub inflation: f64,
    /// RMS over packages of the halves' relative rate-offset difference (1).
    pub half_difference_rms: f64,
}

/// What the clock part of a calibration works on, computed once at the current parameters and
/// motion: each output's residual against the model without timing, the known part of its
/// timing term (`k a . D r`), and each accelerometer's gains on the timing motion
/// (`k a` and `k r x a`).
pub struct ClockProblem {
    n: usize,
    t_s: Vec<f64>,
    residual: Vec<f64>,
    known_gain: Vec<f64>,
    used: Vec<bool>,
    gain: Vec<Vector6<f64>>,
    weights: Vec<f64>,
    package_of: Vec<usize>,
}

impl ClockProblem {
    /// `sensors` at the current parameters, `motion` fitted to `d`, `weights` the outputs'
    /// inverse variances, `package_of` each accelerometer's package.
    pub fn new(
        sensors: &[Sensor],
        d: &DynamicData,
        motion: &[SampleMotion],
        weights: &[f64],
        package_of: &[usize],
    ) -> Self {
        let n = sensors.len();
        let samples = d.samples();
        let mut residual = Vec::with_capacity(samples * n);
        let mut known_gain = Vec::with_capacity(samples * n);
        for (i, m) in motion.iter().enumerate().take(samples) {
            for (j, s) in sensors.iter().enumerate() {
                residual.push(d.outputs[(i, j)] - s.output(&m.specific_force_m_s2(&s.position_m)));
                known_gain.push(s.k * s.axis.dot(&centripetal_rate(m, &s.position_m)));
            }
        }
        let gain = sensors
            .iter()
            .map(|s| {
                let (a, b) = timing_directions(s);
                let (a, b) = (a * s.k, b * s.k);
                Vector6::new(a[0], a[1], a[2], b[0], b[1], b[2])
            })
            .collect();
        Self {
            n,
            t_s: d.t_s.clone(),
            residual,
            known_gain,
            used: d.used.clone(),
            gain,
            weights: weights.to_vec(),
            package_of: package_of.to_vec(),
        }
    }

    pub fn samples(&self) -> usize {
        self.t_s.len()
    }

    /// One sample's timing motion and weighted misfit at the relative ages `tau` of the
    /// packages: `r + tau (c + h . u) = 0` solved for `u` by least squares (`u = 0` where the
    /// ages do not span its six dimensions).
    fn sample_fit(&self, i: usize, tau_package: &[f64]) -> (Vector6<f64>, f64) {
        let base = i * self.n;
        let mut h = Matrix6::zeros();
        let mut b = Vector6::zeros();
        for j in 0..self.n {
            if !self.used[base + j] {
                continue;
            }
            let tau = tau_package[self.package_of[j]];
            let w = self.weights[j];
            let d = self.gain[j] * tau;
            let r = self.residual[base + j] + tau * self.known_gain[base + j];
            // `h += d d^T w` on and below the diagonal, each element as `(d_r d_c) w`.
            for c in 0..6 {
                for r in c..6 {
                    h[(r, c)] += d[r] * d[c] * w;
                }
            }
            b -= d * (w * r);
        }
        // The upper triangle: `(d_c d_r) w` is `(d_r d_c) w` to the bit.
        for c in 1..6 {
            for r in 0..c {
                h[(r, c)] = h[(c, r)];
            }
        }
        let u = timing_solve(&h).map(|c| c.solve(&b)).unwrap_or_else(Vector6::zeros);
        let mut cost = 0.0;
        for j in 0..self.n {
            if self.used[base + j] {
                let tau = tau_package[self.package_of[j]];
                let r = self.residual[base + j] + tau * (self.known_gain[base + j] + self.gain[j].dot(&u));
                cost += self.weights[j] * r * r;
            }
        }
        (u, cost)
    }

    /// Each sample's timing motion and misfit over `rows`, in sample order.
    fn sample_fits(&self, clocks: &[Option<SampleClock>], rows: Range<usize>) -> Vec<(Vector6<f64>, f64)> {
        use rayon::prelude::*;
        rows.into_par_iter()
            .map_init(
                || vec![0.0; clocks.len()],
                |tau, i| {
                    relative_ages(clocks, self.t_s[i], tau);
                    self.sample_fit(i, tau)
                },
            )
            .collect()
    }

    /// The misfit over `rows` with the timing motion refitted at every sample, and the motions.
    pub fn cost(&self, clocks: &[Option<SampleClock>], rows: Range<usize>) -> (f64, Vec<Vector6<f64>>) {
        let parts = self.sample_fits(clocks, rows);
        (parts.iter().map(|p| p.1).sum(), parts.into_iter().map(|p| p.0).collect())
    }

    /// Every sample's misfit with its timing motion refitted, in sample order.
    pub fn sample_costs(&self, clocks: &[Option<SampleClock>]) -> Vec<f64> {
        self.sample_fits(clocks, 0..self.samples()).into_iter().map(|p| p.1).collect()
    }

    /// The misfit without the timing model (every age zero).
    pub fn cost_without_timing(&self) -> f64 {
        (0..self.samples())
            .map(|i| {
                (0..self.n)
                    .filter(|&j| self.used[i * self.n + j])
                    .map(|j| self.weights[j] * self.residual[i * self.n + j].powi(2))
                    .sum::<f64>()
            })
            .sum()
    }

    /// The share of the misfit without timing that the timing model removes at `clocks`, and at
    /// each of `shifts_s`: the same clocks read `shift` seconds later, ages that have the clocks'
    /// statistics but not their samples, a null for what six unknowns a sample remove by chance.
    pub fn shares_removed(&self, clocks: &[Option<SampleClock>], shifts_s: &[f64]) -> (f64, Vec<f64>) {
        use rayon::prelude::*;
        let none = self.cost_without_timing().max(1e-300);
        let at = |shift: f64| -> f64 {
            // Collected, then summed in sample order: rayon's `sum` groups the additions as its
            // threads split the work, so the last bits would depend on the machine's load.
            let costs: Vec<f64> = (0..self.samples())
                .into_par_iter()
                .map_init(
                    || vec![0.0; clocks.len()],
                    |tau, i| {
                        relative_ages(clocks, self.t_s[i] + shift, tau);
                        self.sample_fit(i, tau).1
                    },
                )
                .collect();
            let cost: f64 = costs.iter().sum();
            1.0 - cost / none
        };
        (at(0.0), shifts_s.iter().map(|&s| at(s)).collect())
    }

    /// The share of the misfit that the timing model at `clocks` removes when every sample's
    /// motion is refitted with it: per sample, the least-squares fit of the motion's nine
    /// unknowns (linearised at `motion`, the motion this problem was built at) without the timing
    /// model and with it (its six unknowns more), and `1 - with / without` over the samples.
    ///
    /// [`shares_removed`](Self::shares_removed) holds the motion where it is. On a recording whose
    /// motion was tracked without the timing model (a held-out recording scored with another
    /// recording's clocks), the motion has already absorbed what of the timing signature its own
    /// unknowns can (the timing term's gains are the motion's own, scaled by the packages'
    /// ages), so the share at the held motion depends on how far the motion's solve went: a solve
    /// that stops early leaves the timing model more to take. Refitted with it, the share is what
    /// the timing model adds to the motion, the same from any motion near the solution (to first
    /// order). Unknowns a sample does not resolve (singular values of the column-equilibrated
    /// design below `1e-5` of the largest) are left out. With `rate_given` (`--use-gyro`) the
    /// motion's rate is not refitted. As [`shares_removed`](Self::shares_removed), also at each of
    /// `shifts_s` (the same clocks read later): six unknowns more a sample remove a share of any
    /// misfit by chance (for white residuals 6 of the 15 degrees of freedom the motion leaves a
    /// sample of 24 outputs), and the shifted clocks measure how much.
    pub fn share_removed_motion_refitted(
        &self,
        sensors: &[Sensor],
        motion: &[SampleMotion],
        rate_given: bool,
        clocks: &[Option<SampleClock>],
        shifts_s: &[f64],
    ) -> (f64, Vec<f64>) {
        use rayon::prelude::*;
        let free = if rate_given { 6 } else { MOTION_UNKNOWNS };
        let samples = self.samples().min(motion.len());
        // Each sample's weighted design (the motion's columns, then the timing motion's gains
        // before the ages scale them) and residual.
        let sample = |i: usize| -> (Vec<usize>, DMatrix<f64>, DVector<f64>) {
            let base = i * self.n;
            let rows: Vec<usize> = (0..self.n).filter(|&j| self.used[base + j]).collect();
            let mut design = DMatrix::zeros(rows.len(), free + TIMING_UNKNOWNS_PER_SAMPLE);
            let mut residual = DVector::zeros(rows.len());
            for (row, &j) in rows.iter().enumerate() {
                let root_w = self.weights[j].sqrt();
                for (k, v) in sensors[j].d_motion(&motion[i]).iter().take(free).enumerate() {
                    design[(row, k)] = root_w * v;
                }
                for k in 0..TIMING_UNKNOWNS_PER_SAMPLE {
                    design[(row, free + k)] = root_w * self.gain[j][k];
                }
                residual[row] = root_w * self.residual[base + j];
            }
            (rows, design, residual)
        };
        let without: Vec<f64> = (0..samples)
            .into_par_iter()
            .map(|i| {
                let (_, design, residual) = sample(i);
                least_squares_misfit(design.columns(0, free).into_owned(), &residual)
            })
            .collect();
        // Summed in sample order (the bits do not follow how the threads split the work).
        let without = without.iter().sum::<f64>().max(1e-300);
        let at = |shift: f64| -> f64 {
            let with: Vec<f64> = (0..samples)
                .into_par_iter()
                .map_init(
                    || vec![0.0; clocks.len()],
                    |tau, i| {
                        relative_ages(clocks, self.t_s[i] + shift, tau);
                        let (rows, mut design, mut residual) = sample(i);
                        for (row, &j) in rows.iter().enumerate() {
                            let age = tau[self.package_of[j]];
                            for k in 0..TIMING_UNKNOWNS_PER_SAMPLE {
                                design[(row, free + k)] *= age;
                            }
                            residual[row] += self.weights[j].sqrt() * age * self.known_gain[i * self.n + j];
                        }
                        least_squares_misfit(design, &residual)
                    },
                )
                .collect();
            1.0 - with.iter().sum::<f64>() / without
        };
        (at(0.0), shifts_s.iter().map(|&s| at(s)).collect())
    }

    /// The timing motion of every sample.
    pub fn timing(&self, clocks: &[Option<SampleClock>]) -> Vec<TimingMotion> {
        self.cost(clocks, 0..self.samples()).1.iter().map(TimingMotion::from_vector).collect()
    }

    /// Each output's rate of change that its age multiplies in [`ClockProblem::corrected`] (samples
    /// x accelerometers, m/s^3): `k a . (J + dalpha/dt x r + D r)` with the timing motion `timing`.
    /// Times a clock parameter's derivative of the package's relative age, it is the corrected
    /// output's derivative in that parameter.
    pub fn output_rates_m_s3(&self, timing: &[TimingMotion]) -> DMatrix<f64> {
        DMatrix::from_fn(self.samples(), self.n, |i, j| {
            let u = timing.get(i).map_or(Vector6::zeros(), TimingMotion::vector);
            self.known_gain[i * self.n + j] + self.gain[j].dot(&u)
        })
    }

    /// The outputs corrected to the mean instant: `s + tau k a . (J + dalpha/dt x r + D r)`.
    pub fn corrected(
        &self,
        outputs: &DMatrix<f64>,
        clocks: &[Option<SampleClock>],
        timing: &[TimingMotion],
    ) -> DMatrix<f64> {
        self.corrected_at_rates(outputs, clocks, &self.output_rates_m_s3(timing), timing.len())
    }

    /// [`ClockProblem::corrected`] with the outputs' rates of change formed
    /// ([`ClockProblem::output_rates_m_s3`]); only the first `samples` samples (those with a timing
    /// motion) are corrected.
    pub fn corrected_at_rates(
        &self,
        outputs: &DMatrix<f64>,
        clocks: &[Option<SampleClock>],
        rates_m_s3: &DMatrix<f64>,
        samples: usize,
    ) -> DMatrix<f64> {
        let mut out = outputs.clone();
        let mut tau = vec![0.0; clocks.len()];
        for i in 0..samples.min(self.samples()) {
            relative_ages(clocks, self.t_s[i], &mut tau);
            for j in 0..self.n {
                out[(i, j)] += tau[self.package_of[j]] * rates_m_s3[(i, j)];
            }
        }
        out
    }

    /// The optimum over `rows` of the clocks' relative part as linearised at `clocks` (the wraps
    /// held, each sample's timing motion eliminated): `clocks` moved by one full Gauss-Newton
    /// step, and the information there ([`ClockProblem::relative_information`]). Where the misfit
    /// is V-shaped at the wraps a step may not lower it, but the step is still where the smooth
    /// part of the misfit puts the clocks: what the halves' check compares.
    pub fn linearised_optimum(
        &self,
        clocks: &[Option<SampleClock>],
        rows: Range<usize>,
    ) -> (Vec<Option<SampleClock>>, DMatrix<f64>) {
        let (_, u) = self.cost(clocks, rows.clone());
        let (h, g) = self.relative_normal(clocks, rows, &u, true);
        let (inv, _) = crate::stats::symmetric_pinv(&h, 1e-12);
        (stepped(clocks, &(&inv * &g), 1.0), h)
    }

    /// Gauss-Newton steps on the clocks' relative part over `rows` (the timing motion held at
    /// each linearisation, the wraps held and re-assigned after each step, a step halved until
    /// the misfit falls); the common part (the gauge) does not move. Returns the clocks and the
    /// misfit. The steps' matrix keeps the timing motion held (it is a search direction, each
    /// step accepted only where the misfit falls); the clocks' information is
    /// [`ClockProblem::relative_information`].
    pub fn relative_steps(
        &self,
        clocks: &[Option<SampleClock>],
        rows: Range<usize>,
        steps: usize,
    ) -> (Vec<Option<SampleClock>>, f64) {
        let mut current = clocks.to_vec();
        let (mut cost, mut u) = self.cost(&current, rows.clone());
        for _ in 0..steps {
            let (h, g) = self.relative_normal(&current, rows.clone(), &u, false);
            let (inv, _) = crate::stats::symmetric_pinv(&h, 1e-12);
            let step = &inv * &g;
            let Some(moved) = self.halving_search(&current, &step, rows.clone(), cost) else { break };
            (current, cost, u) = moved;
        }
        (current, cost)
    }

    /// `current` moved by `step`, halved up to 6 times until the misfit over `rows` falls below
    /// `cost`: the clocks, their misfit and their timing motion (`None`: no fall).
    fn halving_search(
        &self,
        current: &[Option<SampleClock>],
        step: &DVector<f64>,
        rows: Range<usize>,
        cost: f64,
    ) -> Option<Moved> {
        let mut scale = 1.0;
        for _ in 0..6 {
            let trial = stepped(current, step, scale);
            let (after, u_after) = self.cost(&trial, rows.clone());
            if after < cost {
                return Some((trial, after, u_after));
            }
            scale *= 0.5;
        }
        None
    }

    /// Gauss-Newton steps over `rows` on one clocked package's `(rate_offset, drift, phase)`
    /// alone, every other clock held (each step from that package's block of the normal matrix
    /// with the timing motion eliminated, halved until the misfit falls). Meant for a package
    /// whose sawtooth completes less than a period over `rows` ([`sawtooth_periods`]): none of
    /// its samples crosses a wrap and the others' wraps stay put, so its misfit is smooth where
    /// the joint steps of [`ClockProblem::relative_steps`] meet the others' staircase. Returns the
    /// clocks and the misfit.
    pub fn package_steps(
        &self,
        clocks: &[Option<SampleClock>],
        rows: Range<usize>,
        package: usize,
        steps: usize,
    ) -> (Vec<Option<SampleClock>>, f64) {
        let mut current = clocks.to_vec();
        let (mut cost, mut u) = self.cost(&current, rows.clone());
        let Some(c) = (0..current.len()).filter(|&p| current[p].is_some()).position(|p| p == package) else {
            return (current, cost);
        };
        for _ in 0..steps {
            let (h, g) = self.relative_normal(&current, rows.clone(), &u, true);
            let block = h.view((3 * c, 3 * c), (3, 3)).into_owned();
            let Some(chol) = block.cholesky() else { break };
            let own = chol.solve(&g.rows(3 * c, 3).into_owned());
            let mut step = DVector::zeros(g.len());
            step.rows_mut(3 * c, 3).copy_from(&own);
            let Some(moved) = self.halving_search(&current, &step, rows.clone(), cost) else { break };
            (current, cost, u) = moved;
        }
        (current, cost)
    }

    /// The information over `rows` on the clocked packages' `(rate_offset, drift, phase)` at
    /// `clocks`: the normal matrix with each sample's timing motion eliminated (it is refitted at
    /// every clock), whose pseudo-inverse is the relative part's covariance.
    pub fn relative_information(&self, clocks: &[Option<SampleClock>], rows: Range<usize>) -> DMatrix<f64> {
        let (_, u) = self.cost(clocks, rows.clone());
        self.relative_normal(clocks, rows, &u, true).0
    }

    /// The normal equations of the clocks' relative part over `rows` at `current` (the timing
    /// motion `u`, one per row, held): the matrix and the gradient over the clocked packages'
    /// `(rate_offset, drift, phase)`.
    fn relative_normal(
        &self,
        current: &[Option<SampleClock>],
        rows: Range<usize>,
        u: &[Vector6<f64>],
        project: bool,
    ) -> (DMatrix<f64>, DVector<f64>) {
        use rayon::prelude::*;
        let clocked: Vec<usize> = (0..current.len()).filter(|&p| current[p].is_some()).collect();
        let npk = current.len() as f64;
        let dim = 3 * clocked.len();
        // Normal equations summed over fixed chunks of samples, the chunks then added in order:
        // the same bits on any number of threads and under any load (rayon's fold/reduce
        // groups the sums as its threads split the work).
        const CHUNK: usize = 256;
        let chunks = rows.len().div_ceil(CHUNK);
        let chunk_sums: Vec<(DMatrix<f64>, DVector<f64>)> = (0..chunks)
            .into_par_iter()
            .map(|k| {
                let mut h = DMatrix::<f64>::zeros(dim, dim);
                let mut g = DVector::<f64>::zeros(dim);
                let mut tau = vec![0.0; current.len()];
                let start = rows.start + k * CHUNK;
                for i in start..(start + CHUNK).min(rows.end) {
                    relative_ages(current, self.t_s[i], &mut tau);
                    let ui = &u[i - rows.start];
                    // the package-level row: d r_j / d c_p = gain_j (delta(p, p_j) - 1/P) d age_p / d c_p
                    let parts: Vec<[f64; 3]> =
                        clocked.iter().map(|&p| current[p].map_or([0.0; 3], |c| c.age_partials(self.t_s[i]))).collect();
                    let mut row = vec![0.0; dim];
                    // With `project`: the sample's timing-motion block `m` and its cross terms with
                    // the clocks, for the Schur complement below.
                    let mut m = Matrix6::zeros();
                    let mut cross = DMatrix::<f64>::zeros(if project { 6 } else { 0 }, dim);
                    for j in 0..self.n {
                        if !self.used[i * self.n + j] {
                            continue;
                        }
                        let gain = self.known_gain[i * self.n + j] + self.gain[j].dot(ui);
                        let tj = tau[self.package_of[j]];
                        let r = self.residual[i * self.n + j] + tj * gain;
                        for (c, &p) in clocked.iter().enumerate() {
                            let f = (if p == self.package_of[j] { 1.0 } else { 0.0 }) - 1.0 / npk;
                            for a in 0..3 {
                                row[3 * c + a] = gain * f * parts[c][a];
                            }
                        }
                        let w = self.weights[j];
                        if project {
                            let du = self.gain[j] * tj;
                            m += du * du.transpose() * w;
                            for (a, ra) in row.iter().enumerate() {
                                for e in 0..6 {
                                    cross[(e, a)] += w * du[e] * ra;
                                }
                            }
                        }
                        for a in 0..dim {
                            if row[a] == 0.0 {
                                continue;
                            }
                            g[a] -= w * row[a] * r;
                            for b in a..dim {
                                h[(a, b)] += w * row[a] * row[b];
                            }
                        }
                    }
                    // The sample's timing motion is refitted at every clock (`sample_fit`), so
                    // the clocks' information is what is left with it eliminated:
                    // `H -= C^T M^-1 C` (the gradient needs nothing: at the refitted motion the
                    // residual is orthogonal to its columns). Where `sample_fit` leaves the motion
                    // at zero (`timing_solve` refuses `m`) nothing is eliminated.
                    if let Some(chol) = timing_solve(&m).filter(|_| project) {
                        let mut y = DMatrix::<f64>::zeros(6, dim);
                        for col in 0..dim {
                            let v = chol.solve(&Vector6::from_fn(|e, _| cross[(e, col)]));
                            for e in 0..6 {
                                y[(e, col)] = v[e];
                            }
                        }
                        for a in 0..dim {
                            for b in a..dim {
                                h[(a, b)] -= (0..6).map(|e| cross[(e, a)] * y[(e, b)]).sum::<f64>();
                            }
                        }
                    }
                }
                (h, g)
            })
            .collect();
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        for (hk, gk) in &chunk_sums {
            h += hk;
            g += gk;
        }
        for a in 0..dim {
            for b in 0..a {
                h[(a, b)] = h[(b, a)];
            }
        }
        (h, g)
    }
}

/// How many of its periods `clock`'s sawtooth sweeps through when read at the host's samples
/// `t_s` (host step `host_dt_s`): the range over the samples of its ticks less the whole ticks
/// of the host steps, `n(t) - round(f0 dt) (t - t_0) / dt` (drift included). Below 1 the
/// sawtooth does not complete a period: at most one of its wraps falls among the samples.
pub fn sawtooth_periods(clock: &SampleClock, t_s: &[f64], host_dt_s: f64) -> f64 {
    clock.periods_over(t_s, host_dt_s)
}

/// Clocks after an accepted step: the clocks, their misfit and their timing motion per row.
type Moved = (Vec<Option<SampleClock>>, f64, Vec<Vector6<f64>>);

/// The clocked packages moved by `scale` times `step` (three entries a clocked package, in order).
fn stepped(clocks: &[Option<SampleClock>], step: &DVector<f64>, scale: f64) -> Vec<Option<SampleClock>> {
    let mut k = 0;
    clocks
        .iter()
        .map(|c| {
            c.map(|c| {
                let d = [scale * step[3 * k], scale * step[3 * k + 1], scale * step[3 * k + 2]];
                k += 1;
                c.moved(d)
            })
        })
        .collect()
}

/// The Cholesky factor of a sample's timing-motion normal matrix `h`, where the motion is
/// solved: where its smallest eigenvalue exceeds 1e-10 of its largest diagonal element. `1 /
/// |H^-1|_F` bounds the smallest eigenvalue from below, so where it clears twice the threshold the
/// eigenvalues need not be computed (the same decision, cheaper).
fn timing_solve(h: &Matrix6<f64>) -> Option<nalgebra::Cholesky<f64, nalgebra::U6>> {
    let scale = (0..6).map(|a| h[(a, a)]).fold(0.0, f64::max);
    let chol = if scale > 0.0 { h.cholesky() } else { None };
    chol.filter(|c| {
        let bound = 1.0 / c.inverse().norm();
        bound > 2e-10 * scale || h.symmetric_eigenvalues().min() > 1e-10 * scale
    })
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};

    use super::least_squares_misfit;

    /// A design of `rows x columns` with entries of very different scales (the timing columns are
    /// the motion's gains times ages of about 1e-4 s), from a fixed sequence.
    fn design(rows: usize, columns: usize) -> DMatrix<f64> {
        DMatrix::from_fn(rows, columns, |i, j| {
            let x = ((i * 37 + j * 101) as f64 * 0.618_033_988_749_895).fract() - 0.5;
            if j >= 9 { 1e-4 * x } else { x }
        })
    }

    /// Against the normal equations (an independent route): on a full-rank design the misfit is
    /// `r^T r - b^T (A^T A)^-1 b` with `b = A^T r`, to 1e-9 relative.
    #[test]
    fn the_misfit_matches_the_normal_equations_on_a_full_rank_design() {
        let a = design(24, 15);
        let r = DVector::from_fn(24, |i, _| ((i * 13) as f64 * 0.414_213_562_373_095).fract() - 0.5);
        let b = a.transpose() * &r;
        let normal = a.transpose() * &a;
        let x = normal.cholesky().expect("full rank").solve(&b);
        let want = r.norm_squared() - b.dot(&x);
        let got = least_squares_misfit(a, &r);
        assert!((got - want).abs() <= 1e-9 * want, "{got} against {want}");
    }

    /// A column the others span adds nothing: the misfit with a repeated column (scaled) equals the
    /// misfit without it, and a zero column is left out.
    #[test]
    fn a_dependent_or_zero_column_changes_nothing() {
        let a = design(24, 12);
        let r = DVector::from_fn(24, |i, _| ((i * 7) as f64 * 0.302_775_637_731_995).fract() - 0.5);
        let base = least_squares_misfit(a.clone(), &r);
        let mut repeated = a.clone().insert_column(12, 0.0);
        let copy = repeated.column(3) * 2.5;
        repeated.set_column(12, &copy);
        let zero = a.insert_column(12, 0.0);
        for (name, m) in [("repeated", repeated), ("zero", zero)] {
            let got = least_squares_misfit(m, &r);
            assert!((got - base).abs() <= 1e-9 * base, "{name}: {got} against {base}");
        }
    }
}

#[cfg(test)]
mod information_tests {
    use nalgebra::{DMatrix, Vector6};

    use super::ClockProblem;
    use crate::selfcal::clock::{SampleClock, relative_ages};

    /// A small problem built by hand: 3 clocked packages of 4 outputs each, 30 samples 16 ms
    /// apart, gains and residuals from a fixed sequence.
    fn problem() -> (ClockProblem, Vec<Option<SampleClock>>) {
        let (n, samples) = (12, 30);
        // A fixed sequence that is not affine in `k` (an affine one modulo 1 makes the gains span
        // only two dimensions).
        let x = |k: usize| ((k as f64 + 1.0).sin() * 43_758.545_3).fract() * 0.5;
        let problem = ClockProblem {
            n,
            t_s: (0..samples).map(|i| 0.016 * i as f64).collect(),
            residual: (0..samples * n).map(|k| 0.3 * x(3 * k + 1)).collect(),
            known_gain: (0..samples * n).map(|k| 200.0 * x(5 * k + 2)).collect(),
            used: vec![true; samples * n],
            gain: (0..n).map(|j| Vector6::from_fn(|a, _| x(7 * j + a + 3))).collect(),
            weights: (0..n).map(|j| 1.0 + 0.1 * j as f64).collect(),
            package_of: (0..n).map(|j| j / 4).collect(),
        };
        let clock = |rate: f64, phase: f64| {
            Some(SampleClock { nominal_hz: 1000.0, rate_offset: rate, drift_per_s: 1e-6, phase_s: phase, t_ref_s: 0.2 })
        };
        (problem, vec![clock(2.1e-3, 0.1e-3), clock(-1.3e-3, 0.45e-3), clock(0.4e-3, 0.8e-3)])
    }

    /// Against the whole problem written out (an independent route): the Gauss-Newton normal
    /// matrix over the clocks' 9 parameters and every sample's 6 timing-motion unknowns, from the
    /// model `r + tau_p (c + h . u)` with its Jacobian formed column by column, and the clocks'
    /// block of its Schur complement `N_cc - N_cu N_uu^-1 N_uc`: `relative_information` equals it
    /// to 1e-9 of its largest element, and is below the clocks' block with the motion held
    /// (`N_cc`) by a positive semi-definite difference.
    #[test]
    fn the_information_is_the_whole_problems_schur_complement() {
        let (p, clocks) = problem();
        let samples = p.t_s.len();
        let got = p.relative_information(&clocks, 0..samples);
        let (_, u) = p.cost(&clocks, 0..samples);
        let (nc, packages) = (9, 3);
        let dim = nc + 6 * samples;
        let mut normal = DMatrix::<f64>::zeros(dim, dim);
        let mut tau = vec![0.0; packages];
        for i in 0..samples {
            relative_ages(&clocks, p.t_s[i], &mut tau);
            for j in 0..p.n {
                let mut row = vec![0.0; dim];
                let c = p.known_gain[i * p.n + j] + p.gain[j].dot(&u[i]);
                for q in 0..packages {
                    let part = clocks[q].expect("clocked").age_partials(p.t_s[i]);
                    let f = if q == p.package_of[j] { 1.0 } else { 0.0 } - 1.0 / packages as f64;
                    for a in 0..3 {
                        row[3 * q + a] = c * f * part[a];
                    }
                }
                for e in 0..6 {
                    row[nc + 6 * i + e] = tau[p.package_of[j]] * p.gain[j][e];
                }
                for a in 0..dim {
                    for b in 0..dim {
                        normal[(a, b)] += p.weights[j] * row[a] * row[b];
                    }
                }
            }
        }
        let n_cc = normal.view((0, 0), (nc, nc)).into_owned();
        let n_cu = normal.view((0, nc), (nc, dim - nc)).into_owned();
        let n_uu = normal.view((nc, nc), (dim - nc, dim - nc)).into_owned();
        let want = &n_cc - &n_cu * n_uu.cholesky().expect("every sample's motion is solved").solve(&n_cu.transpose());
        let scale = want.abs().max();
        let got_sym = DMatrix::from_fn(nc, nc, |a, b| got[(a.min(b), a.max(b))]);
        let diff = (&got_sym - &want).abs().max();
        assert!(diff <= 1e-9 * scale, "largest difference {diff:e} against {scale:e}");
        let held_minus = &n_cc - &want;
        let smallest = held_minus.symmetric_eigenvalues().min();
        assert!(smallest >= -1e-9 * scale, "N_cc - information has eigenvalue {smallest:e}");
        assert!(held_minus.abs().max() > 1e-3 * scale, "eliminating the motion changes the information");
    }
}

#[cfg(test)]
mod period_tests {
    use super::sawtooth_periods;
    use crate::selfcal::clock::SampleClock;

    /// Closed forms: a clock `eps` off a 1 kHz nominal read every 16 ms sweeps `16 eps` of a
    /// period a sample, so `f0 eps T` periods over `T` seconds (drift adds `f0 drift T^2 / 8`
    /// each side of the middle); the count does not depend on the phase, and agrees with the
    /// wraps counted in the ages read at the samples.
    #[test]
    fn the_periods_swept_are_f0_eps_t_and_match_the_wraps_counted() {
        let t_s: Vec<f64> = (0..6250).map(|k| 3.0 + k as f64 * 0.016).collect();
        let span = t_s[t_s.len() - 1] - t_s[0];
        for (eps, phase_s) in [(3.7e-6, 0.0), (3.7e-6, 0.9e-3), (-37.5e-6, 0.4e-3), (1120.4e-6, 0.1e-3)] {
            let clock = SampleClock { nominal_hz: 1000.0, rate_offset: eps, drift_per_s: 0.0, phase_s, t_ref_s: 53.0 };
            let periods = sawtooth_periods(&clock, &t_s, 0.016);
            let expected = 1000.0 * eps.abs() * span;
            assert!((periods - expected).abs() < 1e-6 * expected.max(1.0), "eps {eps}: {periods} vs {expected}");
            // the ages' wraps: a step of more than half a period
            let ages: Vec<f64> = t_s.iter().map(|&t| clock.age_s(t)).collect();
            let wraps = ages.windows(2).filter(|w| (w[1] - w[0]).abs() > 0.5e-3).count() as f64;
            assert!((wraps - expected).abs() <= 1.0, "eps {eps}: {wraps} wraps, {expected} periods");
        }
        // A drift that turns the sawtooth round in the middle: 1.6e-7 /s over +-50 s with no rate
        // offset sweeps 1000 * 1.6e-7 * 50^2 / 2 = 0.2 of a period each side, the same way.
        let middle = 0.5 * (t_s[0] + t_s[t_s.len() - 1]);
        let turning =
            SampleClock { nominal_hz: 1000.0, rate_offset: 0.0, drift_per_s: 1.6e-7, phase_s: 0.0, t_ref_s: middle };
        let periods = sawtooth_periods(&turning, &t_s, 0.016);
        let half = 0.5 * span;
        assert!((periods - 1000.0 * 0.5 * 1.6e-7 * half * half).abs() < 1e-6, "{periods}");
    }

    /// Each accelerometer's age at every sample is its own package's age at that sample's time,
    /// less the packages' mean there (written out from `SampleClock::ticks`, not through
    /// `relative_ages`). It once filled a column-major matrix from a per-row cache, so every
    /// accelerometer after the first took the last sample's ages at every sample.
    #[test]
    fn every_accelerometer_takes_its_own_packages_age_at_each_sample() {
        use super::super::data::DynamicData;
        use super::accelerometer_ages;
        use crate::selfcal::clock::SampleClock;
        let clock = |rate: f64, phase: f64| {
            Some(SampleClock { nominal_hz: 1000.0, rate_offset: rate, drift_per_s: 1e-6, phase_s: phase, t_ref_s: 0.2 })
        };
        let clocks = [clock(2.1e-3, 0.1e-3), clock(-1.3e-3, 0.45e-3), clock(0.4e-3, 0.8e-3)];
        let samples = 25;
        let t_s: Vec<f64> = (0..samples).map(|i| 0.016 * i as f64 + 0.003).collect();
        let d = DynamicData {
            t_s: t_s.clone(),
            outputs: nalgebra::DMatrix::zeros(samples, 5),
            used: vec![true; samples * 5],
            run_starts: vec![0],
            reference_rate_rad_s: None,
            extra_unknowns_per_sample: 0,
        };
        let package_of = [2, 0, 1, 0, 2];
        let ages = accelerometer_ages(&d, &clocks, &package_of);
        let age = |p: usize, t: f64| {
            let n = clocks[p].expect("clocked").ticks(t);
            (n - n.floor()) / 1000.0
        };
        for (i, &t) in t_s.iter().enumerate() {
            let mean = (0..3).map(|p| age(p, t)).sum::<f64>() / 3.0;
            for (j, &p) in package_of.iter().enumerate() {
                let expected = age(p, t) - mean;
                assert!(
                    (ages[(i, j)] - expected).abs() < 1e-15,
                    "sample {i}, accelerometer {j}: {} against {expected}",
                    ages[(i, j)]
                );
            }
        }
    }
}
