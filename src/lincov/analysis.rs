//! The analysis of one cell: every compensation, horizon and drift metric, with its
//! distribution, its error budget and its nonlinearity index.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, SMatrix, UnitQuaternion, Vector3, Vector4};
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::dynamics::{Linearisation, LinearisationError, linearise};
use super::nonlinearity::{Probe, SIGMA_POINT, index, navigate_probes, pair_index, principal_direction};
use super::norm::{GaussNorm, ScaleMixture, turned_axes};
use super::sources::{
    Calibration, ParamBlock, block_covariances, calibration_with, nominal_errors, nominal_parameters, reference, truths,
};
use super::stacked::StackedBlocks;
use crate::calib::fisher::step_motions;
use crate::calib::params::PER_ACCEL;
use crate::config::calibration::Estimator;
use crate::mc::Cell;
use crate::mc::config::Compensation;
use crate::nav::MotionGrid;
use crate::nav::lanes::LANES;
use crate::rng::trial_rng;

/// The nonlinearity index at or below which a row is `linear` (LinCov stands by its number).
/// Calibrated on the comparisons with the Monte Carlo in docs/lincov.md.
pub const LINEAR_THRESHOLD: f64 = 0.1;

/// Truths the `true` compensation's navigation is linearised again at, for its index.
pub const NOISE_TRUTHS: usize = 8;

/// Salt of the streams of the mixture's random rotations.
const ROTATION_SALT: u64 = 0x6c69_6e63_6f76_726f;

/// How to analyse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Truths drawn for a mixture (when some error parameter varies).
    pub truths: usize,
    /// Whether to run the navigator at sigma points for the nonlinearity index.
    pub nonlinearity: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Self { truths: 1024, nonlinearity: true }
    }
}

/// Where a share of a metric's mean square comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Source {
    /// A parameter of the layout (index): its own error, and half of its covariance with every
    /// other parameter.
    Parameter(usize),
    /// What the fixture's pose errors add to the calibration's covariance.
    Fixture,
    /// The navigation's white noise.
    Noise,
}

/// One compensation, horizon and metric.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricResult {
    pub compensation: Compensation,
    /// Index into `mc::trial::DRIFT_METRICS`.
    pub metric: usize,
    pub horizon_s: f64,
    pub median: f64,
    pub p95: f64,
    pub p05: f64,
    /// `sqrt(E |e|^2)`.
    pub rms: f64,
    /// Standard errors of `median` and `p95` from the mixture's finite draws (0 for one Gaussian).
    pub median_se: f64,
    pub p95_se: f64,
    /// Gaussians in the distribution (1: one Gaussian; more: a mixture over drawn truths).
    pub components: usize,
    /// Parameters the schedule cannot identify whose error reaches this metric (its quantiles are
    /// then infinite).
    pub unbounded_by: Vec<String>,
    /// Shares of `E |e|^2` by source (they add up to it).
    pub budget: Vec<(Source, f64)>,
    pub nonlinearity: f64,
    pub linear: bool,
}

/// The analysis of one cell.
#[derive(Debug, Clone)]
pub struct CellResult {
    pub cell: usize,
    pub rows: Vec<MetricResult>,
    /// Truths of the estimated compensation's mixture left out: a fit at them cannot stay in the
    /// model's small-error region (where the Monte Carlo's fits are refused) at all.
    pub excluded_truths: usize,
    /// The chance that the estimated compensation's fit leaves the small-error region, over the
    /// truths drawn (the fraction of its fits the Monte Carlo would refuse; 0 without it).
    pub refused_fraction: f64,
}

/// Why a cell cannot be analysed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LincovError {
    /// The config asks for something LinCov does not model (bad input for `gfcal lincov`).
    #[error("key `{key}`: {problem}")]
    Unsupported { key: String, problem: String },
    #[error(transparent)]
    Linearisation(#[from] LinearisationError),
}

/// Refuses what LinCov does not model, naming the key.
pub fn check(cell: &Cell) -> Result<(), LincovError> {
    let unsupported =
        |key: &str, problem: &str| Err(LincovError::Unsupported { key: key.into(), problem: problem.into() });
    if cell.protocol.is_some() {
        return unsupported(
            "protocol",
            "LinCov needs a rate-table schedule: a hand-held protocol's calibration has no Fisher information here",
        );
    }
    if cell.calibration.estimator == Estimator::Paper
        && cell.navigation.compensations.contains(&Compensation::Estimated)
    {
        return unsupported(
            "calibration.estimator",
            "LinCov's estimated compensation uses the Cramer-Rao covariance, which the joint estimator reaches; \
             the paper's procedure does not (use estimator = \"joint\", or leave \"estimated\" out)",
        );
    }
    let noise = &cell.noise;
    if cell.navigation.noise {
        if noise.gauss_markov.is_some_and(|g| g.sigma_m_s2 > 0.0) {
            return unsupported("noise.gauss_markov_sigma_ug", "LinCov propagates white noise only");
        }
        if noise.random_walk_m_s2_per_sqrt_s > 0.0 {
            return unsupported("noise.random_walk_ug_per_sqrt_s", "LinCov propagates white noise only");
        }
        if noise.quantization_m_s2 > 0.0 {
            return unsupported("noise.quantization_ug", "LinCov propagates white noise only");
        }
    }
    Ok(())
}

/// The linearisation of a cell's navigation (shared by cells that navigate alike).
pub fn linearisation(cell: &Cell) -> Result<Linearisation, LincovError> {
    linearisation_at(cell, &reference(cell))
}

/// The linearisation of a cell's navigation about the truth `x` (layout form).
pub fn linearisation_at(cell: &Cell, x: &DVector<f64>) -> Result<Linearisation, LincovError> {
    let nav = &cell.navigation;
    let noise = nav.noise && cell.noise.white.density_m_s2_per_sqrt_hz() > 0.0;
    Ok(linearise(&cell.layout, x, &nav.trajectory, cell.calibration.gravity_m_s2, nav.step_s, &nav.horizons_s, noise)?)
}

/// A metric block at one horizon: `S_b` (3 x P) and the unit-density noise covariance.
struct Block {
    s: DMatrix<f64>,
    noise_unit: Matrix3<f64>,
}

/// What one Gaussian (one truth) gives a block: its covariance and mean, and what makes it
/// unbounded.
struct Part {
    cov: Matrix3<f64>,
    mean: Vector3<f64>,
    /// The unidentifiable parameters (at this component's truth) whose error reaches the block:
    /// the component is then unbounded.
    unbounded_by: Vec<String>,
}

/// A block's error budget over a compensation's components (their weighted mean): per
/// parameter, the fixture's and the noise's shares of `E |e|^2`.
struct Shares {
    parameters: Vec<f64>,
    fixture: f64,
    noise: f64,
}

/// A parameter covariance and how to multiply by it.
struct ParamCov<'a> {
    cov: &'a DMatrix<f64>,
    block_diagonal: bool,
}

impl ParamCov<'_> {
    /// `S C` for a 3 x P `s`.
    fn left(&self, s: &DMatrix<f64>) -> DMatrix<f64> {
        if !self.block_diagonal {
            return s * self.cov;
        }
        let p = s.ncols();
        let mut out = DMatrix::zeros(3, p);
        for o in (0..p).step_by(PER_ACCEL) {
            for c in o..o + PER_ACCEL {
                for k in o..o + PER_ACCEL {
                    let ck = self.cov[(k, c)];
                    if ck != 0.0 {
                        for r in 0..3 {
                            out[(r, c)] += s[(r, k)] * ck;
                        }
                    }
                }
            }
        }
        out
    }
}

