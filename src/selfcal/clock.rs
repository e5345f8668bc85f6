//! A package's free-running sample clock, read by sample-and-hold, and its estimation from
//! per-sample time offsets.
//!
//! **The effect.** A package (chip) refreshes its output registers at the ticks of its own clock,
//! nominally `f0` Hz; the host reads every package once per host sample and gets the latest
//! refresh, so each sample is `age` seconds old, `0 <= age < 1 / f0`. The packet time stamps
//! cannot show it. The package's clock counts
//!
//! ```text
//! n(t) = f0 [ (1 + eps) x + eps_dot x^2 / 2 ] + f0 phase,   x = t - t_ref
//! age(t) = frac(n(t)) / f0
//! ```
//!
//! ticks at host time `t`, with `eps = f / f0 - 1` the clock's rate offset in the host's time base
//! (positive: the package runs fast), `eps_dot` its slow drift (1/s) and `phase` the age at
//! `t_ref` (s). A fast package's age grows by `R eps / f0` per host sample (`R = f0 dt` ticks a
//! sample) and drops by one period when it wraps; a slow one's shrinks and jumps up. Between
//! wraps the age is smooth in the parameters: `d age / d (eps, eps_dot, phase) = (x, x^2 / 2, 1)`.
//!
//! **What a recording sees.** A sample of age `a` is the signal at `t - a`: a specific force `q`
//! reads `q - a dq/dt` to first order. A shift common to every package is a rigid motion at
//! another time and the per-sample motion absorbs it, so only the ages relative to their mean
//! over the packages, [`relative_ages`], enter the model. Their beat makes each package's
//! relative age a sawtooth in the host's samples; its rate and phase are found here by a matched
//! filter ([`search`]) and refined by Gauss-Newton with the wraps re-assigned after every step
//! ([`refine`]). The common part of the clocks still moves the wraps (each package wraps at its
//! own samples), which is how it is seen at all.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

/// One package's sample clock in the host's time base (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleClock {
    /// Nominal rate `f0`, Hz.
    pub nominal_hz: f64,
    /// `f / f0 - 1` in the host's time base (positive: the package runs fast).
    pub rate_offset: f64,
    /// The rate offset's slow drift, 1/s.
    pub drift_per_s: f64,
    /// The age at `t_ref_s`, s, in `[0, 1 / f0)`.
    pub phase_s: f64,
    /// The time the phase is given at, s (host time base).
    pub t_ref_s: f64,
}

impl SampleClock {
    /// Ticks counted at host time `t_s` (fractional part: how far into the current period).
    pub fn ticks(&self, t_s: f64) -> f64 {
        let x = t_s - self.t_ref_s;
        self.nominal_hz * ((1.0 + self.rate_offset) * x + 0.5 * self.drift_per_s * x * x + self.phase_s)
    }

    /// The age of the sample the host reads at `t_s`, s: `0 <= age < 1 / f0`.
    pub fn age_s(&self, t_s: f64) -> f64 {
        let n = self.ticks(t_s);
        (n - floor(n)) / self.nominal_hz
    }

    /// `d age / d (rate_offset, drift_per_s, phase_s)` at `t_s`, the wraps held.
    /// How many of its periods the sawtooth sweeps through when read at the host's samples
    /// `t_s` (host step `host_dt_s`): the range over the samples of its ticks less the whole
    /// ticks of the host steps, `n(t) - round(f0 dt) (t - t_0) / dt` (drift included). Below 1
    /// it does not complete a period: at most one of its wraps falls among the samples.
    pub fn periods_over(&self, t_s: &[f64], host_dt_s: f64) -> f64 {
        let Some(&t0) = t_s.first() else { return 0.0 };
        let whole = (self.nominal_hz * host_dt_s).round();
        let (lo, hi) = t_s.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| {
            let x = self.ticks(t) - whole * (t - t0) / host_dt_s;
            (lo.min(x), hi.max(x))
        });
        (hi - lo).max(0.0)
    }

    pub fn age_partials(&self, t_s: f64) -> [f64; 3] {
        let x = t_s - self.t_ref_s;
        [x, 0.5 * x * x, 1.0]
    }

    /// The clock moved by `d` in `(rate_offset, drift_per_s, phase_s)`, the phase wrapped into
    /// one period.
    pub fn moved(&self, d: [f64; 3]) -> Self {
        let period = 1.0 / self.nominal_hz;
        let phase = (self.phase_s + d[2]).rem_euclid(period);
        Self { rate_offset: self.rate_offset + d[0], drift_per_s: self.drift_per_s + d[1], phase_s: phase, ..*self }
    }

    /// The same clock with its phase given at another time.
    pub fn at_reference(&self, t_ref_s: f64) -> Self {
        let x = t_ref_s - self.t_ref_s;
        let n = self.ticks(t_ref_s);
        Self {
            rate_offset: self.rate_offset + self.drift_per_s * x,
            phase_s: (n - n.floor()) / self.nominal_hz,
            t_ref_s,
            ..*self
        }
    }
}

/// `x.floor()`, the same value, without a call into the maths library: the crate is built for
/// baseline x86-64, which has no rounding instruction, and the sample clocks' grid search
/// ([`refine_grid`]) takes the fractional part of millions of tick counts. Beyond `2^52` every
/// float is an integer, and NaN stays NaN through `x - floor(x)`.
#[inline]
fn floor(x: f64) -> f64 {
    if x.abs() < 4.0e15 {
        let t = x as i64 as f64;
        // an integer (and -0.0) is its own floor
        if t == x {
            x
        } else if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        x.floor()
    }
}

