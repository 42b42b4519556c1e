//! Feed-forward networks over one flat parameter vector: plain and equivariant linear layers
//! (optionally with a residual plain path, RPP), LayerNorm (plain, or field-tied for regular
//! fields: one layer, [`Layer::Norm`]), Tanh, ReLU, and the invariant group-pooling head of a
//! critic. Forward keeps a [`Tape`]; backward adds parameter gradients
//! into a flat gradient vector and returns the input gradient when asked.
//!
//! Parameters live in `Net::params`; [`Net::expand`] turns them into the dense matrices the
//! forward and backward passes use (after construction, every optimiser step and every load).
//! A plain layer stores its weight as `n_in x n_out` (the layout `x W` reads), so its expanded
//! matrix is a copy; an equivariant layer expands its basis coefficients (see [`crate::equi`]).

use equigym_nn::gemm::transpose;
use equigym_nn::{gemm, layer_norm, ops, Real, Trans};
use serde::{Deserialize, Serialize};

use crate::equi::Basis;
use crate::fourier::{Circulant, ORDER};
use crate::rng::Rng;

/// Weight decay of the equivariant path of an RPP layer (Finzi et al. 2021, the paper).
pub const RPP_EQUI_DECAY: f64 = 1e-5;
/// Weight decay of the plain path of an RPP layer.
pub const RPP_PLAIN_DECAY: f64 = 1e-2;

/// Where a linear layer's parameters live and how they expand.
#[derive(Clone, Debug)]
pub enum LinearKind {
    /// Weight (`n_in x n_out`) at `w`, bias (`n_out`) at `b`.
    Dense { w: usize, b: usize },
    /// Basis coefficients at `w` (weights then biases); `plain`: an RPP path's (weight, bias).
    Equi { basis: std::sync::Arc<Basis>, w: usize, plain: Option<(usize, usize)> },
}

/// A linear layer and its expanded matrices.
#[derive(Clone, Debug)]
pub struct Linear<T> {
    pub n_in: usize,
    pub n_out: usize,
    pub kind: LinearKind,
    /// `n_in x n_out` (forward).
    wt: Vec<T>,
    /// `n_out x n_in` (input gradient).
    w: Vec<T>,
    bias: Vec<T>,
}

/// A layer of a [`Net`].
#[derive(Clone, Debug)]
pub enum Layer<T> {
    Linear(Linear<T>),
    /// LayerNorm over all `fields x order` units of a row, with one gain and one shift per
    /// group of `order` consecutive units (at `g` and `s`, `fields` each). `order` 1 is the
    /// plain LayerNorm (one gain and shift per feature). Over regular fields (`order` = the
    /// group's order) it is the field-tied norm: the row's mean and variance are invariant under
    /// the group's cyclic shifts within fields and the tied gain and shift commute with them, so
    /// the layer is exactly equivariant. `gain` and `shift` hold the per-unit expansion
    /// (refreshed by [`Net::expand`]).
    Norm {
        fields: usize,
        order: usize,
        g: usize,
        s: usize,
        gain: Vec<T>,
        shift: Vec<T>,
    },
    Tanh,
    Relu,
    /// Critic head: `q = b + sum_f w_f max_a h(f, a)` over `fields` regular fields of size
    /// `order` (invariant), plus an RPP plain path `b' + v . h` when `plain` is given.
    PoolHead {
        fields: usize,
        order: usize,
        w: usize,
        b: usize,
        plain: Option<(usize, usize)>,
    },
    /// A regular -> regular C8-equivariant layer run in the Fourier basis ([`crate::fourier`]).
    Circulant(Circulant<T>),
}

/// The first position of a field's largest value, and that value (a NaN never wins). Written
/// without a data-dependent branch: the critic head's group pooling compares random values, and
/// the branchy loop's mispredictions cost 8.7 % of an Equi-DSRL gradient step (`perf` on
/// `examples/bench --only equi`); the selects give the same result.
#[inline(always)]
fn first_argmax<T: Real>(field: &[T]) -> (usize, T) {
    let (mut best, mut top) = (0, field[0]);
    for (a, &v) in field.iter().enumerate().skip(1) {
        let wins = v > top;
        best = if wins { a } else { best };
        top = if wins { v } else { top };
    }
    (best, top)
}