/// `S C S^T` and the shares `diag(S^T S C)` (see [`Source::Parameter`]).
fn propagate(s: &DMatrix<f64>, c: &ParamCov<'_>) -> (Matrix3<f64>, Vec<f64>) {
    let mut shares = vec![0.0; s.ncols()];
    let cov = propagate_into(s, c, Some(&mut shares));
    (cov, shares)
}

/// `S C S^T` alone (a mixture's truths: their shares go to the budget through the mean of their
/// covariances, see [`Prepared::shares`]).
fn propagate_cov(s: &DMatrix<f64>, c: &ParamCov<'_>) -> Matrix3<f64> {
    propagate_into(s, c, None)
}

/// `S C S^T`, and the shares `diag(S^T S C)` into `shares` where asked. A block-diagonal `C` goes
/// 7 x 7 block by block on the matrices' storage (column-major), without allocating.
fn propagate_into(s: &DMatrix<f64>, c: &ParamCov<'_>, mut shares: Option<&mut [f64]>) -> Matrix3<f64> {
    if !c.block_diagonal {
        let sc = c.left(s);
        if let Some(shares) = shares {
            for (i, share) in shares.iter_mut().enumerate() {
                *share = (0..3).map(|r| s[(r, i)] * sc[(r, i)]).sum();
            }
        }
        return Matrix3::from_fn(|r, q| (0..s.ncols()).map(|i| sc[(r, i)] * s[(q, i)]).sum());
    }
    let p = s.ncols();
    let (sd, cd) = (s.as_slice(), c.cov.as_slice());
    let mut cov = [[0.0; 3]; 3];
    for o in (0..p).step_by(PER_ACCEL) {
        // sc = S_j C_j, 3 x 7, at a fixed size (summed over k in order, as by hand).
        let s_j = SMatrix::<f64, 3, PER_ACCEL>::from_column_slice(&sd[3 * o..3 * (o + PER_ACCEL)]);
        let c_j = SMatrix::<f64, PER_ACCEL, PER_ACCEL>::from_fn(|r, c| cd[(o + c) * p + o + r]);
        let sc_j = s_j * c_j;
        for col in 0..PER_ACCEL {
            let sc_col = sc_j.column(col);
            let s_col = &sd[3 * (o + col)..3 * (o + col) + 3];
            if let Some(shares) = shares.as_deref_mut() {
                shares[o + col] = s_col[0] * sc_col[0] + s_col[1] * sc_col[1] + s_col[2] * sc_col[2];
            }
            for r in 0..3 {
                for q in 0..3 {
                    cov[r][q] += sc_col[r] * s_col[q];
                }
            }
        }
    }
    Matrix3::from_fn(|r, q| cov[r][q])
}

/// The parameters of the null directions `null` (as [`Calibration::null`]) that move the metric
/// block `s` (3 x P): a direction reaches it when `|s dir|` exceeds 1e-9 of the block's largest
/// response to one target of any parameter (`dir` has unit length in targets).
fn reached_by(
    s: &DMatrix<f64>,
    null: &[(DVector<f64>, Vec<usize>)],
    target: &DVector<f64>,
    layout: &crate::calib::Layout,
) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    if null.is_empty() {
        return names;
    }
    let scale =
        (0..s.ncols()).map(|i| (0..3).map(|r| (s[(r, i)] * target[i]).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max);
    for (dir, who) in null {
        if (s * dir).norm() > 1e-9 * scale {
            for &i in who {
                let name = layout.name(i);
                if !names.contains(&name) {
                    names.push(name);
                }
            }
        }
    }
    names
}

/// The mixture over drawn truths of block `(h, m)`: its components that no unidentifiable
/// parameter reaches (their indices), each covariance less `less` (the noise's, for the
/// parameters' part alone; zero for the whole), read along their turned `axes` with their
/// `weights`, and the share of the weight they carry (a quantile at or above it is infinite).
fn bounded_mixture(
    parts: &[Vec<Vec<Part>>],
    weights: &[f64],
    axes: &[[Vector3<f64>; 6]],
    h: usize,
    m: usize,
    less: &Matrix3<f64>,
) -> (ScaleMixture, Vec<usize>, f64) {
    let bounded: Vec<usize> = (0..parts.len()).filter(|&k| parts[k][h][m].unbounded_by.is_empty()).collect();
    let mut mix = ScaleMixture::default();
    for &k in &bounded {
        mix.add_gaussian_along(&(parts[k][h][m].cov - less), &axes[k], weights[k]);
    }
    let share = bounded.iter().map(|&k| weights[k]).sum::<f64>() / weights.iter().sum::<f64>();
    (mix, bounded, share)
}

/// A row's distribution: its quantiles, their standard errors and its mean square.
#[derive(Debug, Clone, Copy)]
struct RowDistribution {
    median: f64,
    p95: f64,
    p05: f64,
    median_se: f64,
    p95_se: f64,
    mean_square: f64,
}

impl RowDistribution {
    /// Where an unidentifiable parameter reaches every component.
    fn unbounded() -> Self {
        let inf = f64::INFINITY;
        Self { median: inf, p95: inf, p05: inf, median_se: 0.0, p95_se: 0.0, mean_square: inf }
    }
}

/// The distribution of block `(h, m)` of a mixture over drawn truths (weights `weights`, read
/// along `axes`): components where an unidentifiable parameter reaches the metric are infinite,
/// so a quantile at or above the bounded components' weight is infinite too.
fn mixture_distribution(
    parts: &[Vec<Vec<Part>>],
    weights: &[f64],
    axes: &[[Vector3<f64>; 6]],
    h: usize,
    m: usize,
) -> RowDistribution {
    let (mix, bounded, weight) = bounded_mixture(parts, weights, axes, h, m, &Matrix3::zeros());
    if bounded.is_empty() {
        return RowDistribution::unbounded();
    }
    let within = |p: f64| if p < weight { Some(p / weight) } else { None };
    let q = |p: f64| within(p).map_or((f64::INFINITY, 0.0), |p| mix.quantile_with_error(p));
    let ((median, median_se), (p95, p95_se)) = (q(0.5), q(0.95));
    let p05 = within(0.05).map_or(f64::INFINITY, |p| mix.quantile(p));
    let mean_square = if bounded.len() < parts.len() {
        f64::INFINITY
    } else {
        let total_weight: f64 = weights.iter().sum();
        parts.iter().zip(weights).map(|(c, w)| w * c[h][m].cov.trace()).sum::<f64>() / total_weight
    };
    RowDistribution { median, p95, p05, median_se, p95_se, mean_square }
}

/// The largest eigenvalue of a symmetric 3 x 3 matrix (0 for a zero matrix).
fn largest_eigenvalue(m: &Matrix3<f64>) -> f64 {
    let e = nalgebra::SymmetricEigen::new((m + m.transpose()) * 0.5);
    e.eigenvalues.max().max(0.0)
}

/// Per horizon and metric, how far a linearisation at another truth moves a metric's RMS:
/// `|sqrt(moved / here) - 1|` from `mean_squares(at, h, m) = (moved, here)`; infinite where the
/// linearisation failed or a metric moves from nothing.
fn rms_change(
    at: Result<Linearisation, LincovError>,
    horizons: usize,
    mean_squares: impl Fn(&Linearisation, usize, usize) -> (f64, f64),
) -> Vec<[f64; 4]> {
    let Ok(at) = at else { return vec![[f64::INFINITY; 4]; horizons] };
    (0..horizons)
        .map(|h| {
            std::array::from_fn(|m| {
                let (moved, here) = mean_squares(&at, h, m);
                if here > 0.0 {
                    ((moved / here).sqrt() - 1.0).abs()
                } else if moved > 0.0 {
                    f64::INFINITY
                } else {
                    0.0
                }
            })
        })
        .collect()
}

