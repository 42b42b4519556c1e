//! Soft actor-critic as DSRL runs it (Stable-Baselines3's `SAC.train`, step for step): twin
//! critics with a min backup, Polyak-averaged targets, an entropy coefficient learned towards the
//! target entropy, Adam everywhere.
//!
//! One gradient step, in SB3's order:
//! 1. sample a minibatch; the actor samples `a ~ pi(.|s)` with its log-probability;
//! 2. entropy coefficient `alpha = exp(log_alpha)` (the value before this step's update) and its
//!    loss `-log_alpha * mean(log pi + target_entropy)`, one Adam step;
//! 3. target `y = r + gamma (1 - terminated) (min_k Q'_k(s', a') - alpha log pi(a'|s'))`,
//!    `a' ~ pi(.|s')`;
//! 4. critic loss `0.5 sum_k mean (Q_k(s, a) - y)^2`, one Adam step per critic;
//! 5. actor loss `mean(alpha log pi(a|s) - min_k Q_k(s, a))` through the *updated* critics, one
//!    Adam step;
//! 6. targets `Q' <- (1 - tau) Q' + tau Q`.

use equigym_nn::{Adam, AdamConfig, Real};
use serde::{Deserialize, Serialize};

use crate::models::{Models, PolicyHead};
use crate::net::{Net, Tape};
use crate::replay::Batch;
use crate::rng::Rng;

/// SAC hyperparameters (DSRL's and `baselines/steer.py`'s).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SacConfig {
    pub lr: f64,
    pub gamma: f64,
    pub tau: f64,
    pub target_entropy: f64,
    pub ent_init: f64,
}

/// A squashed Gaussian sample of the actor with what its backward pass needs.
#[derive(Clone, Debug, Default)]
pub struct ActorSample<T> {
    pub rows: usize,
    pub tape: Tape<T>,
    pub eps: Vec<T>,
    pub u: Vec<T>,
    pub a: Vec<T>,
    pub std: Vec<T>,
    pub logp: Vec<T>,
}

/// Fill `out` with standard normal draws (f64 Box-Muller, rounded).
pub fn normals<T: Real>(rng: &mut Rng, out: &mut [T]) {
    for v in out {
        *v = T::from_f64(rng.normal());
    }
}

impl PolicyHead {
    /// Forward the actor on `obs` (rows x obs_dim) with noise `eps` (rows x dim).
    pub fn sample<T: Real>(&self, actor: &Net<T>, obs: &[T], rows: usize, eps: &[T], s: &mut ActorSample<T>) {
        let d = self.dim;
        actor.forward(obs, rows, &mut s.tape);
        s.rows = rows;
        s.eps.clear();
        s.eps.extend_from_slice(&eps[..rows * d]);
        s.u.resize(rows * d, T::ZERO);
        s.a.resize(rows * d, T::ZERO);
        s.std.resize(rows * d, T::ZERO);
        s.logp.resize(rows, T::ZERO);
        let (lo, hi) = (T::from_f64(self.log_std_range.0), T::from_f64(self.log_std_range.1));
        let half_log_2pi = T::from_f64(0.5 * (2.0 * std::f64::consts::PI).ln());
        let half = T::from_f64(0.5);
        let out = s.tape.output();
        let width = actor.n_out;
        for r in 0..rows {
            let o = &out[r * width..(r + 1) * width];
            let mut lp = T::ZERO;
            for i in 0..d {
                let ls = o[self.log_std_index[i]].max(lo).min(hi);
                let std = ls.exp();
                let e = s.eps[r * d + i];
                s.std[r * d + i] = std;
                s.u[r * d + i] = std * e + o[i];
                lp += -(half * e * e) - ls - half_log_2pi;
            }
            let logdet = self.squash.forward(&s.u[r * d..(r + 1) * d], &mut s.a[r * d..(r + 1) * d]);
            s.logp[r] = lp - logdet;
        }
    }

