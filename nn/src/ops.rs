//! Pointwise and per-row operations with their backward passes: bias, ReLU, Tanh, LayerNorm.
//!
//! Every reduction runs in index order on one thread (LayerNorm statistics over a row; bias,
//! gain and shift gradients over the rows of a batch), so results do not depend on threads.

use crate::{as_f32s, as_f32s_mut, Isa, Real};

/// Defines a kernel as a dispatcher over compiled copies of one `#[inline(always)]` body:
/// `$name` runs the widest copy this CPU has ([`Isa::best`]), `$on` the copy `isa` (for the
/// tests that compare them). The copies differ only in the registers LLVM may use: the
/// arithmetic is the same `+`, `-`, `*`, `/` and `sqrt` in the same order (Rust never fuses a
/// multiply and an add), so every copy gives the same bits. Before, these loops ran as SSE2
/// (4 lanes) except Tanh (AVX2); on an AVX-512 Xeon, Tanh and the LayerNorm passes were 35 %
/// of a DSRL gradient step's samples (`perf` on `examples/bench --only dsrl`).
macro_rules! kernel_copies {
    ($(#[$doc:meta])* pub fn $name:ident / $on:ident ($($arg:ident: $ty:ty),* $(,)?) => $body:ident;) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        pub fn $name<T: Real>($($arg: $ty),*) {
            $on(Isa::best(), $($arg),*)
        }

        #[doc = concat!("[`", stringify!($name), "`] in the compiled copy `isa` (the portable one where this CPU lacks it).")]
        #[allow(clippy::too_many_arguments)]
        pub fn $on<T: Real>(isa: Isa, $($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx2")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn avx512<T: Real>($($arg: $ty),*) {
                    $body($($arg),*)
                }
                #[target_feature(enable = "avx2")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn avx2<T: Real>($($arg: $ty),*) {
                    $body($($arg),*)
                }
                match isa {
                    // SAFETY: the guard checks that the CPU has the copy's features.
                    Isa::Avx512 if crate::has_avx512() => return unsafe { avx512($($arg),*) },
                    // SAFETY: as above.
                    Isa::Avx2 if crate::has_fast_fma() => return unsafe { avx2($($arg),*) },
                    _ => {}
                }
            }
            let _ = isa;
            $body($($arg),*)
        }
    };
}

/// LayerNorm's epsilon (PyTorch's default).
pub const LAYER_NORM_EPS: f64 = 1e-5;

/// Write `bias` into every row of `out` (`rows x bias.len()`), ready for an accumulating gemm.
pub fn fill_bias<T: Real>(out: &mut [T], bias: &[T]) {
    for row in out.chunks_exact_mut(bias.len().max(1)) {
        row.copy_from_slice(bias);
    }
}

kernel_copies! {
    /// `grad += sum over rows of dy` (a bias gradient), rows in order.
    pub fn add_column_sums / add_column_sums_on(dy: &[T], grad: &mut [T]) => add_column_sums_body;
}

#[inline(always)]
fn add_column_sums_body<T: Real>(dy: &[T], grad: &mut [T]) {
    for row in dy.chunks_exact(grad.len().max(1)) {
        for (g, d) in grad.iter_mut().zip(row) {
            *g += *d;
        }
    }
}

/// Resize `v` to `n` elements for a kernel that then writes every element: unlike
/// `clear` + `resize`, a buffer reused at the same length is not zeroed first.
pub fn resize_for_overwrite<T: Real>(v: &mut Vec<T>, n: usize) {
    v.resize(n, T::ZERO);
}

pub fn relu<T: Real>(x: &mut [T]) {
    for v in x {
        *v = if *v > T::ZERO { *v } else { T::ZERO };
    }
}

kernel_copies! {
    /// `y = relu(x)` (`y` as long as `x`).
    pub fn relu_into / relu_into_on(x: &[T], y: &mut [T]) => relu_into_body;
}

#[inline(always)]
fn relu_into_body<T: Real>(x: &[T], y: &mut [T]) {
    for (o, v) in y.iter_mut().zip(x) {
        *o = if *v > T::ZERO { *v } else { T::ZERO };
    }
}

kernel_copies! {
    /// `dy *= [y > 0]` (backward through ReLU, from its output).
    pub fn relu_backward / relu_backward_on(y: &[T], dy: &mut [T]) => relu_backward_body;
}

