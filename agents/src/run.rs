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

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use equigym_envs::EnvConfig;
use equigym_envs::{AutoresetMode, Env, EnvError};
use equigym_nn::Adam;
use equigym_wrappers::latent::{latent_batch, LatentBatchEnv};
use equigym_wrappers::{DiffusionPolicy, Group, LatentEnv, TaskSymmetry, DEFAULT_LATENT_BOUND};
use serde::{Deserialize, Serialize};

use crate::error::{io_err, Error, Result};
use crate::evaluation::run_episodes;
use crate::models::{Arch, Method, Models, GROUP_ORDER};
use crate::net::Net;
use crate::replay::{Batch, Replay, DEFAULT_CAPACITY};
use crate::rng::{Rng, Stream};
use crate::sac::{normals, Diagnostics, Sac, SacConfig};

/// Learning rate, Polyak rate and target entropy (DSRL's).
pub const LEARNING_RATE: f64 = 3e-4;
pub const TAU: f64 = 0.005;
pub const TARGET_ENTROPY: f64 = 0.0;
/// Discount: 0.999 for Square, 0.99 otherwise.
pub const GAMMA: f64 = 0.99;
pub const GAMMA_SQUARE: f64 = 0.999;
/// Evaluation defaults of `baselines/steer.py`.
pub const EVAL_EVERY: usize = 2000;
pub const EVAL_EPISODES: usize = 50;
/// Replay transitions whose mean Q the log reports.
pub const MEAN_Q_SAMPLE: usize = 256;
/// Checkpoint format tag.
pub const CHECKPOINT_FORMAT: &str = "equigym-agents-ckpt-3";
const CHECKPOINT_FILE: &str = "checkpoint.bin";
const SUMMARY_FILE: &str = "summary.json";

/// `summary.json`: step counts, the final weights' hash, the run's clock and its time split.
#[derive(Debug, Serialize, Deserialize)]
struct SummaryFile {
    env_steps: u64,
    grad_steps: u64,
    params_hash: String,
    seconds: f64,
    /// Absent in summaries of older versions (then the split starts again from zero).
    #[serde(default)]
    seconds_by_activity: TimeSplit,
    /// Primitive env steps the evaluation episodes ran, over all invocations: what the
    /// evaluation's time is spent on (its physics and one DDIM call per chunk). Absent in older
    /// summaries.
    #[serde(default)]
    eval_env_steps: u64,
}

/// Tenths of a second, for files people read.
fn tenths(x: f64) -> f64 {
    (x * 10.0).round() / 10.0
}

/// Shipped diffusion policies (`assets/edp/<task>.safetensors`) in the source tree.
pub const DEFAULT_POLICY_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/edp");

/// Network width, depth and schedule (`baselines/steer.py`'s presets).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Preset {
    pub name: String,
    pub width: usize,
    pub layers: usize,
    pub utd: usize,
    /// UTD for Square where it differs (the paper: 20 instead of 30).
    pub utd_square: Option<usize>,
    pub batch: usize,
    pub n_envs: usize,
    /// Warm-up transitions (latent steps summed over environments).
    pub warmup: usize,
    pub ent_init: f64,
}

impl Preset {
    /// `cpu` (3 x 64, UTD 4, entropy coefficient from 0.2) or `paper` (3 x 2048, UTD 30/20).
    pub fn named(name: &str) -> Result<Self> {
        match name {
            "cpu" => Ok(Self {
                name: name.into(),
                width: 64,
                layers: 3,
                utd: 4,
                utd_square: None,
                batch: 256,
                n_envs: 4,
                warmup: 1000,
                ent_init: 0.2,
            }),
            "paper" => Ok(Self {
                name: name.into(),
                width: 2048,
                layers: 3,
                utd: 30,
                utd_square: Some(20),
                batch: 256,
                n_envs: 4,
                warmup: 6000,
                ent_init: 1.0,
            }),
            other => Err(Error::InvalidOption(format!("preset must be 'cpu' or 'paper', got '{other}'"))),
        }
    }
}

