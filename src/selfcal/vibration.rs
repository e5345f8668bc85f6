//! Band-limited random vibration of a hand-held board, for the simulator of recordings
//! ([`super::simulate`]): white noise through a first-order high-pass (corner `f_lo`) and a
//! Butterworth low-pass of order 2 or 3 (corner `f_hi`), one independent process per axis,
//! integrated exactly on a fine time grid and evaluable at any instant between its points.
//!
//! **Model.** Per axis, with `w_l = 2 pi f_lo`, `w_c = 2 pi f_hi` and `e = u - w_l z` the
//! high-passed drive (`u` white), the second-order state is `x = (z, y, v)`, `v = y' / w_c`:
//!
//! ```text
//! z' = -w_l z + u
//! y' = w_c v
//! v' = w_c (e - y) - sqrt(2) w_c v
//! ```
//!
//! so `y` is `u` high-passed (`s / (s + w_l)`) then low-passed
//! (`w_c^2 / (s^2 + sqrt(2) w_c s + w_c^2)`). Its spectrum is flat between the corners, falls as
//! `f^-4` above `f_hi` and as `f^2` below `f_lo` (a hand does not drift away). The output `y` and
//! its derivative `y' = w_c v` are continuous (the relative degree is two): an acceleration it
//! drives has a continuous jerk, an angular rate it drives a continuous angular acceleration, as a
//! rigid body's motion must. The derivative of `y'` is not: it carries the drive itself, white up
//! to the grid's `1 / (2 h)`.
//!
//! The third-order state is `x = (z, y, p, q)`, `p = y' / w_c`, `q = y'' / w_c^2`:
//!
//! ```text
//! y' = w_c p,   p' = w_c q,   q' = w_c (e - y - 2 p - 2 q)
//! ```
//!
//! (`w_c^3 / (s^3 + 2 w_c s^2 + 2 w_c^2 s + w_c^3)`, `|H|^2 = 1 / (1 + (f / f_hi)^6)`): the
//! spectrum falls as `f^-6`, and `y''` is continuous too. An angular rate needs it when the
//! angular jerk matters (an accelerometer read at a clock's age sees `dalpha/dt x r`): with the
//! second order the angular jerk is the grid's white drive, as large as the grid is fine.
//!
//! **Integration.** The drive is held over each step of the grid (`u_n`, variance `1 / h`: white
//! up to about `1 / (2 h)`, far above `f_hi`) and the state is carried by the exact transition
//! `x(t_n + d) = Phi(d) x_n + Gamma(d) u_n` for any `0 <= d <= h`: the state at an instant
//! between grid points (a package's tick) is exact, not interpolated. The process starts from
//! its stationary distribution on the grid (the discrete Lyapunov equation) and is scaled to the
//! requested RMS per axis. Both orders are held in four-state matrices; the second order's fourth
//! state starts at zero and stays there (its row and column of `A` and its drive are zero), so
//! its arithmetic is the three-state one's.

use nalgebra::{DMatrix, DVector, Matrix4, Matrix5, Vector4};
use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

/// The order of a [`BandNoise`]'s Butterworth low-pass (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LowPass {
    /// Second order: the output and its derivative continuous (`f^-4` above the corner).
    #[default]
    Second,
    /// Third order: the second derivative continuous too (`f^-6` above the corner).
    Third,
}

impl LowPass {
    /// The order as a number (2 or 3); `None` for any other.
    pub fn from_order(order: u32) -> Option<Self> {
        match order {
            2 => Some(Self::Second),
            3 => Some(Self::Third),
            _ => None,
        }
    }

    pub fn order(self) -> u32 {
        match self {
            Self::Second => 2,
            Self::Third => 3,
        }
    }

    /// States of the process: the high-pass's and the low-pass's.
    fn states(self) -> usize {
        1 + self.order() as usize
    }
}

/// One axis's shaping filter and its exact transitions over a grid step and half a step.
#[derive(Debug, Clone)]
pub struct BandNoise {
    a: Matrix4<f64>,
    b: Vector4<f64>,
    step_s: f64,
    /// States in use (3 or 4); the rest of `a`, `b` and the state are zero.
    states: usize,
    phi: Matrix4<f64>,
    gamma: Vector4<f64>,
    phi_half: Matrix4<f64>,
    gamma_half: Vector4<f64>,
    /// Output scale: the requested RMS over the stationary standard deviation of `y`.
    gain: f64,
    /// Lower Cholesky factor of the stationary covariance of the state (unit drive).
    start: Matrix4<f64>,
}

impl BandNoise {
    /// The second-order process for a band `[f_lo, f_hi]` (Hz, `0 < f_lo < f_hi`), an RMS of
    /// `rms` per axis and a grid step `step_s`; `None` when the band, the RMS or the step is not
    /// usable (the caller checks its inputs and names them).
    pub fn new(band_hz: [f64; 2], rms: f64, step_s: f64) -> Option<Self> {
        Self::with_low_pass(band_hz, rms, step_s, LowPass::Second)
    }

