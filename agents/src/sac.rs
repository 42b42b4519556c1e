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
//!
//! The noise-aliased variant (DSRL-NA, [`Sac::train_step_aliased`]) learns the value of the
//! action chunk instead of the noise: the map from actions to outcomes is smooth where the map
//! from noise to outcomes is not (docs/steering.md, "Steerability"), and many noises alias one
//! chunk. Its step:
//! 1. and 2. as above;
//! 3. target `y = r + gamma (1 - terminated) (min_k Q^A'_k(s', D(s', w')) - alpha log pi(w'|s'))`,
//!    `w' ~ pi(.|s')`, `D` the diffusion policy's (normalised) chunk;
//! 4. action-critic loss `0.5 sum_k mean (Q^A_k(s, a) - y)^2` at the executed chunk `a`;
//! 5. distillation: the noise critics regress `min_k Q^A_k(s, D(s, w))` (updated critics) at
//!    `w ~ N(0, I)` clipped to the latent box, `0.5 sum_k mean (Q^W_k(s, w) - q)^2`;
//! 6. actor loss as in 5. above, through the noise critics;
//! 7. Polyak for the action critics' targets (and for the noise critics' targets, read only by
//!    the learner diagnostics).
//!
//! The selecting variant ([`Sac::train_step_select`], `--select N`) has no actor: its policy is
//! the best of N fresh candidates from the EDP's own noise N(0, I) by min-Q ([`Sac::select`]),
//! so every chosen noise is one the EDP was trained on, and its critics learn that policy's
//! value (targets over the same best-of-N choice at the next state). SAC's actor moves the
//! noise off N(0, I) as a smooth function of the state, which this EDP punishes
//! (docs/steering.md, "Does the critic know which noise succeeds?"); selection tests whether a
//! critic alone, used only to rank the base's own candidates, can steer.

use equigym_nn::{Adam, AdamConfig, Real};
use serde::{Deserialize, Serialize};

use crate::models::{Models, PolicyHead};
use crate::net::{Net, Tape, Workspace};
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
    /// Regularise towards the diffusion policy's own noise instead of towards high entropy
    /// (`None`: SAC's entropy term with `target_entropy`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior: Option<NoisePrior>,
}

impl SacConfig {
    /// What the entropy coefficient's loss compares `log pi` (or `log pi - log p`) against.
    fn alpha_target(&self) -> f64 {
        self.prior.map_or(self.target_entropy, |p| -p.target_kl)
    }
}

/// KL regularisation towards the noise the diffusion policy was trained on, `N(0, I)` over the
/// latent (restricted to the latent box), in place of SAC's entropy bonus: every `log pi(a|s)` of
/// the soft targets, the actor loss and the coefficient's loss becomes `log pi(a|s) - log p(a)`,
/// a one-sample estimate of `KL(pi(.|s) || p)`, and `alpha` is tuned to hold its mean at
/// `target_kl`. The optimal actor is then `pi(w|s) ~ p(w) exp(Q(s, w) / alpha)`: a reweighting of
/// the base policy's own noise by the critic, rather than a distribution that only has to be
/// wide. An entropy target constrains the width but not the centre (entropy does not change when
/// the mean moves), so SAC's actor may drift wherever the critic's errors point, into noise the
/// EDP was never trained on; the prior charges for both (docs/steering.md).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoisePrior {
    /// Half-width of the latent box: the environment receives `bound * a`.
    pub bound: f64,
    /// KL budget in nats.
    pub target_kl: f64,
}

impl NoisePrior {
    /// Each row's `log pi(a|s)` in `s` becomes `log pi(a|s) - log p(a)`, with `p` the density of
    /// `a = w / bound`, `w ~ N(0, I)` restricted to the box:
    /// `-log p(a) = bound^2 |a|^2 / 2 + const` ([`crate::models::Squash::prior_log_norm`]).
    pub fn apply<T: Real>(&self, head: &PolicyHead, s: &mut ActorSample<T>) {
        let d = head.dim;
        let c = T::from_f64(head.squash.prior_log_norm(d, self.bound));
        let k = T::from_f64(0.5 * self.bound * self.bound);
        for (lp, a) in s.logp.iter_mut().zip(s.a.chunks_exact(d.max(1))) {
            let mut sq = T::ZERO;
            for v in a {
                sq += *v * *v;
            }
            *lp += k * sq + c;
        }
    }

    /// `d(-log p)/da = bound^2 a`, scaled by `g` per row, added into `ga`.
    fn add_grad<T: Real>(&self, a: &[T], g: &[T], d: usize, ga: &mut [T]) {
        let k = T::from_f64(self.bound * self.bound);
        for (r, gr) in g.iter().enumerate() {
            for i in r * d..(r + 1) * d {
                ga[i] += *gr * k * a[i];
            }
        }
    }
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
    /// Each row's squash log-determinant, and a buffer for computing it.
    logdet: Vec<T>,
    scratch: Vec<T>,
}