/// Everything a run needs.
#[derive(Clone, Debug)]
pub struct RunConfig {
    pub method: Method,
    pub task: String,
    pub seed: u64,
    /// Primitive environment steps.
    pub steps: usize,
    pub out: PathBuf,
    /// Threads for environments and denoising (0: one per core). Results do not depend on it.
    pub threads: usize,
    pub preset: Preset,
    pub joint_limits: bool,
    /// Arm controller: None keeps the environment's default, Some(true) Cartesian, Some(false) joint.
    pub cartesian: Option<bool>,
    pub eval_every: usize,
    pub eval_episodes: usize,
    /// Diffusion policy file (default: the shipped one for the task).
    pub policy: Option<PathBuf>,
    /// Initial entropy coefficient (default: the preset's).
    pub ent_init: Option<f64>,
    /// Episode length override (control steps); tests use short episodes.
    pub horizon: Option<usize>,
    /// Reset-distribution variant ("D0", "D1", "D2"; None: the task's default, which is the
    /// shipped policy's).
    pub variant: Option<String>,
    /// End training episodes at the first latent step that succeeds (a terminal transition,
    /// then a reset) instead of running them to the horizon as DSRL does. The return then
    /// counts the steps to success, the quantity the evaluation measures, rather than the time
    /// spent successful, which after a lift depends on a part of the task the demos never show.
    /// Evaluation is unchanged.
    pub terminate_on_success: bool,
    /// Noise aliasing (DSRL-NA, [`Sac::train_step_aliased`]): an action-space critic trained by
    /// TD on the executed chunks, the noise critic distilled from it. Any method: the action
    /// critic has the noise critic's architecture (equivariant nets: invariant, since a chunk
    /// has the noise's representation).
    pub noise_aliased: bool,
    /// Target entropy of the actor (default: DSRL's 0). With target 0 the 40-d latent actor
    /// narrows to a std of about 0.3, and narrow noise is what the shipped EDPs do worst with
    /// (docs/steering.md, "Steerability").
    pub target_entropy: Option<f64>,
    /// Print a line per evaluation to stderr.
    pub progress: bool,
    /// Stop (as if killed) right after the checkpoint of this many evaluations (tests).
    pub stop_after_evals: Option<usize>,
}

impl RunConfig {
    pub fn new(method: Method, task: &str, seed: u64, steps: usize, out: impl Into<PathBuf>) -> Result<Self> {
        Ok(Self {
            method,
            task: task.into(),
            seed,
            steps,
            out: out.into(),
            threads: 1,
            preset: Preset::named("cpu")?,
            joint_limits: true,
            cartesian: None,
            eval_every: EVAL_EVERY,
            eval_episodes: EVAL_EPISODES,
            policy: None,
            ent_init: None,
            horizon: None,
            variant: None,
            terminate_on_success: false,
            noise_aliased: false,
            target_entropy: None,
            progress: false,
            stop_after_evals: None,
        })
    }

    /// `out/<task>[-nolimits][-joint|-cartesian]/<method>/seed<S>` (the SB3 runs' layout).
    pub fn run_dir(&self) -> PathBuf {
        let mut task = self.task.clone();
        if !self.joint_limits {
            task.push_str("-nolimits");
        }
        match self.cartesian {
            Some(true) => task.push_str("-cartesian"),
            Some(false) => task.push_str("-joint"),
            None => {}
        }
        self.out.join(task).join(self.method.name()).join(format!("seed{}", self.seed))
    }

    pub(crate) fn policy_path(&self) -> PathBuf {
        self.policy.clone().unwrap_or_else(|| Path::new(DEFAULT_POLICY_DIR).join(format!("{}.safetensors", self.task)))
    }

    fn gamma(&self) -> f64 {
        if self.task == "square" {
            GAMMA_SQUARE
        } else {
            GAMMA
        }
    }

    fn utd(&self) -> usize {
        if self.task == "square" {
            self.preset.utd_square.unwrap_or(self.preset.utd)
        } else {
            self.preset.utd
        }
    }

    /// What must match for a checkpoint to be resumed (not steps, threads or output place).
    fn fingerprint(&self) -> String {
        // Options added later append themselves only when set, so that earlier runs' checkpoints
        // keep their fingerprints.
        let mut later = [(self.terminate_on_success, "|terminate_on_success"), (self.noise_aliased, "|noise_aliased")]
            .iter()
            .filter(|(on, _)| *on)
            .map(|(_, s)| *s)
            .collect::<String>();
        if let Some(t) = self.target_entropy {
            later.push_str(&format!("|target_entropy={t:?}"));
        }
        if let Some(v) = &self.variant {
            later.push_str(&format!("|variant={v}"));
        }
        format!(
            "{}|{}|{}|{:?}|{}|{:?}|{}|{}|{}|{:?}|{:?}",
            self.method.name(),
            self.task,
            self.seed,
            self.preset,
            self.joint_limits,
            self.cartesian,
            self.eval_every,
            self.eval_episodes,
            self.policy_path().display(),
            self.ent_init,
            self.horizon
        ) + &later
    }