    /// The process with a low-pass of order `low_pass` (module docs), as [`BandNoise::new`].
    pub fn with_low_pass(band_hz: [f64; 2], rms: f64, step_s: f64, low_pass: LowPass) -> Option<Self> {
        let [lo, hi] = band_hz;
        if !(lo > 0.0 && hi > lo && rms > 0.0 && step_s > 0.0 && rms.is_finite() && hi.is_finite()) {
            return None;
        }
        let wl = 2.0 * std::f64::consts::PI * lo;
        let wc = 2.0 * std::f64::consts::PI * hi;
        let (a, b) = match low_pass {
            LowPass::Second => {
                let s2 = std::f64::consts::SQRT_2;
                #[rustfmt::skip]
                let a = Matrix4::new(
                    -wl,        0.0,  0.0,       0.0,
                    0.0,        0.0,  wc,        0.0,
                    -wc * wl,   -wc,  -s2 * wc,  0.0,
                    0.0,        0.0,  0.0,       0.0,
                );
                (a, Vector4::new(1.0, 0.0, wc, 0.0))
            }
            LowPass::Third => {
                #[rustfmt::skip]
                let a = Matrix4::new(
                    -wl,        0.0,  0.0,        0.0,
                    0.0,        0.0,  wc,         0.0,
                    0.0,        0.0,  0.0,        wc,
                    -wc * wl,   -wc,  -2.0 * wc,  -2.0 * wc,
                );
                (a, Vector4::new(1.0, 0.0, 0.0, wc))
            }
        };
        let states = low_pass.states();
        let (phi, gamma) = transition(&a, &b, step_s);
        let (phi_half, gamma_half) = transition(&a, &b, 0.5 * step_s);
        // Stationary covariance on the grid, over the states in use: P = Phi P Phi^T + Gamma
        // Gamma^T / h.
        let n = states;
        let kron = DMatrix::from_fn(n * n, n * n, |r, c| phi[(r / n, c / n)] * phi[(r % n, c % n)]);
        let lhs = DMatrix::identity(n * n, n * n) - kron;
        let rhs = DVector::from_fn(n * n, |i, _| gamma[i / n] * gamma[i % n] / step_s);
        let p = lhs.lu().solve(&rhs)?;
        let p = DMatrix::from_fn(n, n, |r, c| 0.5 * (p[n * r + c] + p[n * c + r]));
        let l = p.clone().cholesky()?.l();
        let start = Matrix4::from_fn(|r, c| if r < n && c < n { l[(r, c)] } else { 0.0 });
        let sd = p[(1, 1)].sqrt();
        if !(sd > 0.0 && sd.is_finite()) {
            return None;
        }
        Some(Self { a, b, step_s, states, phi, gamma, phi_half, gamma_half, gain: rms / sd, start })
    }

    pub fn step_s(&self) -> f64 {
        self.step_s
    }

    /// `(value, derivative)` of the output for state `x`.
    fn output(&self, x: &Vector4<f64>) -> (f64, f64) {
        (self.gain * x[1], self.gain * self.a[(1, 2)] * x[2])
    }
}

/// `Phi(d) = exp(A d)` and `Gamma(d) = int_0^d exp(A s) ds B`, from the exponential of the
/// augmented matrix `[[A, B], [0, 0]] d`.
fn transition(a: &Matrix4<f64>, b: &Vector4<f64>, d: f64) -> (Matrix4<f64>, Vector4<f64>) {
    let mut m = Matrix5::zeros();
    m.fixed_view_mut::<4, 4>(0, 0).copy_from(&(a * d));
    m.fixed_view_mut::<4, 1>(0, 4).copy_from(&(b * d));
    let e = m.exp();
    (e.fixed_view::<4, 4>(0, 0).into_owned(), e.fixed_view::<4, 1>(0, 4).into_owned())
}

/// Most axes a [`Bank`] holds (a translational and an angular vibration, three axes each).
pub const MAX_AXES: usize = 6;

/// `(value, time derivative)` of every axis of a [`Bank`] at one instant (unit RMS; axes past
/// the bank's count are zero).
pub type Sample = [(f64, f64); MAX_AXES];

/// Independent axes of one process (unit RMS each) advanced on its grid: the state at grid point
/// `n` and the drive held over the step that follows it.
#[derive(Debug, Clone)]
pub struct Bank {
    noise: BandNoise,
    axes: usize,
    x: [Vector4<f64>; MAX_AXES],
    u: [f64; MAX_AXES],
}

