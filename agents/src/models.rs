//! The actor and critic networks of each method, built from the task's field layouts, and the
//! squashed Gaussian policy head.
//!
//! - **DSRL**: MLPs with LayerNorm after every hidden linear layer and Tanh (the DSRL recipe, as
//!   `baselines/agents.py::LayerNormSACPolicy`); actor outputs mean and log-std per latent
//!   dimension (log-std clamped to [-20, 2], SB3's range), elementwise tanh squash.
//! - **Equi-DSRL**: C8-equivariant trunks of regular fields, each linear layer followed by a
//!   field-tied LayerNorm and Tanh (DSRL's recipe made equivariant: one gain and shift per
//!   field; see [`crate::net::Layer::Norm`]). Without the normalisation, ReLU trunks let the
//!   critics diverge at UTD 4 on the articulated arm: once the policy's entropy collapsed
//!   (8k env steps, Lift, seed 1), mean Q climbed to +1,750 where true soft returns are below 0
//!   (`train.csv` of that run, docs/steering.md). The actor head maps onto
//!   the latent's rho1 / rho0 blocks (the means) plus one invariant log-std per block (a shared,
//!   isotropic std per rho1 pair; clamped to [-5, 2]); the radial squash
//!   `a = tanh(|u|) u / |u|` per rho1 pair (elementwise tanh on rho0 values) keeps the bounded
//!   policy exactly C8-equivariant. Twin critics are invariant: trunk, max over each regular
//!   field (group pooling), linear.
//! - **Approx-Equi-DSRL**: the same with a plain linear path beside every equivariant one
//!   (residual pathway priors, weight decay 1e-5 / 1e-2).
//!
//! Equivariant widths are matched to the DSRL networks' parameter count (actor plus both
//! critics) exactly as `baselines/steer.py::equi_fields_matching` does: the candidate field
//! counts in order, the closest count, stopping at the first one above.
//!
//! Actions are in the scaled box (SB3's convention): the policy's `a` lies in [-1, 1]^d (a disk
//! per rho1 pair for the radial squash); the environment receives `bound * a`. Log-probabilities
//! are of `a`, so the target entropy 0 means what it means in the SB3 runs.

use std::sync::Arc;

use equigym_nn::{ops, Real};
use equigym_wrappers::TaskSymmetry;
use serde::{Deserialize, Serialize};

use crate::equi::{fields_of, regular_fields, Basis, Field};
use crate::error::{Error, Result};
use crate::net::{Net, NetBuilder, RPP_EQUI_DECAY};
use crate::rng::{Rng, Stream};

/// The group of the paper: C8.
pub const GROUP_ORDER: usize = 8;
/// Candidate hidden field counts for parameter matching (as in `baselines/steer.py`).
pub const FIELD_CANDIDATES: [usize; 10] = [8, 16, 24, 32, 48, 64, 96, 128, 192, 256];
/// SB3's log-std clamp for the MLP actor.
pub const MLP_LOG_STD: (f64, f64) = (-20.0, 2.0);
/// The equivariant actor's log-std clamp (`baselines/agents.py`).
pub const EQUI_LOG_STD: (f64, f64) = (-5.0, 2.0);
/// Epsilon inside SB3's tanh log-det, log(1 - a^2 + eps).
pub const TANH_EPS: f64 = 1e-6;
/// Epsilon inside the radial squash's log-det, log1p(-t^2 + eps) (`baselines/agents.py`).
pub const RADIAL_EPS: f64 = 1e-7;
/// Below this norm a rho1 pair's radius is clamped (its direction is undefined).
pub const RADIAL_MIN_NORM: f64 = 1e-8;
/// Below this radius tanh(r)/r uses its series 1 - r^2/3.
pub const RADIAL_SERIES_BELOW: f64 = 1e-4;