/// Every package's age at `t_s` less their mean, s (packages without a clock have age 0).
pub fn relative_ages(clocks: &[Option<SampleClock>], t_s: f64, out: &mut [f64]) {
    let mut mean = 0.0;
    for (o, c) in out.iter_mut().zip(clocks) {
        *o = c.map_or(0.0, |c| c.age_s(t_s));
        mean += *o;
    }
    mean /= clocks.len().max(1) as f64;
    for o in out.iter_mut() {
        *o -= mean;
    }
}

/// Per-sample time offsets of one package (s, positive: late), on the host's samples.
#[derive(Debug, Clone)]
pub struct Offsets {
    /// Host sample index of each offset (from the recording's start).
    pub sample: Vec<i64>,
    pub t_s: Vec<f64>,
    pub offset_s: Vec<f64>,
    /// Least-squares weights (inverse variances, 1/s^2).
    pub weight: Vec<f64>,
}

/// The integer number of ticks nearest one host sample period, and the aliasing it implies: the
/// sawtooth advances by `frac(R (1 + eps))` cycles a host sample, `R = f0 dt`.
fn ticks_per_sample(nominal_hz: f64, host_dt_s: f64) -> f64 {
    nominal_hz * host_dt_s
}

/// The rate offset and phase (at `t_ref_s`) of the rising sawtooth of period `1 / f0` that best
/// correlates with the offsets (any scale and constant), over `|rate offset| <= max_rate_offset`:
/// a matched filter of six harmonics, one FFT of the weighted offsets on the host's sample grid.
///
/// The offsets' sawtooth advances by `nu = frac(R (1 + eps))` cycles a sample (`R = f0 dt`), so
/// `eps` is found modulo `1 / R` (6.25% for the MIMU4444's R = 16): well beyond any clock's
/// tolerance. Returns `None` with fewer than 16 offsets.
pub fn search(
    offsets: &Offsets,
    nominal_hz: f64,
    host_dt_s: f64,
    t_ref_s: f64,
    max_rate_offset: f64,
) -> Option<SampleClock> {
    let n = offsets.sample.len();
    if n < 16 {
        return None;
    }
    let k0 = *offsets.sample.iter().min()?;
    let span = (*offsets.sample.iter().max()? - k0 + 1) as usize;
    let len = (8 * span).next_power_of_two().max(1 << 16);
    let wsum: f64 = offsets.weight.iter().sum();
    let mean = offsets.weight.iter().zip(&offsets.offset_s).map(|(w, y)| w * y).sum::<f64>() / wsum;
    let mut buf = vec![Complex::new(0.0, 0.0); len];
    for i in 0..n {
        buf[(offsets.sample[i] - k0) as usize].re += offsets.weight[i] * (offsets.offset_s[i] - mean);
    }
    FftPlanner::new().plan_fft_forward(len).process(&mut buf);
    // S(nu) = sum_k x_k exp(2 pi i nu k) = conj(X[nu len]) for nu = m / len.
    let s_at = |m: i64| -> Complex<f64> { buf[m.rem_euclid(len as i64) as usize].conj() };
    let r = ticks_per_sample(nominal_hz, host_dt_s);
    let whole = r.round();
    let base = r - whole; // nu at eps = 0 (aliased)
    let nu_of = |eps: f64| base + r * eps;
    let m_lo = (nu_of(-max_rate_offset) * len as f64).floor() as i64;
    let m_hi = (nu_of(max_rate_offset) * len as f64).ceil() as i64;
    const HARMONICS: i64 = 6;
    const PHASES: usize = 64;
    // exp(2 pi i h phi) for every phase and harmonic, the same at every frequency.
    let rotations: Vec<[Complex<f64>; HARMONICS as usize]> = (0..PHASES)
        .map(|p| {
            let phi = p as f64 / PHASES as f64;
            std::array::from_fn(|h| Complex::from_polar(1.0, 2.0 * std::f64::consts::PI * (h + 1) as f64 * phi))
        })
        .collect();
    let mut best = (f64::NEG_INFINITY, 0i64, 0.0);
    for m in m_lo..=m_hi {
        let s: [Complex<f64>; HARMONICS as usize] = std::array::from_fn(|h| s_at((h as i64 + 1) * m));
        for (p, rotation) in rotations.iter().enumerate() {
            let phi = p as f64 / PHASES as f64;
            // correlation with frac(nu k + phi) - 1/2 = -sum_h sin(2 pi h (nu k + phi)) / (pi h)
            let c: f64 = s
                .iter()
                .zip(rotation)
                .enumerate()
                .map(|(h, (sh, rot))| {
                    let h = (h + 1) as f64;
                    -(rot * sh).im / (std::f64::consts::PI * h)
                })
                .sum();
            if c > best.0 {
                best = (c, m, phi);
            }
        }
    }
    let nu = best.1 as f64 / len as f64;
    let eps = (nu - base) / r;
    // The sawtooth's phase at sample k0 is `phi` cycles: the clock's ticks there are `phi` past a
    // tick, i.e. its age at t(k0) is phi / f0; carry it to t_ref.
    let t0 = offsets.t_s[offsets.sample.iter().position(|&k| k == k0)?];
    let at_k0 =
        SampleClock { nominal_hz, rate_offset: eps, drift_per_s: 0.0, phase_s: best.2 / nominal_hz, t_ref_s: t0 };
    Some(at_k0.at_reference(t_ref_s))
}

