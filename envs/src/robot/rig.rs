//! The robot rig: a [`RobotModel`] spawned into a rapier world as one articulated multibody.
//!
//! - **Reduced coordinates.** The base link is the fixed root; each arm joint is a revolute
//!   multibody joint with the URDF's position limits, and the two fingers are prismatic joints
//!   of the last link (the hand's link; fixed joints are folded into it). A finger therefore
//!   cannot leave its axis or its travel, and the hand is exactly where the joint state puts it.
//! - **Mass.** Every link carries its URDF mass, centre of mass and principal inertia; each
//!   joint adds the reflected inertia of its drive ([`PhysicsConfig::joint_armature`],
//!   [`PhysicsConfig::finger_armature`]), which also keeps the 15 g fingers from being
//!   squeezed out of their travel between the arm and the table (see `examples/physics_sweep.rs`).
//! - **Actuation.** Each joint has a force-based position servo (stiffness, damping) whose
//!   torque is capped at the URDF effort limit (87 N m for joints 1-4, 12 N m for 5-7; 70 N per
//!   finger). rapier does not cap joint speeds, so [`RobotRig::clamp_joint_velocities`] holds
//!   every joint to its URDF velocity limit after each physics step.
//! - **Gravity compensation.** The links feel no gravity (gravity scale 0): this is ideal
//!   gravity compensation, as robosuite's controllers add the gravity torques before clipping
//!   to the torque limits. Objects keep their weight, so what the fingers hold loads the joints.
//! - **Collisions.** Every link has colliders (the URDF's primitives) that touch the table and the
//!   objects. Link pairs at least [`SELF_COLLISION_MIN_GAP`] joints apart collide with each other
//!   when [`PhysicsConfig::self_collision`] is on (the fingers never touch the arm), except pairs whose primitive shapes are
//!   already within [`SELF_COLLISION_MARGIN`] of each other in the posture the robot is spawned
//!   in (the "default in collision" rule of robot setup tools; none for the shipped Panda, see
//!   [`RobotRig::self_collision_exclusions`]). Neighbours and grand-neighbours do not: the
//!   URDF's coarse capsules of link 5 and the hand touch at joint 6 = 3.67 rad, inside the real
//!   range (limit 3.75), where the real links clear each other, and that contact kept 3 of 40
//!   random reachable targets out of reach (`envs/tests/physics.rs`).

use std::sync::Arc;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rapier3d::prelude::*;

use super::{LinkInertia, RobotModel};
use super::{LinkShape, ShapeKind};
use crate::error::{EnvError, Result};
use crate::math::{from_pose, to_pose, to_vector};
use crate::world::{colour_code, PhysicsConfig, FIRST_LINK_GROUP_BIT, GROUP_OBJECT, GROUP_ROBOT, GROUP_STATIC};

/// Finger pads are rubber: their friction is this multiple of the scene's.
pub const FINGER_PAD_FRICTION: f64 = 2.0;

/// Finger servo gains (force-based, N/m and N s/m). With 15 g fingers, stiffer or more damped
/// servos squeeze objects out of the grasp.
const FINGER_STIFFNESS: f32 = 2000.0;
const FINGER_DAMPING: f32 = 40.0;

/// Link pairs whose shapes are closer than this (m) in the spawn posture never collide with
/// each other.
pub const SELF_COLLISION_MARGIN: f64 = 0.005;
/// Link pairs fewer joints apart than this never collide with each other (the fingers count
/// as one link after the last).
pub const SELF_COLLISION_MIN_GAP: usize = 3;

/// Colours of the links, alternating along the chain; the fingers are dark.
const LINK_COLOURS: [[u8; 3]; 2] = [[235, 235, 235], [209, 209, 214]];
const FINGER_COLOUR: [u8; 3] = [60, 60, 60];

