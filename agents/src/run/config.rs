//! What a steering run is: its options ([`RunConfig`]), the network and schedule presets
//! ([`Preset`]), DSRL's constants, the checks on a configuration and the fingerprint that a
//! checkpoint must match to be resumed.

use equigym_envs::{Controller, EnvOptions};
use equigym_wrappers::edp::Kernel;
use equigym_wrappers::DiffusionPolicy;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::models::Method;

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
    /// The environments' options: the Python environments' keyword arguments (joint limits,
    /// controller, horizon, reset variant, physics, ...). Default: the task's own.
    pub env: EnvOptions,
    pub eval_every: usize,
    pub eval_episodes: usize,
    /// Diffusion policy file (default: the shipped one for the task).
    pub policy: Option<PathBuf>,
    /// The kernel that runs the policy's regular-to-regular layers ([`Kernel`]; default the
    /// Fourier basis). The dense kernel is the same map up to float rounding, about 5x slower on
    /// Square D2 (most of a noise-aliased run's cost), and the one the runs recorded before the
    /// Fourier kernel existed used: a run that sets it replays them.
    pub edp_kernel: Kernel,
    /// Initial entropy coefficient (default: the preset's).
    pub ent_init: Option<f64>,
    /// Gradient steps per environment transition, for every task (default: the preset's, whose
    /// Square value may differ). The paper ties DSRL's Q divergence to a high ratio (30); the
    /// `cpu` preset's 4 does not provoke it, so this is the knob that tests that claim.
    pub utd: Option<usize>,
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
    /// Regularise the actor towards the diffusion policy's own noise `N(0, I)` with this KL
    /// budget in nats ([`crate::sac::NoisePrior`]) instead of towards a target entropy.
    pub prior_kl: Option<f64>,
    /// Multiply every reward the learner stores by this factor (default 1: the latent MDP's
    /// sum of `success - 1` over the chunk). The returns of a failing episode reach a few
    /// hundred, which a small critic trained with Adam approaches only slowly; a smaller scale
    /// brings the values within its reach without changing which noise is best. Evaluation is
    /// unchanged.
    pub reward_scale: Option<f64>,
    /// Steer by selection instead of by an actor ([`crate::sac::Sac::train_step_select`]): at
    /// every latent step the best of this many fresh N(0, I) candidates by the critics' min-Q,
    /// and critics that learn that policy's value. The noise stays the EDP's own (a pick's KL
    /// to N(0, I) is at most ln n); 1 evaluates the base policy. Collection and the run's
    /// evaluations use the same policy.
    pub select: Option<usize>,
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
            env: EnvOptions::default(),
            eval_every: EVAL_EVERY,
            eval_episodes: EVAL_EPISODES,
            policy: None,
            edp_kernel: Kernel::default(),
            ent_init: None,
            utd: None,
            terminate_on_success: false,
            noise_aliased: false,
            target_entropy: None,
            prior_kl: None,
            reward_scale: None,
            select: None,
            progress: false,
            stop_after_evals: None,
        })
    }

    /// Whether the arm's joint limits are enforced.
    pub fn joint_limits(&self) -> bool {
        self.env.joint_limits_on()
    }

    /// `out/<task>[-nolimits][-joint|-cartesian]/<method>/seed<S>` (the SB3 runs' layout).
    pub fn run_dir(&self) -> PathBuf {
        let mut task = self.task.clone();
        if !self.joint_limits() {
            task.push_str("-nolimits");
        }
        if let Some(c) = self.env.controller {
            task.push('-');
            task.push_str(c.name());
        }
        self.out.join(task).join(self.method.name()).join(format!("seed{}", self.seed))
    }

    /// The environment options other than the four a run names on its own (joint limits,
    /// controller, horizon, variant), where any differs from the default: what `run.json` and
    /// the fingerprint add for them.
    pub(super) fn other_env_options(&self) -> Option<EnvOptions> {
        let rest =
            EnvOptions { joint_limits: None, controller: None, horizon: None, variant: None, ..self.env.clone() };
        (rest != EnvOptions::default()).then_some(rest)
    }

    pub(crate) fn policy_path(&self) -> PathBuf {
        self.policy.clone().unwrap_or_else(|| Path::new(DEFAULT_POLICY_DIR).join(format!("{}.safetensors", self.task)))
    }

    /// The run's diffusion policy, loaded, on the run's kernel.
    pub(crate) fn load_policy(&self) -> Result<DiffusionPolicy> {
        let mut policy = DiffusionPolicy::load(self.policy_path())?;
        policy.kernel = self.edp_kernel;
        Ok(policy)
    }

    pub(super) fn gamma(&self) -> f64 {
        if self.task == "square" {
            GAMMA_SQUARE
        } else {
            GAMMA
        }
    }

    pub(super) fn utd(&self) -> usize {
        if let Some(u) = self.utd {
            u
        } else if self.task == "square" {
            self.preset.utd_square.unwrap_or(self.preset.utd)
        } else {
            self.preset.utd
        }
    }

    /// What must match for a checkpoint to be resumed (not steps, threads or output place).
    pub(super) fn fingerprint(&self) -> String {
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
        if let Some(k) = self.prior_kl {
            later.push_str(&format!("|prior_kl={k:?}"));
        }
        if let Some(k) = self.reward_scale {
            later.push_str(&format!("|reward_scale={k:?}"));
        }
        if let Some(n) = self.select {
            later.push_str(&format!("|select={n}"));
        }
        if let Some(u) = self.utd {
            later.push_str(&format!("|utd={u}"));
        }
        if let Some(v) = &self.env.variant {
            later.push_str(&format!("|variant={v}"));
        }
        if let Some(rest) = self.other_env_options() {
            later.push_str(&format!("|env={}", serde_json::to_string(&rest).unwrap_or_default()));
        }
        // Named where it is not dense, the kernel of every run recorded before the Fourier one
        // existed, so that their checkpoints keep their fingerprints.
        if self.edp_kernel != Kernel::Dense {
            later.push_str(&format!("|edp_kernel={}", self.edp_kernel.as_str()));
        }
        format!(
            "{}|{}|{}|{:?}|{}|{:?}|{}|{}|{}|{:?}|{:?}",
            self.method.name(),
            self.task,
            self.seed,
            self.preset,
            self.joint_limits(),
            // spelled as the earlier `cartesian: Option<bool>`, so that checkpoints still resume
            self.env.controller.map(|c| c == Controller::Cartesian),
            self.eval_every,
            self.eval_episodes,
            self.policy_path().display(),
            self.ent_init,
            self.env.horizon
        ) + &later
    }

    pub(crate) fn validate(&self) -> Result<()> {
        let p = &self.preset;
        let bad = |m: String| Err(Error::InvalidOption(m));
        if !equigym_envs::tasks::TASK_IDS.contains(&self.task.as_str()) {
            return bad(format!("task must be one of {:?}, got '{}'", equigym_envs::tasks::TASK_IDS, self.task));
        }
        if p.n_envs == 0 || p.batch == 0 || p.utd == 0 {
            return bad(format!("preset needs n_envs, batch and utd >= 1, got {p:?}"));
        }
        if self.utd == Some(0) {
            return bad("utd must be at least 1 gradient step per transition".into());
        }
        if self.eval_every == 0 || self.eval_episodes == 0 {
            return bad("eval_every and eval_episodes must be >= 1".into());
        }
        if self.target_entropy.is_some_and(|t| !t.is_finite()) {
            return bad(format!("the target entropy must be finite, got {:?}", self.target_entropy));
        }
        if let Some(k) = self.prior_kl {
            if !(k.is_finite() && k > 0.0) {
                return bad(format!("the prior KL budget must be a positive number of nats, got {k}"));
            }
            if self.target_entropy.is_some() {
                return bad("a prior KL budget replaces the target entropy: give one of them".into());
            }
        }
        if let Some(k) = self.reward_scale {
            if !(k.is_finite() && k > 0.0) {
                return bad(format!("the reward scale must be a positive number, got {k}"));
            }
        }
        if let Some(n) = self.select {
            if n == 0 {
                return bad("select needs at least one candidate".into());
            }
            if self.noise_aliased || self.prior_kl.is_some() || self.target_entropy.is_some() {
                return bad(
                    "select has no actor: noise aliasing, a prior KL budget and a target entropy do not apply".into()
                );
            }
        }
        let ent = self.ent_init.unwrap_or(p.ent_init);
        if !(ent.is_finite() && ent > 0.0) {
            return bad(format!("the initial entropy coefficient must be positive, got {ent}"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(task: &str) -> RunConfig {
        RunConfig::new(Method::Dsrl, task, 0, 100, "/tmp/unused").unwrap()
    }

    #[test]
    fn a_runs_own_utd_replaces_the_presets_for_every_task_and_changes_its_fingerprint() {
        let (mut lift, mut square) = (cfg("lift"), cfg("square"));
        let before = lift.fingerprint();
        assert_eq!(lift.utd(), 4);
        lift.utd = Some(30);
        square.preset = Preset::named("paper").unwrap();
        assert_eq!(square.utd(), 20, "the paper preset's Square ratio");
        square.utd = Some(30);
        assert_eq!((lift.utd(), square.utd()), (30, 30));
        assert_ne!(lift.fingerprint(), before, "a checkpoint of another ratio must not resume");
        assert!(lift.validate().is_ok());
        lift.utd = Some(0);
        assert!(matches!(lift.validate(), Err(Error::InvalidOption(_))));
    }

    #[test]
    fn the_fourier_kernel_is_the_default_and_named_in_the_fingerprint() {
        let mut lift = cfg("lift");
        assert_eq!(lift.edp_kernel, Kernel::Fourier);
        assert!(lift.fingerprint().ends_with("|edp_kernel=fourier"));
        assert_eq!(lift.load_policy().unwrap().kernel, Kernel::Fourier);
        lift.edp_kernel = Kernel::Dense;
        assert!(
            !lift.fingerprint().contains("edp_kernel"),
            "earlier (dense) runs' checkpoints keep their fingerprints"
        );
        assert_eq!(lift.load_policy().unwrap().kernel, Kernel::Dense);
    }
}
