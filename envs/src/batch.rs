//! [`BatchEnv`]: B environments stepped together on a thread pool, with gymnasium 1.x
//! auto-reset semantics.
//!
//! One call to [`BatchEnv::step`] takes all B actions as one flat `B x action_dim` slice,
//! checks every one of them before anything moves (a bad action is an error and no
//! environment has stepped), then steps the environments in parallel on the batch's own
//! rayon pool, slowest first by each one's last step time (so that the threads finish
//! together), and leaves observations, rewards and flags in buffers owned by the batch.
//!
//! # Auto-reset
//!
//! [`AutoresetMode::NextStep`] (gymnasium's default): the step on which an episode ends returns
//! that episode's last observation with its reward and `terminated`/`truncated` flag; the
//! *next* call to `step` ignores that environment's action, resets it and returns its reset
//! observation with reward 0 and both flags false.
//!
//! [`AutoresetMode::SameStep`]: the step on which an episode ends resets the environment at
//! once; the reset observation is returned, and the last observation of the finished episode
//! is kept in [`BatchEnv::final_obs`] (gymnasium's `final_obs`, Stable-Baselines3's
//! `terminal_observation`).
//!
//! [`AutoresetMode::Disabled`]: nothing resets by itself. The caller resets the environments
//! whose episodes ended (or that it wants to end, e.g. on success) with
//! [`BatchEnv::reset_masked`] and seeds of its own choosing; stepping an environment whose
//! episode ended without that reset is an error (gymnasium's `AutoresetMode.DISABLED`). The
//! Rust steering runner uses this mode: its seeds come from the run's own streams.
//!
//! # Stepping some of the environments
//!
//! [`BatchEnv::step_masked`] steps only the environments where a mask is true; the others keep
//! their episodes and observations (an evaluation stops the episodes that are over while the
//! rest go on). In the auto-reset modes, a masked-out environment whose episode ended is reset
//! on its next stepped call, as it would have been.
//!
//! # Seeds
//!
//! `reset(seeds)` resets environment `i` with episode seed `seeds[i]`, exactly like
//! `Env::reset(seeds[i])`. Each later (automatic) reset of environment `i` draws its episode
//! seed from a per-environment stream seeded with `seeds[i]` ([`episode_seed_stream`], the
//! [`SeedUse::AutoReset`] stream of `crate::rng`), so a batch is a pure function of its seeds
//! and actions, independent of the thread count; the
//! seed of each environment's current episode is available from [`BatchEnv::episode_seeds`],
//! so a single `Env` reset with that seed reproduces the episode bit for bit.
//!
//! # Genericity
//!
//! The batch is generic over what it steps ([`BatchMember`]): `Env` is one, and
//! `equigym_wrappers::latent::LatentEnv` another. An [`ActionDecoder`] maps the batch's actions
//! to the members' actions in one batched call before the parallel step (the latent vector
//! environment's decoder denoises all B latent noises with one batched DDIM).
//!
//! # Indices
//!
//! Per-environment accessors ([`BatchEnv::obs`], [`BatchEnv::last_step`],
//! [`BatchEnv::was_reset`], [`BatchEnv::final_obs`], [`BatchEnv::env`]) return `None` for an
//! index out of range; nothing here panics on user input.

use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::Instant;

use crate::env::{Env, ACTION_DIM};
use crate::error::{check_finite, EnvError, Result};
use crate::rng::{EpisodeRng, SeedUse};

/// What one member step reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MemberStep {
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    pub success: bool,
}

/// Something a [`BatchEnv`] can step: a reset with a seed and a step that writes its
/// observation into a slice.
pub trait BatchMember: Send {
    fn observation_dim(&self) -> usize;
    fn action_dim(&self) -> usize;
    /// Start an episode and write its first observation.
    fn reset_into(&mut self, seed: u64, obs: &mut [f64]) -> Result<()>;
    /// One step with an already-validated action; writes the new observation.
    fn step_into(&mut self, action: &[f64], obs: &mut [f64]) -> Result<MemberStep>;
    /// Write the current observation (after a change made outside the batch: [`BatchEnv::edit`]).
    fn observe_into(&mut self, obs: &mut [f64]);
}

