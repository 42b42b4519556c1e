//! Building blocks shared by the tasks: boxes and compounds, poses, grasp tests, and the
//! gripper part of every observation.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rapier3d::prelude::*;

use super::TaskObject;
use crate::layout::{FieldKind, Layout};
use crate::math::{from_pose, rot6d, to_pose};
use crate::scene::{colour_code, Scene, GROUP_OBJECT, GROUP_STATIC};

/// Density of the task objects (wood-like, as robosuite's defaults).
pub const OBJECT_DENSITY: f32 = 1000.0;

/// A pose on the table plane: position and a yaw about the world z axis.
pub fn yaw_pose(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw))
}

/// Add a dynamic object made of boxes `(pose in the object frame, half extents)`.
/// `fixed` makes it part of the static world (a peg), still reported as a task object.
pub fn add_boxes(
    scene: &mut Scene,
    name: &'static str,
    parts: &[(Isometry3<f64>, Vector3<f64>)],
    rgb: [u8; 3],
    fixed: bool,
) -> TaskObject {
    // Extra solver work on objects converges the chain table - object - hand - arm when the arm
    // crushes an object onto the table; it only runs while something touches the object. Under
    // the adversarial targets of `tests/physics.rs` (`examples/depth_probe.rs`, 3 tasks x 20
    // episodes x 400 steps), with 4 substeps of 1 sweep everywhere, the deepest object went
    // 4.3 mm into the table with 4 extra substeps and 2.5 mm with 8; the shipped extra sweeps
    // (`world` module docs) do as well for less. A second stabilisation iteration lowered
    // object depths further but let a finger 8 mm into the peg.
    let builder = if fixed {
        RigidBodyBuilder::fixed()
    } else {
        RigidBodyBuilder::dynamic()
            .additional_solver_iterations(scene.config.object_extra_substeps)
            .additional_pgs_iterations(scene.config.object_extra_pgs_iterations)
            .soft_ccd_prediction(scene.config.soft_ccd_prediction as f32)
    };
    let body = scene.world.insert_body(builder);
    let groups = if fixed {
        InteractionGroups::new(GROUP_STATIC, Group::ALL, InteractionTestMode::And)
    } else {
        InteractionGroups::new(GROUP_OBJECT, Group::ALL, InteractionTestMode::And)
    };
    let mut colliders = Vec::new();
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for (pose, h) in parts {
        colliders.push(
            scene.world.insert_collider(
                ColliderBuilder::cuboid(h.x as f32, h.y as f32, h.z as f32)
                    .position(to_pose(pose))
                    .density(OBJECT_DENSITY)
                    .friction(scene.config.friction as f32)
                    .collision_groups(groups)
                    .user_data(colour_code(rgb)),
                Some(body),
            ),
        );
        let c = pose.translation.vector;
        let r = pose.rotation.to_rotation_matrix();
        let ext = r.matrix().abs() * h;
        lo = lo.inf(&(c - ext));
        hi = hi.sup(&(c + ext));
    }
    let half_extents = (hi - lo) * 0.5;
    TaskObject { name, body, colliders, half_extents }
}

/// A single box object.
pub fn add_box(scene: &mut Scene, name: &'static str, half: Vector3<f64>, rgb: [u8; 3]) -> TaskObject {
    add_boxes(scene, name, &[(Isometry3::identity(), half)], rgb, false)
}

/// Teleport an object to `pose`, at rest.
pub fn place(scene: &mut Scene, object: &TaskObject, pose: &Isometry3<f64>) {
    let body = &mut scene.world.bodies[object.body];
    body.set_position(to_pose(pose), true);
    body.set_linvel(Vector::ZERO, true);
    body.set_angvel(Vector::ZERO, true);
}

pub fn pose_of(scene: &Scene, object: &TaskObject) -> Isometry3<f64> {
    from_pose(scene.world.bodies[object.body].position())
}

/// Both fingers touch the object.
pub fn grasped(scene: &Scene, object: &TaskObject) -> bool {
    scene.body_touches(&scene.rig.finger_colliders[0], &object.colliders)
        && scene.body_touches(&scene.rig.finger_colliders[1], &object.colliders)
}

/// Any collider of `a` touches any of `b`.
pub fn touching(scene: &Scene, a: &TaskObject, b: &TaskObject) -> bool {
    scene.body_touches(&a.colliders, &b.colliders)
}

/// Append the gripper fields every task observes (TCP position, 6D rotation, finger travels).
pub fn with_gripper_fields(layout: Layout) -> Layout {
    layout.with("gripper_pos", FieldKind::Position, 3).with("gripper_rot6d", FieldKind::Rotation6d, 6).with(
        "gripper_joint_pos",
        FieldKind::Invariant,
        2,
    )
}

/// Write the 11 gripper values at the start of `out`.
pub fn observe_gripper(scene: &Scene, out: &mut [f64]) {
    let tcp = scene.tcp_pose();
    out[0..3].copy_from_slice(tcp.translation.vector.as_slice());
    out[3..9].copy_from_slice(&rot6d(&tcp.rotation));
    out[9..11].copy_from_slice(&scene.finger_positions());
}

/// Whether `object`, if it stood at `pose`, would be clear of every robot collider (exact
/// shape queries at the robot's current posture).
pub fn clear_of_robot(scene: &Scene, object: &TaskObject, pose: &Isometry3<f64>) -> bool {
    let world = &scene.world;
    let at = to_pose(pose);
    object.colliders.iter().all(|c| {
        let oc = &world.colliders[*c];
        let local = oc.position_wrt_parent().copied().unwrap_or_default();
        let placed = at * local;
        scene.rig.colliders().all(|r| {
            let rc = &world.colliders[r];
            !matches!(rapier3d::parry::query::intersection_test(&placed, oc.shape(), rc.position(), rc.shape()), Ok(r) if r.intersecting)
        })
    })
}

/// Draws tried before an initial placement that overlaps the robot is kept anyway (with the
/// documented ranges a few are ever needed: `envs/tests/physics.rs` resets 2,000 seeds).
pub const MAX_PLACEMENT_DRAWS: usize = 100;

/// Sample planar positions (and yaws) for several objects so that no two centres are closer
/// than their required clearance. Gives up after many tries and keeps the last draw (with
/// the documented ranges that never happens in practice).
pub fn sample_separated(
    rng: &mut crate::rng::EpisodeRng,
    ranges: &[PlacementRange],
    clearance: &[f64],
) -> Vec<(f64, f64, f64)> {
    let mut out = Vec::with_capacity(ranges.len());
    for _attempt in 0..1000 {
        out.clear();
        for r in ranges {
            out.push((rng.uniform(r.x.0, r.x.1), rng.uniform(r.y.0, r.y.1), rng.uniform(r.yaw.0, r.yaw.1)));
        }
        let ok = (0..out.len()).all(|i| {
            (0..i).all(|j| {
                let d = ((out[i].0 - out[j].0).powi(2) + (out[i].1 - out[j].1).powi(2)).sqrt();
                d >= clearance[i] + clearance[j]
            })
        });
        if ok {
            break;
        }
    }
    out
}

/// Where one object may start: x, y and yaw ranges.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlacementRange {
    pub x: (f64, f64),
    pub y: (f64, f64),
    pub yaw: (f64, f64),
}