/// A clock fitted to one package's offsets: `offset = amplitude * age + constant`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetFit {
    pub clock: SampleClock,
    /// The fitted scale of the sawtooth (1 for a clean measurement of the age; below 1 where the
    /// offsets are diluted by noise in their regressor).
    pub amplitude: f64,
    /// The amplitude's standard deviation (from the residual scatter): a sawtooth the offsets
    /// really hold has `amplitude / amplitude_sigma` in the tens or more.
    pub amplitude_sigma: f64,
    pub constant_s: f64,
    /// Weighted residual sum of squares and the number of offsets.
    pub cost: f64,
    pub count: usize,
}

impl OffsetFit {
    /// Whether the offsets show the sawtooth: its scale (1 for a clean measurement of a clock
    /// read by sample-and-hold) above 0.25 and 10 sigma.
    pub fn shows_sawtooth(&self) -> bool {
        self.amplitude > 10.0 * self.amplitude_sigma && self.amplitude > 0.25
    }
}

/// The amplitude's sigma of [`linear_part`] at a clock: `sqrt(cost / (N - 2) * S1 / det)`.
fn amplitude_sigma(offsets: &Offsets, target: &[f64], clock: &SampleClock) -> f64 {
    let (mut saa, mut sa, mut s1) = (0.0, 0.0, 0.0);
    for i in 0..offsets.t_s.len() {
        let (w, a) = (offsets.weight[i], clock.age_s(offsets.t_s[i]));
        saa += w * a * a;
        sa += w * a;
        s1 += w;
    }
    let (_, _, cost) = linear_part(offsets, target, clock);
    let dof = (offsets.t_s.len() as f64 - 2.0).max(1.0);
    (cost / dof * s1 / (saa * s1 - sa * sa)).sqrt()
}