    fn validate(&self) -> Result<()> {
        let p = &self.preset;
        let bad = |m: String| Err(Error::InvalidOption(m));
        if !equigym_envs::tasks::TASK_IDS.contains(&self.task.as_str()) {
            return bad(format!("task must be one of {:?}, got '{}'", equigym_envs::tasks::TASK_IDS, self.task));
        }
        if p.n_envs == 0 || p.batch == 0 || p.utd == 0 {
            return bad(format!("preset needs n_envs, batch and utd >= 1, got {p:?}"));
        }
        if self.eval_every == 0 || self.eval_episodes == 0 {
            return bad("eval_every and eval_episodes must be >= 1".into());
        }
        if self.target_entropy.is_some_and(|t| !t.is_finite()) {
            return bad(format!("the target entropy must be finite, got {:?}", self.target_entropy));
        }
        let ent = self.ent_init.unwrap_or(p.ent_init);
        if !(ent.is_finite() && ent > 0.0) {
            return bad(format!("the initial entropy coefficient must be positive, got {ent}"));
        }
        Ok(())
    }
}

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

#[derive(Clone, Debug, Serialize, Deserialize)]
struct Streams {
    env_seeds: Rng,
    warmup: Rng,
    rollout: Rng,
    replay: Rng,
    train: Rng,
    mean_q: Rng,
}

impl Streams {
    fn new(seed: u64) -> Self {
        Self {
            env_seeds: Rng::new(seed, Stream::EnvSeeds, 0),
            warmup: Rng::new(seed, Stream::Warmup, 0),
            rollout: Rng::new(seed, Stream::Rollout, 0),
            replay: Rng::new(seed, Stream::Replay, 0),
            train: Rng::new(seed, Stream::Train, 0),
            mean_q: Rng::new(seed, Stream::MeanQ, 0),
        }
    }
}

/// The first field of every checkpoint format, read before the rest so that an older format is
/// named as such rather than reported as corrupt.
#[derive(Deserialize)]
struct CheckpointHeader {
    format: String,
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    format: String,
    fingerprint: String,
    actor: Vec<f32>,
    critics: [Vec<f32>; 2],
    targets: [Vec<f32>; 2],
    log_alpha: f32,
    opt_actor: Adam<f32>,
    opt_critics: [Adam<f32>; 2],
    opt_alpha: Adam<f32>,
    replay: Replay,
    streams: Streams,
    envs: Vec<Vec<u8>>,
    num_timesteps: u64,
    next_eval: u64,
    grad_steps: u64,
    elapsed: f64,
    rows: Vec<LogRow>,
    diagnostics: Vec<Diagnostics>,
    /// The noise-aliased agents' action critics (None for the others).
    action_critics: Option<ActionCriticState>,
}

