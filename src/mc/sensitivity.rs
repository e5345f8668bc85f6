//! Which error parameters drive each drift metric: standardised rank regression coefficients
//! (SRRC) from a run's trials.
//!
//! For every drift column and cell, the trials' values are rank-transformed, as are the inputs,
//! and the standardised ranks of the output are regressed on those of the inputs; the
//! coefficients are the SRRC, and `R^2` says how much of the output's rank variance the inputs
//! explain linearly (an index is only meaningful when it is high). Drift metrics are magnitudes,
//! so the inputs are magnitudes too: `|true - nominal|` of each parameter for nominal
//! compensation (the nominal is 0 except for scale factors, whose true value is near the nominal
//! one: `|true|` would rank a signed deviation), `|estimated - true|` for estimated compensation.
//! Runs written before the `nominal` column existed fall back to `|true|`. Inputs that do not vary are left out. At most
//! `max_trials` trials per cell are used (the first by trial id), so memory stays bounded.
//!
//! A regression with as many coefficients as trials fits them exactly (R^2 = 1 from 15 trials and
//! 42 inputs says nothing). With fewer than [`MIN_TRIALS_PER_INPUT`] trials per varying input, a
//! cell's output gets no coefficients: one row with `srrc` and `r2` empty and a note saying why.

use std::collections::BTreeMap;
use std::path::Path;

use arrow_array::{Array, Float64Array, StringArray, UInt32Array, UInt64Array};
use nalgebra::{DMatrix, DVector};

use super::output::drift_value;
use crate::io::parquet::{ParquetIoError, read_batches};

/// The fewest trials per varying input a rank regression is fitted with.
pub const MIN_TRIALS_PER_INPUT: usize = 10;

/// Ranks of `x` (average rank for ties), 0-based.
pub fn ranks(x: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut r = vec![0.0; x.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        let avg = (i + j) as f64 / 2.0;
        for k in i..=j {
            r[idx[k]] = avg;
        }
        i = j + 1;
    }
    r
}

fn standardise(v: &[f64]) -> Option<Vec<f64>> {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt();
    (sd > 0.0).then(|| v.iter().map(|x| (x - m) / sd).collect())
}

/// SRRC of each input (`None` where the input does not vary) and the regression's `R^2`.
pub fn srrc(inputs: &[Vec<f64>], output: &[f64]) -> (Vec<Option<f64>>, f64) {
    let Some(y) = standardise(&ranks(output)) else { return (vec![None; inputs.len()], f64::NAN) };
    let cols: Vec<Option<Vec<f64>>> = inputs.iter().map(|x| standardise(&ranks(x))).collect();
    let used: Vec<usize> = (0..cols.len()).filter(|&i| cols[i].is_some()).collect();
    if used.is_empty() {
        return (vec![None; inputs.len()], 0.0);
    }
    let n = y.len();
    let x = DMatrix::from_fn(n, used.len(), |r, c| cols[used[c]].as_ref().map(|v| v[r]).unwrap_or(0.0));
    let yv = DVector::from_vec(y);
    let beta = x.clone().svd(true, true).solve(&yv, 1e-12).unwrap_or_else(|_| DVector::zeros(used.len()));
    let fitted = &x * &beta;
    let r2 = 1.0 - (&yv - &fitted).norm_squared() / yv.norm_squared();
    let mut out = vec![None; inputs.len()];
    for (c, &i) in used.iter().enumerate() {
        out[i] = Some(beta[c]);
    }
    (out, r2)
}

/// One index, or (with `srrc` and `r2` `None`, `input` empty and a `note`) the refusal to fit
/// a cell's output from too few trials.
#[derive(Debug, Clone, PartialEq)]
pub struct SensitivityRow {
    pub cell: u32,
    /// The drift column.
    pub output: String,
    /// `|a1.bias|` (true value) or `|error a1.bias|` (estimation error).
    pub input: String,
    pub srrc: Option<f64>,
    /// `R^2` of the output's rank regression.
    pub r2: Option<f64>,
    /// The trials the regression used (those with a value of the output).
    pub trials: usize,
    /// Why there are no coefficients, if there are none.
    pub note: Option<String>,
}

/// The rows as CSV (`sensitivity.csv`): `cell,output,input,srrc,r2,trials,note`.
pub fn sensitivity_csv(rows: &[SensitivityRow]) -> String {
    let mut csv = String::from("cell,output,input,srrc,r2,trials,note\n");
    let num = |v: Option<f64>| v.map(|v| format!("{v:e}")).unwrap_or_default();
    for r in rows {
        csv.push_str(&format!(
            "{},{},\"{}\",{},{},{},{}\n",
            r.cell,
            r.output,
            r.input,
            num(r.srrc),
            num(r.r2),
            r.trials,
            r.note.as_ref().map(|n| format!("\"{}\"", n.replace('"', "\"\""))).unwrap_or_default()
        ));
    }
    csv
}

