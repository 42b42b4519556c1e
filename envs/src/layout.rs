//! Named slices of a flat vector (observation or action), each with its group representation.
//!
//! A layout is declared once per task and used by the env, the symmetry layer and the Python
//! field metadata. Representations follow the paper's appendix tables for the planar rotation
//! group: `Trivial` (rho0, one invariant value) and `Rot` (rho1, an (x, y) pair that rotates).
//! A 6D rotation is three rho1 pairs `(r0, r3), (r1, r4), (r2, r5)`; see [`Field::reps`].

use serde::{Deserialize, Serialize};

/// Dimension of every task's action: TCP position (3), 6D rotation (6), gripper width (1).
pub const ACTION_DIM: usize = 10;
/// One control action ([`ACTION_DIM`] values: TCP position, 6D rotation, gripper width).
pub type Action = [f64; ACTION_DIM];

/// How a field transforms under a rotation about the world z axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FieldKind {
    /// A world-frame position (x, y, z): rho1 on (x, y), rho0 on z.
    Position,
    /// A world-frame planar vector (x, y): rho1.
    PlanarVector,
    /// A world-frame 6D rotation (first two rows): rho1 on (r0, r3), (r1, r4), (r2, r5).
    Rotation6d,
    /// Values invariant under the rotation (rho0 each): widths, joint positions, quantities
    /// expressed in an object's own frame.
    Invariant,
}

/// One named slice.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Field {
    pub name: String,
    pub start: usize,
    pub len: usize,
    pub kind: FieldKind,
}

impl Field {
    pub fn range(&self) -> std::ops::Range<usize> {
        self.start..self.start + self.len
    }

    /// The representation of this field, written as in the paper ("rho1 + rho0", ...).
    pub fn reps(&self) -> String {
        match self.kind {
            FieldKind::Position => "rho1 + rho0".into(),
            FieldKind::PlanarVector => "rho1".into(),
            FieldKind::Rotation6d => "rho1^3".into(),
            FieldKind::Invariant => format!("rho0^{}", self.len),
        }
    }
}

/// An ordered list of fields covering a flat vector.
#[derive(Clone, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct Layout {
    fields: Vec<Field>,
}

impl Layout {
    pub fn new() -> Self {
        Self::default()
    }

    /// Append a field (builder style).
    pub fn with(mut self, name: &str, kind: FieldKind, len: usize) -> Self {
        let start = self.dim();
        let len = match kind {
            FieldKind::Position => 3,
            FieldKind::PlanarVector => 2,
            FieldKind::Rotation6d => 6,
            FieldKind::Invariant => len,
        };
        self.fields.push(Field { name: name.to_string(), start, len, kind });
        self
    }

    pub fn dim(&self) -> usize {
        self.fields.last().map_or(0, |f| f.start + f.len)
    }

    pub fn fields(&self) -> &[Field] {
        &self.fields
    }

    pub fn field(&self, name: &str) -> Option<&Field> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// `times` copies of this layout one after another, field names prefixed `t{k}.`
    /// (an action chunk of `times` actions).
    pub fn repeat(&self, times: usize) -> Layout {
        let mut out = Layout::new();
        for k in 0..times {
            for f in &self.fields {
                out = out.with(&format!("t{k}.{}", f.name), f.kind, f.len);
            }
        }
        out
    }

    /// The 10-d absolute end-effector action every task takes.
    pub fn action() -> Self {
        Layout::new().with("position", FieldKind::Position, 3).with("rotation_6d", FieldKind::Rotation6d, 6).with(
            "gripper_width",
            FieldKind::Invariant,
            1,
        )
    }
}