/// Buffers the SAC losses reuse from call to call, so that a gradient step allocates no
/// activation buffers once warm (see [`Workspace`]).
#[derive(Clone, Debug, Default)]
pub struct Buffers<T> {
    ws: Workspace<T>,
    tapes: [Tape<T>; 2],
    x: Vec<T>,
    dout: Vec<T>,
    gu: Vec<T>,
    dsel: [Vec<T>; 2],
    ga: Vec<T>,
    next_q: Vec<T>,
    dq: Vec<T>,
    glogp: Vec<T>,
}

/// Fill `out` with standard normal draws (f64 Box-Muller, rounded).
pub fn normals<T: Real>(rng: &mut Rng, out: &mut [T]) {
    rng.fill_normal(out);
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
        let half_log_2pi = T::from_f64(0.5 * libm::log(2.0 * std::f64::consts::PI));
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
            s.logp[r] = lp;
        }
        s.logdet.resize(rows, T::ZERO);
        self.squash.forward_rows(&s.u, &mut s.a, d, &mut s.logdet, &mut s.scratch);
        for (lp, ld) in s.logp.iter_mut().zip(&s.logdet) {
            *lp = *lp - *ld;
        }
    }

    /// Backward of a sample: `ga` = dL/da (rows x dim), `glogp` = dL/dlog pi per row; adds the
    /// actor's parameter gradients into `grads` (`dout`, `gu` and `ws` are reused buffers).
    #[allow(clippy::too_many_arguments)]
    pub fn sample_backward<T: Real>(
        &self,
        actor: &Net<T>,
        s: &ActorSample<T>,
        ga: &[T],
        glogp: &[T],
        grads: &mut [T],
        dout: &mut Vec<T>,
        gu: &mut Vec<T>,
        ws: &mut Workspace<T>,
    ) {
        let (d, rows, width) = (self.dim, s.rows, actor.n_out);
        let out = s.tape.output();
        dout.clear();
        dout.resize(rows * width, T::ZERO);
        gu.clear();
        gu.resize(d, T::ZERO);
        let (lo, hi) = (T::from_f64(self.log_std_range.0), T::from_f64(self.log_std_range.1));
        for r in 0..rows {
            let sl = r * d..(r + 1) * d;
            self.squash.backward(&s.u[sl.clone()], &s.a[sl.clone()], &ga[sl.clone()], -glogp[r], gu);
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
        actor.backward(&s.tape, dout, Some(grads), false, ws);
    }
}

/// The soft target `y = r + gamma (1 - terminated) (min_k Q'_k(s', a') - alpha log pi(a'|s'))`,
/// with `a'` the actor's sample for noise `eps` (kept in `s2`; with a `prior`, `log pi - log p`),
/// into `y`.
#[allow(clippy::too_many_arguments)]
pub fn soft_target<T: Real>(
    head: &PolicyHead,
    actor: &Net<T>,
    targets: &[Net<T>; 2],
    batch: &Batch<T>,
    eps: &[T],
    alpha: T,
    gamma: T,
    prior: Option<&NoisePrior>,
    s2: &mut ActorSample<T>,
    buf: &mut Buffers<T>,
    y: &mut Vec<T>,
) {
    let (b, ad) = (batch.rows, head.dim);
    let od = batch.obs.len() / b.max(1);
    sample_policy(head, actor, prior, &batch.next_obs, b, eps, s2);
    min_over(targets, &batch.next_obs, od, &s2.a, ad, b, &mut buf.x, &mut buf.tapes[0], &mut buf.next_q);
    soft_values(batch, gamma, &buf.next_q, alpha, &s2.logp, y);
}

/// The actor's reparameterised sample for noise `eps` at `rows` observations, into `s`; with a
/// `prior`, its `log pi` becomes `log pi - log p`.
fn sample_policy<T: Real>(
    head: &PolicyHead,
    actor: &Net<T>,
    prior: Option<&NoisePrior>,
    obs: &[T],
    rows: usize,
    eps: &[T],
    s: &mut ActorSample<T>,
) {
    head.sample(actor, obs, rows, eps, s);
    if let Some(p) = prior {
        p.apply(head, s);
    }
}

/// `y_r = r_r + gamma (1 - terminated_r) (next_q_r - alpha log pi_r)`, into `y`.
fn soft_values<T: Real>(batch: &Batch<T>, gamma: T, next_q: &[T], alpha: T, logp: &[T], y: &mut Vec<T>) {
    y.clear();
    y.extend(
        (0..batch.rows).map(|r| batch.reward[r] + (T::ONE - batch.done[r]) * gamma * (next_q[r] - alpha * logp[r])),
    );
}

