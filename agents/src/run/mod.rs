//! One steering run: collect with 4 latent-action environments, train SAC, evaluate, log,
//! checkpoint, resume.
//!
//! # Protocol (`baselines/steer.py`'s)
//! - Steps are primitive environment steps: a latent step runs a 4-action chunk, so one vector
//!   step of 4 environments is 16 env steps; SB3's `num_timesteps` counts latent transitions.
//! - Warm-up: while fewer than `warmup` transitions were collected, the latent action is
//!   N(0, I) clipped to the bound (the base policy's own noise); training starts after.
//! - After each vector step: `utd x n_envs` gradient steps on minibatches of `batch`.
//! - Evaluation whenever the env-step count reaches the next multiple of `eval_every` (the first
//!   after the first vector step): `eval_episodes` episodes of the stochastic actor, reset with
//!   seeds 10000 + k, an episode succeeds if any step succeeds and stops there. Episodes run
//!   batched; each has its own noise stream, so the result does not depend on the batching.
//! - `log.csv`: `env_steps, success_rate, mean_q, seconds`; mean Q is min over the twin critics,
//!   averaged over 256 replay transitions.
//! - `train.csv`, one row per evaluation: the learner's state on another 256 replay transitions
//!   ([`Diagnostics`]: entropy coefficient, policy entropy, fraction of latent coordinates at
//!   the edge of the box, critic loss, mean soft target, mean Q at the actor's own actions),
//!   drawn from their own stream so that recording them changes nothing else.
//!
//! One difference in order: SB3 evaluates inside its step callback, before that step's
//! transitions are stored and trained on; here the evaluation comes after them, at a point
//! where the whole run state can be checkpointed.
//!
//! # Reproducibility
//! Everything random comes from the run's [`crate::rng`] streams; environments step on a rayon
//! pool, but each environment's work and each row of every batched computation is independent
//! of the others, so `--threads` changes nothing in the results. A checkpoint (written after
//! every evaluation, atomically) holds networks, optimisers, replay, streams, the environments'
//! full states and the log, so a killed run that is started again ends bit for bit where the
//! uninterrupted run ends (the `seconds` column aside).
//!
//! # Where things are
//! [`config`](RunConfig): what a run is (options, presets, validation, fingerprint); `state`:
//! what a checkpoint holds and how a run resumes; `files`: what a run writes (`log.csv`,
//! `train.csv`, `summary.json`, `run.json`); `eval`: the learner used as a policy on the pinned
//! starts (the run's evaluations and `steer eval`); this file: the learner and the loop.

mod config;
mod eval;
mod files;
pub mod probe;
mod state;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use equigym_envs::{AutoresetMode, Env};
use equigym_wrappers::latent::{latent_batch, LatentBatchEnv};
use equigym_wrappers::{DiffusionPolicy, Group, LatentEnv, TaskSymmetry, DEFAULT_LATENT_BOUND};
use serde::{Deserialize, Serialize};

pub use config::{
    Preset, RunConfig, DEFAULT_POLICY_DIR, EVAL_EPISODES, EVAL_EVERY, GAMMA, GAMMA_SQUARE, LEARNING_RATE,
    MEAN_Q_SAMPLE, TARGET_ENTROPY, TAU,
};
pub use eval::{evaluate_checkpoint, ActorNoise};
pub use probe::{critic_probe, CriticProbeConfig, CriticProbeReport};
pub use state::CHECKPOINT_FORMAT;

use crate::error::{io_err, Error, Result};
use crate::models::{Arch, Models, GROUP_ORDER};
use crate::replay::{Batch, Replay, DEFAULT_CAPACITY};
use crate::rng::{Rng, Stream};
use crate::sac::{normals, Diagnostics, NoisePrior, Sac, SacConfig};
use state::{params_hash, Progress};

/// One line of `log.csv`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LogRow {
    pub env_steps: u64,
    pub success_rate: f64,
    pub mean_q: f64,
    pub seconds: f64,
}

