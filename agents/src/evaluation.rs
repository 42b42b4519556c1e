//! Evaluation on the pinned starts: the one home of the protocol that a run's evaluations (the
//! stochastic actor) and its control arms (the base policy with latent noise N(0, s^2 I)) share,
//! so that every method and every control is measured on the same episodes, paired.
//!
//! - Episode k of an evaluation is reset with seed [`EVAL_SEED`] + k: the same starts for every
//!   method, seed and control (the demos are recorded from seeds below 1000, so no evaluation
//!   start is a training start).
//! - An episode succeeds if any latent step succeeds, and stops there; otherwise it runs to the
//!   horizon.
//! - Episodes run batched on a thread pool; each draws its noise from its own stream, so the
//!   result depends neither on the batching nor on the thread count.
//!
//! The base evaluation ([`evaluate_base`]) takes the run configuration it is the control of: the
//! same task, policy, controller, joint limits and horizon, and the run's seed for its noise
//! ([`Stream::BaseEval`], one stream per episode, shared by every scale: common random numbers,
//! so the scales differ only by the scale).

use std::sync::Arc;

use equigym_envs::ACTION_DIM;
use equigym_wrappers::latent::LatentBatchEnv;
use equigym_wrappers::steerability::Rate;
use equigym_wrappers::DEFAULT_LATENT_BOUND;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::rng::{Rng, Stream};
use crate::run::{make_batch, member_obs, RunConfig};

/// Seed of evaluation episode 0; episode k starts from seed `EVAL_SEED + k`.
pub const EVAL_SEED: u64 = 10_000;

/// A chunk whose commanded hand position (the mean of its actions' positions) moved less than
/// this from the previous chunk's counts as stalled (metres). The EDP's loop, run on a noise that
/// is a function of the state alone, can settle where each chunk commands the pose it starts
/// from (docs/steering.md, "Why Stack D1 falls as training starts"); with fresh N(0, I) noise
/// per chunk its failing episodes move by centimetres per chunk.
pub const STALL_MOVE: f64 = 0.002;

/// Per-episode successes of an evaluation, the primitive env steps it ran, the moments of the
/// latent noise it chose and how much of each episode stalled.
#[derive(Clone, Debug, PartialEq)]
pub struct Episodes {
    pub successes: Vec<bool>,
    pub env_steps: u64,
    pub noise: NoiseMoments,
    /// Per episode: chunk-to-chunk moves of the commanded hand position, and how many of them
    /// were below [`STALL_MOVE`].
    pub moves: Vec<ChunkMoves>,
}

/// Chunk-to-chunk moves of one episode's commanded hand position.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChunkMoves {
    pub moves: u32,
    pub stalled: u32,
}

/// First and second moments of the latents an evaluation chose (latent units, clipped to the
/// box as stepped), pooled over episodes and latent steps: how far a steering policy's noise is
/// from the EDP's own N(0, I) on average. A state-independent preference shows as a mean far
/// from 0 (iid N(0, I) picks give about sqrt(d / count)); a preference for small or large noise
/// as an RMS away from 1 (clipping to the box alone gives a little less than 1).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NoiseMoments {
    /// Latent vectors counted.
    pub count: u64,
    /// Their sum, per coordinate.
    pub sum: Vec<f64>,
    /// Sum of their squared coordinates.
    pub sum_sq: f64,
}

impl NoiseMoments {
    fn add(&mut self, w: &[f64], bound: f64) {
        if self.sum.is_empty() {
            self.sum = vec![0.0; w.len()];
        }
        for (s, v) in self.sum.iter_mut().zip(w) {
            let v = v.clamp(-bound, bound);
            *s += v;
            self.sum_sq += v * v;
        }
        self.count += 1;
    }

    /// The mean latent, per coordinate (its direction says which of the chunk's coordinates a
    /// state-independent preference moves).
    pub fn mean(&self) -> Vec<f64> {
        let n = self.count.max(1) as f64;
        self.sum.iter().map(|s| s / n).collect()
    }

    /// Norm of the mean latent.
    pub fn mean_norm(&self) -> f64 {
        self.mean().iter().map(|m| m * m).sum::<f64>().sqrt()
    }

    /// Root mean square of a coordinate.
    pub fn rms(&self) -> f64 {
        (self.sum_sq / (self.count.max(1) as f64 * self.sum.len().max(1) as f64)).sqrt()
    }
}

impl Episodes {
    pub fn rate(&self) -> f64 {
        self.successes.iter().filter(|s| **s).count() as f64 / self.successes.len().max(1) as f64
    }

    /// Over the failing episodes, the mean share of their chunk-to-chunk moves that stalled
    /// (`None` without a failing episode that moved).
    pub fn failures_stalled(&self) -> Option<f64> {
        let shares: Vec<f64> = self
            .successes
            .iter()
            .zip(&self.moves)
            .filter(|(ok, m)| !**ok && m.moves > 0)
            .map(|(_, m)| m.stalled as f64 / m.moves as f64)
            .collect();
        (!shares.is_empty()).then(|| shares.iter().sum::<f64>() / shares.len() as f64)
    }
}