/// Handles of the robot's parts in the world, and where their coordinates live.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotRig {
    pub model: Arc<RobotModel>,
    /// Pose of the base (arm frame 0) in the world.
    pub base: Isometry3<f64>,
    /// Bodies of arm frames 0 (fixed root) ..= dof (the last carries the hand).
    pub link_bodies: Vec<RigidBodyHandle>,
    /// Colliders of each arm frame's body (the hand's are in the last one).
    pub link_colliders: Vec<Vec<ColliderHandle>>,
    pub hand_colliders: Vec<ColliderHandle>,
    pub finger_bodies: [RigidBodyHandle; 2],
    pub finger_colliders: [Vec<ColliderHandle>; 2],
    arm_joints: Vec<MultibodyJointHandle>,
    finger_joints: [MultibodyJointHandle; 2],
    /// Generalised-coordinate index of each arm joint, then of each finger.
    arm_dofs: Vec<usize>,
    finger_dofs: [usize; 2],
    joint_limits: bool,
}

/// The joint's local x axis is its axis of motion (rapier's convention).
fn align_x(axis: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(&Vector3::x(), axis)
        .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI))
}

/// What every body of the robot (links and fingers) shares: gravity scale 0 (ideal gravity
/// compensation, see the module docs), never asleep, the robot's soft CCD and its island's
/// extra substeps.
fn robot_body(builder: RigidBodyBuilder, config: &PhysicsConfig) -> RigidBodyBuilder {
    builder
        .gravity_scale(0.0)
        .can_sleep(false)
        .soft_ccd_prediction(config.soft_ccd_prediction as f32)
        .additional_solver_iterations(config.robot_extra_substeps)
}

fn mass_properties(i: &LinkInertia, offset: &Isometry3<f64>, what: &str) -> Result<MassProperties> {
    let finite = i.mass.is_finite() && i.centre_of_mass.iter().chain(i.principal_inertia.iter()).all(|v| v.is_finite());
    if !finite || i.mass < 0.0 || i.principal_inertia.iter().any(|v| *v < 0.0) {
        return Err(EnvError::Urdf {
            source_name: "<robot>".into(),
            reason: format!("{what}: mass and inertia must be finite and non-negative"),
        });
    }
    Ok(MassProperties::new(to_vector(&i.centre_of_mass), i.mass as f32, to_vector(&i.principal_inertia))
        .transform_by(&to_pose(offset)))
}

/// Collision groups of self-collision index `index` given which index pairs may collide.
fn link_groups(index: usize, allowed: &[Vec<bool>]) -> InteractionGroups {
    let bit = |k: usize| Group::from_bits_truncate(1 << (FIRST_LINK_GROUP_BIT as usize + k));
    let mut filter = GROUP_OBJECT | GROUP_STATIC;
    for (other, ok) in allowed[index].iter().enumerate() {
        if *ok {
            filter |= bit(other);
        }
    }
    InteractionGroups::new(GROUP_ROBOT | bit(index), filter, InteractionTestMode::And)
}