/// What a finished (or stopped) run returns.
#[derive(Clone, Debug, PartialEq)]
pub struct RunSummary {
    pub run_dir: PathBuf,
    pub rows: Vec<LogRow>,
    /// FNV-1a hash of every parameter's bits (actor, critics, targets) and the entropy coefficient.
    pub params_hash: u64,
    pub env_steps: u64,
    pub grad_steps: u64,
    pub seconds: f64,
    /// The run's wall-clock seconds by activity, summed over every invocation that advanced it.
    pub time: TimeSplit,
    /// Primitive env steps the evaluation episodes ran, summed like `time`.
    pub eval_env_steps: u64,
    /// Hidden regular fields of the equivariant nets (0 for DSRL).
    pub fields: usize,
    pub params_actor: usize,
    pub params_critic: usize,
}

/// The diffusion policy's normalised chunks for `rows` observations and scaled latent actions
/// (the noise-aliased step's decoder): the latent is scaled to the bound, clamped there (as the
/// latent environments clamp), denoised and normalised.
fn decode_normalized(policy: &DiffusionPolicy, obs: &[f32], w: &[f32], rows: usize, out: &mut Vec<f32>) {
    let o: Vec<f64> = obs.iter().map(|v| *v as f64).collect();
    let l: Vec<f64> = w
        .iter()
        .map(|v| (*v as f64 * DEFAULT_LATENT_BOUND).clamp(-DEFAULT_LATENT_BOUND, DEFAULT_LATENT_BOUND))
        .collect();
    let mut c = vec![0.0; rows * policy.action_dim()];
    // Inputs come from the replay and the actor (finite, of the policy's shapes): a failure here
    // is a bug, not user input, and the run's divergence check reports the NaN it leaves.
    if policy.sample(&o, &l, policy.default_ddim_steps, &mut c).is_err() {
        c.fill(f64::NAN);
    }
    policy.normalize_actions(&mut c);
    out.clear();
    out.extend(c.iter().map(|v| *v as f32));
}

fn to_f32(v: &[f64]) -> Vec<f32> {
    v.iter().map(|x| *x as f32).collect()
}

struct Runner {
    cfg: RunConfig,
    policy: Arc<DiffusionPolicy>,
    sac: Sac<f32>,
    /// The training environments; the runner resets them, with seeds from its own stream.
    envs: LatentBatchEnv,
    /// One environment per evaluation episode, made at the first evaluation.
    eval_envs: Option<LatentBatchEnv>,
    /// Replay, streams, step counts, clock and log (checkpointed as they are).
    progress: Progress,
    obs_dim: usize,
    /// Where the run's time went, over all its invocations (kept in `summary.json`, not in the
    /// checkpoint: wall time is not reproducible).
    time: TimeSplit,
    /// Primitive env steps run by the evaluation episodes (kept beside `time`, in `summary.json`).
    eval_env_steps: u64,
    /// Hidden regular fields of the equivariant nets (0 for DSRL).
    fields: usize,
}

/// Wall-clock seconds of a run by activity, summed over its invocations and written to
/// `summary.json` (`seconds_by_activity`) so that a run's cost can be attributed (gradient steps
/// vs simulation), also for sweep trials that resume once per evaluation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TimeSplit {
    /// Collecting transitions: actor forward passes, DDIM and the environments' physics.
    pub rollout: f64,
    /// Gradient steps (minibatch sampling included).
    pub train: f64,
    /// Evaluation episodes.
    pub eval: f64,
}