#[derive(Serialize, Deserialize)]
struct ActionCriticState {
    critics: [Vec<f32>; 2],
    targets: [Vec<f32>; 2],
    opt: [Adam<f32>; 2],
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

/// Checkpointed parameters into twin nets (sizes already checked), re-expanded.
fn load_twins(nets: &mut [Net<f32>; 2], params: [Vec<f32>; 2]) {
    for (n, p) in nets.iter_mut().zip(params) {
        n.params = p;
        n.expand();
    }
}

/// FNV-1a over f32 bits.
fn hash_params<'a>(vs: impl IntoIterator<Item = &'a [f32]>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in vs {
        for x in v {
            for b in x.to_bits().to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
    }
    h
}

fn params_hash(sac: &Sac<f32>) -> u64 {
    let la = [sac.log_alpha];
    hash_params([
        &sac.actor.params[..],
        &sac.critics[0].params,
        &sac.critics[1].params,
        &sac.targets[0].params,
        &sac.targets[1].params,
        &la[..],
    ])
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
    replay: Replay,
    streams: Streams,
    num_timesteps: u64,
    next_eval: u64,
    grad_steps: u64,
    elapsed: f64,
    rows: Vec<LogRow>,
    /// One per row of `rows`.
    diagnostics: Vec<Diagnostics>,
    obs_dim: usize,
    /// Where the run's time went, over all its invocations (kept in `summary.json`, not in the
    /// checkpoint: wall time is not reproducible).
    time: TimeSplit,
    /// Primitive env steps run by the evaluation episodes (kept beside `time`, in `summary.json`).
    eval_env_steps: u64,
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
    /// Save the run's state: the checkpoint (what a resume needs) and `summary.json` (step
    /// counts, weights hash, clock and time split).
    fn save(&mut self, dir: &Path) -> Result<()> {
        let ckpt_path = dir.join(CHECKPOINT_FILE);
        let bytes = postcard::to_stdvec(&self.checkpoint()?).map_err(|e| io_err(&ckpt_path, e))?;
        write_atomic(&ckpt_path, &bytes)?;
        let t = self.time;
        let file = SummaryFile {
            env_steps: self.env_steps(),
            grad_steps: self.grad_steps,
            params_hash: format!("{:016x}", params_hash(&self.sac)),
            seconds: tenths(self.elapsed),
            seconds_by_activity: TimeSplit { rollout: tenths(t.rollout), train: tenths(t.train), eval: tenths(t.eval) },
            eval_env_steps: self.eval_env_steps,
        };
        let path = dir.join(SUMMARY_FILE);
        let text = serde_json::to_string(&file).map_err(|e| io_err(&path, e))?;
        write_atomic(&path, format!("{text}\n").as_bytes())
    }

    /// The time split and evaluation step count of the invocations before this one (from
    /// `summary.json`, if readable).
    fn load_cost_record(&mut self, dir: &Path) {
        let prior = std::fs::read(dir.join(SUMMARY_FILE)).ok();
        if let Some(file) = prior.and_then(|b| serde_json::from_slice::<SummaryFile>(&b).ok()) {
            self.time = file.seconds_by_activity;
            self.eval_env_steps = file.eval_env_steps;
        }
    }

    fn env_steps(&self) -> u64 {
        self.num_timesteps * self.policy.chunk_len as u64
    }

    /// One vector step with its transitions and gradient steps.
    fn collect_and_train(&mut self, batch: &mut Batch<f32>) -> Result<()> {
        let rollout_started = Instant::now();
        let (n, ad, od) = (self.envs.num_envs(), self.sac.latent_dim(), self.obs_dim);
        let obs: Vec<f32> = (0..n).flat_map(|i| member_obs(&self.envs, i)).collect();
        debug_assert_eq!(obs.len(), n * od);
        let bound = DEFAULT_LATENT_BOUND;
        let scaled: Vec<f32> = if (self.num_timesteps as usize) < self.cfg.preset.warmup {
            (0..n * ad).map(|_| (self.streams.warmup.normal().clamp(-bound, bound) / bound) as f32).collect()
        } else {
            let mut eps = vec![0.0f32; n * ad];
            normals(&mut self.streams.rollout, &mut eps);
            self.sac.act(&obs, n, &eps)
        };
        let latents: Vec<f64> = scaled.iter().map(|a| *a as f64 * bound).collect();
        self.envs.step(&latents)?;
        self.num_timesteps += n as u64;
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
            self.replay.push_with_chunk(o, a, &chunk, r.reward as f32, &next, terminal);
            if terminal || r.truncated {
                seeds[i] = self.streams.env_seeds.next_u64();
                ended[i] = true;
            }
        }
        if ended.contains(&true) {
            self.envs.reset_masked(&seeds, &ended)?;
        }
        let train_started = Instant::now();
        self.time.rollout += (train_started - rollout_started).as_secs_f64();
        if self.num_timesteps as usize > self.cfg.preset.warmup {
            for _ in 0..self.cfg.utd() * n {
                self.replay.sample(self.cfg.preset.batch, &mut self.streams.replay, batch);
                let stats = if self.cfg.noise_aliased {
                    let policy = &self.policy;
                    let mut decode = |obs: &[f32], w: &[f32], rows: usize, out: &mut Vec<f32>| {
                        decode_normalized(policy, obs, w, rows, out)
                    };
                    self.sac.train_step_aliased(batch, &mut decode, DEFAULT_LATENT_BOUND, &mut self.streams.train)
                } else {
                    self.sac.train_step(batch, &mut self.streams.train)
                };
                self.grad_steps += 1;
                if !(stats.critic_loss.is_finite() && stats.actor_loss.is_finite()) {
                    return Err(Error::Diverged(format!(
                        "non-finite loss at gradient step {} (critic {}, actor {})",
                        self.grad_steps, stats.critic_loss, stats.actor_loss
                    )));
                }
            }
        }
        self.time.train += train_started.elapsed().as_secs_f64();
        Ok(())
    }