impl RobotRig {
    /// Spawn the robot at joints `q0` (clamped to the limits when they apply), fingers at
    /// `finger0`, at rest.
    pub fn spawn(
        world: &mut PhysicsWorld,
        model: Arc<RobotModel>,
        base: Isometry3<f64>,
        q0: &[f64],
        finger0: f64,
        config: &PhysicsConfig,
    ) -> Result<Self> {
        let dof = model.dof();
        if q0.len() != dof {
            return Err(EnvError::WrongLength {
                what: "initial joint configuration".into(),
                expected: dof,
                got: q0.len(),
            });
        }
        if dof + 2 + FIRST_LINK_GROUP_BIT as usize > 32 {
            return Err(EnvError::Urdf {
                source_name: "<robot>".into(),
                reason: format!("{dof} arm joints: at most 26 are supported"),
            });
        }
        // One self-collision index per arm frame (the fingers take the next, unused one). Until
        // the exclusions are known (`allow_self_collision`), nothing collides with anything of
        // the robot.
        let group_count = dof + 2;
        let none = vec![vec![false; group_count]; group_count];
        let (link_bodies, link_colliders, hand_colliders) = Self::spawn_links(world, &model, &base, config, &none)?;
        let arm_joints = Self::spawn_arm_joints(world, &model, &link_bodies, config)?;
        // The fingers touch the table and the objects, never the arm: in rapier (4 solver
        // iterations) a contact between a finger and the forearm, both links of one multibody,
        // pushed the finger 30 mm through its joint limit.
        let finger_groups = link_groups(dof + 1, &none);
        let (finger_bodies, finger_joints, finger_colliders) =
            Self::spawn_fingers(world, &model, link_bodies[dof], config, finger_groups)?;
        let mut rig = Self {
            model,
            base,
            link_bodies,
            link_colliders,
            hand_colliders,
            finger_bodies: [finger_bodies[0], finger_bodies[1]],
            finger_colliders: [finger_colliders[0].clone(), finger_colliders[1].clone()],
            arm_joints,
            finger_joints: [finger_joints[0], finger_joints[1]],
            arm_dofs: Vec::new(),
            finger_dofs: [0; 2],
            joint_limits: config.joint_limits,
        };
        rig.resolve_dofs(world, config)?;
        rig.place(world, q0, [finger0; 2]);
        let PhysicsWorld { bodies, colliders, .. } = world;
        bodies.propagate_modified_body_positions_to_colliders(colliders);
        if config.self_collision {
            rig.allow_self_collision(world, group_count);
        }
        Ok(rig)
    }

    /// The bodies of each arm frame with the links (and, last, the hand) attached to it, their
    /// colliders, and the hand's colliders.
    #[allow(clippy::type_complexity)]
    fn spawn_links(
        world: &mut PhysicsWorld,
        model: &RobotModel,
        base: &Isometry3<f64>,
        config: &PhysicsConfig,
        none: &[Vec<bool>],
    ) -> Result<(Vec<RigidBodyHandle>, Vec<Vec<ColliderHandle>>, Vec<ColliderHandle>)> {
        let dof = model.dof();
        let frames = dof + 1;
        let robot_friction = config.friction as f32;
        let mut link_bodies = Vec::with_capacity(frames);
        let mut link_colliders = Vec::with_capacity(frames);
        let mut hand_colliders = Vec::new();
        for frame in 0..frames {
            let mut mprops = MassProperties::default();
            for link in model.links.iter().filter(|l| l.frame == frame) {
                mprops += mass_properties(&link.inertia, &link.offset, &link.name)?;
            }
            if frame == dof {
                mprops += mass_properties(&model.hand_inertia, &model.hand_offset, &model.hand_link)?;
            }
            let builder =
                if frame == 0 { RigidBodyBuilder::fixed().pose(to_pose(base)) } else { RigidBodyBuilder::dynamic() };
            let body = world.insert_body(robot_body(builder, config).additional_mass_properties(mprops));
            let groups = link_groups(frame, none);
            let colour = colour_code(LINK_COLOURS[frame % 2]);
            let mut cols = Vec::new();
            for link in model.links.iter().filter(|l| l.frame == frame) {
                for s in &link.shapes {
                    let c = link_collider(s, &link.offset)
                        .friction(robot_friction)
                        .collision_groups(groups)
                        .user_data(colour);
                    cols.push(world.insert_collider(c, Some(body)));
                }
            }
            if frame == dof {
                for s in &model.hand_shapes {
                    let c = link_collider(s, &model.hand_offset)
                        .friction(robot_friction)
                        .collision_groups(groups)
                        .user_data(colour);
                    let h = world.insert_collider(c, Some(body));
                    cols.push(h);
                    hand_colliders.push(h);
                }
            }
            link_bodies.push(body);
            link_colliders.push(cols);
        }

        Ok((link_bodies, link_colliders, hand_colliders))
    }

