//! The latent-action MDP of DSRL: the agent picks the diffusion policy's initial noise w; the
//! policy denoises it (once, deterministic DDIM) from the current observation into an action
//! chunk; the chunk runs in the environment and the rewards add up.
//!
//! Reward per primitive step is success - 1 (DSRL's sparse reward, in {-1, 0}); a latent step
//! returns the sum over the steps it executed. Episodes truncate at the task's horizon (a chunk
//! stops early there), never at success. Latent actions are clipped to [-bound, bound].

use std::sync::Arc;

use equigym_envs::batch::ActionDecoder;
use equigym_envs::error::check_finite;
use equigym_envs::tasks::Evaluation;
use equigym_envs::{AutoresetMode, BatchEnv, BatchMember, Env, MemberStep, ACTION_DIM};
use rayon::prelude::*;

use crate::edp::DiffusionPolicy;
use crate::error::Result;

/// Default latent bound (DSRL's noise action space).
pub const DEFAULT_LATENT_BOUND: f64 = 1.5;

/// Latent actions clipped to the box [-bound, bound]: the one place where a latent action
/// meets its bound on the way to the policy (single and batched stepping both call it).
fn clip(latent: &[f64], bound: f64) -> Vec<f64> {
    latent.iter().map(|v| v.clamp(-bound, bound)).collect()
}

/// What a latent step returns.
#[derive(Clone, Debug, PartialEq)]
pub struct LatentStep {
    /// Sum of (success - 1) over the executed primitive steps.
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    /// Whether any executed primitive step succeeded.
    pub success: bool,
    /// Primitive steps executed (the chunk length, or fewer at the horizon).
    pub executed: usize,
    /// The evaluation after the last executed step.
    pub evaluation: Evaluation,
}

/// An environment whose action is the diffusion policy's latent noise.
pub struct LatentEnv {
    env: Env,
    policy: Arc<DiffusionPolicy>,
    bound: f64,
    ddim_steps: usize,
    chunk: Vec<f64>,
    last_executed: usize,
}

impl LatentEnv {
    /// Wrap `env` with `policy` (trained for the same task), latent bound and DDIM steps.
    pub fn new(env: Env, policy: Arc<DiffusionPolicy>, bound: f64, ddim_steps: usize) -> Result<Self> {
        policy.check_layout(env.task().id(), env.observation_layout())?;
        if env.config().reward != equigym_envs::RewardKind::Sparse {
            return Err(equigym_envs::EnvError::InvalidConfig(
                "latent environments return their own reward (success - 1 per primitive step); reward must be 'sparse'"
                    .into(),
            )
            .into());
        }
        if !(bound.is_finite() && bound > 0.0) {
            return Err(
                equigym_envs::EnvError::InvalidConfig(format!("latent bound must be positive, got {bound}")).into()
            );
        }
        if ddim_steps == 0 || ddim_steps > policy.num_train_timesteps() {
            return Err(equigym_envs::EnvError::InvalidConfig(format!(
                "DDIM steps must lie in 1..={}, got {ddim_steps}",
                policy.num_train_timesteps()
            ))
            .into());
        }
        let chunk = vec![0.0; policy.action_dim()];
        Ok(Self { env, policy, bound, ddim_steps, chunk, last_executed: 0 })
    }

    pub fn env(&self) -> &Env {
        &self.env
    }
    pub fn env_mut(&mut self) -> &mut Env {
        &mut self.env
    }
    pub fn policy(&self) -> &Arc<DiffusionPolicy> {
        &self.policy
    }
    pub fn ddim_steps(&self) -> usize {
        self.ddim_steps
    }
    pub fn bound(&self) -> f64 {
        self.bound
    }
    pub fn latent_dim(&self) -> usize {
        self.policy.action_dim()
    }
    pub fn chunk_len(&self) -> usize {
        self.policy.chunk_len
    }
    /// The action chunk the last step executed (absolute actions, chunk_len x 10).
    pub fn last_chunk(&self) -> &[f64] {
        &self.chunk
    }

    /// Primitive steps the last latent step executed (the chunk length, or fewer at the horizon).
    pub fn last_executed(&self) -> usize {
        self.last_executed
    }

    pub fn reset(&mut self, seed: u64) -> Result<Vec<f64>> {
        self.last_executed = 0;
        Ok(self.env.reset(seed)?.to_vec())
    }

    /// The chunk the policy makes of `latent` at the current observation (no stepping).
    pub fn decode(&mut self, latent: &[f64]) -> Result<Vec<f64>> {
        check_finite("latent action", latent, self.latent_dim())?;
        let w = clip(latent, self.bound);
        let obs = self.env.observe().to_vec();
        let mut chunk = vec![0.0; self.latent_dim()];
        self.policy.sample(&obs, &w, self.ddim_steps, &mut chunk)?;
        Ok(chunk)
    }

    /// One latent step: denoise once, run the chunk.
    pub fn step(&mut self, latent: &[f64]) -> Result<LatentStep> {
        let chunk = self.decode(latent)?;
        self.execute(chunk)
    }

