//! [`Env`]: a task, its scene and its random stream behind `reset` / `step`.
//!
//! Actions are 10-d absolute end-effector targets: TCP position (3), 6D rotation (6: the first
//! two rows of the rotation matrix) and gripper width (1, metres), applied at 20 Hz.

use std::sync::Arc;

use nalgebra::{Isometry3, Translation3};
use serde::{Deserialize, Serialize};

use crate::error::{check_finite, EnvError, Result};
use crate::layout::{Action, Layout};
use crate::math::rotation_from_rot6d;
use crate::options::EnvSpec;
use crate::rng::EpisodeRng;
use crate::robot::{load_urdf, parse_urdf, IkReport, RobotModel};
use crate::scene::Scene;
use crate::tasks::{make_task, Evaluation, Task};

/// The robot description shipped with equigym.
pub const PANDA_URDF: &str = include_str!("../../assets/panda/panda.urdf");

pub use crate::layout::ACTION_DIM;
pub use crate::options::EnvConfig;

/// Bounds of the raw (absolute) action space: TCP position box, 6D rotation in [-1, 1],
/// gripper width in [0, max width].
pub const POSITION_LOW: [f64; 3] = [-0.5, -0.5, 0.75];
pub const POSITION_HIGH: [f64; 3] = [0.5, 0.5, 1.35];

/// What `step` returns.
#[derive(Clone, Debug, PartialEq)]
pub struct StepResult {
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    pub evaluation: Evaluation,
}

/// Length of the checksum that ends the bytes of a saved state.
pub const STATE_CHECKSUM_LEN: usize = 8;

/// FNV-1a (64-bit) of a saved state's payload: a stable, dependency-free integrity check (not a
/// defence against deliberate forgery).
fn state_checksum(bytes: &[u8]) -> u64 {
    const OFFSET_BASIS: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    bytes.iter().fold(OFFSET_BASIS, |h, &b| (h ^ u64::from(b)).wrapping_mul(PRIME))
}

/// Bytes of a saved environment state (see [`Env::get_state`]): this, postcard-encoded, then
/// The text of a caught panic's payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into())
}

/// [`STATE_CHECKSUM_LEN`] bytes of [`state_checksum`].
#[derive(Serialize, Deserialize)]
struct SavedState {
    task: String,
    scene: Vec<u8>,
    rng: EpisodeRng,
    steps: usize,
    in_episode: bool,
    task_params: Vec<f64>,
    last_target: Action,
}

pub struct Env {
    config: EnvConfig,
    task: Box<dyn Task>,
    scene: Scene,
    rng: EpisodeRng,
    steps: usize,
    horizon: usize,
    in_episode: bool,
    obs: Vec<f64>,
    /// Last applied action (the target kept when a 6D rotation is degenerate).
    last_target: Action,
    /// The scene as built, restored at every reset.
    pristine: Vec<u8>,
}

impl Env {
    pub fn new(config: EnvConfig) -> Result<Self> {
        let robot = match &config.urdf {
            Some(path) => load_urdf(path)?,
            None => parse_urdf(PANDA_URDF)?,
        };
        Self::with_robot(config, Arc::new(robot))
    }

    /// Build with an already-loaded robot (shared between many environments).
    pub fn with_robot(config: EnvConfig, robot: Arc<RobotModel>) -> Result<Self> {
        if !(config.init_joint_noise.is_finite() && config.init_joint_noise >= 0.0) {
            return Err(EnvError::InvalidConfig("init_joint_noise must be finite and >= 0".into()));
        }
        let mut task = make_task(&config.task, &config.task_options)?;
        let spec = task.scene_spec();
        if spec.home_q.len() != robot.dof() {
            return Err(EnvError::InvalidConfig(format!(
                "task '{}' needs a {}-joint arm, the robot has {}",
                config.task,
                spec.home_q.len(),
                robot.dof()
            )));
        }
        let mut scene =
            Scene::new(robot, spec.robot_base, &spec.home_q, spec.table, config.physics.clone(), config.controller)?;
        task.load_scene(&mut scene);
        let horizon = match config.horizon {
            Some(0) => return Err(EnvError::InvalidConfig("horizon must be positive".into())),
            Some(h) => h,
            None => task.horizon(),
        };
        let obs = vec![0.0; task.observation_layout().dim()];
        let pristine = scene.save()?;
        Ok(Self {
            pristine,
            config,
            task,
            scene,
            rng: EpisodeRng::from_seed(0),
            steps: 0,
            horizon,
            in_episode: false,
            obs,
            last_target: [0.0; ACTION_DIM],
        })
    }