/// Activations kept by a forward pass for the backward pass.
#[derive(Clone, Debug, Default)]
pub struct Tape<T> {
    pub rows: usize,
    /// `acts[0]` is the input, `acts[l + 1]` the output of layer `l` (left empty for a
    /// LayerNorm that feeds a Tanh: the two run fused, and only the Tanh's output is kept).
    pub acts: Vec<Vec<T>>,
    /// LayerNorm: mean, then 1/std per row (concatenated; [`layer_norm::layer_norm_stats`]).
    aux: Vec<Vec<T>>,
    /// PoolHead: the argmax position of each field, per row.
    argmax: Vec<Vec<u32>>,
    /// Reused buffer of the Fourier layers' forward pass.
    yhat: Vec<T>,
}

/// Buffers a backward pass reuses from call to call, so that a gradient step allocates no
/// activation buffers once warm (the LayerNorm kernels in `equigym_nn::ops` still take a
/// per-call scratch of 16 x width floats, which belongs here). Fresh buffers each pass cost page faults: before they were kept, 23 % of a DSRL
/// gradient step's time was spent in the kernel (`perf` on `examples/bench --only dsrl`).
#[derive(Clone, Debug, Default)]
pub struct Workspace<T> {
    d: Vec<T>,
    next: Vec<T>,
    lin: Vec<T>,
    dyhat: Vec<T>,
    gm: Vec<T>,
}

impl<T: Real> Tape<T> {
    pub fn output(&self) -> &[T] {
        self.acts.last().map_or(&[], |v| &v[..])
    }
}

/// A network: layers over one parameter vector.
#[derive(Clone, Debug)]
pub struct Net<T> {
    pub n_in: usize,
    pub n_out: usize,
    pub layers: Vec<Layer<T>>,
    pub params: Vec<T>,
    /// (end, weight decay) segments of `params`, in order (RPP gives two strengths).
    pub decay: Vec<(usize, f64)>,
}

/// Builds a [`Net`] layer by layer, allocating and initialising parameters.
pub struct NetBuilder<'a, T> {
    net: Net<T>,
    width: usize,
    rng: &'a mut Rng,
    /// Per parameter: its weight decay (turned into segments by `build`).
    decay_of: Vec<f64>,
}

impl<'a, T: Real> NetBuilder<'a, T> {
    pub fn new(n_in: usize, rng: &'a mut Rng) -> Self {
        Self {
            net: Net { n_in, n_out: n_in, layers: Vec::new(), params: Vec::new(), decay: Vec::new() },
            width: n_in,
            rng,
            decay_of: Vec::new(),
        }
    }

    fn alloc(&mut self, n: usize, bound: f64, decay: f64) -> usize {
        let at = self.net.params.len();
        for _ in 0..n {
            let v = if bound == 0.0 { 0.0 } else { (2.0 * self.rng.uniform() - 1.0) * bound };
            self.net.params.push(T::from_f64(v));
        }
        self.decay_of.extend(std::iter::repeat_n(decay, n));
        at
    }

    fn alloc_const(&mut self, n: usize, value: f64, decay: f64) -> usize {
        let at = self.net.params.len();
        self.net.params.extend(std::iter::repeat_n(T::from_f64(value), n));
        self.decay_of.extend(std::iter::repeat_n(decay, n));
        at
    }

    /// A plain linear layer (PyTorch's default initialisation: U(+-1/sqrt(fan_in))).
    pub fn dense(mut self, n_out: usize) -> Self {
        let n_in = self.width;
        let bound = 1.0 / (n_in as f64).sqrt();
        let w = self.alloc(n_in * n_out, bound, 0.0);
        let b = self.alloc(n_out, bound, 0.0);
        self.push_linear(LinearKind::Dense { w, b }, n_out);
        self
    }

    /// An equivariant linear layer with this basis (coefficients U(+-1/sqrt(n_in)), zero bias),
    /// with a parallel plain path when `residual` (RPP: decays [`RPP_EQUI_DECAY`] and
    /// [`RPP_PLAIN_DECAY`]).
    pub fn equi(mut self, basis: std::sync::Arc<Basis>, residual: bool) -> Self {
        debug_assert_eq!(basis.n_in, self.width);
        let n_out = basis.n_out;
        let bound = 1.0 / (basis.fan_in() as f64).sqrt();
        let equi_decay = if residual { RPP_EQUI_DECAY } else { 0.0 };
        let w = self.alloc(basis.n_weights, bound, equi_decay);
        self.alloc_const(basis.n_bias, 0.0, equi_decay);
        let plain = residual.then(|| {
            let pw = self.alloc(basis.n_in * n_out, bound, RPP_PLAIN_DECAY);
            let pb = self.alloc(n_out, bound, RPP_PLAIN_DECAY);
            (pw, pb)
        });
        self.push_linear(LinearKind::Equi { basis, w, plain }, n_out);
        self
    }