#[inline(always)]
fn relu_backward_body<T: Real>(y: &[T], dy: &mut [T]) {
    for (d, v) in dy.iter_mut().zip(y) {
        *d = if *v > T::ZERO { *d } else { T::ZERO };
    }
}

kernel_copies! {
    /// `y = tanh(x)` (`y` as long as `x`).
    pub fn tanh_into / tanh_into_on(x: &[T], y: &mut [T]) => tanh_body;
}

#[inline(always)]
fn tanh_body<T: Real>(x: &[T], y: &mut [T]) {
    for (o, v) in y.iter_mut().zip(x) {
        *o = v.tanh();
    }
}

kernel_copies! {
    /// `y = ln(x)`, bit for bit [`Real::ln`] (`libm`): the branch-free main path
    /// ([`crate::logs`]) over the whole slice, vectorised, then `libm` for any input that is not
    /// positive, normal and finite.
    pub fn ln_into / ln_into_on(x: &[T], y: &mut [T]) => ln_body;
}

#[inline(always)]
fn ln_body<T: Real>(x: &[T], y: &mut [T]) {
    for (o, v) in y.iter_mut().zip(x) {
        *o = v.ln_positive_normal();
    }
    for (o, v) in y.iter_mut().zip(x) {
        if !v.is_positive_normal() {
            *o = v.ln();
        }
    }
}

kernel_copies! {
    /// `dy *= 1 - y^2` (backward through tanh, from its output).
    pub fn tanh_backward / tanh_backward_on(y: &[T], dy: &mut [T]) => tanh_backward_body;
}

#[inline(always)]
fn tanh_backward_body<T: Real>(y: &[T], dy: &mut [T]) {
    for (d, v) in dy.iter_mut().zip(y) {
        *d *= T::ONE - *v * *v;
    }
}

/// Rows whose statistics one pass of [`layer_norm`] and [`layer_norm_backward`] accumulates side
/// by side. Each row keeps its own accumulator, summed in index order exactly as a row-at-a-time
/// loop would, so the bits do not change; interleaving only hides the adds' latency (a single
/// row's running sum is one dependent chain). With the field-tied LayerNorm of the cpu-preset
/// Equi-DSRL nets, the forward's share of a gradient step fell from 14 % to 8 % (`perf` on
/// `examples/bench --only equi`).
pub const LAYER_NORM_ROW_BLOCK: usize = 8;

/// The per-row statistics [`layer_norm`] keeps for its backward pass, in one buffer of
/// `2 x rows`: the means, then the reciprocal standard deviations.
pub fn layer_norm_stats<T>(stats: &[T]) -> (&[T], &[T]) {
    stats.split_at(stats.len() / 2)
}

/// LayerNorm over each row of `x` (`rows x n`) into `y`, with gain and shift, followed by Tanh
/// when `then_tanh` (`y = tanh(xhat * gain + shift)`, bit for bit what [`tanh_into`] gives on
/// the LayerNorm's output). Keeps each row's mean and `1/std` in `stats` (`2 x rows`, see
/// [`layer_norm_stats`]); the backward pass recomputes the normalised values from `x` with the
/// same operations.
///
/// # Why fused, and why the normalised values are not kept
///
/// At batch 256 a 192-unit activation is 196 KB, and a gradient step's activations (about 20 MB)
/// do not fit in the core's L2: the kernels wait on memory, not arithmetic. LayerNorm then Tanh
/// as two kernels wrote three arrays (normalised values, LayerNorm output, Tanh output) and read
/// two; fused, a block of rows is read once while it sits in L1 and one array is written. The
/// same bits come out (the golden runs are unchanged).
#[allow(clippy::too_many_arguments)]
pub fn layer_norm<T: Real>(x: &[T], y: &mut [T], n: usize, gain: &[T], shift: &[T], stats: &mut [T], then_tanh: bool) {
    layer_norm_on(Isa::best(), x, y, n, gain, shift, stats, then_tanh)
}

