//! Does a trained critic know which noise succeeds? The critic probe asks a run's learner about
//! the states of the steerability probe ([`equigym_wrappers::steerability::probe_with`]).
//!
//! At states along base rollouts, M random noises N(0, I) for the next chunk are each followed
//! by K base-policy continuations, which estimate P(success | s, w) and the discounted return
//! the runner's reward gives (terminate-on-success: minus one per primitive step until the first
//! success). The run's critic scores the same noises. Per state it reports the rank correlation
//! of the critic's Q with the Monte-Carlo estimates, and what the critic's own choice among the M
//! gains: the Monte-Carlo success of its argmax minus the state's mean. The critic's pick does not
//! see the continuations, so that gain is unbiased (unlike the best Monte-Carlo estimate's). The
//! actor's picks (its mean and samples) are probed too, as extra candidates with continuations
//! of their own. The same numbers for the run's untrained learner (its initial weights, the same
//! configuration) are the control.
//!
//! The Monte-Carlo estimates are themselves noisy; the split-half rank correlation of the
//! candidates' success rates (first K/2 continuations against the last) says how well any
//! scorer could agree with them at this K.
//!
//! Continuations run the base policy after the probed chunk, so the Monte-Carlo values are the
//! base policy's Q, where the critic learns its own actor's; for one chunk's choice that is the
//! comparison that says whether the critic ranks noises the right way round.

use serde::Serialize;
use std::sync::Mutex;

use equigym_wrappers::steerability::{mean_se, probe_with, Phase, ProbeConfig, ProbeReport, ProbedState, Rollout};
use equigym_wrappers::DEFAULT_LATENT_BOUND;

use super::{latent_env, RunConfig, Runner};
use crate::error::{Error, Result};
use crate::rng::{Rng, Stream};
use crate::sac::{argmax, normals, Sac};

/// Settings of [`critic_probe`].
#[derive(Clone, Debug, Serialize)]
pub struct CriticProbeConfig {
    pub probe: ProbeConfig,
    /// Samples of the stochastic actor probed at every state, beside its mean.
    pub actor_samples: usize,
}

/// One probed state, scored.
#[derive(Clone, Debug, Serialize)]
pub struct ScoredState {
    pub seed: u64,
    pub latent_step: usize,
    pub phase: Phase,
    /// Monte-Carlo success rate of each random candidate.
    pub success: Vec<f64>,
    /// Monte-Carlo discounted return of each random candidate (the runner's reward).
    pub mc_return: Vec<f64>,
    /// The trained and the untrained critic's min-Q of each random candidate.
    pub q_trained: Vec<f64>,
    pub q_untrained: Vec<f64>,
    /// Spearman correlations over the random candidates (`None` where either side is constant).
    pub rho_success: Option<f64>,
    pub rho_return: Option<f64>,
    pub rho_success_untrained: Option<f64>,
    /// Split-half Spearman correlation of the candidates' success rates.
    pub split_half: Option<f64>,
    /// Monte-Carlo success of the trained / untrained critic's argmax candidate.
    pub critic_pick: f64,
    pub critic_pick_untrained: f64,
    /// Monte-Carlo success of the actor's mean noise and of its samples (pooled).
    pub actor_mean: f64,
    pub actor_samples: f64,
    /// Trained critic's Q of the actor's mean, minus its mean Q over the random candidates.
    pub q_actor_mean_excess: f64,
    /// Mean success over the random candidates (the base policy's P(success | s)).
    pub mean: f64,
}

/// A mean with its standard error over states.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct MeanSe {
    pub mean: f64,
    pub se: f64,
    pub n: usize,
}

impl MeanSe {
    fn of(xs: impl IntoIterator<Item = f64>) -> Self {
        let v: Vec<f64> = xs.into_iter().filter(|x| x.is_finite()).collect();
        let (mean, se) = mean_se(&v);
        Self { mean, se, n: v.len() }
    }
}

/// What [`critic_probe`] found.
#[derive(Clone, Debug, Serialize)]
pub struct CriticProbeReport {
    pub config: CriticProbeConfig,
    /// Env steps the learner was trained for (`None`: no checkpoint, the untrained learner).
    pub trained_env_steps: Option<u64>,
    pub gamma: f64,
    pub states: Vec<ScoredState>,
    pub rho_success: MeanSe,
    pub rho_return: MeanSe,
    pub rho_success_untrained: MeanSe,
    pub split_half: MeanSe,
    /// Per-state gains over the state's mean success.
    pub critic_pick_gain: MeanSe,
    pub critic_pick_gain_untrained: MeanSe,
    pub actor_mean_gain: MeanSe,
    pub actor_samples_gain: MeanSe,
    /// The perfect chooser among the M, re-measured on fresh continuations (the probe's).
    pub best_fresh_gain: MeanSe,
    pub q_actor_mean_excess: MeanSe,
    /// The critic as a value function across states: each state's mean Q over the random
    /// noises beside its mean Monte-Carlo return (the base's value, in the learner's units).
    pub values: ValueFit,
    pub primitive_steps: usize,
}