    /// Success rate of the stochastic actor over the evaluation episodes.
    fn evaluate(&mut self) -> Result<f64> {
        let episodes = self.cfg.eval_episodes;
        let eval_index = self.rows.len() as u64;
        let mut rngs: Vec<Rng> =
            (0..episodes as u64).map(|k| Rng::new(self.cfg.seed, Stream::Eval, (eval_index << 32) | k)).collect();
        let ad = self.sac.latent_dim();
        let sac = &mut self.sac;
        let mut choose = |idx: &[usize], obs: &[f32], out: &mut Vec<f64>| {
            let mut eps = vec![0.0f32; idx.len() * ad];
            for (j, &k) in idx.iter().enumerate() {
                normals(&mut rngs[k], &mut eps[j * ad..(j + 1) * ad]);
            }
            let a = sac.act(obs, idx.len(), &eps);
            out.extend(a.iter().map(|v| *v as f64 * DEFAULT_LATENT_BOUND));
        };
        let envs = match &mut self.eval_envs {
            Some(envs) => envs,
            none => none.insert(make_batch(&self.cfg, &self.policy, episodes)?),
        };
        let result = run_episodes(envs, &mut choose)?;
        self.eval_env_steps += result.env_steps;
        Ok(result.rate())
    }

    fn mean_q(&mut self) -> f64 {
        if self.replay.is_empty() {
            return f64::NAN;
        }
        let mut b = Batch::<f32>::default();
        self.replay.sample(MEAN_Q_SAMPLE.min(self.replay.len()), &mut self.streams.mean_q, &mut b);
        let q = self.sac.min_q(&b.obs, &b.act, b.rows);
        let s: f32 = q.iter().sum::<f32>() / q.len() as f32;
        s as f64
    }

    /// The learner's state at evaluation `rows.len()` (its own stream: see [`crate::rng`]).
    fn diagnose(&mut self) -> Diagnostics {
        if self.replay.is_empty() {
            return Diagnostics::default();
        }
        let mut rng = Rng::new(self.cfg.seed, Stream::Diagnostics, self.rows.len() as u64);
        let mut b = Batch::<f32>::default();
        self.replay.sample(MEAN_Q_SAMPLE.min(self.replay.len()), &mut rng, &mut b);
        self.sac.diagnose(&b, &mut rng)
    }

    fn checkpoint(&mut self) -> Result<Checkpoint> {
        let envs = self.envs.envs().map(|e| e.env().get_state()).collect::<std::result::Result<Vec<_>, EnvError>>()?;
        Ok(Checkpoint {
            format: CHECKPOINT_FORMAT.into(),
            fingerprint: self.cfg.fingerprint(),
            actor: self.sac.actor.params.clone(),
            critics: [self.sac.critics[0].params.clone(), self.sac.critics[1].params.clone()],
            targets: [self.sac.targets[0].params.clone(), self.sac.targets[1].params.clone()],
            log_alpha: self.sac.log_alpha,
            opt_actor: self.sac.opt_actor.clone(),
            opt_critics: self.sac.opt_critics.clone(),
            opt_alpha: self.sac.opt_alpha.clone(),
            replay: self.replay.clone(),
            streams: self.streams.clone(),
            envs,
            num_timesteps: self.num_timesteps,
            next_eval: self.next_eval,
            grad_steps: self.grad_steps,
            elapsed: self.elapsed,
            rows: self.rows.clone(),
            diagnostics: self.diagnostics.clone(),
            action_critics: self.sac.aliased.as_ref().map(|na| ActionCriticState {
                critics: [na.critics[0].params.clone(), na.critics[1].params.clone()],
                targets: [na.targets[0].params.clone(), na.targets[1].params.clone()],
                opt: na.opt.clone(),
            }),
        })
    }

