//! Regular-to-regular C8-equivariant layers in the Fourier (irrep) basis.
//!
//! A C8-equivariant map between regular fields is block-circulant: dense, it costs
//! `64 F_out F_in` multiply-adds per sample. The real, orthonormal 8-point DFT `T` splits each
//! regular field into its irreducible parts: rho0 (the normalised sum), rho4 (the alternating
//! sum) and rho1, rho2, rho3 as (re, im) pairs. In that basis the map is block-diagonal by
//! frequency: a real `F_in x F_out` matrix for rho0 and for rho4, and a complex one
//! (`A + iB`, acting on (re, im) as `[[A, B], [-B, A]]`) for each 2-d irrep: 2 + 3 x 2 = 8
//! parameters per field pair, as in the spatial basis, for `(2 + 3 x 4) F_out F_in = 14 F_out
//! F_in` multiply-adds (4.6x fewer), plus the transforms into and out of the basis (64 per field
//! and direction) around the pointwise nonlinearities, which act on the spatial values.
//!
//! The parameters are the Fourier-basis coefficients themselves (a fixed invertible
//! reparametrisation of the circulant weights); the bias is one value per output field,
//! constant over the field. Each frequency's product is one [`gemm`] with its fixed summation
//! order, so results stay independent of batch size and row splits. Exactly equivariant: a
//! group element acts in the Fourier basis as a rotation by `w theta` on each (re, im) pair and
//! a sign on rho4, which every such block commutes with (up to float rounding in `T`).

use crate::gemm::transpose;
use crate::{gemm, ops, Real, Trans};

/// The group order this layer is written for.
pub const ORDER: usize = 8;
/// Rows of `T`: rho0, rho4, then (re, im) of rho1, rho2, rho3.
const COMPLEX_FREQS: [usize; 3] = [1, 2, 3];

/// The orthonormal real DFT `T` (8 x 8, row-major): `xhat = T x`, `x = T^T xhat`.
#[allow(clippy::needless_range_loop)]
pub fn dft_matrix() -> [[f64; ORDER]; ORDER] {
    let mut t = [[0.0; ORDER]; ORDER];
    let n = ORDER as f64;
    for a in 0..ORDER {
        let th = std::f64::consts::TAU * a as f64 / n;
        t[0][a] = 1.0 / n.sqrt();
        t[1][a] = if a % 2 == 0 { 1.0 } else { -1.0 } / n.sqrt();
        for (j, &w) in COMPLEX_FREQS.iter().enumerate() {
            t[2 + 2 * j][a] = libm::cos(w as f64 * th) * (2.0 / n).sqrt();
            t[3 + 2 * j][a] = -libm::sin(w as f64 * th) * (2.0 / n).sqrt();
        }
    }
    t
}

/// A regular -> regular layer in the Fourier basis and its expanded matrices.
#[derive(Clone, Debug)]
pub struct Circulant<T> {
    pub f_in: usize,
    pub f_out: usize,
    /// Parameter offset: rho0 (F_in x F_out), rho4, then A_w, B_w for w = 1, 2, 3; then bias (F_out).
    pub w: usize,
    pub b: usize,
    t: [[T; ORDER]; ORDER],
    /// Per frequency block: the gemm matrix (`n_in x n_out`) and its transpose.
    mats: [Vec<T>; 5],
    mats_t: [Vec<T>; 5],
}

impl<T: Real> Circulant<T> {
    pub fn new(f_in: usize, f_out: usize, w: usize, b: usize) -> Self {
        let d = dft_matrix();
        let t = d.map(|row| row.map(T::from_f64));
        let sizes = [f_in * f_out, f_in * f_out, 4 * f_in * f_out, 4 * f_in * f_out, 4 * f_in * f_out];
        Self { f_in, f_out, w, b, t, mats: sizes.map(|n| vec![T::ZERO; n]), mats_t: sizes.map(|n| vec![T::ZERO; n]) }
    }

    /// Parameters: 8 per field pair plus one bias per output field.
    pub fn num_weights(f_in: usize, f_out: usize) -> usize {
        8 * f_in * f_out
    }

