//! The latent-action MDP of DSRL: the agent picks the diffusion policy's initial noise w; the
//! policy denoises it (once, deterministic DDIM) from the current observation into an action
//! chunk; the chunk runs in the environment and the rewards add up.
//!
//! Reward per primitive step is success - 1 (DSRL's sparse reward, in {-1, 0}); a latent step
//! returns the sum over the steps it executed. Episodes truncate at the task's horizon (a chunk
//! stops early there), never at success. Latent actions are clipped to [-bound, bound].

use std::sync::Arc;

use equigym_envs::error::check_finite;
use equigym_envs::tasks::Evaluation;
use equigym_envs::{Env, ACTION_DIM};

use crate::edp::DiffusionPolicy;
use crate::error::Result;

/// Default latent bound (DSRL's noise action space).
pub const DEFAULT_LATENT_BOUND: f64 = 1.5;

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
}

impl LatentEnv {
    /// Wrap `env` with `policy` (trained for the same task), latent bound and DDIM steps.
    pub fn new(
        env: Env,
        policy: Arc<DiffusionPolicy>,
        bound: f64,
        ddim_steps: usize,
    ) -> Result<Self> {
        policy.check_layout(env.task().id(), env.observation_layout())?;
        if !(bound.is_finite() && bound > 0.0) {
            return Err(equigym_envs::EnvError::InvalidConfig(format!(
                "latent bound must be positive, got {bound}"
            ))
            .into());
        }
        if ddim_steps == 0 || ddim_steps > policy.num_train_timesteps() {
            return Err(equigym_envs::EnvError::InvalidConfig(format!(
                "DDIM steps must lie in 1..={}, got {ddim_steps}",
                policy.num_train_timesteps()
            ))
            .into());
        }
        let chunk = vec![0.0; policy.action_dim()];
        Ok(Self {
            env,
            policy,
            bound,
            ddim_steps,
            chunk,
        })
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

    pub fn reset(&mut self, seed: u64) -> Result<Vec<f64>> {
        Ok(self.env.reset(seed)?.to_vec())
    }

    /// The chunk the policy makes of `latent` at the current observation (no stepping).
    pub fn decode(&mut self, latent: &[f64]) -> Result<Vec<f64>> {
        check_finite("latent action", latent, self.latent_dim())?;
        let w: Vec<f64> = latent
            .iter()
            .map(|v| v.clamp(-self.bound, self.bound))
            .collect();
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

    /// Run an already-decoded chunk (used by batched stepping, which denoises many at once).
    pub fn execute(&mut self, chunk: Vec<f64>) -> Result<LatentStep> {
        if chunk.len() != self.latent_dim() {
            return Err(equigym_envs::EnvError::WrongLength {
                what: "chunk".into(),
                expected: self.latent_dim(),
                got: chunk.len(),
            }
            .into());
        }
        self.chunk = chunk;
        let mut out = LatentStep {
            reward: 0.0,
            terminated: false,
            truncated: false,
            success: false,
            executed: 0,
            evaluation: Evaluation::default(),
        };
        for a in self.chunk.chunks_exact(ACTION_DIM) {
            let r = self.env.step(a)?;
            out.executed += 1;
            out.reward += r.evaluation.success as u8 as f64 - 1.0;
            out.success |= r.evaluation.success;
            out.terminated |= r.terminated;
            out.truncated |= r.truncated;
            out.evaluation = r.evaluation;
            if out.terminated || out.truncated {
                break;
            }
        }
        Ok(out)
    }
}

/// Step many latent environments with one batched denoising call. They must share one
/// policy (the same `Arc`) and the same DDIM steps.
pub fn step_batch(envs: &mut [LatentEnv], latents: &[f64]) -> Result<Vec<LatentStep>> {
    let Some(first) = envs.first() else {
        return Ok(Vec::new());
    };
    let policy = first.policy.clone();
    let steps = first.ddim_steps;
    if envs
        .iter()
        .any(|e| !Arc::ptr_eq(&e.policy, &policy) || e.ddim_steps != steps)
    {
        return Err(equigym_envs::EnvError::InvalidConfig(
            "batched latent steps need one shared policy and DDIM setting".into(),
        )
        .into());
    }
    let (ad, od) = (policy.action_dim(), policy.obs_dim());
    check_finite("latent actions", latents, envs.len() * ad)?;
    let mut obs = Vec::with_capacity(envs.len() * od);
    let mut w = Vec::with_capacity(latents.len());
    for (e, l) in envs.iter_mut().zip(latents.chunks_exact(ad)) {
        obs.extend_from_slice(e.env.observe());
        w.extend(l.iter().map(|v| v.clamp(-e.bound, e.bound)));
    }
    let mut chunks = vec![0.0; w.len()];
    policy.sample(&obs, &w, steps, &mut chunks)?;
    envs.iter_mut()
        .zip(chunks.chunks_exact(ad))
        .map(|(e, c)| e.execute(c.to_vec()))
        .collect()
}
