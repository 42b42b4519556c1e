//! LayerNorm's row statistics sixteen rows at a time on AVX-512 (f32).
//!
//! Each row's sums run in index order, so with rows in memory one after another a row-at-a-time
//! loop is one dependent chain, and eight rows side by side ([`super::LAYER_NORM_ROW_BLOCK`]) made
//! LLVM gather one value per row per step: the statistics were about a quarter of the LayerNorm
//! passes. Here a 16 x 16 tile of sixteen rows is loaded as sixteen vectors and transposed in
//! registers (four rounds of two-source permutes), so that one vector holds column `j` of the
//! sixteen rows and each row's running sum is one lane: the same additions in the same order,
//! sixteen rows per instruction. The rest of each pass (normalising, the gradients) is the
//! portable code compiled for AVX-512.

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
            let idx =
                [_mm512_loadu_si512(pair[0].as_ptr() as *const _), _mm512_loadu_si512(pair[1].as_ptr() as *const _)];
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
            let r = _mm512_div_ps(_mm512_set1_ps(1.0), _mm512_sqrt_ps(_mm512_add_ps(_mm512_mul_ps(var, inv_n), eps)));
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
