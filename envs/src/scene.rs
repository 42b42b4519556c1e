//! The physical scene: a rapier world with a table, the robot's hand and fingers, and whatever
//! objects a task adds, plus the arm controller that drives the hand.
//!
//! How the robot is simulated (and why):
//! - The arm's joint state is integrated by the controller ([`ArmController`]): absolute TCP
//!   targets go through a joint-limited IK, joints move at most at their velocity limits, and the
//!   resulting hand pose is the *target* of a dynamic hand body. Arm links are posed by forward
//!   kinematics for rendering; they are not physical bodies.
//! - The hand and the two fingers are dynamic rigid bodies. The hand is servoed towards its
//!   target by a velocity servo whose per-substep velocity change is capped by a force and a
//!   torque limit, and the fingers are prismatic joints with force-capped motors. Everything the
//!   robot does to the world therefore goes through bounded forces: pressing into the table or
//!   crushing an object stalls the hand instead of driving it through. Objects are held only by
//!   contact friction.

use std::sync::Arc;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EnvError, Result};
use crate::math::{clamp_norm, from_pose, from_vector, to_pose, to_vector};
use crate::robot::kinematics::rotation_error;
use crate::robot::{IkOptions, IkReport, LinkShape, RobotModel, ShapeKind};

/// Collision groups: the robot touches objects and the table, never itself.
pub const GROUP_ROBOT: Group = Group::GROUP_1;
pub const GROUP_OBJECT: Group = Group::GROUP_2;
pub const GROUP_STATIC: Group = Group::GROUP_3;

/// Physics and actuation settings. The defaults are the ones the shipped tasks are tuned for.
/// Deserialised field by field (missing fields keep their defaults, unknown ones are errors), so
/// user options can override any subset (see `crate::options::EnvOptions`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PhysicsConfig {
    /// Physics timestep (s).
    pub timestep: f64,
    /// Physics steps per control step (control period = timestep * substeps; 20 Hz by default).
    pub substeps: usize,
    pub solver_iterations: usize,
    /// Friction coefficient of fingers, objects and table.
    pub friction: f64,
    /// Cap on the force the arm can apply through the hand (N).
    pub max_hand_force: f64,
    /// Cap on the torque the arm can apply through the hand (N m).
    pub max_hand_torque: f64,
    /// Cap on each finger's grip force (N).
    pub max_finger_force: f64,
    /// Finger travel speed (m/s).
    pub finger_speed: f64,
    /// Time constant of the hand's pose servo (s).
    pub servo_time_constant: f64,
    /// Whether the arm's joint limits are enforced (turn off for symmetry ablations).
    pub joint_limits: bool,
    /// Cartesian (operational-space-like) arm control instead of joint-space interpolation
    /// (see [`ArmController`]); with `joint_limits` off it makes every control step commute
    /// with rotations of the scene about a vertical axis.
    pub cartesian_control: bool,
}

impl Default for PhysicsConfig {
    fn default() -> Self {
        Self {
            timestep: 1.0 / 240.0,
            substeps: 12,
            solver_iterations: 4,
            friction: 1.0,
            max_hand_force: 25.0,
            max_hand_torque: 5.0,
            max_finger_force: 40.0,
            finger_speed: 0.2,
            servo_time_constant: 0.02,
            joint_limits: true,
            cartesian_control: false,
        }
    }
}

impl PhysicsConfig {
    pub fn control_period(&self) -> f64 {
        self.timestep * self.substeps as f64
    }

    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("timestep", self.timestep),
            ("friction", self.friction),
            ("max_hand_force", self.max_hand_force),
            ("max_hand_torque", self.max_hand_torque),
            ("max_finger_force", self.max_finger_force),
            ("finger_speed", self.finger_speed),
            ("servo_time_constant", self.servo_time_constant),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(EnvError::InvalidConfig(format!("{name} must be positive and finite, got {v}")));
            }
        }
        if self.substeps == 0 || self.substeps > 1000 || self.solver_iterations == 0 || self.solver_iterations > 100 {
            return Err(EnvError::InvalidConfig("substeps must be in 1..=1000 and solver_iterations in 1..=100".into()));
        }
        Ok(())
    }
}