    fn restore(&mut self, c: Checkpoint, path: &Path) -> Result<()> {
        // (the format was checked on the header, before the whole checkpoint was decoded)
        let bad = |reason: String| Error::Checkpoint { path: path.display().to_string(), reason };
        if c.fingerprint != self.cfg.fingerprint() {
            return Err(bad(format!(
                "written by another configuration ({}); use another --out or delete it",
                c.fingerprint
            )));
        }
        let fit = |name: &str, got: usize, want: usize| {
            if got == want {
                Ok(())
            } else {
                Err(bad(format!("{name} has {got} parameters, expected {want}")))
            }
        };
        let fit_twins = |name: &str, saved: &[Vec<f32>; 2], nets: &[Net<f32>; 2]| {
            saved.iter().zip(nets).try_for_each(|(s, n)| fit(name, s.len(), n.num_params()))
        };
        fit("actor", c.actor.len(), self.sac.actor.num_params())?;
        fit_twins("critic", &c.critics, &self.sac.critics)?;
        fit_twins("target critic", &c.targets, &self.sac.targets)?;
        match (&self.sac.aliased, &c.action_critics) {
            (Some(na), Some(s)) => {
                fit_twins("action critic", &s.critics, &na.critics)?;
                fit_twins("action target", &s.targets, &na.targets)?;
            }
            (None, None) => {}
            _ => return Err(bad("action critics saved for a run without noise aliasing, or missing".into())),
        }
        let n = self.envs.num_envs();
        if c.envs.len() != n {
            return Err(bad(format!("{} environments saved, {n} needed", c.envs.len())));
        }
        // Any start will do: every environment's state is replaced by the saved one.
        self.envs.reset(&vec![0; n])?;
        for (i, s) in c.envs.iter().enumerate() {
            self.envs.edit(i, |e| e.env_mut().set_state(s)).unwrap_or(Ok(()))?;
        }
        self.sac.actor.params = c.actor;
        self.sac.actor.expand();
        load_twins(&mut self.sac.critics, c.critics);
        load_twins(&mut self.sac.targets, c.targets);
        if let (Some(na), Some(s)) = (self.sac.aliased.as_mut(), c.action_critics) {
            load_twins(&mut na.critics, s.critics);
            load_twins(&mut na.targets, s.targets);
            na.opt = s.opt;
        }
        self.sac.log_alpha = c.log_alpha;
        self.sac.opt_actor = c.opt_actor;
        self.sac.opt_critics = c.opt_critics;
        self.sac.opt_alpha = c.opt_alpha;
        self.replay = c.replay;
        self.streams = c.streams;
        self.num_timesteps = c.num_timesteps;
        self.next_eval = c.next_eval;
        self.grad_steps = c.grad_steps;
        self.elapsed = c.elapsed;
        self.rows = c.rows;
        self.diagnostics = c.diagnostics;
        Ok(())
    }

    fn write_log(&self, dir: &Path) -> Result<()> {
        let mut s = String::from("env_steps,success_rate,mean_q,seconds\n");
        for r in &self.rows {
            s.push_str(&format!(
                "{},{},{},{:.1}\n",
                r.env_steps,
                fmt_float(r.success_rate),
                fmt_float(r.mean_q),
                r.seconds
            ));
        }
        write_atomic(&dir.join("log.csv"), s.as_bytes())?;
        let mut s = String::from("env_steps,alpha,entropy,edge_fraction,critic_loss,target_q,policy_q\n");
        for (r, d) in self.rows.iter().zip(&self.diagnostics) {
            let cells = [d.alpha, d.entropy, d.edge_fraction, d.critic_loss, d.target_q, d.policy_q].map(fmt_float);
            s.push_str(&format!("{},{}\n", r.env_steps, cells.join(",")));
        }
        write_atomic(&dir.join("train.csv"), s.as_bytes())
    }
}

/// Python's spelling of floats in CSV (`nan` for NaN).
fn fmt_float(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else {
        format!("{v:?}")
    }
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).map_err(|e| io_err(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| io_err(path, e))
}

