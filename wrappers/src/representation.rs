//! Group representations on flat vectors, derived from a task's field [`Layout`].
//!
//! Every field kind maps to a direct sum of irreducible representations of SO(2):
//! a position is rho1 + rho0 (x, y rotate; z is invariant), a planar vector is rho1, a 6D
//! rotation (the first two rows of a rotation matrix) is rho1^3 on the pairs (r0, r3),
//! (r1, r4), (r2, r5), and invariant fields are rho0 each. Under R' = Rz R the first two rows
//! mix as rows, so each column pair rotates as a planar vector.

use equigym_envs::error::check_finite;
use equigym_envs::{EnvError, FieldKind, Layout};

use crate::error::Result;
use crate::group::PlanarRotation;

/// One irreducible block of a representation, by the indices it acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Block {
    /// rho0 on one value.
    Trivial { index: usize },
    /// rho_w on the pair (x, y).
    Rotating { x: usize, y: usize, frequency: u32 },
}

/// A representation of the planar rotations on R^dim, as a list of irreducible blocks that
/// together cover every index once.
#[derive(Clone, Debug, PartialEq)]
pub struct Representation {
    dim: usize,
    blocks: Vec<Block>,
}

impl Representation {
    /// The representation a field layout declares.
    pub fn from_layout(layout: &Layout) -> Self {
        let mut blocks = Vec::new();
        for f in layout.fields() {
            let s = f.start;
            match f.kind {
                FieldKind::Position => {
                    blocks.push(Block::Rotating { x: s, y: s + 1, frequency: 1 });
                    blocks.push(Block::Trivial { index: s + 2 });
                }
                FieldKind::PlanarVector => blocks.push(Block::Rotating { x: s, y: s + 1, frequency: 1 }),
                FieldKind::Rotation6d => {
                    for c in 0..3 {
                        blocks.push(Block::Rotating { x: s + c, y: s + 3 + c, frequency: 1 });
                    }
                }
                FieldKind::Invariant => blocks.extend((s..s + f.len).map(|index| Block::Trivial { index })),
            }
        }
        Self { dim: layout.dim(), blocks }
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    /// (number of rho0 copies, number of rho1 copies).
    pub fn multiplicities(&self) -> (usize, usize) {
        let rot = self.blocks.iter().filter(|b| matches!(b, Block::Rotating { .. })).count();
        (self.blocks.len() - rot, rot)
    }

    /// Apply g in place to one vector of length `dim`.
    pub fn act(&self, g: &PlanarRotation, x: &mut [f64]) -> Result<()> {
        check_finite("vector", x, self.dim)?;
        self.apply(g, x);
        Ok(())
    }

    /// Apply g in place to every row of a row-major batch (length a multiple of `dim`).
    pub fn act_batch(&self, g: &PlanarRotation, data: &mut [f64]) -> Result<()> {
        self.check_batch(data)?;
        for row in data.chunks_exact_mut(self.dim.max(1)) {
            self.apply(g, row);
        }
        Ok(())
    }

    /// Apply a different element to each row of a row-major batch.
    pub fn act_each(&self, elements: &[PlanarRotation], data: &mut [f64]) -> Result<()> {
        self.check_batch(data)?;
        let rows = data.len().checked_div(self.dim).unwrap_or(0);
        if elements.len() != rows {
            return Err(EnvError::WrongLength {
                what: "group elements (one per row)".into(),
                expected: rows,
                got: elements.len(),
            }
            .into());
        }
        for (row, g) in data.chunks_exact_mut(self.dim.max(1)).zip(elements) {
            self.apply(g, row);
        }
        Ok(())
    }

    /// The matrix of g (row-major, dim x dim): orthogonal, block diagonal up to a permutation.
    pub fn matrix(&self, g: &PlanarRotation) -> Vec<f64> {
        let d = self.dim;
        let mut m = vec![0.0; d * d];
        for b in &self.blocks {
            match *b {
                Block::Trivial { index } => m[index * d + index] = 1.0,
                Block::Rotating { x, y, frequency } => {
                    let r = g.irrep(frequency);
                    m[x * d + x] = r[0][0];
                    m[x * d + y] = r[0][1];
                    m[y * d + x] = r[1][0];
                    m[y * d + y] = r[1][1];
                }
            }
        }
        m
    }

    fn check_batch(&self, data: &[f64]) -> Result<()> {
        if self.dim == 0 || !data.len().is_multiple_of(self.dim) {
            return Err(EnvError::WrongLength {
                what: format!("batch of {}-d vectors (total length)", self.dim),
                expected: (data.len() / self.dim.max(1)) * self.dim,
                got: data.len(),
            }
            .into());
        }
        if let Some((index, value)) = data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(EnvError::NonFinite { what: "batch".into(), index, value: *value }.into());
        }
        Ok(())
    }

    fn apply(&self, g: &PlanarRotation, x: &mut [f64]) {
        for b in &self.blocks {
            if let Block::Rotating { x: i, y: j, frequency } = *b {
                let (a, c) = if frequency == 1 {
                    g.rotate_xy(x[i], x[j])
                } else {
                    let r = g.irrep(frequency);
                    (r[0][0] * x[i] + r[0][1] * x[j], r[1][0] * x[i] + r[1][1] * x[j])
                };
                x[i] = a;
                x[j] = c;
            }
        }
    }
}