impl BatchMember for Env {
    fn observation_dim(&self) -> usize {
        self.observation_layout().dim()
    }
    fn action_dim(&self) -> usize {
        ACTION_DIM
    }
    fn reset_into(&mut self, seed: u64, obs: &mut [f64]) -> Result<()> {
        obs.copy_from_slice(self.reset(seed)?);
        Ok(())
    }
    fn step_into(&mut self, action: &[f64], obs: &mut [f64]) -> Result<MemberStep> {
        let r = self.step(action)?;
        obs.copy_from_slice(self.observe());
        Ok(MemberStep {
            reward: r.reward,
            terminated: r.terminated,
            truncated: r.truncated,
            success: r.evaluation.success(),
        })
    }
    fn observe_into(&mut self, obs: &mut [f64]) {
        obs.copy_from_slice(self.observe());
    }
}

/// Maps the batch's actions (B x `input_dim`) to the members' actions (B x member action dim)
/// in one call, seeing the current observations (B x obs dim). Runs on the calling thread
/// before the members step; it may use the batch's thread pool through `pool.install`.
pub trait ActionDecoder: Send {
    fn input_dim(&self) -> usize;
    fn decode(&mut self, pool: &rayon::ThreadPool, obs: &[f64], input: &[f64], output: &mut [f64]) -> Result<()>;
}

/// No decoder: members receive the batch's actions unchanged (the type has no values; it only
/// fills the decoder parameter of [`BatchEnv::new`]).
#[derive(Clone, Copy, Debug)]
pub enum Identity {}

impl ActionDecoder for Identity {
    fn input_dim(&self) -> usize {
        match *self {}
    }
    fn decode(&mut self, _: &rayon::ThreadPool, _: &[f64], _: &[f64], _: &mut [f64]) -> Result<()> {
        match *self {}
    }
}

/// When a finished episode's environment is reset; see the module documentation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AutoresetMode {
    #[default]
    NextStep,
    SameStep,
    Disabled,
}

impl AutoresetMode {
    /// gymnasium's name for the mode (`gymnasium.vector.AutoresetMode` values).
    pub fn as_str(self) -> &'static str {
        match self {
            AutoresetMode::NextStep => "next_step",
            AutoresetMode::SameStep => "same_step",
            AutoresetMode::Disabled => "disabled",
        }
    }
}

impl std::str::FromStr for AutoresetMode {
    type Err = EnvError;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "next_step" => Ok(AutoresetMode::NextStep),
            "same_step" => Ok(AutoresetMode::SameStep),
            "disabled" => Ok(AutoresetMode::Disabled),
            other => Err(EnvError::InvalidConfig(format!(
                "autoreset_mode must be 'next_step', 'same_step' or 'disabled', got '{other}'"
            ))),
        }
    }
}

/// The per-environment stream that seeds automatic resets after an episode started from `seed`
/// ([`SeedUse::AutoReset`]).
pub fn episode_seed_stream(seed: u64) -> EpisodeRng {
    EpisodeRng::for_use(seed, SeedUse::AutoReset)
}

/// One environment of the batch with its output slots.
struct Slot<E> {
    env: E,
    obs: Vec<f64>,
    final_obs: Vec<f64>,
    step: MemberStep,
    /// The episode ended on the last step (NextStep: reset on the next call).
    ended: bool,
    /// This step reset the environment (NextStep: the action was ignored; SameStep: `final_obs` is valid).
    reset_now: bool,
    seeds: EpisodeRng,
    episode_seed: u64,
    episode: u64,
    /// How long this member's last stepped call took (ns): the batch steps the slowest first.
    last_step_ns: u64,
}

impl<E: BatchMember> Slot<E> {
    fn reset(&mut self, seed: u64) -> Result<()> {
        self.env.reset_into(seed, &mut self.obs)?;
        self.episode_seed = seed;
        self.ended = false;
        Ok(())
    }

    fn auto_reset(&mut self) -> Result<()> {
        let seed = self.seeds.next_u64();
        self.reset(seed)?;
        self.episode += 1;
        Ok(())
    }

    fn step(&mut self, action: &[f64], mode: AutoresetMode) -> Result<()> {
        self.reset_now = false;
        if self.ended && mode == AutoresetMode::NextStep {
            self.auto_reset()?;
            self.step = MemberStep::default();
            self.reset_now = true;
            return Ok(());
        }
        self.step = self.env.step_into(action, &mut self.obs)?;
        self.ended = self.step.terminated || self.step.truncated;
        if self.ended && mode == AutoresetMode::SameStep {
            std::mem::swap(&mut self.obs, &mut self.final_obs);
            self.auto_reset()?;
            self.reset_now = true;
        }
        Ok(())
    }
}