/// Mean Q against mean Monte-Carlo return over states: their means, Pearson correlation and the
/// least-squares slope of Q on the return (1 for a calibrated critic of the base policy).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ValueFit {
    pub mean_q: f64,
    pub mean_return: f64,
    pub correlation: f64,
    pub slope: f64,
}

impl ValueFit {
    fn of(q: &[f64], g: &[f64]) -> Self {
        let n = q.len().max(1) as f64;
        let (mq, mg) = (q.iter().sum::<f64>() / n, g.iter().sum::<f64>() / n);
        let cov: f64 = q.iter().zip(g).map(|(a, b)| (a - mq) * (b - mg)).sum();
        let (vq, vg): (f64, f64) = (q.iter().map(|a| (a - mq).powi(2)).sum(), g.iter().map(|b| (b - mg).powi(2)).sum());
        Self { mean_q: mq, mean_return: mg, correlation: cov / (vq * vg).sqrt(), slope: cov / vg }
    }
}

/// Average ranks (ties share their mean rank).
fn ranks(x: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut r = vec![0.0; x.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        for &k in &idx[i..=j] {
            r[k] = (i + j) as f64 / 2.0;
        }
        i = j + 1;
    }
    r
}

/// Spearman's rank correlation (`None` when either side is constant).
pub fn spearman(a: &[f64], b: &[f64]) -> Option<f64> {
    let (ra, rb) = (ranks(a), ranks(b));
    let n = ra.len() as f64;
    let (ma, mb) = (ra.iter().sum::<f64>() / n, rb.iter().sum::<f64>() / n);
    let cov: f64 = ra.iter().zip(&rb).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = ra.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = rb.iter().map(|y| (y - mb).powi(2)).sum();
    (va > 0.0 && vb > 0.0).then(|| cov / (va * vb).sqrt())
}

/// The discounted return of one continuation under the runner's terminate-on-success reward:
/// minus one per primitive step before the first success, `chunk` steps per latent step.
fn discounted_return(r: &Rollout, chunk: usize, gamma: f64) -> f64 {
    let failing = if r.success { r.primitive_steps.saturating_sub(1) } else { r.primitive_steps };
    (0..failing).map(|i| -gamma.powi((i / chunk) as i32)).sum()
}

fn rate(rs: &[Rollout]) -> f64 {
    rs.iter().filter(|r| r.success).count() as f64 / rs.len().max(1) as f64
}

/// The critic's min-Q of `noises` (latent units) at observation `obs`: the noise is clipped to
/// the box and scaled to the actor's [-1, 1], as the runner stores it.
fn score(sac: &mut Sac<f32>, obs: &[f64], noises: &[Vec<f64>]) -> Vec<f64> {
    let b = DEFAULT_LATENT_BOUND;
    let o: Vec<f32> = noises.iter().flat_map(|_| obs.iter().map(|v| *v as f32)).collect();
    let a: Vec<f32> = noises.iter().flatten().map(|v| (v.clamp(-b, b) / b) as f32).collect();
    sac.min_q(&o, &a, noises.len()).iter().map(|q| *q as f64).collect()
}

