//! URDF -> [`RobotModel`].
//!
//! The loader walks the kinematic tree from its root towards the one link that carries two
//! prismatic child joints (the hand). Revolute and continuous joints on that path become arm
//! joints; fixed joints are folded into the next frame. The TCP is a fixed child link of the
//! hand whose name contains "tcp"; without one it is put 4.5 cm beyond the finger origins
//! along the hand's z axis.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};

use super::{ArmJoint, ArmLink, FingerJoint, LinkInertia, LinkShape, RobotModel, ShapeKind};
use crate::error::{EnvError, Result};

/// Load a robot description from a URDF file.
pub fn load_urdf(path: impl AsRef<Path>) -> Result<RobotModel> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => {
            EnvError::FileNotFound { what: "robot description".into(), path: path.display().to_string() }
        }
        _ => EnvError::Urdf { source_name: path.display().to_string(), reason: format!("cannot read file: {e}") },
    })?;
    parse_urdf(&text).map_err(|e| match e {
        EnvError::Urdf { reason, .. } => EnvError::Urdf { source_name: path.display().to_string(), reason },
        other => other,
    })
}

fn err(reason: impl Into<String>) -> EnvError {
    EnvError::Urdf { source_name: "<string>".into(), reason: reason.into() }
}

fn pose(p: &urdf_rs::Pose) -> Isometry3<f64> {
    let rot = UnitQuaternion::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]);
    Isometry3::from_parts(Translation3::new(p.xyz[0], p.xyz[1], p.xyz[2]), rot)
}

fn finite_pose(p: &urdf_rs::Pose, what: &str) -> Result<Isometry3<f64>> {
    if p.xyz.iter().chain(p.rpy.iter()).all(|v| v.is_finite()) {
        Ok(pose(p))
    } else {
        Err(err(format!("{what}: origin has a non-finite value")))
    }
}

fn axis(j: &urdf_rs::Joint) -> Result<Unit<Vector3<f64>>> {
    let v = Vector3::new(j.axis.xyz[0], j.axis.xyz[1], j.axis.xyz[2]);
    if !v.iter().all(|x| x.is_finite()) || v.norm() < 1e-9 {
        return Err(err(format!("joint '{}': axis must be a finite non-zero vector", j.name)));
    }
    Ok(Unit::new_normalize(v))
}

fn shapes(link: &urdf_rs::Link) -> Result<Vec<LinkShape>> {
    let mut out = Vec::new();
    for c in &link.collision {
        let what = format!("link '{}' collision", link.name);
        let shape = match &c.geometry {
            urdf_rs::Geometry::Box { size } => {
                ShapeKind::Cuboid { half_extents: Vector3::new(size[0], size[1], size[2]) * 0.5 }
            }
            urdf_rs::Geometry::Cylinder { radius, length } => {
                ShapeKind::Cylinder { radius: *radius, half_height: length * 0.5 }
            }
            urdf_rs::Geometry::Capsule { radius, length } => {
                ShapeKind::Capsule { radius: *radius, half_height: length * 0.5 }
            }
            urdf_rs::Geometry::Sphere { radius } => ShapeKind::Ball { radius: *radius },
            urdf_rs::Geometry::Mesh { filename, .. } => {
                return Err(err(format!(
                    "{what} uses mesh '{filename}': equigym needs primitive collision shapes \
                     (box, cylinder, capsule, sphere)"
                )))
            }
        };
        let ok = match &shape {
            ShapeKind::Cuboid { half_extents } => half_extents.iter().all(|v| v.is_finite() && *v > 0.0),
            ShapeKind::Cylinder { radius, half_height } | ShapeKind::Capsule { radius, half_height } => {
                radius.is_finite() && *radius > 0.0 && half_height.is_finite() && *half_height >= 0.0
            }
            ShapeKind::Ball { radius } => radius.is_finite() && *radius > 0.0,
        };
        if !ok {
            return Err(err(format!("{what}: shape sizes must be finite and positive")));
        }
        out.push(LinkShape { pose: finite_pose(&c.origin, &what)?, shape });
    }
    Ok(out)
}