/// Step the members of one batch step (those where `stepped`; the others only clear their
/// flags) on `pool`, longest first. The threads take members from one shared queue ordered by
/// each member's last step time, slowest first (longest-processing-time-first list
/// scheduling): a member's cost changes slowly from step to step (contacts, resets), so the
/// members left for the end of the batch step are the quick ones and the threads finish
/// together. Rayon's range splitting would hand each thread a fixed half and leave the step's
/// end to whichever member happened to be last. The order changes nothing but the timing:
/// each member steps with its own action and state. Of several failing members, the error of
/// the lowest index is returned.
fn step_longest_first<E: BatchMember>(
    pool: &rayon::ThreadPool,
    slots: &mut [Slot<E>],
    actions: &[f64],
    adim: usize,
    stepped: &(dyn Fn(usize) -> bool + Sync),
    mode: AutoresetMode,
) -> Result<()> {
    let mut order: Vec<usize> = (0..slots.len()).collect();
    order.sort_by(|&a, &b| slots[b].last_step_ns.cmp(&slots[a].last_step_ns).then(a.cmp(&b)));
    let members: Vec<Mutex<&mut Slot<E>>> = slots.iter_mut().map(Mutex::new).collect();
    let next = AtomicUsize::new(0);
    let first_error: Mutex<Option<(usize, EnvError)>> = Mutex::new(None);
    let work = || {
        while let Some(&i) = order.get(next.fetch_add(1, Ordering::Relaxed)) {
            let mut slot = members[i].lock().unwrap_or_else(PoisonError::into_inner);
            if !stepped(i) {
                slot.reset_now = false;
                slot.step = MemberStep::default();
                continue;
            }
            let t0 = Instant::now();
            let result = slot.step(&actions[i * adim..(i + 1) * adim], mode);
            slot.last_step_ns = u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX);
            if let Err(e) = result {
                let mut first = first_error.lock().unwrap_or_else(PoisonError::into_inner);
                if first.as_ref().is_none_or(|(j, _)| i < *j) {
                    *first = Some((i, e));
                }
            }
        }
    };
    pool.install(|| {
        rayon::scope(|s| {
            for _ in 1..pool.current_num_threads() {
                s.spawn(|_| work());
            }
            work();
        })
    });
    match first_error.into_inner().unwrap_or_else(PoisonError::into_inner) {
        Some((_, e)) => Err(e),
        None => Ok(()),
    }
}

/// B environments stepped together; see the module documentation.
pub struct BatchEnv<E: BatchMember = Env, D: ActionDecoder = Identity> {
    slots: Vec<Slot<E>>,
    pool: rayon::ThreadPool,
    threads: usize,
    mode: AutoresetMode,
    decoder: Option<D>,
    decoded: Vec<f64>,
    obs_dim: usize,
    member_action_dim: usize,
    needs_reset: bool,
}

impl<E: BatchMember> BatchEnv<E, Identity> {
    /// A batch over `envs` (at least one, all with the same dimensions) on a pool of `threads`
    /// threads (0: one per available core).
    pub fn new(envs: Vec<E>, threads: usize, mode: AutoresetMode) -> Result<Self> {
        Self::build(envs, None, threads, mode)
    }
}

impl<E: BatchMember, D: ActionDecoder> BatchEnv<E, D> {
    /// A batch whose actions go through `decoder` before reaching the members.
    pub fn with_decoder(envs: Vec<E>, decoder: D, threads: usize, mode: AutoresetMode) -> Result<Self> {
        Self::build(envs, Some(decoder), threads, mode)
    }

    fn build(envs: Vec<E>, decoder: Option<D>, threads: usize, mode: AutoresetMode) -> Result<Self> {
        let first =
            envs.first().ok_or_else(|| EnvError::InvalidConfig("a batch needs at least one environment".into()))?;
        let (obs_dim, member_action_dim) = (first.observation_dim(), first.action_dim());
        if envs.iter().any(|e| e.observation_dim() != obs_dim || e.action_dim() != member_action_dim) {
            return Err(EnvError::InvalidConfig("all environments of a batch need the same dimensions".into()));
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("equigym-batch-{i}"))
            .build()
            .map_err(|e| EnvError::InvalidConfig(format!("cannot start the thread pool: {e}")))?;
        let threads = pool.current_num_threads();
        let decoded = vec![0.0; if decoder.is_some() { envs.len() * member_action_dim } else { 0 }];
        let slots = envs
            .into_iter()
            .map(|env| Slot {
                env,
                obs: vec![0.0; obs_dim],
                final_obs: vec![0.0; obs_dim],
                step: MemberStep::default(),
                ended: false,
                reset_now: false,
                seeds: episode_seed_stream(0),
                episode_seed: 0,
                episode: 0,
                last_step_ns: 0,
            })
            .collect();
        Ok(Self { slots, pool, threads, mode, decoder, decoded, obs_dim, member_action_dim, needs_reset: true })
    }