    /// Backward of a sample: `ga` = dL/da (rows x dim), `glogp` = dL/dlog pi per row; adds the
    /// actor's parameter gradients into `grads`.
    pub fn sample_backward<T: Real>(
        &self,
        actor: &Net<T>,
        s: &ActorSample<T>,
        ga: &[T],
        glogp: &[T],
        grads: &mut [T],
        scratch: &mut Vec<T>,
    ) {
        let (d, rows, width) = (self.dim, s.rows, actor.n_out);
        let out = s.tape.output();
        let mut dout = vec![T::ZERO; rows * width];
        let mut gu = vec![T::ZERO; d];
        let (lo, hi) = (T::from_f64(self.log_std_range.0), T::from_f64(self.log_std_range.1));
        for r in 0..rows {
            let sl = r * d..(r + 1) * d;
            self.squash.backward(&s.u[sl.clone()], &s.a[sl.clone()], &ga[sl.clone()], -glogp[r], &mut gu);
            let o = &out[r * width..(r + 1) * width];
            let dr = &mut dout[r * width..(r + 1) * width];
            for i in 0..d {
                dr[i] += gu[i];
                let raw = o[self.log_std_index[i]];
                if raw >= lo && raw <= hi {
                    // u = mean + exp(ls) eps; the Gaussian term of log pi is -ls per dimension.
                    dr[self.log_std_index[i]] += gu[i] * s.std[r * d + i] * s.eps[r * d + i] - glogp[r];
                }
            }
        }
        actor.backward(&s.tape, &dout, Some(grads), false, scratch);
    }
}

/// The soft target `y = r + gamma (1 - terminated) (min_k Q'_k(s', a') - alpha log pi(a'|s'))`,
/// with `a'` the actor's sample for noise `eps` (kept in `s2`).
#[allow(clippy::too_many_arguments)]
pub fn soft_target<T: Real>(
    head: &PolicyHead,
    actor: &Net<T>,
    targets: &[Net<T>; 2],
    batch: &Batch<T>,
    eps: &[T],
    alpha: T,
    gamma: T,
    s2: &mut ActorSample<T>,
) -> Vec<T> {
    let (b, ad) = (batch.rows, head.dim);
    let od = batch.obs.len() / b.max(1);
    head.sample(actor, &batch.next_obs, b, eps, s2);
    let mut x = Vec::new();
    concat_rows(&batch.next_obs, od, &s2.a, ad, b, &mut x);
    let mut tape = Tape::default();
    let mut next_q = vec![T::ZERO; b];
    for (k, t) in targets.iter().enumerate() {
        t.forward(&x, b, &mut tape);
        for (q, v) in next_q.iter_mut().zip(tape.output()) {
            *q = if k == 0 { *v } else { q.min(*v) };
        }
    }
    (0..b).map(|r| batch.reward[r] + (T::ONE - batch.done[r]) * gamma * (next_q[r] - alpha * s2.logp[r])).collect()
}

/// One critic's loss `0.5 mean_r (Q(x_r) - y_r)^2` (the SB3 critic loss is the sum over the
/// twins); its parameter gradient is added into `grads`.
pub fn critic_loss_grad<T: Real>(
    critic: &Net<T>,
    x: &[T],
    y: &[T],
    grads: &mut [T],
    tape: &mut Tape<T>,
    scratch: &mut Vec<T>,
) -> f64 {
    let b = y.len();
    let inv_b = T::from_f64(1.0 / b as f64);
    critic.forward(x, b, tape);
    let q = tape.output();
    let dq: Vec<T> = q.iter().zip(y).map(|(q, y)| (*q - *y) * inv_b).collect();
    let loss = q.iter().zip(y).map(|(q, y)| 0.5 * (q.to_f64() - y.to_f64()).powi(2)).sum::<f64>() / b as f64;
    critic.backward(tape, &dq, Some(grads), false, scratch);
    loss
}