fn inertia(link: &urdf_rs::Link) -> LinkInertia {
    let i = &link.inertial;
    LinkInertia {
        mass: i.mass.value,
        centre_of_mass: Vector3::new(i.origin.xyz[0], i.origin.xyz[1], i.origin.xyz[2]),
        principal_inertia: Vector3::new(i.inertia.ixx, i.inertia.iyy, i.inertia.izz),
    }
}

/// A finger joint (the hand is the link with two of them).
fn is_prismatic(j: &&&urdf_rs::Joint) -> bool {
    matches!(j.joint_type, urdf_rs::JointType::Prismatic)
}

/// Path from the root to the hand, found depth first (the arm is serial, so it is unique).
fn path_to_hand<'a>(
    link: &'a str,
    children: &HashMap<&'a str, Vec<&'a urdf_rs::Joint>>,
    is_hand: &dyn Fn(&str) -> bool,
    depth: usize,
) -> Option<Vec<&'a urdf_rs::Joint>> {
    if is_hand(link) {
        return Some(Vec::new());
    }
    if depth > 64 {
        return None;
    }
    for j in children.get(link).into_iter().flatten() {
        if matches!(j.joint_type, urdf_rs::JointType::Prismatic) {
            continue;
        }
        if let Some(mut rest) = path_to_hand(j.child.link.as_str(), children, is_hand, depth + 1) {
            rest.insert(0, j);
            return Some(rest);
        }
    }
    None
}

/// The hand's two prismatic finger joints, with their links.
fn finger_joints(hand_children: &[&urdf_rs::Joint], links: &HashMap<&str, &urdf_rs::Link>) -> Result<[FingerJoint; 2]> {
    let mut fingers = Vec::new();
    for j in hand_children.iter().filter(is_prismatic) {
        let link = links[j.child.link.as_str()];
        if j.limit.lower.is_nan() || j.limit.upper.is_nan() || j.limit.lower > j.limit.upper {
            return Err(err(format!("finger joint '{}': limits are not an interval", j.name)));
        }
        fingers.push(FingerJoint {
            name: j.name.clone(),
            origin: finite_pose(&j.origin, &format!("joint '{}'", j.name))?,
            axis: axis(j)?,
            lower: j.limit.lower,
            upper: j.limit.upper,
            max_effort: if j.limit.effort > 0.0 { j.limit.effort } else { 70.0 },
            max_velocity: if j.limit.velocity > 0.0 { j.limit.velocity } else { f64::INFINITY },
            link: link.name.clone(),
            shapes: shapes(link)?,
            inertia: inertia(link),
        });
    }
    fingers.try_into().map_err(|_| err("the hand needs exactly two fingers"))
}