impl Bank {
    /// Starts `axes` axes (at most [`MAX_AXES`]) from the stationary distribution and draws the
    /// first step's drive.
    pub fn start<R: Rng + ?Sized>(noise: BandNoise, axes: usize, rng: &mut R) -> Self {
        let axes = axes.min(MAX_AXES);
        let mut x = [Vector4::zeros(); MAX_AXES];
        for xk in x.iter_mut().take(axes) {
            // One standard normal a state in use, in order (the second order draws three).
            let mut z = Vector4::zeros();
            for v in z.iter_mut().take(noise.states) {
                *v = rng.sample::<f64, _>(StandardNormal);
            }
            *xk = noise.start * z;
        }
        let mut b = Self { noise, axes, x, u: [0.0; MAX_AXES] };
        b.draw(rng);
        b
    }

    fn draw<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let s = 1.0 / self.noise.step_s.sqrt();
        for k in 0..self.axes {
            self.u[k] = s * rng.sample::<f64, _>(StandardNormal);
        }
    }

    /// Moves to the next grid point and draws the drive of the step after it.
    pub fn advance<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        for k in 0..self.axes {
            self.x[k] = self.noise.phi * self.x[k] + self.noise.gamma * self.u[k];
        }
        self.draw(rng);
    }

    fn evaluate(&self, phi: &Matrix4<f64>, gamma: &Vector4<f64>) -> Sample {
        let mut out = [(0.0, 0.0); MAX_AXES];
        for (o, (x, u)) in out.iter_mut().zip(self.x.iter().zip(&self.u)).take(self.axes) {
            *o = self.noise.output(&(phi * x + gamma * *u));
        }
        out
    }

    /// Every axis at the current grid point.
    pub fn now(&self) -> Sample {
        let mut out = [(0.0, 0.0); MAX_AXES];
        for (o, x) in out.iter_mut().zip(&self.x).take(self.axes) {
            *o = self.noise.output(x);
        }
        out
    }

    /// Every axis half a step after the current grid point.
    pub fn half(&self) -> Sample {
        self.evaluate(&self.noise.phi_half, &self.noise.gamma_half)
    }

    /// Every axis a full step after the current grid point (the next grid point's, before the
    /// next drive is drawn).
    pub fn next(&self) -> Sample {
        self.evaluate(&self.noise.phi, &self.noise.gamma)
    }

    /// Every axis `d` seconds after the current grid point, `0 <= d <= h`.
    pub fn after(&self, d: f64) -> Sample {
        self.after_with(self.transition_over(d).as_ref())
    }

    /// The exact transition of this bank's process over `d` seconds (`None` at `d <= 0`), for
    /// [`Self::after_with`]: banks of one process share it, and it is a matrix exponential.
    pub fn transition_over(&self, d: f64) -> Option<(Matrix4<f64>, Vector4<f64>)> {
        (d > 0.0).then(|| transition(&self.noise.a, &self.noise.b, d))
    }

    /// [`Self::after`] with its transition given ([`Self::transition_over`] of a bank of the same
    /// process).
    pub fn after_with(&self, transition: Option<&(Matrix4<f64>, Vector4<f64>)>) -> Sample {
        match transition {
            Some((phi, gamma)) => self.evaluate(phi, gamma),
            None => self.now(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use rand::SeedableRng;

    /// The exact transition composes: two half steps are one step, and a step of `d` then
    /// `h - d` with the same held drive is one step.
    #[test]
    fn transitions_compose() {
        let n = BandNoise::new([2.0, 50.0], 1.0, 1e-4).expect("valid");
        let x0 = Vector4::new(0.3, -1.2, 0.7, 0.0);
        let u = 2.5;
        let mid = n.phi_half * x0 + n.gamma_half * u;
        let two = n.phi_half * mid + n.gamma_half * u;
        let one = n.phi * x0 + n.gamma * u;
        assert!((two - one).norm() < 1e-12 * one.norm().max(1.0), "{two} vs {one}");
        let (pa, ga) = transition(&n.a, &n.b, 0.37e-4);
        let (pb, gb) = transition(&n.a, &n.b, 0.63e-4);
        let split = pb * (pa * x0 + ga * u) + gb * u;
        assert!((split - one).norm() < 1e-12 * one.norm().max(1.0));
    }

    /// `(int f^k |H|^2 df) / (int |H|^2 df)` for a band and a low-pass (`|H|^2 = (f/lo)^2 /
    /// (1 + (f/lo)^2) / (1 + (f/hi)^(2 order))`), integrated numerically: the closed form of
    /// `var(y^(k/2)) / var(y) / (2 pi)^k`.
    fn moment_ratio(band: [f64; 2], low_pass: LowPass, k: i32) -> f64 {
        let order = 2 * low_pass.order() as i32;
        let h2 = |f: f64| (f / band[0]).powi(2) / (1.0 + (f / band[0]).powi(2)) / (1.0 + (f / band[1]).powi(order));
        let df = 0.01;
        let (mut total, mut fk) = (0.0, 0.0);
        for i in 0..2_000_000 {
            let f = (i as f64 + 0.5) * df;
            total += h2(f);
            fk += f.powi(k) * h2(f);
        }
        fk / total
    }

    /// Against independent oracles, for each order: the RMS per axis is the one asked for (Monte
    /// Carlo over a long run, started stationary), the output's derivative integrates to the
    /// output's increment over every grid step (Simpson's rule on the derivative at the step's
    /// start, middle and end: the drive is held over a step, so the state is smooth inside it and
    /// Simpson's rule is exact to `(w h)^4 / 2880`), and the spectrum's RMS frequency is the
    /// closed form's (the filter's |H|^2 integrated numerically). For the third order also the
    /// second derivative's: the derivative's increments over the grid steps have the RMS of the
    /// closed form's `y''` (for the second order they grow without bound as the grid is refined).
    ///
    /// (A central difference across grid points is no oracle for the first derivative: its
    /// spectrum falls only as `f^-2` above `f_hi` at the second order, so content up to the drive's
    /// `1 / (2 h)` makes a central difference wrong by about 10 %.)
    #[test]
    fn the_process_has_the_asked_rms_a_consistent_derivative_and_its_band() {
        for low_pass in [LowPass::Second, LowPass::Third] {
            let h = 1e-4;
            let band = [2.0, 50.0];
            let n = BandNoise::with_low_pass(band, 3.0, h, low_pass).expect("valid");
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
            let mut v = Bank::start(n, 3, &mut rng);
            let steps = 400_000; // 40 s
            let mut ys = Vec::with_capacity(steps);
            let mut ds = Vec::with_capacity(steps);
            let (mut err, mut scale, mut dd2) = (0.0, 0.0, 0.0);
            for _ in 0..steps {
                let s = v.now();
                ys.push(Vector3::new(s[0].0, s[1].0, s[2].0));
                ds.push(Vector3::new(s[0].1, s[1].1, s[2].1));
                assert_eq!(s[3], (0.0, 0.0));
                let (mid, end) = (v.half(), v.next());
                for k in 0..3 {
                    let simpson = h / 6.0 * (s[k].1 + 4.0 * mid[k].1 + end[k].1);
                    let increment = end[k].0 - s[k].0;
                    err += (simpson - increment).powi(2);
                    scale += increment.powi(2);
                    dd2 += ((end[k].1 - s[k].1) / h).powi(2);
                }
                v.advance(&mut rng);
            }
            let ms: f64 = ys.iter().map(|y| y.norm_squared()).sum::<f64>() / (3 * steps) as f64;
            // 40 s at a correlation time of about 1/(2 pi 2 Hz): thousands of independent stretches.
            assert!((ms.sqrt() - 3.0).abs() < 0.1, "{low_pass:?}: RMS {}", ms.sqrt());
            // (w_c h)^4 / 2880 ~ 3e-10 for the smooth part; 1e-6 leaves room for rounding.
            assert!((err / scale).sqrt() < 1e-6, "{low_pass:?}: derivative relative error {}", (err / scale).sqrt());
            let two_pi = 2.0 * std::f64::consts::PI;
            let expect_rms_hz = moment_ratio(band, low_pass, 2).sqrt();
            let dms: f64 = ds.iter().map(|d| d.norm_squared()).sum::<f64>() / (3 * steps) as f64;
            let rms_hz = (dms / ms).sqrt() / two_pi;
            assert!(
                (rms_hz / expect_rms_hz - 1.0).abs() < 0.05,
                "{low_pass:?}: RMS frequency {rms_hz} vs {expect_rms_hz}"
            );
            let second = (dd2 / (3 * steps) as f64 / ms).sqrt() / two_pi.powi(2);
            if low_pass == LowPass::Third {
                let expect = moment_ratio(band, low_pass, 4).sqrt();
                assert!((second / expect - 1.0).abs() < 0.05, "third order: y'' RMS ratio {second} vs {expect}");
            } else {
                // The second order's `y''` is the grid's white drive: about 9 times the third's at this grid
                let third = moment_ratio(band, LowPass::Third, 4).sqrt();
                assert!(second > 5.0 * third, "second order: y'' RMS ratio {second} against {third}");
            }
        }
    }

    #[test]
    fn bad_bands_are_refused() {
        assert!(BandNoise::new([50.0, 2.0], 1.0, 1e-4).is_none());
        assert!(BandNoise::new([0.0, 2.0], 1.0, 1e-4).is_none());
        assert!(BandNoise::new([1.0, 2.0], 0.0, 1e-4).is_none());
        assert!(BandNoise::new([1.0, f64::NAN], 1.0, 1e-4).is_none());
    }
}