/// A steering method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Method {
    Dsrl,
    Equi,
    Approx,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Dsrl => "dsrl",
            Method::Equi => "equi",
            Method::Approx => "approx",
        }
    }
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "dsrl" => Ok(Method::Dsrl),
            "equi" => Ok(Method::Equi),
            "approx" => Ok(Method::Approx),
            other => Err(Error::InvalidOption(format!("method must be dsrl, equi or approx, got '{other}'"))),
        }
    }
}

/// The largest differential entropy, in nats, of a Gaussian squashed by `tanh` into [-1, 1], per
/// coordinate (entropy measured in the squashed box, as SB3 and DSRL measure it). It peaks at mean 0
/// and standard deviation about 0.88, a little below the box's uniform `ln 2 = 0.693`, because
/// `tanh` piles the tails' mass up at the edges.
pub const MAX_TANH_ENTROPY: f64 = 0.6836;
/// The same for an isotropic 2-d Gaussian squashed radially into the unit disk, per rho1 pair
/// (peak at standard deviation about 0.80; the disk's uniform is `ln pi = 1.145`).
pub const MAX_RADIAL_PAIR_ENTROPY: f64 = 1.1221;

/// How the policy bounds its Gaussian sample.
#[derive(Clone, Debug, PartialEq)]
pub enum Squash {
    /// Elementwise tanh, log(1 - a^2 + [`TANH_EPS`]).
    Tanh,
    /// Radial tanh on each rho1 pair, elementwise tanh on the rest (log1p(-t^2 + [`RADIAL_EPS`])).
    Radial { pairs: Vec<(usize, usize)>, singles: Vec<usize> },
}

/// How the actor's output reads as a Gaussian over the latent.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyHead {
    pub dim: usize,
    /// Output index of each latent dimension's log-std (the means are outputs 0..dim).
    pub log_std_index: Vec<usize>,
    pub log_std_range: (f64, f64),
    pub squash: Squash,
}

/// Network sizes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Arch {
    /// MLP width.
    pub width: usize,
    pub layers: usize,
}

/// A method's networks for one task.
pub struct Models<T> {
    pub actor: Net<T>,
    pub critics: [Net<T>; 2],
    pub head: PolicyHead,
    /// Hidden regular fields (equivariant methods; 0 for DSRL).
    pub fields: usize,
}

fn mlp<T: Real>(n_in: usize, arch: Arch, n_out: usize, rng: &mut Rng) -> Net<T> {
    let mut b = NetBuilder::new(n_in, rng);
    for _ in 0..arch.layers {
        b = b.dense(arch.width).layer_norm().tanh();
    }
    b.dense(n_out).build()
}

/// The fields of the observation, of the latent, and their concatenation (critic input).
struct Io {
    obs: Vec<Field>,
    latent: Vec<Field>,
    critic_in: Vec<Field>,
    obs_dim: usize,
    latent_dim: usize,
}

fn io(sym: &TaskSymmetry) -> Result<Io> {
    let (obs_dim, latent_dim) = (sym.observation.dim(), sym.chunk.dim());
    let obs = fields_of(&sym.observation, 0)?;
    let latent = fields_of(&sym.chunk, 0)?;
    let mut critic_in = obs.clone();
    critic_in.extend(fields_of(&sym.chunk, obs_dim)?);
    Ok(Io { obs, latent, critic_in, obs_dim, latent_dim })
}

/// Actor head fields: the latent's blocks, then one invariant log-std per block.
fn head_fields(latent: &[Field], latent_dim: usize) -> Vec<Field> {
    let mut out = latent.to_vec();
    out.extend((0..latent.len()).map(|b| Field::Trivial(latent_dim + b)));
    out
}

