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

pub fn relu<T: Real>(x: &mut [T]) {
    for v in x {
        *v = if *v > T::ZERO { *v } else { T::ZERO };
    }
}

/// `dy *= [y > 0]` (backward through ReLU, from its output).
pub fn relu_backward<T: Real>(y: &[T], dy: &mut [T]) {
    for (d, v) in dy.iter_mut().zip(y) {
        *d = if *v > T::ZERO { *d } else { T::ZERO };
    }
}

pub fn tanh<T: Real>(x: &mut [T]) {
    #[cfg(target_arch = "x86_64")]
    {
        if crate::has_fast_fma() {
            // SAFETY: the CPU has the features; the arithmetic is unfused either way.
            unsafe { tanh_avx2(x) };
            return;
        }
    }
    tanh_body(x)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn tanh_avx2<T: Real>(x: &mut [T]) {
    tanh_body(x)
}

#[inline(always)]
fn tanh_body<T: Real>(x: &mut [T]) {
    for v in x {
        *v = v.tanh();
    }
}

/// `dy *= 1 - y^2` (backward through tanh, from its output).
pub fn tanh_backward<T: Real>(y: &[T], dy: &mut [T]) {
    for (d, v) in dy.iter_mut().zip(y) {
        *d *= T::ONE - *v * *v;
    }
}

/// LayerNorm over each row of `x` (`rows x n`) in place, with gain and shift; keeps the
/// normalised values `xhat` and `1/std` per row for the backward pass.
pub fn layer_norm<T: Real>(x: &mut [T], n: usize, gain: &[T], shift: &[T], xhat: &mut [T], rstd: &mut [T]) {
    let inv_n = T::from_f64(1.0 / n as f64);
    let eps = T::from_f64(LAYER_NORM_EPS);
    for ((row, xh), rs) in x.chunks_exact_mut(n).zip(xhat.chunks_exact_mut(n)).zip(rstd.iter_mut()) {
        let mut mean = T::ZERO;
        for v in row.iter() {
            mean += *v;
        }
        mean *= inv_n;
        let mut var = T::ZERO;
        for v in row.iter() {
            let d = *v - mean;
            var += d * d;
        }
        var *= inv_n;
        let r = T::ONE / (var + eps).sqrt();
        *rs = r;
        for ((v, h), (g, s)) in row.iter_mut().zip(xh.iter_mut()).zip(gain.iter().zip(shift)) {
            *h = (*v - mean) * r;
            *v = *h * *g + *s;
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
    let inv_n = T::from_f64(1.0 / n as f64);
    for ((row, xh), r) in dy.chunks_exact_mut(n).zip(xhat.chunks_exact(n)).zip(rstd) {
        if let Some((dg, ds)) = grads.as_mut() {
            for j in 0..n {
                dg[j] += row[j] * xh[j];
                ds[j] += row[j];
            }
        }
        let mut mean_d = T::ZERO;
        let mut mean_dx = T::ZERO;
        for j in 0..n {
            let d = row[j] * gain[j];
            mean_d += d;
            mean_dx += d * xh[j];
        }
        mean_d *= inv_n;
        mean_dx *= inv_n;
        for j in 0..n {
            let d = row[j] * gain[j];
            row[j] = (d - mean_d - xh[j] * mean_dx) * *r;
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
            let want = (x as f64).tanh();
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
