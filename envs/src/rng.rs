//! The one seeded random-number generator of an environment.
//!
//! Every random draw of an episode (initial state, robot noise) comes from [`EpisodeRng`], which
//! is seeded at reset and saved with the state, so a seed fixes a rollout bit for bit.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A serialisable, seedable random stream (ChaCha8).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct EpisodeRng(ChaCha8Rng);

impl EpisodeRng {
    pub fn from_seed(seed: u64) -> Self {
        Self(ChaCha8Rng::seed_from_u64(seed))
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        if hi <= lo {
            return lo;
        }
        self.0.random_range(lo..hi)
    }

    /// Standard normal draw (Box-Muller, so the stream is the same on every platform).
    pub fn normal(&mut self) -> f64 {
        let u1: f64 = 1.0 - self.0.random::<f64>();
        let u2: f64 = self.0.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.random::<u64>()
    }
}
