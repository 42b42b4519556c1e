//! The runtime of an exported Equivariant Diffusion Policy (EDP): load a safetensors file
//! written by `python -m baselines.edp train`, and turn (observation, latent noise) into an
//! action chunk with deterministic DDIM, batched.
//!
//! The file holds a plain MLP (the escnn model's exported linear layers, already permuted into
//! the task's natural field order), the DDPM schedule (`alphas_cumprod`), the timestep
//! embedding table and the normalisation. Sampling never clips the predicted clean sample:
//! elementwise clipping would break equivariance.
//!
//! The network runs on the shared kernels of `equigym-nn` ([`equigym_nn::gemm`]): float32 by
//! default ([`Precision::F32`], what the latent environments use), float64 on request
//! ([`Precision::F64`], for parity with PyTorch in float64). Either way every row's chunk is
//! summed in one fixed order, so it is bit for bit the same whatever the batch size, the row
//! split across threads or the CPU's vector width (see the `equigym-nn` docs). The DDIM update
//! and the (de)normalisation stay in float64.
//!
//! # The Fourier kernel
//!
//! A C8 EDP's hidden layers map regular fields to regular fields, so each 8 x 8 block of their
//! exported matrices is circulant, and in the Fourier (irrep) basis the layer is block-diagonal
//! by frequency: 14 instead of 64 multiply-adds per field pair
//! ([`equigym_nn::fourier::Circulant`], the kernel the agents' equivariant layers run on). The
//! first time a policy needs them (its first sample on [`Kernel::Fourier`]), every layer whose
//! blocks are circulant (to float32 rounding: the file stores the escnn expansion rounded to
//! float32) and whose bias is constant over each field gets a Fourier copy, its coefficients
//! projected from the dense matrix; the Fourier kernel runs those layers in that basis, the
//! others (the input and output layers, every layer of a plain EDP) dense. A policy that only
//! ever runs dense pays nothing for them, at load or in memory.
//!
//! It is the same map up to float rounding, not the same bits, and it is the default: several
//! times the dense kernel's chunks per second on the shipped EDPs, the more the wider their
//! hidden layers (`benches/edp_kernels.py`), and its float32 chunks are at least as close to the
//! float64 map as the dense kernel's (`wrappers/tests/edp.rs`). The dense kernel
//! ([`Kernel::Dense`]) stays for the runs recorded on it, which replay only there: a steering run
//! names the Fourier kernel in its `run.json` and its checkpoint's fingerprint, and one that
//! names no kernel ran dense. Like the dense one the Fourier kernel sums every row in a fixed
//! order, so its results do not depend on the batch, the thread split or the CPU's vector width
//! either.

use std::path::Path;
use std::sync::OnceLock;

use equigym_envs::Layout;
use equigym_nn::fourier::{dft_matrix, Circulant, ORDER};
use equigym_nn::{gemm, ops, Real, Trans};
use safetensors::{Dtype, SafeTensors};

use crate::error::{Error, Result};

/// File format tag written by the trainer.
pub const FORMAT: &str = "equigym-edp-1";

/// Arithmetic of the network (the DDIM update is float64 either way).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Precision {
    /// float32 network (the default).
    #[default]
    F32,
    /// float64 network (parity tests).
    F64,
}

impl std::str::FromStr for Precision {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "f32" | "float32" => Ok(Precision::F32),
            "f64" | "float64" => Ok(Precision::F64),
            other => {
                Err(equigym_envs::EnvError::InvalidConfig(format!("precision must be 'f32' or 'f64', got '{other}'"))
                    .into())
            }
        }
    }
}

/// Which kernel runs the layers that have a Fourier copy (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Kernel {
    /// Every layer as a dense matrix product: the file's own matrices, the kernel of the runs
    /// recorded before the Fourier kernel existed (a `run.json` that names no kernel).
    Dense,
    /// Regular-to-regular layers in the Fourier basis (4.6x fewer multiply-adds there); layers
    /// without a Fourier copy run dense. The default.
    #[default]
    Fourier,
}

impl Kernel {
    /// The name [`Kernel::from_str`](std::str::FromStr) reads.
    pub fn as_str(self) -> &'static str {
        match self {
            Kernel::Dense => "dense",
            Kernel::Fourier => "fourier",
        }
    }
}