/// A uniformly random rotation from a stream.
fn random_rotation(seed: u64, m: usize) -> Rotation3<f64> {
    let mut rng = trial_rng(seed ^ ROTATION_SALT, m as u64);
    let v = Vector4::from_fn(|_, _| StandardNormal.sample(&mut rng));
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::from_vector(v)).to_rotation_matrix()
}

/// What the cell's compensations share: the cell, its metric blocks and the settings.
struct Context<'a> {
    cell: &'a Cell,
    blocks: Vec<Vec<Block>>,
    /// The blocks stacked for a mixture's truths (horizon-major, metric-minor), where the
    /// parameters are whole accelerometers.
    stacked: Option<StackedBlocks>,
    horizons_s: &'a [f64],
    seed: u64,
    settings: &'a Settings,
    grid: Option<&'a Arc<MotionGrid>>,
    density: f64,
    noise_var: f64,
}

/// A sigma-point probe's navigation and what it was aimed at.
struct ProbeBlock {
    /// The metric it was aimed at (`usize::MAX`: the centre, serving every metric).
    metric: usize,
    /// The horizon it serves (every one where `None`).
    horizon: Option<usize>,
    /// The parameter error it navigates with.
    dx: DVector<f64>,
    /// How many of the probed component's standard deviations along its direction it lies at (the
    /// index's spread term is that many of the metric's largest standard deviations).
    sigmas: f64,
    /// Its linear prediction `|S_h dx|` per horizon and metric from its truth's own linearisation,
    /// where that is not the reference (`None`: from the reference's blocks).
    linear: Option<Vec<[f64; 4]>>,
}

/// One compensation's distribution, before its rows: the Gaussians (one per kept truth) of every
/// (horizon, metric) block, and the sigma-point probes navigated.
struct Prepared {
    comp: Compensation,
    /// `parts[component][horizon][metric]`.
    parts: Vec<Vec<Vec<Part>>>,
    /// A mixture's distribution per horizon and metric (`None` for one Gaussian: its row finds
    /// it).
    distributions: Option<Vec<Vec<RowDistribution>>>,
    /// `shares[horizon][metric]`: the budget, the weighted mean over the components of each one's
    /// shares. They are linear in its parameter covariance and the sensitivity is the reference's
    /// for every component, so they are taken once, from the weighted mean of the components'
    /// covariances.
    shares: Vec<Vec<Shares>>,
    probes: Vec<ProbeBlock>,
    /// Per probe, the navigated norms at every horizon (empty without a grid or probes).
    navigated: Vec<Vec<[f64; 4]>>,
    /// Per horizon and metric, the unidentifiable parameters that reach it in some component.
    unbounded: Vec<Vec<Vec<String>>>,
    /// The component (truth) the sigma-point probes belong to.
    probe_component: usize,
    /// For a mixture: per horizon and metric, how far the probed truth's own linearisation moves
    /// the metric's RMS from the reference's (the sensitivity's change across truths).
    truth_index: Option<Vec<[f64; 4]>>,
    excluded: usize,
    /// The chance, over the truths drawn, that a fit leaves the small-error region.
    refused_fraction: f64,
}

