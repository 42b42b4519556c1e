//! Scripted experts: waypoint state machines with privileged access to object poses.
//!
//! They produce the same 10-d absolute actions a policy would, optionally with noise
//! (for noisy / suboptimal demonstrations), and are deterministic given their seed.

pub mod lift;
pub mod square;
pub mod stack;

use crate::layout::{Action, ACTION_DIM};
use nalgebra::{Isometry3, UnitQuaternion, Vector3};

use crate::env::Env;
use crate::error::{EnvError, Result};
use crate::math::{from_pose, rot6d};
use crate::rng::{EpisodeRng, SeedUse};

/// A policy that maps the environment's current (privileged) state to an action.
pub trait Expert: Send + Sync {
    /// Called after `Env::reset`.
    fn reset(&mut self, env: &Env, seed: u64);
    /// The next action.
    fn act(&mut self, env: &Env) -> Action;
    /// Short name of the current phase (for logging and failure statistics).
    fn phase(&self) -> &'static str;
}

/// Options of every expert.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExpertOptions {
    /// Std of Gaussian noise on the commanded position (m); 0 = clean demonstrations.
    pub position_noise: f64,
    /// Std of Gaussian noise on the grasp yaw (rad).
    pub yaw_noise: f64,
}

impl Default for ExpertOptions {
    fn default() -> Self {
        Self { position_noise: 0.0, yaw_noise: 0.0 }
    }
}

/// Build the expert of a task.
pub fn make_expert(task: &str, options: ExpertOptions) -> Result<Box<dyn Expert>> {
    if !(options.position_noise.is_finite()
        && options.position_noise >= 0.0
        && options.yaw_noise.is_finite()
        && options.yaw_noise >= 0.0)
    {
        return Err(EnvError::InvalidConfig("expert noise must be finite and >= 0".into()));
    }
    match task {
        "lift" => Ok(Box::new(lift::LiftExpert::new(options))),
        "stack" => Ok(Box::new(stack::StackExpert::new(options))),
        "square" => Ok(Box::new(square::SquareExpert::new(options))),
        other => Err(EnvError::InvalidConfig(format!("no scripted expert for task '{other}'"))),
    }
}

/// The phases of the pick-and-place experts (Lift uses the first four).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Phase {
    Approach,
    Descend,
    Close,
    Lift,
    Carry,
    Lower,
    Release,
    Retreat,
}

impl Phase {
    pub fn name(self) -> &'static str {
        match self {
            Phase::Approach => "approach",
            Phase::Descend => "descend",
            Phase::Close => "close",
            Phase::Lift => "lift",
            Phase::Carry => "carry",
            Phase::Lower => "lower",
            Phase::Release => "release",
            Phase::Retreat => "retreat",
        }
    }
}

/// Shared helpers for waypoint experts.
pub(crate) struct Waypoints {
    pub rng: EpisodeRng,
    pub options: ExpertOptions,
    /// The position the expert is currently commanding (moves towards waypoints at a bounded speed).
    pub commanded: Vector3<f64>,
}

impl Waypoints {
    pub fn new(options: ExpertOptions) -> Self {
        Self { rng: EpisodeRng::from_seed(0), options, commanded: Vector3::zeros() }
    }

    pub fn reset(&mut self, env: &Env, seed: u64) {
        // The expert's own stream of this seed (apart from the episode's and the auto-resets').
        self.rng = EpisodeRng::for_use(seed, SeedUse::Expert);
        self.commanded = env.scene().tcp_pose().translation.vector;
    }

    /// Move the commanded point towards `goal` by at most `max_step`; true when it is there.
    pub fn advance(&mut self, goal: Vector3<f64>, max_step: f64) -> bool {
        let d = goal - self.commanded;
        if d.norm() <= max_step {
            self.commanded = goal;
            true
        } else {
            self.commanded += d * (max_step / d.norm());
            false
        }
    }

    /// Yaw of an object about the world z axis.
    pub fn yaw(pose: &Isometry3<f64>) -> f64 {
        let x = pose.rotation * Vector3::x();
        libm::atan2(x.y, x.x)
    }

    /// The action for the commanded point, a rotation and a gripper width (with noise).
    pub fn action(&mut self, rotation: &UnitQuaternion<f64>, width: f64) -> Action {
        let mut a = [0.0; ACTION_DIM];
        let sigma = self.options.position_noise;
        for (ak, ck) in a.iter_mut().zip(self.commanded.iter()) {
            *ak = ck + if sigma > 0.0 { sigma * self.rng.normal() } else { 0.0 };
        }
        a[3..9].copy_from_slice(&rot6d(rotation));
        a[9] = width;
        a
    }
}

/// Pose of a task object.
pub(crate) fn object_pose(env: &Env, index: usize) -> Isometry3<f64> {
    let body = env.task().objects()[index].body;
    from_pose(env.scene().world.bodies[body].position())
}

/// A top-down grasp rotation: the TCP rotation at the robot's home posture turned about the
/// world z axis so that the fingers close along `finger_yaw` modulo `period` (pi/2 for the
/// faces of a square box, pi for a bar). The turn is the smallest one (|turn| <= period / 2)
/// from the home posture, which keeps the last wrist joint far from its limits.
pub(crate) fn top_down_grasp(env: &Env, finger_yaw: f64, period: f64) -> UnitQuaternion<f64> {
    turned_home(env, top_down_turn(env, finger_yaw, period))
}

/// The turn about the world z axis from the home posture that [`top_down_grasp`] uses.
pub(crate) fn top_down_turn(env: &Env, finger_yaw: f64, period: f64) -> f64 {
    let scene = env.scene();
    let home = scene.robot().tcp_pose(scene.base(), &env.task().scene_spec().home_q).rotation;
    let finger_dir = home * (scene.robot().fingers[0].origin.rotation * scene.robot().fingers[0].axis.into_inner());
    let home_finger_yaw = libm::atan2(finger_dir.y, finger_dir.x);
    let mut turn = (finger_yaw - home_finger_yaw).rem_euclid(period);
    if turn > period / 2.0 {
        turn -= period;
    }
    turn
}

/// The TCP rotation at the robot's home posture turned by `turn` about the world z axis.
pub(crate) fn turned_home(env: &Env, turn: f64) -> UnitQuaternion<f64> {
    let scene = env.scene();
    let home = scene.robot().tcp_pose(scene.base(), &env.task().scene_spec().home_q).rotation;
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), turn) * home
}