impl std::str::FromStr for Kernel {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "dense" => Ok(Kernel::Dense),
            "fourier" => Ok(Kernel::Fourier),
            other => Err(equigym_envs::EnvError::InvalidConfig(format!(
                "kernel must be 'dense' or 'fourier', got '{other}'"
            ))
            .into()),
        }
    }
}

/// Largest deviation from a circulant block (relative to the layer's largest weight) that still
/// counts as one: the file's float32 rounding of the escnn expansion is about 1e-7.
const CIRCULANT_TOLERANCE: f64 = 1e-5;

/// A layer's Fourier copy: the kernel and its parameters (coefficients, then one bias per
/// output field), in both precisions.
#[derive(Debug)]
struct FourierLayer {
    c32: Circulant<f32>,
    p32: Vec<f32>,
    c64: Circulant<f64>,
    p64: Vec<f64>,
}

impl FourierLayer {
    /// The Fourier copy of a dense layer, or `None` where its blocks are not circulant or its
    /// bias is not constant over each field.
    fn of(layer: &Dense) -> Option<Self> {
        let (n_in, n_out, weight, bias) = (layer.n_in, layer.n_out, &layer.wt64, &layer.bias64);
        if !n_out.is_multiple_of(ORDER) || !n_in.is_multiple_of(ORDER) || n_out == 0 || n_in == 0 {
            return None;
        }
        let (fo, fi) = (n_out / ORDER, n_in / ORDER);
        let tol = CIRCULANT_TOLERANCE * weight.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if bias.chunks_exact(ORDER).any(|f| f.iter().any(|v| (v - f[0]).abs() > tol)) {
            return None;
        }
        let t = dft_matrix();
        let n = fi * fo;
        let mut params = vec![0.0; Circulant::<f64>::num_weights(fi, fo) + fo];
        for o in 0..fo {
            for i in 0..fi {
                // Block (o, i) of the layer's matrix, D[a][b] from input i * 8 + b to output
                // o * 8 + a; the dense copy is stored (in, out).
                let d = |a: usize, b: usize| weight[(i * ORDER + b) * n_out + o * ORDER + a];
                // G = T D T^T; a circulant block is diagonal in it but for a rotation-scaling
                // [[A, -B], [B, A]] per 2-d irrep (rows 2 + 2j: re, 3 + 2j: im).
                let g = |p: usize, q: usize| -> f64 {
                    (0..ORDER).map(|a| t[p][a] * (0..ORDER).map(|b| d(a, b) * t[q][b]).sum::<f64>()).sum()
                };
                let mut gd = [[0.0; ORDER]; ORDER];
                gd[0][0] = g(0, 0);
                gd[1][1] = g(1, 1);
                params[i * fo + o] = gd[0][0];
                params[n + i * fo + o] = gd[1][1];
                for j in 0..3 {
                    let (re, im) = (2 + 2 * j, 3 + 2 * j);
                    let (a, b) = (g(re, re), g(im, re));
                    (gd[re][re], gd[im][im], gd[im][re], gd[re][im]) = (a, a, b, -b);
                    params[(2 + 2 * j) * n + i * fo + o] = a;
                    params[(3 + 2 * j) * n + i * fo + o] = b;
                }
                // The block must be what its coefficients give back: D = T^T G T.
                for a in 0..ORDER {
                    for b in 0..ORDER {
                        let back: f64 =
                            (0..ORDER).map(|p| t[p][a] * (0..ORDER).map(|q| gd[p][q] * t[q][b]).sum::<f64>()).sum();
                        if (back - d(a, b)).abs() > tol {
                            return None;
                        }
                    }
                }
            }
        }
        let nw = params.len() - fo;
        for o in 0..fo {
            params[nw + o] = bias[o * ORDER];
        }
        let mut c64 = Circulant::new(fi, fo, 0, nw);
        c64.expand(&params);
        let p32: Vec<f32> = params.iter().map(|v| *v as f32).collect();
        let c32 = c64.cast(&p32);
        Some(Self { c32, p32, c64, p64: params })
    }
}

/// The float type a sampling call runs in, with its copy of each layer's parameters.
trait Arith: Real {
    fn dense(l: &Dense) -> (&[Self], &[Self]);
    fn fourier(f: &FourierLayer) -> (&Circulant<Self>, &[Self]);
}