/// Probe the learner of the run `cfg` names (its checkpoint; the untrained learner when there
/// is none) on the steerability probe's states. Runs on rayon's global pool.
pub fn critic_probe(cfg: &RunConfig, pc: &CriticProbeConfig) -> Result<CriticProbeReport> {
    if pc.probe.hold != 1 {
        return Err(Error::InvalidOption("the critic probe scores one chunk's noise: hold must be 1".into()));
    }
    let mut r = Runner::new(cfg)?;
    let untrained = r.sac.state();
    let trained_env_steps = r.load_learner(&cfg.run_dir())?;
    let chunk = r.policy.chunk_len;
    let dim = r.sac.latent_dim();
    let seed = cfg.seed;
    let policy = r.policy.clone();
    let make = || latent_env(cfg, &policy);
    let report: ProbeReport = {
        let sac = Mutex::new(&mut r.sac);
        let picks = |ep: u64, k: usize, obs: &[f64]| -> equigym_wrappers::Result<Vec<Vec<f64>>> {
            // (a panic elsewhere poisons the lock; the learner inside is still whole)
            let mut sac = sac.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            let rows = 1 + pc.actor_samples;
            let o: Vec<f32> = (0..rows).flat_map(|_| obs.iter().map(|v| *v as f32)).collect();
            let mut eps = vec![0.0f32; rows * dim];
            normals(&mut Rng::new(seed, Stream::Probe, ep * 1000 + k as u64), &mut eps[dim..]);
            let a = sac.act(&o, rows, &eps);
            Ok(a.chunks(dim).map(|row| row.iter().map(|v| *v as f64 * DEFAULT_LATENT_BOUND).collect()).collect())
        };
        probe_with(&pc.probe, &make, &picks)?
    };
    let m = pc.probe.candidates.max(2);
    let gamma = cfg.gamma();
    let mut states: Vec<ScoredState> =
        report.states.iter().map(|s| scored(s, m, chunk, gamma, cfg.reward_scale.unwrap_or(1.0))).collect();
    for (st, p) in states.iter_mut().zip(&report.states) {
        st.q_trained = score(&mut r.sac, &p.observation, &p.candidates[..m]);
        let actor_q = score(&mut r.sac, &p.observation, &p.candidates[m..m + 1])[0];
        st.q_actor_mean_excess = actor_q - st.q_trained.iter().sum::<f64>() / m as f64;
    }
    r.sac.set_state(untrained).map_err(Error::InvalidOption)?;
    for (st, p) in states.iter_mut().zip(&report.states) {
        st.q_untrained = score(&mut r.sac, &p.observation, &p.candidates[..m]);
    }
    for st in &mut states {
        st.rho_success = spearman(&st.q_trained, &st.success);
        st.rho_return = spearman(&st.q_trained, &st.mc_return);
        st.rho_success_untrained = spearman(&st.q_untrained, &st.success);
        st.critic_pick = st.success[argmax(&st.q_trained)];
        st.critic_pick_untrained = st.success[argmax(&st.q_untrained)];
    }
    let of = |f: &dyn Fn(&ScoredState) -> Option<f64>| MeanSe::of(states.iter().filter_map(f));
    Ok(CriticProbeReport {
        config: pc.clone(),
        trained_env_steps,
        gamma,
        rho_success: of(&|s| s.rho_success),
        rho_return: of(&|s| s.rho_return),
        rho_success_untrained: of(&|s| s.rho_success_untrained),
        split_half: of(&|s| s.split_half),
        critic_pick_gain: of(&|s| Some(s.critic_pick - s.mean)),
        critic_pick_gain_untrained: of(&|s| Some(s.critic_pick_untrained - s.mean)),
        actor_mean_gain: of(&|s| Some(s.actor_mean - s.mean)),
        actor_samples_gain: of(&|s| Some(s.actor_samples - s.mean)),
        best_fresh_gain: MeanSe::of(report.states.iter().map(|s| s.best_holdout.rate - s.mean)),
        q_actor_mean_excess: of(&|s| Some(s.q_actor_mean_excess)),
        values: {
            let avg = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
            let q: Vec<f64> = states.iter().map(|s| avg(&s.q_trained)).collect();
            let g: Vec<f64> = states.iter().map(|s| avg(&s.mc_return)).collect();
            ValueFit::of(&q, &g)
        },
        primitive_steps: report.primitive_steps,
        states,
    })
}

/// The Monte-Carlo side of one state (the critics' fields are filled in after).
/// Returns are in the learner's units (times the run's reward scale), so that they read beside Q.
fn scored(p: &ProbedState, m: usize, chunk: usize, gamma: f64, scale: f64) -> ScoredState {
    let random = &p.continuations[..m];
    let success: Vec<f64> = random.iter().map(|rs| rate(rs)).collect();
    let mc_return = random
        .iter()
        .map(|rs| scale * rs.iter().map(|r| discounted_return(r, chunk, gamma)).sum::<f64>() / rs.len().max(1) as f64)
        .collect();
    let half = |lo: bool| -> Vec<f64> {
        random
            .iter()
            .map(|rs| {
                let h = rs.len() / 2;
                rate(if lo { &rs[..h] } else { &rs[h..] })
            })
            .collect()
    };
    let samples: Vec<Rollout> = p.continuations[m + 1..].iter().flatten().copied().collect();
    ScoredState {
        seed: p.seed,
        latent_step: p.latent_step,
        phase: p.phase,
        mean: p.mean,
        split_half: spearman(&half(true), &half(false)),
        actor_mean: rate(&p.continuations[m]),
        actor_samples: if samples.is_empty() { f64::NAN } else { rate(&samples) },
        success,
        mc_return,
        q_trained: Vec::new(),
        q_untrained: Vec::new(),
        rho_success: None,
        rho_return: None,
        rho_success_untrained: None,
        critic_pick: f64::NAN,
        critic_pick_untrained: f64::NAN,
        q_actor_mean_excess: f64::NAN,
    }
}