/// Weighted least squares of the offsets on `(age, 1)` at a given clock, the amplitude held at
/// or above 0: amplitude, constant and cost. An age rises between wraps, so a falling sawtooth
/// (the mirror `age -> period - age` of another clock, which fits the offsets as well with the
/// amplitude negated) is no sawtooth of this clock: there the fit is the constant alone, and a
/// search over clocks cannot settle on a mirror.
fn linear_part(offsets: &Offsets, target: &[f64], clock: &SampleClock) -> (f64, f64, f64) {
    let (mut saa, mut sa, mut s1, mut say, mut sy, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for ((&t, &w), &y) in offsets.t_s.iter().zip(&offsets.weight).zip(target) {
        let a = clock.age_s(t);
        saa += w * a * a;
        sa += w * a;
        s1 += w;
        say += w * a * y;
        sy += w * y;
        syy += w * y * y;
    }
    fit_from_moments([saa, sa, s1, say, sy, syy])
}

/// [`linear_part`]'s least squares from its weighted moments `[sum w a^2, sum w a, sum w,
/// sum w a y, sum w y, sum w y^2]`: amplitude (held at or above 0), constant and cost.
fn fit_from_moments([saa, sa, s1, say, sy, syy]: [f64; 6]) -> (f64, f64, f64) {
    let det = saa * s1 - sa * sa;
    if det.abs() < 1e-300 {
        return (0.0, sy / s1.max(1e-300), syy - sy * sy / s1.max(1e-300));
    }
    let amp = (say * s1 - sa * sy) / det;
    if amp < 0.0 {
        return (0.0, sy / s1.max(1e-300), (syy - sy * sy / s1.max(1e-300)).max(0.0));
    }
    let c = (saa * sy - sa * say) / det;
    let cost = syy - amp * say - c * sy;
    (amp, c, cost.max(0.0))
}

/// A grid around `start` over rate offset (+-`rate_span`), drift (+-`drift_span`, 1/s; none
/// when 0) and phase (+-0.2 of a period), shrunk four times per level over three levels, the
/// amplitude and constant solved linearly at every point. The misfit jumps where a wrap moves
/// past a sample, so a grid, not a gradient, finds its basin. Every phase of a (rate, drift)
/// point is scored at once by [`PhaseScan`].
pub fn refine_grid(
    offsets: &Offsets,
    target: &[f64],
    start: &SampleClock,
    rate_span: f64,
    drift_span: f64,
) -> OffsetFit {
    let period = 1.0 / start.nominal_hz;
    let mut best = *start;
    let (_, _, mut best_cost) = linear_part(offsets, target, &best);
    let (mut de, mut dd, mut dp) = (rate_span, drift_span, 0.2 * period);
    let mut scan = PhaseScan::new(offsets, target);
    for _level in 0..3 {
        let center = best;
        let (ne, nd, np) = (8i32, if drift_span > 0.0 { 6 } else { 0 }, 16i32);
        for ie in -ne..=ne {
            for id in -nd..=nd {
                let base = center.moved([de * ie as f64 / ne as f64, dd * id as f64 / nd.max(1) as f64, 0.0]);
                let step_s = dp / np as f64;
                scan.bin(offsets, &base, step_s, np as usize);
                for ip in -np..=np {
                    let cost = scan.cost(ip);
                    if cost < best_cost {
                        best_cost = cost;
                        best = base.moved([0.0, 0.0, step_s * ip as f64]);
                    }
                }
            }
        }
        de /= 4.0;
        dd /= 4.0;
        dp /= 4.0;
    }
    let (amplitude, constant_s, cost) = linear_part(offsets, target, &best);
    let amplitude_sigma = amplitude_sigma(offsets, target, &best);
    OffsetFit { clock: best, amplitude, amplitude_sigma, constant_s, cost, count: offsets.t_s.len() }
}

/// [`linear_part`]'s cost at one clock and every phase shift `k h`, `|k| <= K`, in one pass
/// over the offsets instead of `2K + 1`. With `u = frac(n)` a sample's ticks into its period at
/// the unshifted clock, the shifted age is `(u + k h f0 - c) / f0` where `c` is 1 for the samples
/// the shift wraps forward (`u + k h f0 >= 1`) and -1 for those it wraps back (`u + k h f0 < 0`).
/// Those are the samples whose `u` passes a threshold, so each sample is binned once by the first
/// shift that wraps it, and the wrapped samples' sums of `w`, `w u` and `w y` at every shift are
/// running sums over the bins; the moments of the age follow from them exactly.
struct PhaseScan {
    /// Totals over the samples: `w`, `w y`, `w y^2` (independent of the clock).
    s1: f64,
    sy: f64,
    syy: f64,
    /// Totals of `w u`, `w u^2`, `w u y` at the unshifted clock.
    su: f64,
    suu: f64,
    suy: f64,
    /// Per shift `k` (0..=K): the sums `(w, w u, w y)` over the samples first wrapped at
    /// `+k` (forward) and at `-k` (back), then made cumulative.
    forward: Vec<[f64; 3]>,
    back: Vec<[f64; 3]>,
    /// The shift in ticks, `h f0`, and the nominal rate.
    step_ticks: f64,
    nominal_hz: f64,
    /// Per sample `w y` (fixed).
    wy: Vec<f64>,
}

impl PhaseScan {
    fn new(offsets: &Offsets, target: &[f64]) -> Self {
        let (mut s1, mut sy, mut syy) = (0.0, 0.0, 0.0);
        let wy: Vec<f64> = offsets.weight.iter().zip(target).map(|(w, y)| w * y).collect();
        for ((&w, &y), &wy) in offsets.weight.iter().zip(target).zip(&wy) {
            s1 += w;
            sy += wy;
            syy += wy * y;
        }
        Self {
            s1,
            sy,
            syy,
            su: 0.0,
            suu: 0.0,
            suy: 0.0,
            forward: Vec::new(),
            back: Vec::new(),
            step_ticks: 0.0,
            nominal_hz: 1.0,
            wy,
        }
    }

    /// Bins the samples at `clock` for the shifts `k step_s`, `|k| <= max_shift`.
    fn bin(&mut self, offsets: &Offsets, clock: &SampleClock, step_s: f64, max_shift: usize) {
        self.nominal_hz = clock.nominal_hz;
        self.step_ticks = step_s * clock.nominal_hz;
        let h = self.step_ticks;
        self.forward.clear();
        self.forward.resize(max_shift + 1, [0.0; 3]);
        self.back.clear();
        self.back.resize(max_shift + 1, [0.0; 3]);
        let (mut su, mut suu, mut suy) = (0.0, 0.0, 0.0);
        for (i, &t) in offsets.t_s.iter().enumerate() {
            let n = clock.ticks(t);
            let u = n - floor(n);
            let (w, wy) = (offsets.weight[i], self.wy[i]);
            let sums = [w, w * u, wy];
            su += sums[1];
            suu += sums[1] * u;
            suy += wy * u;
            if h > 0.0 {
                // first k >= 1 with u + k h >= 1, and first k >= 1 with u - k h < 0
                let mut kf = ((1.0 - u) / h).ceil().max(1.0) as usize;
                while kf > 1 && u + (kf - 1) as f64 * h >= 1.0 {
                    kf -= 1;
                }
                while kf <= max_shift && u + kf as f64 * h < 1.0 {
                    kf += 1;
                }
                if kf <= max_shift {
                    add(&mut self.forward[kf], &sums);
                }
                let mut kb = ((u / h).floor() + 1.0).max(1.0) as usize;
                while kb > 1 && u - (kb - 1) as f64 * h < 0.0 {
                    kb -= 1;
                }
                while kb <= max_shift && u - kb as f64 * h >= 0.0 {
                    kb += 1;
                }
                if kb <= max_shift {
                    add(&mut self.back[kb], &sums);
                }
            }
        }
        for k in 1..=max_shift {
            let (f, b) = (self.forward[k - 1], self.back[k - 1]);
            add(&mut self.forward[k], &f);
            add(&mut self.back[k], &b);
        }
        (self.su, self.suu, self.suy) = (su, suu, suy);

        fn add(a: &mut [f64; 3], b: &[f64; 3]) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
    }

    /// [`linear_part`]'s cost at the binned clock's phase moved by `k` steps.
    fn cost(&self, k: i32) -> f64 {
        let s = k as f64 * self.step_ticks;
        let (wrapped, c) = if k >= 0 { (self.forward[k as usize], 1.0) } else { (self.back[(-k) as usize], -1.0) };
        let [ww, wu, wy] = wrapped;
        // sums of w b, w b^2, w b y with b = u - c over the wrapped samples, u elsewhere
        let b1 = self.su - c * ww;
        let b2 = self.suu - 2.0 * c * wu + ww;
        let by = self.suy - c * wy;
        let f0 = self.nominal_hz;
        let sa = (b1 + s * self.s1) / f0;
        let saa = (b2 + 2.0 * s * b1 + s * s * self.s1) / (f0 * f0);
        let say = (by + s * self.sy) / f0;
        fit_from_moments([saa, sa, self.s1, say, self.sy, self.syy]).2
    }
}

/// Gauss-Newton on `(rate offset, drift, phase, amplitude, constant)` from `start`, with the
/// samples within 5% of a period of a wrap left out of each step (which side of the wrap they
/// fall on is what a step may change) and the wraps re-assigned after it; a step is kept when the
/// whole misfit falls.
pub fn refine(offsets: &Offsets, target: &[f64], start: &SampleClock, with_drift: bool) -> OffsetFit {
    let mut clock = *start;
    let (mut amp, mut c0, mut cost) = linear_part(offsets, target, &clock);
    for _ in 0..8 {
        let dim = if with_drift { 5 } else { 4 };
        let mut h = nalgebra::DMatrix::<f64>::zeros(dim, dim);
        let mut g = nalgebra::DVector::<f64>::zeros(dim);
        for (t, w, y, fr) in away_from_wraps(offsets, target, &clock) {
            let age = fr / clock.nominal_hz;
            let p = clock.age_partials(t);
            let r = y - amp * age - c0;
            let row: Vec<f64> = if with_drift {
                vec![amp * p[0], amp * p[1], amp * p[2], age, 1.0]
            } else {
                vec![amp * p[0], amp * p[2], age, 1.0]
            };
            for a in 0..dim {
                g[a] += w * row[a] * r;
                for b in 0..dim {
                    h[(a, b)] += w * row[a] * row[b];
                }
            }
        }
        let Some(step) = h.clone().cholesky().map(|ch| ch.solve(&g)) else { break };
        let d = if with_drift { [step[0], step[1], step[2]] } else { [step[0], 0.0, step[1]] };
        let Some((trial, cost2, (a2, c2))) = halving_step(&clock, d, cost, |c| {
            let (a, c0, cost) = linear_part(offsets, target, c);
            (cost, (a, c0))
        }) else {
            break;
        };
        (clock, amp, c0, cost) = (trial, a2, c2, cost2);
    }
    let amplitude_sigma = amplitude_sigma(offsets, target, &clock);
    OffsetFit { clock, amplitude: amp, amplitude_sigma, constant_s: c0, cost, count: offsets.t_s.len() }
}

/// The samples of `offsets` (time, weight, target and the fraction of a period `clock` has
/// ticked) within 5% of a period of a wrap left out: which side of the wrap they fall on is what
/// a step of [`refine`] or [`refine_held`] may change.
fn away_from_wraps<'a>(
    offsets: &'a Offsets,
    target: &'a [f64],
    clock: &'a SampleClock,
) -> impl Iterator<Item = (f64, f64, f64, f64)> + 'a {
    offsets.t_s.iter().zip(&offsets.weight).zip(target).filter_map(|((&t, &w), &y)| {
        let n = clock.ticks(t);
        let fr = n - floor(n);
        (0.05..=0.95).contains(&fr).then_some((t, w, y, fr))
    })
}