    /// Run an already-decoded chunk (the batch member's step: [`LatentDecoder`] denoises all
    /// rows at once before).
    fn execute(&mut self, chunk: Vec<f64>) -> Result<LatentStep> {
        if chunk.len() != self.latent_dim() {
            return Err(equigym_envs::EnvError::WrongLength {
                what: "chunk".into(),
                expected: self.latent_dim(),
                got: chunk.len(),
            }
            .into());
        }
        self.chunk = chunk;
        // The first primitive step, then the rest of the chunk (a chunk holds at least one
        // action: the policy's layout was checked against the task's).
        let (first, rest) = self.chunk.split_at(ACTION_DIM.min(self.chunk.len()));
        let r = self.env.step(first)?;
        let mut out = LatentStep {
            reward: r.evaluation.success() as u8 as f64 - 1.0,
            terminated: r.terminated,
            truncated: r.truncated,
            success: r.evaluation.success(),
            executed: 1,
            evaluation: r.evaluation,
        };
        for a in rest.chunks_exact(ACTION_DIM) {
            if out.terminated || out.truncated {
                break;
            }
            let r = self.env.step(a)?;
            out.executed += 1;
            out.reward += r.evaluation.success() as u8 as f64 - 1.0;
            out.success |= r.evaluation.success();
            out.terminated |= r.terminated;
            out.truncated |= r.truncated;
            out.evaluation = r.evaluation;
        }
        self.last_executed = out.executed;
        Ok(out)
    }
}

// -- the latent vector environment ------------------------------------------------------------

/// The batch member is the latent environment running an already-decoded chunk; the batch's
/// [`LatentDecoder`] turns all B latent actions into chunks with one batched DDIM first.
impl BatchMember for LatentEnv {
    fn observation_dim(&self) -> usize {
        self.env.observation_layout().dim()
    }
    fn action_dim(&self) -> usize {
        self.latent_dim()
    }
    fn reset_into(&mut self, seed: u64, obs: &mut [f64]) -> equigym_envs::Result<()> {
        // last_executed stays: in same-step auto-reset it still describes the step that ended.
        obs.copy_from_slice(self.env.reset(seed)?);
        Ok(())
    }
    fn step_into(&mut self, chunk: &[f64], obs: &mut [f64]) -> equigym_envs::Result<MemberStep> {
        let r = self.execute(chunk.to_vec()).map_err(into_env_error)?;
        obs.copy_from_slice(self.env.observe());
        Ok(MemberStep { reward: r.reward, terminated: r.terminated, truncated: r.truncated, success: r.success })
    }
    fn observe_into(&mut self, obs: &mut [f64]) {
        obs.copy_from_slice(self.env.observe());
    }
}

/// Latent noise -> action chunks for a whole batch: clip to the bound, then deterministic DDIM
/// with the shared policy, the rows split across the batch's threads. Each row's chunk is bit for
/// bit what a single [`LatentEnv`] makes of it.
pub struct LatentDecoder {
    policy: Arc<DiffusionPolicy>,
    bound: f64,
    ddim_steps: usize,
}

impl LatentDecoder {
    /// The decoder of environments that share one policy, bound and DDIM setting.
    pub fn shared_by(envs: &[LatentEnv]) -> Result<Self> {
        let first = envs
            .first()
            .ok_or_else(|| equigym_envs::EnvError::InvalidConfig("a batch needs at least one environment".into()))?;
        if envs.iter().any(|e| {
            !Arc::ptr_eq(&e.policy, &first.policy) || e.ddim_steps != first.ddim_steps || e.bound != first.bound
        }) {
            return Err(equigym_envs::EnvError::InvalidConfig(
                "batched latent environments need one shared policy, bound and DDIM setting".into(),
            )
            .into());
        }
        Ok(Self { policy: first.policy.clone(), bound: first.bound, ddim_steps: first.ddim_steps })
    }

    fn decode_rows(&self, obs: &[f64], latents: &[f64], out: &mut [f64]) -> Result<()> {
        self.policy.sample(obs, &clip(latents, self.bound), self.ddim_steps, out)
    }
}

impl ActionDecoder for LatentDecoder {
    fn input_dim(&self) -> usize {
        self.policy.action_dim()
    }
    fn decode(
        &mut self,
        pool: &rayon::ThreadPool,
        obs: &[f64],
        input: &[f64],
        output: &mut [f64],
    ) -> equigym_envs::Result<()> {
        let (od, ad) = (self.policy.obs_dim(), self.policy.action_dim());
        let rows = input.len() / ad.max(1);
        // Whole rows per thread, in blocks of four (the kernel's row block).
        let per = rows.div_ceil(pool.current_num_threads()).div_ceil(4).max(1) * 4;
        let this = &*self;
        pool.install(|| {
            output
                .par_chunks_mut(per * ad)
                .zip(input.par_chunks(per * ad))
                .zip(obs.par_chunks(per * od))
                .try_for_each(|((out, w), o)| this.decode_rows(o, w, out))
        })
        .map_err(into_env_error)
    }
}

/// The batch traits speak `EnvError`; a policy error keeps its message.
fn into_env_error(e: crate::Error) -> equigym_envs::EnvError {
    match e {
        crate::Error::Env(e) => e,
        other => equigym_envs::EnvError::InvalidConfig(other.to_string()),
    }
}

/// B latent-action environments stepped per call: one batched DDIM, then the chunks run in
/// parallel, with the auto-reset and seeding rules of [`BatchEnv`].
pub type LatentBatchEnv = BatchEnv<LatentEnv, LatentDecoder>;

/// A [`LatentBatchEnv`] over `envs` (one shared policy) on `threads` threads (0: one per core).
pub fn latent_batch(envs: Vec<LatentEnv>, threads: usize, mode: AutoresetMode) -> Result<LatentBatchEnv> {
    let decoder = LatentDecoder::shared_by(&envs)?;
    Ok(BatchEnv::with_decoder(envs, decoder, threads, mode)?)
}
