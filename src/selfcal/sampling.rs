//! How the parts of a package are sampled in a simulated recording ([`super::simulate`]): the
//! package's own clock, of which the host reads the latest tick's sample, and a first-order
//! anti-alias filter before the package's internal sampling.
//!
//! **Clocks.** A package that declares `sample_clock_hz` and `sample_and_hold` in the array file
//! samples all its parts (accelerometers and gyroscope) at the ticks of its own free-running
//! clock, a [`SampleClock`] in the host's time base: tick `m` is the instant at which
//! [`SampleClock::ticks`] equals `m`. At its instant `t_k` the host reads the sample of the latest
//! tick at or before `t_k` ([`last_tick_s`]); that sample is `t_k - last_tick_s` old, which is
//! [`SampleClock::age_s`] to within the clock's rate offset (`frac(n) / f0` against
//! `frac(n) / (f0 (1 + eps))`, below 0.3 % of the age for this board's clocks). The clocks are
//! drawn per recording ([`draw_clocks`]): a rate offset per package plus one common to every
//! package, one slow drift common to every package, and a phase uniform over one period.
//!
//! **Anti-alias filter.** `y' = (x - y) / tau` on a part's noise-free output, integrated on the
//! simulator's fine grid with the input linear between grid points ([`FirstOrder`]); its group
//! delay at low frequency is `tau`.

use rand::{Rng, RngExt};
use rand_distr::{Distribution, Normal, Uniform};

use super::clock::SampleClock;
use crate::array::wiring::Package;

/// A distribution of one clock quantity, SI (a rate offset as a fraction, a drift in 1/s).
#[derive(Debug, Clone, PartialEq)]
pub enum Spread {
    Normal {
        mean: f64,
        sigma: f64,
    },
    Uniform {
        mean: f64,
        half_width: f64,
    },
    /// One value for every package, or one per package of the array file (in its order).
    Fixed(Vec<f64>),
}

impl Spread {
    /// A draw for package `p` (the index into the array file's packages).
    pub fn draw<R: Rng + ?Sized>(&self, p: usize, rng: &mut R) -> f64 {
        match self {
            Spread::Normal { mean, sigma } => {
                if *sigma > 0.0 {
                    Normal::new(*mean, *sigma).map(|d| d.sample(rng)).unwrap_or(*mean)
                } else {
                    *mean
                }
            }
            Spread::Uniform { mean, half_width } => {
                if *half_width > 0.0 {
                    Uniform::new(mean - half_width, mean + half_width).map(|d| d.sample(rng)).unwrap_or(*mean)
                } else {
                    *mean
                }
            }
            Spread::Fixed(v) => match v.len() {
                0 => 0.0,
                1 => v[0],
                _ => v.get(p).copied().unwrap_or(0.0),
            },
        }
    }

    pub fn zero() -> Self {
        Spread::Fixed(vec![0.0])
    }
}

/// The distributions of the packages' clocks in one recording.
#[derive(Debug, Clone, PartialEq)]
pub struct ClockSpread {
    /// Each package's rate offset `f / f0 - 1` (positive: fast).
    pub rate_offset: Spread,
    /// A rate offset common to every package of a recording (the host's own clock against the
    /// packages' crystal: on the MIMU4444 it moves by up to 200 ppm between recordings).
    pub common_rate_offset: Spread,
    /// The slow drift of every package's rate offset, common to the packages, 1/s.
    pub drift_per_s: Spread,
}

/// One recording's clocks: `Some` for every package whose array-file entry declares a sample
/// clock read by sample-and-hold, `None` for the others. Draws the common rate offset, the
/// drift, then per such package (in the array file's order) its rate offset and its phase
/// (uniform over one period at `t_ref_s`).
pub fn draw_clocks<R: Rng + ?Sized>(
    packages: &[Package],
    spread: &ClockSpread,
    t_ref_s: f64,
    rng: &mut R,
) -> Vec<Option<SampleClock>> {
    let common = spread.common_rate_offset.draw(0, rng);
    let drift = spread.drift_per_s.draw(0, rng);
    packages
        .iter()
        .enumerate()
        .map(|(p, pkg)| {
            let f0 = pkg.sample_clock_hz.filter(|_| pkg.free_running())?;
            let eps = spread.rate_offset.draw(p, rng) + common;
            let phase_s = rng.random_range(0.0..1.0) / f0;
            Some(SampleClock { nominal_hz: f0, rate_offset: eps, drift_per_s: drift, phase_s, t_ref_s })
        })
        .collect()
}

/// The instant of the clock's latest tick at or before `t_s` (the host's time base): where
/// [`SampleClock::ticks`] equals `floor(ticks(t_s))`, by Newton's method on the clock's quadratic
/// from `t_s` (its rate is within a fraction of a percent of nominal: three steps reach rounding).
pub fn last_tick_s(clock: &SampleClock, t_s: f64) -> f64 {
    let n = clock.ticks(t_s);
    let target = n.floor();
    let mut t = t_s - (n - target) / clock.nominal_hz;
    for _ in 0..3 {
        let x = t - clock.t_ref_s;
        let rate = clock.nominal_hz * (1.0 + clock.rate_offset + clock.drift_per_s * x);
        t -= (clock.ticks(t) - target) / rate;
    }
    t.min(t_s)
}

