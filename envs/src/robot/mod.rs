//! The robot: a serial arm with a parallel two-finger hand, described by a URDF.
//!
//! [`RobotModel`] is what the rest of the crate needs from a URDF: the revolute chain from the
//! base to the hand (fixed joints folded into the next joint's origin), the hand and finger
//! geometry and masses, the tool-centre point (TCP), and every joint's limits.
//! [`kinematics`] adds forward kinematics, the Jacobian and a damped-least-squares IK that
//! respects the joint limits.

pub mod controller;
pub mod kinematics;
pub mod rig;
mod urdf;

use nalgebra::{Isometry3, Unit, Vector3};

pub use controller::{ActiveController, ArmController, Controller};
pub use kinematics::{IkOptions, IkReport};
pub use rig::RobotRig;
pub use urdf::{load_urdf, parse_urdf};

/// A primitive collision shape, in the frame of the link that owns it.
#[derive(Clone, Debug, PartialEq)]
pub enum ShapeKind {
    /// A box given by its half extents.
    Cuboid { half_extents: Vector3<f64> },
    /// A cylinder along the local z axis.
    Cylinder { radius: f64, half_height: f64 },
    /// A capsule along the local z axis; `half_height` is half the distance between cap centres.
    Capsule { radius: f64, half_height: f64 },
    /// A sphere.
    Ball { radius: f64 },
}

/// One collision shape of a link, with its pose in the link frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkShape {
    pub pose: Isometry3<f64>,
    pub shape: ShapeKind,
}

/// Mass properties of a link (from the URDF `<inertial>`), expressed in the link frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkInertia {
    pub mass: f64,
    pub centre_of_mass: Vector3<f64>,
    /// Principal moments (the diagonal of the URDF inertia; products of inertia are ignored).
    pub principal_inertia: Vector3<f64>,
}

/// A revolute arm joint, between the previous arm frame and the next.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmJoint {
    pub name: String,
    /// Pose of the joint frame in the previous arm frame (fixed joints in between folded in).
    pub origin: Isometry3<f64>,
    pub axis: Unit<Vector3<f64>>,
    /// Position limits (rad). Continuous joints get (-inf, inf).
    pub lower: f64,
    pub upper: f64,
    /// Velocity limit (rad/s).
    pub max_velocity: f64,
    /// Effort limit (N m).
    pub max_effort: f64,
}

/// A prismatic finger joint on the hand. Its value is the finger's travel (half the opening).
#[derive(Clone, Debug, PartialEq)]
pub struct FingerJoint {
    pub name: String,
    /// Pose of the finger frame in the hand frame at joint value 0.
    pub origin: Isometry3<f64>,
    /// Direction of travel, in the finger frame.
    pub axis: Unit<Vector3<f64>>,
    pub lower: f64,
    pub upper: f64,
    /// Maximum closing force (N).
    pub max_effort: f64,
    /// Speed limit along the axis (m/s).
    pub max_velocity: f64,
    pub link: String,
    pub shapes: Vec<LinkShape>,
    pub inertia: LinkInertia,
}

/// The geometry of one arm link, attached to an arm frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmLink {
    pub name: String,
    /// 0 = the base frame, k = the frame after arm joint k.
    pub frame: usize,
    /// Pose of the link in that frame (non-identity for links hanging off fixed joints).
    pub offset: Isometry3<f64>,
    pub shapes: Vec<LinkShape>,
    /// Mass properties in the link's own frame (the URDF `<inertial>`; zero mass if absent).
    pub inertia: LinkInertia,
}

/// Everything equigym needs to know about a robot.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotModel {
    pub name: String,
    pub joints: Vec<ArmJoint>,
    /// Arm links (base included), each a body of the articulated arm.
    pub links: Vec<ArmLink>,
    /// Pose of the hand link in the last arm frame.
    pub hand_offset: Isometry3<f64>,
    pub hand_link: String,
    pub hand_shapes: Vec<LinkShape>,
    pub hand_inertia: LinkInertia,
    pub fingers: [FingerJoint; 2],
    /// Pose of the tool-centre point (between the fingertips) in the hand frame.
    pub tcp_offset: Isometry3<f64>,
}

impl RobotModel {
    /// Number of arm joints (7 for a Panda).
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// Largest gripper opening (sum of the two finger travels), in metres.
    pub fn max_gripper_width(&self) -> f64 {
        self.fingers[0].upper + self.fingers[1].upper
    }

    /// Clamp a joint vector into the limits.
    pub fn clamp_to_limits(&self, q: &mut [f64]) {
        for (qi, j) in q.iter_mut().zip(&self.joints) {
            *qi = qi.clamp(j.lower, j.upper);
        }
    }

    /// A copy of this model with each arm joint's range scaled about its midpoint by `scale`
    /// (the symmetry-breaking dial, `PhysicsConfig::joint_limit_scale`). Fingers keep theirs.
    pub fn with_joint_limit_scale(&self, scale: f64) -> RobotModel {
        let mut m = self.clone();
        for j in &mut m.joints {
            if j.lower.is_finite() && j.upper.is_finite() {
                let (mid, half) = (0.5 * (j.lower + j.upper), 0.5 * (j.upper - j.lower));
                j.lower = mid - scale * half;
                j.upper = mid + scale * half;
            }
        }
        m
    }

    /// A copy of this model with the arm's joint limits removed (for symmetry ablations).
    pub fn without_joint_limits(&self) -> RobotModel {
        let mut m = self.clone();
        for j in &mut m.joints {
            j.lower = f64::NEG_INFINITY;
            j.upper = f64::INFINITY;
        }
        m
    }
}