impl Context<'_> {
    /// The navigator at the probes (independent navigations, in parallel chunks), each only as
    /// far as the horizons its block serves.
    fn navigate(&self, probes: &[Probe], blocks: &[ProbeBlock]) -> Vec<Vec<[f64; 4]>> {
        let Some(grid) = self.grid else { return vec![] };
        if probes.is_empty() {
            return vec![];
        }
        let (layout, g) = (&self.cell.layout, self.cell.calibration.gravity_m_s2);
        let reach = |k: usize| blocks[k].horizon.map_or(self.blocks.len(), |h| h + 1);
        // Runs of probes with the same reach, in chunks of two lane sets (each probe's numbers
        // are those it gets navigated alone).
        let mut chunks: Vec<(std::ops::Range<usize>, usize)> = Vec::new();
        let mut start = 0;
        for k in 1..=probes.len() {
            if k == probes.len() || reach(k) != reach(start) || k - start == 2 * LANES {
                chunks.push((start..k, reach(start)));
                start = k;
            }
        }
        let navigated: Vec<Vec<Vec<[f64; 4]>>> = chunks
            .par_iter()
            .map(|(range, reach)| navigate_probes(layout, grid, g, &probes[range.clone()], *reach))
            .collect();
        navigated.into_iter().flatten().collect()
    }

    /// One part per (horizon, metric) block.
    fn per_block<T>(&self, mut part: impl FnMut(&Block) -> T) -> Vec<Vec<T>> {
        self.blocks.iter().map(|hb| hb.iter().map(&mut part).collect()).collect()
    }

    /// One part and its shares per (horizon, metric) block, in two tables.
    fn per_block_with_shares(&self, part: impl Fn(&Block) -> (Part, Shares)) -> (Vec<Vec<Part>>, Vec<Vec<Shares>>) {
        self.per_block(part).into_iter().map(|hb| hb.into_iter().unzip()).unzip()
    }

    fn nominal(&self) -> Prepared {
        let (cell, settings) = (self.cell, self.settings);
        let (mean, variance) = nominal_errors(cell);
        let cov = DMatrix::from_diagonal(&variance);
        let pc = ParamCov { cov: &cov, block_diagonal: true };
        let (parts, shares) = self.per_block_with_shares(|b| {
            let (c, mut shares) = propagate(&b.s, &pc);
            let mu = &b.s * &mean;
            let mu = Vector3::new(mu[0], mu[1], mu[2]);
            for (i, sh) in shares.iter_mut().enumerate() {
                let own = Vector3::new(b.s[(0, i)], b.s[(1, i)], b.s[(2, i)]) * mean[i];
                *sh += own.dot(&mu);
            }
            let noise = self.noise_var * b.noise_unit;
            let part = Part { cov: c + noise, mean: mu, unbounded_by: vec![] };
            (part, Shares { parameters: shares, fixture: 0.0, noise: noise.trace() })
        });
        let (mut probes, mut probe_blocks) = (Vec::new(), Vec::new());
        if settings.nonlinearity {
            let x_nom = nominal_parameters(cell);
            probes.push(Probe { truth: &x_nom - &mean, compensation: x_nom.clone() });
            probe_blocks.push(ProbeBlock {
                metric: usize::MAX,
                horizon: None,
                dx: mean.clone(),
                sigmas: SIGMA_POINT,
                linear: None,
            });
            // The nominal errors are large: each horizon's own principal directions (the last
            // horizon's need not move an earlier one's metric the most).
            for (h, hb) in self.blocks.iter().enumerate() {
                for (m, b) in hb.iter().enumerate() {
                    if let Some(u) = principal_direction(&b.s, &cov) {
                        for sign in [1.0, -1.0] {
                            let dx = &mean + &u * (sign * SIGMA_POINT);
                            probes.push(Probe { truth: &x_nom - &dx, compensation: x_nom.clone() });
                            probe_blocks.push(ProbeBlock {
                                metric: m,
                                horizon: Some(h),
                                dx,
                                sigmas: SIGMA_POINT,
                                linear: None,
                            });
                        }
                    }
                }
            }
        }
        self.prepared(Compensation::Nominal, parts, shares, &probes, probe_blocks)
    }

    fn true_noise(&self) -> Prepared {
        let p = self.cell.layout.len();
        let (parts, shares) = self.per_block_with_shares(|b| {
            let noise = self.noise_var * b.noise_unit;
            let part = Part { cov: noise, mean: Vector3::zeros(), unbounded_by: vec![] };
            (part, Shares { parameters: vec![0.0; p], fixture: 0.0, noise: noise.trace() })
        });
        let (mut probes, mut probe_blocks) = (Vec::new(), Vec::new());
        if self.settings.nonlinearity || self.noise_var == 0.0 {
            let x_ref = reference(self.cell);
            probes.push(Probe { truth: x_ref.clone(), compensation: x_ref });
            probe_blocks.push(ProbeBlock {
                metric: usize::MAX,
                horizon: None,
                dx: DVector::zeros(p),
                sigmas: SIGMA_POINT,
                linear: None,
            });
        }
        let mut prepared = self.prepared(Compensation::True, parts, shares, &probes, probe_blocks);
        if self.settings.nonlinearity && self.noise_var > 0.0 {
            prepared.truth_index = self.noise_truth_index();
        }
        prepared
    }

    /// The `true` compensation's truth index: the noise's propagation depends on the true errors
    /// (a rate error's centripetal feedback goes through the true axes and locations), so the
    /// navigation is linearised again at [`NOISE_TRUTHS`] of the cell's drawn truths, and per
    /// horizon and metric the index is the largest `|sqrt(moved / here) - 1|`, `moved` and `here`
    /// the noise-driven mean square there and at the reference. `None` when no error varies.
    fn noise_truth_index(&self) -> Option<Vec<[f64; 4]>> {
        let xs = truths(self.cell, self.seed, NOISE_TRUTHS);
        if xs.len() < 2 {
            return None;
        }
        let per_truth: Vec<Vec<[f64; 4]>> = xs
            .par_iter()
            .map(|x| {
                rms_change(linearisation_at(self.cell, x), self.blocks.len(), |at, h, m| {
                    (at.noise_block(h, m).trace(), self.blocks[h][m].noise_unit.trace())
                })
            })
            .collect();
        Some(
            (0..self.blocks.len())
                .map(|h| std::array::from_fn(|m| per_truth.iter().map(|t| t[h][m]).fold(0.0, f64::max)))
                .collect(),
        )
    }

    /// A compensation of one Gaussian (no truth index, nothing excluded or unbounded).
    fn prepared(
        &self,
        comp: Compensation,
        parts: Vec<Vec<Part>>,
        shares: Vec<Vec<Shares>>,
        probes: &[Probe],
        probe_blocks: Vec<ProbeBlock>,
    ) -> Prepared {
        Prepared {
            comp,
            distributions: None,
            parts: vec![parts],
            shares,
            navigated: self.navigate(probes, &probe_blocks),
            probes: probe_blocks,
            unbounded: vec![vec![vec![]; 4]; self.blocks.len()],
            probe_component: 0,
            truth_index: None,
            excluded: 0,
            refused_fraction: 0.0,
        }
    }

    /// A truth's Gaussian per (horizon, metric) block from its parameter covariance held as one
    /// block per accelerometer: every block's `S C S^T` at once.
    fn parts_from_blocks(&self, stacked: &StackedBlocks, blocks: &[ParamBlock]) -> Vec<Vec<Part>> {
        let covs = stacked.covariances(blocks);
        let per_horizon = self.blocks.first().map_or(0, Vec::len);
        (0..self.blocks.len())
            .map(|h| {
                (0..per_horizon)
                    .map(|m| Part {
                        cov: covs[h * per_horizon + m] + self.noise_var * self.blocks[h][m].noise_unit,
                        mean: Vector3::zeros(),
                        unbounded_by: vec![],
                    })
                    .collect()
            })
            .collect()
    }

    /// The truths `xs` calibrated one by one on the whole covariance (a fixture error, or a
    /// truth where the schedule loses a parameter), with their null directions: each truth's
    /// Gaussians and weight (`None`: excluded), and the weighted sum of their covariances. One
    /// truth (fixed errors) finds its null directions by eigenvalues, as `gfcal identify` does;
    /// a mixture inverts each truth by Cholesky, by eigenvalues only where that fails.
    fn calibrate_one_by_one(
        &self,
        xs: &[DVector<f64>],
        x_ref: &DVector<f64>,
    ) -> (Vec<Option<TruthParts>>, WeightedSum) {
        let cell = self.cell;
        let layout = &cell.layout;
        let single = xs.len() == 1;
        let target = crate::calib::fisher::Targets::default().si(layout, x_ref);
        let perfect = cell.calibration.pose.is_perfect();
        let bounds = crate::calib::estimate::small_error_bounds(layout);
        let p = layout.len();
        // Chunks of truths in parallel, each summing its truths' weighted covariances in order
        // (the budget's mean covariance: the same bits on any number of threads).
        let per_chunk: Vec<(Vec<Option<TruthParts>>, WeightedSum)> = xs
            .par_chunks(TRUTH_CHUNK)
            .map(|chunk| {
                let mut sum = WeightedSum::new(p, perfect);
                let parts = chunk
                    .iter()
                    .map(|x| {
                        let mut cal = calibration_with(cell, x, self.density, single);
                        let fixture = (!perfect).then_some(&mut cal.fixture);
                        let weight = stay_in_small_error_region(&mut cal.covariance, fixture, x, &bounds);
                        if weight.is_nan() || weight <= 0.0 {
                            return None;
                        }
                        sum.add(&cal, weight);
                        let pc = ParamCov { cov: &cal.covariance, block_diagonal: perfect };
                        // Every block's S C S^T at once where C is block-diagonal (the same bits).
                        let stacked = self.stacked.as_ref().filter(|_| perfect).map(|st| {
                            let c = &cal.covariance;
                            let diagonal: Vec<ParamBlock> = (0..c.nrows() / PER_ACCEL)
                                .map(|j| ParamBlock::from_fn(|r, q| c[(PER_ACCEL * j + r, PER_ACCEL * j + q)]))
                                .collect();
                            st.covariances(&diagonal)
                        });
                        let mut index = 0;
                        let parts = self.per_block(|b| {
                            let cov = match &stacked {
                                Some(covs) => covs[index],
                                None => propagate_cov(&b.s, &pc),
                            };
                            index += 1;
                            Part {
                                cov: cov + self.noise_var * b.noise_unit,
                                mean: Vector3::zeros(),
                                unbounded_by: reached_by(&b.s, &cal.null, &target, layout),
                            }
                        });
                        Some((parts, weight))
                    })
                    .collect();
                (parts, sum)
            })
            .collect();
        let mut sum = WeightedSum::new(p, perfect);
        let mut per_truth = Vec::with_capacity(xs.len());
        for (parts, chunk_sum) in per_chunk {
            sum.merge(&chunk_sum);
            per_truth.extend(parts);
        }
        (per_truth, sum)
    }

    fn estimated(&self, calibrated: Option<&CalibratedTruths>) -> Result<Prepared, LincovError> {
        let (cell, settings, blocks) = (self.cell, self.settings, &self.blocks);
        let layout = &cell.layout;
        let horizons = blocks.len();
        let x_ref = reference(cell);
        // The truths calibrated before the linearisation where they could be, block by block;
        // here, one by one, otherwise.
        let (drawn, per_truth, sum) = match (calibrated, &self.stacked) {
            (Some(c), Some(stacked)) => {
                let parts = c
                    .blocks
                    .par_iter()
                    .map(|t| t.as_ref().map(|(b, weight)| (self.parts_from_blocks(stacked, b), *weight)))
                    .collect();
                (std::borrow::Cow::Borrowed(&c.xs), parts, c.sum.clone())
            }
            _ => {
                let xs = truths(cell, self.seed, settings.truths.max(1));
                let (parts, sum) = self.calibrate_one_by_one(&xs, &x_ref);
                (std::borrow::Cow::Owned(xs), parts, sum)
            }
        };
        let xs = drawn.as_ref();
        let single = xs.len() == 1;
        // The region the Monte Carlo's fits are refused outside of.
        let bounds = crate::calib::estimate::small_error_bounds(layout);
        let excluded = per_truth.iter().filter(|p| p.is_none()).count();
        let kept: Vec<usize> = (0..xs.len()).filter(|&k| per_truth[k].is_some()).collect();
        let xs: Vec<DVector<f64>> = kept.iter().map(|&k| xs[k].clone()).collect();
        let (per_truth, weights): (Vec<Vec<Vec<Part>>>, Vec<f64>) = per_truth.into_iter().flatten().unzip();
        let refused_fraction = 1.0 - weights.iter().sum::<f64>() / (kept.len() + excluded) as f64;
        // Relative to the largest (the mixture reads only their ratios; equal weights stay 1, and
        // tiny ones do not underflow in the standard errors' sum of squares).
        let largest = weights.iter().copied().fold(0.0, f64::max);
        let weights: Vec<f64> = weights.iter().map(|w| w / largest).collect();
        // One random rotation per component: the directions its Gaussian is read along.
        let axes: Vec<[Vector3<f64>; 6]> = if per_truth.len() > 1 {
            (0..per_truth.len()).map(|k| turned_axes(&random_rotation(self.seed, k))).collect()
        } else {
            vec![]
        };
        if per_truth.is_empty() {
            return Err(LincovError::Unsupported {
                key: "errors".into(),
                problem: format!(
                    "at every one of the {} truths drawn a fit cannot stay inside the model's small-error \
                     region (its Cramer-Rao covariance reaches beyond it): the calibration is not linear anywhere",
                    excluded
                ),
            });
        }
        let shares = sum.shares(self);
        let mut unbounded: Vec<Vec<Vec<String>>> = vec![vec![vec![]; 4]; horizons];
        for parts in &per_truth {
            for (h, hp) in parts.iter().enumerate() {
                for (m, part) in hp.iter().enumerate() {
                    for name in &part.unbounded_by {
                        if !unbounded[h][m].contains(name) {
                            unbounded[h][m].push(name.clone());
                        }
                    }
                }
            }
        }
        // The nonlinearity's probes, beside the mixture's distributions (which need only the
        // truths' Gaussians: they fill the threads while the probed truth is linearised again).
        // Without navigation noise the probes' p95 at the last horizon is that row's own (the
        // parameters' part is the whole): its rows are read once, by the probe stage, and the
        // distributions' stage reads the other horizons (the same bits as reading every row there).
        let last_rows_by_probes = settings.nonlinearity && per_truth.len() > 1 && self.noise_var == 0.0;
        let probe_stage = || {
            let mut probe_blocks = Vec::new();
            let (mut probe_component, mut truth_index, mut navigated) = (0, None, vec![]);
            let mut last_rows: Option<Vec<RowDistribution>> = None;
            if settings.nonlinearity {
                // Sigma points of the component at the 95th percentile of the last horizon's
                // position variance (the tail), navigated with its own truth. The percentile is
                // weighted by the components' weights (equal weights: the plain order statistic).
                let mut order: Vec<usize> = (0..per_truth.len()).collect();
                let size = |k: usize| per_truth[k][horizons - 1][3].cov.trace();
                order.sort_by(|&a, &b| size(a).total_cmp(&size(b)));
                let k = if weights.iter().all(|&w| w == 1.0) {
                    order[((order.len() as f64 - 1.0) * 0.95).round() as usize]
                } else {
                    let target = 0.95 * weights.iter().sum::<f64>();
                    let mut cumulative = 0.0;
                    *order
                        .iter()
                        .find(|&&k| {
                            cumulative += weights[k];
                            cumulative >= target
                        })
                        .unwrap_or(&order[order.len() - 1])
                };
                probe_component = k;
                // Its covariance again (the truths' are not kept: 1,024 of them are 14 MB).
                let x_t = &xs[k];
                let mut cov = calibration_with(cell, x_t, self.density, single).covariance;
                stay_in_small_error_region(&mut cov, None, x_t, &bounds);
                let cov = &cov;
                // Per metric of the last horizon, a pair of probes along its principal direction, as far
                // out as the mixture's p95 there (the row's own number), not the probed truth's own
                // tail beyond it; navigated beside the probed truth's own linearisation.
                let directions = |last: Option<&Vec<RowDistribution>>| -> Vec<(usize, DVector<f64>, f64)> {
                    (0..blocks[horizons - 1].len())
                        .into_par_iter()
                        .filter_map(|m| {
                            let b = &blocks[horizons - 1][m];
                            let u = principal_direction(&b.s, cov)?;
                            // The parameters' part of the p95 (the probes move the parameters; a metric
                            // the noise dominates would put them far out).
                            let noise = self.noise_var * b.noise_unit;
                            let p95 = if let Some(rows) = last {
                                rows[m].p95
                            } else if per_truth.len() == 1 {
                                let part = &per_truth[0][horizons - 1][m];
                                if part.unbounded_by.is_empty() {
                                    GaussNorm::new(&part.mean, &(part.cov - noise)).quantile(0.95)
                                } else {
                                    f64::INFINITY
                                }
                            } else {
                                let (mix, _, share) =
                                    bounded_mixture(&per_truth, &weights, &axes, horizons - 1, m, &noise);
                                if 0.95 < share { mix.quantile(0.95 / share) } else { f64::INFINITY }
                            };
                            let one_sigma = (&b.s * &u).norm();
                            let sigmas = if p95.is_finite() && one_sigma > 0.0 { p95 / one_sigma } else { SIGMA_POINT };
                            Some((m, u, sigmas))
                        })
                        .collect()
                };
                let relinearised;
                (relinearised, (probe_blocks, navigated, last_rows)) = rayon::join(
                    || (!single).then(|| linearisation_at(cell, x_t)),
                    || {
                        let last: Option<Vec<RowDistribution>> = last_rows_by_probes.then(|| {
                            (0..4)
                                .into_par_iter()
                                .map(|m| mixture_distribution(&per_truth, &weights, &axes, horizons - 1, m))
                                .collect()
                        });
                        let (mut probes, mut probe_blocks) = (Vec::new(), Vec::new());
                        for (m, u, sigmas) in directions(last.as_ref()) {
                            for sign in [1.0, -1.0] {
                                let dx = &u * (sign * sigmas);
                                probes.push(Probe { truth: x_t.clone(), compensation: x_t + &dx });
                                probe_blocks.push(ProbeBlock { metric: m, horizon: None, dx, sigmas, linear: None });
                            }
                        }
                        let navigated = self.navigate(&probes, &probe_blocks);
                        (probe_blocks, navigated, last)
                    },
                );
                // The probes' linear prediction from the probed truth's own linearisation: the
                // index then measures the navigator's departure from it at that truth, and the
                // sensitivity's change from the reference's is the truth index's.
                if let Some(Ok(at)) = &relinearised {
                    let at_blocks: Vec<[DMatrix<f64>; 4]> =
                        (0..horizons).map(|h| std::array::from_fn(|m| at.block(h, m))).collect();
                    for pb in probe_blocks.iter_mut() {
                        pb.linear = Some(
                            at_blocks.iter().map(|hb| std::array::from_fn(|m| (&hb[m] * &pb.dx).norm())).collect(),
                        );
                    }
                }
                truth_index = relinearised.map(|at| {
                    rms_change(at, horizons, |at, h, m| {
                        let s = at.block(h, m);
                        let moved = (&s * cov * s.transpose()).trace() + self.noise_var * at.noise_block(h, m).trace();
                        (moved, per_truth[k][h][m].cov.trace())
                    })
                });
            }
            (probe_blocks, probe_component, truth_index, navigated, last_rows)
        };
        let mixture = || {
            (per_truth.len() > 1).then(|| {
                let read = if last_rows_by_probes { horizons - 1 } else { horizons };
                (0..read)
                    .into_par_iter()
                    .map(|h| (0..4).map(|m| mixture_distribution(&per_truth, &weights, &axes, h, m)).collect())
                    .collect::<Vec<Vec<RowDistribution>>>()
            })
        };
        let (mut distributions, (probe_blocks, probe_component, truth_index, navigated, last_rows)) =
            rayon::join(mixture, probe_stage);
        if let (Some(d), Some(last)) = (&mut distributions, last_rows) {
            d.push(last);
        }
        Ok(Prepared {
            comp: Compensation::Estimated,
            distributions,
            parts: per_truth,
            shares,
            probes: probe_blocks,
            navigated,
            unbounded,
            probe_component,
            truth_index,
            excluded,
            refused_fraction,
        })
    }

    /// The row of one horizon and metric.
    fn row(&self, prep: &Prepared, h: usize, m: usize) -> MetricResult {
        let parts = &prep.parts;
        let components = parts.len();
        let first = &parts[0][h][m];
        let d = match &prep.distributions {
            Some(d) => d[h][m],
            None if !first.unbounded_by.is_empty() => RowDistribution::unbounded(),
            None => {
                let dist = GaussNorm::new(&first.mean, &first.cov);
                let (median, p95, p05) =
                    if dist.is_deterministic() && first.mean == Vector3::zeros() && !prep.navigated.is_empty() {
                        // No parameter error and no noise: the navigator's own integration error.
                        let e = prep.navigated[0][h][m];
                        (e, e, e)
                    } else {
                        (dist.quantile(0.5), dist.quantile(0.95), dist.quantile(0.05))
                    };
                RowDistribution { median, p95, p05, median_se: 0.0, p95_se: 0.0, mean_square: dist.mean_square() }
            }
        };
        // Budget: the (weighted) average over components (see [`Prepared::shares`]).
        let shares = &prep.shares[h][m];
        let mut budget: Vec<(Source, f64)> =
            shares.parameters.iter().enumerate().map(|(i, &v)| (Source::Parameter(i), v)).collect();
        budget.push((Source::Fixture, shares.fixture));
        budget.push((Source::Noise, shares.noise));
        // Nonlinearity: the probes of this metric (in pairs about the centre) and the centre's
        // (for a mean), against the probed component's spread at this horizon.
        let spread = largest_eigenvalue(&parts[prep.probe_component][h][m].cov).sqrt();
        let mut nl = 0.0_f64;
        let mut have = false;
        let mut pair: Vec<(f64, f64, f64)> = Vec::with_capacity(2);
        for (k, probe) in prep.probes.iter().enumerate() {
            if prep.navigated.is_empty()
                || (probe.metric != m && probe.metric != usize::MAX)
                || probe.horizon.is_some_and(|ph| ph != h)
            {
                continue;
            }
            let lin_norm = match &probe.linear {
                Some(linear) => linear[h][m],
                None => (&self.blocks[h][m].s * &probe.dx).norm(),
            };
            if probe.metric == usize::MAX {
                if lin_norm > 0.0 {
                    have = true;
                    nl = nl.max(index(prep.navigated[k][h][m], lin_norm, probe.sigmas * spread));
                }
                continue;
            }
            have = true;
            pair.push((prep.navigated[k][h][m], lin_norm, probe.sigmas * spread));
            if pair.len() == 2 {
                let (a, b) = (pair[0], pair[1]);
                nl = nl.max(pair_index([a.0, b.0], [a.1, b.1], a.2.max(b.2)));
                pair.clear();
            }
        }
        for (navigated, linear, scale) in pair {
            nl = nl.max(index(navigated, linear, scale));
        }
        if let Some(t) = &prep.truth_index {
            nl = nl.max(t[h][m]);
            have = true;
        }
        let nonlinearity = if have {
            nl
        } else if self.settings.nonlinearity {
            0.0
        } else {
            f64::NAN
        };
        MetricResult {
            compensation: prep.comp,
            metric: m,
            horizon_s: self.horizons_s[h],
            median: d.median,
            p95: d.p95,
            p05: d.p05,
            rms: d.mean_square.sqrt(),
            median_se: d.median_se,
            p95_se: d.p95_se,
            components,
            unbounded_by: prep.unbounded[h][m].clone(),
            budget,
            nonlinearity,
            linear: d.mean_square.is_finite() && nonlinearity <= LINEAR_THRESHOLD,
        }
    }
}