    pub fn config(&self) -> &EnvConfig {
        &self.config
    }
    pub fn task(&self) -> &dyn Task {
        self.task.as_ref()
    }
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    pub fn scene_mut(&mut self) -> &mut Scene {
        &mut self.scene
    }
    pub fn horizon(&self) -> usize {
        self.horizon
    }
    pub fn elapsed_steps(&self) -> usize {
        self.steps
    }
    pub fn observation_layout(&self) -> &Layout {
        self.task.observation_layout()
    }
    pub fn action_layout(&self) -> Layout {
        Layout::action()
    }
    pub fn max_gripper_width(&self) -> f64 {
        self.scene.robot().max_gripper_width()
    }

    /// The read-only description of this environment (task, horizon, bounds, layouts).
    pub fn spec(&self) -> EnvSpec {
        let (action_low, action_high) = self.action_bounds();
        EnvSpec {
            task: self.task.id(),
            horizon: self.horizon,
            control_period: self.config.physics.control_period(),
            max_gripper_width: self.max_gripper_width(),
            action_low,
            action_high,
            observation_layout: self.observation_layout().clone(),
            action_layout: self.action_layout(),
        }
    }

    /// Lower and upper bounds of the raw action.
    pub fn action_bounds(&self) -> (Action, Action) {
        let w = self.max_gripper_width();
        let mut lo = [-1.0; ACTION_DIM];
        let mut hi = [1.0; ACTION_DIM];
        lo[..3].copy_from_slice(&POSITION_LOW);
        hi[..3].copy_from_slice(&POSITION_HIGH);
        lo[9] = 0.0;
        hi[9] = w;
        (lo, hi)
    }

    /// Start an episode. The seed fixes everything random about it.
    pub fn reset(&mut self, seed: u64) -> Result<&[f64]> {
        self.rng = EpisodeRng::from_seed(seed);
        // Start from the freshly built world (no contacts or solver caches from the previous
        // episode), so that an episode depends on its seed alone.
        self.scene.restore(&self.pristine)?;
        let spec = self.task.scene_spec();
        let mut q = spec.home_q.clone();
        for qi in q.iter_mut() {
            *qi += self.config.init_joint_noise * self.rng.normal();
        }
        let open = self.scene.robot().fingers[0].upper;
        self.scene.place_robot(&q, open);
        self.task.initialise_episode(&mut self.scene, &mut self.rng);
        // Move the colliders with their bodies now, so that renders and queries before the
        // first step see the new placement.
        let world = &mut self.scene.world;
        world.bodies.propagate_modified_body_positions_to_colliders(&mut world.colliders);
        self.steps = 0;
        self.in_episode = true;
        self.last_target = self.current_target();
        Ok(self.observe())
    }

    /// The action that holds the robot where it is now.
    pub fn current_target(&self) -> Action {
        let tcp = self.scene.tcp_pose();
        let r = crate::math::rot6d(&tcp.rotation);
        let f = self.scene.finger_positions();
        let mut a = [0.0; ACTION_DIM];
        a[..3].copy_from_slice(tcp.translation.vector.as_slice());
        a[3..9].copy_from_slice(&r);
        a[9] = (f[0] + f[1]).clamp(0.0, self.max_gripper_width());
        a
    }

    /// The current observation.
    pub fn observe(&mut self) -> &[f64] {
        self.task.observe(&self.scene, &mut self.obs);
        &self.obs
    }

