//! The run's learner used as a policy on the pinned evaluation starts: the run's own
//! evaluations (the stochastic actor, or the selecting policy) and `steer eval`'s other uses
//! of a checkpoint (the actor's mean, the critic's best of N fresh candidates).

use equigym_wrappers::DEFAULT_LATENT_BOUND;

use super::{make_batch, RunConfig, Runner};
use crate::error::Result;
use crate::evaluation::{run_episodes, Episodes};
use crate::rng::{Rng, Stream};
use crate::sac::{candidates, normals};

impl Runner {
    /// Success rate of the stochastic actor (of the selecting policy, with `select`) over the
    /// evaluation episodes.
    pub(super) fn evaluate(&mut self) -> Result<f64> {
        let noise = self.cfg.select.map_or(ActorNoise::Sampled, ActorNoise::BestOf);
        let result = self.evaluate_actor(noise, self.cfg.eval_episodes)?;
        self.eval_env_steps += result.env_steps;
        Ok(result.rate())
    }

    /// The actor on the pinned evaluation starts: sampled (the run's evaluations: episode k
    /// draws from its own [`Stream::Eval`] stream) or its mean noise (zero reparameterisation
    /// noise, SB3's `deterministic=True`).
    pub(super) fn evaluate_actor(&mut self, noise: ActorNoise, episodes: usize) -> Result<Episodes> {
        let eval_index = self.progress.rows.len() as u64;
        let mut rngs: Vec<Rng> =
            (0..episodes as u64).map(|k| Rng::new(self.cfg.seed, Stream::Eval, (eval_index << 32) | k)).collect();
        let ad = self.sac.latent_dim();
        let sac = &mut self.sac;
        let mut choose = |idx: &[usize], obs: &[f32], out: &mut Vec<f64>| {
            if let ActorNoise::BestOf(n) = noise {
                // Each episode's candidates from its own stream, all episodes scored at once.
                let mut w = vec![0.0f32; idx.len() * n * ad];
                for (j, &k) in idx.iter().enumerate() {
                    candidates(&mut rngs[k], DEFAULT_LATENT_BOUND, &mut w[j * n * ad..(j + 1) * n * ad]);
                }
                let picks = sac.pick(obs, idx.len(), n, &w);
                out.extend(picks.iter().map(|v| *v as f64 * DEFAULT_LATENT_BOUND));
                return;
            }
            let mut eps = vec![0.0f32; idx.len() * ad];
            if noise == ActorNoise::Sampled {
                for (j, &k) in idx.iter().enumerate() {
                    normals(&mut rngs[k], &mut eps[j * ad..(j + 1) * ad]);
                }
            }
            let a = sac.act(obs, idx.len(), &eps);
            out.extend(a.iter().map(|v| *v as f64 * DEFAULT_LATENT_BOUND));
        };
        let envs = match &mut self.eval_envs {
            Some(envs) if envs.num_envs() == episodes => envs,
            slot => slot.insert(make_batch(&self.cfg, &self.policy, episodes)?),
        };
        run_episodes(envs, &mut choose)
    }
}

/// How the actor's noise is drawn when it is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ActorNoise {
    /// Samples of the actor (DSRL's evaluation, and every run's `log.csv`).
    Sampled,
    /// The actor's mean (squashed), one noise per observation.
    Mean,
    /// The critic as a ranker: `n` fresh candidates from the EDP's own noise N(0, I) (clipped to
    /// the box), the one of highest min-Q taken. With an uninformative critic this is the base
    /// policy; the pick's KL to N(0, I) is at most ln n.
    BestOf(usize),
}

/// The learner of the run `cfg` names (its checkpoint, as last saved; the untrained learner
/// when there is none) evaluated on the run's pinned starts: `(env steps it was trained for,
/// per-episode results)` on `episodes` starts (`None`: the run's `eval_episodes`; episode k
/// starts from the same seed whatever the count). The sampled actor reproduces the run's
/// evaluation only for the first one (each later evaluation draws from its own streams).
pub fn evaluate_checkpoint(
    cfg: &RunConfig,
    noise: ActorNoise,
    episodes: Option<usize>,
) -> Result<(Option<u64>, Episodes)> {
    cfg.validate()?;
    let mut r = Runner::new(cfg)?;
    let trained = r.load_learner(&cfg.run_dir())?;
    Ok((trained, r.evaluate_actor(noise, episodes.unwrap_or(cfg.eval_episodes))?))
}