/// [`layer_norm`] in the compiled copy `isa` (the portable one where this CPU lacks it).
#[allow(clippy::too_many_arguments)]
pub fn layer_norm_on<T: Real>(
    isa: Isa,
    x: &[T],
    y: &mut [T],
    n: usize,
    gain: &[T],
    shift: &[T],
    stats: &mut [T],
    then_tanh: bool,
) {
    let rows = (stats.len() / 2).min(x.len() / n.max(1));
    let (mean, rstd) = stats.split_at_mut(stats.len() / 2);
    let (gain, shift) = (&gain[..n], &shift[..n]);
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if isa == Isa::Avx512 && crate::has_avx512() {
        if let (Some(x32), Some(y32), Some(g32), Some(s32), Some(m32), Some(r32)) =
            (as_f32s(x), as_f32s_mut(y), as_f32s(gain), as_f32s(shift), as_f32s_mut(mean), as_f32s_mut(rstd))
        {
            // SAFETY: the CPU has AVX-512 F and VL (checked above).
            done = unsafe { rows16::layer_norm(x32, y32, n, g32, s32, m32, r32, rows, then_tanh) };
        }
    }
    layer_norm_rows_on(
        isa,
        &x[done * n..rows * n],
        &mut y[done * n..rows * n],
        n,
        gain,
        shift,
        &mut mean[done..rows],
        &mut rstd[done..rows],
        then_tanh,
    );
}

kernel_copies! {
    /// The rows of [`layer_norm`], `LAYER_NORM_ROW_BLOCK` at a time (statistics side by side).
    pub fn layer_norm_rows / layer_norm_rows_on(
        x: &[T],
        y: &mut [T],
        n: usize,
        gain: &[T],
        shift: &[T],
        mean: &mut [T],
        rstd: &mut [T],
        then_tanh: bool,
    ) => layer_norm_body;
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn layer_norm_body<T: Real>(
    x: &[T],
    y: &mut [T],
    n: usize,
    gain: &[T],
    shift: &[T],
    mean: &mut [T],
    rstd: &mut [T],
    then_tanh: bool,
) {
    const B: usize = LAYER_NORM_ROW_BLOCK;
    let rows = mean.len();
    let mut r0 = 0;
    while r0 + B <= rows {
        layer_norm_block::<T, B>(r0, x, y, n, gain, shift, mean, rstd, then_tanh);
        r0 += B;
    }
    while r0 < rows {
        layer_norm_block::<T, 1>(r0, x, y, n, gain, shift, mean, rstd, then_tanh);
        r0 += 1;
    }
}

/// Rows `r0..r0 + R` of [`layer_norm`], their statistics accumulated side by side (a fixed `R`
/// lets the compiler keep the `R` running sums in registers).
#[inline(always)]
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)] // j indexes R rows at once
fn layer_norm_block<T: Real, const R: usize>(
    r0: usize,
    x: &[T],
    y: &mut [T],
    n: usize,
    gain: &[T],
    shift: &[T],
    mean_out: &mut [T],
    rstd_out: &mut [T],
    then_tanh: bool,
) {
    let inv_n = T::from_f64(1.0 / n as f64);
    let eps = T::from_f64(LAYER_NORM_EPS);
    let src: [&[T]; R] = std::array::from_fn(|b| &x[(r0 + b) * n..(r0 + b + 1) * n]);
    let mut mean = [T::ZERO; R];
    for j in 0..n {
        for b in 0..R {
            mean[b] += src[b][j];
        }
    }
    for m in mean.iter_mut() {
        *m *= inv_n;
    }
    let mut var = [T::ZERO; R];
    for j in 0..n {
        for b in 0..R {
            let d = src[b][j] - mean[b];
            var[b] += d * d;
        }
    }
    for b in 0..R {
        let r = T::ONE / (var[b] * inv_n + eps).sqrt();
        mean_out[r0 + b] = mean[b];
        rstd_out[r0 + b] = r;
        normalize_row(src[b], &mut y[(r0 + b) * n..(r0 + b + 1) * n], gain, shift, mean[b], r, then_tanh);
    }
}

/// One row of [`layer_norm`]'s output from its statistics.
#[inline(always)]
fn normalize_row<T: Real>(x: &[T], out: &mut [T], gain: &[T], shift: &[T], mean: T, r: T, then_tanh: bool) {
    for ((v, o), (g, s)) in x.iter().zip(out.iter_mut()).zip(gain.iter().zip(shift)) {
        *o = ((*v - mean) * r) * *g + *s;
    }
    if then_tanh {
        for o in out.iter_mut() {
            *o = o.tanh();
        }
    }
}