    /// The arm's revolute joints (position motors, limits where they apply) between frames.
    fn spawn_arm_joints(
        world: &mut PhysicsWorld,
        model: &RobotModel,
        link_bodies: &[RigidBodyHandle],
        config: &PhysicsConfig,
    ) -> Result<Vec<MultibodyJointHandle>> {
        let dof = model.dof();
        let stiffness = config.joint_stiffness as f32;
        let damping = config.joint_damping as f32;
        let mut arm_joints = Vec::with_capacity(dof);
        for (k, j) in model.joints.iter().enumerate() {
            let align = align_x(&j.axis);
            let mut b = GenericJointBuilder::new(JointAxesMask::LOCKED_REVOLUTE_AXES)
                .local_frame1(to_pose(&(j.origin * align)))
                .local_frame2(to_pose(&Isometry3::from_parts(nalgebra::Translation3::identity(), align)))
                .contacts_enabled(false)
                .motor_model(JointAxis::AngX, MotorModel::ForceBased)
                .motor_position(JointAxis::AngX, 0.0, stiffness, damping)
                .motor_max_force(JointAxis::AngX, j.max_effort.max(0.0) as f32);
            if config.joint_limits && j.lower.is_finite() && j.upper.is_finite() {
                b = b.limits(JointAxis::AngX, [j.lower as f32, j.upper as f32]);
            }
            let handle = world
                .multibody_joints
                .insert(link_bodies[k], link_bodies[k + 1], b.build(), true)
                .ok_or_else(|| EnvError::Urdf {
                    source_name: "<robot>".into(),
                    reason: format!("joint '{}' closes a loop", j.name),
                })?;
            arm_joints.push(handle);
        }

        Ok(arm_joints)
    }

    /// The two fingers: bodies, prismatic joints on the hand, colliders.
    #[allow(clippy::type_complexity)]
    fn spawn_fingers(
        world: &mut PhysicsWorld,
        model: &RobotModel,
        hand_body: RigidBodyHandle,
        config: &PhysicsConfig,
        finger_groups: InteractionGroups,
    ) -> Result<(Vec<RigidBodyHandle>, Vec<MultibodyJointHandle>, Vec<Vec<ColliderHandle>>)> {
        let finger_force = config.max_finger_force;
        let mut finger_bodies = Vec::new();
        let mut finger_joints = Vec::new();
        let mut finger_colliders = Vec::new();
        for f in &model.fingers {
            let mprops = mass_properties(&f.inertia, &Isometry3::identity(), &f.link)?;
            let body =
                world.insert_body(robot_body(RigidBodyBuilder::dynamic(), config).additional_mass_properties(mprops));
            let mut cols = Vec::new();
            for s in &f.shapes {
                let c = link_collider(s, &Isometry3::identity())
                    .friction((config.friction * FINGER_PAD_FRICTION) as f32)
                    .collision_groups(finger_groups)
                    .user_data(colour_code(FINGER_COLOUR));
                cols.push(world.insert_collider(c, Some(body)));
            }
            let align = align_x(&f.axis);
            let joint = GenericJointBuilder::new(JointAxesMask::LOCKED_PRISMATIC_AXES)
                .local_frame1(to_pose(&(model.hand_offset * f.origin * align)))
                .local_frame2(to_pose(&Isometry3::from_parts(nalgebra::Translation3::identity(), align)))
                .contacts_enabled(false)
                .limits(JointAxis::LinX, [f.lower as f32, f.upper as f32])
                .motor_model(JointAxis::LinX, MotorModel::ForceBased)
                .motor_position(JointAxis::LinX, f.lower as f32, FINGER_STIFFNESS, FINGER_DAMPING)
                .motor_max_force(JointAxis::LinX, finger_force.min(f.max_effort) as f32)
                .build();
            let handle = world.multibody_joints.insert(hand_body, body, joint, true).ok_or_else(|| EnvError::Urdf {
                source_name: "<robot>".into(),
                reason: format!("finger '{}' closes a loop", f.name),
            })?;
            finger_bodies.push(body);
            finger_joints.push(handle);
            finger_colliders.push(cols);
        }

        Ok((finger_bodies, finger_joints, finger_colliders))
    }

