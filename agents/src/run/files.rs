//! What a run writes beside its checkpoint, each file atomically (written aside, then
//! renamed): `log.csv` (evaluations), `train.csv` (the learner's state at each), `summary.json`
//! (step counts, weights hash, clock and time split) and `run.json` (what the run is, for
//! reports; the layout of the committed runs).

use equigym_envs::{Controller, EnvOptions};
use equigym_wrappers::edp::Kernel;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::state::params_hash;
use super::{Runner, TimeSplit, EVAL_EPISODES, EVAL_EVERY};
use crate::error::{io_err, Result};

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

impl Runner {
    /// Save the run's state: the checkpoint (what a resume needs) and `summary.json` (step
    /// counts, weights hash, clock and time split).
    pub(super) fn save(&mut self, dir: &Path) -> Result<()> {
        self.write_checkpoint(dir)?;
        let t = self.time;
        let file = SummaryFile {
            env_steps: self.env_steps(),
            grad_steps: self.progress.grad_steps,
            params_hash: format!("{:016x}", params_hash(&self.sac)),
            seconds: tenths(self.progress.elapsed),
            seconds_by_activity: TimeSplit { rollout: tenths(t.rollout), train: tenths(t.train), eval: tenths(t.eval) },
            eval_env_steps: self.eval_env_steps,
        };
        let path = dir.join(SUMMARY_FILE);
        let text = serde_json::to_string(&file).map_err(|e| io_err(&path, e))?;
        write_atomic(&path, format!("{text}\n").as_bytes())
    }

    /// The time split and evaluation step count of the invocations before this one (from
    /// `summary.json`, if readable).
    pub(super) fn load_cost_record(&mut self, dir: &Path) {
        let prior = std::fs::read(dir.join(SUMMARY_FILE)).ok();
        if let Some(file) = prior.and_then(|b| serde_json::from_slice::<SummaryFile>(&b).ok()) {
            self.time = file.seconds_by_activity;
            self.eval_env_steps = file.eval_env_steps;
        }
    }

    pub(super) fn write_log(&self, dir: &Path) -> Result<()> {
        let mut s = String::from("env_steps,success_rate,mean_q,seconds\n");
        for r in &self.progress.rows {
            s.push_str(&format!(
                "{},{},{},{:.1}\n",
                r.env_steps,
                fmt_float(r.success_rate),
                fmt_float(r.mean_q),
                r.seconds
            ));
        }
        write_atomic(&dir.join("log.csv"), s.as_bytes())?;
        let mut s = String::from("env_steps,alpha,entropy,edge_fraction,critic_loss,target_q,policy_q,prior_kl\n");
        for (r, d) in self.progress.rows.iter().zip(&self.progress.diagnostics) {
            let cells =
                [d.alpha, d.entropy, d.edge_fraction, d.critic_loss, d.target_q, d.policy_q, d.prior_kl].map(fmt_float);
            s.push_str(&format!("{},{}\n", r.env_steps, cells.join(",")));
        }
        write_atomic(&dir.join("train.csv"), s.as_bytes())
    }

    /// `run.json` for this run.
    pub(super) fn write_run_json(&self, dir: &Path) -> Result<()> {
        let cfg = &self.cfg;
        let meta = RunMeta {
            method: cfg.method.name(),
            task: &cfg.task,
            seed: cfg.seed,
            steps: cfg.steps,
            preset: &cfg.preset.name,
            joint_limits: cfg.joint_limits(),
            agent: "rust",
            fields: self.fields,
            params_actor: self.sac.actor.num_params(),
            params_critic: self.critic_params(),
            policy: cfg.policy_path().display().to_string(),
            terminate_on_success: cfg.terminate_on_success,
            noise_aliased: cfg.noise_aliased,
            target_entropy: cfg.target_entropy,
            prior_kl: cfg.prior_kl,
            reward_scale: cfg.reward_scale,
            select: cfg.select,
            utd: cfg.utd,
            variant: cfg.env.variant.as_deref(),
            eval_every: (cfg.eval_every != EVAL_EVERY).then_some(cfg.eval_every),
            eval_episodes: (cfg.eval_episodes != EVAL_EPISODES).then_some(cfg.eval_episodes),
            controller: cfg.env.controller.map(Controller::name),
            horizon: cfg.env.horizon,
            env: cfg.other_env_options(),
            edp_kernel: (cfg.edp_kernel != Kernel::Dense).then_some(cfg.edp_kernel.as_str()),
        };
        write_atomic(&dir.join("run.json"), meta.to_json().as_bytes())
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

pub(super) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
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
    prior_kl: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    reward_scale: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    select: Option<usize>,
    /// Gradient steps per transition where a run sets its own (else the preset's).
    #[serde(skip_serializing_if = "Option::is_none")]
    utd: Option<usize>,
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
    /// The other environment options, where any differs from the default.
    #[serde(skip_serializing_if = "Option::is_none")]
    env: Option<EnvOptions>,
    /// The EDP's kernel, where not dense (the kernel of every run recorded before the Fourier
    /// one existed, whose files name none).
    #[serde(skip_serializing_if = "Option::is_none")]
    edp_kernel: Option<&'a str>,
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
            prior_kl: None,
            reward_scale: None,
            select: None,
            utd: None,
            variant: None,
            eval_every: None,
            eval_episodes: None,
            controller: None,
            horizon: None,
            env: None,
            edp_kernel: None,
        }
    }

    /// `run.json` keeps the layout of the committed runs, later options only when set.
    #[test]
    fn run_meta_matches_committed_runs() {
        let plain = meta("python/equigym/shipped/edp/lift.safetensors");
        assert_eq!(plain.to_json(), include_str!("../../../docs/steering/arm3/runs/rust/lift/dsrl/seed0/run.json"));
        let mut recipe = meta("docs/steering/steerability/lift-edp-training/edp/plain_16k.safetensors");
        recipe.terminate_on_success = true;
        recipe.noise_aliased = true;
        recipe.target_entropy = Some(40.0);
        assert_eq!(
            recipe.to_json(),
            include_str!("../../../docs/steering/arm3/recipe/edp16k-na-tos-h40-dsrl-seed0/run.json")
        );
        recipe.edp_kernel = Some("fourier");
        assert!(recipe.to_json().trim_end().ends_with(r#", "edp_kernel": "fourier"}"#), "{}", recipe.to_json());
    }
}