    /// The standard deviation scale of the coefficients that gives the same Frobenius norm as
    /// the spatial (circulant) initialisation U(+-1/sqrt(8 F_in)): sqrt(64 / 14).
    pub fn init_scale() -> f64 {
        (64.0f64 / 14.0).sqrt()
    }

    fn block_dims(&self, k: usize) -> (usize, usize) {
        if k < 2 {
            (self.f_in, self.f_out)
        } else {
            (2 * self.f_in, 2 * self.f_out)
        }
    }

    /// Rebuild the gemm matrices from the parameters.
    pub fn expand(&mut self, params: &[T]) {
        let (fi, fo) = (self.f_in, self.f_out);
        let n = fi * fo;
        self.mats[0].copy_from_slice(&params[self.w..self.w + n]);
        self.mats[1].copy_from_slice(&params[self.w + n..self.w + 2 * n]);
        for j in 0..3 {
            let a = &params[self.w + (2 + 2 * j) * n..self.w + (3 + 2 * j) * n];
            let bb = &params[self.w + (3 + 2 * j) * n..self.w + (4 + 2 * j) * n];
            let m = &mut self.mats[2 + j];
            // [re_in | im_in] (2 F_in rows) x [re_out | im_out] (2 F_out columns): [[A, B], [-B, A]]
            for i in 0..fi {
                for o in 0..fo {
                    let (av, bv) = (a[i * fo + o], bb[i * fo + o]);
                    m[i * 2 * fo + o] = av;
                    m[i * 2 * fo + fo + o] = bv;
                    m[(fi + i) * 2 * fo + o] = -bv;
                    m[(fi + i) * 2 * fo + fo + o] = av;
                }
            }
        }
        for k in 0..5 {
            let (r, c) = self.block_dims(k);
            transpose(r, c, &self.mats[k], &mut self.mats_t[k]);
        }
    }

    /// Spatial (rows x 8 F) -> Fourier blocks, concatenated: [x0 | x4 | xc1 | xc2 | xc3], each
    /// block rows x (F or 2 F).
    fn fourier(&self, x: &[T], rows: usize, f: usize, out: &mut Vec<T>) {
        ops::resize_for_overwrite(out, rows * ORDER * f);
        transform::forward(&self.t, x, rows, f, out);
    }

    /// Fourier blocks -> spatial (rows x 8 F) into `out`, each field starting from its value in
    /// `init` (a bias) or 0.
    fn spatial(&self, xh: &[T], rows: usize, f: usize, init: Option<&[T]>, out: &mut Vec<T>) {
        ops::resize_for_overwrite(out, rows * ORDER * f);
        transform::inverse(&self.t, xh, rows, f, init, out);
    }

    /// Block offsets within a Fourier buffer of `f` fields.
    fn offsets(rows: usize, f: usize) -> [usize; 6] {
        [0, rows * f, 2 * rows * f, 4 * rows * f, 6 * rows * f, 8 * rows * f]
    }

    /// Forward: `out` (rows x 8 F_out) from `x` (rows x 8 F_in); keeps the input's Fourier
    /// blocks in `xhat` for the backward pass (`yhat` is a reused buffer).
    #[allow(clippy::too_many_arguments)]
    pub fn forward(&self, params: &[T], x: &[T], rows: usize, out: &mut Vec<T>, xhat: &mut Vec<T>, yhat: &mut Vec<T>) {
        let (fi, fo) = (self.f_in, self.f_out);
        self.fourier(x, rows, fi, xhat);
        ops::resize_for_overwrite(yhat, rows * 8 * fo);
        let (oi, oo) = (Self::offsets(rows, fi), Self::offsets(rows, fo));
        for k in 0..5 {
            let (n_in, n_out) = self.block_dims(k);
            gemm(
                rows,
                n_out,
                n_in,
                &xhat[oi[k]..oi[k + 1]],
                Trans::N,
                &self.mats[k],
                &mut yhat[oo[k]..oo[k + 1]],
                false,
            );
        }
        self.spatial(yhat, rows, fo, Some(&params[self.b..self.b + fo]), out);
    }