/// `run.json`: what the run is, for reports. Options added later appear only when set, so that
/// earlier runs' files stay as they were.
#[derive(Serialize)]
struct RunMeta<'a> {
    method: &'a str,
    task: &'a str,
    seed: u64,
    steps: usize,
    preset: &'a str,
    joint_limits: bool,
    agent: &'a str,
    fields: usize,
    params_actor: usize,
    params_critic: usize,
    policy: String,
    #[serde(skip_serializing_if = "is_false")]
    terminate_on_success: bool,
    #[serde(skip_serializing_if = "is_false")]
    noise_aliased: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    target_entropy: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    variant: Option<&'a str>,
    /// Evaluation settings and the controller, when not the defaults.
    #[serde(skip_serializing_if = "Option::is_none")]
    eval_every: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    eval_episodes: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    controller: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    horizon: Option<usize>,
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// JSON on one line with `", "` and `": "` between items (the layout of the committed runs).
struct SpacedJson;

impl serde_json::ser::Formatter for SpacedJson {
    fn begin_object_key<W: ?Sized + std::io::Write>(&mut self, w: &mut W, first: bool) -> std::io::Result<()> {
        if first {
            Ok(())
        } else {
            w.write_all(b", ")
        }
    }

    fn begin_object_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b": ")
    }
}

impl RunMeta<'_> {
    fn to_json(&self) -> String {
        let mut out = Vec::new();
        let mut ser = serde_json::Serializer::with_formatter(&mut out, SpacedJson);
        self.serialize(&mut ser).expect("a RunMeta always serialises");
        String::from_utf8(out).expect("serde_json writes UTF-8") + "\n"
    }
}