impl Runner {
    /// A fresh run of `cfg`: its environments, nets, replay and streams (nothing stepped or reset).
    fn new(cfg: &RunConfig) -> Result<Self> {
        let policy = Arc::new(cfg.load_policy()?);
        let envs = make_batch(cfg, &policy, cfg.preset.n_envs)?;
        let first = envs.env(0).ok_or_else(|| Error::InvalidOption("a run needs at least one environment".into()))?;
        let sym = TaskSymmetry::for_env(first.env(), Group::cyclic(GROUP_ORDER)?, policy.chunk_len)?;
        let obs_dim = sym.observation.dim();
        let arch = Arch { width: cfg.preset.width, layers: cfg.preset.layers };
        let models = Models::<f32>::new(cfg.method, &sym, arch, cfg.seed)?;
        let fields = models.fields;
        let sac_cfg = SacConfig {
            lr: LEARNING_RATE,
            gamma: cfg.gamma(),
            tau: TAU,
            target_entropy: cfg.target_entropy.unwrap_or(TARGET_ENTROPY),
            ent_init: cfg.ent_init.unwrap_or(cfg.preset.ent_init),
            prior: cfg.prior_kl.map(|target_kl| NoisePrior { bound: DEFAULT_LATENT_BOUND, target_kl }),
        };
        let sac = if cfg.noise_aliased {
            let action_critics = Models::<f32>::action_critics(cfg.method, &sym, arch, cfg.seed)?;
            Sac::aliased(models, action_critics, obs_dim, sac_cfg)
        } else {
            Sac::new(models, obs_dim, sac_cfg)
        };
        let latent_dim = sac.latent_dim();
        let reachable = sac.max_entropy();
        if sac_cfg.target_entropy >= reachable {
            return Err(Error::InvalidOption(format!(
                "target entropy {} is out of reach: the actor (a squashed Gaussian over the {latent_dim}-d latent) has at most \
                 {reachable:.1} nats, so the entropy coefficient would grow without end (docs/steering.md); \
                 choose a lower target (DSRL uses 0)",
                sac_cfg.target_entropy
            )));
        }
        let chunk_dim = if cfg.noise_aliased { policy.action_dim() } else { 0 };
        Ok(Runner {
            cfg: cfg.clone(),
            policy,
            sac,
            envs,
            eval_envs: None,
            progress: Progress::new(Replay::with_chunks(obs_dim, latent_dim, chunk_dim, DEFAULT_CAPACITY), cfg.seed),
            obs_dim,
            time: TimeSplit::default(),
            eval_env_steps: 0,
            fields,
        })
    }

    fn env_steps(&self) -> u64 {
        self.progress.num_timesteps * self.policy.chunk_len as u64
    }

