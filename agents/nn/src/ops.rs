//! Pointwise and per-row operations with their backward passes: bias, ReLU, Tanh, LayerNorm.
//!
//! Every reduction runs in index order on one thread (LayerNorm statistics over a row; bias,
//! gain and shift gradients over the rows of a batch), so results do not depend on threads.

use crate::Real;

/// LayerNorm's epsilon (PyTorch's default).
pub const LAYER_NORM_EPS: f64 = 1e-5;

/// Write `bias` into every row of `out` (`rows x bias.len()`), ready for an accumulating gemm.
pub fn fill_bias<T: Real>(out: &mut [T], bias: &[T]) {
    for row in out.chunks_exact_mut(bias.len().max(1)) {
        row.copy_from_slice(bias);
    }
}

/// `grad += sum over rows of dy` (a bias gradient), rows in order.
pub fn add_column_sums<T: Real>(dy: &[T], grad: &mut [T]) {
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

/// `y = relu(x)` (`y` as long as `x`).
pub fn relu_into<T: Real>(x: &[T], y: &mut [T]) {
    for (o, v) in y.iter_mut().zip(x) {
        *o = if *v > T::ZERO { *v } else { T::ZERO };
    }
}

/// `dy *= [y > 0]` (backward through ReLU, from its output).
pub fn relu_backward<T: Real>(y: &[T], dy: &mut [T]) {
    for (d, v) in dy.iter_mut().zip(y) {
        *d = if *v > T::ZERO { *d } else { T::ZERO };
    }
}

/// `y = tanh(x)` (`y` as long as `x`).
pub fn tanh_into<T: Real>(x: &[T], y: &mut [T]) {
    #[cfg(target_arch = "x86_64")]
    {
        if crate::has_fast_fma() {
            // SAFETY: the CPU has the features; the arithmetic is unfused either way.
            unsafe { tanh_avx2(x, y) };
            return;
        }
    }
    tanh_body(x, y)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn tanh_avx2<T: Real>(x: &[T], y: &mut [T]) {
    tanh_body(x, y)
}

#[inline(always)]
fn tanh_body<T: Real>(x: &[T], y: &mut [T]) {
    for (o, v) in y.iter_mut().zip(x) {
        *o = v.tanh();
    }
}

/// `dy *= 1 - y^2` (backward through tanh, from its output).
pub fn tanh_backward<T: Real>(y: &[T], dy: &mut [T]) {
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

/// LayerNorm over each row of `x` (`rows x n`) into `y`, with gain and shift; keeps the
/// normalised values `xhat` and `1/std` per row for the backward pass.
pub fn layer_norm<T: Real>(x: &[T], y: &mut [T], n: usize, gain: &[T], shift: &[T], xhat: &mut [T], rstd: &mut [T]) {
    const B: usize = LAYER_NORM_ROW_BLOCK;
    let rows = rstd.len().min(x.len() / n.max(1));
    let (gain, shift) = (&gain[..n], &shift[..n]);
    let mut r0 = 0;
    while r0 + B <= rows {
        layer_norm_block::<T, B>(r0, x, y, n, gain, shift, xhat, rstd);
        r0 += B;
    }
    while r0 < rows {
        layer_norm_block::<T, 1>(r0, x, y, n, gain, shift, xhat, rstd);
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
    xhat: &mut [T],
    rstd: &mut [T],
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
        rstd[r0 + b] = r;
        let at = (r0 + b) * n;
        let (out, xh) = (&mut y[at..at + n], &mut xhat[at..at + n]);
        for (((v, o), h), (g, s)) in src[b].iter().zip(out.iter_mut()).zip(xh.iter_mut()).zip(gain.iter().zip(shift)) {
            *h = (*v - mean[b]) * r;
            *o = *h * *g + *s;
        }
    }
}

/// Backward through [`layer_norm`]: `dy` (rows x n) becomes `dx` in place; gain and shift
/// gradients are added (rows in order) when given.
pub fn layer_norm_backward<T: Real>(
    dy: &mut [T],
    n: usize,
    gain: &[T],
    xhat: &[T],
    rstd: &[T],
    mut grads: Option<(&mut [T], &mut [T])>,
) {
    const B: usize = LAYER_NORM_ROW_BLOCK;
    let inv_n = T::from_f64(1.0 / n as f64);
    let rows = rstd.len().min(dy.len() / n.max(1));
    if let Some((dg, ds)) = grads.as_mut() {
        for (row, xh) in dy.chunks_exact(n).zip(xhat.chunks_exact(n)).take(rows) {
            for j in 0..n {
                dg[j] += row[j] * xh[j];
                ds[j] += row[j];
            }
        }
    }
    let gain = &gain[..n];
    let mut r0 = 0;
    while r0 + B <= rows {
        layer_norm_backward_block::<T, B>(r0, dy, n, gain, xhat, rstd, inv_n);
        r0 += B;
    }
    while r0 < rows {
        layer_norm_backward_block::<T, 1>(r0, dy, n, gain, xhat, rstd, inv_n);
        r0 += 1;
    }
}

/// Rows `r0..r0 + R` of [`layer_norm_backward`]'s input gradient, their two statistics
/// accumulated side by side.
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
        let x_rows: [&[T]; R] = std::array::from_fn(|b| &xhat[(r0 + b) * n..(r0 + b + 1) * n]);
        for (j, g) in gain.iter().enumerate() {
            for b in 0..R {
                let d = d_rows[b][j] * *g;
                mean_d[b] += d;
                mean_dx[b] += d * x_rows[b][j];
            }
        }
    }
    for b in 0..R {
        let (md, mdx, r) = (mean_d[b] * inv_n, mean_dx[b] * inv_n, rstd[r0 + b]);
        let at = (r0 + b) * n;
        for ((v, h), g) in dy[at..at + n].iter_mut().zip(&xhat[at..at + n]).zip(gain) {
            let d = *v * *g;
            *v = (d - md - *h * mdx) * r;
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
}