    /// The multibody's dof index of every joint, and the armature of each.
    fn resolve_dofs(&mut self, world: &mut PhysicsWorld, config: &PhysicsConfig) -> Result<()> {
        // Settle the root type (a fixed base has no free joint) before reading dof indices.
        if let Some((mb, _)) = world.multibody_joints.get_mut(self.arm_joints[0]) {
            mb.forward_kinematics(&world.bodies, true);
        }
        let dof_of = |world: &PhysicsWorld, h: MultibodyJointHandle| {
            world.multibody_joints.get(h).and_then(|(mb, id)| mb.link(id)).map(|l| l.assembly_id())
        };
        let mut arm_dofs = Vec::with_capacity(self.arm_joints.len());
        for h in &self.arm_joints {
            arm_dofs.push(
                dof_of(world, *h).ok_or_else(|| EnvError::InvalidConfig("the arm multibody lost a joint".into()))?,
            );
        }
        self.arm_dofs = arm_dofs;
        for k in 0..2 {
            self.finger_dofs[k] = dof_of(world, self.finger_joints[k])
                .ok_or_else(|| EnvError::InvalidConfig("the arm multibody lost a finger".into()))?;
        }
        {
            let (arm_dofs, finger_dofs) = (self.arm_dofs.clone(), self.finger_dofs);
            let mb = self.multibody_mut(world);
            let armature = mb.armature_mut();
            for d in arm_dofs {
                armature[d] = config.joint_armature as f32;
            }
            for d in finger_dofs {
                armature[d] = config.finger_armature as f32;
            }
        }
        Ok(())
    }

    /// Let arm frames at least [`SELF_COLLISION_MIN_GAP`] apart collide, except pairs already
    /// within [`SELF_COLLISION_MARGIN`] of each other in the current posture.
    fn allow_self_collision(&self, world: &mut PhysicsWorld, group_count: usize) {
        let frames = self.link_colliders.len();
        let mut allowed = vec![vec![false; group_count]; group_count];
        for (i, row) in allowed.iter_mut().enumerate().take(frames) {
            for (j, ok) in row.iter_mut().enumerate().take(frames) {
                *ok = i.abs_diff(j) >= SELF_COLLISION_MIN_GAP;
            }
        }
        for (i, j) in self.self_collision_exclusions(world) {
            allowed[i][j] = false;
            allowed[j][i] = false;
        }
        let groups = self.link_colliders.clone();
        for (index, handles) in groups.iter().enumerate() {
            for h in handles {
                world.colliders[*h].set_collision_groups(link_groups(index, &allowed));
            }
        }
    }

    /// Pairs of arm frames at least [`SELF_COLLISION_MIN_GAP`] apart (arm frames, then the fingers) whose
    /// shapes are within [`SELF_COLLISION_MARGIN`] of each other in the current posture.
    pub fn self_collision_exclusions(&self, world: &PhysicsWorld) -> Vec<(usize, usize)> {
        let groups = &self.link_colliders;
        let mut out = Vec::new();
        for i in 0..groups.len() {
            for j in i + SELF_COLLISION_MIN_GAP..groups.len() {
                let close = groups[i].iter().any(|a| {
                    groups[j].iter().any(|b| {
                        let (ca, cb) = (&world.colliders[*a], &world.colliders[*b]);
                        rapier3d::parry::query::distance(ca.position(), ca.shape(), cb.position(), cb.shape())
                            .is_ok_and(|d| (d.distance as f64) < SELF_COLLISION_MARGIN)
                    })
                });
                if close {
                    out.push((i, j));
                }
            }
        }
        out
    }