impl Arith for f32 {
    fn dense(l: &Dense) -> (&[f32], &[f32]) {
        (&l.wt32, &l.bias32)
    }
    fn fourier(f: &FourierLayer) -> (&Circulant<f32>, &[f32]) {
        (&f.c32, &f.p32)
    }
}

impl Arith for f64 {
    fn dense(l: &Dense) -> (&[f64], &[f64]) {
        (&l.wt64, &l.bias64)
    }
    fn fourier(f: &FourierLayer) -> (&Circulant<f64>, &[f64]) {
        (&f.c64, &f.p64)
    }
}

#[derive(Debug)]
struct Dense {
    /// Row-major (in, out): the layout `x W` reads, in both precisions.
    wt64: Vec<f64>,
    wt32: Vec<f32>,
    bias64: Vec<f64>,
    bias32: Vec<f32>,
    n_in: usize,
    n_out: usize,
}

/// Most layers a policy file may declare (the shipped ones have 3 to 5).
const MAX_LAYERS: usize = 1024;
/// Longest action chunk a policy file may declare (the shipped ones have 4).
const MAX_CHUNK_LEN: usize = 4096;

/// A loaded diffusion policy.
#[derive(Debug)]
pub struct DiffusionPolicy {
    layers: Vec<Dense>,
    /// Each layer's Fourier copy, where it has one, made on first use (see the module docs).
    fourier: OnceLock<Vec<Option<FourierLayer>>>,
    alphas_cumprod: Vec<f64>,
    time_embedding: Vec<f64>,
    time_dim: usize,
    obs_offset: Vec<f64>,
    obs_scale: Vec<f64>,
    action_offset: Vec<f64>,
    action_scale: Vec<f64>,
    /// Task id, chunk length and the rest of the file's metadata.
    pub task: String,
    pub chunk_len: usize,
    pub default_ddim_steps: usize,
    pub group: String,
    pub metadata: std::collections::HashMap<String, String>,
    /// Arithmetic of [`DiffusionPolicy::sample`] (set before sharing the policy).
    pub precision: Precision,
    /// Kernel of [`DiffusionPolicy::sample`] (set before sharing the policy).
    pub kernel: Kernel,
}

fn bad(path: &str, reason: impl Into<String>) -> Error {
    Error::Policy { path: path.into(), reason: reason.into() }
}

fn tensor(st: &SafeTensors, path: &str, name: &str, shape: &[usize]) -> Result<Vec<f64>> {
    let t = st.tensor(name).map_err(|_| bad(path, format!("missing tensor '{name}'")))?;
    if t.shape() != shape {
        return Err(bad(path, format!("tensor '{name}' has shape {:?}, expected {shape:?}", t.shape())));
    }
    let data = t.data();
    let values: Vec<f64> = match t.dtype() {
        Dtype::F32 => data.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64).collect(),
        Dtype::F64 => data.chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))).collect(),
        other => return Err(bad(path, format!("tensor '{name}' has dtype {other:?}, expected F32 or F64"))),
    };
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        return Err(bad(path, format!("tensor '{name}' holds a non-finite value ({v})")));
    }
    Ok(values)
}

fn shape_of(st: &SafeTensors, path: &str, name: &str) -> Result<Vec<usize>> {
    Ok(st.tensor(name).map_err(|_| bad(path, format!("missing tensor '{name}'")))?.shape().to_vec())
}