/// One kept truth's parts (`[horizon][metric]`) and its weight.
type TruthParts = (Vec<Vec<Part>>, f64);

/// Truths of a mixture per parallel chunk (fixed, so that the chunks' sums are the same on any
/// number of threads).
const TRUTH_CHUNK: usize = 32;

/// The weighted sum of a mixture's parameter covariances (and of their fixture parts), for the
/// budget ([`Prepared::shares`]). Block by block where the covariances are block-diagonal.
#[derive(Clone)]
struct WeightedSum {
    cov: DMatrix<f64>,
    /// Empty for a perfect fixture.
    fixture: DMatrix<f64>,
    weight: f64,
    block_diagonal: bool,
}

impl WeightedSum {
    fn new(p: usize, perfect: bool) -> Self {
        let q = if perfect { 0 } else { p };
        WeightedSum { cov: DMatrix::zeros(p, p), fixture: DMatrix::zeros(q, q), weight: 0.0, block_diagonal: perfect }
    }

    fn add(&mut self, cal: &Calibration, weight: f64) {
        self.weight += weight;
        if self.block_diagonal {
            for o in (0..self.cov.nrows()).step_by(PER_ACCEL) {
                for c in o..o + PER_ACCEL {
                    for r in o..o + PER_ACCEL {
                        self.cov[(r, c)] += weight * cal.covariance[(r, c)];
                    }
                }
            }
        } else {
            // In place (no temporary matrix per truth).
            self.cov.zip_apply(&cal.covariance, |a, b| *a += weight * b);
            self.fixture.zip_apply(&cal.fixture, |a, b| *a += weight * b);
        }
    }