/// A latent environment as the run configures it.
pub fn make_env(cfg: &RunConfig, policy: &Arc<DiffusionPolicy>) -> Result<LatentEnv> {
    let mut ec = EnvConfig::new(&cfg.task);
    ec.physics.joint_limits = cfg.joint_limits;
    if let Some(c) = cfg.cartesian {
        ec.physics.cartesian_control = c;
    }
    ec.horizon = cfg.horizon;
    ec.task_options.variant = cfg.variant.clone();
    let env = Env::new(ec)?;
    Ok(LatentEnv::new(env, policy.clone(), DEFAULT_LATENT_BOUND, policy.default_ddim_steps)?)
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
    let policy = Arc::new(DiffusionPolicy::load(cfg.policy_path())?);
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
    };
    let sac = if cfg.noise_aliased {
        let action_critics = Models::<f32>::action_critics(cfg.method, &sym, arch, cfg.seed)?;
        Sac::aliased(models, action_critics, obs_dim, sac_cfg)
    } else {
        Sac::new(models, obs_dim, sac_cfg)
    };
    let latent_dim = sac.latent_dim();
    let chunk_dim = if cfg.noise_aliased { policy.action_dim() } else { 0 };
    let mut r = Runner {
        cfg: cfg.clone(),
        policy,
        sac,
        envs,
        eval_envs: None,
        replay: Replay::with_chunks(obs_dim, latent_dim, chunk_dim, DEFAULT_CAPACITY),
        streams: Streams::new(cfg.seed),
        num_timesteps: 0,
        next_eval: 0,
        grad_steps: 0,
        elapsed: 0.0,
        rows: Vec::new(),
        diagnostics: Vec::new(),
        obs_dim,
        time: TimeSplit::default(),
        eval_env_steps: 0,
    };
    let dir = cfg.run_dir();
    std::fs::create_dir_all(&dir).map_err(|e| io_err(&dir, e))?;
    let ckpt_path = dir.join(CHECKPOINT_FILE);
    if ckpt_path.exists() {
        let bytes = std::fs::read(&ckpt_path).map_err(|e| io_err(&ckpt_path, e))?;
        let corrupt = |e: postcard::Error| Error::Checkpoint {
            path: ckpt_path.display().to_string(),
            reason: format!("corrupt ({e})"),
        };
        let header: CheckpointHeader = postcard::from_bytes(&bytes).map_err(corrupt)?;
        if header.format != CHECKPOINT_FORMAT {
            return Err(Error::Checkpoint {
                path: ckpt_path.display().to_string(),
                reason: format!(
                    "format '{}' is not '{CHECKPOINT_FORMAT}' (written by another equigym version); use another --out or delete it",
                    header.format
                ),
            });
        }
        let c: Checkpoint = postcard::from_bytes(&bytes).map_err(corrupt)?;
        r.restore(c, &ckpt_path)?;
        r.write_log(&dir)?;
        r.load_cost_record(&dir);
    } else {
        let seeds: Vec<u64> = (0..r.envs.num_envs()).map(|_| r.streams.env_seeds.next_u64()).collect();
        r.envs.reset(&seeds)?;
        // A log from an older run without a checkpoint would mix two runs.
        let _ = std::fs::remove_file(dir.join("log.csv"));
    }
    let (params_actor, params_critic) =
        (r.sac.actor.num_params(), r.sac.critics[0].num_params() + r.sac.critics[1].num_params());
    let meta = RunMeta {
        method: cfg.method.name(),
        task: &cfg.task,
        seed: cfg.seed,
        steps: cfg.steps,
        preset: &cfg.preset.name,
        joint_limits: cfg.joint_limits,
        agent: "rust",
        fields,
        params_actor,
        params_critic,
        policy: cfg.policy_path().display().to_string(),
        terminate_on_success: cfg.terminate_on_success,
        noise_aliased: cfg.noise_aliased,
        target_entropy: cfg.target_entropy,
        variant: cfg.variant.as_deref(),
        eval_every: (cfg.eval_every != EVAL_EVERY).then_some(cfg.eval_every),
        eval_episodes: (cfg.eval_episodes != EVAL_EPISODES).then_some(cfg.eval_episodes),
        controller: cfg.cartesian.map(|c| if c { "cartesian" } else { "joint" }),
        horizon: cfg.horizon,
    }
    .to_json();
    write_atomic(&dir.join("run.json"), meta.as_bytes())?;
    let base_elapsed = r.elapsed;
    let steps_at_start = r.env_steps();
    let mut batch = Batch::default();
    let mut evals_now = 0;
    while r.env_steps() < cfg.steps as u64 {
        r.collect_and_train(&mut batch)?;
        let steps = r.env_steps();
        if steps >= r.next_eval {
            r.next_eval += cfg.eval_every as u64;
            let eval_started = Instant::now();
            let success_rate = r.evaluate()?;
            r.time.eval += eval_started.elapsed().as_secs_f64();
            let mean_q = r.mean_q();
            let diagnostics = r.diagnose();
            r.diagnostics.push(diagnostics);
            r.elapsed = base_elapsed + started.elapsed().as_secs_f64();
            r.rows.push(LogRow { env_steps: steps, success_rate, mean_q, seconds: (r.elapsed * 10.0).round() / 10.0 });
            r.write_log(&dir)?;
            r.save(&dir)?;
            if cfg.progress {
                eprintln!(
                    "{}/{}/seed{}: {steps} env steps, success {success_rate:.2}, mean Q {mean_q:.3}, {:.1} s",
                    cfg.task,
                    cfg.method.name(),
                    cfg.seed,
                    r.elapsed
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
        r.elapsed = base_elapsed + started.elapsed().as_secs_f64();
        r.save(&dir)?;
    }
    let summary = RunSummary {
        run_dir: dir.clone(),
        rows: r.rows.clone(),
        params_hash: params_hash(&r.sac),
        env_steps: r.env_steps(),
        grad_steps: r.grad_steps,
        seconds: r.elapsed,
        time: r.time,
        eval_env_steps: r.eval_env_steps,
        fields,
        params_actor,
        params_critic,
    };
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::RunMeta;

    fn meta(policy: &str) -> RunMeta<'static> {
        RunMeta {
            method: "dsrl",
            task: "lift",
            seed: 0,
            steps: 16000,
            preset: "cpu",
            joint_limits: true,
            agent: "rust",
            fields: 0,
            params_actor: 15376,
            params_critic: 25602,
            policy: policy.into(),
            terminate_on_success: false,
            noise_aliased: false,
            target_entropy: None,
            variant: None,
            eval_every: None,
            eval_episodes: None,
            controller: None,
            horizon: None,
        }
    }

    /// `run.json` keeps the layout of the committed runs, later options only when set.
    #[test]
    fn run_meta_matches_committed_runs() {
        let plain = meta("python/equigym/shipped/edp/lift.safetensors");
        assert_eq!(plain.to_json(), include_str!("../../docs/steering/arm3/runs/rust/lift/dsrl/seed0/run.json"));
        let mut recipe = meta("docs/steering/steerability/lift-edp-training/edp/plain_16k.safetensors");
        recipe.terminate_on_success = true;
        recipe.noise_aliased = true;
        recipe.target_entropy = Some(40.0);
        assert_eq!(
            recipe.to_json(),
            include_str!("../../docs/steering/arm3/recipe/edp16k-na-tos-h40-dsrl-seed0/run.json")
        );
    }
}
