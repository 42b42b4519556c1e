//! A self-contained SAC gradient case in f64 for parity tests against an independent
//! implementation (the Python test rebuilds every layer and loss in PyTorch from this
//! description and compares gradients). Everything here derives `Serialize`, so the binding
//! hands it to Python as plain dicts and lists (layers tagged by `kind`).

use equigym_envs::TaskOptions;
use equigym_wrappers::{Group, TaskSymmetry};
use serde::Serialize;

use crate::error::Result;
use crate::models::{Arch, Method, Models, Squash, GROUP_ORDER};
use crate::net::{Layer, LinearKind, Net};
use crate::replay::Batch;
use crate::rng::{Rng, Stream};
use crate::sac::{actor_loss_grad, alpha_loss_grad, concat_rows, critic_loss_grad, soft_target, ActorSample, Buffers};

/// One layer, with parameter offsets into its net's flat vector.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LayerSpec {
    Dense {
        n_in: usize,
        n_out: usize,
        w: usize,
        b: usize,
    },
    /// Dense matrix entry `entries[i]` (row-major `n_in x n_out`) += `coefs[i] * params[w + pidx[i]]`;
    /// bias `bias_out[j]` += `params[w + n_weights + bias_pidx[j]]`; plus a plain path.
    Equi {
        n_in: usize,
        n_out: usize,
        w: usize,
        n_weights: usize,
        entries: Vec<u32>,
        pidx: Vec<u32>,
        coefs: Vec<f64>,
        bias_out: Vec<u32>,
        bias_pidx: Vec<u32>,
        plain: Option<(usize, usize)>,
    },
    /// LayerNorm over `fields x order` units, gain `params[g + f]` and shift `params[s + f]` for
    /// every unit of group `f` (`order` 1: a plain LayerNorm).
    Norm {
        fields: usize,
        order: usize,
        g: usize,
        s: usize,
    },
    Tanh,
    Relu,
    PoolHead {
        fields: usize,
        order: usize,
        w: usize,
        b: usize,
        plain: Option<(usize, usize)>,
    },
    /// Fourier-basis regular layer: rho0 (F_in x F_out) at w, rho4 next, then A_k, B_k for
    /// k = 1, 2, 3; bias (F_out) at b.
    Circulant {
        f_in: usize,
        f_out: usize,
        w: usize,
        b: usize,
    },
}

pub fn describe(net: &Net<f64>) -> Vec<LayerSpec> {
    net.layers
        .iter()
        .map(|l| match l {
            Layer::Linear(lin) => match &lin.kind {
                LinearKind::Dense { w, b } => LayerSpec::Dense { n_in: lin.n_in, n_out: lin.n_out, w: *w, b: *b },
                LinearKind::Equi { basis, w, plain } => LayerSpec::Equi {
                    n_in: lin.n_in,
                    n_out: lin.n_out,
                    w: *w,
                    n_weights: basis.n_weights,
                    entries: basis.weights.iter().map(|t| t.0).collect(),
                    pidx: basis.weights.iter().map(|t| t.1).collect(),
                    coefs: basis.weights.iter().map(|t| t.2).collect(),
                    bias_out: basis.bias.iter().map(|t| t.0).collect(),
                    bias_pidx: basis.bias.iter().map(|t| t.1).collect(),
                    plain: *plain,
                },
            },
            Layer::Norm { fields, order, g, s, .. } => LayerSpec::Norm { fields: *fields, order: *order, g: *g, s: *s },
            Layer::Tanh => LayerSpec::Tanh,
            Layer::Relu => LayerSpec::Relu,
            Layer::PoolHead { fields, order, w, b, plain } => {
                LayerSpec::PoolHead { fields: *fields, order: *order, w: *w, b: *b, plain: *plain }
            }
            Layer::Circulant(c) => LayerSpec::Circulant { f_in: c.f_in, f_out: c.f_out, w: c.w, b: c.b },
        })
        .collect()
}

/// The radial squash's rho1 pairs and rho0 indices.
pub type RadialFields = (Vec<(usize, usize)>, Vec<usize>);

/// A network: its layers and its flat parameter vector.
#[derive(Clone, Debug, Serialize)]
pub struct NetSpec {
    pub layers: Vec<LayerSpec>,
    pub params: Vec<f64>,
}

impl NetSpec {
    fn of(net: &Net<f64>) -> Self {
        NetSpec { layers: describe(net), params: net.params.clone() }
    }
}

