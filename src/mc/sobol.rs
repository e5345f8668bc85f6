//! First-order and total Sobol' indices from a run on a Saltelli design (see
//! [`Saltelli`](super::sample::Saltelli)), with bootstrap confidence intervals.
//!
//! With `f_A`, `f_B` and `f_ABi` the outputs of the rows of one base sample and `V` the variance
//! of all `f_A` and `f_B`:
//! - first order (Saltelli et al. 2010, with `f_B` centred on the mean output, which leaves the
//!   estimator consistent and removes the mean's share of its variance):
//!   `S_i = mean((f_B - mean) (f_ABi - f_A)) / V`;
//! - total (Jansen 1999): `ST_i = mean((f_A - f_ABi)^2) / (2 V)`.
//!
//! The output is `log10` of the drift metric: drift spans decades between trials and its raw
//! variance is dominated by the few largest values, so indices of the raw value mostly describe
//! the tail; those of its logarithm describe the orders of magnitude.
//!
//! The 95% intervals are bootstrap percentiles over the base samples. A base sample with any
//! output missing (no estimate) or diverged is left out. The noise (of the calibration, and of
//! the navigation when it has noise) is one more input of the design, the same in a block's A
//! and AB rows ([`Saltelli::noise_stream`](super::sample::Saltelli::noise_stream)): it is part
//! of `V`, so for the estimated compensation the parameters' first-order indices sum to less
//! than one by the noise's share, but it does not enter their total indices except through
//! interactions.

use std::collections::BTreeMap;
use std::path::Path;

use arrow_array::{Float64Array, UInt64Array};
use rand::RngExt;

use super::config::McConfig;
use super::output::{drift_column, drift_value};
use crate::io::parquet::{ParquetIoError, column, part_files, read_batches};
use crate::mc::trial::DRIFT_METRICS;

/// Resamples for the confidence intervals.
pub const BOOTSTRAP_RESAMPLES: usize = 300;
/// Salt of the bootstrap streams.
const BOOTSTRAP_SALT: u64 = 0x626f_6f74_7374_7270;

/// The indices of one input for one output.
#[derive(Debug, Clone, PartialEq)]
pub struct SobolRow {
    pub cell: u32,
    pub output: String,
    pub input: String,
    pub first_order: f64,
    pub first_order_lo: f64,
    pub first_order_hi: f64,
    pub total: f64,
    pub total_lo: f64,
    pub total_hi: f64,
    /// Base samples used (all of the block's outputs finite).
    pub base_samples: usize,
}

/// First-order and total indices of each input from the outputs of the base samples `idx`:
/// `a[j]`, `b[j]` and `ab[i][j]`.
pub fn indices(a: &[f64], b: &[f64], ab: &[Vec<f64>], idx: &[usize]) -> (Vec<f64>, Vec<f64>) {
    let n = idx.len() as f64;
    let mean = idx.iter().map(|&j| a[j] + b[j]).sum::<f64>() / (2.0 * n);
    let var = idx.iter().map(|&j| (a[j] - mean).powi(2) + (b[j] - mean).powi(2)).sum::<f64>() / (2.0 * n - 1.0);
    if var.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return (vec![0.0; ab.len()], vec![0.0; ab.len()]);
    }
    let first =
        ab.iter().map(|abi| idx.iter().map(|&j| (b[j] - mean) * (abi[j] - a[j])).sum::<f64>() / n / var).collect();
    let total =
        ab.iter().map(|abi| idx.iter().map(|&j| (a[j] - abi[j]).powi(2)).sum::<f64>() / (2.0 * n) / var).collect();
    (first, total)
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let k = ((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1);
    v[k]
}

