//! The transforms of a batch of regular fields into and out of the Fourier blocks of
//! [`super::Circulant`], written as one kernel each instead of an `8 x 8` matrix product and a
//! reshuffle.
//!
//! # Why a kernel of its own
//!
//! As a matrix product (`(rows F) x 8` times `8 x 8`) the transform ran at 37 GFLOP/s (the
//! product's narrowest shape), and the reshuffle into the blocks was scalar: together 19 % of an
//! Equi-DSRL gradient step (`perf` and a per-shape tally of `examples/bench --only equi`). Here
//! each row's fields are loaded a tile at a time (8 fields on AVX2, 16 on AVX-512), transposed
//! in registers so that one vector holds one component of the tile's fields, and each frequency
//! is one chain of eight fused multiply-adds written straight into its block. The loops are
//! written once ([`forward_tiles`], [`inverse_tiles`]) over a [`Tile`]: what differs between
//! the instruction sets is only the vector type, its masked loads and stores, and the
//! in-register transpose. The generic loops use no closures: a closure there is compiled
//! without the entry point's target features, its intrinsics stay calls, and Equi-DSRL's
//! gradient steps ran 3x slower (`examples/bench --only equi`, 37 against 108 steps/s); as
//! plain loops they run as the two hand-written copies did (120 against 115, alternating runs
//! on an AVX-512 machine).
//!
//! # Same bits as the matrix product
//!
//! Every coefficient is the chain the product computes, `(((c0 + x_0 t_0) + x_1 t_1) + ...)`
//! with fused multiply-adds from component (or frequency) 0 up, `c0` = 0 for the forward
//! transform and the field's bias (or 0) for the inverse. Only where the values travel differs.
//! The portable copy (also the `f64` path and CPUs without AVX2) runs the same chains one
//! coefficient at a time; a test compares the copies bit for bit. A tile's lanes past the last
//! field are zero-filled on load and never stored.

use super::ORDER;
use crate::{as_f32s, as_f32s_mut, Isa, Real};

/// Where frequency row `k` of the transform of row `r` lives in a Fourier buffer of `f`
/// fields: `base + r * stride` (then `f` consecutive values, one per field).
#[derive(Clone, Copy, Debug)]
pub struct Blocks {
    rows: usize,
    f: usize,
}

impl Blocks {
    pub fn new(rows: usize, f: usize) -> Self {
        Self { rows, f }
    }

    /// rho0 (`rows x F`), rho4 (`rows x F`), then each 2-d irrep as `rows x [re (F) | im (F)]`.
    #[inline(always)]
    fn at(&self, k: usize, r: usize) -> usize {
        let (rows, f) = (self.rows, self.f);
        match k {
            0 => r * f,
            1 => rows * f + r * f,
            _ => {
                let j = (k - 2) / 2;
                2 * rows * f + 2 * j * rows * f + r * 2 * f + ((k - 2) % 2) * f
            }
        }
    }

    pub fn len(&self) -> usize {
        self.rows * self.f * ORDER
    }
}

/// `out` (blocks of `f` fields) from `x` (`rows x 8 F`, field-major): coefficient `k` of
/// field `i` is `sum_a x[i, a] t[k][a]`.
pub fn forward<T: Real>(t: &[[T; ORDER]; ORDER], x: &[T], rows: usize, f: usize, out: &mut [T]) {
    let blocks = Blocks::new(rows, f);
    assert!(x.len() >= blocks.len() && out.len() >= blocks.len(), "transform: short buffers");
    #[cfg(target_arch = "x86_64")]
    if let (Some(t32), Some(x32), Some(o32)) = (as_f32s(t.as_flattened()), as_f32s(x), as_f32s_mut(out)) {
        match Isa::best() {
            // SAFETY: the CPU has AVX-512 F; the lengths were checked above.
            Isa::Avx512 => return unsafe { x86::forward_avx512(t32, x32, blocks, o32) },
            // SAFETY: the CPU has AVX2 and FMA; the lengths were checked above.
            Isa::Avx2 => return unsafe { x86::forward_avx2(t32, x32, blocks, o32) },
            Isa::Portable => {}
        }
    }
    forward_body(t, x, blocks, out)
}