    pub fn dof(&self) -> usize {
        self.model.dof()
    }

    /// Clamp joints into the limits (when they apply).
    pub fn clamp_to_limits(&self, q: &mut [f64]) {
        if self.joint_limits {
            self.model.clamp_to_limits(q);
        }
    }

    fn multibody<'a>(&self, world: &'a PhysicsWorld) -> &'a Multibody {
        // The arm's joints are inserted at spawn and never removed.
        world.multibody_joints.get(self.arm_joints[0]).map(|(mb, _)| mb).expect("the rig's multibody exists")
    }

    fn multibody_mut<'a>(&self, world: &'a mut PhysicsWorld) -> &'a mut Multibody {
        world.multibody_joints.get_mut(self.arm_joints[0]).map(|(mb, _)| mb).expect("the rig's multibody exists")
    }

    /// Generalised coordinate of one joint (revolute: angle about its x axis; prismatic: travel).
    fn coordinate(&self, world: &PhysicsWorld, handle: MultibodyJointHandle, revolute: bool) -> f64 {
        let (mb, id) = world.multibody_joints.get(handle).expect("the rig's joints exist");
        let c = mb.link(id).expect("the rig's links exist").joint().coords();
        (if revolute { c[3] } else { c[0] }) as f64
    }

    /// Measured arm joint positions (rad).
    pub fn joint_positions(&self, world: &PhysicsWorld, out: &mut [f64]) {
        for (k, h) in self.arm_joints.iter().enumerate() {
            out[k] = self.coordinate(world, *h, true);
        }
    }

    /// Measured arm joint velocities (rad/s).
    pub fn joint_velocities(&self, world: &PhysicsWorld, out: &mut [f64]) {
        let v = self.multibody(world).generalized_velocity();
        for (k, d) in self.arm_dofs.iter().enumerate() {
            out[k] = v[*d] as f64;
        }
    }

    /// Travel of each finger (half the opening each).
    pub fn finger_positions(&self, world: &PhysicsWorld) -> [f64; 2] {
        [self.coordinate(world, self.finger_joints[0], false), self.coordinate(world, self.finger_joints[1], false)]
    }

    /// World pose of the hand link, from its body.
    pub fn hand_pose(&self, world: &PhysicsWorld) -> Isometry3<f64> {
        from_pose(world.bodies[self.link_bodies[self.dof()]].position()) * self.model.hand_offset
    }

    /// World pose of the tool-centre point.
    pub fn tcp_pose(&self, world: &PhysicsWorld) -> Isometry3<f64> {
        self.hand_pose(world) * self.model.tcp_offset
    }

    /// Put the arm at joints `q` (clamped to the limits when they apply) and the fingers at
    /// `fingers` travel, at rest, with the servos holding that configuration.
    pub fn place(&self, world: &mut PhysicsWorld, q: &[f64], fingers: [f64; 2]) {
        let dof = self.dof();
        let mut q = q.to_vec();
        self.clamp_to_limits(&mut q);
        let travel: [f64; 2] = std::array::from_fn(|k| {
            let f = &self.model.fingers[k];
            fingers[k].clamp(f.lower, f.upper)
        });
        let mut current = vec![0.0; dof];
        self.joint_positions(world, &mut current);
        let fingers_now = self.finger_positions(world);
        let mb = self.multibody_mut(world);
        let mut disp = vec![0.0f32; mb.ndofs()];
        for k in 0..dof {
            disp[self.arm_dofs[k]] = (q[k] - current[k]) as f32;
        }
        for k in 0..2 {
            disp[self.finger_dofs[k]] = (travel[k] - fingers_now[k]) as f32;
        }
        mb.apply_displacements(&disp);
        mb.generalized_velocity_mut().fill(0.0);
        let PhysicsWorld { multibody_joints, bodies, .. } = world;
        let mb = multibody_joints.get_mut(self.arm_joints[0]).map(|(mb, _)| mb).expect("the rig's multibody exists");
        mb.forward_kinematics(bodies, false);
        mb.update_rigid_bodies(bodies, true);
        for h in self.link_bodies.iter().chain(&self.finger_bodies) {
            let b = &mut bodies[*h];
            b.set_linvel(Vector::ZERO, true);
            b.set_angvel(Vector::ZERO, true);
        }
        let zero = vec![0.0; dof];
        self.set_arm_targets(world, &q, &zero);
        for (k, h) in self.finger_joints.iter().enumerate() {
            self.set_finger_target(world, *h, travel[k]);
        }
    }

    /// Set the joint velocities (rad/s) of the arm, keeping its configuration.
    pub fn set_joint_velocities(&self, world: &mut PhysicsWorld, qd: &[f64]) {
        let mb = self.multibody_mut(world);
        let mut v = mb.generalized_velocity_mut();
        for (k, d) in self.arm_dofs.iter().enumerate() {
            v[*d] = qd[k] as f32;
        }
    }

    /// Servo targets of the arm joints: positions (rad) and feed-forward velocities (rad/s).
    pub fn set_arm_targets(&self, world: &mut PhysicsWorld, q: &[f64], qd: &[f64]) {
        for (k, h) in self.arm_joints.iter().enumerate() {
            if let Some((mb, id)) = world.multibody_joints.get_mut(*h) {
                if let Some(link) = mb.link_mut(id) {
                    let m = link.joint.data.motor(JointAxis::AngX).copied().unwrap_or_default();
                    link.joint.data.set_motor(JointAxis::AngX, q[k] as f32, qd[k] as f32, m.stiffness, m.damping);
                }
            }
        }
    }

    /// Servo target of both fingers (travel, m).
    pub fn set_finger_targets(&self, world: &mut PhysicsWorld, travel: f64) {
        for h in &self.finger_joints {
            self.set_finger_target(world, *h, travel);
        }
    }

    fn set_finger_target(&self, world: &mut PhysicsWorld, joint: MultibodyJointHandle, travel: f64) {
        if let Some((mb, id)) = world.multibody_joints.get_mut(joint) {
            if let Some(link) = mb.link_mut(id) {
                link.joint.data.set_motor_position(JointAxis::LinX, travel as f32, FINGER_STIFFNESS, FINGER_DAMPING);
            }
        }
    }

    /// Hold every joint to its URDF velocity limit (rapier itself does not cap joint speeds:
    /// contacts and the servos drove joints to 1.3-6x their limits without this).
    pub fn clamp_joint_velocities(&self, world: &mut PhysicsWorld) {
        let model = self.model.clone();
        let mb = self.multibody_mut(world);
        let mut v = mb.generalized_velocity_mut();
        for (j, d) in model.joints.iter().zip(&self.arm_dofs) {
            let max = j.max_velocity as f32;
            v[*d] = v[*d].clamp(-max, max);
        }
        for (f, d) in model.fingers.iter().zip(&self.finger_dofs) {
            let max = f.max_velocity as f32;
            v[*d] = v[*d].clamp(-max, max);
        }
    }

    /// Project joints that the solver left outside their position limits (and fingers outside
    /// their travel) back onto the limit, with no velocity further out. Why: rapier solves a
    /// multibody's limit constraints together with the contacts in a few iterations, and a hand
    /// pressed onto the table by the 87 N m shoulder dragged a 15 g finger up to 56 mm past its
    /// travel along a tilted axis (`examples/physics_sweep.rs`). Returns whether anything moved.
    pub fn enforce_position_limits(&self, world: &mut PhysicsWorld) -> bool {
        // The common case (everything inside) allocates nothing.
        if self.limited_coordinates(world).all(|(_, x, lo, hi)| x >= lo && x <= hi) {
            return false;
        }
        let bounds: Vec<_> = self.limited_coordinates(world).collect();
        let PhysicsWorld { multibody_joints, bodies, .. } = world;
        let Some((mb, _)) = multibody_joints.get_mut(self.arm_joints[0]) else { return false };
        let mut disp = vec![0.0f32; mb.ndofs()];
        for (d, x, lo, hi) in &bounds {
            if x < lo {
                disp[*d] = (lo - x) as f32;
                let v = mb.generalized_velocity()[*d];
                mb.generalized_velocity_mut()[*d] = v.max(0.0);
            } else if x > hi {
                disp[*d] = (hi - x) as f32;
                let v = mb.generalized_velocity()[*d];
                mb.generalized_velocity_mut()[*d] = v.min(0.0);
            }
        }
        mb.apply_displacements(&disp);
        mb.forward_kinematics(bodies, false);
        mb.update_rigid_bodies(bodies, false);
        true
    }

    /// `(multibody dof, position, lower, upper)` of every coordinate with a position limit: the
    /// arm joints (when joint limits apply) and the fingers.
    fn limited_coordinates<'a>(&'a self, world: &'a PhysicsWorld) -> impl Iterator<Item = (usize, f64, f64, f64)> + 'a {
        let arm = self.arm_joints.iter().zip(&self.arm_dofs).zip(&self.model.joints).filter(|_| self.joint_limits);
        let arm = arm.map(move |((h, d), j)| (*d, self.coordinate(world, *h, true), j.lower, j.upper));
        let fingers = self.finger_joints.iter().zip(&self.finger_dofs).zip(&self.model.fingers);
        arm.chain(fingers.map(move |((h, d), f)| (*d, self.coordinate(world, *h, false), f.lower, f.upper)))
    }

    /// All colliders of the robot: links, hand and fingers.
    pub fn colliders(&self) -> impl Iterator<Item = ColliderHandle> + '_ {
        self.link_colliders.iter().flatten().chain(self.finger_colliders.iter().flatten()).copied()
    }

    /// All dynamic bodies of the robot (links after the base, and the fingers).
    pub fn moving_bodies(&self) -> impl Iterator<Item = RigidBodyHandle> + '_ {
        self.link_bodies[1..].iter().chain(&self.finger_bodies).copied()
    }
}

