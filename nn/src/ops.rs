//! Pointwise operations with their backward passes: bias, ReLU, Tanh, ln (LayerNorm, the one
//! per-row operation, is [`crate::layer_norm`]).
//!
//! Every reduction runs in index order on one thread (LayerNorm statistics over a row; bias,
//! gain and shift gradients over the rows of a batch), so results do not depend on threads.

use crate::{Isa, Real};

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
pub(crate) fn tanh_backward_body<T: Real>(y: &[T], dy: &mut [T]) {
    for (d, v) in dy.iter_mut().zip(y) {
        *d *= T::ONE - *v * *v;
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
        use crate::layer_norm::{layer_norm_backward_on, layer_norm_on};
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
}