    /// Backward from `dy` (rows x 8 F_out): parameter gradients into `grads` (when given), the
    /// input gradient into `dx` (when given); `dyhat` and `gm` are reused buffers.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        xhat: &[T],
        dy: &[T],
        rows: usize,
        grads: Option<&mut [T]>,
        dx: Option<&mut Vec<T>>,
        dyhat: &mut Vec<T>,
        gm: &mut Vec<T>,
    ) {
        let (fi, fo) = (self.f_in, self.f_out);
        // The inverse transform is T^T, so its backward is T.
        self.fourier(dy, rows, fo, dyhat);
        let (oi, oo) = (Self::offsets(rows, fi), Self::offsets(rows, fo));
        if let Some(g) = grads {
            let n = fi * fo;
            for fld in 0..fo {
                let mut s = T::ZERO;
                for r in 0..rows {
                    for a in 0..ORDER {
                        s += dy[r * ORDER * fo + fld * ORDER + a];
                    }
                }
                g[self.b + fld] += s;
            }
            for k in 0..5 {
                let (n_in, n_out) = self.block_dims(k);
                ops::resize_for_overwrite(gm, n_in * n_out);
                gemm(n_in, n_out, rows, &xhat[oi[k]..oi[k + 1]], Trans::T, &dyhat[oo[k]..oo[k + 1]], gm, false);
                if k < 2 {
                    for (gi, v) in g[self.w + k * n..self.w + (k + 1) * n].iter_mut().zip(gm.iter()) {
                        *gi += *v;
                    }
                } else {
                    let j = k - 2;
                    let (ga, gb) = (self.w + (2 + 2 * j) * n, self.w + (3 + 2 * j) * n);
                    for i in 0..fi {
                        for o in 0..fo {
                            let g00 = gm[i * 2 * fo + o];
                            let g01 = gm[i * 2 * fo + fo + o];
                            let g10 = gm[(fi + i) * 2 * fo + o];
                            let g11 = gm[(fi + i) * 2 * fo + fo + o];
                            g[ga + i * fo + o] += g00 + g11;
                            g[gb + i * fo + o] += g01 - g10;
                        }
                    }
                }
            }
        }
        if let Some(dx) = dx {
            ops::resize_for_overwrite(gm, rows * 8 * fi);
            for k in 0..5 {
                let (n_in, n_out) = self.block_dims(k);
                gemm(
                    rows,
                    n_in,
                    n_out,
                    &dyhat[oo[k]..oo[k + 1]],
                    Trans::N,
                    &self.mats_t[k],
                    &mut gm[oi[k]..oi[k + 1]],
                    false,
                );
            }
            self.spatial(gm, rows, fi, None, dx);
        }
    }

    pub fn cast<U: Real>(&self, params: &[U]) -> Circulant<U> {
        let mut c = Circulant::new(self.f_in, self.f_out, self.w, self.b);
        c.expand(params);
        c
    }
}