/// A bank of first-order low-pass filters with one time constant each, on a grid: the input is
/// taken linear between the points the filter is moved through.
#[derive(Debug, Clone)]
pub struct FirstOrder {
    tau_s: Vec<f64>,
    /// The inputs and outputs at the last point moved to.
    x: Vec<f64>,
    y: Vec<f64>,
}

impl FirstOrder {
    /// Filters at rest at input `x0` (their outputs equal to it), time constants `tau_s` (0: the
    /// filter passes its input).
    pub fn at_rest(tau_s: Vec<f64>, x0: &[f64]) -> Self {
        Self { tau_s, x: x0.to_vec(), y: x0.to_vec() }
    }

    /// The output of filter `j` after `d` seconds more, the input going linearly from its last
    /// value to `x1`: `y(d) = e y0 + (1 - e) x0 + (x1 - x0) (1 - tau (1 - e) / d)`, `e = exp(-d / tau)`
    /// (exact for a linear input).
    pub fn peek(&self, j: usize, d: f64, x1: f64) -> f64 {
        let tau = self.tau_s[j];
        let (x0, y0) = (self.x[j], self.y[j]);
        if tau <= 0.0 {
            return x1;
        }
        if d <= 0.0 {
            return y0;
        }
        let r = d / tau;
        let e = (-r).exp();
        // 1 - (1 - e) / r, by its series where r is small (cancellation)
        let ramp = if r < 1e-4 { r / 2.0 - r * r / 6.0 } else { 1.0 - (1.0 - e) / r };
        e * y0 + (1.0 - e) * x0 + (x1 - x0) * ramp
    }

    /// Moves every filter `d` seconds on, to inputs `x1`.
    pub fn advance(&mut self, d: f64, x1: &[f64]) {
        for (j, &x) in x1.iter().enumerate().take(self.y.len()) {
            self.y[j] = self.peek(j, d, x);
            self.x[j] = x;
        }
    }

    /// Sets every filter at rest at input `x` (after a long constant input).
    pub fn rest(&mut self, x: &[f64]) {
        self.x.copy_from_slice(x);
        self.y.copy_from_slice(x);
    }

    pub fn len(&self) -> usize {
        self.y.len()
    }

    pub fn is_empty(&self) -> bool {
        self.y.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The latest tick: `ticks` there is a whole number, at most one period before `t`, and the
    /// age it implies is `age_s` to within the rate offset's share of it.
    #[test]
    fn the_latest_tick_is_a_whole_tick_at_most_one_period_back() {
        let c = SampleClock {
            nominal_hz: 1000.0,
            rate_offset: -2.5e-3,
            drift_per_s: 3e-7,
            phase_s: 0.4e-3,
            t_ref_s: 300.0,
        };
        for k in 0..20_000 {
            let t = k as f64 * 0.016 + 0.003;
            let tick = last_tick_s(&c, t);
            let n = c.ticks(tick);
            assert!((n - n.round()).abs() < 1e-7, "t {t}: ticks {n}");
            assert!(tick <= t && t - tick < 1.0e-3 / (1.0 - 3e-3), "t {t}: tick {tick}");
            let age = t - tick;
            assert!((age - c.age_s(t)).abs() <= 3e-3 * 1e-3 + 1e-12, "t {t}: age {age} vs {}", c.age_s(t));
        }
    }

    /// A first-order filter against its closed form: a ramp input `x = s t` from rest settles to
    /// `s (t - tau)` (a delay of tau), and a step to `1 - exp(-t / tau)`, whatever the grid.
    #[test]
    fn the_filter_follows_its_closed_form() {
        let tau = 1.5e-3;
        let mut f = FirstOrder::at_rest(vec![tau], &[0.0]);
        let h = 1e-4;
        let slope = 7.0;
        let mut t: f64 = 0.0;
        for _ in 0..200 {
            t += h;
            f.advance(h, &[slope * t]);
        }
        let exact = slope * (t - tau + tau * (-t / tau).exp());
        assert!((f.y[0] - exact).abs() < 1e-12, "{} vs {exact}", f.y[0]);
        let mut g = FirstOrder::at_rest(vec![tau], &[1.0]);
        g.x[0] = 1.0;
        g.y[0] = 0.0;
        let mut t: f64 = 0.0;
        for d in [0.3e-4, 1e-4, 0.7e-4, 2e-4] {
            t += d;
            g.advance(d, &[1.0]);
        }
        assert!((g.y[0] - (1.0 - (-t / tau).exp())).abs() < 1e-14);
        assert_eq!(FirstOrder::at_rest(vec![0.0], &[2.0]).peek(0, 1e-4, 3.0), 3.0);
    }
}