    pub fn num_envs(&self) -> usize {
        self.slots.len()
    }
    pub fn threads(&self) -> usize {
        self.threads
    }
    pub fn autoreset_mode(&self) -> AutoresetMode {
        self.mode
    }
    pub fn observation_dim(&self) -> usize {
        self.obs_dim
    }
    /// Dimension of one environment's action as passed to [`BatchEnv::step`].
    pub fn action_dim(&self) -> usize {
        self.decoder.as_ref().map_or(self.member_action_dim, |d| d.input_dim())
    }
    pub fn envs(&self) -> impl ExactSizeIterator<Item = &E> {
        self.slots.iter().map(|s| &s.env)
    }
    pub fn env(&self, i: usize) -> Option<&E> {
        self.slots.get(i).map(|s| &s.env)
    }

    /// Reset every environment; `seeds[i]` seeds environment `i`'s episode and its stream of
    /// later automatic-reset seeds.
    pub fn reset(&mut self, seeds: &[u64]) -> Result<()> {
        let n = self.slots.len();
        if seeds.len() != n {
            return Err(EnvError::WrongLength { what: "seeds".into(), expected: n, got: seeds.len() });
        }
        self.needs_reset = false;
        // Only a member's own failure gets past the checks; then the batch needs a new reset.
        self.reset_masked(seeds, &vec![true; n]).inspect_err(|_| self.needs_reset = true)
    }

    /// Reset the environments where `mask` is true (seeds of the others are ignored); the others
    /// keep their episodes and observations (gymnasium's `reset_mask` option).
    pub fn reset_masked(&mut self, seeds: &[u64], mask: &[bool]) -> Result<()> {
        let n = self.slots.len();
        if seeds.len() != n || mask.len() != n {
            return Err(EnvError::WrongLength {
                what: "seeds and reset mask".into(),
                expected: n,
                got: if seeds.len() != n { seeds.len() } else { mask.len() },
            });
        }
        if self.needs_reset && !mask.iter().all(|m| *m) {
            return Err(EnvError::CallOrder("the first reset() must reset every environment".into()));
        }
        self.pool.install(|| {
            self.slots.par_iter_mut().zip(seeds.par_iter()).zip(mask.par_iter()).try_for_each(|((slot, &seed), &m)| {
                slot.reset_now = false;
                if !m {
                    return Ok(());
                }
                slot.seeds = episode_seed_stream(seed);
                slot.episode = 0;
                slot.step = MemberStep::default();
                slot.reset(seed)
            })
        })
    }

    /// Step every environment with its row of `actions` (B x [`BatchEnv::action_dim`], row-major).
    /// All rows are checked first: on error nothing has stepped.
    pub fn step(&mut self, actions: &[f64]) -> Result<()> {
        self.step_where(actions, None)
    }

    /// Step the environments where `mask` is true with their rows of `actions` (B x
    /// [`BatchEnv::action_dim`]; the rows of the others are not read and may be anything). The
    /// others keep their state and report an empty step. All stepped rows are checked first: on
    /// error nothing has stepped.
    pub fn step_masked(&mut self, actions: &[f64], mask: &[bool]) -> Result<()> {
        let n = self.slots.len();
        if mask.len() != n {
            return Err(EnvError::WrongLength { what: "step mask".into(), expected: n, got: mask.len() });
        }
        self.step_where(actions, Some(mask))
    }