/// Indices with bootstrap intervals: `(first, first_lo, first_hi, total, total_lo, total_hi)`
/// per input, over the base samples whose outputs are all finite; `None` with fewer than 10.
#[allow(clippy::type_complexity)]
pub fn indices_with_intervals(
    a: &[f64],
    b: &[f64],
    ab: &[Vec<f64>],
    resamples: usize,
    seed: u64,
) -> Option<(Vec<[f64; 6]>, usize)> {
    let valid: Vec<usize> = (0..a.len())
        .filter(|&j| a[j].is_finite() && b[j].is_finite() && ab.iter().all(|abi| abi[j].is_finite()))
        .collect();
    if valid.len() < 10 {
        return None;
    }
    let (first, total) = indices(a, b, ab, &valid);
    let mut rng = crate::rng::trial_rng(seed ^ BOOTSTRAP_SALT, 0);
    let d = ab.len();
    let mut boot_first = vec![Vec::with_capacity(resamples); d];
    let mut boot_total = vec![Vec::with_capacity(resamples); d];
    let mut idx = vec![0usize; valid.len()];
    for _ in 0..resamples {
        for k in idx.iter_mut() {
            *k = valid[rng.random_range(0..valid.len())];
        }
        let (f, t) = indices(a, b, ab, &idx);
        for i in 0..d {
            boot_first[i].push(f[i]);
            boot_total[i].push(t[i]);
        }
    }
    let rows = (0..d)
        .map(|i| {
            [
                first[i],
                percentile(&mut boot_first[i], 0.025),
                percentile(&mut boot_first[i], 0.975),
                total[i],
                percentile(&mut boot_total[i], 0.025),
                percentile(&mut boot_total[i], 0.975),
            ]
        })
        .collect();
    Some((rows, valid.len()))
}

/// Sobol' indices of every input for `log10` of every drift column (every compensation, horizon
/// and metric) of each cell of a run on a Saltelli design (empty when the run has none).
pub fn sobol(dir: &Path, cfg: &McConfig) -> Result<Vec<SobolRow>, ParquetIoError> {
    if cfg.cells.iter().all(|c| c.saltelli.is_none()) {
        return Ok(Vec::new());
    }
    // (cell, column) -> value of each trial of the cell, by local index.
    let mut values: BTreeMap<(u32, String), Vec<f64>> = BTreeMap::new();
    let tpc = cfg.trials_per_cell as usize;
    let wanted: Vec<Vec<String>> = cfg
        .cells
        .iter()
        .map(|c| {
            let nav = &c.navigation;
            nav.compensations
                .iter()
                .flat_map(|comp| {
                    nav.horizons_s
                        .iter()
                        .flat_map(move |h| DRIFT_METRICS.iter().map(move |(m, _)| drift_column(comp.name(), m, *h)))
                })
                .collect()
        })
        .collect();
    for file in part_files(&dir.join("trials")) {
        for batch in read_batches(&file)? {
            let trial = column::<UInt64Array>(&batch, "trial_id", &file)?;
            // Each cell's wanted columns, looked up once per batch.
            let arrays: Vec<Vec<Option<&Float64Array>>> = wanted
                .iter()
                .map(|cols| cols.iter().map(|col| column::<Float64Array>(&batch, col, &file).ok()).collect())
                .collect();
            for i in 0..batch.num_rows() {
                let t = trial.value(i);
                let c = (t / cfg.trials_per_cell) as usize;
                let (Some(cols), Some(arrays)) = (wanted.get(c), arrays.get(c)) else { continue };
                for (col, array) in cols.iter().zip(arrays) {
                    let Some(v) = array else { continue };
                    values.entry((c as u32, col.clone())).or_insert_with(|| vec![f64::NAN; tpc])
                        [(t % cfg.trials_per_cell) as usize] = drift_value(v, i);
                }
            }
        }
    }
    let mut rows = Vec::new();
    for ((c, col), v) in &values {
        let cell = &cfg.cells[*c as usize];
        let Some(design) = &cell.saltelli else { continue };
        let per = design.rows_per_sample() as usize;
        let n = design.base_samples as usize;
        let d = design.inputs.len();
        // log10 of the drift (zero -> -inf, left out like a divergence).
        let y = |k: usize| v[k].log10();
        let a: Vec<f64> = (0..n).map(|j| y(j * per)).collect();
        let b: Vec<f64> = (0..n).map(|j| y(j * per + 1)).collect();
        let ab: Vec<Vec<f64>> = (0..d).map(|i| (0..n).map(|j| y(j * per + 2 + i)).collect()).collect();
        let Some((idx, used)) = indices_with_intervals(&a, &b, &ab, BOOTSTRAP_RESAMPLES, cfg.seed ^ *c as u64) else {
            continue;
        };
        for (i, r) in idx.iter().enumerate() {
            rows.push(SobolRow {
                cell: *c,
                output: col.clone(),
                input: cell.layout.name(design.inputs[i]),
                first_order: r[0],
                first_order_lo: r[1],
                first_order_hi: r[2],
                total: r[3],
                total_lo: r[4],
                total_hi: r[5],
                base_samples: used,
            });
        }
    }
    Ok(rows)
}