    /// Apply one 10-d absolute action for one control period.
    pub fn step(&mut self, action: &[f64]) -> Result<StepResult> {
        if !self.in_episode {
            return Err(EnvError::CallOrder(if self.steps == 0 {
                "step() called before reset()".into()
            } else {
                format!("the episode ended after {} steps; call reset() before step()", self.steps)
            }));
        }
        check_finite("action", action, ACTION_DIM)?;
        let (lo, hi) = self.action_bounds();
        let mut a = [0.0; ACTION_DIM];
        for k in 0..ACTION_DIM {
            a[k] = action[k].clamp(lo[k], hi[k]);
        }
        // A degenerate 6D rotation (zero or parallel rows) keeps the previous orientation.
        let rotation = match rotation_from_rot6d(&a[3..9]) {
            Some(r) => r,
            None => {
                a[3..9].copy_from_slice(&self.last_target[3..9]);
                rotation_from_rot6d(&a[3..9]).unwrap_or_else(|| self.scene.tcp_pose().rotation)
            }
        };
        self.last_target = a;
        let target = Isometry3::from_parts(Translation3::new(a[0], a[1], a[2]), rotation);
        // The physics engine trusts the worlds it steps. Worlds built here never make it panic;
        // one restored from hand-made state bytes with a valid checksum can (`set_state` steps a
        // copy first, but cannot prove every later step safe). A panic ends the episode with a
        // typed error instead of unwinding into the caller; `reset` starts from the pristine
        // world again.
        let scene = &mut self.scene;
        let gripper = a[9] * 0.5;
        if let Err(panic) =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| scene.control_step(&target, gripper)))
        {
            self.in_episode = false;
            return Err(EnvError::Physics(panic_message(panic.as_ref())));
        }
        self.steps += 1;
        let evaluation = self.task.evaluate(&self.scene);
        let reward = evaluation.reward(self.config.reward);
        let truncated = self.steps >= self.horizon;
        if truncated {
            self.in_episode = false;
        }
        Ok(StepResult { reward, terminated: false, truncated, evaluation })
    }

    /// Move everything that moves (the task's objects, the hand and the fingers) rigidly by
    /// `motion`, with their velocities, while the robot base and the table stay where they are:
    /// the arm's joints are re-solved for the moved hand (the hand is where the joints put it,
    /// so an unreachable pose ends at the closest reachable one) and the last target moves too.
    /// This is how symmetry probes build the transformed state g.s from s. The returned report
    /// says how well the arm reaches the moved hand (joint limits and reach break the symmetry).
    pub fn transform_scene(&mut self, motion: &Isometry3<f64>) -> Result<IkReport> {
        if !self.in_episode && self.steps == 0 {
            return Err(EnvError::CallOrder("transform_scene() called before reset()".into()));
        }
        let m = motion.to_homogeneous();
        if let Some(bad) = m.iter().find(|v| !v.is_finite()) {
            return Err(EnvError::NonFinite { what: "motion".into(), index: 0, value: *bad });
        }
        let bodies: Vec<_> = self.task.objects().iter().map(|o| o.body).collect();
        self.scene.transform_bodies(&bodies, motion);
        let home = self.task.scene_spec().home_q;
        let report = self.scene.transform_robot(motion, &[home.as_slice()]);
        let world = &mut self.scene.world;
        world.bodies.propagate_modified_body_positions_to_colliders(&mut world.colliders);
        let t = &mut self.last_target;
        let p = motion * nalgebra::Point3::new(t[0], t[1], t[2]);
        t[..3].copy_from_slice(p.coords.as_slice());
        if let Some(r) = rotation_from_rot6d(&t[3..9]) {
            t[3..9].copy_from_slice(&crate::math::rot6d(&(motion.rotation * r)));
        }
        Ok(report)
    }

    /// Evaluate the current state without stepping.
    pub fn evaluate(&self) -> Evaluation {
        self.task.evaluate(&self.scene)
    }

    /// The whole state (physics, controller, random stream, step count) as bytes.
    pub fn get_state(&self) -> Result<Vec<u8>> {
        let saved = SavedState {
            task: self.task.id().to_string(),
            scene: self.scene.save()?,
            rng: self.rng.clone(),
            steps: self.steps,
            in_episode: self.in_episode,
            task_params: self.task.episode_params(),
            last_target: self.last_target,
        };
        let mut bytes =
            postcard::to_stdvec(&saved).map_err(|e| EnvError::InvalidState(format!("cannot serialise: {e}")))?;
        bytes.extend_from_slice(&state_checksum(&bytes).to_le_bytes());
        Ok(bytes)
    }

    /// Restore a state from [`Env::get_state`]; continuing from it is bitwise identical.
    /// On error the environment is left unchanged.
    /// The bytes carry a checksum: edited, truncated or foreign bytes are refused before they
    /// reach the physics engine (which trusts its own serialised state).
    pub fn set_state(&mut self, bytes: &[u8]) -> Result<()> {
        let payload = match bytes.len().checked_sub(STATE_CHECKSUM_LEN) {
            Some(n) if state_checksum(&bytes[..n]).to_le_bytes() == bytes[n..] => &bytes[..n],
            _ => {
                return Err(EnvError::InvalidState(
                    "not an equigym state (checksum mismatch: edited or truncated bytes)".into(),
                ))
            }
        };
        let saved: SavedState =
            postcard::from_bytes(payload).map_err(|e| EnvError::InvalidState(format!("not an equigym state ({e})")))?;
        if saved.task != self.task.id() {
            return Err(EnvError::InvalidState(format!(
                "the state is from task '{}', this environment runs '{}'",
                saved.task,
                self.task.id()
            )));
        }
        Scene::trial_step(&saved.scene)?;
        let before = self.task.episode_params();
        self.task.set_episode_params(&mut self.scene, &saved.task_params)?;
        if let Err(e) = self.scene.restore(&saved.scene) {
            self.task.set_episode_params(&mut self.scene, &before)?;
            return Err(e);
        }
        self.rng = saved.rng;
        self.steps = saved.steps;
        self.in_episode = saved.in_episode;
        self.last_target = saved.last_target;
        Ok(())
    }
}