    fn step_where(&mut self, actions: &[f64], mask: Option<&[bool]>) -> Result<()> {
        if self.needs_reset {
            return Err(EnvError::CallOrder("step() called before reset()".into()));
        }
        let n = self.slots.len();
        let dim = self.action_dim();
        if actions.len() != n * dim {
            return Err(EnvError::WrongLength {
                what: format!("actions ({n} x {dim})"),
                expected: n * dim,
                got: actions.len(),
            });
        }
        let stepped = |i: usize| mask.is_none_or(|m| m[i]);
        for (i, row) in actions.chunks_exact(dim).enumerate().filter(|(i, _)| stepped(*i)) {
            // Environments that reset on this step ignore their action, but a bad one is still an error.
            check_finite(&format!("action of environment {i}"), row, dim)?;
        }
        if self.mode == AutoresetMode::Disabled {
            if let Some(i) = (0..n).find(|&i| stepped(i) && self.slots[i].ended) {
                return Err(EnvError::CallOrder(format!(
                    "environment {i}'s episode ended; reset it (reset_masked) before stepping it again"
                )));
            }
        }
        let actions: &[f64] = match self.decoder.as_mut() {
            None => actions,
            Some(decoder) => {
                let adim = self.member_action_dim;
                match mask {
                    None => {
                        let obs: Vec<f64> = self.slots.iter().flat_map(|s| s.obs.iter().copied()).collect();
                        decoder.decode(&self.pool, &obs, actions, &mut self.decoded)?;
                    }
                    Some(m) => {
                        // Only the stepped rows are decoded (the others' chunks never run; their
                        // rows of `decoded` keep what they held). A decoder's rows are
                        // independent, so a row decodes the same in any batch.
                        let rows: Vec<usize> = (0..n).filter(|&i| m[i]).collect();
                        let obs: Vec<f64> = rows.iter().flat_map(|&i| self.slots[i].obs.iter().copied()).collect();
                        let input: Vec<f64> =
                            rows.iter().flat_map(|&i| actions[i * dim..(i + 1) * dim].iter().copied()).collect();
                        let mut out = vec![0.0; rows.len() * adim];
                        if !rows.is_empty() {
                            decoder.decode(&self.pool, &obs, &input, &mut out)?;
                        }
                        for (&i, row) in rows.iter().zip(out.chunks_exact(adim)) {
                            self.decoded[i * adim..(i + 1) * adim].copy_from_slice(row);
                        }
                    }
                }
                let rows = self.decoded.chunks_exact(adim).enumerate();
                for (i, row) in rows.filter(|(i, _)| stepped(*i)) {
                    check_finite(&format!("decoded action of environment {i}"), row, adim)?;
                }
                &self.decoded
            }
        };
        let result =
            step_longest_first(&self.pool, &mut self.slots, actions, self.member_action_dim, &stepped, self.mode);
        if result.is_err() {
            // Only reachable through a member's own failure; the batch must be reset.
            self.needs_reset = true;
        }
        result
    }

    /// Change environment `i` in place with `edit` (e.g. restore a saved state); its observation
    /// is read again afterwards and its episode counts as running. `None` when `i` is out of
    /// range.
    pub fn edit<R>(&mut self, i: usize, edit: impl FnOnce(&mut E) -> R) -> Option<R> {
        let slot = self.slots.get_mut(i)?;
        let out = edit(&mut slot.env);
        slot.env.observe_into(&mut slot.obs);
        slot.ended = false;
        slot.reset_now = false;
        slot.step = MemberStep::default();
        Some(out)
    }

    /// Observation of environment `i` after the last call (the reset observation where it
    /// reset); `None` when `i` is out of range.
    pub fn obs(&self, i: usize) -> Option<&[f64]> {
        self.slots.get(i).map(|s| &s.obs[..])
    }
    /// What environment `i`'s last step reported (all zero/false where it was reset in NextStep
    /// mode); `None` when `i` is out of range.
    pub fn last_step(&self, i: usize) -> Option<MemberStep> {
        self.slots.get(i).map(|s| s.step)
    }
    /// Whether environment `i` was reset during the last call to `step`; `None` when `i` is out
    /// of range.
    pub fn was_reset(&self, i: usize) -> Option<bool> {
        self.slots.get(i).map(|s| s.reset_now)
    }
    /// SameStep mode: the last observation of the episode that ended on the last step, where
    /// [`BatchEnv::was_reset`] is true; `None` otherwise or when `i` is out of range.
    pub fn final_obs(&self, i: usize) -> Option<&[f64]> {
        let s = self.slots.get(i)?;
        (self.mode == AutoresetMode::SameStep && s.reset_now).then_some(&s.final_obs[..])
    }
    /// Seed of environment `i`'s current episode.
    pub fn episode_seeds(&self) -> Vec<u64> {
        self.slots.iter().map(|s| s.episode_seed).collect()
    }
    /// How many automatic resets environment `i` has had since its last explicit reset; `None`
    /// when `i` is out of range.
    pub fn episode_index(&self, i: usize) -> Option<u64> {
        self.slots.get(i).map(|s| s.episode)
    }
}