/// The rows as CSV.
pub fn sobol_csv(rows: &[SobolRow]) -> String {
    let mut out = String::from(
        "cell,output,input,first_order,first_order_lo95,first_order_hi95,total,total_lo95,total_hi95,base_samples\n",
    );
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{:e},{:e},{:e},{:e},{:e},{:e},{}\n",
            r.cell,
            r.output,
            r.input,
            r.first_order,
            r.first_order_lo,
            r.first_order_hi,
            r.total,
            r.total_lo,
            r.total_hi,
            r.base_samples
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Ishigami function (a = 7, b = 0.1) on [-pi, pi]^3, whose indices are known in closed
    /// form: S = (0.3139, 0.4424, 0), ST = (0.5576, 0.4424, 0.2437).
    #[test]
    fn ishigami_indices_match_the_closed_form() {
        let f = |x: [f64; 3]| x[0].sin() + 7.0 * x[1].sin().powi(2) + 0.1 * x[2].powi(4) * x[0].sin();
        let pi = std::f64::consts::PI;
        let (a_var, b_var) = (7.0f64, 0.1f64);
        let v1 = 0.5 * (1.0 + b_var * pi.powi(4) / 5.0).powi(2);
        let v2 = a_var * a_var / 8.0;
        let v13 = b_var * b_var * pi.powi(8) * (1.0 / 18.0 - 1.0 / 50.0);
        let v = v1 + v2 + v13;
        let exact_first = [v1 / v, v2 / v, 0.0];
        let exact_total = [(v1 + v13) / v, v2 / v, v13 / v];
        let mut rng = crate::rng::trial_rng(11, 0);
        let n = 20000;
        let draw =
            |rng: &mut rand_chacha::ChaCha8Rng| -> [f64; 3] { [0, 1, 2].map(|_| -pi + 2.0 * pi * rng.random::<f64>()) };
        let xa: Vec<[f64; 3]> = (0..n).map(|_| draw(&mut rng)).collect();
        let xb: Vec<[f64; 3]> = (0..n).map(|_| draw(&mut rng)).collect();
        let a: Vec<f64> = xa.iter().map(|x| f(*x)).collect();
        let b: Vec<f64> = xb.iter().map(|x| f(*x)).collect();
        let ab: Vec<Vec<f64>> = (0..3)
            .map(|i| {
                (0..n)
                    .map(|j| {
                        let mut x = xa[j];
                        x[i] = xb[j][i];
                        f(x)
                    })
                    .collect()
            })
            .collect();
        let (rows, used) = indices_with_intervals(&a, &b, &ab, 200, 3).unwrap();
        assert_eq!(used, n);
        for i in 0..3 {
            let r = rows[i];
            assert!((r[0] - exact_first[i]).abs() < 0.03, "S{}: {} vs {}", i + 1, r[0], exact_first[i]);
            assert!((r[3] - exact_total[i]).abs() < 0.03, "ST{}: {} vs {}", i + 1, r[3], exact_total[i]);
            // The intervals are about the estimate and cover the exact value.
            assert!(r[1] <= r[0] && r[0] <= r[2] && r[4] <= r[3] && r[3] <= r[5]);
            assert!(r[1] - 0.01 <= exact_first[i] && exact_first[i] <= r[2] + 0.01, "S{} interval", i + 1);
            assert!(r[4] - 0.01 <= exact_total[i] && exact_total[i] <= r[5] + 0.01, "ST{} interval", i + 1);
        }
    }

    #[test]
    fn blocks_with_a_missing_output_are_left_out() {
        let a: Vec<f64> = (0..20).map(|j| j as f64).collect();
        let b: Vec<f64> = (0..20).map(|j| (j * 7 % 20) as f64).collect();
        // An input the output does not depend on: f_AB = f_A, so both indices are exactly 0.
        let mut ab = vec![a.clone()];
        ab[0][3] = f64::NAN;
        let (rows, used) = indices_with_intervals(&a, &b, &ab, 10, 1).unwrap();
        assert_eq!(used, 19);
        assert_eq!(rows[0], [0.0; 6]);
        assert!(indices_with_intervals(&a[..5], &b[..5], &[b[..5].to_vec()], 10, 1).is_none());
    }
}
