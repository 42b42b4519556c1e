//! The planar rotation group SO(2) about the world z axis through the table centre, and its
//! cyclic subgroups C_N.
//!
//! An element is a [`PlanarRotation`]. Elements of C_N are built from their index k (angle
//! 2 pi k / N), with exact cosines and sines at quarter turns so that C_4 acts without rounding.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use crate::error::{Error, Result};

/// A rotation about the world z axis through the point (`centre`, any z). The table centre
/// (x = y = 0) is the centre every task uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanarRotation {
    angle: f64,
    cos: f64,
    sin: f64,
}

impl PlanarRotation {
    pub const IDENTITY: PlanarRotation = PlanarRotation { angle: 0.0, cos: 1.0, sin: 0.0 };

    /// The rotation by `angle` radians (counter-clockwise seen from above), any real angle.
    pub fn new(angle: f64) -> Result<Self> {
        if !angle.is_finite() {
            return Err(Error::InvalidGroup(format!("rotation angle must be finite, got {angle}")));
        }
        let angle = angle.rem_euclid(std::f64::consts::TAU);
        Ok(Self { angle, cos: libm::cos(angle), sin: libm::sin(angle) })
    }

    /// The k-th of n equal turns, with exact values at multiples of a quarter turn.
    fn fraction(k: usize, n: usize) -> Self {
        let k = k % n;
        if (4 * k).is_multiple_of(n) {
            let quarter = 4 * k / n;
            let (cos, sin) = [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][quarter];
            return Self { angle: std::f64::consts::FRAC_PI_2 * quarter as f64, cos, sin };
        }
        let angle = std::f64::consts::TAU * k as f64 / n as f64;
        Self { angle, cos: libm::cos(angle), sin: libm::sin(angle) }
    }

    /// Angle in [0, 2 pi).
    pub fn angle(&self) -> f64 {
        self.angle
    }
    pub fn cos(&self) -> f64 {
        self.cos
    }
    pub fn sin(&self) -> f64 {
        self.sin
    }

    /// g h: first h, then g.
    pub fn compose(&self, other: &PlanarRotation) -> PlanarRotation {
        let cos = self.cos * other.cos - self.sin * other.sin;
        let sin = self.sin * other.cos + self.cos * other.sin;
        PlanarRotation { angle: (self.angle + other.angle).rem_euclid(std::f64::consts::TAU), cos, sin }
    }

    pub fn inverse(&self) -> PlanarRotation {
        PlanarRotation { angle: (-self.angle).rem_euclid(std::f64::consts::TAU), cos: self.cos, sin: -self.sin }
    }

    /// The irreducible representation of frequency `frequency` (rho_0 is 1x1, others 2x2),
    /// as the 2x2 matrix [[cos wg, -sin wg], [sin wg, cos wg]] (frequency 0 gives the identity).
    pub fn irrep(&self, frequency: u32) -> [[f64; 2]; 2] {
        let (c, s) = match frequency {
            0 => (1.0, 0.0),
            1 => (self.cos, self.sin),
            w => {
                let a = self.angle * w as f64;
                (libm::cos(a), libm::sin(a))
            }
        };
        [[c, -s], [s, c]]
    }

    /// Rotate a planar vector (rho_1).
    pub fn rotate_xy(&self, x: f64, y: f64) -> (f64, f64) {
        (self.cos * x - self.sin * y, self.sin * x + self.cos * y)
    }

    /// The rigid motion of 3-D space: rotation about the vertical axis through `centre` (x, y).
    pub fn isometry(&self, centre: [f64; 2]) -> Isometry3<f64> {
        let c = Vector3::new(centre[0], centre[1], 0.0);
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.angle);
        Translation3::from(c) * Isometry3::from_parts(Translation3::identity(), q) * Translation3::from(-c)
    }
}

/// Which group the symmetry layer acts with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Group {
    /// The cyclic group of `order` rotations by multiples of 2 pi / order.
    Cyclic { order: usize },
    /// All planar rotations (elements are given by angle).
    SO2,
}

impl Group {
    /// C_N; N >= 1.
    pub fn cyclic(order: usize) -> Result<Self> {
        if order == 0 {
            return Err(Error::InvalidGroup("the cyclic group's order must be at least 1".into()));
        }
        Ok(Group::Cyclic { order })
    }

    /// Number of elements (None for SO(2)).
    pub fn order(&self) -> Option<usize> {
        match self {
            Group::Cyclic { order } => Some(*order),
            Group::SO2 => None,
        }
    }

    /// The k-th element of C_N (the generator to the power k), or an error for an index out of
    /// range or for SO(2), whose elements are given by angle.
    pub fn element(&self, k: usize) -> Result<PlanarRotation> {
        match self {
            Group::Cyclic { order } if k < *order => Ok(PlanarRotation::fraction(k, *order)),
            Group::Cyclic { order } => Err(Error::InvalidGroup(format!("C{order} has elements 0..{order}, got {k}"))),
            Group::SO2 => Err(Error::InvalidGroup("SO(2) elements are given by angle, not by index".into())),
        }
    }

    /// All elements of C_N in index order (identity first); SO(2) gives an error.
    pub fn elements(&self) -> Result<Vec<PlanarRotation>> {
        let n = self.order().ok_or_else(|| Error::InvalidGroup("SO(2) has no finite list of elements".into()))?;
        (0..n).map(|k| self.element(k)).collect()
    }

    /// The generator (rotation by 2 pi / N).
    pub fn generator(&self) -> Result<PlanarRotation> {
        self.element(1 % self.order().unwrap_or(1))
    }

    /// Whether `g` belongs to the group (to 1e-9 rad).
    pub fn contains(&self, g: &PlanarRotation) -> bool {
        match self {
            Group::SO2 => true,
            Group::Cyclic { order } => {
                let steps = g.angle * *order as f64 / std::f64::consts::TAU;
                ((steps - steps.round()).abs() * std::f64::consts::TAU / *order as f64) < 1e-9
            }
        }
    }

    /// The regular representation of element k of C_N: the permutation matrix that shifts a
    /// vector of N values (one per element) cyclically by k, row-major.
    pub fn regular_representation(&self, k: usize) -> Result<Vec<f64>> {
        let n = self.order().ok_or_else(|| Error::InvalidGroup("SO(2) has no regular representation here".into()))?;
        self.element(k)?;
        let mut m = vec![0.0; n * n];
        for j in 0..n {
            m[((j + k) % n) * n + j] = 1.0;
        }
        Ok(m)
    }

    /// A short name ("C8", "SO2").
    pub fn name(&self) -> String {
        match self {
            Group::Cyclic { order } => format!("C{order}"),
            Group::SO2 => "SO2".into(),
        }
    }
}

impl std::str::FromStr for Group {
    type Err = Error;
    /// "C8", "c4", "SO2" / "so(2)".
    fn from_str(s: &str) -> Result<Self> {
        let t = s.trim().to_ascii_lowercase();
        if t == "so2" || t == "so(2)" {
            return Ok(Group::SO2);
        }
        match t.strip_prefix('c').and_then(|n| n.parse::<usize>().ok()) {
            Some(n) => Group::cyclic(n),
            None => Err(Error::InvalidGroup(format!("unknown group '{s}' (use 'C<N>' or 'SO2')"))),
        }
    }
}
