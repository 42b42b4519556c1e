//! C_N-equivariant linear maps between field types: rho0 (invariant scalars), rho1 (planar
//! vectors rotating with the scene) and regular fields (N values that the group shifts
//! cyclically), as a fixed basis computed once.
//!
//! # Conventions
//!
//! - rho1 is the rotation by `theta_k = 2 pi k / N` counter-clockwise, exactly as the symmetry
//!   layer's [`PlanarRotation`] acts on a task's rho1 pairs (its cosines and sines are used here).
//! - The regular representation shifts: `(g_k h)(a) = h(a - k mod N)`.
//!
//! # The basis (closed form of the intertwiner spaces of C_N, N > 2)
//!
//! With `R_a` the rotation by `theta_a`, every equivariant map out <- in between two fields is a
//! combination of these (parameters per field pair in brackets):
//!
//! | out <- in | map | params |
//! |---|---|---|
//! | rho0 <- rho0 | `y = w x` | 1 |
//! | rho1 <- rho1 | `y = [[p, -q], [q, p]] x` (commutes with every rotation) | 2 |
//! | regular <- rho0 | `y(a) = w x` | 1 |
//! | regular <- rho1 | `y(a) = (R_a u) . x` | 2 |
//! | rho0 <- regular | `y = w sum_a h(a)` | 1 |
//! | rho1 <- regular | `y = sum_a h(a) R_a u` | 2 |
//! | regular <- regular | `y(a) = sum_b w[(a - b) mod N] h(b)` (circulant) | N |
//! | rho0 <-> rho1 | none | 0 |
//!
//! These are the dimensions of the intertwiner spaces (escnn's basis has the same sizes), so a
//! parameter count here equals escnn's for the same field types. Biases live on the invariant
//! parts only: one per rho0 output and one per regular output field (constant over the field).
//!
//! # Expansion
//!
//! A [`Basis`] is a list of (dense entry, parameter, coefficient) triples, in a fixed order. The
//! layer expands its parameters into a plain `n_in x n_out` matrix once per optimiser step and
//! then runs one [`gemm`](equigym_nn::gemm); the gradient of the matrix projects back onto the
//! parameters through the same triples. The expanded matrix is exactly equivariant up to the
//! rounding of `cos theta_a`, `sin theta_a` (exact at quarter turns).

use equigym_wrappers::representation::{Block, Representation};
use equigym_wrappers::{Group, PlanarRotation};

use crate::error::{Error, Result};

/// One field of a flat feature vector, by the indices it occupies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// rho0 at one index.
    Trivial(usize),
    /// rho1 on (x, y).
    Rho1(usize, usize),
    /// A regular field on `start .. start + N`.
    Regular(usize),
}

/// The fields of a representation from the symmetry layer (its rho0 and rho1 blocks), shifted by
/// `offset` (to place it after another representation in a concatenated input).
pub fn fields_of(rep: &Representation, offset: usize) -> Result<Vec<Field>> {
    rep.blocks()
        .iter()
        .map(|b| match *b {
            Block::Trivial { index } => Ok(Field::Trivial(index + offset)),
            Block::Rotating { x, y, frequency: 1 } => Ok(Field::Rho1(x + offset, y + offset)),
            Block::Rotating { frequency, .. } => Err(Error::InvalidOption(format!(
                "equivariant layers take rho0 and rho1 fields, got frequency {frequency}"
            ))),
        })
        .collect()
}

/// `fields` regular fields, contiguous from index 0.
pub fn regular_fields(fields: usize, order: usize) -> Vec<Field> {
    (0..fields).map(|f| Field::Regular(f * order)).collect()
}

/// A basis of the equivariant maps from one list of fields to another (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    pub n_in: usize,
    pub n_out: usize,
    /// Weight parameters (coefficients of the basis).
    pub n_weights: usize,
    /// Bias parameters (stored after the weights).
    pub n_bias: usize,
    /// (index into the `n_in x n_out` matrix, weight parameter, coefficient).
    pub weights: Vec<(u32, u32, f64)>,
    /// (output index, bias parameter).
    pub bias: Vec<(u32, u32)>,
}

/// The group's elements (cos, sin) from the symmetry layer.
fn rotations(order: usize) -> Result<Vec<PlanarRotation>> {
    Ok(Group::cyclic(order)?.elements()?)
}