/// Backward through [`layer_norm`]: `dy` (rows x n, the gradient of its output `y`) becomes the
/// gradient of `x` in place; gain and shift gradients are added (rows in order) when given.
/// `tanh_out` is the forward's `y` when it ran `then_tanh` (the backward through Tanh,
/// `dy *= 1 - y^2`, runs first on each block of rows).
pub fn layer_norm_backward<T: Real>(
    dy: &mut [T],
    n: usize,
    gain: &[T],
    x: &[T],
    stats: &[T],
    tanh_out: Option<&[T]>,
    grads: Option<(&mut [T], &mut [T])>,
) {
    layer_norm_backward_on(Isa::best(), dy, n, gain, x, stats, tanh_out, grads)
}

/// [`layer_norm_backward`] in the compiled copy `isa` (the portable one where this CPU lacks it).
#[allow(clippy::too_many_arguments)]
pub fn layer_norm_backward_on<T: Real>(
    isa: Isa,
    dy: &mut [T],
    n: usize,
    gain: &[T],
    x: &[T],
    stats: &[T],
    tanh_out: Option<&[T]>,
    mut grads: Option<(&mut [T], &mut [T])>,
) {
    let rows = (stats.len() / 2).min(dy.len() / n.max(1));
    let (mean, rstd) = layer_norm_stats(stats);
    let gain = &gain[..n];
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if isa == Isa::Avx512 && crate::has_avx512() {
        let t32 = tanh_out.map(as_f32s);
        if let (Some(d32), Some(g32), Some(x32), Some(m32), Some(r32), None | Some(Some(_))) =
            (as_f32s_mut(dy), as_f32s(gain), as_f32s(x), as_f32s(mean), as_f32s(rstd), t32)
        {
            let grads32 = grads
                .as_mut()
                .map(|(dg, ds)| (as_f32s_mut(dg).expect("T is f32 here"), as_f32s_mut(ds).expect("T is f32 here")));
            // SAFETY: the CPU has AVX-512 F and VL (checked above).
            done = unsafe { rows16::layer_norm_backward(d32, n, g32, x32, m32, r32, t32.flatten(), grads32, rows) };
        }
    }
    layer_norm_backward_rows_on(
        isa,
        &mut dy[done * n..rows * n],
        n,
        gain,
        &x[done * n..rows * n],
        &mean[done..rows],
        &rstd[done..rows],
        tanh_out.map(|t| &t[done * n..rows * n]),
        grads,
    );
}

kernel_copies! {
    /// The rows of [`layer_norm_backward`], `LAYER_NORM_ROW_BLOCK` at a time.
    pub fn layer_norm_backward_rows / layer_norm_backward_rows_on(
        dy: &mut [T],
        n: usize,
        gain: &[T],
        x: &[T],
        mean: &[T],
        rstd: &[T],
        tanh_out: Option<&[T]>,
        grads: Option<(&mut [T], &mut [T])>,
    ) => layer_norm_backward_body;
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn layer_norm_backward_body<T: Real>(
    dy: &mut [T],
    n: usize,
    gain: &[T],
    x: &[T],
    mean: &[T],
    rstd: &[T],
    tanh_out: Option<&[T]>,
    mut grads: Option<(&mut [T], &mut [T])>,
) {
    const B: usize = LAYER_NORM_ROW_BLOCK;
    let inv_n = T::from_f64(1.0 / n as f64);
    let rows = mean.len();
    // the normalised values of one block of rows, recomputed as the forward computed them
    let mut xhat = vec![T::ZERO; B * n];
    let mut r0 = 0;
    while r0 < rows {
        let rb = B.min(rows - r0);
        backward_block_prologue(r0, rb, dy, n, x, mean, rstd, tanh_out, grads.as_mut(), &mut xhat);
        if rb == B {
            layer_norm_backward_block::<T, B>(r0, dy, n, gain, &xhat, rstd, inv_n);
        } else {
            for b in 0..rb {
                layer_norm_backward_block::<T, 1>(r0 + b, dy, n, gain, &xhat[b * n..(b + 1) * n], rstd, inv_n);
            }
        }
        r0 += rb;
    }
}

/// The first steps of the backward of rows `r0..r0 + rb`: through Tanh (when it ran), the
/// normalised values into `xhat`, the gain and shift gradients (rows in order).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn backward_block_prologue<T: Real>(
    r0: usize,
    rb: usize,
    dy: &mut [T],
    n: usize,
    x: &[T],
    mean: &[T],
    rstd: &[T],
    tanh_out: Option<&[T]>,
    grads: Option<&mut (&mut [T], &mut [T])>,
    xhat: &mut [T],
) {
    let block = r0 * n..(r0 + rb) * n;
    if let Some(t) = tanh_out {
        tanh_backward_body(&t[block.clone()], &mut dy[block.clone()]);
    }
    for (b, xh) in xhat.chunks_exact_mut(n).take(rb).enumerate() {
        let (m, r) = (mean[r0 + b], rstd[r0 + b]);
        for (h, v) in xh.iter_mut().zip(&x[(r0 + b) * n..(r0 + b + 1) * n]) {
            *h = (*v - m) * r;
        }
    }
    if let Some((dg, ds)) = grads {
        for (row, xh) in dy[block].chunks_exact(n).zip(xhat.chunks_exact(n)) {
            for j in 0..n {
                dg[j] += row[j] * xh[j];
                ds[j] += row[j];
            }
        }
    }
}