fn trunk<'a, T: Real>(
    mut b: NetBuilder<'a, T>,
    inputs: &[Field],
    n_in: usize,
    fields: usize,
    layers: usize,
    residual: bool,
) -> Result<NetBuilder<'a, T>> {
    let hidden = regular_fields(fields, GROUP_ORDER);
    let width = fields * GROUP_ORDER;
    let norm_decay = if residual { RPP_EQUI_DECAY } else { 0.0 };
    let basis = Arc::new(Basis::new(inputs, n_in, &hidden, width, GROUP_ORDER)?);
    b = b.equi(basis, residual).field_norm(GROUP_ORDER, norm_decay).tanh();
    for _ in 1..layers {
        if residual {
            // RPP adds a dense plain path anyway: one expanded matrix serves both.
            let basis = Arc::new(Basis::new(&hidden, width, &hidden, width, GROUP_ORDER)?);
            b = b.equi(basis, true);
        } else {
            b = b.circulant(fields);
        }
        b = b.field_norm(GROUP_ORDER, norm_decay).tanh();
    }
    Ok(b)
}

/// Parameter count of an equivariant actor + twin critics with `fields` hidden fields.
pub fn equi_param_count(sym: &TaskSymmetry, fields: usize, layers: usize, residual: bool) -> Result<usize> {
    let io = io(sym)?;
    let hidden = regular_fields(fields, GROUP_ORDER);
    let width = fields * GROUP_ORDER;
    let count = |basis: &Basis| {
        basis.n_weights + basis.n_bias + if residual { basis.n_in * basis.n_out + basis.n_out } else { 0 }
    };
    let trunk_count = |inputs: &[Field], n_in: usize| -> Result<usize> {
        // every hidden layer has a field-tied LayerNorm: one gain and one shift per field
        let mut total = count(&Basis::new(inputs, n_in, &hidden, width, GROUP_ORDER)?) + 2 * fields;
        if layers > 1 {
            total += (layers - 1) * (count(&Basis::new(&hidden, width, &hidden, width, GROUP_ORDER)?) + 2 * fields);
        }
        Ok(total)
    };
    let head = head_fields(&io.latent, io.latent_dim);
    let actor = trunk_count(&io.obs, io.obs_dim)?
        + count(&Basis::new(&hidden, width, &head, io.latent_dim + io.latent.len(), GROUP_ORDER)?);
    let critic =
        trunk_count(&io.critic_in, io.obs_dim + io.latent_dim)? + fields + 1 + if residual { width + 1 } else { 0 };
    Ok(actor + 2 * critic)
}

/// Parameter count of the DSRL actor + twin critics.
pub fn mlp_param_count(obs_dim: usize, latent_dim: usize, arch: Arch) -> usize {
    let body = |n_in: usize| {
        n_in * arch.width + arch.width + 2 * arch.width + (arch.layers - 1) * (arch.width * arch.width + 3 * arch.width)
    };
    let actor = body(obs_dim) + arch.width * 2 * latent_dim + 2 * latent_dim;
    let critic = body(obs_dim + latent_dim) + arch.width + 1;
    actor + 2 * critic
}

/// Hidden fields whose parameter count is closest to the DSRL networks' (see module docs).
pub fn matched_fields(sym: &TaskSymmetry, arch: Arch, residual: bool) -> Result<usize> {
    let target = mlp_param_count(sym.observation.dim(), sym.chunk.dim(), arch) as i64;
    let (mut best, mut best_gap) = (FIELD_CANDIDATES[0], i64::MAX);
    for &f in &FIELD_CANDIDATES {
        let n = equi_param_count(sym, f, arch.layers, residual)? as i64;
        if (n - target).abs() < best_gap {
            best = f;
            best_gap = (n - target).abs();
        }
        if n > target {
            break;
        }
    }
    Ok(best)
}

impl<T: Real> Models<T> {
    /// Build a method's networks for a task, initialised from the run seed's init stream.
    pub fn new(method: Method, sym: &TaskSymmetry, arch: Arch, seed: u64) -> Result<Self> {
        Self::from_stream(method, sym, arch, seed, Stream::Init)
    }

    /// The twin action-space critics Q(s, a) of the noise-aliased agents (DSRL-NA): the same
    /// critic architecture as the noise critics (an action chunk has the latent noise's size and
    /// representation), initialised from their own stream.
    pub fn action_critics(method: Method, sym: &TaskSymmetry, arch: Arch, seed: u64) -> Result<[Net<T>; 2]> {
        Ok(Self::from_stream(method, sym, arch, seed, Stream::InitActionCritics)?.critics)
    }