    /// [`Self::add`] for a perfect fixture's covariance held as one block per accelerometer.
    fn add_blocks(&mut self, blocks: &[ParamBlock], weight: f64) {
        self.weight += weight;
        for (j, b) in blocks.iter().enumerate() {
            let o = PER_ACCEL * j;
            for c in 0..PER_ACCEL {
                for r in 0..PER_ACCEL {
                    self.cov[(o + r, o + c)] += weight * b[(r, c)];
                }
            }
        }
    }

    fn merge(&mut self, other: &WeightedSum) {
        self.weight += other.weight;
        self.cov += &other.cov;
        self.fixture += &other.fixture;
    }

    /// Each block's budget from the weighted mean covariance: the parameters' shares less the
    /// fixture's part of each, which is the fixture's share.
    fn shares(&self, ctx: &Context<'_>) -> Vec<Vec<Shares>> {
        let mean = &self.cov / self.weight;
        let pc = ParamCov { cov: &mean, block_diagonal: self.block_diagonal };
        let fixture = (!self.block_diagonal).then(|| &self.fixture / self.weight);
        ctx.per_block(|b| {
            let (_, mut parameters) = propagate(&b.s, &pc);
            let mut fixture_share = 0.0;
            if let Some(fixture) = &fixture {
                let (_, fix_shares) = propagate(&b.s, &ParamCov { cov: fixture, block_diagonal: false });
                for (s, f) in parameters.iter_mut().zip(&fix_shares) {
                    *s -= f;
                    fixture_share += f;
                }
            }
            Shares { parameters, fixture: fixture_share, noise: (ctx.noise_var * b.noise_unit).trace() }
        })
    }
}

