//! The scene: the world ([`crate::world`]), the robot rig ([`crate::robot::rig`]), the arm
//! controller ([`crate::robot::controller`]) and the servo loop that ties them together.
//!
//! One control step (20 Hz) plans the arm's motion towards the absolute target once, then runs
//! `substeps` physics steps; before each, the controller's joint targets go to the joint
//! servos and the finger command moves at the finger speed limit; after each, joint speeds are
//! held to their limits. Everything the robot does to the world goes through torque-capped
//! joint servos and contacts: pressing into the table or crushing an object stalls the arm
//! instead of driving it through, and objects are held by contact friction alone.

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix6, Vector6};
use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EnvError, Result};
use crate::math::{from_pose, from_vector, to_pose, to_vector};
use crate::robot::controller::{seed_bank, worse, ControlContext};
use crate::robot::kinematics::MAX_DOF;
use crate::robot::{ActiveController, Controller, IkOptions, IkReport, RobotModel, RobotRig};
use crate::world::{build_world, PhysicsConfig, TableSpec, WorldColliders};

pub use crate::robot::rig::link_shape;
pub use crate::world::{colour_code, GROUP_OBJECT, GROUP_ROBOT, GROUP_STATIC};

/// IK tolerance (m, rad) when the robot is moved for a symmetry probe.
const TRANSFORM_IK_TOLERANCE: f64 = 1e-8;

/// Damping of the least-squares map from a TCP twist to joint velocities (symmetry probes).
const TWIST_DAMPING: f64 = 1e-3;

/// The physics world with the robot in it.
pub struct Scene {
    pub world: PhysicsWorld,
    pub rig: RobotRig,
    /// The table's and the floor's colliders.
    pub statics: WorldColliders,
    pub config: PhysicsConfig,
    controller: ActiveController,
    /// Commanded finger travel (half the opening), rate limited.
    finger_cmd: f64,
    ik: IkOptions,
    /// Warm starts for IK restarts.
    seeds: Vec<Vec<f64>>,
}

/// The part of a [`Scene`] that changes during an episode, serialisable bit for bit.
#[derive(Serialize, Deserialize)]
struct SceneState {
    world: PhysicsWorld,
    controller: ActiveController,
    finger_cmd: f64,
}

#[derive(Serialize)]
struct SceneStateRef<'a> {
    world: &'a PhysicsWorld,
    controller: &'a ActiveController,
    finger_cmd: f64,
}

impl Scene {
    /// Build the world with the table, and the robot at joint configuration `home` with open
    /// fingers.
    pub fn new(
        robot: Arc<RobotModel>,
        base: Isometry3<f64>,
        home: &[f64],
        table: TableSpec,
        config: PhysicsConfig,
        controller: Controller,
    ) -> Result<Self> {
        config.validate()?;
        let robot = if config.joint_limit_scale == 1.0 {
            robot
        } else {
            Arc::new(robot.with_joint_limit_scale(config.joint_limit_scale))
        };
        let (mut world, statics) = build_world(&config, &table);
        let open = robot.fingers[0].upper;
        let rig = RobotRig::spawn(&mut world, robot.clone(), base, home, open, &config)?;
        let ik = IkOptions { joint_limits: config.joint_limits, ..IkOptions::default() };
        let seeds = seed_bank(&robot, home);
        let mut q = home.to_vec();
        rig.clamp_to_limits(&mut q);
        let ctx =
            ControlContext { model: &robot, base: &base, ik: &ik, seeds: &seeds, period: config.control_period() };
        let controller = ActiveController::new(controller, &ctx, &q);
        Ok(Self { world, rig, statics, config, controller, finger_cmd: open, ik, seeds })
    }

    pub fn robot(&self) -> &Arc<RobotModel> {
        &self.rig.model
    }

    pub fn base(&self) -> &Isometry3<f64> {
        &self.rig.base
    }

    pub fn controller(&self) -> &ActiveController {
        &self.controller
    }

    /// Put the arm at joints `q` (clamped to the limits), at rest, fingers at `finger_travel`.
    pub fn place_robot(&mut self, q: &[f64], finger_travel: f64) {
        let mut q = q.to_vec();
        self.rig.clamp_to_limits(&mut q);
        self.rig.place(&mut self.world, &q, [finger_travel; 2]);
        let world = &mut self.world;
        world.bodies.propagate_modified_body_positions_to_colliders(&mut world.colliders);
        let f = &self.rig.model.fingers[0];
        self.finger_cmd = finger_travel.clamp(f.lower, f.upper);
        let ctx = self.context();
        let mut controller = self.controller.clone();
        controller.get().reset(&ctx, &q);
        self.controller = controller;
    }

