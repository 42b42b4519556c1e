//! What a run's checkpoint holds (networks, optimisers, replay, random streams, the
//! environments' full states and the log) and how a run resumes from it: a killed run that is
//! started again ends bit for bit where the uninterrupted run ends.

use std::path::Path;

use equigym_envs::EnvError;
use equigym_nn::Adam;
use serde::{Deserialize, Serialize};

use super::files::write_atomic;
use super::{LogRow, Runner};
use crate::error::{io_err, Error, Result};
use crate::net::Net;
use crate::replay::Replay;
use crate::rng::{Rng, Stream};
use crate::sac::{Diagnostics, Sac};

/// Checkpoint format tag.
pub const CHECKPOINT_FORMAT: &str = "equigym-agents-ckpt-3";
const CHECKPOINT_FILE: &str = "checkpoint.bin";

#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct Streams {
    pub(super) env_seeds: Rng,
    pub(super) warmup: Rng,
    pub(super) rollout: Rng,
    pub(super) replay: Rng,
    pub(super) train: Rng,
    pub(super) mean_q: Rng,
}

impl Streams {
    pub(super) fn new(seed: u64) -> Self {
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

pub(super) fn params_hash(sac: &Sac<f32>) -> u64 {
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

impl Runner {
    /// Resume from `dir`'s checkpoint if there is one (its log and cost record too); otherwise
    /// reset the environments from the run's seed stream and drop a stale log.
    pub(super) fn resume_or_start(&mut self, dir: &Path) -> Result<()> {
        let ckpt_path = dir.join(CHECKPOINT_FILE);
        if !ckpt_path.exists() {
            let seeds: Vec<u64> = (0..self.envs.num_envs()).map(|_| self.streams.env_seeds.next_u64()).collect();
            self.envs.reset(&seeds)?;
            // A log from an older run without a checkpoint would mix two runs.
            let _ = std::fs::remove_file(dir.join("log.csv"));
            return Ok(());
        }
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
        self.restore(c, &ckpt_path)?;
        self.write_log(dir)?;
        self.load_cost_record(dir);
        Ok(())
    }

    /// Write the checkpoint (atomically).
    pub(super) fn write_checkpoint(&mut self, dir: &Path) -> Result<()> {
        let path = dir.join(CHECKPOINT_FILE);
        let bytes = postcard::to_stdvec(&self.checkpoint()?).map_err(|e| io_err(&path, e))?;
        write_atomic(&path, &bytes)
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
}
