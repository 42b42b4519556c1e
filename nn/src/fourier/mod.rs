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

mod transform;

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
