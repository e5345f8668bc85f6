//! Random streams: one per trial, derived from (master seed, trial index) alone, so a run gives
//! the same numbers on 1 or many threads and when split into shards.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The stream of trial `trial`: ChaCha8 keyed by `seed`, stream number `trial`.
///
/// ```
/// use rand::RngExt;
/// let a: f64 = gfcal::rng::trial_rng(7, 3).random();
/// let b: f64 = gfcal::rng::trial_rng(7, 3).random();
/// assert_eq!(a, b);
/// ```
pub fn trial_rng(seed: u64, trial: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(trial);
    rng
}
