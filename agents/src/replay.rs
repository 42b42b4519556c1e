//! The replay buffer: a ring of transitions (observation, scaled latent action, summed reward,
//! next observation, terminated flag) in f32, sampled uniformly with replacement (SB3's rule).
//! Truncation at the horizon is not termination: the target still bootstraps there.
//!
//! The noise-aliased agents (DSRL-NA) also keep the action chunk each latent action decoded to
//! (normalised as the diffusion policy normalises actions); the others keep none
//! (`chunk_dim` 0), and sampling draws the same indices either way.

use equigym_nn::Real;
use serde::{Deserialize, Serialize};

use crate::rng::Rng;

/// SB3's default buffer size (transitions).
pub const DEFAULT_CAPACITY: usize = 1_000_000;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Replay {
    pub obs_dim: usize,
    pub act_dim: usize,
    /// Length of the stored action chunk per transition (0: none stored).
    pub chunk_dim: usize,
    pub capacity: usize,
    len: usize,
    pos: usize,
    obs: Vec<f32>,
    act: Vec<f32>,
    chunk: Vec<f32>,
    reward: Vec<f32>,
    next_obs: Vec<f32>,
    done: Vec<f32>,
}

/// A minibatch, row-major.
#[derive(Clone, Debug, Default)]
pub struct Batch<T> {
    pub rows: usize,
    pub obs: Vec<T>,
    pub act: Vec<T>,
    /// The decoded action chunks (rows x chunk_dim; empty when the replay stores none).
    pub chunk: Vec<T>,
    pub reward: Vec<T>,
    pub next_obs: Vec<T>,
    pub done: Vec<T>,
}

impl<T> Batch<T> {
    /// A minibatch of `reward.len()` transitions without action chunks (tests and probes).
    pub fn of(obs: Vec<T>, act: Vec<T>, reward: Vec<T>, next_obs: Vec<T>, done: Vec<T>) -> Self {
        Self { rows: reward.len(), obs, act, chunk: Vec::new(), reward, next_obs, done }
    }
}

impl Replay {
    pub fn new(obs_dim: usize, act_dim: usize, capacity: usize) -> Self {
        Self::with_chunks(obs_dim, act_dim, 0, capacity)
    }

    /// A replay that also stores a `chunk_dim`-long action chunk per transition.
    pub fn with_chunks(obs_dim: usize, act_dim: usize, chunk_dim: usize, capacity: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            chunk_dim,
            capacity: capacity.max(1),
            len: 0,
            pos: 0,
            obs: Vec::new(),
            act: Vec::new(),
            chunk: Vec::new(),
            reward: Vec::new(),
            next_obs: Vec::new(),
            done: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn push(&mut self, obs: &[f32], act: &[f32], reward: f32, next_obs: &[f32], terminated: bool) {
        self.push_with_chunk(obs, act, &[], reward, next_obs, terminated)
    }

    /// [`Replay::push`] with the transition's action chunk (`chunk_dim` values; ignored when
    /// the replay stores no chunks).
    pub fn push_with_chunk(
        &mut self,
        obs: &[f32],
        act: &[f32],
        chunk: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        let (od, ad, cd) = (self.obs_dim, self.act_dim, self.chunk_dim);
        let chunk = &chunk[..cd.min(chunk.len())];
        debug_assert_eq!(chunk.len(), cd, "a chunk of {cd} values per transition");
        if self.len < self.capacity {
            self.obs.extend_from_slice(obs);
            self.act.extend_from_slice(act);
            self.chunk.extend_from_slice(chunk);
            self.reward.push(reward);
            self.next_obs.extend_from_slice(next_obs);
            self.done.push(terminated as u8 as f32);
            self.len += 1;
        } else {
            let p = self.pos;
            self.obs[p * od..(p + 1) * od].copy_from_slice(obs);
            self.act[p * ad..(p + 1) * ad].copy_from_slice(act);
            self.chunk[p * cd..(p + 1) * cd].copy_from_slice(chunk);
            self.reward[p] = reward;
            self.next_obs[p * od..(p + 1) * od].copy_from_slice(next_obs);
            self.done[p] = terminated as u8 as f32;
        }
        self.pos = (self.pos + 1) % self.capacity;
    }

    /// `rows` transitions drawn uniformly with replacement (the buffer must not be empty).
    pub fn sample<T: Real>(&self, rows: usize, rng: &mut Rng, out: &mut Batch<T>) {
        let (od, ad, cd) = (self.obs_dim, self.act_dim, self.chunk_dim);
        out.rows = rows;
        for v in [&mut out.obs, &mut out.act, &mut out.chunk, &mut out.reward, &mut out.next_obs, &mut out.done] {
            v.clear();
        }
        let cv = |x: &f32| T::from_f64(*x as f64);
        for _ in 0..rows {
            let i = rng.below(self.len.max(1));
            out.obs.extend(self.obs[i * od..(i + 1) * od].iter().map(cv));
            out.act.extend(self.act[i * ad..(i + 1) * ad].iter().map(cv));
            out.chunk.extend(self.chunk[i * cd..(i + 1) * cd].iter().map(cv));
            out.reward.push(cv(&self.reward[i]));
            out.next_obs.extend(self.next_obs[i * od..(i + 1) * od].iter().map(cv));
            out.done.push(cv(&self.done[i]));
        }
    }
}