/// One Adam step of each twin critic on `0.5 mean (Q_k(x) - y)^2`; returns the sum of the two
/// losses (SB3's critic loss). `grads` and `buf` are reused buffers.
fn fit_twins<T: Real>(
    critics: &mut [Net<T>; 2],
    opts: &mut [Adam<T>; 2],
    x: &[T],
    y: &[T],
    grads: &mut Vec<T>,
    buf: &mut Buffers<T>,
) -> f64 {
    let mut loss = 0.0;
    for (c, opt) in critics.iter_mut().zip(opts.iter_mut()) {
        grads.clear();
        grads.resize(c.num_params(), T::ZERO);
        loss += critic_loss_grad(c, x, y, grads, buf);
        opt.update(&mut c.params, grads);
        c.expand();
    }
    loss
}

/// One Adam step of the entropy coefficient; returns `alpha` before the step and the loss.
fn step_alpha<T: Real>(log_alpha: &mut T, opt: &mut Adam<T>, logp: &[T], target_entropy: f64) -> (T, f64) {
    let alpha = log_alpha.exp();
    let (loss, grad) = alpha_loss_grad(*log_alpha, logp, target_entropy);
    let mut la = [*log_alpha];
    opt.update(&mut la, &[grad]);
    *log_alpha = la[0];
    (alpha, loss)
}

/// One critic's loss `0.5 mean_r (Q(x_r) - y_r)^2` (the SB3 critic loss is the sum over the
/// twins), forward only; the critic's outputs stay on `tape`.
pub fn critic_loss<T: Real>(critic: &Net<T>, x: &[T], y: &[T], tape: &mut Tape<T>) -> f64 {
    let b = y.len();
    critic.forward(x, b, tape);
    tape.output().iter().zip(y).map(|(q, y)| 0.5 * (q.to_f64() - y.to_f64()).powi(2)).sum::<f64>() / b as f64
}

/// [`critic_loss`], its parameter gradient added into `grads`.
pub fn critic_loss_grad<T: Real>(critic: &Net<T>, x: &[T], y: &[T], grads: &mut [T], buf: &mut Buffers<T>) -> f64 {
    let inv_b = T::from_f64(1.0 / y.len() as f64);
    let tape = &mut buf.tapes[0];
    let loss = critic_loss(critic, x, y, tape);
    buf.dq.clear();
    buf.dq.extend(tape.output().iter().zip(y).map(|(q, y)| (*q - *y) * inv_b));
    critic.backward(tape, &buf.dq, Some(grads), false, &mut buf.ws);
    loss
}