/// A link shape as a rapier shape.
pub fn shape_of(s: &ShapeKind) -> SharedShape {
    match s {
        ShapeKind::Cuboid { half_extents: h } => SharedShape::cuboid(h.x as f32, h.y as f32, h.z as f32),
        ShapeKind::Cylinder { radius, half_height } => SharedShape::cylinder(*half_height as f32, *radius as f32),
        ShapeKind::Capsule { radius, half_height } => SharedShape::capsule_z(*half_height as f32, *radius as f32),
        ShapeKind::Ball { radius } => SharedShape::ball(*radius as f32),
    }
}

/// rapier's cylinders run along y; URDF's along z.
fn shape_pose(s: &LinkShape) -> Isometry3<f64> {
    match s.shape {
        ShapeKind::Cylinder { .. } => {
            s.pose * nalgebra::UnitQuaternion::from_euler_angles(std::f64::consts::FRAC_PI_2, 0.0, 0.0)
        }
        _ => s.pose,
    }
}

/// A link shape as a rapier shape and its pose in the link frame.
pub fn link_shape(s: &LinkShape) -> (SharedShape, Isometry3<f64>) {
    (shape_of(&s.shape), shape_pose(s))
}

/// A collider for a link shape placed at `offset * shape pose` in its body's frame.
pub fn link_collider(s: &LinkShape, offset: &Isometry3<f64>) -> ColliderBuilder {
    let (shape, pose) = link_shape(s);
    ColliderBuilder::new(shape).position(to_pose(&(offset * pose))).density(0.0)
}
