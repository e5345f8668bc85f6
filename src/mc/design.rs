//! Sweep designs: full factorial over listed levels, and space-filling points (Latin hypercube,
//! Owen-scrambled Sobol) over continuous factors.

use rand::seq::SliceRandom;
use rand::{Rng, RngExt};

/// `points` Latin-hypercube points in `[0, 1)^dims`: each dimension's strata are a random
/// permutation, with a uniform draw within each stratum.
pub fn latin_hypercube<R: Rng + ?Sized>(points: usize, dims: usize, rng: &mut R) -> Vec<Vec<f64>> {
    let mut out = vec![vec![0.0; dims]; points];
    for d in 0..dims {
        let mut strata: Vec<usize> = (0..points).collect();
        strata.shuffle(rng);
        for (row, s) in out.iter_mut().zip(&strata) {
            row[d] = (*s as f64 + rng.random::<f64>()) / points as f64;
        }
    }
    out
}

/// `points` Owen-scrambled Sobol points in `[0, 1)^dims` (Burley 2020, `sobol_burley`), scrambled
/// by `seed`.
pub fn sobol(points: usize, dims: usize, seed: u32) -> Vec<Vec<f64>> {
    (0..points).map(|p| (0..dims).map(|d| sobol_burley::sample(p as u32, d as u32, seed) as f64).collect()).collect()
}

/// Every combination of `levels[0] x levels[1] x ...` as index vectors (the last factor varies
/// fastest).
pub fn factorial(levels: &[usize]) -> Vec<Vec<usize>> {
    let mut out = vec![vec![]];
    for &n in levels {
        out = out.into_iter().flat_map(|prefix| (0..n).map(move |i| [prefix.clone(), vec![i]].concat())).collect();
    }
    out
}
