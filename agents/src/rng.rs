//! The seeded random streams of a run, one per use, each with its own documented tag.
//!
//! A stream is ChaCha8 keyed by (run seed, tag, index): streams never overlap, and adding a draw
//! to one use never shifts another. All streams are saved in checkpoints.
//!
//! | tag | use |
//! |---|---|
//! | [`Stream::Init`] | initial weights (index: 0 actor, 1 and 2 critics) |
//! | [`Stream::EnvSeeds`] | episode seeds of the training environments, drawn in env order |
//! | [`Stream::Warmup`] | warm-up latent noise N(0, I), clipped to the bound |
//! | [`Stream::Rollout`] | the actor's exploration noise while collecting |
//! | [`Stream::Replay`] | replay-buffer minibatch indices |
//! | [`Stream::Train`] | the actor's reparameterisation noise inside a gradient step |
//! | [`Stream::MeanQ`] | the replay sample whose mean Q the log reports |
//! | [`Stream::Eval`] | the stochastic actor's noise in evaluation episode `index` |
//! | [`Stream::Diagnostics`] | replay sample and actor noise of the learner diagnostics at evaluation `index` |
//! | [`Stream::InitActionCritics`] | initial weights of the noise-aliased agents' action critics (index 1 and 2) |
//! | [`Stream::BaseEval`] | the base policy's latent noise in evaluation episode `index` ([`crate::evaluation::evaluate_base`]) |
//! | [`Stream::Probe`] | the actor's noise for its sampled picks at a probed state (index: episode seed x 1000 + latent step; [`crate::run::critic_probe`]) |

use equigym_envs::rng::{box_muller, box_muller_uniforms};
use equigym_nn::{ops, Real};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// What a stream is used for (its tag is part of the key).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u64)]
pub enum Stream {
    Init = 1,
    EnvSeeds = 2,
    Warmup = 3,
    Rollout = 4,
    Replay = 5,
    Train = 6,
    MeanQ = 7,
    Eval = 8,
    Diagnostics = 9,
    InitActionCritics = 10,
    BaseEval = 11,
    Probe = 12,
}

/// Domain separator in every key, so that these streams differ from any other ChaCha use.
const DOMAIN: &[u8; 8] = b"eqg-agnt";

/// A seeded random stream.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rng(ChaCha8Rng);

impl Rng {
    pub fn new(seed: u64, stream: Stream, index: u64) -> Self {
        let mut key = [0u8; 32];
        key[..8].copy_from_slice(&seed.to_le_bytes());
        key[8..16].copy_from_slice(&(stream as u64).to_le_bytes());
        key[16..24].copy_from_slice(&index.to_le_bytes());
        key[24..].copy_from_slice(DOMAIN);
        Self(ChaCha8Rng::from_seed(key))
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.random::<f64>()
    }

    /// Standard normal ([`equigym_envs::rng::standard_normal`]: the same on every platform).
    pub fn normal(&mut self) -> f64 {
        equigym_envs::rng::standard_normal(&mut self.0)
    }

    /// Fill `out` with standard normals: the draws of [`Rng::normal`] one after another, bit
    /// for bit, with the logarithms of each block of draws taken in one vectorised pass
    /// ([`ops::ln_into`]; scalar `libm::log` was a fifth of a DSRL gradient step's sampling).
    pub fn fill_normal<T: Real>(&mut self, out: &mut [T]) {
        const BLOCK: usize = 256;
        let (mut u1, mut u2, mut ln_u1) = ([0.0f64; BLOCK], [0.0f64; BLOCK], [0.0f64; BLOCK]);
        for chunk in out.chunks_mut(BLOCK) {
            let n = chunk.len();
            for (a, b) in u1[..n].iter_mut().zip(&mut u2[..n]) {
                (*a, *b) = box_muller_uniforms(&mut self.0);
            }
            ops::ln_into(&u1[..n], &mut ln_u1[..n]);
            for ((o, l), b) in chunk.iter_mut().zip(&ln_u1).zip(&u2) {
                *o = T::from_f64(box_muller(*l, *b));
            }
        }
    }

    /// Uniform index in 0..n (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        self.0.random_range(0..n as u64) as usize
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.random::<u64>()
    }
}