/// State of the arm controller.
///
/// Two controllers share it (see [`PhysicsConfig::cartesian_control`]):
/// - **joint** (default): the target goes through IK, the joints move towards the solution at
///   most at their velocity limits, and the hand follows the forward kinematics of the
///   interpolated joints (the Panda's own joint-space behaviour);
/// - **Cartesian**: a commanded TCP pose moves towards the closest reachable pose along a
///   straight line and the rotation geodesic at bounded speed, like an operational-space
///   controller. Without joint limits it commutes with rotations of the scene about a vertical
///   axis, so it isolates the joint limits as the cause of symmetry breaking.
///
/// Either way a velocity servo makes the dynamic hand body follow the per-substep target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArmController {
    /// Commanded joints at the end of the last control step (joint controller).
    pub q_cmd: Vec<f64>,
    /// Commanded TCP pose at the end of the last control step (Cartesian controller).
    pub tcp_cmd: Isometry3<f64>,
    /// Joints that reproduce the hand's actual pose (the "measured" joint positions, used to
    /// draw the arm and to warm-start inverse kinematics).
    pub q_meas: Vec<f64>,
    /// Joints that reach the last target as closely as the limits allow.
    pub q_des: Vec<f64>,
    /// Commanded finger travel (half the opening), rate limited.
    pub finger_cmd: f64,
}

/// How far the commanded joints may run ahead of the measured ones (rad): bounds the wind-up
/// when the hand is blocked, so it does not leap when released (joint controller).
const MAX_JOINT_LEAD: f64 = 0.15;

/// How far the commanded TCP may run ahead of the actual one (m, rad) (Cartesian controller).
const MAX_TCP_LEAD: f64 = 0.05;
const MAX_TCP_LEAD_ANGLE: f64 = 0.25;

/// Speed limits of the commanded TCP (m/s, rad/s); the Panda's Cartesian limits are 1.7 m/s
/// and 2.5 rad/s.
const MAX_TCP_SPEED: f64 = 1.0;
const MAX_TCP_ANGULAR_SPEED: f64 = 2.5;

/// Finger motor gains (force-based). Tuned with the experts: stiffer or more damped finger
/// motors on 15 g fingers make grasps squeeze objects out.
const FINGER_STIFFNESS: f32 = 2000.0;
const FINGER_DAMPING: f32 = 40.0;

/// Finger pads are rubber: their friction is this multiple of the scene's.
const FINGER_PAD_FRICTION: f64 = 2.0;

/// Speed limit of the hand servo (m/s); the Panda's Cartesian limit is 1.7 m/s.
const MAX_HAND_SPEED: f64 = 1.0;

/// Handles of the robot's physical parts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotBodies {
    pub hand: RigidBodyHandle,
    pub fingers: [RigidBodyHandle; 2],
    pub finger_joints: [ImpulseJointHandle; 2],
    pub hand_colliders: Vec<ColliderHandle>,
    pub finger_colliders: [Vec<ColliderHandle>; 2],
}

/// Rendering colour of a collider, kept in its user data.
pub fn colour_code(rgb: [u8; 3]) -> u128 {
    ((rgb[0] as u128) << 16) | ((rgb[1] as u128) << 8) | rgb[2] as u128 | (1u128 << 32)
}

/// The world plus the robot.
pub struct Scene {
    pub world: PhysicsWorld,
    pub robot: Arc<RobotModel>,
    /// The robot model used for control (the same one, or with limits removed).
    control_model: Arc<RobotModel>,
    pub base: Isometry3<f64>,
    pub config: PhysicsConfig,
    pub bodies: RobotBodies,
    pub arm: ArmController,
    pub table_top: f64,
    pub table_half_extents: [f64; 2],
    pub ik: IkOptions,
    frames: Vec<Isometry3<f64>>,
}