    fn push_linear(&mut self, kind: LinearKind, n_out: usize) {
        let n_in = self.width;
        self.net.layers.push(Layer::Linear(Linear {
            n_in,
            n_out,
            kind,
            wt: vec![T::ZERO; n_in * n_out],
            w: vec![T::ZERO; n_in * n_out],
            bias: vec![T::ZERO; n_out],
        }));
        self.width = n_out;
    }

    /// A regular -> regular equivariant layer in the Fourier basis (`fields` output fields).
    pub fn circulant(mut self, fields: usize) -> Self {
        let f_in = self.width / ORDER;
        let bound = Circulant::<T>::init_scale() / (self.width as f64).sqrt();
        let w = self.alloc(Circulant::<T>::num_weights(f_in, fields), bound, 0.0);
        let b = self.alloc_const(fields, 0.0, 0.0);
        self.net.layers.push(Layer::Circulant(Circulant::new(f_in, fields, w, b)));
        self.width = fields * ORDER;
        self
    }

    /// A plain LayerNorm over the current features (gain 1, shift 0, no weight decay).
    pub fn layer_norm(self) -> Self {
        self.field_norm(1, 0.0)
    }

    /// A field-tied LayerNorm over the current regular fields of size `order` (gain 1, shift 0),
    /// its parameters with weight `decay`.
    pub fn field_norm(mut self, order: usize, decay: f64) -> Self {
        let n = self.width;
        let fields = n / order;
        debug_assert_eq!(fields * order, n);
        let g = self.alloc_const(fields, 1.0, decay);
        let s = self.alloc_const(fields, 0.0, decay);
        let (gain, shift) = (vec![T::ONE; n], vec![T::ZERO; n]);
        self.net.layers.push(Layer::Norm { fields, order, g, s, gain, shift });
        self
    }

    pub fn tanh(mut self) -> Self {
        self.net.layers.push(Layer::Tanh);
        self
    }

    pub fn relu(mut self) -> Self {
        self.net.layers.push(Layer::Relu);
        self
    }

    /// The invariant critic head over regular fields (one output).
    pub fn pool_head(mut self, order: usize, residual: bool) -> Self {
        let fields = self.width / order;
        let bound = 1.0 / (fields as f64).sqrt();
        let w = self.alloc(fields, bound, 0.0);
        let b = self.alloc(1, bound, 0.0);
        let plain = residual.then(|| {
            let pbound = 1.0 / (self.width as f64).sqrt();
            let pw = self.alloc(self.width, pbound, RPP_PLAIN_DECAY);
            let pb = self.alloc(1, pbound, RPP_PLAIN_DECAY);
            (pw, pb)
        });
        self.net.layers.push(Layer::PoolHead { fields, order, w, b, plain });
        self.width = 1;
        self
    }

    pub fn build(mut self) -> Net<T> {
        self.net.n_out = self.width;
        let mut segments: Vec<(usize, f64)> = Vec::new();
        for (i, d) in self.decay_of.iter().enumerate() {
            match segments.last_mut() {
                Some((end, last)) if *last == *d => *end = i + 1,
                _ => segments.push((i + 1, *d)),
            }
        }
        self.net.decay = segments;
        self.net.expand();
        self.net
    }
}

impl<T: Real> Net<T> {
    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    /// Expand the parameters into the layers' dense matrices (after every change of `params`).
    pub fn expand(&mut self) {
        let params = &self.params;
        for layer in &mut self.layers {
            if let Layer::Circulant(c) = layer {
                c.expand(params);
                continue;
            }
            if let Layer::Norm { order, g, s, gain, shift, .. } = layer {
                for (j, (gj, sj)) in gain.iter_mut().zip(shift.iter_mut()).enumerate() {
                    *gj = params[*g + j / *order];
                    *sj = params[*s + j / *order];
                }
                continue;
            }
            let Layer::Linear(l) = layer else { continue };
            let (n_in, n_out) = (l.n_in, l.n_out);
            match &l.kind {
                LinearKind::Dense { w, b } => {
                    l.wt.copy_from_slice(&params[*w..*w + n_in * n_out]);
                    l.bias.copy_from_slice(&params[*b..*b + n_out]);
                }
                LinearKind::Equi { basis, w, plain } => {
                    match plain {
                        Some((pw, pb)) => {
                            l.wt.copy_from_slice(&params[*pw..*pw + n_in * n_out]);
                            l.bias.copy_from_slice(&params[*pb..*pb + n_out]);
                        }
                        None => {
                            l.wt.fill(T::ZERO);
                            l.bias.fill(T::ZERO);
                        }
                    }
                    for &(d, p, c) in &basis.weights {
                        let d = d as usize;
                        l.wt[d] += params[*w + p as usize] * T::from_f64(c);
                    }
                    let bias_at = *w + basis.n_weights;
                    for &(o, p) in &basis.bias {
                        l.bias[o as usize] += params[bias_at + p as usize];
                    }
                }
            }
            transpose(n_in, n_out, &l.wt, &mut l.w);
        }
    }