/// Rows `r0..r0 + R` of [`layer_norm_backward`]'s input gradient, their two statistics
/// accumulated side by side; `xhat` holds the block's normalised values (`R x n`).
#[inline(always)]
fn layer_norm_backward_block<T: Real, const R: usize>(
    r0: usize,
    dy: &mut [T],
    n: usize,
    gain: &[T],
    xhat: &[T],
    rstd: &[T],
    inv_n: T,
) {
    let (mut mean_d, mut mean_dx) = ([T::ZERO; R], [T::ZERO; R]);
    {
        let d_rows: [&[T]; R] = std::array::from_fn(|b| &dy[(r0 + b) * n..(r0 + b + 1) * n]);
        let x_rows: [&[T]; R] = std::array::from_fn(|b| &xhat[b * n..(b + 1) * n]);
        for (j, g) in gain.iter().enumerate() {
            for b in 0..R {
                let d = d_rows[b][j] * *g;
                mean_d[b] += d;
                mean_dx[b] += d * x_rows[b][j];
            }
        }
    }
    for b in 0..R {
        backward_row_out(
            &mut dy[(r0 + b) * n..(r0 + b + 1) * n],
            &xhat[b * n..(b + 1) * n],
            gain,
            mean_d[b],
            mean_dx[b],
            rstd[r0 + b],
            inv_n,
        );
    }
}

/// One row of the input gradient from its two sums.
#[inline(always)]
fn backward_row_out<T: Real>(dy: &mut [T], xhat: &[T], gain: &[T], sum_d: T, sum_dx: T, r: T, inv_n: T) {
    let (md, mdx) = (sum_d * inv_n, sum_dx * inv_n);
    for ((v, h), g) in dy.iter_mut().zip(xhat).zip(gain) {
        let d = *v * *g;
        *v = (d - md - *h * mdx) * r;
    }
}

/// LayerNorm's row statistics sixteen rows at a time on AVX-512 (f32).
///
/// Each row's sums run in index order, so with rows in memory one after another a row-at-a-time
/// loop is one dependent chain, and eight rows side by side ([`LAYER_NORM_ROW_BLOCK`]) made
/// LLVM gather one value per row per step: the statistics were about a quarter of the LayerNorm
/// passes. Here a 16 x 16 tile of sixteen rows is loaded as sixteen vectors and transposed in
/// registers (four rounds of two-source permutes), so that one vector holds column `j` of the
/// sixteen rows and each row's running sum is one lane: the same additions in the same order,
/// sixteen rows per instruction. The rest of each pass (normalising, the gradients) is the
/// portable code compiled for AVX-512.
#[cfg(target_arch = "x86_64")]
mod rows16 {
    use super::{backward_block_prologue, backward_row_out, normalize_row, LAYER_NORM_EPS};
    use std::arch::x86_64::*;

    /// Rows per block: one per lane.
    pub const ROWS: usize = 16;

    /// Permute indices that swap bit `k` of the vector index with bit `k` of the lane index;
    /// `b` is bit `k` of the output vector.
    const fn swap_bit(k: usize, b: usize) -> [i32; 16] {
        let mut idx = [0i32; 16];
        let mut l = 0;
        while l < 16 {
            idx[l] = (((l >> k) & 1) * 16 + ((l & !(1 << k)) | (b << k))) as i32;
            l += 1;
        }
        idx
    }