    fn from_stream(method: Method, sym: &TaskSymmetry, arch: Arch, seed: u64, init: Stream) -> Result<Self> {
        if arch.layers == 0 || arch.width == 0 {
            return Err(Error::InvalidOption(format!("networks need at least one layer of width >= 1, got {arch:?}")));
        }
        let io = io(sym)?;
        let (od, ld) = (io.obs_dim, io.latent_dim);
        let mut rng: Vec<Rng> = (0..3).map(|i| Rng::new(seed, init, i)).collect();
        match method {
            Method::Dsrl => {
                let actor = mlp(od, arch, 2 * ld, &mut rng[0]);
                let c0 = mlp(od + ld, arch, 1, &mut rng[1]);
                let c1 = mlp(od + ld, arch, 1, &mut rng[2]);
                let head = PolicyHead {
                    dim: ld,
                    log_std_index: (ld..2 * ld).collect(),
                    log_std_range: MLP_LOG_STD,
                    squash: Squash::Tanh,
                };
                Ok(Self { actor, critics: [c0, c1], head, fields: 0 })
            }
            Method::Equi | Method::Approx => {
                let residual = method == Method::Approx;
                let fields = matched_fields(sym, arch, residual)?;
                let width = fields * GROUP_ORDER;
                let hidden = regular_fields(fields, GROUP_ORDER);
                let head_f = head_fields(&io.latent, ld);
                let head_basis = Arc::new(Basis::new(&hidden, width, &head_f, ld + io.latent.len(), GROUP_ORDER)?);
                let actor = trunk(NetBuilder::new(od, &mut rng[0]), &io.obs, od, fields, arch.layers, residual)?
                    .equi(head_basis, residual)
                    .build();
                let mut critics = Vec::new();
                for r in rng[1..].iter_mut() {
                    critics.push(
                        trunk(NetBuilder::new(od + ld, r), &io.critic_in, od + ld, fields, arch.layers, residual)?
                            .pool_head(GROUP_ORDER, residual)
                            .build(),
                    );
                }
                let mut log_std_index = vec![0; ld];
                let (mut pairs, mut singles) = (Vec::new(), Vec::new());
                for (b, f) in io.latent.iter().enumerate() {
                    match *f {
                        Field::Trivial(i) => {
                            log_std_index[i] = ld + b;
                            singles.push(i);
                        }
                        Field::Rho1(x, y) => {
                            log_std_index[x] = ld + b;
                            log_std_index[y] = ld + b;
                            pairs.push((x, y));
                        }
                        Field::Regular(_) => unreachable!("latent fields are rho0 / rho1"),
                    }
                }
                let head = PolicyHead {
                    dim: ld,
                    log_std_index,
                    log_std_range: EQUI_LOG_STD,
                    squash: Squash::Radial { pairs, singles },
                };
                let [c0, c1]: [Net<T>; 2] =
                    critics.try_into().map_err(|_| Error::InvalidOption("two critics".into()))?;
                Ok(Self { actor, critics: [c0, c1], head, fields })
            }
        }
    }
}