    /// Whether layer `l` is a LayerNorm followed by a Tanh: the two run as one kernel
    /// ([`layer_norm::layer_norm`] with `then_tanh`), which reads the rows once while they sit in L1.
    fn norm_feeds_tanh(&self, l: usize) -> bool {
        matches!(self.layers[l], Layer::Norm { .. }) && matches!(self.layers.get(l + 1), Some(Layer::Tanh))
    }

    /// Whether layer `l` is a Tanh that the LayerNorm before it runs ([`Self::norm_feeds_tanh`]).
    fn tanh_fused_into_norm(&self, l: usize) -> bool {
        l > 0 && self.norm_feeds_tanh(l - 1)
    }

    /// Forward a batch (`rows x n_in`, row-major); the output is `tape.output()`.
    pub fn forward(&self, x: &[T], rows: usize, tape: &mut Tape<T>) {
        let nl = self.layers.len();
        tape.rows = rows;
        tape.acts.resize_with(nl + 1, Vec::new);
        tape.aux.resize_with(nl, Vec::new);
        tape.argmax.resize_with(nl, Vec::new);
        tape.acts[0].clear();
        tape.acts[0].extend_from_slice(&x[..rows * self.n_in]);
        let mut width = self.n_in;
        for (l, layer) in self.layers.iter().enumerate() {
            if self.tanh_fused_into_norm(l) {
                continue;
            }
            let fused = self.norm_feeds_tanh(l);
            let (before, after) = tape.acts.split_at_mut(l + 1);
            let input = &before[l];
            // a LayerNorm that feeds a Tanh writes the Tanh's output (its own is not kept)
            let out = &mut after[usize::from(fused)];
            match layer {
                Layer::Linear(lin) => {
                    out.resize(rows * lin.n_out, T::ZERO);
                    ops::fill_bias(out, &lin.bias);
                    gemm(rows, lin.n_out, lin.n_in, input, Trans::N, &lin.wt, out, true);
                    width = lin.n_out;
                }
                Layer::Norm { fields, order, gain, shift, .. } => {
                    let n = fields * order;
                    ops::resize_for_overwrite(out, input.len());
                    let stats = &mut tape.aux[l];
                    ops::resize_for_overwrite(stats, 2 * rows);
                    layer_norm::layer_norm(input, out, n, gain, shift, stats, fused);
                }
                Layer::Tanh => {
                    ops::resize_for_overwrite(out, input.len());
                    ops::tanh_into(input, out);
                }
                Layer::Circulant(c) => {
                    c.forward(&self.params, input, rows, out, &mut tape.aux[l], &mut tape.yhat);
                    width = c.f_out * ORDER;
                }
                Layer::Relu => {
                    ops::resize_for_overwrite(out, input.len());
                    ops::relu_into(input, out);
                }
                Layer::PoolHead { fields, order, w, b, plain } => {
                    out.resize(rows, T::ZERO);
                    let am = &mut tape.argmax[l];
                    am.resize(rows * fields, 0);
                    for r in 0..rows {
                        let h = &input[r * width..(r + 1) * width];
                        let mut q = self.params[*b];
                        for f in 0..*fields {
                            let (best, top) = first_argmax(&h[f * order..(f + 1) * order]);
                            am[r * fields + f] = best as u32;
                            q += top * self.params[*w + f];
                        }
                        if let Some((pw, pb)) = plain {
                            let mut s = self.params[*pb];
                            for (i, v) in h.iter().enumerate() {
                                s += *v * self.params[pw + i];
                            }
                            q += s;
                        }
                        out[r] = q;
                    }
                    width = 1;
                }
            }
        }
    }