/// The actor loss `mean_r(alpha log pi(a_r|s_r) - min_k Q_k(s_r, a_r))` for the sample `s1`
/// (taken at `obs`; with a `prior`, `s1.logp` already holds `log pi - log p`); its gradient with
/// respect to the actor's parameters is added into `grads`.
#[allow(clippy::too_many_arguments)]
pub fn actor_loss_grad<T: Real>(
    head: &PolicyHead,
    actor: &Net<T>,
    critics: &[Net<T>; 2],
    obs: &[T],
    s1: &ActorSample<T>,
    alpha: T,
    prior: Option<&NoisePrior>,
    grads: &mut [T],
    buf: &mut Buffers<T>,
) -> f64 {
    let (b, ad) = (s1.rows, head.dim);
    let od = actor.n_in;
    let inv_b = T::from_f64(1.0 / b as f64);
    let Buffers { ws, tapes, x, dout, gu, dsel, ga, glogp, .. } = buf;
    concat_rows(obs, od, &s1.a, ad, b, x);
    for k in 0..2 {
        critics[k].forward(x, b, &mut tapes[k]);
    }
    let (q0, q1) = (tapes[0].output(), tapes[1].output());
    let mut loss = 0.0;
    for ds in dsel.iter_mut() {
        ds.clear();
        ds.resize(b, T::ZERO);
    }
    for r in 0..b {
        // torch.min over the twins: the gradient goes to the first minimum
        let k = if q0[r] <= q1[r] { 0 } else { 1 };
        dsel[k][r] = -inv_b;
        loss += (alpha.to_f64() * s1.logp[r].to_f64() - q0[r].min(q1[r]).to_f64()) / b as f64;
    }
    ga.clear();
    ga.resize(b * ad, T::ZERO);
    for k in 0..2 {
        if let Some(dx) = critics[k].backward(&tapes[k], &dsel[k], None, true, ws) {
            for r in 0..b {
                for i in 0..ad {
                    ga[r * ad + i] += dx[r * (od + ad) + od + i];
                }
            }
        }
    }
    glogp.clear();
    glogp.resize(b, alpha * inv_b);
    if let Some(p) = prior {
        p.add_grad(&s1.a, glogp, ad, ga);
    }
    head.sample_backward(actor, s1, ga, glogp, grads, dout, gu, ws);
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

/// The action-space critics of the noise-aliased variant, with their targets and optimisers.
#[derive(Clone, Debug)]
pub struct ActionCritics<T> {
    pub critics: [Net<T>; 2],
    pub targets: [Net<T>; 2],
    pub opt: [Adam<T>; 2],
}

impl<T: Real> ActionCritics<T> {
    pub fn new(critics: [Net<T>; 2], lr: f64) -> Self {
        let opt = [adam_for(&critics[0], lr), adam_for(&critics[1], lr)];
        Self { targets: critics.clone(), critics, opt }
    }
}

/// Maps `rows` observations and scaled latent actions (in [-1, 1]) to the diffusion policy's
/// normalised action chunks (rows x latent dim), for the noise-aliased step.
pub type ChunkDecoder<'a, T> = dyn FnMut(&[T], &[T], usize, &mut Vec<T>) + 'a;

/// What training changes in a learner and a checkpoint keeps: the nets' parameters, the
/// entropy coefficient and the optimisers (the action critics too, for the noise-aliased one).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SacState {
    actor: Vec<f32>,
    critics: [Vec<f32>; 2],
    targets: [Vec<f32>; 2],
    log_alpha: f32,
    opt_actor: Adam<f32>,
    opt_critics: [Adam<f32>; 2],
    opt_alpha: Adam<f32>,
    action_critics: Option<ActionCriticState>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct ActionCriticState {
    critics: [Vec<f32>; 2],
    targets: [Vec<f32>; 2],
    opt: [Adam<f32>; 2],
}

fn twin_params(nets: &[Net<f32>; 2]) -> [Vec<f32>; 2] {
    [nets[0].params.clone(), nets[1].params.clone()]
}

/// Saved parameters into twin nets (sizes already checked), re-expanded.
fn load_twins(nets: &mut [Net<f32>; 2], params: [Vec<f32>; 2]) {
    for (n, p) in nets.iter_mut().zip(params) {
        n.params = p;
        n.expand();
    }
}

impl Sac<f32> {
    /// The learner's trainable state (see [`SacState`]).
    pub fn state(&self) -> SacState {
        SacState {
            actor: self.actor.params.clone(),
            critics: twin_params(&self.critics),
            targets: twin_params(&self.targets),
            log_alpha: self.log_alpha,
            opt_actor: self.opt_actor.clone(),
            opt_critics: self.opt_critics.clone(),
            opt_alpha: self.opt_alpha.clone(),
            action_critics: self.aliased.as_ref().map(|na| ActionCriticState {
                critics: twin_params(&na.critics),
                targets: twin_params(&na.targets),
                opt: na.opt.clone(),
            }),
        }
    }

    /// Put a saved state back; every size is checked first, so a state of another architecture
    /// changes nothing and says which net does not fit.
    pub fn set_state(&mut self, s: SacState) -> std::result::Result<(), String> {
        let fit = |name: &str, got: usize, want: usize| {
            if got == want {
                Ok(())
            } else {
                Err(format!("{name} has {got} parameters, expected {want}"))
            }
        };
        let fit_twins = |name: &str, saved: &[Vec<f32>; 2], nets: &[Net<f32>; 2]| {
            saved.iter().zip(nets).try_for_each(|(s, n)| fit(name, s.len(), n.num_params()))
        };
        fit("actor", s.actor.len(), self.actor.num_params())?;
        fit_twins("critic", &s.critics, &self.critics)?;
        fit_twins("target critic", &s.targets, &self.targets)?;
        match (&self.aliased, &s.action_critics) {
            (Some(na), Some(a)) => {
                fit_twins("action critic", &a.critics, &na.critics)?;
                fit_twins("action target", &a.targets, &na.targets)?;
            }
            (None, None) => {}
            _ => return Err("action critics saved for a run without noise aliasing, or missing".into()),
        }
        self.actor.params = s.actor;
        self.actor.expand();
        load_twins(&mut self.critics, s.critics);
        load_twins(&mut self.targets, s.targets);
        if let (Some(na), Some(a)) = (self.aliased.as_mut(), s.action_critics) {
            load_twins(&mut na.critics, a.critics);
            load_twins(&mut na.targets, a.targets);
            na.opt = a.opt;
        }
        self.log_alpha = s.log_alpha;
        self.opt_actor = s.opt_actor;
        self.opt_critics = s.opt_critics;
        self.opt_alpha = s.opt_alpha;
        Ok(())
    }
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
    /// The action critics of the noise-aliased variant (`None`: plain SAC on the noise).
    pub aliased: Option<ActionCritics<T>>,
    scratch: Scratch<T>,
}

#[derive(Default)]
struct Scratch<T> {
    s1: ActorSample<T>,
    s2: ActorSample<T>,
    tape: Tape<T>,
    x: Vec<T>,
    y: Vec<T>,
    grads: Vec<T>,
    eps: Vec<T>,
    buf: Buffers<T>,
    /// The noise-aliased step's decoded chunks and critic values.
    chunk: Vec<T>,
    q: Vec<T>,
}

/// What one gradient step reports (for tests and logs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    pub critic_loss: f64,
    pub actor_loss: f64,
    pub alpha: f64,
    pub alpha_loss: f64,
}

/// A latent coordinate counts as at the edge of the bounded box once its squashed magnitude
/// (the radius, for a rho1 pair) exceeds this.
pub const EDGE: f64 = 0.99;