/// The actor loss `mean_r(alpha log pi(a_r|s_r) - min_k Q_k(s_r, a_r))` for the sample `s1`
/// (taken at `obs`); its gradient with respect to the actor's parameters is added into `grads`.
#[allow(clippy::too_many_arguments)]
pub fn actor_loss_grad<T: Real>(
    head: &PolicyHead,
    actor: &Net<T>,
    critics: &[Net<T>; 2],
    obs: &[T],
    s1: &ActorSample<T>,
    alpha: T,
    grads: &mut [T],
    scratch: &mut Vec<T>,
) -> f64 {
    let (b, ad) = (s1.rows, head.dim);
    let od = actor.n_in;
    let inv_b = T::from_f64(1.0 / b as f64);
    let mut x = Vec::new();
    concat_rows(obs, od, &s1.a, ad, b, &mut x);
    let mut tapes = [Tape::default(), Tape::default()];
    for k in 0..2 {
        critics[k].forward(&x, b, &mut tapes[k]);
    }
    let (q0, q1) = (tapes[0].output(), tapes[1].output());
    let mut loss = 0.0;
    let mut dsel = [vec![T::ZERO; b], vec![T::ZERO; b]];
    for r in 0..b {
        // torch.min over the twins: the gradient goes to the first minimum
        let k = if q0[r] <= q1[r] { 0 } else { 1 };
        dsel[k][r] = -inv_b;
        loss += (alpha.to_f64() * s1.logp[r].to_f64() - q0[r].min(q1[r]).to_f64()) / b as f64;
    }
    let mut ga = vec![T::ZERO; b * ad];
    for k in 0..2 {
        if let Some(dx) = critics[k].backward(&tapes[k], &dsel[k], None, true, scratch) {
            for r in 0..b {
                for i in 0..ad {
                    ga[r * ad + i] += dx[r * (od + ad) + od + i];
                }
            }
        }
    }
    let glogp = vec![alpha * inv_b; b];
    head.sample_backward(actor, s1, &ga, &glogp, grads, scratch);
    loss
}

/// The entropy-coefficient loss `-log_alpha mean(log pi + target_entropy)` and its gradient.
pub fn alpha_loss_grad<T: Real>(log_alpha: T, logp: &[T], target_entropy: f64) -> (f64, T) {
    let mut mean = T::ZERO;
    for lp in logp {
        mean += *lp + T::from_f64(target_entropy);
    }
    mean *= T::from_f64(1.0 / logp.len().max(1) as f64);
    ((-(log_alpha * mean)).to_f64(), -mean)
}

/// The SAC learner: networks, targets, optimisers, entropy coefficient.
pub struct Sac<T> {
    pub config: SacConfig,
    pub head: PolicyHead,
    pub actor: Net<T>,
    pub critics: [Net<T>; 2],
    pub targets: [Net<T>; 2],
    pub log_alpha: T,
    pub opt_actor: Adam<T>,
    pub opt_critics: [Adam<T>; 2],
    pub opt_alpha: Adam<T>,
    pub obs_dim: usize,
    scratch: Scratch<T>,
}

#[derive(Default)]
struct Scratch<T> {
    s1: ActorSample<T>,
    s2: ActorSample<T>,
    tape: Tape<T>,
    tapes: [Tape<T>; 2],
    x: Vec<T>,
    grads: Vec<T>,
    lin: Vec<T>,
    eps: Vec<T>,
}

/// What one gradient step reports (for tests and logs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    pub critic_loss: f64,
    pub actor_loss: f64,
    pub alpha: f64,
    pub alpha_loss: f64,
}

/// Concatenate obs (rows x od) and actions (rows x ad) row by row.
pub fn concat_rows<T: Real>(obs: &[T], od: usize, act: &[T], ad: usize, rows: usize, out: &mut Vec<T>) {
    out.clear();
    for r in 0..rows {
        out.extend_from_slice(&obs[r * od..(r + 1) * od]);
        out.extend_from_slice(&act[r * ad..(r + 1) * ad]);
    }
}

/// Optimiser segments of a net (its weight-decay groups).
fn adam_for<T: Real>(net: &Net<T>, lr: f64) -> Adam<T> {
    Adam::new(AdamConfig::new(lr), net.num_params(), net.decay.clone())
}

impl<T: Real> Sac<T> {
    pub fn new(models: Models<T>, obs_dim: usize, config: SacConfig) -> Self {
        let Models { actor, critics, head, .. } = models;
        let targets = critics.clone();
        let opt_actor = adam_for(&actor, config.lr);
        let opt_critics = [adam_for(&critics[0], config.lr), adam_for(&critics[1], config.lr)];
        let opt_alpha = Adam::new(AdamConfig::new(config.lr), 1, Vec::new());
        Self {
            log_alpha: T::from_f64(config.ent_init.ln()),
            config,
            head,
            actor,
            critics,
            targets,
            opt_actor,
            opt_critics,
            opt_alpha,
            obs_dim,
            scratch: Scratch::default(),
        }
    }