    fn context(&self) -> ControlContext<'_> {
        ControlContext {
            model: &self.rig.model,
            base: &self.rig.base,
            ik: &self.ik,
            seeds: &self.seeds,
            period: self.config.control_period(),
        }
    }

    /// Measured arm joint positions (rad).
    pub fn joint_positions(&self) -> Vec<f64> {
        let mut q = vec![0.0; self.rig.dof()];
        self.rig.joint_positions(&self.world, &mut q);
        q
    }

    /// Measured arm joint velocities (rad/s).
    pub fn joint_velocities(&self) -> Vec<f64> {
        let mut qd = vec![0.0; self.rig.dof()];
        self.rig.joint_velocities(&self.world, &mut qd);
        qd
    }

    pub fn hand_pose(&self) -> Isometry3<f64> {
        self.rig.hand_pose(&self.world)
    }

    /// World pose of the tool-centre point (forward kinematics of the physical joint state).
    pub fn tcp_pose(&self) -> Isometry3<f64> {
        self.rig.tcp_pose(&self.world)
    }

    /// Travel of each finger (half the opening each).
    pub fn finger_positions(&self) -> [f64; 2] {
        self.rig.finger_positions(&self.world)
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
    /// Returns how well the IK reaches the target.
    pub fn control_step(&mut self, target: &Isometry3<f64>, finger_travel: f64) -> IkReport {
        let dof = self.rig.dof();
        let mut q_meas = [0.0; MAX_DOF];
        self.rig.joint_positions(&self.world, &mut q_meas[..dof]);
        let mut controller = std::mem::replace(&mut self.controller, ActiveController::Joint(Default::default()));
        let ctx = ControlContext {
            model: &self.rig.model,
            base: &self.rig.base,
            ik: &self.ik,
            seeds: &self.seeds,
            period: self.config.control_period(),
        };
        let fit = controller.get().plan(&ctx, &q_meas[..dof], target);

        let f = &self.rig.model.fingers[0];
        let travel = finger_travel.clamp(f.lower, f.upper);
        let dt = self.config.timestep;
        let finger_step = self.config.finger_speed.min(f.max_velocity) * dt;
        let mut q = [0.0; MAX_DOF];
        let mut qd = [0.0; MAX_DOF];
        for s in 1..=self.config.substeps {
            let a = s as f64 / self.config.substeps as f64;
            controller.get().joint_targets(&ctx, a, &mut q[..dof], &mut qd[..dof]);
            self.rig.set_arm_targets(&mut self.world, &q[..dof], &qd[..dof]);
            self.finger_cmd += (travel - self.finger_cmd).clamp(-finger_step, finger_step);
            self.rig.set_finger_targets(&mut self.world, self.finger_cmd);
            self.world.step();
            self.rig.clamp_joint_velocities(&mut self.world);
            if self.rig.enforce_position_limits(&mut self.world) {
                let world = &mut self.world;
                world.bodies.propagate_modified_body_positions_to_colliders(&mut world.colliders);
            }
        }
        self.controller = controller;
        fit
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

    /// Move the hand rigidly by `motion` while the base stays put: the arm's joints are
    /// re-solved for the moved TCP pose (warm start, then the seed bank and `seeds`), the joint
    /// velocities are those that give the rotated TCP twist, the fingers keep their travel and
    /// the controller's commanded state moves with the hand. Returns the worst IK fit: a moved
    /// hand the arm cannot reach (joint limits, reach) ends at the closest joint-limited pose.
    pub fn transform_robot(&mut self, motion: &Isometry3<f64>, seeds: &[&[f64]]) -> IkReport {
        let dof = self.rig.dof();
        let model = self.rig.model.clone();
        let base = self.rig.base;
        let q = self.joint_positions();
        let qd = self.joint_velocities();
        let twist = tcp_jacobian(&model, &base, &q) * nalgebra::DVector::from_column_slice(&qd);
        let v = motion.rotation * twist.fixed_rows::<3>(0).into_owned();
        let w = motion.rotation * twist.fixed_rows::<3>(3).into_owned();
        let target = motion * self.tcp_pose();
        // Symmetry probes compare g.s with the rotated observation: solve far below the
        // control tolerance, so what is left is the f32 physics (about 1e-6 m).
        let opts = IkOptions {
            max_iterations: self.ik.max_iterations.max(200),
            position_tolerance: TRANSFORM_IK_TOLERANCE,
            rotation_tolerance: TRANSFORM_IK_TOLERANCE,
            ..self.ik
        };
        let mut all: Vec<&[f64]> = self.seeds.iter().map(|s| s.as_slice()).collect();
        all.extend_from_slice(seeds);
        let mut q_new = q.clone();
        let fit = model.solve_ik_restarts(&base, &target, &mut q_new, &all, &opts);
        let fingers = self.finger_positions();
        self.rig.place(&mut self.world, &q_new, fingers);
        // Joint velocities for the rotated twist (damped least squares).
        let j = tcp_jacobian(&model, &base, &q_new);
        let e = Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z);
        let a: Matrix6<f64> = &j * j.transpose() + Matrix6::identity() * TWIST_DAMPING * TWIST_DAMPING;
        let qd_new = a.cholesky().map(|c| j.transpose() * c.solve(&e)).unwrap_or_else(|| nalgebra::DVector::zeros(dof));
        self.rig.set_joint_velocities(&mut self.world, qd_new.as_slice());
        self.rig.set_finger_targets(&mut self.world, self.finger_cmd);
        let mut controller = self.controller.clone();
        let ctx = ControlContext {
            model: &model,
            base: &base,
            ik: &opts,
            seeds: &self.seeds,
            period: self.config.control_period(),
        };
        let fit_cmd = controller.get().transform(&ctx, motion, &q_new);
        self.controller = controller;
        worse(fit, fit_cmd)
    }

    /// Serialise the dynamic state (bodies, contacts, joints, controller) to bytes.
    pub fn save(&self) -> Result<Vec<u8>> {
        postcard::to_stdvec(&SceneStateRef {
            world: &self.world,
            controller: &self.controller,
            finger_cmd: self.finger_cmd,
        })
        .map_err(|e| EnvError::InvalidState(format!("cannot serialise the scene: {e}")))
    }

    /// Step a copy of the world in `bytes` (from [`Scene::save`]) once, to refuse a world the
    /// physics engine cannot step before it replaces anything. rapier trusts its serialised
    /// worlds: forged bytes with a valid checksum (`tests/fuzz.rs`) reached index and
    /// assertion panics in its multibody code at the first step.
    pub fn trial_step(bytes: &[u8]) -> Result<()> {
        let state: SceneState =
            postcard::from_bytes(bytes).map_err(|e| EnvError::InvalidState(format!("cannot decode the scene: {e}")))?;
        let mut world = state.world;
        if !world_is_finite(&world) {
            return Err(EnvError::InvalidState("the state holds non-finite poses or velocities".into()));
        }
        let stepped = std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || {
            world.step();
            world_is_finite(&world) && world.quarantine().bodies().is_empty()
        }));
        match stepped {
            Ok(true) => Ok(()),
            Ok(false) => Err(EnvError::InvalidState("the state's world goes non-finite when stepped".into())),
            Err(_) => Err(EnvError::InvalidState("the physics engine cannot step this world".into())),
        }
    }

    /// Restore a state produced by [`Scene::save`] on a scene of the same task.
    pub fn restore(&mut self, bytes: &[u8]) -> Result<()> {
        let state: SceneState =
            postcard::from_bytes(bytes).map_err(|e| EnvError::InvalidState(format!("cannot decode the scene: {e}")))?;
        let same_kind = state.controller.kind() == self.controller.kind();
        if !same_kind
            || state.controller.dof() != self.rig.dof()
            || !state.finger_cmd.is_finite()
            || state.world.bodies.len() != self.world.bodies.len()
            || state.world.colliders.len() != self.world.colliders.len()
            || state.world.multibody_joints.multibodies().count() != self.world.multibody_joints.multibodies().count()
            || self.rig.moving_bodies().any(|h| state.world.multibody_joints.rigid_body_link(h).is_none())
        {
            return Err(EnvError::InvalidState("the state belongs to a different scene".into()));
        }
        let SceneState { world, controller, finger_cmd } = state;
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
        self.controller = controller;
        self.finger_cmd = finger_cmd;
        Ok(())
    }
}

/// Whether every body's pose and velocity and every collider's pose in `world` is finite.
fn world_is_finite(world: &PhysicsWorld) -> bool {
    let pose_ok = |p: &Pose| p.translation.is_finite() && p.rotation.is_finite();
    world.bodies.iter().all(|(_, b)| pose_ok(b.position()) && b.linvel().is_finite() && b.angvel().is_finite())
        && world.colliders.iter().all(|(_, c)| pose_ok(c.position()))
}

/// The 6 x dof geometric Jacobian of the TCP (rows: linear, angular velocity).
fn tcp_jacobian(model: &RobotModel, base: &Isometry3<f64>, q: &[f64]) -> nalgebra::DMatrix<f64> {
    let n = model.dof();
    let mut cols = [Vector6::zeros(); MAX_DOF];
    model.jacobian(base, q, &mut cols);
    nalgebra::DMatrix::from_fn(6, n, |r, c| cols[c][r])
}
