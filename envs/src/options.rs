//! [`EnvOptions`]: everything a user may set when building an environment, declared once.
//!
//! Every front end (the Python `Env`, `VecEnv`, `LatentEnv` and `LatentVecEnv`, Rust callers,
//! pickled environments) builds its [`EnvConfig`] from this one type, so an option added here
//! reaches all of them. It derives serde with `deny_unknown_fields` (an unknown or misspelt
//! option is an error, never silently dropped) and `default` (only the options given change);
//! `physics` is a partial [`PhysicsConfig`] deserialised the same way, so new physics fields need
//! no edit here or in the bindings.
//!
//! [`EnvSpec`] is the small read-only description of a built environment (task, horizon,
//! dimensions, bounds, layouts) that vector environments answer metadata queries from.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::error::{EnvError, Result};
use crate::layout::{Layout, ACTION_DIM};
pub use crate::robot::Controller;
use crate::tasks::{RewardKind, TaskOptions};
use crate::PhysicsConfig;

/// Std of the Gaussian noise added to the home joint configuration at reset (rad), by default.
pub const DEFAULT_INIT_JOINT_NOISE: f64 = 0.02;

/// How an environment is built.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvConfig {
    pub task: String,
    pub reward: RewardKind,
    pub physics: PhysicsConfig,
    /// The arm controller.
    pub controller: Controller,
    /// A URDF to load instead of the shipped Panda.
    pub urdf: Option<PathBuf>,
    /// Std of the Gaussian noise added to the home joint configuration at reset (rad).
    pub init_joint_noise: f64,
    /// Episode length override (control steps).
    pub horizon: Option<usize>,
    pub task_options: TaskOptions,
}

impl EnvConfig {
    pub fn new(task: &str) -> Self {
        Self {
            task: task.to_string(),
            reward: RewardKind::Sparse,
            physics: PhysicsConfig::default(),
            controller: Controller::Joint,
            urdf: None,
            init_joint_noise: DEFAULT_INIT_JOINT_NOISE,
            horizon: None,
            task_options: TaskOptions::default(),
        }
    }
}

/// How an environment is configured (see the module documentation). Field names are the
/// keyword arguments of the Python environments.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvOptions {
    /// `"sparse"` (1 on success) or `"dense"` (shaped, in [0, 1]).
    #[serde(serialize_with = "reward_to_str", deserialize_with = "reward_from_str")]
    pub reward: RewardKind,
    /// A URDF file to load instead of the shipped Panda.
    pub urdf: Option<PathBuf>,
    /// Enforce the arm's joint limits (`None`: the value in `physics`, on by default).
    pub joint_limits: Option<bool>,
    /// The arm controller (`None`: joint-space).
    pub controller: Option<Controller>,
    /// Std of the noise added to the home joint configuration at reset (rad).
    pub init_joint_noise: f64,
    /// Episode length in control steps (`None`: the task's).
    pub horizon: Option<usize>,
    /// Overrides of the physics and actuation settings (a partial [`PhysicsConfig`]).
    pub physics: PhysicsConfig,
    /// Overrides of the initial-state ranges, name -> (low, high).
    pub ranges: BTreeMap<String, (f64, f64)>,
    /// Reset distribution (`"D0"`, `"D1"`, `"D2"`; `None`: the task's default).
    pub variant: Option<String>,
}

impl Default for EnvOptions {
    fn default() -> Self {
        Self {
            reward: RewardKind::Sparse,
            urdf: None,
            joint_limits: None,
            controller: None,
            init_joint_noise: DEFAULT_INIT_JOINT_NOISE,
            horizon: None,
            physics: PhysicsConfig::default(),
            ranges: BTreeMap::new(),
            variant: None,
        }
    }
}

fn reward_to_str<S: Serializer>(reward: &RewardKind, s: S) -> std::result::Result<S::Ok, S::Error> {
    s.serialize_str(match reward {
        RewardKind::Sparse => "sparse",
        RewardKind::Dense => "dense",
    })
}

fn reward_from_str<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<RewardKind, D::Error> {
    String::deserialize(d)?.parse().map_err(serde::de::Error::custom)
}

impl EnvOptions {
    /// Whether the arm's joint limits are enforced: the option, else the physics setting.
    pub fn joint_limits_on(&self) -> bool {
        self.joint_limits.unwrap_or(self.physics.joint_limits)
    }

    /// The arm controller: the option, else joint-space.
    pub fn arm_controller(&self) -> Controller {
        self.controller.unwrap_or_default()
    }

    /// The configuration of `task` with these options.
    pub fn into_config(self, task: &str) -> Result<EnvConfig> {
        let mut physics = self.physics.clone();
        physics.joint_limits = self.joint_limits_on();
        if self.horizon == Some(0) {
            return Err(EnvError::InvalidConfig("horizon must be positive".into()));
        }
        Ok(EnvConfig {
            task: task.to_string(),
            reward: self.reward,
            physics,
            controller: self.arm_controller(),
            urdf: self.urdf,
            init_joint_noise: self.init_joint_noise,
            horizon: self.horizon,
            task_options: TaskOptions {
                variant: self.variant,
                ranges: self.ranges.into_iter().map(|(name, (lo, hi))| (name, lo, hi)).collect(),
            },
        })
    }

    /// The options that rebuild `config` (for pickling and copies).
    pub fn from_config(config: &EnvConfig) -> Self {
        Self {
            reward: config.reward,
            urdf: config.urdf.clone(),
            joint_limits: None,
            controller: Some(config.controller),
            init_joint_noise: config.init_joint_noise,
            horizon: config.horizon,
            physics: config.physics.clone(),
            ranges: config.task_options.ranges.iter().map(|(n, lo, hi)| (n.clone(), (*lo, *hi))).collect(),
            variant: config.task_options.variant.clone(),
        }
    }
}

/// What a built environment is, without the simulator: read-only metadata (see
/// `Env::spec`). Vector environments keep one instead of a probe environment.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvSpec {
    pub task: &'static str,
    /// Episode length in control steps.
    pub horizon: usize,
    /// Seconds per control step.
    pub control_period: f64,
    pub max_gripper_width: f64,
    /// Lower and upper bounds of the raw action.
    pub action_low: [f64; ACTION_DIM],
    pub action_high: [f64; ACTION_DIM],
    pub observation_layout: Layout,
    pub action_layout: Layout,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_match_the_config_defaults() {
        let built = EnvOptions::default().into_config("lift").unwrap();
        assert_eq!(built, EnvConfig::new("lift"));
    }

    #[test]
    fn options_round_trip_through_a_config() {
        let mut options = EnvOptions { horizon: Some(9), variant: Some("D0".into()), ..EnvOptions::default() };
        options.ranges.insert("cube_xy".into(), (-0.01, 0.01));
        options.physics.substeps = 7;
        let config = options.clone().into_config("stack").unwrap();
        assert_eq!(config.physics.substeps, 7);
        assert_eq!(EnvOptions::from_config(&config).into_config("stack").unwrap(), config);
    }

    #[test]
    fn switches_override_physics_and_zero_horizon_is_refused() {
        let mut options =
            EnvOptions { joint_limits: Some(false), controller: Some(Controller::Cartesian), ..Default::default() };
        let config = options.clone().into_config("lift").unwrap();
        assert!(!config.physics.joint_limits && config.controller == Controller::Cartesian);
        options.horizon = Some(0);
        assert!(matches!(options.into_config("lift"), Err(EnvError::InvalidConfig(_))));
    }
}