/// Parse a URDF document held in a string.
pub fn parse_urdf(text: &str) -> Result<RobotModel> {
    let robot = urdf_rs::read_from_string(text).map_err(|e| err(format!("not a valid URDF document: {e}")))?;
    let links: HashMap<&str, &urdf_rs::Link> = robot.links.iter().map(|l| (l.name.as_str(), l)).collect();
    let mut children: HashMap<&str, Vec<&urdf_rs::Joint>> = HashMap::new();
    for j in &robot.joints {
        for name in [&j.parent.link, &j.child.link] {
            if !links.contains_key(name.as_str()) {
                return Err(err(format!("joint '{}' refers to unknown link '{}'", j.name, name)));
            }
        }
        children.entry(j.parent.link.as_str()).or_default().push(j);
    }
    let is_child: std::collections::HashSet<&str> = robot.joints.iter().map(|j| j.child.link.as_str()).collect();
    let roots: Vec<&str> = robot.links.iter().map(|l| l.name.as_str()).filter(|n| !is_child.contains(n)).collect();
    let root = match roots.as_slice() {
        [r] => *r,
        [] => return Err(err("the kinematic tree has no root link (is there a loop?)")),
        many => return Err(err(format!("the URDF has several root links: {many:?}"))),
    };

    let is_hand = |name: &str| children.get(name).map_or(0, |c| c.iter().filter(is_prismatic).count()) == 2;
    let path = path_to_hand(root, &children, &is_hand, 0)
        .ok_or_else(|| err("no hand found: expected one link with exactly two prismatic finger joints"))?;

    let mut joints = Vec::new();
    let mut arm_links = vec![ArmLink {
        name: root.to_string(),
        frame: 0,
        offset: Isometry3::identity(),
        shapes: shapes(links[root])?,
        inertia: inertia(links[root]),
    }];
    // Pose of the current link in the current arm frame (accumulates fixed joints).
    let mut pending = Isometry3::identity();
    for j in &path {
        let origin = finite_pose(&j.origin, &format!("joint '{}'", j.name))?;
        let child = links[j.child.link.as_str()];
        match j.joint_type {
            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                let (lower, upper) = if matches!(j.joint_type, urdf_rs::JointType::Continuous) {
                    (f64::NEG_INFINITY, f64::INFINITY)
                } else {
                    (j.limit.lower, j.limit.upper)
                };
                if lower.is_nan() || upper.is_nan() || lower > upper {
                    return Err(err(format!("joint '{}': limits [{lower}, {upper}] are not an interval", j.name)));
                }
                let max_velocity = if j.limit.velocity > 0.0 { j.limit.velocity } else { f64::INFINITY };
                joints.push(ArmJoint {
                    name: j.name.clone(),
                    origin: pending * origin,
                    axis: axis(j)?,
                    lower,
                    upper,
                    max_velocity,
                    max_effort: j.limit.effort,
                });
                pending = Isometry3::identity();
            }
            urdf_rs::JointType::Fixed => pending *= origin,
            _ => {
                return Err(err(format!(
                    "joint '{}' on the arm is {:?}: only revolute, continuous and fixed joints are supported \
                     between the base and the hand",
                    j.name, j.joint_type
                )))
            }
        }
        if child.name != path.last().map(|l| l.child.link.clone()).unwrap_or_default() {
            arm_links.push(ArmLink {
                name: child.name.clone(),
                frame: joints.len(),
                offset: pending,
                shapes: shapes(child)?,
                inertia: inertia(child),
            });
        }
    }
    if joints.is_empty() {
        return Err(err("the arm has no revolute joint between the base and the hand"));
    }
    let hand_name = path.last().map(|j| j.child.link.as_str()).unwrap_or(root);
    let hand = links[hand_name];
    let hand_children = &children[hand_name];

    let fingers = finger_joints(hand_children, &links)?;
    if fingers.iter().any(|f| f.inertia.mass <= 0.0) || inertia(hand).mass <= 0.0 {
        return Err(err("the hand and both fingers need a positive <inertial> mass"));
    }

    let tcp_offset = hand_children
        .iter()
        .find(|j| matches!(j.joint_type, urdf_rs::JointType::Fixed) && j.child.link.to_lowercase().contains("tcp"))
        .map(|j| finite_pose(&j.origin, &format!("joint '{}'", j.name)))
        .transpose()?
        .unwrap_or_else(|| {
            let mid = (fingers[0].origin.translation.vector + fingers[1].origin.translation.vector) * 0.5;
            Isometry3::translation(mid.x, mid.y, mid.z + 0.045)
        });

    Ok(RobotModel {
        name: robot.name.clone(),
        joints,
        links: arm_links,
        hand_offset: pending,
        hand_link: hand.name.clone(),
        hand_shapes: shapes(hand)?,
        hand_inertia: inertia(hand),
        fingers,
        tcp_offset,
    })
}