/// The transforms of a batch of regular fields into and out of the Fourier blocks of
/// [`Circulant`], written as one kernel each instead of an `8 x 8` matrix product and a reshuffle.
///
/// # Why a kernel of its own
///
/// As a matrix product (`(rows F) x 8` times `8 x 8`) the transform ran at 37 GFLOP/s (the
/// product's narrowest shape), and the reshuffle into the blocks was scalar: together 19 % of an
/// Equi-DSRL gradient step (`perf` and a per-shape tally of `examples/bench --only equi`). Here
/// each row's fields are loaded sixteen at a time, transposed in registers (AVX-512 two-source
/// permutes) so that one vector holds one component of sixteen fields, and each frequency is one
/// chain of eight fused multiply-adds written straight into its block.
///
/// # Same bits as the matrix product
///
/// Every coefficient is the chain the product computes, `(((c0 + x_0 t_0) + x_1 t_1) + ...)`
/// with fused multiply-adds from component (or frequency) 0 up, `c0` = 0 for the forward
/// transform and the field's bias (or 0) for the inverse. Only where the values travel differs.
/// The portable copy (also the `f64` path and CPUs without AVX-512) runs the same chains one
/// coefficient at a time; a test compares the copies bit for bit.
mod transform {
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
                Isa::Avx512 => return unsafe { avx512::forward(t32, x32, blocks, o32) },
                // SAFETY: the CPU has AVX2 and FMA.
                Isa::Avx2 => return unsafe { avx2::forward(t32, x32, blocks, o32) },
                Isa::Portable => {}
            }
        }
        forward_body(t, x, blocks, out)
    }

    /// `out` (`rows x 8 F`, field-major, overwritten) from the blocks `xh`: value `a` of field
    /// `i` is `init_i + sum_k xh_k[i] t[k][a]`, with `init` one value per field (a bias) or 0.
    pub fn inverse<T: Real>(
        t: &[[T; ORDER]; ORDER],
        xh: &[T],
        rows: usize,
        f: usize,
        init: Option<&[T]>,
        out: &mut [T],
    ) {
        let blocks = Blocks::new(rows, f);
        assert!(xh.len() >= blocks.len() && out.len() >= blocks.len(), "transform: short buffers");
        assert!(init.is_none_or(|v| v.len() >= f), "transform: short init");
        #[cfg(target_arch = "x86_64")]
        if let (Some(t32), Some(x32), Some(o32)) = (as_f32s(t.as_flattened()), as_f32s(xh), as_f32s_mut(out)) {
            let init32 = init.map(|v| as_f32s(v).expect("init has the type of xh"));
            match Isa::best() {
                // SAFETY: the CPU has AVX-512 F; the lengths were checked above.
                Isa::Avx512 => return unsafe { avx512::inverse(t32, x32, blocks, init32, o32) },
                // SAFETY: the CPU has AVX2 and FMA.
                Isa::Avx2 => return unsafe { avx2::inverse(t32, x32, blocks, init32, o32) },
                Isa::Portable => {}
            }
        }
        inverse_body(t, xh, blocks, init, out)
    }

    #[inline(always)]
    fn forward_body<T: Real>(t: &[[T; ORDER]; ORDER], x: &[T], blocks: Blocks, out: &mut [T]) {
        for r in 0..blocks.rows {
            for i in 0..blocks.f {
                forward_field(t, x, blocks, r, i, out);
            }
        }
    }

    /// The forward transform of field `i` of row `r`.
    #[inline(always)]
    fn forward_field<T: Real>(t: &[[T; ORDER]; ORDER], x: &[T], blocks: Blocks, r: usize, i: usize, out: &mut [T]) {
        let f = blocks.f;
        let xs = &x[(r * f + i) * ORDER..(r * f + i + 1) * ORDER];
        for (k, tk) in t.iter().enumerate() {
            let mut acc = T::ZERO;
            for (xa, ta) in xs.iter().zip(tk) {
                acc = xa.fma(*ta, acc);
            }
            out[blocks.at(k, r) + i] = acc;
        }
    }

    #[inline(always)]
    fn inverse_body<T: Real>(t: &[[T; ORDER]; ORDER], xh: &[T], blocks: Blocks, init: Option<&[T]>, out: &mut [T]) {
        for r in 0..blocks.rows {
            for i in 0..blocks.f {
                inverse_field(t, xh, blocks, init, r, i, out);
            }
        }
    }

    /// The inverse transform of field `i` of row `r`.
    #[inline(always)]
    fn inverse_field<T: Real>(
        t: &[[T; ORDER]; ORDER],
        xh: &[T],
        blocks: Blocks,
        init: Option<&[T]>,
        r: usize,
        i: usize,
        out: &mut [T],
    ) {
        let f = blocks.f;
        let c0 = init.map_or(T::ZERO, |v| v[i]);
        for a in 0..ORDER {
            let mut acc = c0;
            for (k, tk) in t.iter().enumerate() {
                acc = xh[blocks.at(k, r) + i].fma(tk[a], acc);
            }
            out[(r * f + i) * ORDER + a] = acc;
        }
    }

    /// The AVX2 copy: eight fields at a time (an 8 x 8 tile transposed in registers), the
    /// fields past the last multiple of eight one at a time. As the portable chains, the old
    /// matrix-product form ran at about the same speed; the portable chains alone took 28 % of
    /// an Equi-DSRL gradient step on AVX2 (`perf`, the AVX-512 copies switched off).
    #[cfg(target_arch = "x86_64")]
    mod avx2 {
        use super::{forward_field, inverse_field, Blocks, ORDER};
        use std::arch::x86_64::*;

        /// Fields per register block.
        const LANES: usize = 8;

        /// Transpose an 8 x 8 tile held as eight row vectors (its own inverse).
        #[inline(always)]
        unsafe fn transpose(r: [__m256; 8]) -> [__m256; 8] {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let t: [__m256; 8] = std::array::from_fn(|i| {
                    let (a, b) = (r[2 * (i / 2)], r[2 * (i / 2) + 1]);
                    if i % 2 == 0 {
                        _mm256_unpacklo_ps(a, b)
                    } else {
                        _mm256_unpackhi_ps(a, b)
                    }
                });
                // u[4 g + q]: rows 4 g .. 4 g + 4, component q (and q + 4) of each 128-bit half
                let u: [__m256; 8] = std::array::from_fn(|i| {
                    let (g, q) = (i / 4, i % 4);
                    let (a, b) = (t[4 * g + q / 2], t[4 * g + 2 + q / 2]);
                    if q % 2 == 0 {
                        _mm256_shuffle_ps::<0x44>(a, b)
                    } else {
                        _mm256_shuffle_ps::<0xEE>(a, b)
                    }
                });
                std::array::from_fn(|c| {
                    if c < 4 {
                        _mm256_permute2f128_ps::<0x20>(u[c], u[4 + c])
                    } else {
                        _mm256_permute2f128_ps::<0x31>(u[c - 4], u[c])
                    }
                })
            }
        }

        #[target_feature(enable = "avx2,fma")]
        pub unsafe fn forward(t: &[f32], x: &[f32], blocks: Blocks, out: &mut [f32]) {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let f = blocks.f;
                let t88: &[[f32; ORDER]; ORDER] = &*(t.as_ptr() as *const [[f32; ORDER]; ORDER]);
                let xp = x.as_ptr();
                for r in 0..blocks.rows {
                    let mut i0 = 0;
                    while i0 + LANES <= f {
                        let base = xp.add((r * f + i0) * ORDER);
                        let comp = transpose(std::array::from_fn(|b| _mm256_loadu_ps(base.add(b * ORDER))));
                        for k in 0..ORDER {
                            let mut acc = _mm256_setzero_ps();
                            for (a, ca) in comp.iter().enumerate() {
                                acc = _mm256_fmadd_ps(*ca, _mm256_set1_ps(t[k * ORDER + a]), acc);
                            }
                            _mm256_storeu_ps(out.as_mut_ptr().add(blocks.at(k, r) + i0), acc);
                        }
                        i0 += LANES;
                    }
                    for i in i0..f {
                        forward_field(t88, x, blocks, r, i, out);
                    }
                }
            }
        }

        #[target_feature(enable = "avx2,fma")]
        pub unsafe fn inverse(t: &[f32], xh: &[f32], blocks: Blocks, init: Option<&[f32]>, out: &mut [f32]) {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let f = blocks.f;
                let t88: &[[f32; ORDER]; ORDER] = &*(t.as_ptr() as *const [[f32; ORDER]; ORDER]);
                let xp = xh.as_ptr();
                for r in 0..blocks.rows {
                    let mut i0 = 0;
                    while i0 + LANES <= f {
                        let c0 = match init {
                            Some(v) => _mm256_loadu_ps(v.as_ptr().add(i0)),
                            None => _mm256_setzero_ps(),
                        };
                        let coef: [__m256; 8] = std::array::from_fn(|k| _mm256_loadu_ps(xp.add(blocks.at(k, r) + i0)));
                        let vals: [__m256; 8] = std::array::from_fn(|a| {
                            let mut acc = c0;
                            for (k, ck) in coef.iter().enumerate() {
                                acc = _mm256_fmadd_ps(*ck, _mm256_set1_ps(t[k * ORDER + a]), acc);
                            }
                            acc
                        });
                        let fields = transpose(vals);
                        let base = out.as_mut_ptr().add((r * f + i0) * ORDER);
                        for (b, v) in fields.iter().enumerate() {
                            _mm256_storeu_ps(base.add(b * ORDER), *v);
                        }
                        i0 += LANES;
                    }
                    for i in i0..f {
                        inverse_field(t88, xh, blocks, init, r, i, out);
                    }
                }
            }
        }
    }

    /// The AVX-512 copy: sixteen fields at a time (a masked block for the rest).
    #[cfg(target_arch = "x86_64")]
    mod avx512 {
        use super::{Blocks, ORDER};
        use std::arch::x86_64::*;

        /// Fields per register block: a 512-bit vector holds one component of sixteen fields.
        const LANES: usize = 16;

        /// Two-source permute indices of the three transpose stages (field-major -> one vector
        /// per component). Stage 1 (by component half `h`): lane `4 l + c` = field `l` (of 4),
        /// component `4 h + c`. Stage 2 (by component pair `q`): lane `2 l + c` = field `l` (of
        /// 8), component `2 q + c` of the half. Stage 3 (by component parity `c`): lane `l` =
        /// field `l` (of 16).
        const fn to_components(stage: usize, sel: usize) -> [i32; 16] {
            let mut idx = [0i32; 16];
            let mut lane = 0;
            while lane < 16 {
                idx[lane] = match stage {
                    1 => {
                        let (l, c) = (lane / 4, lane % 4);
                        (l / 2) * 16 + (l % 2) * 8 + 4 * sel + c
                    }
                    2 => {
                        let (l, c) = (lane / 2, lane % 2);
                        (l / 4) * 16 + (l % 4) * 4 + 2 * sel + c
                    }
                    _ => (lane / 8) * 16 + (lane % 8) * 2 + sel,
                } as i32;
                lane += 1;
            }
            idx
        }

        /// The inverse stages (one vector per component -> field-major), in the order they run.
        const fn to_fields(stage: usize, sel: usize) -> [i32; 16] {
            let mut idx = [0i32; 16];
            let mut lane = 0;
            while lane < 16 {
                idx[lane] = match stage {
                    // undo stage 3: lane 2 l + c of field block `sel` (of 8 fields)
                    3 => {
                        let (l, c) = (lane / 2, lane % 2);
                        c * 16 + 8 * sel + l
                    }
                    // undo stage 2: lane 4 l + c, fields 4 sel + l of the 8
                    2 => {
                        let (l, c) = (lane / 4, lane % 4);
                        (c / 2) * 16 + (4 * sel + l) * 2 + c % 2
                    }
                    // undo stage 1: lane p = field (2 sel + p / 8), component p % 8
                    _ => {
                        let comp = lane % 8;
                        (comp / 4) * 16 + (2 * sel + lane / 8) * 4 + comp % 4
                    }
                } as i32;
                lane += 1;
            }
            idx
        }

        #[inline(always)]
        unsafe fn idx(v: [i32; 16]) -> __m512i {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe { _mm512_loadu_si512(v.as_ptr() as *const _) }
        }

        /// 16 fields x 8 components, field-major in `v[0..8]` (two fields each) -> `v[a]` =
        /// component `a` of the 16 fields.
        #[inline(always)]
        unsafe fn fields_to_components(v: [__m512; 8]) -> [__m512; 8] {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let s1i = [idx(to_components(1, 0)), idx(to_components(1, 1))];
                let s2i = [idx(to_components(2, 0)), idx(to_components(2, 1))];
                let s3i = [idx(to_components(3, 0)), idx(to_components(3, 1))];
                // s1[g][h]: fields 4 g .. 4 g + 4, components 4 h .. 4 h + 4
                let s1: [[__m512; 2]; 4] = std::array::from_fn(|g| {
                    std::array::from_fn(|h| _mm512_permutex2var_ps(v[2 * g], s1i[h], v[2 * g + 1]))
                });
                // s2[g][h][q]: fields 8 g .. 8 g + 8, components 4 h + 2 q, + 1
                let s2: [[[__m512; 2]; 2]; 2] = std::array::from_fn(|g| {
                    std::array::from_fn(|h| {
                        std::array::from_fn(|q| _mm512_permutex2var_ps(s1[2 * g][h], s2i[q], s1[2 * g + 1][h]))
                    })
                });
                std::array::from_fn(|a| {
                    let (h, q, c) = (a / 4, (a / 2) % 2, a % 2);
                    _mm512_permutex2var_ps(s2[0][h][q], s3i[c], s2[1][h][q])
                })
            }
        }

        /// The inverse of [`fields_to_components`].
        #[inline(always)]
        unsafe fn components_to_fields(w: [__m512; 8]) -> [__m512; 8] {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let j3 = [idx(to_fields(3, 0)), idx(to_fields(3, 1))];
                let j2 = [idx(to_fields(2, 0)), idx(to_fields(2, 1))];
                let j1 = [idx(to_fields(1, 0)), idx(to_fields(1, 1))];
                let s2: [[[__m512; 2]; 2]; 2] = std::array::from_fn(|g| {
                    std::array::from_fn(|h| {
                        std::array::from_fn(|q| _mm512_permutex2var_ps(w[4 * h + 2 * q], j3[g], w[4 * h + 2 * q + 1]))
                    })
                });
                let s1: [[__m512; 2]; 4] = std::array::from_fn(|g4| {
                    let (g, t) = (g4 / 2, g4 % 2);
                    std::array::from_fn(|h| _mm512_permutex2var_ps(s2[g][h][0], j2[t], s2[g][h][1]))
                });
                std::array::from_fn(|i| {
                    let (g4, u) = (i / 2, i % 2);
                    _mm512_permutex2var_ps(s1[g4][0], j1[u], s1[g4][1])
                })
            }
        }

        /// Mask of the first `n` lanes (`n <= 16`).
        #[inline(always)]
        fn first(n: usize) -> __mmask16 {
            ((1u32 << n) - 1) as __mmask16
        }

        #[target_feature(enable = "avx512f")]
        pub unsafe fn forward(t: &[f32], x: &[f32], blocks: Blocks, out: &mut [f32]) {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let f = blocks.f;
                let (xp, op) = (x.as_ptr(), out.as_mut_ptr());
                for r in 0..blocks.rows {
                    let mut i0 = 0;
                    while i0 < f {
                        let nf = LANES.min(f - i0);
                        let base = xp.add((r * f + i0) * ORDER);
                        let v: [__m512; 8] = std::array::from_fn(|b| {
                            let valid = (nf * ORDER).saturating_sub(b * LANES).min(LANES);
                            _mm512_maskz_loadu_ps(first(valid), base.add(b * LANES))
                        });
                        let comp = fields_to_components(v);
                        for k in 0..ORDER {
                            let mut acc = _mm512_setzero_ps();
                            for (a, ca) in comp.iter().enumerate() {
                                acc = _mm512_fmadd_ps(*ca, _mm512_set1_ps(t[k * ORDER + a]), acc);
                            }
                            _mm512_mask_storeu_ps(op.add(blocks.at(k, r) + i0), first(nf), acc);
                        }
                        i0 += nf;
                    }
                }
            }
        }

        #[target_feature(enable = "avx512f")]
        pub unsafe fn inverse(t: &[f32], xh: &[f32], blocks: Blocks, init: Option<&[f32]>, out: &mut [f32]) {
            // SAFETY: this function's contract (its callers check the CPU features it is compiled for
            // and pass slices of the documented lengths) is what makes the intrinsics, loads and stores
            // below sound; every pointer offset stays inside those slices.
            unsafe {
                let f = blocks.f;
                let (xp, op) = (xh.as_ptr(), out.as_mut_ptr());
                for r in 0..blocks.rows {
                    let mut i0 = 0;
                    while i0 < f {
                        let nf = LANES.min(f - i0);
                        let m = first(nf);
                        let c0 = match init {
                            Some(v) => _mm512_maskz_loadu_ps(m, v.as_ptr().add(i0)),
                            None => _mm512_setzero_ps(),
                        };
                        let coef: [__m512; 8] =
                            std::array::from_fn(|k| _mm512_maskz_loadu_ps(m, xp.add(blocks.at(k, r) + i0)));
                        let vals: [__m512; 8] = std::array::from_fn(|a| {
                            let mut acc = c0;
                            for (k, ck) in coef.iter().enumerate() {
                                acc = _mm512_fmadd_ps(*ck, _mm512_set1_ps(t[k * ORDER + a]), acc);
                            }
                            acc
                        });
                        let fields = components_to_fields(vals);
                        let base = op.add((r * f + i0) * ORDER);
                        for (b, v) in fields.iter().enumerate() {
                            let valid = (nf * ORDER).saturating_sub(b * LANES).min(LANES);
                            _mm512_mask_storeu_ps(base.add(b * LANES), first(valid), *v);
                        }
                        i0 += nf;
                    }
                }
            }
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        use crate::hashed_values as data;

        /// The dispatched copy (AVX-512 where the CPU has it) gives the portable chains' bits,
        /// for field counts below, at and above a register block, and the inverse undoes the
        /// forward (the transform is orthonormal).
        #[test]
        fn every_copy_gives_the_portable_bits_and_the_inverse_undoes_the_forward() {
            let t = super::super::dft_matrix().map(|row| row.map(|v| v as f32));
            for &(rows, f) in &[(5, 24), (3, 1), (4, 16), (7, 17), (2, 40)] {
                let n = rows * f * ORDER;
                let (x, bias) = (data(n, 1), data(f, 2));
                let blocks = Blocks::new(rows, f);
                let (mut fast, mut slow) = (vec![0.0; n], vec![0.0; n]);
                forward(&t, &x, rows, f, &mut fast);
                forward_body(&t, &x, blocks, &mut slow);
                #[cfg(target_arch = "x86_64")]
                if crate::has_fast_fma() {
                    let (mut v2, mut back2, mut back2_slow) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
                    // SAFETY: the CPU has AVX2 and FMA.
                    unsafe { avx2::forward(t.as_flattened(), &x, blocks, &mut v2) };
                    assert_eq!(
                        v2.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        slow.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "avx2 forward {rows} x {f}"
                    );
                    unsafe { avx2::inverse(t.as_flattened(), &slow, blocks, Some(&bias), &mut back2) };
                    inverse_body(&t, &slow, blocks, Some(&bias[..]), &mut back2_slow);
                    assert_eq!(
                        back2.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        back2_slow.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "avx2 inverse {rows} x {f}"
                    );
                }
                assert_eq!(
                    fast.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    slow.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    "forward {rows} x {f}"
                );
                for init in [None, Some(&bias[..])] {
                    let (mut back, mut back_slow) = (vec![0.0; n], vec![0.0; n]);
                    inverse(&t, &fast, rows, f, init, &mut back);
                    inverse_body(&t, &fast, blocks, init, &mut back_slow);
                    assert_eq!(
                        back.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        back_slow.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "inverse {rows} x {f}"
                    );
                    for (j, (b, v)) in back.iter().zip(&x).enumerate() {
                        let c0 = init.map_or(0.0, |i| i[(j / ORDER) % f]);
                        assert!((b - c0 - v).abs() < 1e-5, "round trip at {j}: {b} vs {v}");
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dft_is_orthonormal() {
        let t = dft_matrix();
        for i in 0..ORDER {
            for j in 0..ORDER {
                let s: f64 = (0..ORDER).map(|a| t[i][a] * t[j][a]).sum();
                assert!((s - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }
}