    const SWAPS: [[[i32; 16]; 2]; 4] = [
        [swap_bit(0, 0), swap_bit(0, 1)],
        [swap_bit(1, 0), swap_bit(1, 1)],
        [swap_bit(2, 0), swap_bit(2, 1)],
        [swap_bit(3, 0), swap_bit(3, 1)],
    ];

    /// Transpose a 16 x 16 tile held as sixteen row vectors.
    #[inline(always)]
    unsafe fn transpose(v: &mut [__m512; 16]) {
        // SAFETY: this function's contract (its callers check the CPU features it is compiled for
        // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
        // below sound; every pointer offset stays inside those slices.
        unsafe {
            for (k, pair) in SWAPS.iter().enumerate() {
                let idx = [
                    _mm512_loadu_si512(pair[0].as_ptr() as *const _),
                    _mm512_loadu_si512(pair[1].as_ptr() as *const _),
                ];
                let s = 1 << k;
                for lo in 0..16 {
                    if lo & s == 0 {
                        let (a, b) = (v[lo], v[lo | s]);
                        v[lo] = _mm512_permutex2var_ps(a, idx[0], b);
                        v[lo | s] = _mm512_permutex2var_ps(a, idx[1], b);
                    }
                }
            }
        }
    }

    /// Columns `c0..c0 + w` of rows `r0..r0 + 16` of `m` (rows of `n`), transposed: `out[j]`
    /// is column `c0 + j` (lanes past `w` are zero and never used).
    #[inline(always)]
    unsafe fn tile(m: &[f32], n: usize, r0: usize, c0: usize, w: usize) -> [__m512; 16] {
        // SAFETY: this function's contract (its callers check the CPU features it is compiled for
        // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
        // below sound; every pointer offset stays inside those slices.
        unsafe {
            let mask = ((1u32 << w) - 1) as __mmask16;
            let p = m.as_ptr();
            let mut v: [__m512; 16] = std::array::from_fn(|b| _mm512_maskz_loadu_ps(mask, p.add((r0 + b) * n + c0)));
            transpose(&mut v);
            v
        }
    }

    /// Rows `0..16 floor(rows / 16)` of [`super::layer_norm`]; returns how many rows it did.
    #[target_feature(enable = "avx512f,avx512vl,avx2")]
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn layer_norm(
        x: &[f32],
        y: &mut [f32],
        n: usize,
        gain: &[f32],
        shift: &[f32],
        mean_out: &mut [f32],
        rstd_out: &mut [f32],
        rows: usize,
        then_tanh: bool,
    ) -> usize {
        // SAFETY: this function's contract (its callers check the CPU features it is compiled for
        // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
        // below sound; every pointer offset stays inside those slices.
        unsafe {
            assert!(x.len() >= rows * n && y.len() >= rows * n && mean_out.len() >= rows && rstd_out.len() >= rows);
            let inv_n = _mm512_set1_ps((1.0 / n as f64) as f32);
            let eps = _mm512_set1_ps(LAYER_NORM_EPS as f32);
            // the block's columns, transposed (column j of the sixteen rows at 16 j)
            let mut cols = vec![0.0f32; n * ROWS];
            let mut r0 = 0;
            while r0 + ROWS <= rows {
                let mut sum = _mm512_setzero_ps();
                for c0 in (0..n).step_by(ROWS) {
                    let w = ROWS.min(n - c0);
                    let t = tile(x, n, r0, c0, w);
                    for (j, col) in t.iter().enumerate().take(w) {
                        sum = _mm512_add_ps(sum, *col);
                        _mm512_storeu_ps(cols.as_mut_ptr().add((c0 + j) * ROWS), *col);
                    }
                }
                let mean = _mm512_mul_ps(sum, inv_n);
                let mut var = _mm512_setzero_ps();
                for j in 0..n {
                    let d = _mm512_sub_ps(_mm512_loadu_ps(cols.as_ptr().add(j * ROWS)), mean);
                    var = _mm512_add_ps(var, _mm512_mul_ps(d, d));
                }
                let r =
                    _mm512_div_ps(_mm512_set1_ps(1.0), _mm512_sqrt_ps(_mm512_add_ps(_mm512_mul_ps(var, inv_n), eps)));
                let (mut m, mut rs) = ([0.0f32; ROWS], [0.0f32; ROWS]);
                _mm512_storeu_ps(m.as_mut_ptr(), mean);
                _mm512_storeu_ps(rs.as_mut_ptr(), r);
                mean_out[r0..r0 + ROWS].copy_from_slice(&m);
                rstd_out[r0..r0 + ROWS].copy_from_slice(&rs);
                for b in 0..ROWS {
                    let at = (r0 + b) * n;
                    normalize_row(&x[at..at + n], &mut y[at..at + n], gain, shift, m[b], rs[b], then_tanh);
                }
                r0 += ROWS;
            }
            r0
        }
    }