/// The commanded hand position of a chunk of absolute actions: the mean of its actions'
/// positions.
fn commanded_position(chunk: &[f64]) -> [f64; 3] {
    let mut p = [0.0; 3];
    let actions = chunk.chunks_exact(ACTION_DIM);
    let n = actions.len().max(1) as f64;
    for a in actions {
        for (pi, ai) in p.iter_mut().zip(a) {
            *pi += ai / n;
        }
    }
    p
}

/// Fills the latents of the running episodes: `(active indices, their observations, latents)`.
pub(crate) type Choose<'a> = dyn FnMut(&[usize], &[f32], &mut Vec<f64>) + 'a;

/// Run one evaluation episode in each environment of `envs` (a batch without auto-reset;
/// episode k starts from seed [`EVAL_SEED`] + k). Before every latent step, `choose(active, obs,
/// latents)` gets the indices of the still-running episodes and their observations (rows,
/// float32) and fills their latents (rows x latent dim, the scaled box; clipped to the bound
/// when stepped).
pub(crate) fn run_episodes(envs: &mut LatentBatchEnv, choose: &mut Choose<'_>) -> Result<Episodes> {
    let episodes = envs.num_envs();
    let seeds: Vec<u64> = (0..episodes as u64).map(|k| EVAL_SEED + k).collect();
    envs.reset(&seeds)?;
    let ad = envs.action_dim();
    let mut active = vec![true; episodes];
    let mut successes = vec![false; episodes];
    let mut env_steps = 0u64;
    let mut noise = NoiseMoments::default();
    let mut moves = vec![ChunkMoves::default(); episodes];
    let mut commanded: Vec<Option<[f64; 3]>> = vec![None; episodes];
    let (mut latents, mut rows) = (Vec::new(), vec![0.0; episodes * ad]);
    while active.contains(&true) {
        let idx: Vec<usize> = (0..episodes).filter(|k| active[*k]).collect();
        let obs: Vec<f32> = idx.iter().flat_map(|&k| member_obs(envs, k)).collect();
        latents.clear();
        choose(&idx, &obs, &mut latents);
        for (&k, w) in idx.iter().zip(latents.chunks_exact(ad)) {
            rows[k * ad..(k + 1) * ad].copy_from_slice(w);
            noise.add(w, DEFAULT_LATENT_BOUND);
        }
        envs.step_masked(&rows, &active)?;
        for &k in &idx {
            let r = envs.last_step(k).unwrap_or_default();
            if let Some(e) = envs.env(k) {
                env_steps += e.last_executed() as u64;
                let now = commanded_position(e.last_chunk());
                if let Some(before) = commanded[k] {
                    let d = now.iter().zip(&before).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
                    moves[k].moves += 1;
                    moves[k].stalled += u32::from(d < STALL_MOVE);
                }
                commanded[k] = Some(now);
            }
            successes[k] |= r.success;
            if r.success || r.terminated || r.truncated {
                active[k] = false;
            }
        }
    }
    Ok(Episodes { successes, env_steps, noise, moves })
}

/// The base policy on a run's evaluation starts, with latent noise N(0, scale^2 I) clipped to
/// the bound (scale 1: the base policy, "before steering"; smaller: a narrow-noise control).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BaseEvaluation {
    pub task: String,
    /// The diffusion policy file.
    pub policy: String,
    pub scale: f64,
    /// The noise streams' seed (the run's seed).
    pub seed: u64,
    pub first_start: u64,
    pub rate: Rate,
    /// Per episode, in start order (for paired comparisons).
    pub successes: Vec<bool>,
}

/// Evaluate the base policy of `cfg` (task, policy, controller, joint limits, horizon,
/// `eval_episodes`, threads) at noise `scale`, as [`crate::run`] evaluates its actor.
pub fn evaluate_base(cfg: &RunConfig, scale: f64) -> Result<BaseEvaluation> {
    if !(scale.is_finite() && scale >= 0.0) {
        return Err(Error::InvalidOption(format!("the noise scale must be finite and >= 0, got {scale}")));
    }
    if cfg.eval_episodes == 0 {
        return Err(Error::InvalidOption("eval_episodes must be >= 1".into()));
    }
    if !equigym_envs::tasks::TASK_IDS.contains(&cfg.task.as_str()) {
        return Err(Error::InvalidOption(format!(
            "task must be one of {:?}, got '{}'",
            equigym_envs::tasks::TASK_IDS,
            cfg.task
        )));
    }
    let path = cfg.policy_path();
    let policy = Arc::new(cfg.load_policy()?);
    let episodes = cfg.eval_episodes;
    let latent_dim = policy.action_dim();
    let mut rngs: Vec<Rng> = (0..episodes as u64).map(|k| Rng::new(cfg.seed, Stream::BaseEval, k)).collect();
    let mut choose = |idx: &[usize], _obs: &[f32], out: &mut Vec<f64>| {
        for &k in idx {
            out.extend((0..latent_dim).map(|_| scale * rngs[k].normal()));
        }
    };
    let mut envs = make_batch(cfg, &policy, episodes)?;
    let result = run_episodes(&mut envs, &mut choose)?;
    let wins = result.successes.iter().filter(|s| **s).count();
    Ok(BaseEvaluation {
        task: cfg.task.clone(),
        policy: path.display().to_string(),
        scale,
        seed: cfg.seed,
        first_start: EVAL_SEED,
        rate: Rate::of(wins, episodes),
        successes: result.successes,
    })
}
