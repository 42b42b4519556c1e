//! The matrix product every layer runs on: `C (+)= op(A) B`, summed in one fixed order.
//!
//! `C[i, j] = c0 + sum_p A[i, p] B[p, j]`, accumulated with fused multiply-adds from `p = 0`
//! up, where `c0` is the old `C[i, j]` (`accumulate = true`, e.g. a bias written first) or 0.
//! Blocks of 6 rows x 16 columns keep 6 x 16 accumulators in registers (12 of the 16 AVX
//! registers in f32; with 4 x 16, 8 accumulators barely covered the FMA latency: on the
//! 256 x 192 x 192 layer 6 x 16 ran 79-80 GFLOP/s against 50-59, two alternating runs of
//! `examples/bench` each on a loaded machine) and stream one row of `B` per step of `p`:
//! vectorised across the outputs `j`, never across `p`. Edge blocks (fewer rows or columns) use
//! narrower copies of the same loop, with the same order of operations, so every element's bits
//! are independent of blocking and batch size.
//!
//! Shapes: `A` is `m x k` row-major ([`Trans::N`]) or stored `k x m` row-major and read
//! transposed ([`Trans::T`], e.g. `X^T dY` for a weight gradient); `B` is `k x n` row-major; `C`
//! is `m x n` row-major. Slices must be at least that long (checked; a short slice panics, which
//! is a bug in the caller, never user input).

use crate::Real;

/// How `A` is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trans {
    /// `A` is `m x k`, row-major.
    N,
    /// `A` is stored as its transpose, `k x m` row-major.
    T,
}

/// Rows per register block.
const MR: usize = 6;
/// Rows per block for what is left below `MR`.
const MR_EDGE: usize = 4;
/// Columns per register block (two 8-lane f32 vectors).
const NR: usize = 16;
/// Columns per register block where the CPU has AVX-512 (two 16-lane f32 vectors).
const NR_WIDE: usize = 32;
/// Narrower column block for edges.
const NR_HALF: usize = 8;