/// Analyses one cell (see the module docs of [`super`]). `lin` is the cell's linearisation.
/// The compensations, the truths of a mixture, the probes' navigations and the rows run in
/// parallel; every number is a function of the cell and seed alone.
/// The estimated compensation's drawn truths calibrated before the navigation is linearised (they
/// do not need it, so [`super::run`] calibrates them beside the linearisation): a mixture with a
/// perfect fixture, each truth's covariance as one block per accelerometer, shrunk to the
/// small-error region, with its weight (`None`: excluded), and the weighted sum of them for the
/// budget (summed in fixed chunks, in order: the same bits on any number of threads).
pub struct CalibratedTruths {
    xs: Vec<DVector<f64>>,
    blocks: Vec<Option<(Vec<ParamBlock>, f64)>>,
    sum: WeightedSum,
}

/// [`CalibratedTruths`] of `cell`'s estimated compensation; `None` where it has none, where its
/// errors are fixed (one truth), with a fixture error or without noise, or where some truth's
/// block is not positive definite (a schedule that loses a parameter there): the analysis then
/// calibrates the truths one by one, with their null directions.
pub fn calibrate_truths(cell: &Cell, seed: u64, settings: &Settings) -> Option<CalibratedTruths> {
    let density = cell.noise.white.density_m_s2_per_sqrt_hz();
    let p = cell.layout.len();
    if !cell.navigation.compensations.contains(&Compensation::Estimated)
        || !cell.calibration.pose.is_perfect()
        || density <= 0.0
        || p == 0
        || !p.is_multiple_of(PER_ACCEL)
    {
        return None;
    }
    let xs = truths(cell, seed, settings.truths.max(1));
    if xs.len() < 2 {
        return None;
    }
    let motions = step_motions(&cell.schedule, cell.calibration.gravity_m_s2);
    let bounds = crate::calib::estimate::small_error_bounds(&cell.layout);
    type Chunk = (Vec<Option<(Vec<ParamBlock>, f64)>>, WeightedSum);
    let per_chunk: Vec<Option<Chunk>> = xs
        .par_chunks(TRUTH_CHUNK)
        .map(|chunk| {
            let mut sum = WeightedSum::new(p, true);
            let mut out = Vec::with_capacity(chunk.len());
            for x in chunk {
                let mut blocks = block_covariances(cell, x, density, &motions)?;
                let weight = stay_in_small_error_region_blocks(&mut blocks, x, &bounds);
                if weight.is_nan() || weight <= 0.0 {
                    out.push(None);
                    continue;
                }
                sum.add_blocks(&blocks, weight);
                out.push(Some((blocks, weight)));
            }
            Some((out, sum))
        })
        .collect();
    let mut sum = WeightedSum::new(p, true);
    let mut blocks = Vec::with_capacity(xs.len());
    for chunk in per_chunk {
        let (out, chunk_sum) = chunk?;
        sum.merge(&chunk_sum);
        blocks.extend(out);
    }
    Some(CalibratedTruths { xs, blocks, sum })
}

/// Analyses one cell, navigated as `lin` and `grid` say; `calibrated`: its truths, where
/// [`calibrate_truths`] has them already (otherwise they are calibrated here).
pub fn analyse_cell(
    cell: &Cell,
    lin: &Linearisation,
    seed: u64,
    settings: &Settings,
    grid: Option<&Arc<MotionGrid>>,
    calibrated: Option<CalibratedTruths>,
) -> Result<CellResult, LincovError> {
    check(cell)?;
    let calibrated = calibrated.or_else(|| calibrate_truths(cell, seed, settings));
    let nav = &cell.navigation;
    let horizons = lin.horizons_s.len();
    let density = cell.noise.white.density_m_s2_per_sqrt_hz();
    let blocks: Vec<Vec<Block>> = (0..horizons)
        .map(|h| (0..4).map(|m| Block { s: lin.block(h, m), noise_unit: lin.noise_block(h, m) }).collect())
        .collect();
    let stacked = StackedBlocks::new(&blocks.iter().flatten().map(|b| &b.s).collect::<Vec<_>>());
    let ctx = Context {
        cell,
        blocks,
        stacked,
        horizons_s: &lin.horizons_s,
        seed,
        settings,
        grid,
        density,
        noise_var: if nav.noise { density * density } else { 0.0 },
    };
    let prepared: Vec<Prepared> = nav
        .compensations
        .par_iter()
        .map(|comp| match comp {
            Compensation::Nominal => Ok(ctx.nominal()),
            Compensation::True => Ok(ctx.true_noise()),
            Compensation::Estimated => ctx.estimated(calibrated.as_ref()),
        })
        .collect::<Result<_, _>>()?;
    // Every compensation's rows at once, in order.
    let rows: Vec<MetricResult> = (0..prepared.len() * horizons * 4)
        .into_par_iter()
        .map(|i| {
            let (c, hm) = (i / (horizons * 4), i % (horizons * 4));
            ctx.row(&prepared[c], hm / 4, hm % 4)
        })
        .collect();
    let excluded = prepared.iter().map(|p| p.excluded).sum();
    let refused_fraction = prepared.iter().map(|p| p.refused_fraction).sum();
    Ok(CellResult { cell: cell.index, rows, excluded_truths: excluded, refused_fraction })
}

/// The chance that a fit at truth `x`, its error distributed `N(0, cov)`, stays inside the
/// small-error region `|x_i + e_i| <= bounds[i]` (the bounded parameters taken as independent),
/// and `cov` and `fixture` (the fixture's part of `cov`) turned into those of the fits that stay.
/// Per bounded parameter `i` whose bound is not far in its tail, the error is shrunk along the
/// parameter, `e' = e - (1 - s) (C e_i / C_ii) e_i`, with `s^2` the second moment of the normal
/// truncated at the bounds over its variance: so `C_ii` becomes that second moment (about the
/// truth, where the navigation's error is measured), and every parameter correlated with it is
/// conditioned with it, `C' = C - (1 - s^2) C[:, i] C[i, :] / C_ii` (exact for one bound; in turn
/// for several). The same linear map on `fixture` keeps the budget's split. Weight exactly 1 and
/// nothing changed where every bound is far in its parameter's tail; 0 where a fit cannot stay.
fn stay_in_small_error_region(
    cov: &mut DMatrix<f64>,
    fixture: Option<&mut DMatrix<f64>>,
    x: &DVector<f64>,
    bounds: &[f64],
) -> f64 {
    let mut fixture = fixture;
    let mut weight = 1.0;
    for (i, &r) in bounds.iter().enumerate() {
        let var = cov[(i, i)];
        let (inside, shrink) = match stay(var, x[i], r) {
            Stay::Always => continue,
            Stay::Never => return 0.0,
            Stay::Within { inside, shrink } => (inside, shrink),
        };
        weight *= inside;
        let beta: Vec<f64> = (0..cov.nrows()).map(|k| cov[(k, i)] / var).collect();
        for m in [Some(&mut *cov), fixture.as_deref_mut()].into_iter().flatten() {
            let n = m.nrows();
            shrink_along(m, n, &beta, i, shrink);
        }
    }
    weight
}

/// [`stay_in_small_error_region`] for a perfect fixture's covariance held as one block per
/// accelerometer (the same arithmetic, so the same bits: the shrink of a parameter reaches only
/// its own block).
fn stay_in_small_error_region_blocks(blocks: &mut [ParamBlock], x: &DVector<f64>, bounds: &[f64]) -> f64 {
    let mut weight = 1.0;
    for (j, m) in blocks.iter_mut().enumerate() {
        for i in 0..PER_ACCEL {
            let var = m[(i, i)];
            let (inside, shrink) = match stay(var, x[PER_ACCEL * j + i], bounds[PER_ACCEL * j + i]) {
                Stay::Always => continue,
                Stay::Never => return 0.0,
                Stay::Within { inside, shrink } => (inside, shrink),
            };
            weight *= inside;
            let beta: [f64; PER_ACCEL] = std::array::from_fn(|k| m[(k, i)] / var);
            shrink_along(m, PER_ACCEL, &beta, i, shrink);
        }
    }
    weight
}