/// Everything a parity test needs: networks, inputs, noise, and Rust's losses and gradients.
#[derive(Clone, Debug, Serialize)]
pub struct GradCase {
    pub obs_dim: usize,
    pub latent_dim: usize,
    pub rows: usize,
    pub actor: NetSpec,
    pub critics: [NetSpec; 2],
    pub log_std_index: Vec<usize>,
    pub log_std_range: (f64, f64),
    /// None: elementwise tanh; Some((pairs, singles)): radial squash.
    pub radial: Option<RadialFields>,
    pub obs: Vec<f64>,
    pub act: Vec<f64>,
    pub reward: Vec<f64>,
    pub next_obs: Vec<f64>,
    pub done: Vec<f64>,
    pub eps1: Vec<f64>,
    pub eps2: Vec<f64>,
    pub log_alpha: f64,
    pub gamma: f64,
    /// Soft targets (target critics = the critics).
    pub y: Vec<f64>,
    pub logp: Vec<f64>,
    pub actor_loss: f64,
    pub critic_losses: [f64; 2],
    pub alpha_loss: f64,
    pub actor_grad: Vec<f64>,
    pub critic_grads: [Vec<f64>; 2],
    pub alpha_grad: f64,
}

/// A gradient case for `method` on `task` with small nets (2 x 16, parameter-matched fields).
pub fn grad_case(method: Method, task: &str, seed: u64, rows: usize) -> Result<GradCase> {
    let sym = TaskSymmetry::new(task, &TaskOptions::default(), Group::cyclic(GROUP_ORDER)?, 4)?;
    let m = Models::<f64>::new(method, &sym, Arch { width: 16, layers: 2 }, seed)?;
    let (od, ad) = (sym.observation.dim(), sym.chunk.dim());
    let mut rng = Rng::new(seed, Stream::Eval, u64::MAX);
    let mut draw = |n: usize, scale: f64| -> Vec<f64> { (0..n).map(|_| rng.normal() * scale).collect() };
    let obs = draw(rows * od, 1.0);
    let act: Vec<f64> = draw(rows * ad, 0.5).iter().map(|&v| libm::tanh(v)).collect();
    let next_obs = draw(rows * od, 1.0);
    let reward: Vec<f64> = draw(rows, 1.0).iter().map(|v| -v.abs().min(4.0)).collect();
    let done: Vec<f64> = (0..rows).map(|r| (r % 3 == 2) as u8 as f64).collect();
    let eps1 = draw(rows * ad, 1.0);
    let eps2 = draw(rows * ad, 1.0);
    let (log_alpha, gamma, target_entropy) = (libm::log(0.2), 0.99, 0.0);
    let batch = Batch::of(obs.clone(), act.clone(), reward.clone(), next_obs.clone(), done.clone());
    let alpha = libm::exp(log_alpha);
    let mut s2 = ActorSample::default();
    let (mut buf, mut y) = (Buffers::default(), Vec::new());
    soft_target(&m.head, &m.actor, &m.critics, &batch, &eps2, alpha, gamma, None, &mut s2, &mut buf, &mut y);
    let mut x = Vec::new();
    concat_rows(&obs, od, &act, ad, rows, &mut x);
    let mut critic_grads = [vec![0.0; m.critics[0].num_params()], vec![0.0; m.critics[1].num_params()]];
    let mut critic_losses = [0.0; 2];
    for k in 0..2 {
        critic_losses[k] = critic_loss_grad(&m.critics[k], &x, &y, &mut critic_grads[k], &mut buf);
    }
    let mut s1 = ActorSample::default();
    m.head.sample(&m.actor, &obs, rows, &eps1, &mut s1);
    let mut actor_grad = vec![0.0; m.actor.num_params()];
    let actor_loss = actor_loss_grad(&m.head, &m.actor, &m.critics, &obs, &s1, alpha, None, &mut actor_grad, &mut buf);
    let (alpha_loss, alpha_grad) = alpha_loss_grad(log_alpha, &s1.logp, target_entropy);
    let radial = match &m.head.squash {
        Squash::Tanh => None,
        Squash::Radial { pairs, singles } => Some((pairs.clone(), singles.clone())),
    };
    Ok(GradCase {
        obs_dim: od,
        latent_dim: ad,
        rows,
        actor: NetSpec::of(&m.actor),
        critics: [NetSpec::of(&m.critics[0]), NetSpec::of(&m.critics[1])],
        log_std_index: m.head.log_std_index.clone(),
        log_std_range: m.head.log_std_range,
        radial,
        obs,
        act,
        reward,
        next_obs,
        done,
        eps1,
        eps2,
        log_alpha,
        gamma,
        y,
        logp: s1.logp.clone(),
        actor_loss,
        critic_losses,
        alpha_loss,
        actor_grad,
        critic_grads,
        alpha_grad,
    })
}