/// The step search of [`refine`] and [`refine_held`]: `clock` moved by `step` (rate offset,
/// drift, phase), halved up to five times, until `cost_of` falls below `cost`. The first such
/// trial, its cost and what `cost_of` found beside it; `None` where none falls.
fn halving_step<T>(
    clock: &SampleClock,
    step: [f64; 3],
    cost: f64,
    cost_of: impl Fn(&SampleClock) -> (f64, T),
) -> Option<(SampleClock, f64, T)> {
    let mut scale = 1.0;
    for _ in 0..6 {
        let trial = clock.moved([step[0] * scale, step[1] * scale, step[2] * scale]);
        let (c, beside) = cost_of(&trial);
        if c < cost {
            return Some((trial, c, beside));
        }
        scale *= 0.5;
    }
    None
}

/// Gauss-Newton on `(rate offset, drift, phase)` with the sawtooth's scale and constant held at
/// `amplitude` and `constant_s`, from ten phases a tenth of a period apart (the best kept): for a
/// package whose sawtooth does not complete a period, whose age is a ramp without a wrap, so
/// that a free scale and constant take up its level and leave the phase unmeasured. Held at the
/// other packages' values, the offsets' level is the age's.
fn refine_held(offsets: &Offsets, target: &[f64], start: &SampleClock, amplitude: f64, constant_s: f64) -> OffsetFit {
    let cost_at = |c: &SampleClock| -> f64 {
        offsets
            .t_s
            .iter()
            .zip(&offsets.weight)
            .zip(target)
            .map(|((&t, &w), &y)| w * (y - amplitude * c.age_s(t) - constant_s).powi(2))
            .sum()
    };
    const STARTS: usize = 10;
    let period_s = 1.0 / start.nominal_hz;
    let mut best: Option<(SampleClock, f64)> = None;
    for k in 0..STARTS {
        let mut clock = start.moved([0.0, 0.0, k as f64 * period_s / STARTS as f64]);
        let mut cost = cost_at(&clock);
        for _ in 0..8 {
            let mut h = nalgebra::Matrix3::<f64>::zeros();
            let mut g = nalgebra::Vector3::<f64>::zeros();
            for (t, w, y, fr) in away_from_wraps(offsets, target, &clock) {
                let r = y - amplitude * fr / clock.nominal_hz - constant_s;
                let row = nalgebra::Vector3::from(clock.age_partials(t)) * amplitude;
                g += row * (w * r);
                h += row * row.transpose() * w;
            }
            let Some(step) = h.cholesky().map(|ch| ch.solve(&g)) else { break };
            let Some((trial, c, ())) = halving_step(&clock, [step[0], step[1], step[2]], cost, |c| (cost_at(c), ()))
            else {
                break;
            };
            (clock, cost) = (trial, c);
        }
        if best.is_none_or(|(_, b)| cost < b) {
            best = Some((clock, cost));
        }
    }
    let (clock, cost) = best.unwrap_or((*start, f64::INFINITY));
    OffsetFit {
        clock,
        amplitude,
        amplitude_sigma: amplitude_sigma(offsets, target, &clock),
        constant_s,
        cost,
        count: offsets.t_s.len(),
    }
}