/// `C (+)= op(A) B`; see the module docs.
#[allow(clippy::too_many_arguments)]
pub fn gemm<T: Real>(m: usize, n: usize, k: usize, a: &[T], ta: Trans, b: &[T], c: &mut [T], accumulate: bool) {
    assert!(a.len() >= m * k && b.len() >= k * n && c.len() >= m * n, "gemm: slices shorter than {m}x{k} . {k}x{n}");
    #[cfg(target_arch = "x86_64")]
    match crate::Isa::best() {
        // SAFETY: `Isa::best` names only a copy whose features the CPU has.
        crate::Isa::Avx512 => return unsafe { gemm_avx512(m, n, k, a, ta, b, c, accumulate) },
        // SAFETY: as above.
        crate::Isa::Avx2 => return unsafe { gemm_avx2(m, n, k, a, ta, b, c, accumulate) },
        crate::Isa::Portable => {}
    }
    gemm_body::<T, NR>(m, n, k, a, ta, b, c, accumulate)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_avx2<T: Real>(m: usize, n: usize, k: usize, a: &[T], ta: Trans, b: &[T], c: &mut [T], accumulate: bool) {
    gemm_body::<T, NR>(m, n, k, a, ta, b, c, accumulate)
}

/// The same loops with 32-column blocks (two 16-lane vectors per row, 12 of the 32 AVX-512
/// registers): every element is still one chain of fused multiply-adds from `p = 0` up, so the
/// bits are the AVX2 path's.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_avx512<T: Real>(
    m: usize,
    n: usize,
    k: usize,
    a: &[T],
    ta: Trans,
    b: &[T],
    c: &mut [T],
    accumulate: bool,
) {
    gemm_body::<T, NR_WIDE>(m, n, k, a, ta, b, c, accumulate)
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gemm_body<T: Real, const W: usize>(
    m: usize,
    n: usize,
    k: usize,
    a: &[T],
    ta: Trans,
    b: &[T],
    c: &mut [T],
    accumulate: bool,
) {
    let (ars, acs) = match ta {
        Trans::N => (k, 1),
        Trans::T => (1, m),
    };
    let mut i0 = 0;
    while i0 + MR <= m {
        row_block::<T, MR, W>(i0, n, k, a, ars, acs, b, c, accumulate);
        i0 += MR;
    }
    if i0 + MR_EDGE <= m {
        row_block::<T, MR_EDGE, W>(i0, n, k, a, ars, acs, b, c, accumulate);
        i0 += MR_EDGE;
    }
    while i0 < m {
        row_block::<T, 1, W>(i0, n, k, a, ars, acs, b, c, accumulate);
        i0 += 1;
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn row_block<T: Real, const R: usize, const W: usize>(
    i0: usize,
    n: usize,
    k: usize,
    a: &[T],
    ars: usize,
    acs: usize,
    b: &[T],
    c: &mut [T],
    accumulate: bool,
) {
    let mut j0 = 0;
    while j0 + W <= n {
        micro::<T, R, W>(i0, j0, n, k, a, ars, acs, b, c, accumulate);
        j0 += W;
    }
    while j0 + NR <= n {
        micro::<T, R, NR>(i0, j0, n, k, a, ars, acs, b, c, accumulate);
        j0 += NR;
    }
    while j0 + NR_HALF <= n {
        micro::<T, R, NR_HALF>(i0, j0, n, k, a, ars, acs, b, c, accumulate);
        j0 += NR_HALF;
    }
    while j0 < n {
        micro::<T, R, 1>(i0, j0, n, k, a, ars, acs, b, c, accumulate);
        j0 += 1;
    }
}

/// One R x C block of C: accumulators in registers, one pass over p.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn micro<T: Real, const R: usize, const C: usize>(
    i0: usize,
    j0: usize,
    n: usize,
    k: usize,
    a: &[T],
    ars: usize,
    acs: usize,
    b: &[T],
    c: &mut [T],
    accumulate: bool,
) {
    let mut acc = [[T::ZERO; C]; R];
    if accumulate {
        for (r, row) in acc.iter_mut().enumerate() {
            row.copy_from_slice(&c[(i0 + r) * n + j0..(i0 + r) * n + j0 + C]);
        }
    }
    // Bounds of every access below, checked once (the caller asserted the slice lengths).
    debug_assert!(k == 0 || (i0 + R - 1) * ars + (k - 1) * acs < a.len());
    debug_assert!(k == 0 || (k - 1) * n + j0 + C <= b.len());
    let (ap, bp) = (a.as_ptr(), b.as_ptr());
    for p in 0..k {
        // SAFETY: p < k, i0 + r < m and j0 + C <= n, inside the asserted lengths of a and b.
        let brow: &[T; C] = unsafe { &*(bp.add(p * n + j0) as *const [T; C]) };
        for (r, row) in acc.iter_mut().enumerate() {
            let av = unsafe { *ap.add((i0 + r) * ars + p * acs) };
            for j in 0..C {
                row[j] = av.fma(brow[j], row[j]);
            }
        }
    }
    for (r, row) in acc.iter().enumerate() {
        c[(i0 + r) * n + j0..(i0 + r) * n + j0 + C].copy_from_slice(row);
    }
}

/// Transpose `src` (`rows x cols`, row-major) into `dst` (`cols x rows`).
pub fn transpose<T: Real>(rows: usize, cols: usize, src: &[T], dst: &mut [T]) {
    for r in 0..rows {
        for c in 0..cols {
            dst[c * rows + r] = src[r * cols + c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(m: usize, n: usize, k: usize, a: &[f32], ta: Trans, b: &[f32], c0: &[f32]) -> Vec<f32> {
        let mut c = c0.to_vec();
        for i in 0..m {
            for j in 0..n {
                let mut s = c[i * n + j];
                for p in 0..k {
                    let av = match ta {
                        Trans::N => a[i * k + p],
                        Trans::T => a[p * m + i],
                    };
                    s = av.mul_add(b[p * n + j], s);
                }
                c[i * n + j] = s;
            }
        }
        c
    }

    fn data(len: usize, salt: u32) -> Vec<f32> {
        (0..len)
            .map(|i| (((i as u32).wrapping_mul(2654435761).wrapping_add(salt) >> 8) as f32 / 16777216.0) - 0.5)
            .collect()
    }

    #[test]
    fn blocked_equals_naive_bitwise_for_every_shape() {
        for &(m, n, k) in &[(1, 1, 1), (5, 17, 3), (4, 16, 9), (9, 41, 13), (10, 23, 7), (13, 64, 40), (3, 7, 0)] {
            for ta in [Trans::N, Trans::T] {
                let (a, b, c0) = (data(m * k, 1), data(k * n, 2), data(m * n, 3));
                let mut c = c0.clone();
                gemm(m, n, k, &a, ta, &b, &mut c, true);
                assert_eq!(c, naive(m, n, k, &a, ta, &b, &c0), "{m}x{n}x{k} {ta:?}");
            }
        }
    }

    /// Every copy this machine can run (portable, AVX2 + FMA, AVX-512) gives the same bits, on
    /// shapes that exercise the 32-, 16-, 8- and 1-column blocks.
    #[test]
    fn every_instruction_set_copy_gives_the_same_bits() {
        for &(m, n, k) in &[(7, 61, 19), (13, 32, 40), (6, 47, 5), (256, 192, 24)] {
            for ta in [Trans::N, Trans::T] {
                let (a, b, c0) = (data(m * k, 6), data(k * n, 7), data(m * n, 8));
                let mut portable = c0.clone();
                gemm_body::<f32, NR>(m, n, k, &a, ta, &b, &mut portable, true);
                #[cfg(target_arch = "x86_64")]
                {
                    if crate::has_fast_fma() {
                        let mut c = c0.clone();
                        unsafe { gemm_avx2(m, n, k, &a, ta, &b, &mut c, true) };
                        assert_eq!(c, portable, "AVX2 {m}x{n}x{k} {ta:?}");
                    }
                    if crate::has_avx512() {
                        let mut c = c0.clone();
                        unsafe { gemm_avx512(m, n, k, &a, ta, &b, &mut c, true) };
                        assert_eq!(c, portable, "AVX-512 {m}x{n}x{k} {ta:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_row_does_not_depend_on_the_batch() {
        let (n, k) = (37, 29);
        let a = data(11 * k, 4);
        let b = data(k * n, 5);
        let mut all = vec![0.0; 11 * n];
        gemm(11, n, k, &a, Trans::N, &b, &mut all, false);
        for r in 0..11 {
            let mut one = vec![0.0; n];
            gemm(1, n, k, &a[r * k..(r + 1) * k], Trans::N, &b, &mut one, false);
            assert_eq!(one, all[r * n..(r + 1) * n]);
        }
    }
}
