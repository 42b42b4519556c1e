//! The one home of seeded randomness: the random stream type and the tag of every use of a seed.
//!
//! Every random draw of an episode (initial state, robot noise) comes from [`EpisodeRng`], which
//! is seeded at reset and saved with the state, so a seed fixes a rollout bit for bit.
//!
//! # Seed streams
//!
//! One seed may serve several uses (an episode, the automatic resets that follow it in a batch,
//! the scripted expert that drives it, ...). Each use draws from its own stream: the seed is
//! ChaCha8's key and the use's [`SeedUse::tag`] its 64-bit stream id, so two uses of the same
//! seed never see the same numbers (and, unlike XOR-ing the seed with a constant, no other seed
//! reproduces another use's stream either). Adding a use means adding a variant with a new tag
//! here; tags are never reused.
//!
//! | use | tag | where |
//! |---|---|---|
//! | [`SeedUse::Episode`] | 0 | `Env::reset(seed)`: initial state, joint noise |
//! | [`SeedUse::AutoReset`] | 1 | `BatchEnv`: episode seeds of automatic resets after `reset(seed)` |
//! | [`SeedUse::Expert`] | 2 | scripted experts: waypoint noise of the episode seeded `seed` |
//! | [`SeedUse::SymmetryProbe`] | 3 | `equigym-wrappers` symmetry-breaking measurement: states and group elements |
//! | [`SeedUse::Steerability`] | 4 | `equigym-wrappers` steerability diagnostic: the latent noise of its rollouts |

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// What a seed is used for; see the module documentation for the table of tags.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SeedUse {
    /// An episode's own draws (`Env::reset(seed)`). Tag 0 is ChaCha8's default stream, so
    /// [`EpisodeRng::from_seed`] is this stream.
    Episode,
    /// The per-environment stream of a batch that seeds its automatic resets.
    AutoReset,
    /// A scripted expert's noise for the episode started with the same seed.
    Expert,
    /// The symmetry-breaking measurement's sampling of states and group elements.
    SymmetryProbe,
    /// The steerability diagnostic's latent noise (one stream per rollout).
    Steerability,
}

impl SeedUse {
    /// Every use, in tag order.
    pub const ALL: [SeedUse; 5] =
        [SeedUse::Episode, SeedUse::AutoReset, SeedUse::Expert, SeedUse::SymmetryProbe, SeedUse::Steerability];

    /// The ChaCha8 stream id of this use (distinct per use, never reused).
    pub const fn tag(self) -> u64 {
        match self {
            SeedUse::Episode => 0,
            SeedUse::AutoReset => 1,
            SeedUse::Expert => 2,
            SeedUse::SymmetryProbe => 3,
            SeedUse::Steerability => 4,
        }
    }
}

/// One standard normal draw from `rng`: Box-Muller on two uniform draws, with `log` and `cos`
/// from the pinned `libm` crate, so a stream gives the same normals on every platform (a
/// table-based sampler such as `rand_distr`'s ziggurat would too, but this exact sequence is
/// what the committed golden runs and seeds were recorded with). The one home of this formula:
/// the episode streams here and the steering agents' streams both call it.
pub fn standard_normal<R: rand::Rng + ?Sized>(rng: &mut R) -> f64 {
    let (u1, u2) = box_muller_uniforms(rng);
    box_muller(libm::log(u1), u2)
}

/// The two uniform draws of one [`standard_normal`], in its order: `u1` in (0, 1], `u2` in
/// [0, 1). With [`box_muller`], a caller can draw many normals' uniforms first and take all
/// their logarithms in one vectorised pass (the steering agents do), with the same results.
pub fn box_muller_uniforms<R: rand::Rng + ?Sized>(rng: &mut R) -> (f64, f64) {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random::<f64>();
    (u1, u2)
}

/// [`standard_normal`] from its uniforms, given `ln_u1` = `libm::log(u1)` bit for bit.
pub fn box_muller(ln_u1: f64, u2: f64) -> f64 {
    (-2.0 * ln_u1).sqrt() * libm::cos(std::f64::consts::TAU * u2)
}

/// A serialisable, seedable random stream (ChaCha8).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct EpisodeRng(ChaCha8Rng);

impl EpisodeRng {
    /// The episode stream of `seed` (the same as `for_use(seed, SeedUse::Episode)`).
    pub fn from_seed(seed: u64) -> Self {
        Self::for_use(seed, SeedUse::Episode)
    }

    /// The stream of `seed` for `what`.
    pub fn for_use(seed: u64, what: SeedUse) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(what.tag());
        Self(rng)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        if hi <= lo {
            return lo;
        }
        self.0.random_range(lo..hi)
    }

    /// Standard normal draw ([`standard_normal`]).
    pub fn normal(&mut self) -> f64 {
        standard_normal(&mut self.0)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.random::<u64>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_are_distinct() {
        let tags: std::collections::HashSet<u64> = SeedUse::ALL.iter().map(|u| u.tag()).collect();
        assert_eq!(tags.len(), SeedUse::ALL.len());
    }

    #[test]
    fn uses_of_one_seed_draw_different_numbers() {
        for seed in [0, 1, 7, u64::MAX] {
            let firsts: std::collections::HashSet<u64> =
                SeedUse::ALL.iter().map(|&u| EpisodeRng::for_use(seed, u).next_u64()).collect();
            assert_eq!(firsts.len(), SeedUse::ALL.len(), "seed {seed}");
        }
        // The episode stream is ChaCha8's default stream: recorded rollouts keep their seeds.
        let mut plain = ChaCha8Rng::seed_from_u64(42);
        assert_eq!(EpisodeRng::from_seed(42).next_u64(), plain.random::<u64>());
    }
}