/// The clocks of several packages from their offsets relative to the packages' mean (as the
/// gyroscopes measure them, or the accelerometers): each package's sawtooth found by [`search`]
/// on its own offsets, then refined in turn against its offsets plus the others' current mean
/// age (three sweeps), so that the mean of the others is not left in its target.
pub fn fit_packages(
    offsets: &[Offsets],
    nominal_hz: &[f64],
    host_dt_s: f64,
    t_ref_s: f64,
    max_rate_offset: f64,
) -> Option<Vec<OffsetFit>> {
    use rayon::prelude::*;
    let p = offsets.len();
    // Each package on its own first (in parallel): the matched filter, then the grid and
    // Gauss-Newton on its own offsets.
    let mut fits: Vec<OffsetFit> = offsets
        .par_iter()
        .zip(nominal_hz)
        .map(|(o, &f0)| {
            let c = search(o, f0, host_dt_s, t_ref_s, max_rate_offset)?;
            let last = o.t_s.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let first = o.t_s.iter().cloned().fold(f64::INFINITY, f64::min);
            let half_s = 0.5 * (last - first);
            // the drift that moves the phase by about a third of a period at the ends
            let drift_span = 0.6 / (f0 * half_s * half_s).max(1e-300);
            let rate_span = 2.0 / (f0 * 2.0 * half_s).max(1e-300);
            let grid = refine_grid(o, &o.offset_s, &c, rate_span, drift_span);
            Some(refine(o, &o.offset_s, &grid.clock, true))
        })
        .collect::<Option<Vec<_>>>()?;
    // A package whose offsets do not show its sawtooth (its scale not significant:
    // [`OffsetFit::shows_sawtooth`]) may be one whose clock runs within a few ppm of a whole
    // multiple of the host's rate: its age is then a ramp without a wrap, whose level a free scale
    // and constant take up. It is refitted with the scale and constant held at the median of the
    // packages that show theirs ([`refine_held`]), started at a zero rate offset and their median
    // drift, and kept if its sawtooth then does not complete a period (else its free fit stands,
    // and the calibration's check refuses it). A slow package whose scale the offsets do show is
    // left to its free fit: held too, it came out better on 100 s rotation phases and worse on a
    // 30 s one (docs/sample-clocks.md, "A clock the gyroscopes cannot show").
    let hidden: Vec<bool> = (0..p).map(|q| !fits[q].shows_sawtooth()).collect();
    let shown: Vec<usize> = (0..p).filter(|&q| !hidden[q]).collect();
    // The median over the packages that show their sawtooth, at the fits as they stand.
    let held = |fits: &[OffsetFit], f: &dyn Fn(&OffsetFit) -> f64| {
        crate::stats::median(&shown.iter().map(|&r| f(&fits[r])).collect::<Vec<_>>())
    };
    let holding = !shown.is_empty() && shown.len() < p;
    let free = fits.clone();
    if holding {
        let (amplitude, drift_per_s) = (held(&fits, &|f| f.amplitude), held(&fits, &|f| f.clock.drift_per_s));
        for q in (0..p).filter(|&q| hidden[q]) {
            // a scale the offsets do not show says nothing of the rate: a clock this slow runs
            // within a few ppm of nominal
            fits[q].clock = SampleClock { rate_offset: 0.0, drift_per_s, ..fits[q].clock };
            fits[q].amplitude = amplitude;
        }
    }
    for _sweep in 0..3 {
        for q in 0..p {
            let o = &offsets[q];
            let target: Vec<f64> = o
                .t_s
                .iter()
                .zip(&o.offset_s)
                .map(|(t, y)| {
                    let others: f64 =
                        (0..p).filter(|&r| r != q).map(|r| fits[r].amplitude * fits[r].clock.age_s(*t)).sum();
                    // y = a_q - mean(a) = a_q (1 - 1/p) - others / p
                    (y + others / p as f64) * p as f64 / (p as f64 - 1.0).max(1.0)
                })
                .collect();
            fits[q] = if holding && hidden[q] {
                let (amplitude, constant_s) = (held(&fits, &|f| f.amplitude), held(&fits, &|f| f.constant_s));
                refine_held(o, &target, &fits[q].clock, amplitude, constant_s)
            } else {
                refine(o, &target, &fits[q].clock, true)
            };
        }
    }
    for q in (0..p).filter(|&q| hidden[q]) {
        if fits[q].clock.periods_over(&offsets[q].t_s, host_dt_s) >= 1.0 {
            fits[q] = free[q];
        }
    }
    Some(fits)
}

