//! LayerNorm (optionally fused with the Tanh after it) and its backward pass.
//!
//! Each row's statistics are summed in index order on one thread, so results do not depend on
//! threads or on how many rows run side by side.

use crate::ops::tanh_backward_body;
use crate::{as_f32s, as_f32s_mut, Isa, Real};

/// LayerNorm's epsilon (PyTorch's default).
pub const LAYER_NORM_EPS: f64 = 1e-5;

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
/// when `then_tanh` (`y = tanh(xhat * gain + shift)`, bit for bit what [`crate::ops::tanh_into`] gives on
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

#[cfg(target_arch = "x86_64")]
mod rows16;

#[cfg(test)]
mod tests {
    use crate::hashed_values as data;
    use crate::ops::{tanh_backward, tanh_into};

    /// LayerNorm with `then_tanh` gives bit for bit what LayerNorm then [`crate::ops::tanh_into`] give, and
    /// its backward what [`crate::ops::tanh_backward`] then the plain LayerNorm backward give.
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