impl Squash {
    /// [`Squash::forward`] of `rows` rows at once (`u` and `a`: rows x `dim`), each row's
    /// log |det da/du| into `logdet`. For the elementwise tanh the tanh and the logarithms run as
    /// passes over the whole batch ([`ops::tanh_into`], [`ops::ln_into`]: vectorised, the same
    /// bits as one element at a time) and each row's sum keeps `forward`'s order, so the results
    /// are `forward`'s bit for bit; one `logf` per coordinate, scalar, was half the time of
    /// sampling actions in a DSRL gradient step. `scratch` is a reused buffer.
    pub fn forward_rows<T: Real>(&self, u: &[T], a: &mut [T], dim: usize, logdet: &mut [T], scratch: &mut Vec<T>) {
        let n = logdet.len() * dim;
        match self {
            Squash::Tanh => {
                let eps = T::from_f64(TANH_EPS);
                ops::tanh_into(&u[..n], &mut a[..n]);
                scratch.clear();
                scratch.extend(a[..n].iter().map(|ai| (T::ONE - *ai * *ai) + eps));
                scratch.resize(2 * n, T::ZERO);
                let (args, logs) = scratch.split_at_mut(n);
                ops::ln_into(args, logs);
                for (ld, row) in logdet.iter_mut().zip(logs.chunks_exact(dim.max(1))) {
                    let mut sum = T::ZERO;
                    for v in row {
                        sum += *v;
                    }
                    *ld = sum;
                }
            }
            Squash::Radial { .. } => {
                for (r, ld) in logdet.iter_mut().enumerate() {
                    *ld = self.forward(&u[r * dim..(r + 1) * dim], &mut a[r * dim..(r + 1) * dim]);
                }
            }
        }
    }

    /// The most entropy a squashed diagonal Gaussian over `dim` coordinates can have
    /// ([`MAX_TANH_ENTROPY`] per tanh coordinate, [`MAX_RADIAL_PAIR_ENTROPY`] per radial pair):
    /// 27.3 nats for DSRL's 40-d latent. SAC cannot meet a target entropy at or above it: the
    /// entropy coefficient's loss then keeps one sign and `alpha` grows without end.
    pub fn max_entropy(&self, dim: usize) -> f64 {
        match self {
            Squash::Tanh => MAX_TANH_ENTROPY * dim as f64,
            Squash::Radial { pairs, singles } => {
                MAX_RADIAL_PAIR_ENTROPY * pairs.len() as f64 + MAX_TANH_ENTROPY * singles.len() as f64
            }
        }
    }

    /// The constant part of `-log p(a)` over `dim` coordinates, `p` the density of `a = w / bound`
    /// for `w ~ N(0, I)` restricted to where the squash maps (a square per tanh coordinate, a disk
    /// per radial pair), so that `log pi - log p` estimates a KL that is zero only at `p` itself:
    /// `ln(sqrt(2 pi) / bound) + ln erf(bound / sqrt 2)` per tanh coordinate,
    /// `ln(2 pi / bound^2) + ln(1 - exp(-bound^2 / 2))` per radial pair.
    pub fn prior_log_norm(&self, dim: usize, bound: f64) -> f64 {
        let single = 0.5 * libm::log(2.0 * std::f64::consts::PI) - libm::log(bound)
            + libm::log(libm::erf(bound / std::f64::consts::SQRT_2));
        let pair = libm::log(2.0 * std::f64::consts::PI) - 2.0 * libm::log(bound)
            + libm::log(-libm::expm1(-0.5 * bound * bound));
        match self {
            Squash::Tanh => single * dim as f64,
            Squash::Radial { pairs, singles } => pair * pairs.len() as f64 + single * singles.len() as f64,
        }
    }

    /// `a = squash(u)` for one row; returns log |det da/du|.
    pub fn forward<T: Real>(&self, u: &[T], a: &mut [T]) -> T {
        let mut logdet = T::ZERO;
        match self {
            Squash::Tanh => {
                let eps = T::from_f64(TANH_EPS);
                for (ai, ui) in a.iter_mut().zip(u) {
                    *ai = ui.tanh();
                    logdet += ((T::ONE - *ai * *ai) + eps).ln();
                }
            }
            Squash::Radial { pairs, singles } => {
                let eps = T::from_f64(RADIAL_EPS);
                for &(x, y) in pairs {
                    let n = (u[x] * u[x] + u[y] * u[y]).sqrt();
                    let r = n.max(T::from_f64(RADIAL_MIN_NORM));
                    let t = r.tanh();
                    let s = t / r;
                    a[x] = u[x] * s;
                    a[y] = u[y] * s;
                    let ratio =
                        if r < T::from_f64(RADIAL_SERIES_BELOW) { T::ONE - r * r / T::from_f64(3.0) } else { s };
                    logdet += (-(t * t) + eps).ln_1p() + ratio.ln();
                }
                for &i in singles {
                    let t = u[i].tanh();
                    a[i] = t;
                    logdet += (-(t * t) + eps).ln_1p();
                }
            }
        }
        logdet
    }