    /// One vector step with its transitions and gradient steps.
    fn collect_and_train(&mut self, batch: &mut Batch<f32>) -> Result<()> {
        let rollout_started = Instant::now();
        let (n, ad, od) = (self.envs.num_envs(), self.sac.latent_dim(), self.obs_dim);
        let obs: Vec<f32> = (0..n).flat_map(|i| member_obs(&self.envs, i)).collect();
        debug_assert_eq!(obs.len(), n * od);
        let bound = DEFAULT_LATENT_BOUND;
        let scaled: Vec<f32> = if (self.progress.num_timesteps as usize) < self.cfg.preset.warmup {
            (0..n * ad).map(|_| (self.progress.streams.warmup.normal().clamp(-bound, bound) / bound) as f32).collect()
        } else if let Some(m) = self.cfg.select {
            self.sac.select(&obs, n, m, bound, &mut self.progress.streams.rollout)
        } else {
            let mut eps = vec![0.0f32; n * ad];
            normals(&mut self.progress.streams.rollout, &mut eps);
            self.sac.act(&obs, n, &eps)
        };
        let latents: Vec<f64> = scaled.iter().map(|a| *a as f64 * bound).collect();
        self.envs.step(&latents)?;
        self.progress.num_timesteps += n as u64;
        let (mut seeds, mut ended) = (vec![0; n], vec![false; n]);
        for i in 0..n {
            let r = self.envs.last_step(i).unwrap_or_default();
            let next = member_obs(&self.envs, i);
            let terminal = r.terminated || (self.cfg.terminate_on_success && r.success);
            let chunk = match self.envs.env(i) {
                Some(e) if self.cfg.noise_aliased => {
                    let mut c = e.last_chunk().to_vec();
                    self.policy.normalize_actions(&mut c);
                    to_f32(&c)
                }
                _ => Vec::new(),
            };
            let (o, a) = (&obs[i * od..(i + 1) * od], &scaled[i * ad..(i + 1) * ad]);
            let reward = r.reward * self.cfg.reward_scale.unwrap_or(1.0);
            self.progress.replay.push_with_chunk(o, a, &chunk, reward as f32, &next, terminal);
            if terminal || r.truncated {
                seeds[i] = self.progress.streams.env_seeds.next_u64();
                ended[i] = true;
            }
        }
        if ended.contains(&true) {
            self.envs.reset_masked(&seeds, &ended)?;
        }
        let train_started = Instant::now();
        self.time.rollout += (train_started - rollout_started).as_secs_f64();
        if self.progress.num_timesteps as usize > self.cfg.preset.warmup {
            for _ in 0..self.cfg.utd() * n {
                self.progress.replay.sample(self.cfg.preset.batch, &mut self.progress.streams.replay, batch);
                let stats = if let Some(m) = self.cfg.select {
                    self.sac.train_step_select(batch, m, DEFAULT_LATENT_BOUND, &mut self.progress.streams.train)
                } else if self.cfg.noise_aliased {
                    let policy = &self.policy;
                    let mut decode = |obs: &[f32], w: &[f32], rows: usize, out: &mut Vec<f32>| {
                        decode_normalized(policy, obs, w, rows, out)
                    };
                    self.sac.train_step_aliased(
                        batch,
                        &mut decode,
                        DEFAULT_LATENT_BOUND,
                        &mut self.progress.streams.train,
                    )
                } else {
                    self.sac.train_step(batch, &mut self.progress.streams.train)
                };
                self.progress.grad_steps += 1;
                if !(stats.critic_loss.is_finite() && stats.actor_loss.is_finite()) {
                    return Err(Error::Diverged(format!(
                        "non-finite loss at gradient step {} (critic {}, actor {})",
                        self.progress.grad_steps, stats.critic_loss, stats.actor_loss
                    )));
                }
            }
        }
        self.time.train += train_started.elapsed().as_secs_f64();
        Ok(())
    }

    fn mean_q(&mut self) -> f64 {
        if self.progress.replay.is_empty() {
            return f64::NAN;
        }
        let mut b = Batch::<f32>::default();
        self.progress.replay.sample(
            MEAN_Q_SAMPLE.min(self.progress.replay.len()),
            &mut self.progress.streams.mean_q,
            &mut b,
        );
        let q = self.sac.min_q(&b.obs, &b.act, b.rows);
        let s: f32 = q.iter().sum::<f32>() / q.len() as f32;
        s as f64
    }

    /// The learner's state at evaluation `rows.len()` (its own stream: see [`crate::rng`]).
    fn diagnose(&mut self) -> Diagnostics {
        if self.progress.replay.is_empty() {
            return Diagnostics::default();
        }
        let mut rng = Rng::new(self.cfg.seed, Stream::Diagnostics, self.progress.rows.len() as u64);
        let mut b = Batch::<f32>::default();
        self.progress.replay.sample(MEAN_Q_SAMPLE.min(self.progress.replay.len()), &mut rng, &mut b);
        match self.cfg.select {
            Some(n) => self.sac.diagnose_select(&b, n, DEFAULT_LATENT_BOUND, &mut rng),
            None => self.sac.diagnose(&b, &mut rng, DEFAULT_LATENT_BOUND),
        }
    }

    /// Parameters of the two noise critics together.
    fn critic_params(&self) -> usize {
        self.sac.critics[0].num_params() + self.sac.critics[1].num_params()
    }
}
/// A latent environment as the run configures it.
pub fn make_env(cfg: &RunConfig, policy: &Arc<DiffusionPolicy>) -> Result<LatentEnv> {
    Ok(latent_env(cfg, policy)?)
}