/// The learner's state on one replay sample: what decides whether SAC is stable, recorded at
/// every evaluation (`train.csv`) so that a collapse can be traced to its cause.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Diagnostics {
    /// Entropy coefficient `exp(log_alpha)`.
    pub alpha: f64,
    /// `-mean log pi(a|s)`, `a ~ pi(.|s)` (of the squashed action; the target is `-target_entropy`).
    pub entropy: f64,
    /// Fraction of latent coordinates at the edge of the box (see [`EDGE`]).
    pub edge_fraction: f64,
    /// SB3's critic loss on the sample: `0.5 sum_k mean (Q_k(s, a) - y)^2`.
    pub critic_loss: f64,
    /// Mean soft target `y`.
    pub target_q: f64,
    /// Mean `min_k Q_k(s, a')` at the actor's own actions `a' ~ pi(.|s)`.
    pub policy_q: f64,
    /// Estimated `KL(pi(.|s) || p)` to the diffusion policy's noise `N(0, I)` in the box
    /// ([`NoisePrior`]), whatever the regulariser: how far the actor has moved off the noise the
    /// EDP was trained on (its centre as well as its width).
    #[serde(default)]
    pub prior_kl: f64,
}

/// Concatenate obs (rows x od) and actions (rows x ad) row by row.
pub fn concat_rows<T: Real>(obs: &[T], od: usize, act: &[T], ad: usize, rows: usize, out: &mut Vec<T>) {
    out.clear();
    for r in 0..rows {
        out.extend_from_slice(&obs[r * od..(r + 1) * od]);
        out.extend_from_slice(&act[r * ad..(r + 1) * ad]);
    }
}

/// min_k net_k(obs, act) per row of twin nets, into `q` (`x` and `tape` are reused buffers).
#[allow(clippy::too_many_arguments)]
fn min_over<T: Real>(
    nets: &[Net<T>; 2],
    obs: &[T],
    od: usize,
    act: &[T],
    ad: usize,
    rows: usize,
    x: &mut Vec<T>,
    tape: &mut Tape<T>,
    q: &mut Vec<T>,
) {
    concat_rows(obs, od, act, ad, rows, x);
    q.clear();
    q.resize(rows, T::ZERO);
    for (k, n) in nets.iter().enumerate() {
        n.forward(x, rows, tape);
        for (qi, v) in q.iter_mut().zip(tape.output()) {
            *qi = if k == 0 { *v } else { qi.min(*v) };
        }
    }
}

/// Draws from N(0, I) into `out`, clipped to the box of half-width `bound` and scaled to [-1, 1]
/// (the EDP's own noise in the learner's units).
pub fn candidates<T: Real>(rng: &mut Rng, bound: f64, out: &mut [T]) {
    normals(rng, out);
    for e in out.iter_mut() {
        *e = T::from_f64(e.to_f64().clamp(-bound, bound) / bound);
    }
}

/// Each `dim`-long row of `rows` repeated `n` times in a row, into `out`.
fn repeat_rows<T: Real>(rows: &[T], dim: usize, n: usize, out: &mut Vec<T>) {
    out.clear();
    for row in rows.chunks_exact(dim.max(1)) {
        for _ in 0..n {
            out.extend_from_slice(row);
        }
    }
}

/// Index of the first largest value (0 for an empty slice).
pub fn argmax<T: PartialOrd>(x: &[T]) -> usize {
    (0..x.len()).fold(0, |b, i| if x[i] > x[b] { i } else { b })
}