    /// Rows `0..16 floor(rows / 16)` of [`super::layer_norm_backward`]; returns how many rows
    /// it did.
    #[target_feature(enable = "avx512f,avx512vl,avx2")]
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn layer_norm_backward(
        dy: &mut [f32],
        n: usize,
        gain: &[f32],
        x: &[f32],
        mean: &[f32],
        rstd: &[f32],
        tanh_out: Option<&[f32]>,
        mut grads: Option<(&mut [f32], &mut [f32])>,
        rows: usize,
    ) -> usize {
        // SAFETY: this function's contract (its callers check the CPU features it is compiled for
        // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
        // below sound; every pointer offset stays inside those slices.
        unsafe {
            assert!(dy.len() >= rows * n && x.len() >= rows * n && mean.len() >= rows && rstd.len() >= rows);
            assert!(tanh_out.is_none_or(|t| t.len() >= rows * n) && gain.len() >= n);
            let inv_n = (1.0 / n as f64) as f32;
            let mut xhat = vec![0.0f32; ROWS * n];
            let mut r0 = 0;
            while r0 + ROWS <= rows {
                backward_block_prologue(r0, ROWS, dy, n, x, mean, rstd, tanh_out, grads.as_mut(), &mut xhat);
                let (mut sd, mut sdx) = (_mm512_setzero_ps(), _mm512_setzero_ps());
                for c0 in (0..n).step_by(ROWS) {
                    let w = ROWS.min(n - c0);
                    let (td, tx) = (tile(dy, n, r0, c0, w), tile(&xhat, n, 0, c0, w));
                    for j in 0..w {
                        let d = _mm512_mul_ps(td[j], _mm512_set1_ps(gain[c0 + j]));
                        sd = _mm512_add_ps(sd, d);
                        sdx = _mm512_add_ps(sdx, _mm512_mul_ps(d, tx[j]));
                    }
                }
                let (mut s1, mut s2) = ([0.0f32; ROWS], [0.0f32; ROWS]);
                _mm512_storeu_ps(s1.as_mut_ptr(), sd);
                _mm512_storeu_ps(s2.as_mut_ptr(), sdx);
                for b in 0..ROWS {
                    let at = (r0 + b) * n;
                    backward_row_out(
                        &mut dy[at..at + n],
                        &xhat[b * n..(b + 1) * n],
                        gain,
                        s1[b],
                        s2[b],
                        rstd[r0 + b],
                        inv_n,
                    );
                }
                r0 += ROWS;
            }
            r0
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn tanh_f32_is_within_4_ulp_everywhere() {
        let mut worst = 0.0f64;
        let mut x = -12.0f32;
        while x < 12.0 {
            let got = crate::tanh_f32(x) as f64;
            let want = libm::tanh(x as f64);
            let ulp = (want.abs() as f32).max(f32::MIN_POSITIVE);
            let ulp = (f32::from_bits(ulp.to_bits() + 1) - ulp) as f64;
            worst = worst.max((got - want).abs() / ulp);
            x += 0.000_37;
        }
        assert!(worst <= 4.0, "worst error {worst} ulp");
        assert_eq!(crate::tanh_f32(0.0), 0.0);
        assert_eq!(crate::tanh_f32(30.0), 1.0);
        assert_eq!(crate::tanh_f32(-30.0), -1.0);
    }

    use crate::hashed_values as data;

    /// Every compiled copy of every pointwise and LayerNorm kernel this machine runs gives the
    /// portable copy's bits, on row widths that exercise full vectors and remainders and row
    /// counts below and above the LayerNorm row block.
    #[test]
    fn every_instruction_set_copy_gives_the_same_bits() {
        use super::*;
        use crate::Isa;
        let copies = Isa::available();
        for &(rows, n) in &[(13, 37), (256, 192), (3, 64), (9, 5), (40, 20), (33, 16)] {
            let len = rows * n;
            let (x, d0) = (data(len, 1), data(len, 2));
            let (gain, shift) = (data(n, 3), data(n, 4));
            let run = |isa: Isa| {
                let mut out: Vec<Vec<f32>> = Vec::new();
                let mut y = vec![0.0; len];
                // positive arguments (the squash's) and the rest (zero, negative: libm's path)
                let args: Vec<f32> = x.iter().map(|v| if v.to_bits() % 5 == 0 { *v } else { v.abs() + 1e-6 }).collect();
                ln_into_on(isa, &args, &mut y);
                out.push(y.clone());
                tanh_into_on(isa, &x, &mut y);
                let mut d = d0.clone();
                tanh_backward_on(isa, &y, &mut d);
                out.extend([y.clone(), d]);
                relu_into_on(isa, &x, &mut y);
                let mut d = d0.clone();
                relu_backward_on(isa, &y, &mut d);
                let mut sums = gain.clone();
                add_column_sums_on(isa, &d0, &mut sums);
                out.extend([y.clone(), d, sums]);
                for then_tanh in [false, true] {
                    let mut stats = vec![0.0; 2 * rows];
                    layer_norm_on(isa, &x, &mut y, n, &gain, &shift, &mut stats, then_tanh);
                    let (mut d, mut dg, mut ds) = (d0.clone(), vec![0.0; n], vec![0.0; n]);
                    let t = then_tanh.then_some(&y[..]);
                    layer_norm_backward_on(isa, &mut d, n, &gain, &x, &stats, t, Some((&mut dg, &mut ds)));
                    out.extend([y.clone(), stats, d, dg, ds]);
                }
                out.into_iter().map(|v| v.iter().map(|f| f.to_bits()).collect::<Vec<u32>>()).collect::<Vec<_>>()
            };
            let portable = run(Isa::Portable);
            for &isa in &copies {
                assert_eq!(run(isa), portable, "{isa:?} at {rows} x {n}");
            }
        }
    }

    /// LayerNorm with `then_tanh` gives bit for bit what LayerNorm then [`tanh_into`] give, and
    /// its backward what [`tanh_backward`] then the plain LayerNorm backward give.
    #[test]
    fn fused_layer_norm_tanh_gives_the_bits_of_the_two_kernels() {
        use super::*;
        for &(rows, n) in &[(13, 37), (256, 192), (3, 64)] {
            let len = rows * n;
            let (x, d0) = (data(len, 5), data(len, 6));
            let (gain, shift) = (data(n, 7), data(n, 8));
            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<u32>>();
            let (mut ln, mut t_two) = (vec![0.0; len], vec![0.0; len]);
            let mut stats_two = vec![0.0; 2 * rows];
            layer_norm(&x, &mut ln, n, &gain, &shift, &mut stats_two, false);
            tanh_into(&ln, &mut t_two);
            let (mut d_two, mut dg_two, mut ds_two) = (d0.clone(), vec![0.0; n], vec![0.0; n]);
            tanh_backward(&t_two, &mut d_two);
            layer_norm_backward(&mut d_two, n, &gain, &x, &stats_two, None, Some((&mut dg_two, &mut ds_two)));

            let mut t = vec![0.0; len];
            let mut stats = vec![0.0; 2 * rows];
            layer_norm(&x, &mut t, n, &gain, &shift, &mut stats, true);
            let (mut d, mut dg, mut ds) = (d0.clone(), vec![0.0; n], vec![0.0; n]);
            layer_norm_backward(&mut d, n, &gain, &x, &stats, Some(&t), Some((&mut dg, &mut ds)));
            assert_eq!(bits(&t), bits(&t_two));
            assert_eq!(bits(&stats), bits(&stats_two));
            assert_eq!(bits(&d), bits(&d_two));
            assert_eq!(bits(&dg), bits(&dg_two));
            assert_eq!(bits(&ds), bits(&ds_two));
            assert!(t.iter().any(|v| *v != 0.0) && d.iter().any(|v| *v != 0.0));
        }
    }
}