/// What the small-error region does to one parameter's fits.
enum Stay {
    /// No bound, no spread, or the bound far in the tail: nothing.
    Always,
    /// No fit stays (or the variance is not a number).
    Never,
    /// The chance a fit stays, and how much the kept fits' spread shrinks along the parameter.
    Within { inside: f64, shrink: f64 },
}

/// [`Stay`] of a parameter with variance `var`, true value `x` and bound `r` (`|estimate| <= r`).
fn stay(var: f64, x: f64, r: f64) -> Stay {
    use statrs::function::erf::erfc;
    let phi = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let cdf = |z: f64| 0.5 * erfc(-z / std::f64::consts::SQRT_2);
    if !r.is_finite() {
        return Stay::Always;
    }
    if var.is_nan() || var.is_infinite() {
        return Stay::Never;
    }
    let sigma = var.max(0.0).sqrt();
    if sigma == 0.0 {
        return Stay::Always;
    }
    let (a, b) = ((-r - x) / sigma, (r - x) / sigma);
    if a <= -FAR_IN_THE_TAIL && b >= FAR_IN_THE_TAIL {
        return Stay::Always;
    }
    let inside = if a > 0.0 { cdf(-a) - cdf(-b) } else { cdf(b) - cdf(a) };
    if inside.is_nan() || inside <= 0.0 {
        return Stay::Never;
    }
    let second_moment = 1.0 + (a * phi(a) - b * phi(b)) / inside;
    Stay::Within { inside, shrink: 1.0 - second_moment.max(0.0).sqrt() }
}

fn shrink_along<M: std::ops::IndexMut<(usize, usize), Output = f64>>(
    m: &mut M,
    n: usize,
    beta: &[f64],
    i: usize,
    shrink: f64,
) {
    let active: Vec<usize> = (0..n).filter(|&r| beta[r] != 0.0 || m[(r, i)] != 0.0 || m[(i, r)] != 0.0).collect();
    let row_i: Vec<f64> = active.iter().map(|&c| m[(i, c)]).collect();
    let col_i: Vec<f64> = active.iter().map(|&r| m[(r, i)]).collect();
    let mii = m[(i, i)];
    for (b, &c) in active.iter().enumerate() {
        for (a, &r) in active.iter().enumerate() {
            m[(r, c)] += shrink * (shrink * beta[r] * mii * beta[c] - beta[r] * row_i[b] - col_i[a] * beta[c]);
        }
    }
}

/// Standard deviations beyond which a bound leaves a normal's chance and spread exactly 1 in
/// double precision (`Phi(-9) = 1.1e-19`, `9 phi(9) = 9.2e-18`, both below half an ulp of 1).
const FAR_IN_THE_TAIL: f64 = 9.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// A mixture's truths calibrated block by block on the stack are the whole-covariance path's
    /// bits (its Cholesky inverse and its small-error shrink), on the quickstart's truths: the
    /// fast path must not move a number.
    #[test]
    fn block_by_block_calibrations_are_the_whole_covariances_bits() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs").join("quickstart.toml");
        let cfg = crate::mc::McConfig::load(&path).expect("the quickstart loads");
        let cell = &cfg.cells[0];
        let density = cell.noise.white.density_m_s2_per_sqrt_hz();
        let motions = step_motions(&cell.schedule, cell.calibration.gravity_m_s2);
        let bounds = crate::calib::estimate::small_error_bounds(&cell.layout);
        let p = cell.layout.len();
        let mut shrunk = 0;
        for x in truths(cell, cfg.seed, 64) {
            let mut blocks = block_covariances(cell, &x, density, &motions).expect("positive definite blocks");
            let mut whole = calibration_with(cell, &x, density, false).covariance;
            let w_blocks = stay_in_small_error_region_blocks(&mut blocks, &x, &bounds);
            let before = whole.clone();
            let w_whole = stay_in_small_error_region(&mut whole, None, &x, &bounds);
            shrunk += usize::from(whole != before);
            assert_eq!(w_blocks.to_bits(), w_whole.to_bits());
            for r in 0..p {
                for c in 0..p {
                    let expected = if r / PER_ACCEL == c / PER_ACCEL {
                        blocks[r / PER_ACCEL][(r % PER_ACCEL, c % PER_ACCEL)]
                    } else {
                        0.0
                    };
                    assert_eq!(whole[(r, c)].to_bits(), expected.to_bits(), "({r}, {c})");
                }
            }
        }
        // The shrink was exercised, not only the plain inverse.
        assert!(shrunk > 0);
    }

    /// The chance of staying in the region and the kept fits' second moments against samples of
    /// a normal (an independent generator): a location error of sigma 50 mm at truth 10 mm in a
    /// region of +-60 mm, a misalignment far inside its bound, and a bias without a bound
    /// correlated with the location (0.6), which the kept fits condition.
    #[test]
    fn the_chance_of_staying_and_the_kept_fits_moments_match_samples() {
        let (sigma, truth, bound) = (0.05, 0.01, 0.06);
        let sd = [sigma, 1e-4, 2.0];
        let corr = [[1.0, 0.0, 0.6], [0.0, 1.0, 0.0], [0.6, 0.0, 1.0]];
        let before = DMatrix::from_fn(3, 3, |r, c| corr[r][c] * sd[r] * sd[c]);
        let x = DVector::from_vec(vec![truth, 0.0, 0.0]);
        let bounds = [bound, 0.1, f64::INFINITY];
        let (mut cov, mut fixture) = (before.clone(), before.clone());
        let weight = stay_in_small_error_region(&mut cov, Some(&mut fixture), &x, &bounds);
        let l = before.clone().cholesky().expect("positive definite").l();
        let mut rng = trial_rng(7, 0);
        let n = 2_000_000;
        let mut moments = DMatrix::<f64>::zeros(3, 3);
        let mut kept = 0usize;
        for _ in 0..n {
            let z =
                DVector::from_fn(3, |_, _| <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng));
            let e = &l * z;
            if (truth + e[0]).abs() <= bound {
                kept += 1;
                moments += &e * e.transpose();
            }
        }
        moments /= kept as f64;
        let share = kept as f64 / n as f64;
        // Binomial error of 2e6 draws: 3e-4.
        assert!((weight - share).abs() < 1.5e-3, "weight {weight} vs sampled {share}");
        for r in [0, 2] {
            for c in [0, 2] {
                let scale = (cov[(r, r)] * cov[(c, c)]).sqrt();
                assert!(
                    (cov[(r, c)] - moments[(r, c)]).abs() < 5e-3 * scale,
                    "({r}, {c}): {} vs sampled {}",
                    cov[(r, c)],
                    moments[(r, c)]
                );
            }
        }
        // The kept location errors are much narrower, and the bias they condition narrower too.
        assert!(cov[(0, 0)] < 0.5 * before[(0, 0)] && cov[(2, 2)] < 0.9 * before[(2, 2)]);
        // The misalignment far inside its bound and uncorrelated: untouched.
        assert_eq!(cov[(1, 1)], before[(1, 1)]);
        // The same map on a fixture part equal to the whole: the same matrix.
        assert!((&fixture - &cov).abs().max() < 1e-15 * cov.abs().max());
        // Bounds far out in the tail leave the covariance exactly as it was, weight exactly 1.
        let mut far = before.clone();
        let w = stay_in_small_error_region(&mut far, None, &x, &[100.0, 0.1, f64::INFINITY]);
        assert_eq!(w, 1.0);
        assert_eq!(far, before);
    }
}