impl CriticProbeReport {
    /// The report as Markdown, headed by the command that made it.
    pub fn markdown(&self, command: &str) -> String {
        let f = |x: &MeanSe| format!("{:+.3} +- {:.3} ({} states)", x.mean, x.se, x.n);
        let c = &self.config.probe;
        let trained = self.trained_env_steps.map_or("untrained (no checkpoint)".into(), |s| format!("{s} env steps"));
        let mut md = format!(
            "# Critic probe\n\nMade by `{command}` (module `equigym_agents::run::probe`).\n\n\
             Learner: {trained}. States along base rollouts of {} starts (seeds {}..) at latent steps {:?}; \
             at each, {} random noises N(0, I) for the next chunk and the actor's mean and {} samples, each followed by {} \
             base continuations ({} primitive steps). Returns: the runner's terminate-on-success reward, gamma {}.\n\n\
             | measure | trained | untrained (control) |\n|---|---|---|\n",
            c.starts,
            c.first_seed,
            c.at_latent_steps,
            c.candidates,
            self.config.actor_samples,
            c.continuations,
            self.primitive_steps,
            self.gamma
        );
        md += &format!(
            "| Spearman(Q, MC success) over the random noises, mean over states | {} | {} |\n",
            f(&self.rho_success),
            f(&self.rho_success_untrained)
        );
        md += &format!("| Spearman(Q, MC return) | {} | |\n", f(&self.rho_return));
        md += &format!(
            "| split-half Spearman of the MC success rates (what any scorer can reach at this K) | {} | |\n",
            f(&self.split_half)
        );
        md += &format!(
            "| MC success of the critic's argmax minus the state's mean | {} | {} |\n",
            f(&self.critic_pick_gain),
            f(&self.critic_pick_gain_untrained)
        );
        md += &format!(
            "| perfect chooser among the same noises, fresh continuations | {} | |\n",
            f(&self.best_fresh_gain)
        );
        md += &format!(
            "| MC success of the actor's mean noise minus the state's mean | {} | |\n",
            f(&self.actor_mean_gain)
        );
        md += &format!(
            "| MC success of the actor's samples minus the state's mean | {} | |\n",
            f(&self.actor_samples_gain)
        );
        md += &format!(
            "| critic's Q of the actor's mean minus its mean Q of the random noises | {} | |\n",
            f(&self.q_actor_mean_excess)
        );
        let v = &self.values;
        md += &format!(
            "\nAs a value function across states (each state's mean Q over the random noises against its mean MC \
             return under the base, in the learner's units): mean Q {:.1}, mean return {:.1}, correlation {:+.2}, \
             slope of Q on the return {:.3} (a calibrated critic of the base: 1).\n",
            v.mean_q, v.mean_return, v.correlation, v.slope
        );
        md += "\n| seed | latent step | phase | MC success per noise | Q (trained) | rho | critic pick | actor mean | actor samples |\n\
               |---|---:|---|---|---|---:|---:|---:|---:|\n";
        for s in &self.states {
            let v = |x: &[f64], d: usize| x.iter().map(|v| format!("{v:.d$}")).collect::<Vec<_>>().join(", ");
            md += &format!(
                "| {} | {} | {} | [{}] | [{}] | {} | {:.2} | {:.2} | {:.2} |\n",
                s.seed,
                s.latent_step,
                s.phase.name(),
                v(&s.success, 1),
                v(&s.q_trained, 1),
                s.rho_success.map_or("-".into(), |r| format!("{r:+.2}")),
                s.critic_pick,
                s.actor_mean,
                s.actor_samples
            );
        }
        md
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spearman_ranks_with_ties() {
        assert_eq!(spearman(&[1.0, 2.0, 3.0], &[10.0, 20.0, 30.0]), Some(1.0));
        assert_eq!(spearman(&[1.0, 2.0, 3.0], &[3.0, 2.0, 1.0]), Some(-1.0));
        assert_eq!(spearman(&[1.0, 1.0, 1.0], &[3.0, 2.0, 1.0]), None);
        // ties share their mean rank: ranks (0.5, 0.5, 2) against (0, 1, 2)
        let r = spearman(&[5.0, 5.0, 7.0], &[1.0, 2.0, 3.0]).unwrap();
        assert!((r - 0.866_025_403_784_438_6).abs() < 1e-12, "{r}");
    }

    #[test]
    fn the_return_counts_failing_steps_discounted_per_chunk() {
        let r = |success, primitive_steps| Rollout { success, outcome: None, primitive_steps, first_success: None };
        // success at the 1st step: no failing step
        assert_eq!(discounted_return(&r(true, 1), 4, 0.9), 0.0);
        // 5 failing steps in chunks of 4: -4 - 0.9
        assert!((discounted_return(&r(true, 6), 4, 0.9) + 4.9).abs() < 1e-12);
        assert!((discounted_return(&r(false, 8), 4, 0.5) + 6.0).abs() < 1e-12);
    }
}
