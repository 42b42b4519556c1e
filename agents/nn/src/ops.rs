//! Pointwise and per-row operations with their backward passes: bias, ReLU, Tanh, LayerNorm.
//!
//! Every reduction runs in index order on one thread (LayerNorm statistics over a row; bias,
//! gain and shift gradients over the rows of a batch), so results do not depend on threads.

use crate::{Isa, Real};

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

kernel_copies! {
    /// LayerNorm over each row of `x` (`rows x n`) into `y`, with gain and shift; keeps the
    /// normalised values `xhat` and `1/std` per row for the backward pass.
    pub fn layer_norm / layer_norm_on(
        x: &[T],
        y: &mut [T],
        n: usize,
        gain: &[T],
        shift: &[T],
        xhat: &mut [T],
        rstd: &mut [T],
    ) => layer_norm_body;
}

#[inline(always)]
fn layer_norm_body<T: Real>(x: &[T], y: &mut [T], n: usize, gain: &[T], shift: &[T], xhat: &mut [T], rstd: &mut [T]) {
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

kernel_copies! {
    /// Backward through [`layer_norm`]: `dy` (rows x n) becomes `dx` in place; gain and shift
    /// gradients are added (rows in order) when given.
    pub fn layer_norm_backward / layer_norm_backward_on(
        dy: &mut [T],
        n: usize,
        gain: &[T],
        xhat: &[T],
        rstd: &[T],
        grads: Option<(&mut [T], &mut [T])>,
    ) => layer_norm_backward_body;
}

#[inline(always)]
fn layer_norm_backward_body<T: Real>(
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

    /// Values in [-3, 3) from a fixed integer hash (no RNG dependency).
    fn data(n: usize, salt: u64) -> Vec<f32> {
        (0..n as u64)
            .map(|i| {
                let h = (i.wrapping_add(salt << 32)).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
                (h as f32 / (1u64 << 24) as f32) * 6.0 - 3.0
            })
            .collect()
    }

    /// Every compiled copy of every pointwise and LayerNorm kernel this machine runs gives the
    /// portable copy's bits, on row widths that exercise full vectors and remainders and row
    /// counts below and above the LayerNorm row block.
    #[test]
    fn every_instruction_set_copy_gives_the_same_bits() {
        use super::*;
        use crate::Isa;
        let copies = Isa::available();
        for &(rows, n) in &[(13, 37), (256, 192), (3, 64), (9, 5)] {
            let len = rows * n;
            let (x, d0) = (data(len, 1), data(len, 2));
            let (gain, shift) = (data(n, 3), data(n, 4));
            let run = |isa: Isa| {
                let mut out: Vec<Vec<f32>> = Vec::new();
                let mut y = vec![0.0; len];
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
                let (mut xhat, mut rstd) = (vec![0.0; len], vec![0.0; rows]);
                layer_norm_on(isa, &x, &mut y, n, &gain, &shift, &mut xhat, &mut rstd);
                let (mut d, mut dg, mut ds) = (d0.clone(), vec![0.0; n], vec![0.0; n]);
                layer_norm_backward_on(isa, &mut d, n, &gain, &xhat, &rstd, Some((&mut dg, &mut ds)));
                out.extend([y, xhat, rstd, d, dg, ds]);
                out.into_iter().map(|v| v.iter().map(|f| f.to_bits()).collect::<Vec<u32>>()).collect::<Vec<_>>()
            };
            let portable = run(Isa::Portable);
            for &isa in &copies {
                assert_eq!(run(isa), portable, "{isa:?} at {rows} x {n}");
            }
        }
    }
}