    /// Backward from `dy` (gradient of the output, `rows x n_out`). Adds parameter gradients
    /// into `grads` when given; returns the input gradient (held in `ws`) when `want_dx`.
    pub fn backward<'w>(
        &self,
        tape: &Tape<T>,
        dy: &[T],
        mut grads: Option<&mut [T]>,
        want_dx: bool,
        ws: &'w mut Workspace<T>,
    ) -> Option<&'w [T]> {
        let rows = tape.rows;
        let Workspace { d, next, lin: scratch, dyhat, gm } = ws;
        d.clear();
        d.extend_from_slice(&dy[..rows * self.n_out]);
        for (l, layer) in self.layers.iter().enumerate().rev() {
            if self.tanh_fused_into_norm(l) {
                continue;
            }
            let input = &tape.acts[l];
            let output = &tape.acts[l + 1];
            let need_dx = want_dx || l > 0;
            match layer {
                Layer::Linear(lin) => {
                    let (n_in, n_out) = (lin.n_in, lin.n_out);
                    if let Some(g) = grads.as_deref_mut() {
                        linear_param_grads(lin, input, d, rows, g, scratch);
                    }
                    if need_dx {
                        ops::resize_for_overwrite(next, rows * n_in);
                        gemm(rows, n_in, n_out, d, Trans::N, &lin.w, next, false);
                        std::mem::swap(d, next);
                    }
                }
                Layer::Norm { fields, order, g, s, gain, .. } => {
                    let n = fields * order;
                    let stats = &tape.aux[l];
                    let tanh_out = self.norm_feeds_tanh(l).then(|| &tape.acts[l + 2][..]);
                    match grads.as_deref_mut() {
                        Some(gr) => {
                            // per-unit gradients first, then each field's sum over its units
                            // (bitwise the direct sum for order 1: `grads` start at zero)
                            scratch.clear();
                            scratch.resize(2 * n, T::ZERO);
                            let (dg, ds) = scratch.split_at_mut(n);
                            layer_norm::layer_norm_backward(d, n, gain, input, stats, tanh_out, Some((dg, ds)));
                            for (f, (dgf, dsf)) in dg.chunks_exact(*order).zip(ds.chunks_exact(*order)).enumerate() {
                                for (a, b) in dgf.iter().zip(dsf) {
                                    gr[*g + f] += *a;
                                    gr[*s + f] += *b;
                                }
                            }
                        }
                        None => layer_norm::layer_norm_backward(d, n, gain, input, stats, tanh_out, None),
                    }
                }
                Layer::Tanh => ops::tanh_backward(output, d),
                Layer::Circulant(c) => {
                    c.backward(&tape.aux[l], d, rows, grads.as_deref_mut(), need_dx.then_some(&mut *next), dyhat, gm);
                    if need_dx {
                        std::mem::swap(d, next);
                    }
                }
                Layer::Relu => ops::relu_backward(output, d),
                Layer::PoolHead { fields, order, w, b, plain } => {
                    let head = PoolHeadRef { fields: *fields, order: *order, w: *w, b: *b, plain: *plain };
                    let am = &tape.argmax[l];
                    if let Some(g) = grads.as_deref_mut() {
                        head.param_grads(input, am, d, rows, g);
                    }
                    if need_dx {
                        head.input_grads(&self.params, am, d, rows, next);
                        std::mem::swap(d, next);
                    }
                }
            }
            if l == 0 && !want_dx {
                return None;
            }
        }
        Some(&d[..])
    }

    /// Convert to another float type (the f64 twin of an f32 net for parity tests).
    pub fn cast<U: Real>(&self) -> Net<U> {
        let layers = self
            .layers
            .iter()
            .map(|l| match l {
                Layer::Linear(lin) => Layer::Linear(Linear {
                    n_in: lin.n_in,
                    n_out: lin.n_out,
                    kind: lin.kind.clone(),
                    wt: vec![U::ZERO; lin.wt.len()],
                    w: vec![U::ZERO; lin.w.len()],
                    bias: vec![U::ZERO; lin.bias.len()],
                }),
                Layer::Norm { fields, order, g, s, .. } => Layer::Norm {
                    fields: *fields,
                    order: *order,
                    g: *g,
                    s: *s,
                    gain: vec![U::ONE; fields * order],
                    shift: vec![U::ZERO; fields * order],
                },
                Layer::Tanh => Layer::Tanh,
                Layer::Relu => Layer::Relu,
                Layer::PoolHead { fields, order, w, b, plain } => {
                    Layer::PoolHead { fields: *fields, order: *order, w: *w, b: *b, plain: *plain }
                }
                Layer::Circulant(c) => Layer::Circulant(Circulant::new(c.f_in, c.f_out, c.w, c.b)),
            })
            .collect();
        let mut net = Net {
            n_in: self.n_in,
            n_out: self.n_out,
            layers,
            params: self.params.iter().map(|v| U::from_f64(v.to_f64())).collect(),
            decay: self.decay.clone(),
        };
        net.expand();
        net
    }

    /// The parameters as plain bytes-friendly values (for checkpoints).
    pub fn params_f64(&self) -> Vec<f64> {
        self.params.iter().map(|v| v.to_f64()).collect()
    }
}