    /// Coordinates of one squashed row `a` at the edge: `|a_i| > edge` (tanh, rho0 values), or
    /// both coordinates of a rho1 pair whose radius exceeds `edge`.
    pub fn at_edge<T: Real>(&self, a: &[T], edge: f64) -> usize {
        let beyond = |v: T| v.to_f64().abs() > edge;
        match self {
            Squash::Tanh => a.iter().filter(|v| beyond(**v)).count(),
            Squash::Radial { pairs, singles } => {
                let pair_count = pairs
                    .iter()
                    .filter(|(x, y)| (a[*x].to_f64().powi(2) + a[*y].to_f64().powi(2)).sqrt() > edge)
                    .count();
                2 * pair_count + singles.iter().filter(|i| beyond(a[**i])).count()
            }
        }
    }

    /// Backward for one row: `gu = ga . da/du + g_logdet * dlogdet/du`.
    pub fn backward<T: Real>(&self, u: &[T], a: &[T], ga: &[T], g_logdet: T, gu: &mut [T]) {
        let two = T::from_f64(2.0);
        match self {
            Squash::Tanh => {
                let eps = T::from_f64(TANH_EPS);
                for i in 0..u.len() {
                    let one_m = T::ONE - a[i] * a[i];
                    gu[i] = ga[i] * one_m + g_logdet * (-two * a[i] * one_m / (one_m + eps));
                }
            }
            Squash::Radial { pairs, singles } => {
                let eps = T::from_f64(RADIAL_EPS);
                for &(x, y) in pairs {
                    let n = (u[x] * u[x] + u[y] * u[y]).sqrt();
                    let clamped = n < T::from_f64(RADIAL_MIN_NORM);
                    let r = n.max(T::from_f64(RADIAL_MIN_NORM));
                    let t = r.tanh();
                    let s = t / r;
                    let one_m = T::ONE - t * t;
                    gu[x] = ga[x] * s;
                    gu[y] = ga[y] * s;
                    if !clamped {
                        let ds = one_m / r - t / (r * r);
                        let (dratio, ratio) = if r < T::from_f64(RADIAL_SERIES_BELOW) {
                            (-two * r / T::from_f64(3.0), T::ONE - r * r / T::from_f64(3.0))
                        } else {
                            (ds, s)
                        };
                        let dlogdet_dr = -two * t * one_m / (one_m + eps) + dratio / ratio;
                        let dot = ga[x] * u[x] + ga[y] * u[y];
                        // d/du of (s(r) u): s I + s'(r) u u^T / r; of logdet(r): logdet'(r) u / r
                        let c = (dot * ds + g_logdet * dlogdet_dr) / r;
                        gu[x] += c * u[x];
                        gu[y] += c * u[y];
                    }
                }
                for &i in singles {
                    let one_m = T::ONE - a[i] * a[i];
                    gu[i] = ga[i] * one_m + g_logdet * (-two * a[i] * one_m / (one_m + eps));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Squash, MAX_RADIAL_PAIR_ENTROPY, MAX_TANH_ENTROPY};
    use std::f64::consts::{LN_2, PI};

    /// `ln(1 - tanh(x)^2) = 2 (ln 2 - |x| - ln(1 + e^{-2|x|}))`, stable for large |x|.
    fn ln_sech2(x: f64) -> f64 {
        2.0 * (LN_2 - x.abs() - libm::log1p(libm::exp(-2.0 * x.abs())))
    }

    /// Entropy of `tanh(x)`, `x ~ N(mu, sigma^2)`: `H(x) + E[ln(1 - tanh(x)^2)]` by quadrature.
    fn tanh_entropy(mu: f64, sigma: f64) -> f64 {
        let (n, half) = (20_000, 12.0 * sigma);
        let dz = 2.0 * half / n as f64;
        let e: f64 = (0..=n)
            .map(|i| {
                let z = -half + i as f64 * dz;
                libm::exp(-0.5 * (z / sigma).powi(2)) / (sigma * (2.0 * PI).sqrt()) * ln_sech2(mu + z) * dz
            })
            .sum();
        0.5 * libm::log(2.0 * PI * std::f64::consts::E * sigma * sigma) + e
    }

    /// Entropy of the radial squash of `N(0, sigma^2 I_2)`: the radius is Rayleigh, and
    /// `ln |det| = ln(1 - tanh(r)^2) + ln(tanh(r) / r)`.
    fn radial_entropy(sigma: f64) -> f64 {
        let (n, top) = (20_000, 12.0 * sigma);
        let dr = top / n as f64;
        let e: f64 = (0..n)
            .map(|i| {
                let r = (i as f64 + 0.5) * dr;
                let p = r / (sigma * sigma) * libm::exp(-0.5 * (r / sigma).powi(2));
                p * (ln_sech2(r) + libm::log(libm::tanh(r) / r)) * dr
            })
            .sum();
        libm::log(2.0 * PI * std::f64::consts::E * sigma * sigma) + e
    }

    /// The constants are the families' maxima: reached (to 1e-4) and never exceeded over a grid
    /// of widths (and of means for tanh, where a shifted mean loses entropy).
    #[test]
    fn max_entropy_constants_are_the_squashed_gaussians_maxima() {
        let widths = || (0..=90).map(|k| 0.4 + 0.01 * k as f64);
        let tanh_best = widths().map(|s| tanh_entropy(0.0, s)).fold(f64::NEG_INFINITY, f64::max);
        assert!((tanh_best - MAX_TANH_ENTROPY).abs() < 1e-4, "tanh maximum {tanh_best}");
        assert!(widths().all(|s| tanh_entropy(0.5, s) < MAX_TANH_ENTROPY - 0.01));
        let radial_best = widths().map(radial_entropy).fold(f64::NEG_INFINITY, f64::max);
        assert!((radial_best - MAX_RADIAL_PAIR_ENTROPY).abs() < 1e-4, "radial maximum {radial_best}");
        let radial = Squash::Radial { pairs: vec![(0, 1), (2, 3)], singles: vec![4] };
        assert!((radial.max_entropy(5) - (2.0 * MAX_RADIAL_PAIR_ENTROPY + MAX_TANH_ENTROPY)).abs() < 1e-12);
        assert!((Squash::Tanh.max_entropy(40) - 27.344).abs() < 1e-3);
    }

    /// `exp(-(bound^2 |a|^2 / 2 + const))` integrates to 1 over [-1, 1] and over the unit disk:
    /// the noise prior is a density where the squash maps, so `log pi - log p` estimates a KL.
    #[test]
    fn the_noise_prior_is_normalised_where_the_squash_maps() {
        let bound = 1.5;
        let k = 0.5 * bound * bound;
        let single = Squash::Tanh.prior_log_norm(1, bound);
        let n = 20_000;
        let da = 2.0 / n as f64;
        let line: f64 =
            (0..n).map(|i| -1.0 + (i as f64 + 0.5) * da).map(|a| libm::exp(-(k * a * a + single)) * da).sum();
        assert!((line - 1.0).abs() < 1e-6, "{line}");
        let pair = Squash::Radial { pairs: vec![(0, 1)], singles: vec![] }.prior_log_norm(2, bound);
        let dr = 1.0 / n as f64;
        let disk: f64 =
            (0..n).map(|i| (i as f64 + 0.5) * dr).map(|r| 2.0 * PI * r * libm::exp(-(k * r * r + pair)) * dr).sum();
        assert!((disk - 1.0).abs() < 1e-6, "{disk}");
    }
}