impl DiffusionPolicy {
    /// Load a policy file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let p = path.as_ref();
        Self::from_bytes(&Self::read_file(p)?, &p.display().to_string())
    }

    /// The bytes of a policy file (typed errors for a missing or unreadable file).
    pub fn read_file(path: impl AsRef<Path>) -> Result<Vec<u8>> {
        let p = path.as_ref();
        let name = p.display().to_string();
        std::fs::read(p).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => Error::PolicyNotFound(name.clone()),
            _ => bad(&name, format!("cannot read: {e}")),
        })
    }

    /// Load from the bytes of a policy file (`origin` names it in errors).
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Self> {
        let (_, meta) =
            SafeTensors::read_metadata(bytes).map_err(|e| bad(origin, format!("not a safetensors file ({e})")))?;
        let metadata = meta.metadata().clone().unwrap_or_default();
        let st = SafeTensors::deserialize(bytes).map_err(|e| bad(origin, format!("corrupt or truncated ({e})")))?;
        let get = |k: &str| metadata.get(k).cloned().ok_or_else(|| bad(origin, format!("metadata '{k}' is missing")));
        let format = get("format")?;
        if format != FORMAT {
            return Err(bad(origin, format!("format '{format}' is not '{FORMAT}'")));
        }
        let parse = |k: &str| -> Result<usize> {
            get(k)?.parse::<usize>().map_err(|_| bad(origin, format!("metadata '{k}' is not a count")))
        };
        let task = get("task")?;
        let chunk_len = parse("chunk_len")?;
        let num_layers = parse("num_layers")?;
        let steps = parse("num_train_timesteps")?;
        let default_ddim_steps = parse("ddim_steps")?;
        if get("activation")? != "relu" {
            return Err(bad(origin, "only relu activations are supported"));
        }
        if num_layers == 0 || chunk_len == 0 || steps == 0 {
            return Err(bad(origin, "empty network, chunk or schedule"));
        }
        // Counts come from the file: bound them before they size allocations or products.
        if num_layers > MAX_LAYERS || chunk_len > MAX_CHUNK_LEN {
            return Err(bad(
                origin,
                format!(
                    "{num_layers} layers or a chunk of {chunk_len} exceed the limits ({MAX_LAYERS}, {MAX_CHUNK_LEN})"
                ),
            ));
        }
        let mut layers = Vec::with_capacity(num_layers);
        for i in 0..num_layers {
            let shape = shape_of(&st, origin, &format!("layer{i}.weight"))?;
            if shape.len() != 2 {
                return Err(bad(origin, format!("layer{i}.weight must be 2-d, got {shape:?}")));
            }
            let (n_out, n_in) = (shape[0], shape[1]);
            if let Some(prev) = layers.last().map(|l: &Dense| l.n_out) {
                if prev != n_in {
                    return Err(bad(origin, format!("layer{i} takes {n_in} inputs but layer{} gives {prev}", i - 1)));
                }
            }
            let weight = tensor(&st, origin, &format!("layer{i}.weight"), &[n_out, n_in])?;
            let bias = tensor(&st, origin, &format!("layer{i}.bias"), &[n_out])?;
            let mut wt64 = vec![0.0; n_in * n_out];
            equigym_nn::gemm::transpose(n_out, n_in, &weight, &mut wt64);
            layers.push(Dense {
                wt32: wt64.iter().map(|v| *v as f32).collect(),
                bias32: bias.iter().map(|v| *v as f32).collect(),
                wt64,
                bias64: bias,
                n_in,
                n_out,
            });
        }
        let emb_shape = shape_of(&st, origin, "time_embedding")?;
        if emb_shape.len() != 2 || emb_shape[0] != steps {
            return Err(bad(origin, format!("time_embedding must be ({steps}, dim), got {emb_shape:?}")));
        }
        let time_dim = emb_shape[1];
        let action_dim = chunk_len * equigym_envs::ACTION_DIM;
        let obs_dim = shape_of(&st, origin, "obs_offset")?.first().copied().unwrap_or(0);
        if layers[0].n_in != obs_dim + action_dim + time_dim || layers[num_layers - 1].n_out != action_dim {
            return Err(bad(
                origin,
                format!(
                    "network maps {} -> {}, expected obs {obs_dim} + chunk {action_dim} + time {time_dim} -> {action_dim}",
                    layers[0].n_in,
                    layers[num_layers - 1].n_out
                ),
            ));
        }
        let policy = Self {
            alphas_cumprod: tensor(&st, origin, "alphas_cumprod", &[steps])?,
            time_embedding: tensor(&st, origin, "time_embedding", &[steps, time_dim])?,
            time_dim,
            obs_offset: tensor(&st, origin, "obs_offset", &[obs_dim])?,
            obs_scale: tensor(&st, origin, "obs_scale", &[obs_dim])?,
            action_offset: tensor(&st, origin, "action_offset", &[action_dim])?,
            action_scale: tensor(&st, origin, "action_scale", &[action_dim])?,
            layers,
            fourier: OnceLock::new(),
            task,
            chunk_len,
            default_ddim_steps,
            group: metadata.get("group").cloned().unwrap_or_default(),
            metadata,
            precision: Precision::default(),
            kernel: Kernel::default(),
        };
        if policy.obs_scale.iter().chain(&policy.action_scale).any(|s| *s <= 0.0) {
            return Err(bad(origin, "normalisation scales must be positive"));
        }
        if policy.alphas_cumprod.iter().any(|a| *a <= 0.0 || *a > 1.0) {
            return Err(bad(origin, "alphas_cumprod must lie in (0, 1]"));
        }
        Ok(policy)
    }

    /// Check that the policy fits an observation layout (the task's).
    pub fn check_layout(&self, task: &str, layout: &Layout) -> Result<()> {
        // The trainer's `--obs-history 2` conditions on the change of observation too; the
        // latent environments hold one observation, so such a file runs only in the trainer's
        // own rollouts (`python -m baselines.edp failures`).
        if let Some(h) = self.metadata.get("obs_history").filter(|h| h.as_str() != "1") {
            return Err(Error::Policy {
                path: self.metadata.get("path").cloned().unwrap_or_else(|| "policy".into()),
                reason: format!(
                    "conditions on {h} observations (obs_history); the latent environments give one \
                     (run it with `python -m baselines.edp failures`)"
                ),
            });
        }
        if task != self.task || layout.dim() != self.obs_dim() {
            return Err(Error::Policy {
                path: self.metadata.get("path").cloned().unwrap_or_else(|| "policy".into()),
                reason: format!(
                    "trained for task '{}' ({}-d observations), used with '{task}' ({}-d)",
                    self.task,
                    self.obs_dim(),
                    layout.dim()
                ),
            });
        }
        Ok(())
    }

    pub fn obs_dim(&self) -> usize {
        self.obs_offset.len()
    }
    /// The layers that have a Fourier copy, which [`Kernel::Fourier`] runs in that basis.
    pub fn fourier_layers(&self) -> Vec<usize> {
        let copies = self.fourier_copies();
        (0..copies.len()).filter(|&i| copies[i].is_some()).collect()
    }

    /// Every layer's Fourier copy or `None`, made the first time they are asked for (a C8
    /// policy's; a policy of another group has none).
    fn fourier_copies(&self) -> &[Option<FourierLayer>] {
        self.fourier.get_or_init(|| {
            let equivariant = self.group == "C8";
            self.layers.iter().map(|l| if equivariant { FourierLayer::of(l) } else { None }).collect()
        })
    }
    /// Dimension of a chunk (and of the latent noise).
    pub fn action_dim(&self) -> usize {
        self.action_offset.len()
    }
    pub fn num_train_timesteps(&self) -> usize {
        self.alphas_cumprod.len()
    }

    /// The DDIM timesteps for `steps` denoising steps (evenly spaced, highest first).
    pub fn ddim_timesteps(&self, steps: usize) -> Vec<usize> {
        let ratio = self.num_train_timesteps() / steps.max(1);
        (0..steps).rev().map(|i| i * ratio).collect()
    }

    /// Map absolute action chunks (rows of `action_dim`) to the policy's normalised action
    /// space, the inverse of the last step of [`DiffusionPolicy::sample`]: (a - offset) / scale.
    /// The normalisation commutes with the group (x and y share one scale without offset), so
    /// an invariant critic may read normalised chunks.
    pub fn normalize_actions(&self, chunks: &mut [f64]) {
        let ad = self.action_dim();
        for row in chunks.chunks_exact_mut(ad) {
            for (k, v) in row.iter_mut().enumerate() {
                *v = (*v - self.action_offset[k]) / self.action_scale[k];
            }
        }
    }

    /// Denoise a batch: `obs` (B x obs_dim) and `latent` (B x action_dim) -> chunks
    /// (B x action_dim, absolute actions), with `steps` deterministic DDIM steps.
    pub fn sample(&self, obs: &[f64], latent: &[f64], steps: usize, out: &mut [f64]) -> Result<()> {
        self.sample_with(self.precision, obs, latent, steps, out)
    }

    /// [`DiffusionPolicy::sample`] with the network in the given precision.
    pub fn sample_with(
        &self,
        precision: Precision,
        obs: &[f64],
        latent: &[f64],
        steps: usize,
        out: &mut [f64],
    ) -> Result<()> {
        let (od, ad) = (self.obs_dim(), self.action_dim());
        let b = latent.len() / ad.max(1);
        let check = |what: &str, v: &[f64], want: usize| equigym_envs::error::check_finite(what, v, want);
        check("latent", latent, b * ad)?;
        check("observation batch", obs, b * od)?;
        if out.len() != b * ad {
            return Err(equigym_envs::EnvError::WrongLength {
                what: "output chunk buffer".into(),
                expected: b * ad,
                got: out.len(),
            }
            .into());
        }
        if steps == 0 || steps > self.num_train_timesteps() {
            return Err(equigym_envs::EnvError::InvalidConfig(format!(
                "DDIM steps must lie in 1..={}, got {steps}",
                self.num_train_timesteps()
            ))
            .into());
        }
        let in_dim = od + ad + self.time_dim;
        let mut input = vec![0.0; b * in_dim];
        for r in 0..b {
            for k in 0..od {
                input[r * in_dim + k] = (obs[r * od + k] - self.obs_offset[k]) / self.obs_scale[k];
            }
        }
        let mut x = latent.to_vec();
        let mut eps = vec![0.0; b * ad];
        let mut s32 = Scratch::<f32>::default();
        let mut s64 = Scratch::<f64>::default();
        let ts = self.ddim_timesteps(steps);
        let copies = (self.kernel == Kernel::Fourier).then(|| self.fourier_copies());
        for (k, &t) in ts.iter().enumerate() {
            let ab = self.alphas_cumprod[t];
            let ab_prev = ts.get(k + 1).map_or(1.0, |&p| self.alphas_cumprod[p]);
            let emb = &self.time_embedding[t * self.time_dim..(t + 1) * self.time_dim];
            for r in 0..b {
                let row = &mut input[r * in_dim..(r + 1) * in_dim];
                row[od..od + ad].copy_from_slice(&x[r * ad..(r + 1) * ad]);
                row[od + ad..].copy_from_slice(emb);
            }
            match precision {
                Precision::F32 => self.forward(&input, b, &mut eps, &mut s32, copies),
                Precision::F64 => self.forward(&input, b, &mut eps, &mut s64, copies),
            }
            let (sa, s1a) = (ab.sqrt(), (1.0 - ab).sqrt());
            let (sp, s1p) = (ab_prev.sqrt(), (1.0 - ab_prev).sqrt());
            for (xi, ei) in x.iter_mut().zip(&eps) {
                let x0 = (*xi - s1a * ei) / sa;
                *xi = sp * x0 + s1p * ei;
            }
        }
        for r in 0..b {
            for k in 0..ad {
                out[r * ad + k] = x[r * ad + k] * self.action_scale[k] + self.action_offset[k];
            }
        }
        Ok(())
    }

    /// The MLP on a batch of `rows` inputs (row-major), ReLU between layers, in `T`: each layer
    /// in the Fourier basis where `copies` (the Fourier kernel's) has one, else dense. Every
    /// output is summed in one fixed order ([`equigym_nn::gemm`]), so a row's result does not
    /// depend on the batch it is in.
    fn forward<T: Arith>(
        &self,
        input: &[f64],
        rows: usize,
        out: &mut [f64],
        s: &mut Scratch<T>,
        copies: Option<&[Option<FourierLayer>]>,
    ) {
        let (a, b) = (&mut s.a, &mut s.b);
        a.clear();
        a.extend(input.iter().map(|v| T::from_f64(*v)));
        let last = self.layers.len() - 1;
        for (i, l) in self.layers.iter().enumerate() {
            if let Some(f) = copies.and_then(|c| c[i].as_ref()) {
                let (c, p) = T::fourier(f);
                c.forward(p, a, rows, b, &mut s.xhat, &mut s.yhat);
            } else {
                let (wt, bias) = T::dense(l);
                ops::resize_for_overwrite(b, rows * l.n_out);
                ops::fill_bias(b, bias);
                gemm(rows, l.n_out, l.n_in, a, Trans::N, wt, b, true);
            }
            if i < last {
                ops::relu(b);
            }
            std::mem::swap(a, b);
        }
        for (o, v) in out.iter_mut().zip(a.iter()) {
            *o = v.to_f64();
        }
    }
}

/// Activation buffers of one sampling call.
#[derive(Default)]
struct Scratch<T> {
    a: Vec<T>,
    b: Vec<T>,
    /// The Fourier kernel's blocks of a layer's input and output.
    xhat: Vec<T>,
    yhat: Vec<T>,
}