/// A network's parameters in a checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SavedParams<T>(pub Vec<T>);

/// A linear layer's parameter gradients for output gradients `d` at `input` (`rows` rows), added
/// into `g`; an equivariant layer's dense gradient goes through `scratch` and back onto its basis
/// coefficients (and its plain path, for Approx-Equi).
fn linear_param_grads<T: Real>(lin: &Linear<T>, input: &[T], d: &[T], rows: usize, g: &mut [T], scratch: &mut Vec<T>) {
    let (n_in, n_out) = (lin.n_in, lin.n_out);
    match &lin.kind {
        LinearKind::Dense { w, b } => {
            gemm(n_in, n_out, rows, input, Trans::T, d, &mut g[*w..*w + n_in * n_out], true);
            ops::add_column_sums(d, &mut g[*b..*b + n_out]);
        }
        LinearKind::Equi { basis, w, plain } => {
            scratch.clear();
            scratch.resize(n_in * n_out + n_out, T::ZERO);
            let (gw, gb) = scratch.split_at_mut(n_in * n_out);
            gemm(n_in, n_out, rows, input, Trans::T, d, gw, false);
            ops::add_column_sums(d, gb);
            for &(e, p, c) in &basis.weights {
                let i = *w + p as usize;
                g[i] += gw[e as usize] * T::from_f64(c);
            }
            let bias_at = *w + basis.n_weights;
            for &(o, p) in &basis.bias {
                g[bias_at + p as usize] += gb[o as usize];
            }
            if let Some((pw, pb)) = plain {
                for (gi, v) in g[*pw..*pw + n_in * n_out].iter_mut().zip(gw.iter()) {
                    *gi += *v;
                }
                for (gi, v) in g[*pb..*pb + n_out].iter_mut().zip(gb.iter()) {
                    *gi += *v;
                }
            }
        }
    }
}

/// The group-pooling head's shape and parameter offsets, for its backward pass.
#[derive(Clone, Copy)]
struct PoolHeadRef {
    fields: usize,
    order: usize,
    w: usize,
    b: usize,
    plain: Option<(usize, usize)>,
}

impl PoolHeadRef {
    /// Parameter gradients for output gradients `d` (one per row) at `input`, through each
    /// field's arg-max `am`, added into `g`.
    fn param_grads<T: Real>(&self, input: &[T], am: &[u32], d: &[T], rows: usize, g: &mut [T]) {
        let (fields, order) = (self.fields, self.order);
        let width = fields * order;
        for r in 0..rows {
            let h = &input[r * width..(r + 1) * width];
            for f in 0..fields {
                let a = am[r * fields + f] as usize;
                g[self.w + f] += d[r] * h[f * order + a];
            }
            g[self.b] += d[r];
            if let Some((pw, pb)) = self.plain {
                for (i, v) in h.iter().enumerate() {
                    g[pw + i] += d[r] * *v;
                }
                g[pb] += d[r];
            }
        }
    }

    /// Input gradients into `next` (rows x fields * order, overwritten).
    fn input_grads<T: Real>(&self, params: &[T], am: &[u32], d: &[T], rows: usize, next: &mut Vec<T>) {
        let (fields, order) = (self.fields, self.order);
        let width = fields * order;
        next.clear();
        next.resize(rows * width, T::ZERO);
        for r in 0..rows {
            let row = &mut next[r * width..(r + 1) * width];
            if let Some((pw, _)) = self.plain {
                for (i, v) in row.iter_mut().enumerate() {
                    *v = d[r] * params[pw + i];
                }
            }
            for f in 0..fields {
                let a = am[r * fields + f] as usize;
                row[f * order + a] += d[r] * params[self.w + f];
            }
        }
    }
}