/// The part of a [`Scene`] that changes during an episode, serialisable bit for bit.
#[derive(Serialize, Deserialize)]
pub struct SceneState {
    pub world: PhysicsWorld,
    pub arm: ArmController,
}

pub fn shape_of(s: &ShapeKind) -> SharedShape {
    match s {
        ShapeKind::Cuboid { half_extents: h } => SharedShape::cuboid(h.x as f32, h.y as f32, h.z as f32),
        ShapeKind::Cylinder { radius, half_height } => SharedShape::cylinder(*half_height as f32, *radius as f32),
        ShapeKind::Capsule { radius, half_height } => SharedShape::capsule_z(*half_height as f32, *radius as f32),
        ShapeKind::Ball { radius } => SharedShape::ball(*radius as f32),
    }
}

/// rapier's cylinders and capsules run along y; URDF's along z.
fn shape_pose(s: &LinkShape) -> Isometry3<f64> {
    match s.shape {
        ShapeKind::Cylinder { .. } => s.pose * nalgebra::UnitQuaternion::from_euler_angles(std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        _ => s.pose,
    }
}

/// A link shape as a rapier shape and its pose in the link frame.
pub fn link_shape(s: &LinkShape) -> (SharedShape, Isometry3<f64>) {
    (shape_of(&s.shape), shape_pose(s))
}

impl Scene {
    /// Build the table, the robot's hand and fingers at joint configuration `q0`.
    pub fn new(
        robot: Arc<RobotModel>,
        base: Isometry3<f64>,
        q0: &[f64],
        table_top: f64,
        table_half_extents: [f64; 2],
        config: PhysicsConfig,
    ) -> Result<Self> {
        config.validate()?;
        if q0.len() != robot.dof() {
            return Err(EnvError::WrongLength { what: "initial joint configuration".into(), expected: robot.dof(), got: q0.len() });
        }
        let control_model = if config.joint_limits { robot.clone() } else { Arc::new(robot.without_joint_limits()) };
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -9.81);
        let ip = &mut world.integration_parameters;
        ip.dt = config.timestep as f32;
        ip.num_solver_iterations = config.solver_iterations;
        // A finger must not "hold" an object across a gap, which recycled contacts allow.
        ip.contact_recycling = false;
        // Solve friction in the biased (position-correcting) pass too. Without it, that pass moves
        // bodies with velocities friction has not yet acted on, and anything held by friction
        // alone creeps under gravity by g * dt / iterations (about 1 cm/s): a nut held in the
        // fingers slides out within two seconds, and one held off-centre slowly twists.
        ip.friction_in_bias_pass = true;
        // rapier tolerates 5 mm of penetration by default; objects of 4 cm need tighter contact.
        ip.normalized_allowed_linear_error = 0.001;
        // Stiffer contacts against the table: a light cube pressed by the hand sinks < 2 mm
        // (60 Hz, the default, lets it sink ~5 mm; see examples/physics_sweep.rs).
        ip.static_contact_softness.natural_frequency = 120.0;

        let static_groups = InteractionGroups::new(GROUP_STATIC, GROUP_ROBOT | GROUP_OBJECT, InteractionTestMode::And);
        // The table is a solid block down to the floor: a thin top lets a squeezed object tunnel
        // through, while a block always pushes it back out through the top.
        let table_thickness = table_top as f32;
        let table = world.insert_body(RigidBodyBuilder::fixed().translation(Vector::new(
            0.0,
            0.0,
            table_top as f32 - table_thickness / 2.0,
        )));
        world.insert_collider(
            ColliderBuilder::cuboid(table_half_extents[0] as f32, table_half_extents[1] as f32, table_thickness / 2.0)
                .friction(config.friction as f32)
                .collision_groups(static_groups)
                .user_data(colour_code([196, 164, 124])),
            Some(table),
        );
        // A floor far below catches anything that falls off the table.
        let floor = world.insert_body(RigidBodyBuilder::fixed().translation(Vector::new(0.0, 0.0, -0.05)));
        world.insert_collider(
            ColliderBuilder::cuboid(3.0, 3.0, 0.05).collision_groups(static_groups).user_data(colour_code([90, 90, 100])),
            Some(floor),
        );

        let robot_groups = InteractionGroups::new(GROUP_ROBOT, GROUP_OBJECT | GROUP_STATIC, InteractionTestMode::And);
        let mut q = q0.to_vec();
        control_model.clamp_to_limits(&mut q);
        let hand_pose = robot.hand_pose(&base, &q);
        let mass_props = |i: &crate::robot::LinkInertia| {
            MassProperties::new(to_vector(&i.centre_of_mass), i.mass as f32, to_vector(&i.principal_inertia))
        };
        let hand = world.insert_body(
            RigidBodyBuilder::dynamic()
                .pose(to_pose(&hand_pose))
                .gravity_scale(0.0)
                .can_sleep(false)
                .additional_mass_properties(mass_props(&robot.hand_inertia)),
        );
        let mut hand_colliders = Vec::new();
        for s in &robot.hand_shapes {
            let (shape, pose) = link_shape(s);
            hand_colliders.push(world.insert_collider(
                ColliderBuilder::new(shape)
                    .position(to_pose(&pose))
                    .density(0.0)
                    .friction(config.friction as f32)
                    .collision_groups(robot_groups)
                    .user_data(colour_code([235, 235, 235])),
                Some(hand),
            ));
        }
        let finger_start = (robot.fingers[0].upper * 0.5).max(robot.fingers[0].lower);
        let mut fingers = Vec::new();
        let mut finger_joints = Vec::new();
        let mut finger_colliders = Vec::new();
        for f in &robot.fingers {
            let travel = nalgebra::Translation3::from(f.axis.into_inner() * finger_start);
            let pose = hand_pose * f.origin * travel;
            let body = world.insert_body(
                RigidBodyBuilder::dynamic()
                    .pose(to_pose(&pose))
                    .gravity_scale(0.0)
                    .can_sleep(false)
                    .additional_mass_properties(mass_props(&f.inertia)),
            );
            let mut cols = Vec::new();
            for s in &f.shapes {
                let (shape, spose) = link_shape(s);
                cols.push(world.insert_collider(
                    ColliderBuilder::new(shape)
                        .position(to_pose(&spose))
                        .density(0.0)
                        .friction((config.friction * FINGER_PAD_FRICTION) as f32)
                        .collision_groups(robot_groups)
                        .user_data(colour_code([60, 60, 60])),
                    Some(body),
                ));
            }
            // The joint's local x axis is the finger's direction of travel.
            let align = nalgebra::UnitQuaternion::rotation_between(&Vector3::x(), &f.axis)
                .unwrap_or_else(|| nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::PI));
            let frame1 = f.origin * align;
            let frame2 = Isometry3::from_parts(nalgebra::Translation3::identity(), align);
            let joint = GenericJointBuilder::new(JointAxesMask::LOCKED_PRISMATIC_AXES)
                .local_frame1(to_pose(&frame1))
                .local_frame2(to_pose(&frame2))
                .limits(JointAxis::LinX, [f.lower as f32, f.upper as f32])
                .motor_model(JointAxis::LinX, MotorModel::ForceBased)
                .motor_position(JointAxis::LinX, finger_start as f32, FINGER_STIFFNESS, FINGER_DAMPING)
                .motor_max_force(JointAxis::LinX, config.max_finger_force.min(f.max_effort) as f32)
                .build();
            finger_joints.push(world.insert_impulse_joint(hand, body, joint));
            fingers.push(body);
            finger_colliders.push(cols);
        }
        let bodies = RobotBodies {
            hand,
            fingers: [fingers[0], fingers[1]],
            finger_joints: [finger_joints[0], finger_joints[1]],
            hand_colliders,
            finger_colliders: [finger_colliders[0].clone(), finger_colliders[1].clone()],
        };
        let arm = ArmController { q_cmd: q.clone(), tcp_cmd: robot.tcp_pose(&base, &q), q_meas: q.clone(), q_des: q, finger_cmd: finger_start };
        Ok(Self {
            world,
            robot,
            control_model,
            base,
            config,
            bodies,
            arm,
            table_top,
            table_half_extents,
            ik: IkOptions::default(),
            frames: Vec::new(),
        })
    }

    /// Put the arm at joints `q` (clamped to the limits), at rest, fingers at `finger_travel`.
    pub fn place_robot(&mut self, q: &[f64], finger_travel: f64) {
        let mut q = q.to_vec();
        self.control_model.clamp_to_limits(&mut q);
        let hand_pose = self.robot.hand_pose(&self.base, &q);
        let set = |body: &mut RigidBody, pose: &Isometry3<f64>| {
            body.set_position(to_pose(pose), true);
            body.set_linvel(Vector::ZERO, true);
            body.set_angvel(Vector::ZERO, true);
        };
        set(&mut self.world.bodies[self.bodies.hand], &hand_pose);
        let travel = finger_travel.clamp(self.robot.fingers[0].lower, self.robot.fingers[0].upper);
        let robot = self.robot.clone();
        for (k, f) in robot.fingers.iter().enumerate() {
            let pose = hand_pose * f.origin * nalgebra::Translation3::from(f.axis.into_inner() * travel);
            set(&mut self.world.bodies[self.bodies.fingers[k]], &pose);
            self.set_finger_motor(k, travel);
        }
        let tcp_cmd = self.robot.tcp_pose(&self.base, &q);
        self.arm = ArmController { q_cmd: q.clone(), tcp_cmd, q_meas: q.clone(), q_des: q, finger_cmd: travel };
    }

    /// Move `bodies` rigidly by `motion`: poses and velocities (linear and angular) turn with it.
    pub fn transform_bodies(&mut self, bodies: &[RigidBodyHandle], motion: &Isometry3<f64>) {
        for handle in bodies {
            let body = &mut self.world.bodies[*handle];
            let pose = motion * from_pose(body.position());
            let v = motion.rotation * from_vector(body.linvel());
            let w = motion.rotation * from_vector(body.angvel());
            body.set_position(to_pose(&pose), true);
            body.set_linvel(to_vector(&v), true);
            body.set_angvel(to_vector(&w), true);
        }
    }

    /// Move the hand and fingers rigidly by `motion` (with the commanded TCP pose) and re-solve
    /// the arm's joints (measured, commanded and desired) for the moved poses; the base stays put. Each solve starts from
    /// the joints it replaces, then from each warm start in `seeds`, and keeps the best fit.
    /// Returns the worst fit: a moved hand the arm cannot reach (joint limits, reach) keeps its
    /// pose, and the controller pulls it back towards a reachable one on the next step.
    pub fn transform_hand(&mut self, motion: &Isometry3<f64>, seeds: &[&[f64]]) -> IkReport {
        let robot_bodies = [self.bodies.hand, self.bodies.fingers[0], self.bodies.fingers[1]];
        self.transform_bodies(&robot_bodies, motion);
        let model = self.control_model.clone();
        let opts = IkOptions { max_iterations: self.ik.max_iterations.max(200), ..self.ik };
        let solve = |target: &Isometry3<f64>, start: &[f64]| {
            let mut best: Option<(f64, Vec<f64>, IkReport)> = None;
            for seed in std::iter::once(start).chain(seeds.iter().copied()) {
                let mut q = seed.to_vec();
                let report = model.solve_ik(&self.base, target, &mut q, &opts);
                let score = report.position_error + 0.1 * report.rotation_error;
                if best.as_ref().is_none_or(|b| score < b.0) {
                    best = Some((score, q, report));
                }
            }
            let (_, q, report) = best.expect("the joints themselves are a warm start");
            (q, report)
        };
        let (q_meas, fit) = solve(&self.tcp_pose(), &self.arm.q_meas);
        let (q_des, fit_des) = solve(&(motion * model.tcp_pose(&self.base, &self.arm.q_des)), &self.arm.q_des);
        let (q_cmd, fit_cmd) = solve(&(motion * model.tcp_pose(&self.base, &self.arm.q_cmd)), &self.arm.q_cmd);
        self.arm.q_cmd = q_cmd;
        self.arm.tcp_cmd = motion * self.arm.tcp_cmd;
        self.arm.q_meas = q_meas;
        self.arm.q_des = q_des;
        let mut worst = fit;
        for other in [fit_des, fit_cmd] {
            worst.position_error = worst.position_error.max(other.position_error);
            worst.rotation_error = worst.rotation_error.max(other.rotation_error);
            worst.converged &= other.converged;
            worst.iterations = worst.iterations.max(other.iterations);
        }
        worst
    }

    fn set_finger_motor(&mut self, k: usize, travel: f64) {
        if let Some(j) = self.world.impulse_joints.get_mut(self.bodies.finger_joints[k], true) {
            j.data.set_motor_position(JointAxis::LinX, travel as f32, FINGER_STIFFNESS, FINGER_DAMPING);
        }
    }

    pub fn hand_pose(&self) -> Isometry3<f64> {
        from_pose(self.world.bodies[self.bodies.hand].position())
    }

    /// World pose of the tool-centre point, from the hand body's actual pose.
    pub fn tcp_pose(&self) -> Isometry3<f64> {
        self.hand_pose() * self.robot.tcp_offset
    }

    /// Travel of each finger (half the opening each), measured from the bodies.
    pub fn finger_positions(&self) -> [f64; 2] {
        let hand = self.hand_pose();
        let mut out = [0.0; 2];
        for (k, f) in self.robot.fingers.iter().enumerate() {
            let finger = from_pose(self.world.bodies[self.bodies.fingers[k]].position());
            let rel = hand.inverse() * finger;
            let d = rel.translation.vector - f.origin.translation.vector;
            out[k] = d.dot(&(f.origin.rotation * f.axis.into_inner()));
        }
        out
    }

    /// World poses of the arm frames at the measured joints (for rendering).
    pub fn arm_frames(&mut self) -> &[Isometry3<f64>] {
        let mut frames = std::mem::take(&mut self.frames);
        self.robot.arm_frames(&self.base, &self.arm.q_meas, &mut frames);
        self.frames = frames;
        &self.frames
    }

    /// Whether two colliders are in contact.
    pub fn touching(&self, a: ColliderHandle, b: ColliderHandle) -> bool {
        self.world.narrow_phase.contact_pair(a, b).is_some_and(|p| p.has_any_active_contact())
    }

    /// Whether any collider of `body` touches any of `others`.
    pub fn body_touches(&self, body: &[ColliderHandle], others: &[ColliderHandle]) -> bool {
        body.iter().any(|a| others.iter().any(|b| self.touching(*a, *b)))
    }

    /// Advance one control period towards the absolute TCP target and finger travel.
    pub fn control_step(&mut self, target: &Isometry3<f64>, finger_travel: f64) {
        let model = self.control_model.clone();
        let period = self.config.control_period();
        let dt = self.config.timestep;

        // Measured joints: the configuration that explains the hand's actual pose.
        let tcp_now = self.tcp_pose();
        let mut q_meas = std::mem::take(&mut self.arm.q_meas);
        model.solve_ik(&self.base, &tcp_now, &mut q_meas, &self.ik);
        let mut q_des = std::mem::take(&mut self.arm.q_des);
        let fit = model.solve_ik(&self.base, target, &mut q_des, &self.ik);

        // This step's commanded hand path, as a function of the fraction a in [0, 1].
        let dof = model.dof();
        let tcp_to_hand = self.robot.tcp_offset.inverse();
        let (q_start, q_end, start, end);
        if self.config.cartesian_control {
            // The reachable part of the target (a target reached within the IK tolerance is used
            // as is, so the path does not depend on where the solver started), approached from
            // the last command (kept near the actual pose) at bounded speed.
            let reachable = if fit.converged { *target } else { model.tcp_pose(&self.base, &q_des) };
            start = approach(&tcp_now, &self.arm.tcp_cmd, MAX_TCP_LEAD, MAX_TCP_LEAD_ANGLE);
            end = approach(&start, &reachable, MAX_TCP_SPEED * period, MAX_TCP_ANGULAR_SPEED * period);
            q_start = q_meas.clone();
            q_end = q_des.clone();
        } else {
            let mut qs = self.arm.q_cmd.clone();
            for k in 0..dof {
                qs[k] = qs[k].clamp(q_meas[k] - MAX_JOINT_LEAD, q_meas[k] + MAX_JOINT_LEAD);
            }
            let mut qe = qs.clone();
            for k in 0..dof {
                let max = model.joints[k].max_velocity * period;
                qe[k] += (q_des[k] - qs[k]).clamp(-max, max);
            }
            model.clamp_to_limits(&mut qe);
            start = model.tcp_pose(&self.base, &qs);
            end = model.tcp_pose(&self.base, &qe);
            q_start = qs;
            q_end = qe;
        }
        let cartesian = self.config.cartesian_control;
        let base = self.base;
        let mut q_s = q_start.clone();
        let mut hand_path = |a: f64| -> Isometry3<f64> {
            if cartesian {
                let tcp = Isometry3::from_parts(
                    start.translation.vector.lerp(&end.translation.vector, a).into(),
                    start.rotation.slerp(&end.rotation, a),
                );
                tcp * tcp_to_hand
            } else {
                for k in 0..dof {
                    q_s[k] = q_start[k] + (q_end[k] - q_start[k]) * a;
                }
                model.hand_pose(&base, &q_s)
            }
        };

        let f = &self.robot.fingers[0];
        let travel = finger_travel.clamp(f.lower, f.upper);
        let hand_mass =
            self.robot.hand_inertia.mass + self.robot.fingers.iter().map(|f| f.inertia.mass).sum::<f64>();
        let max_dv = self.config.max_hand_force * dt / hand_mass;
        let inertia = self.robot.hand_inertia.principal_inertia.max().max(1e-4);
        let max_dw = self.config.max_hand_torque * dt / inertia;
        let tau = self.config.servo_time_constant.max(dt);
        let mut prev_target = hand_path(0.0);

        for s in 1..=self.config.substeps {
            let a = s as f64 / self.config.substeps as f64;
            let hand_target = hand_path(a);
            let ff_v = (hand_target.translation.vector - prev_target.translation.vector) / dt;
            let ff_w = rotation_error(&hand_target.rotation, &prev_target.rotation) / dt;
            prev_target = hand_target;

            // Fingers: rate-limited motor targets.
            let step = self.config.finger_speed * dt;
            self.arm.finger_cmd += (travel - self.arm.finger_cmd).clamp(-step, step);
            let cmd = self.arm.finger_cmd;
            self.set_finger_motor(0, cmd);
            self.set_finger_motor(1, cmd);

            // Hand: velocity servo with bounded velocity change (= bounded force and torque).
            let hand = &self.world.bodies[self.bodies.hand];
            let pose = from_pose(hand.position());
            let v = from_vector(hand.linvel());
            let w = from_vector(hand.angvel());
            let v_des = clamp_norm(ff_v + (hand_target.translation.vector - pose.translation.vector) / tau, MAX_HAND_SPEED);
            let w_des = clamp_norm(ff_w + rotation_error(&hand_target.rotation, &pose.rotation) / tau, 8.0);
            let dv = clamp_norm(v_des - v, max_dv);
            let dw = clamp_norm(w_des - w, max_dw);
            let centre = pose.translation.vector;
            self.world.bodies[self.bodies.hand].set_linvel(to_vector(&(v + dv)), true);
            self.world.bodies[self.bodies.hand].set_angvel(to_vector(&(w + dw)), true);
            // The fingers share the hand's velocity change, as if the force acted on the assembly.
            for k in 0..2 {
                let body = &mut self.world.bodies[self.bodies.fingers[k]];
                let r = from_vector(body.translation()) - centre;
                let fv = from_vector(body.linvel()) + dv + dw.cross(&r);
                let fw = from_vector(body.angvel()) + dw;
                body.set_linvel(to_vector(&fv), true);
                body.set_angvel(to_vector(&fw), true);
            }
            self.world.step();
        }
        self.arm.tcp_cmd = end;
        self.arm.q_cmd = q_end;
        self.arm.q_meas = q_meas;
        self.arm.q_des = q_des;
    }

    /// Serialise the dynamic state (bodies, contacts, joints, controller) to bytes.
    pub fn save(&self) -> Result<Vec<u8>> {
        #[derive(Serialize)]
        struct Ref<'a> {
            world: &'a PhysicsWorld,
            arm: &'a ArmController,
        }
        postcard::to_stdvec(&Ref { world: &self.world, arm: &self.arm })
            .map_err(|e| EnvError::InvalidState(format!("cannot serialise the scene: {e}")))
    }

    /// Restore a state produced by [`Scene::save`] on a scene of the same task.
    pub fn restore(&mut self, bytes: &[u8]) -> Result<()> {
        let state: SceneState = postcard::from_bytes(bytes)
            .map_err(|e| EnvError::InvalidState(format!("cannot decode the scene: {e}")))?;
        if state.arm.q_cmd.len() != self.robot.dof() || state.arm.q_meas.len() != self.robot.dof() || state.arm.q_des.len() != self.robot.dof()
            || state.world.bodies.len() != self.world.bodies.len()
            || state.world.colliders.len() != self.world.colliders.len()
        {
            return Err(EnvError::InvalidState("the state belongs to a different scene".into()));
        }
        let SceneState { world, arm } = state;
        self.world.islands = world.islands;
        self.world.broad_phase = world.broad_phase;
        self.world.narrow_phase = world.narrow_phase;
        self.world.bodies = world.bodies;
        self.world.colliders = world.colliders;
        self.world.impulse_joints = world.impulse_joints;
        self.world.multibody_joints = world.multibody_joints;
        self.world.soft_bodies = world.soft_bodies;
        self.world.integration_parameters = world.integration_parameters;
        self.world.gravity = world.gravity;
        self.arm = arm;
        Ok(())
    }
}

/// Move pose `from` towards `to` by at most `max_step` metres and `max_angle` radians (a pose
/// on the straight line and the geodesic between them). Commutes with rigid motions.
fn approach(from: &Isometry3<f64>, to: &Isometry3<f64>, max_step: f64, max_angle: f64) -> Isometry3<f64> {
    let dp = clamp_norm(to.translation.vector - from.translation.vector, max_step);
    let turn = to.rotation * from.rotation.inverse();
    let angle = turn.angle();
    let turn = if angle > max_angle { UnitQuaternion::from_scaled_axis(turn.scaled_axis() * (max_angle / angle)) } else { turn };
    Isometry3::from_parts((from.translation.vector + dp).into(), turn * from.rotation)
}