impl Basis {
    /// The basis of maps `inputs -> outputs` for C_`order` (order > 2).
    pub fn new(inputs: &[Field], n_in: usize, outputs: &[Field], n_out: usize, order: usize) -> Result<Self> {
        if order < 3 {
            return Err(Error::InvalidOption(format!("equivariant layers need C_N with N >= 3, got {order}")));
        }
        let g = rotations(order)?;
        let mut b = Basis { n_in, n_out, n_weights: 0, n_bias: 0, weights: Vec::new(), bias: Vec::new() };
        let push = |b: &mut Basis, i: usize, o: usize, p: usize, c: f64| {
            if c != 0.0 {
                b.weights.push(((i * n_out + o) as u32, p as u32, c));
            }
        };
        for &out in outputs {
            for &inp in inputs {
                let p = b.n_weights;
                match (out, inp) {
                    (Field::Trivial(o), Field::Trivial(i)) => {
                        push(&mut b, i, o, p, 1.0);
                        b.n_weights += 1;
                    }
                    (Field::Rho1(ox, oy), Field::Rho1(ix, iy)) => {
                        // [[p, -q], [q, p]]
                        push(&mut b, ix, ox, p, 1.0);
                        push(&mut b, iy, oy, p, 1.0);
                        push(&mut b, iy, ox, p + 1, -1.0);
                        push(&mut b, ix, oy, p + 1, 1.0);
                        b.n_weights += 2;
                    }
                    (Field::Regular(o), Field::Trivial(i)) => {
                        for a in 0..order {
                            push(&mut b, i, o + a, p, 1.0);
                        }
                        b.n_weights += 1;
                    }
                    (Field::Regular(o), Field::Rho1(ix, iy)) => {
                        // y(a) = (R_a u) . x = x_x (c u0 - s u1) + x_y (s u0 + c u1)
                        for (a, r) in g.iter().enumerate() {
                            let (c, s) = (r.cos(), r.sin());
                            push(&mut b, ix, o + a, p, c);
                            push(&mut b, ix, o + a, p + 1, -s);
                            push(&mut b, iy, o + a, p, s);
                            push(&mut b, iy, o + a, p + 1, c);
                        }
                        b.n_weights += 2;
                    }
                    (Field::Trivial(o), Field::Regular(i)) => {
                        for a in 0..order {
                            push(&mut b, i + a, o, p, 1.0);
                        }
                        b.n_weights += 1;
                    }
                    (Field::Rho1(ox, oy), Field::Regular(i)) => {
                        // y = sum_a h(a) R_a u
                        for (a, r) in g.iter().enumerate() {
                            let (c, s) = (r.cos(), r.sin());
                            push(&mut b, i + a, ox, p, c);
                            push(&mut b, i + a, ox, p + 1, -s);
                            push(&mut b, i + a, oy, p, s);
                            push(&mut b, i + a, oy, p + 1, c);
                        }
                        b.n_weights += 2;
                    }
                    (Field::Regular(o), Field::Regular(i)) => {
                        for a in 0..order {
                            for bb in 0..order {
                                push(&mut b, i + bb, o + a, p + (a + order - bb) % order, 1.0);
                            }
                        }
                        b.n_weights += order;
                    }
                    (Field::Trivial(_), Field::Rho1(..)) | (Field::Rho1(..), Field::Trivial(_)) => {}
                }
            }
        }
        // Sort by dense entry (stable: parameter order within an entry is kept), so that expansion
        // writes each entry's terms in one fixed order.
        b.weights.sort_by_key(|t| t.0);
        for &out in outputs {
            match out {
                Field::Trivial(o) => {
                    b.bias.push((o as u32, b.n_bias as u32));
                    b.n_bias += 1;
                }
                Field::Regular(o) => {
                    for a in 0..order {
                        b.bias.push(((o + a) as u32, b.n_bias as u32));
                    }
                    b.n_bias += 1;
                }
                Field::Rho1(..) => {}
            }
        }
        Ok(b)
    }

    /// How many weight parameters feed each output (for the initial scale).
    pub fn fan_in(&self) -> usize {
        self.n_in
    }
}

/// Apply group element `k` of C_`order` to a vector laid out as `fields` (rho1 pairs rotate,
/// regular fields shift, rho0 stays); used by the equivariance tests.
pub fn act(fields: &[Field], order: usize, k: usize, x: &[f64]) -> Result<Vec<f64>> {
    let g = Group::cyclic(order)?.element(k % order)?;
    let mut y = x.to_vec();
    for f in fields {
        match *f {
            Field::Trivial(_) => {}
            Field::Rho1(i, j) => {
                let (a, b) = g.rotate_xy(x[i], x[j]);
                y[i] = a;
                y[j] = b;
            }
            Field::Regular(s) => {
                for a in 0..order {
                    y[s + a] = x[s + (a + order - k % order) % order];
                }
            }
        }
    }
    Ok(y)
}