/// `out` (`rows x 8 F`, field-major, overwritten) from the blocks `xh`: value `a` of field
/// `i` is `init_i + sum_k xh_k[i] t[k][a]`, with `init` one value per field (a bias) or 0.
pub fn inverse<T: Real>(t: &[[T; ORDER]; ORDER], xh: &[T], rows: usize, f: usize, init: Option<&[T]>, out: &mut [T]) {
    let blocks = Blocks::new(rows, f);
    assert!(xh.len() >= blocks.len() && out.len() >= blocks.len(), "transform: short buffers");
    assert!(init.is_none_or(|v| v.len() >= f), "transform: short init");
    #[cfg(target_arch = "x86_64")]
    if let (Some(t32), Some(x32), Some(o32)) = (as_f32s(t.as_flattened()), as_f32s(xh), as_f32s_mut(out)) {
        let init32 = init.map(|v| as_f32s(v).expect("init has the type of xh"));
        match Isa::best() {
            // SAFETY: the CPU has AVX-512 F; the lengths were checked above.
            Isa::Avx512 => return unsafe { x86::inverse_avx512(t32, x32, blocks, init32, o32) },
            // SAFETY: the CPU has AVX2 and FMA; the lengths were checked above.
            Isa::Avx2 => return unsafe { x86::inverse_avx2(t32, x32, blocks, init32, o32) },
            Isa::Portable => {}
        }
    }
    inverse_body(t, xh, blocks, init, out)
}

/// The portable copy: one chain per coefficient.
fn forward_body<T: Real>(t: &[[T; ORDER]; ORDER], x: &[T], blocks: Blocks, out: &mut [T]) {
    let f = blocks.f;
    for r in 0..blocks.rows {
        for i in 0..f {
            let xs = &x[(r * f + i) * ORDER..(r * f + i + 1) * ORDER];
            for (k, tk) in t.iter().enumerate() {
                let mut acc = T::ZERO;
                for (xa, ta) in xs.iter().zip(tk) {
                    acc = xa.fma(*ta, acc);
                }
                out[blocks.at(k, r) + i] = acc;
            }
        }
    }
}

/// The portable copy of [`inverse`].
fn inverse_body<T: Real>(t: &[[T; ORDER]; ORDER], xh: &[T], blocks: Blocks, init: Option<&[T]>, out: &mut [T]) {
    let f = blocks.f;
    for r in 0..blocks.rows {
        for i in 0..f {
            let c0 = init.map_or(T::ZERO, |v| v[i]);
            for a in 0..ORDER {
                let mut acc = c0;
                for (k, tk) in t.iter().enumerate() {
                    acc = xh[blocks.at(k, r) + i].fma(tk[a], acc);
                }
                out[(r * f + i) * ORDER + a] = acc;
            }
        }
    }
}

/// One instruction set's view of a tile of [`Tile::LANES`] fields x [`ORDER`] components:
/// eight vectors of `LANES` f32 lanes, in memory field-major (`LANES x 8` contiguous values).
///
/// # Safety
///
/// Every method may only run on a CPU with the implementor's features; pointers must be valid
/// for the lanes they name (`valid` lanes for the masked loads and stores).
#[cfg(target_arch = "x86_64")]
unsafe trait Tile {
    const LANES: usize;
    type V: Copy;
    unsafe fn zero() -> Self::V;
    unsafe fn splat(v: f32) -> Self::V;
    /// `a * b + c`, one rounding.
    unsafe fn fmadd(a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    /// The first `valid` lanes from `p` (the rest 0).
    unsafe fn load(p: *const f32, valid: usize) -> Self::V;
    /// The first `valid` lanes to `p`.
    unsafe fn store(p: *mut f32, v: Self::V, valid: usize);
    /// The tile as loaded (vector `b` = values `b LANES ..` of the field-major tile) to one
    /// vector per component (lane `i` = field `i`).
    unsafe fn fields_to_components(v: [Self::V; ORDER]) -> [Self::V; ORDER];
    /// The inverse of [`Tile::fields_to_components`].
    unsafe fn components_to_fields(v: [Self::V; ORDER]) -> [Self::V; ORDER];
}

/// Lanes of vector `b` of a tile holding `nf` fields.
#[inline(always)]
fn valid_lanes(nf: usize, b: usize, lanes: usize) -> usize {
    (nf * ORDER).saturating_sub(b * lanes).min(lanes)
}

/// [`forward`] a tile at a time.
///
/// # Safety
///
/// The CPU has `L`'s features; `t` is 8 x 8 and `x`, `out` hold `blocks.len()` values.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn forward_tiles<L: Tile>(t: &[f32], x: &[f32], blocks: Blocks, out: &mut [f32]) {
    let f = blocks.f;
    let (xp, op) = (x.as_ptr(), out.as_mut_ptr());
    // SAFETY: the caller's contract; every offset stays below `blocks.len()`, and the masks
    // keep the last tile's loads and stores inside its `nf` fields.
    unsafe {
        for r in 0..blocks.rows {
            let mut i0 = 0;
            while i0 < f {
                let nf = L::LANES.min(f - i0);
                let base = xp.add((r * f + i0) * ORDER);
                let mut v = [L::zero(); ORDER];
                for (b, vb) in v.iter_mut().enumerate() {
                    *vb = L::load(base.add(b * L::LANES), valid_lanes(nf, b, L::LANES));
                }
                let comp = L::fields_to_components(v);
                for k in 0..ORDER {
                    let mut acc = L::zero();
                    for (a, ca) in comp.iter().enumerate() {
                        acc = L::fmadd(*ca, L::splat(t[k * ORDER + a]), acc);
                    }
                    L::store(op.add(blocks.at(k, r) + i0), acc, nf);
                }
                i0 += nf;
            }
        }
    }
}