/// The packages' clocks refitted on each half of their offsets (split at `t_split_s`), started
/// from `fits` (the whole-phase clocks, whose reference time they keep): per package the
/// difference first half less second of `(rate_offset, drift_per_s, phase_s)`, the phase's
/// difference wrapped into half a period either side. The spread of these differences is an
/// estimate of the clocks' errors that does not rest on the offsets' noise being white.
pub fn half_differences(offsets: &[Offsets], fits: &[OffsetFit], t_split_s: f64) -> Vec<[f64; 3]> {
    let p = offsets.len();
    let half = |o: &Offsets, first: bool| -> Offsets {
        let keep: Vec<usize> = (0..o.t_s.len()).filter(|&i| (o.t_s[i] < t_split_s) == first).collect();
        Offsets {
            sample: keep.iter().map(|&i| o.sample[i]).collect(),
            t_s: keep.iter().map(|&i| o.t_s[i]).collect(),
            offset_s: keep.iter().map(|&i| o.offset_s[i]).collect(),
            weight: keep.iter().map(|&i| o.weight[i]).collect(),
        }
    };
    (0..p)
        .map(|q| {
            let refit = |first: bool| -> SampleClock {
                let o = half(&offsets[q], first);
                let target: Vec<f64> = o
                    .t_s
                    .iter()
                    .zip(&o.offset_s)
                    .map(|(t, y)| {
                        let others: f64 =
                            (0..p).filter(|&r| r != q).map(|r| fits[r].amplitude * fits[r].clock.age_s(*t)).sum();
                        (y + others / p as f64) * p as f64 / (p as f64 - 1.0).max(1.0)
                    })
                    .collect();
                refine(&o, &target, &fits[q].clock, true).clock
            };
            let (a, b) = (refit(true), refit(false));
            let period = 1.0 / a.nominal_hz;
            let dphase = (a.phase_s - b.phase_s + 0.5 * period).rem_euclid(period) - 0.5 * period;
            [a.rate_offset - b.rate_offset, a.drift_per_s - b.drift_per_s, dphase]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clock(eps: f64, phase_s: f64) -> SampleClock {
        SampleClock { nominal_hz: 1000.0, rate_offset: eps, drift_per_s: 0.0, phase_s, t_ref_s: 0.0 }
    }

    /// A fast clock's age grows by `R eps / f0` a host sample and wraps down (the sign the JSON
    /// states): R = 16 ticks a 16 ms sample, eps = +1000 ppm: +16 us a sample.
    #[test]
    fn a_fast_clock_ages_by_r_eps_over_f0_a_sample_and_wraps_down() {
        let c = clock(1e-3, 0.2e-3);
        let dt = 0.016;
        let a0 = c.age_s(0.0);
        let a1 = c.age_s(dt);
        assert!((a0 - 0.2e-3).abs() < 1e-15);
        assert!((a1 - a0 - 16e-6).abs() < 1e-12, "{}", a1 - a0);
        // (1 - 0.2) / 0.016 = 50 samples reach one period: the 51st has wrapped to 16 us
        let a51 = c.age_s(51.0 * dt);
        assert!((a51 - 16e-6).abs() < 1e-9, "{a51}");
        assert!(c.age_s(49.0 * dt) > 0.98e-3);
    }

    /// The fast floor is `f64::floor` bit for bit: negatives, integers, signed zeros, the
    /// neighbours of integers, values beyond `2^52`, infinities and NaN.
    #[test]
    fn the_fast_floor_is_the_floor_bit_for_bit() {
        let mut xs = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 3.0e15, -3.0e15, 4.1e15, -9.0e18, 1e300, -1e300];
        xs.extend([f64::INFINITY, f64::NEG_INFINITY, f64::MIN_POSITIVE, -f64::MIN_POSITIVE, f64::NAN]);
        for k in -2000..2000 {
            let x = k as f64 * 0.37 + 1e-3 * (k % 7) as f64;
            xs.extend([x, (k as f64).next_up(), (k as f64).next_down(), 123_456.789 * k as f64]);
        }
        for x in xs {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "{x:e}");
        }
    }

    #[test]
    fn age_partials_match_central_differences_between_wraps() {
        let c =
            SampleClock { nominal_hz: 1000.0, rate_offset: -2.3e-4, drift_per_s: 1e-7, phase_s: 0.31e-3, t_ref_s: 5.0 };
        for t in [4.7, 5.0, 5.3, 7.9] {
            let p = c.age_partials(t);
            let h = [1e-9, 1e-9, 1e-9];
            for k in 0..3 {
                let mut d = [0.0; 3];
                d[k] = h[k];
                let up = c.moved(d).age_s(t);
                d[k] = -h[k];
                let down = c.moved(d).age_s(t);
                if (up - down).abs() < 0.5e-3 {
                    let fd = (up - down) / (2.0 * h[k]);
                    assert!((fd - p[k]).abs() < 1e-5 * p[k].abs().max(1.0), "t {t} k {k}: {fd} vs {}", p[k]);
                }
            }
        }
    }

    /// The mirror of a clock (`age -> period - age`, on the host's samples the clock with the rate
    /// offset's sign flipped) fits a sawtooth's offsets with the amplitude negated; held at or
    /// above 0, the amplitude there is 0 and the fit is the constant alone (its cost the offsets'
    /// weighted spread about their mean, computed here directly), while the clock itself fits with
    /// amplitude 1 and no cost.
    #[test]
    fn the_mirror_of_a_clock_is_no_sawtooth() {
        let (eps, phase) = (300e-6, 0.3e-3);
        let truth =
            SampleClock { nominal_hz: 1000.0, rate_offset: eps, drift_per_s: 0.0, phase_s: phase, t_ref_s: 50.0 };
        let mirror = SampleClock { rate_offset: -eps, phase_s: 1e-3 - phase, ..truth };
        let sample: Vec<i64> = (0..6250).collect();
        let t_s: Vec<f64> = sample.iter().map(|&k| k as f64 * 0.016).collect();
        // The premise: on the host's samples the mirror's age is the period less the clock's.
        let mirrored = t_s.iter().filter(|&&t| (mirror.age_s(t) - (1e-3 - truth.age_s(t))).abs() < 1e-9).count();
        assert!(mirrored > 6200, "{mirrored} of 6250 samples mirrored");
        let offset_s: Vec<f64> = t_s.iter().map(|&t| truth.age_s(t) + 0.1e-3).collect();
        let weight: Vec<f64> = (0..6250).map(|k| 1.0 + (k % 3) as f64).collect();
        let o = Offsets { sample, t_s, offset_s: offset_s.clone(), weight: weight.clone() };
        let (amp, constant, cost) = linear_part(&o, &offset_s, &mirror);
        let wsum: f64 = weight.iter().sum();
        let mean = weight.iter().zip(&offset_s).map(|(w, y)| w * y).sum::<f64>() / wsum;
        let spread: f64 = weight.iter().zip(&offset_s).map(|(w, y)| w * (y - mean).powi(2)).sum();
        assert_eq!(amp, 0.0);
        assert!((constant - mean).abs() < 1e-15, "{constant} vs {mean}");
        assert!((cost - spread).abs() < 1e-9 * spread, "{cost} vs {spread}");
        let (amp, constant, cost) = linear_part(&o, &offset_s, &truth);
        assert!((amp - 1.0).abs() < 1e-9 && (constant - 0.1e-3).abs() < 1e-12, "{amp} {constant}");
        assert!(cost < 1e-9 * spread, "{cost}");
    }

    /// The phase scan's cost at every shift is [`linear_part`]'s at the shifted clock, computed
    /// sample by sample (fast and slow clocks, a drift, uneven weights, shifts past a wrap both
    /// ways, and the mirror's amplitude held at 0).
    #[test]
    fn the_phase_scan_scores_every_shift_as_the_direct_fit_does() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, 0.1e-3).expect("normal");
        let truth =
            SampleClock { nominal_hz: 1000.0, rate_offset: 812e-6, drift_per_s: 2e-8, phase_s: 0.4e-3, t_ref_s: 40.0 };
        let sample: Vec<i64> = (0..5000).collect();
        let t_s: Vec<f64> = sample.iter().map(|&k| k as f64 * 0.016).collect();
        let offset_s: Vec<f64> = t_s.iter().map(|&t| 0.8 * truth.age_s(t) + 0.2e-3 + noise.sample(&mut rng)).collect();
        let weight: Vec<f64> = (0..5000).map(|k| 0.5 + (k % 5) as f64).collect();
        let o = Offsets { sample, t_s, offset_s: offset_s.clone(), weight };
        let mut scan = PhaseScan::new(&o, &offset_s);
        let mut checked = 0;
        for base in [truth, truth.moved([-30e-6, 0.0, 0.37e-3]), SampleClock { rate_offset: -812e-6, ..truth }] {
            for (step_s, k_max) in [(0.2e-3 / 16.0, 16usize), (0.05e-3 / 16.0, 16), (0.33e-3, 3)] {
                scan.bin(&o, &base, step_s, k_max);
                for k in -(k_max as i32)..=k_max as i32 {
                    let direct = linear_part(&o, &offset_s, &base.moved([0.0, 0.0, step_s * k as f64])).2;
                    let fast = scan.cost(k);
                    assert!((fast - direct).abs() <= 1e-9 * direct.max(1e-30), "shift {k}: {fast:e} vs {direct:e}");
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 3 * (33 + 33 + 7));
    }

    /// The matched filter and the refinement recover a sawtooth from noisy offsets: rate to a
    /// fraction of a ppm, phase to microseconds, sign included (slow and fast clocks).
    #[test]
    fn search_and_refine_recover_a_noisy_sawtooth() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.2e-3).expect("normal");
        for (eps, phase) in [(-2546.5e-6, 0.67e-3), (1120.4e-6, 0.51e-3), (-37.5e-6, 0.17e-3)] {
            let truth =
                SampleClock { nominal_hz: 1000.0, rate_offset: eps, drift_per_s: 0.0, phase_s: phase, t_ref_s: 50.0 };
            let sample: Vec<i64> = (0..6250).collect();
            let t_s: Vec<f64> = sample.iter().map(|&k| k as f64 * 0.016).collect();
            let offset_s: Vec<f64> = t_s.iter().map(|&t| truth.age_s(t) - 0.5e-3 + noise.sample(&mut rng)).collect();
            let o = Offsets { sample, t_s, offset_s: offset_s.clone(), weight: vec![1.0; 6250] };
            let found = search(&o, 1000.0, 0.016, 50.0, 5e-3).expect("found");
            assert!((found.rate_offset - eps).abs() < 5e-6, "search: {} vs {eps}", found.rate_offset);
            let grid = refine_grid(&o, &offset_s, &found, 5e-6, 0.0);
            let fit = refine(&o, &offset_s, &grid.clock, false);
            assert!((fit.clock.rate_offset - eps).abs() < 0.3e-6, "refine: {} vs {eps}", fit.clock.rate_offset);
            let dphase = (fit.clock.phase_s - phase + 0.5e-3).rem_euclid(1e-3) - 0.5e-3;
            assert!(dphase.abs() < 10e-6, "phase {} vs {phase}", fit.clock.phase_s);
            assert!((fit.amplitude - 1.0).abs() < 0.05, "amplitude {}", fit.amplitude);
        }
    }
}