/// Targets `Q' <- (1 - tau) Q' + tau Q`.
fn polyak<T: Real>(targets: &mut [Net<T>; 2], critics: &[Net<T>; 2], tau: f64) {
    let (tau, keep) = (T::from_f64(tau), T::from_f64(1.0 - tau));
    for (t, c) in targets.iter_mut().zip(critics) {
        for (tp, cp) in t.params.iter_mut().zip(&c.params) {
            *tp = *tp * keep + *cp * tau;
        }
        t.expand();
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
            log_alpha: T::from_f64(libm::log(config.ent_init)),
            config,
            head,
            actor,
            critics,
            targets,
            opt_actor,
            opt_critics,
            opt_alpha,
            obs_dim,
            aliased: None,
            scratch: Scratch::default(),
        }
    }

    /// The noise-aliased learner: `critics` become the noise critics Q^W (trained by
    /// distillation) and `action_critics` the TD-trained Q^A.
    pub fn aliased(models: Models<T>, action_critics: [Net<T>; 2], obs_dim: usize, config: SacConfig) -> Self {
        let mut sac = Self::new(models, obs_dim, config);
        sac.aliased = Some(ActionCritics::new(action_critics, config.lr));
        sac
    }

    /// One noise-aliased gradient step (see the module docs): `batch.chunk` holds the executed
    /// chunks, `decode` runs the diffusion policy; `rng` is the training stream, which also draws
    /// the distillation noise. The reported critic loss is the action critics' plus the
    /// distillation's. A learner built without action critics does a plain step.
    pub fn train_step_aliased(
        &mut self,
        batch: &Batch<T>,
        decode: &mut ChunkDecoder<'_, T>,
        bound: f64,
        rng: &mut Rng,
    ) -> StepStats {
        let (od, ad, b) = (self.obs_dim, self.head.dim, batch.rows);
        // The action critics leave the learner for the step (no other phase reads them there).
        let Some(mut na) = self.aliased.take() else {
            return self.train_step(batch, rng);
        };
        // 1. w ~ pi(.|s); 2. entropy coefficient
        let (alpha, alpha_loss) = self.sample_and_step_alpha(&batch.obs, rng);
        let sc = &mut self.scratch;
        // 3. target through the action critics' targets at the decoded next chunk
        normals(rng, &mut sc.eps);
        sample_policy(&self.head, &self.actor, self.config.prior.as_ref(), &batch.next_obs, b, &sc.eps, &mut sc.s2);
        decode(&batch.next_obs, &sc.s2.a, b, &mut sc.chunk);
        min_over(&na.targets, &batch.next_obs, od, &sc.chunk, ad, b, &mut sc.x, &mut sc.tape, &mut sc.q);
        soft_values(batch, T::from_f64(self.config.gamma), &sc.q, alpha, &sc.s2.logp, &mut sc.y);
        // 4. action critics at the executed chunks
        concat_rows(&batch.obs, od, &batch.chunk, ad, b, &mut sc.x);
        let mut critic_loss = fit_twins(&mut na.critics, &mut na.opt, &sc.x, &sc.y, &mut sc.grads, &mut sc.buf);
        // 5. distil the noise critics from the updated action critics over w ~ N(0, I) in the box
        candidates(rng, bound, &mut sc.eps);
        decode(&batch.obs, &sc.eps, b, &mut sc.chunk);
        min_over(&na.critics, &batch.obs, od, &sc.chunk, ad, b, &mut sc.x, &mut sc.tape, &mut sc.q);
        concat_rows(&batch.obs, od, &sc.eps, ad, b, &mut sc.x);
        critic_loss += fit_twins(&mut self.critics, &mut self.opt_critics, &sc.x, &sc.q, &mut sc.grads, &mut sc.buf);
        // 6. actor through the noise critics
        let actor_loss = self.actor_step(&batch.obs, alpha);
        // 7. Polyak for the action critics (and the noise critics' targets, which only the
        //    learner diagnostics read)
        polyak(&mut na.targets, &na.critics, self.config.tau);
        polyak(&mut self.targets, &self.critics, self.config.tau);
        self.aliased = Some(na);
        StepStats { critic_loss, actor_loss, alpha: alpha.to_f64(), alpha_loss }
    }

    /// One gradient step of the selecting learner (see the module docs): no actor, no entropy
    /// term; the policy is the best of `n` fresh candidates from N(0, I) (clipped to the box of
    /// half-width `bound`, then scaled to [-1, 1]) by min-Q, and the critics learn that policy's
    /// value:
    /// 1. `n` candidates `w'_j` per next state, from `rng`;
    /// 2. target `y = r + gamma (1 - terminated) max_j min_k Q'_k(s', w'_j)`;
    /// 3. critic loss `0.5 sum_k mean (Q_k(s, w) - y)^2` at the executed noise, one Adam step
    ///    per critic;
    /// 4. Polyak.
    ///
    /// With `n = 1` this evaluates the base policy (expected SARSA over the EDP's own noise).
    pub fn train_step_select(&mut self, batch: &Batch<T>, n: usize, bound: f64, rng: &mut Rng) -> StepStats {
        let (od, ad, b) = (self.obs_dim, self.head.dim, batch.rows);
        // 1. and 2.
        self.select_target(batch, n, bound, rng);
        let sc = &mut self.scratch;
        // 3. critics at the executed noise
        concat_rows(&batch.obs, od, &batch.act, ad, b, &mut sc.x);
        let critic_loss = fit_twins(&mut self.critics, &mut self.opt_critics, &sc.x, &sc.y, &mut sc.grads, &mut sc.buf);
        // 4. Polyak
        polyak(&mut self.targets, &self.critics, self.config.tau);
        StepStats { critic_loss, ..StepStats::default() }
    }

    /// Phases 1 and 2 of [`Sac::train_step_select`]: the target into the scratch's `y`.
    fn select_target(&mut self, batch: &Batch<T>, n: usize, bound: f64, rng: &mut Rng) {
        let (od, ad, b, n) = (self.obs_dim, self.head.dim, batch.rows, n.max(1));
        let sc = &mut self.scratch;
        // 1. candidates at the next states, row r's j-th at row r * n + j
        sc.eps.resize(b * n * ad, T::ZERO);
        candidates(rng, bound, &mut sc.eps);
        repeat_rows(&batch.next_obs, od, n, &mut sc.chunk);
        // 2. target over the best candidate of each next state
        min_over(&self.targets, &sc.chunk, od, &sc.eps, ad, b * n, &mut sc.x, &mut sc.tape, &mut sc.q);
        let gamma = T::from_f64(self.config.gamma);
        sc.y.clear();
        sc.y.extend((0..b).map(|r| {
            let best = sc.q[r * n..(r + 1) * n].iter().copied().fold(T::from_f64(f64::NEG_INFINITY), T::max);
            batch.reward[r] + (T::ONE - batch.done[r]) * gamma * best
        }));
    }

    /// The selecting learner's state on `batch` (no parameter changes; `rng` draws the
    /// candidates): its critic loss and mean target as in [`Sac::train_step_select`], and
    /// `policy_q` at its own picks. It has no actor: alpha, entropy, edge fraction and the KL to
    /// N(0, I) are 0 (a pick's KL is at most ln n).
    pub fn diagnose_select(&mut self, batch: &Batch<T>, n: usize, bound: f64, rng: &mut Rng) -> Diagnostics {
        let (od, ad, b) = (self.obs_dim, self.head.dim, batch.rows);
        if b == 0 {
            return Diagnostics::default();
        }
        self.select_target(batch, n, bound, rng);
        let y = std::mem::take(&mut self.scratch.y);
        let mean = |v: &mut dyn Iterator<Item = f64>| v.sum::<f64>() / b as f64;
        let mut x = Vec::new();
        concat_rows(&batch.obs, od, &batch.act, ad, b, &mut x);
        let mut tape = Tape::default();
        let critic_loss: f64 = self.critics.iter().map(|c| critic_loss(c, &x, &y, &mut tape)).sum();
        let picks = self.select(&batch.obs, b, n, bound, rng);
        let policy_q = mean(&mut self.min_q(&batch.obs, &picks, b).iter().map(|q| q.to_f64()));
        let target_q = mean(&mut y.iter().map(|v| v.to_f64()));
        self.scratch.y = y;
        Diagnostics { critic_loss, target_q, policy_q, ..Diagnostics::default() }
    }

    /// The selecting policy's picks: for each of `rows` observations, the best by min-Q of `n`
    /// fresh candidates from `rng` (as in [`Sac::train_step_select`]), scaled to [-1, 1].
    pub fn select(&mut self, obs: &[T], rows: usize, n: usize, bound: f64, rng: &mut Rng) -> Vec<T> {
        let n = n.max(1);
        let mut w = vec![T::ZERO; rows * n * self.head.dim];
        candidates(rng, bound, &mut w);
        self.pick(obs, rows, n, &w)
    }

    /// For each of `rows` observations, the candidate of highest min-Q among its `n` in
    /// `candidates` (row r's j-th at row r * n + j), in one pass of the critics.
    pub fn pick(&mut self, obs: &[T], rows: usize, n: usize, candidates: &[T]) -> Vec<T> {
        let (od, ad, n) = (self.obs_dim, self.head.dim, n.max(1));
        let mut o = Vec::new();
        repeat_rows(&obs[..rows * od], od, n, &mut o);
        let q = self.min_q(&o, candidates, rows * n);
        let mut out = Vec::with_capacity(rows * ad);
        for r in 0..rows {
            let k = r * n + argmax(&q[r * n..(r + 1) * n]);
            out.extend_from_slice(&candidates[k * ad..(k + 1) * ad]);
        }
        out
    }

    /// Phases 1 and 2 of a step: the actor's sample at `obs` (into the scratch's `s1`, with
    /// noise from `rng`), then one Adam step of the entropy coefficient; returns `alpha` before
    /// the step and its loss.
    fn sample_and_step_alpha(&mut self, obs: &[T], rng: &mut Rng) -> (T, f64) {
        let (ad, b, sc) = (self.head.dim, obs.len() / self.obs_dim.max(1), &mut self.scratch);
        sc.eps.resize(b * ad, T::ZERO);
        normals(rng, &mut sc.eps);
        sample_policy(&self.head, &self.actor, self.config.prior.as_ref(), obs, b, &sc.eps, &mut sc.s1);
        step_alpha(&mut self.log_alpha, &mut self.opt_alpha, &sc.s1.logp, self.config.alpha_target())
    }

    /// One Adam step of the actor on `min_k Q_k(s, a(s)) - alpha log pi` (or the prior's
    /// `log pi - log p`) at the reparameterised sample `s1` drawn in phase 2; returns the loss.
    fn actor_step(&mut self, obs: &[T], alpha: T) -> f64 {
        let sc = &mut self.scratch;
        sc.grads.clear();
        sc.grads.resize(self.actor.num_params(), T::ZERO);
        let loss = actor_loss_grad(
            &self.head,
            &self.actor,
            &self.critics,
            obs,
            &sc.s1,
            alpha,
            self.config.prior.as_ref(),
            &mut sc.grads,
            &mut sc.buf,
        );
        self.opt_actor.update(&mut self.actor.params, &sc.grads);
        self.actor.expand();
        loss
    }

    pub fn latent_dim(&self) -> usize {
        self.head.dim
    }

    /// The most entropy the actor's family can have ([`crate::models::Squash::max_entropy`]).
    pub fn max_entropy(&self) -> f64 {
        self.head.squash.max_entropy(self.head.dim)
    }

    /// Actions of the stochastic actor for `rows` observations with noise `eps` (in [-1, 1]).
    pub fn act(&mut self, obs: &[T], rows: usize, eps: &[T]) -> Vec<T> {
        let s = &mut self.scratch.s1;
        self.head.sample(&self.actor, obs, rows, eps, s);
        s.a.clone()
    }

    /// min_k Q_k(s, a) per row.
    pub fn min_q(&mut self, obs: &[T], act: &[T], rows: usize) -> Vec<T> {
        let (od, ad, sc) = (self.obs_dim, self.head.dim, &mut self.scratch);
        let mut q = Vec::new();
        min_over(&self.critics, obs, od, act, ad, rows, &mut sc.x, &mut sc.tape, &mut q);
        q
    }

    /// The learner's state on `batch` (no parameter changes); `rng` draws the actor's noise;
    /// `bound` is the latent box's half-width (for the KL to the noise prior).
    pub fn diagnose(&mut self, batch: &Batch<T>, rng: &mut Rng, bound: f64) -> Diagnostics {
        let (od, ad, b) = (self.obs_dim, self.head.dim, batch.rows);
        if b == 0 {
            return Diagnostics::default();
        }
        let alpha = self.log_alpha.exp();
        let mut eps = vec![T::ZERO; b * ad];
        normals(rng, &mut eps);
        let mut s1 = ActorSample::default();
        self.head.sample(&self.actor, &batch.obs, b, &eps, &mut s1);
        let mean = |v: &mut dyn Iterator<Item = f64>| v.sum::<f64>() / b as f64;
        let entropy = -mean(&mut s1.logp.iter().map(|l| l.to_f64()));
        // s1's log-probabilities are read once, above: they become log pi - log p in place
        NoisePrior { bound, target_kl: 0.0 }.apply(&self.head, &mut s1);
        let prior_kl = mean(&mut s1.logp.iter().map(|l| l.to_f64()));
        normals(rng, &mut eps);
        let (mut s2, mut buf, mut y) = (ActorSample::default(), Buffers::default(), Vec::new());
        soft_target(
            &self.head,
            &self.actor,
            &self.targets,
            batch,
            &eps,
            alpha,
            T::from_f64(self.config.gamma),
            self.config.prior.as_ref(),
            &mut s2,
            &mut buf,
            &mut y,
        );
        let policy_q = mean(&mut self.min_q(&batch.obs, &s1.a, b).iter().map(|q| q.to_f64()));
        let mut x = Vec::new();
        concat_rows(&batch.obs, od, &batch.act, ad, b, &mut x);
        let mut tape = Tape::default();
        let critic_loss: f64 = self.critics.iter().map(|c| critic_loss(c, &x, &y, &mut tape)).sum();
        let edge: usize = s1.a.chunks(ad).map(|a| self.head.squash.at_edge(a, EDGE)).sum();
        Diagnostics {
            alpha: alpha.to_f64(),
            entropy,
            prior_kl,
            edge_fraction: edge as f64 / (b * ad) as f64,
            critic_loss,
            target_q: mean(&mut y.iter().map(|v| v.to_f64())),
            policy_q,
        }
    }

    /// One gradient step on a minibatch (see the module docs); `rng` is the training stream.
    pub fn train_step(&mut self, batch: &Batch<T>, rng: &mut Rng) -> StepStats {
        let (od, ad, b) = (self.obs_dim, self.head.dim, batch.rows);
        // 1. a ~ pi(.|s); 2. entropy coefficient
        let (alpha, alpha_loss) = self.sample_and_step_alpha(&batch.obs, rng);
        let sc = &mut self.scratch;
        // 3. target
        normals(rng, &mut sc.eps);
        soft_target(
            &self.head,
            &self.actor,
            &self.targets,
            batch,
            &sc.eps,
            alpha,
            T::from_f64(self.config.gamma),
            self.config.prior.as_ref(),
            &mut sc.s2,
            &mut sc.buf,
            &mut sc.y,
        );
        // 4. critics
        concat_rows(&batch.obs, od, &batch.act, ad, b, &mut sc.x);
        let critic_loss = fit_twins(&mut self.critics, &mut self.opt_critics, &sc.x, &sc.y, &mut sc.grads, &mut sc.buf);
        // 5. actor through the updated critics
        let actor_loss = self.actor_step(&batch.obs, alpha);
        // 6. Polyak
        polyak(&mut self.targets, &self.critics, self.config.tau);
        StepStats { critic_loss, actor_loss, alpha: alpha.to_f64(), alpha_loss }
    }
}