/// [`inverse`] a tile at a time.
///
/// # Safety
///
/// As [`forward_tiles`]; `init`, when given, holds `blocks.f` values.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn inverse_tiles<L: Tile>(t: &[f32], xh: &[f32], blocks: Blocks, init: Option<&[f32]>, out: &mut [f32]) {
    let f = blocks.f;
    let (xp, op) = (xh.as_ptr(), out.as_mut_ptr());
    // SAFETY: as in `forward_tiles`.
    unsafe {
        for r in 0..blocks.rows {
            let mut i0 = 0;
            while i0 < f {
                let nf = L::LANES.min(f - i0);
                let c0 = match init {
                    Some(v) => L::load(v.as_ptr().add(i0), nf),
                    None => L::zero(),
                };
                let mut coef = [L::zero(); ORDER];
                for (k, ck) in coef.iter_mut().enumerate() {
                    *ck = L::load(xp.add(blocks.at(k, r) + i0), nf);
                }
                let mut vals = [c0; ORDER];
                for (a, va) in vals.iter_mut().enumerate() {
                    for (k, ck) in coef.iter().enumerate() {
                        *va = L::fmadd(*ck, L::splat(t[k * ORDER + a]), *va);
                    }
                }
                let fields = L::components_to_fields(vals);
                let base = op.add((r * f + i0) * ORDER);
                for (b, v) in fields.iter().enumerate() {
                    L::store(base.add(b * L::LANES), *v, valid_lanes(nf, b, L::LANES));
                }
                i0 += nf;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86;

#[cfg(test)]
mod tests {
    use super::*;

    use crate::hashed_values as data;

    /// The dispatched copy (AVX-512 where the CPU has it) and the AVX2 copy give the portable
    /// chains' bits, for field counts below, at and above a tile, and the inverse undoes the
    /// forward (the transform is orthonormal).
    #[test]
    fn every_copy_gives_the_portable_bits_and_the_inverse_undoes_the_forward() {
        let t = super::super::dft_matrix().map(|row| row.map(|v| v as f32));
        let bits = |v: &[f32]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for &(rows, f) in &[(5, 24), (3, 1), (4, 16), (7, 17), (2, 40), (3, 7), (2, 9)] {
            let n = rows * f * ORDER;
            let (x, bias) = (data(n, 1), data(f, 2));
            let blocks = Blocks::new(rows, f);
            let (mut fast, mut slow) = (vec![0.0; n], vec![0.0; n]);
            forward(&t, &x, rows, f, &mut fast);
            forward_body(&t, &x, blocks, &mut slow);
            assert_eq!(bits(&fast), bits(&slow), "forward {rows} x {f}");
            #[cfg(target_arch = "x86_64")]
            if crate::has_fast_fma() {
                let (mut v2, mut back2, mut back2_slow) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
                // SAFETY: the CPU has AVX2 and FMA; the buffers hold `blocks.len()` values.
                unsafe { x86::forward_avx2(t.as_flattened(), &x, blocks, &mut v2) };
                assert_eq!(bits(&v2), bits(&slow), "avx2 forward {rows} x {f}");
                // SAFETY: as above.
                unsafe { x86::inverse_avx2(t.as_flattened(), &slow, blocks, Some(&bias), &mut back2) };
                inverse_body(&t, &slow, blocks, Some(&bias[..]), &mut back2_slow);
                assert_eq!(bits(&back2), bits(&back2_slow), "avx2 inverse {rows} x {f}");
            }
            for init in [None, Some(&bias[..])] {
                let (mut back, mut back_slow) = (vec![0.0; n], vec![0.0; n]);
                inverse(&t, &fast, rows, f, init, &mut back);
                inverse_body(&t, &fast, blocks, init, &mut back_slow);
                assert_eq!(bits(&back), bits(&back_slow), "inverse {rows} x {f}");
                for (j, (b, v)) in back.iter().zip(&x).enumerate() {
                    let c0 = init.map_or(0.0, |i| i[(j / ORDER) % f]);
                    assert!((b - c0 - v).abs() < 1e-5, "round trip at {j}: {b} vs {v}");
                }
            }
        }
    }
}
