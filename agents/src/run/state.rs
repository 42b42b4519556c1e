//! What a run's checkpoint holds (networks, optimisers, replay, random streams, the
//! environments' full states and the log) and how a run resumes from it: a killed run that is
//! started again ends bit for bit where the uninterrupted run ends.

use std::path::Path;

use equigym_envs::EnvError;
use serde::{Deserialize, Serialize};

use super::files::write_atomic;
use super::{LogRow, Runner};
use crate::error::{io_err, Error, Result};
use crate::replay::Replay;
use crate::rng::{Rng, Stream};
use crate::sac::{Diagnostics, Sac, SacState};

/// Checkpoint format tag.
pub const CHECKPOINT_FORMAT: &str = "equigym-agents-ckpt-4";
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

/// The run's progress besides the learner and the environments: replay, random streams, step
/// counts, clock and log.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct Progress {
    pub(super) replay: Replay,
    pub(super) streams: Streams,
    pub(super) num_timesteps: u64,
    pub(super) next_eval: u64,
    pub(super) grad_steps: u64,
    pub(super) elapsed: f64,
    pub(super) rows: Vec<LogRow>,
    /// One per row of `rows`.
    pub(super) diagnostics: Vec<Diagnostics>,
}

impl Progress {
    /// A run that has not started: an empty `replay`, the streams of `seed`.
    pub(super) fn new(replay: Replay, seed: u64) -> Self {
        Self {
            replay,
            streams: Streams::new(seed),
            num_timesteps: 0,
            next_eval: 0,
            grad_steps: 0,
            elapsed: 0.0,
            rows: Vec::new(),
            diagnostics: Vec::new(),
        }
    }
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    format: String,
    fingerprint: String,
    learner: SacState,
    /// Each environment's full state (`Env::get_state`).
    envs: Vec<Vec<u8>>,
    progress: Progress,
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
            let seeds: Vec<u64> =
                (0..self.envs.num_envs()).map(|_| self.progress.streams.env_seeds.next_u64()).collect();
            self.envs.reset(&seeds)?;
            // A log from an older run without a checkpoint would mix two runs.
            let _ = std::fs::remove_file(dir.join("log.csv"));
            return Ok(());
        }
        let c = read_checkpoint(&ckpt_path)?;
        self.restore(c, &ckpt_path)?;
        self.write_log(dir)?;
        self.load_cost_record(dir);
        Ok(())
    }

    /// Load only the learner (networks, optimisers, entropy coefficient) from `dir`'s
    /// checkpoint, leaving environments, replay and files alone; the env steps it was saved at,
    /// or `None` (and the fresh learner) when `dir` has no checkpoint.
    pub(super) fn load_learner(&mut self, dir: &Path) -> Result<Option<u64>> {
        let path = dir.join(CHECKPOINT_FILE);
        if !path.exists() {
            return Ok(None);
        }
        let c = read_checkpoint(&path)?;
        self.check_fingerprint(&c, &path)?;
        let bad = |reason: String| Error::Checkpoint { path: path.display().to_string(), reason };
        self.sac.set_state(c.learner).map_err(bad)?;
        Ok(Some(c.progress.num_timesteps * self.policy.chunk_len as u64))
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
            learner: self.sac.state(),
            envs,
            progress: self.progress.clone(),
        })
    }

    fn check_fingerprint(&self, c: &Checkpoint, path: &Path) -> Result<()> {
        if c.fingerprint != self.cfg.fingerprint() {
            return Err(Error::Checkpoint {
                path: path.display().to_string(),
                reason: format!("written by another configuration ({}); use another --out or delete it", c.fingerprint),
            });
        }
        Ok(())
    }

    fn restore(&mut self, c: Checkpoint, path: &Path) -> Result<()> {
        // (the format was checked on the header, before the whole checkpoint was decoded)
        let bad = |reason: String| Error::Checkpoint { path: path.display().to_string(), reason };
        self.check_fingerprint(&c, path)?;
        let n = self.envs.num_envs();
        if c.envs.len() != n {
            return Err(bad(format!("{} environments saved, {n} needed", c.envs.len())));
        }
        self.sac.set_state(c.learner).map_err(bad)?;
        // Any start will do: every environment's state is replaced by the saved one.
        self.envs.reset(&vec![0; n])?;
        for (i, s) in c.envs.iter().enumerate() {
            self.envs.edit(i, |e| e.env_mut().set_state(s)).unwrap_or(Ok(()))?;
        }
        self.progress = c.progress;
        Ok(())
    }
}

/// Decode a checkpoint file, its format checked on the header first.
fn read_checkpoint(path: &Path) -> Result<Checkpoint> {
    let bytes = std::fs::read(path).map_err(|e| io_err(path, e))?;
    let corrupt =
        |e: postcard::Error| Error::Checkpoint { path: path.display().to_string(), reason: format!("corrupt ({e})") };
    let header: CheckpointHeader = postcard::from_bytes(&bytes).map_err(corrupt)?;
    if header.format != CHECKPOINT_FORMAT {
        return Err(Error::Checkpoint {
            path: path.display().to_string(),
            reason: format!(
                "format '{}' is not '{CHECKPOINT_FORMAT}' (written by another equigym version); use another --out or delete it",
                header.format
            ),
        });
    }
    postcard::from_bytes(&bytes).map_err(corrupt)
}