    pub fn latent_dim(&self) -> usize {
        self.head.dim
    }

    /// Actions of the stochastic actor for `rows` observations with noise `eps` (in [-1, 1]).
    pub fn act(&mut self, obs: &[T], rows: usize, eps: &[T]) -> Vec<T> {
        let s = &mut self.scratch.s1;
        self.head.sample(&self.actor, obs, rows, eps, s);
        s.a.clone()
    }

    /// min_k Q_k(s, a) per row.
    pub fn min_q(&mut self, obs: &[T], act: &[T], rows: usize) -> Vec<T> {
        let (od, ad) = (self.obs_dim, self.head.dim);
        concat_rows(obs, od, act, ad, rows, &mut self.scratch.x);
        let mut q = vec![T::ZERO; rows];
        for (k, c) in self.critics.iter().enumerate() {
            c.forward(&self.scratch.x, rows, &mut self.scratch.tape);
            for (qi, v) in q.iter_mut().zip(self.scratch.tape.output()) {
                *qi = if k == 0 { *v } else { qi.min(*v) };
            }
        }
        q
    }

    /// One gradient step on a minibatch (see the module docs); `rng` is the training stream.
    pub fn train_step(&mut self, batch: &Batch<T>, rng: &mut Rng) -> StepStats {
        let (od, ad, b) = (self.obs_dim, self.head.dim, batch.rows);
        let sc = &mut self.scratch;
        // 1. a ~ pi(.|s)
        sc.eps.resize(b * ad, T::ZERO);
        normals(rng, &mut sc.eps);
        self.head.sample(&self.actor, &batch.obs, b, &sc.eps, &mut sc.s1);
        // 2. entropy coefficient
        let alpha = self.log_alpha.exp();
        let (alpha_loss, g_alpha) = alpha_loss_grad(self.log_alpha, &sc.s1.logp, self.config.target_entropy);
        let mut la = [self.log_alpha];
        self.opt_alpha.update(&mut la, &[g_alpha]);
        self.log_alpha = la[0];
        // 3. target
        normals(rng, &mut sc.eps);
        let y = soft_target(
            &self.head,
            &self.actor,
            &self.targets,
            batch,
            &sc.eps,
            alpha,
            T::from_f64(self.config.gamma),
            &mut sc.s2,
        );
        // 4. critics
        concat_rows(&batch.obs, od, &batch.act, ad, b, &mut sc.x);
        let mut critic_loss = 0.0;
        for k in 0..2 {
            let c = &mut self.critics[k];
            sc.grads.clear();
            sc.grads.resize(c.num_params(), T::ZERO);
            critic_loss += critic_loss_grad(c, &sc.x, &y, &mut sc.grads, &mut sc.tapes[k], &mut sc.lin);
            self.opt_critics[k].update(&mut c.params, &sc.grads);
            c.expand();
        }
        // 5. actor through the updated critics
        sc.grads.clear();
        sc.grads.resize(self.actor.num_params(), T::ZERO);
        let actor_loss = actor_loss_grad(
            &self.head,
            &self.actor,
            &self.critics,
            &batch.obs,
            &sc.s1,
            alpha,
            &mut sc.grads,
            &mut sc.lin,
        );
        self.opt_actor.update(&mut self.actor.params, &sc.grads);
        self.actor.expand();
        // 6. Polyak
        let tau = T::from_f64(self.config.tau);
        let keep = T::from_f64(1.0 - self.config.tau);
        for (t, c) in self.targets.iter_mut().zip(&self.critics) {
            for (tp, cp) in t.params.iter_mut().zip(&c.params) {
                *tp = *tp * keep + *cp * tau;
            }
            t.expand();
        }
        StepStats { critic_loss, actor_loss, alpha: alpha.to_f64(), alpha_loss: alpha_loss.to_f64() }
    }
}