/// [`make_env`], with the environment layer's error.
fn latent_env(cfg: &RunConfig, policy: &Arc<DiffusionPolicy>) -> equigym_wrappers::Result<LatentEnv> {
    let ec = cfg.env.clone().into_config(&cfg.task)?;
    let env = Env::new(ec)?;
    LatentEnv::new(env, policy.clone(), DEFAULT_LATENT_BOUND, policy.default_ddim_steps)
}

/// `n` latent environments as the run configures them, batched on `cfg.threads` threads. The
/// caller resets them (no auto-reset: the runner and the evaluation choose the seeds).
pub(crate) fn make_batch(cfg: &RunConfig, policy: &Arc<DiffusionPolicy>, n: usize) -> Result<LatentBatchEnv> {
    let envs = (0..n).map(|_| make_env(cfg, policy)).collect::<Result<Vec<_>>>()?;
    Ok(latent_batch(envs, cfg.threads, AutoresetMode::Disabled)?)
}

/// Environment `i`'s observation in float32 (empty when out of range).
pub(crate) fn member_obs(envs: &LatentBatchEnv, i: usize) -> Vec<f32> {
    envs.obs(i).map(to_f32).unwrap_or_default()
}

/// Run (or resume, or extend) one steering run; see the module docs.
pub fn run(cfg: &RunConfig) -> Result<RunSummary> {
    cfg.validate()?;
    let started = Instant::now();
    let mut r = Runner::new(cfg)?;
    let dir = cfg.run_dir();
    std::fs::create_dir_all(&dir).map_err(|e| io_err(&dir, e))?;
    r.resume_or_start(&dir)?;
    r.write_run_json(&dir)?;
    let base_elapsed = r.progress.elapsed;
    let steps_at_start = r.env_steps();
    let mut batch = Batch::default();
    let mut evals_now = 0;
    while r.env_steps() < cfg.steps as u64 {
        r.collect_and_train(&mut batch)?;
        let steps = r.env_steps();
        if steps >= r.progress.next_eval {
            r.progress.next_eval += cfg.eval_every as u64;
            let eval_started = Instant::now();
            let success_rate = r.evaluate()?;
            r.time.eval += eval_started.elapsed().as_secs_f64();
            let mean_q = r.mean_q();
            let diagnostics = r.diagnose();
            r.progress.diagnostics.push(diagnostics);
            r.progress.elapsed = base_elapsed + started.elapsed().as_secs_f64();
            r.progress.rows.push(LogRow {
                env_steps: steps,
                success_rate,
                mean_q,
                seconds: (r.progress.elapsed * 10.0).round() / 10.0,
            });
            r.write_log(&dir)?;
            r.save(&dir)?;
            if cfg.progress {
                eprintln!(
                    "{}/{}/seed{}: {steps} env steps, success {success_rate:.2}, mean Q {mean_q:.3}, {:.1} s",
                    cfg.task,
                    cfg.method.name(),
                    cfg.seed,
                    r.progress.elapsed
                );
            }
            evals_now += 1;
            if cfg.stop_after_evals == Some(evals_now) {
                break;
            }
        }
    }
    // An invocation that found the run finished leaves its files (and its clock) as they were.
    if r.env_steps() > steps_at_start && cfg.stop_after_evals != Some(evals_now) {
        r.progress.elapsed = base_elapsed + started.elapsed().as_secs_f64();
        r.save(&dir)?;
    }
    let summary = RunSummary {
        run_dir: dir.clone(),
        rows: r.progress.rows.clone(),
        params_hash: params_hash(&r.sac),
        env_steps: r.env_steps(),
        grad_steps: r.progress.grad_steps,
        seconds: r.progress.elapsed,
        time: r.time,
        eval_env_steps: r.eval_env_steps,
        fields: r.fields,
        params_actor: r.sac.actor.num_params(),
        params_critic: r.critic_params(),
    };
    Ok(summary)
}