/// SRRC of every parameter for every nominal- and estimated-compensation drift column of a run.
pub fn sensitivity(dir: &Path, max_trials: usize) -> Result<Vec<SensitivityRow>, ParquetIoError> {
    // (cell, trial) -> per-parameter |true| and |error|, keyed by name.
    let mut names: Vec<String> = Vec::new();
    let mut truth: BTreeMap<(u32, u64), Vec<f64>> = BTreeMap::new();
    let mut error: BTreeMap<(u32, u64), Vec<f64>> = BTreeMap::new();
    let mut per_cell: BTreeMap<u32, usize> = BTreeMap::new();
    let files = |sub: &str| crate::io::parquet::part_files(&dir.join(sub));
    let col =
        |b: &arrow_array::RecordBatch, name: &str, path: &Path| -> Result<arrow_array::ArrayRef, ParquetIoError> {
            b.column_by_name(name).cloned().ok_or_else(|| ParquetIoError::Format {
                path: path.display().to_string(),
                message: format!("no column `{name}`"),
            })
        };
    for file in files("parameters") {
        for b in read_batches(&file)? {
            let trial = col(&b, "trial_id", &file)?;
            let trial = trial.as_any().downcast_ref::<UInt64Array>().cloned();
            let cell = col(&b, "cell", &file)?;
            let cell = cell.as_any().downcast_ref::<UInt32Array>().cloned();
            let name = col(&b, "name", &file)?;
            let name = name.as_any().downcast_ref::<StringArray>().cloned();
            let t = col(&b, "true", &file)?;
            let t = t.as_any().downcast_ref::<Float64Array>().cloned();
            let e = col(&b, "error", &file)?;
            let e = e.as_any().downcast_ref::<Float64Array>().cloned();
            let nominal = b.column_by_name("nominal").and_then(|c| c.as_any().downcast_ref::<Float64Array>().cloned());
            let (Some(trial), Some(cell), Some(name), Some(t), Some(e)) = (trial, cell, name, t, e) else {
                return Err(ParquetIoError::Format {
                    path: file.display().to_string(),
                    message: "mistyped parameter columns".into(),
                });
            };
            for i in 0..b.num_rows() {
                let key = (cell.value(i), trial.value(i));
                let k = match names.iter().position(|n| n == name.value(i)) {
                    Some(k) => k,
                    None => {
                        names.push(name.value(i).to_string());
                        names.len() - 1
                    }
                };
                if !truth.contains_key(&key) {
                    let c = per_cell.entry(key.0).or_insert(0);
                    if *c >= max_trials {
                        continue;
                    }
                    *c += 1;
                }
                let tv = truth.entry(key).or_default();
                let ev = error.entry(key).or_default();
                tv.resize(tv.len().max(k + 1), f64::NAN);
                ev.resize(ev.len().max(k + 1), f64::NAN);
                tv[k] = (t.value(i) - nominal.as_ref().map_or(0.0, |n| n.value(i))).abs();
                ev[k] = e.value(i).abs();
            }
        }
    }
    // Drift columns of the kept trials.
    let mut outputs: BTreeMap<(u32, String), Vec<(u64, f64)>> = BTreeMap::new();
    for file in files("trials") {
        for b in read_batches(&file)? {
            let trial = col(&b, "trial_id", &file)?;
            let cell = col(&b, "cell", &file)?;
            let (Some(trial), Some(cell)) =
                (trial.as_any().downcast_ref::<UInt64Array>(), cell.as_any().downcast_ref::<UInt32Array>())
            else {
                continue;
            };
            let schema = b.schema();
            for (k, f) in schema.fields().iter().enumerate() {
                let n = f.name();
                if !(n.starts_with("nominal_") || n.starts_with("estimated_")) || !n.contains("_at_") {
                    continue;
                }
                let Some(v) = b.column(k).as_any().downcast_ref::<Float64Array>() else { continue };
                for i in 0..b.num_rows() {
                    let key = (cell.value(i), trial.value(i));
                    if truth.contains_key(&key) {
                        outputs.entry((key.0, n.clone())).or_default().push((key.1, drift_value(v, i)));
                    }
                }
            }
        }
    }
    let mut rows = Vec::new();
    for ((cell, column), values) in &outputs {
        // Finite outputs only (NaN: no estimate; +inf: diverged, ranked last).
        let kept: Vec<(u64, f64)> = values.iter().filter(|(_, v)| !v.is_nan()).copied().collect();
        let estimated = column.starts_with("estimated_");
        let source = if estimated { &error } else { &truth };
        let inputs: Vec<Vec<f64>> = (0..names.len())
            .map(|k| kept.iter().map(|(t, _)| source[&(*cell, *t)].get(k).copied().unwrap_or(f64::NAN)).collect())
            .collect();
        if inputs.iter().any(|x| x.iter().any(|v| v.is_nan())) {
            continue;
        }
        let varying = inputs.iter().filter(|x| x.iter().any(|v| *v != x[0])).count();
        if varying == 0 {
            continue;
        }
        if kept.len() < MIN_TRIALS_PER_INPUT * varying {
            rows.push(SensitivityRow {
                cell: *cell,
                output: column.clone(),
                input: String::new(),
                srrc: None,
                r2: None,
                trials: kept.len(),
                note: Some(format!(
                    "{} trials for {varying} inputs: fewer than {MIN_TRIALS_PER_INPUT} trials per input, so no \
                     coefficients (a regression with about as many coefficients as trials fits the noise)",
                    kept.len()
                )),
            });
            continue;
        }
        let y: Vec<f64> = kept.iter().map(|(_, v)| *v).collect();
        let (coef, r2) = srrc(&inputs, &y);
        for (k, c) in coef.iter().enumerate() {
            if let Some(c) = c {
                let input = if estimated { format!("|error {}|", names[k]) } else { format!("|{}|", names[k]) };
                rows.push(SensitivityRow {
                    cell: *cell,
                    output: column.clone(),
                    input,
                    srrc: Some(*c),
                    r2: Some(r2),
                    trials: kept.len(),
                    note: None,
                });
            }
        }
    }
    Ok(rows)
}
