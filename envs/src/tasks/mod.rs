//! Tasks. A task is a small type with the hooks of a ManiSkill3 task: it loads its objects into
//! the scene, samples an episode's initial state, observes, evaluates success and computes the
//! reward. Adding a task touches its own module plus one line in [`make_task`].

pub mod common;
pub mod lift;
pub mod square;
pub mod stack;
pub mod tabletop;

use nalgebra::{Isometry3, Vector3};
use rapier3d::prelude::{ColliderHandle, RigidBodyHandle};

use crate::error::{EnvError, Result};
use crate::layout::Layout;
use crate::rng::EpisodeRng;
use crate::scene::Scene;
use crate::world::TableSpec;

/// Where the robot and table stand for a task.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneSpec {
    pub table: TableSpec,
    /// Pose of the robot base in the world.
    pub robot_base: Isometry3<f64>,
    /// Joint configuration at the start of an episode (before noise).
    pub home_q: Vec<f64>,
}

/// A movable object of a task, exposed to experts, renderers and symmetry tools.
#[derive(Clone, Debug, PartialEq)]
pub struct TaskObject {
    pub name: &'static str,
    pub body: RigidBodyHandle,
    pub colliders: Vec<ColliderHandle>,
    /// Half extents of the object's bounding box in its own frame.
    pub half_extents: Vector3<f64>,
}

/// What a task measured of a state, typed per task: the one source of its success, of the
/// named terms that `info` reports and of its shaped reward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Measures {
    Lift(lift::LiftMeasures),
    Stack(stack::StackMeasures),
    Square(square::SquareMeasures),
}

impl Measures {
    /// Whether the state is a success.
    pub fn success(&self) -> bool {
        match self {
            Measures::Lift(m) => m.success(),
            Measures::Stack(m) => m.success(),
            Measures::Square(m) => m.success(),
        }
    }

    /// The measurements by name, as `info` reports them (booleans as 0 / 1).
    pub fn terms(&self) -> Vec<(&'static str, f64)> {
        match self {
            Measures::Lift(m) => m.terms(),
            Measures::Stack(m) => m.terms(),
            Measures::Square(m) => m.terms(),
        }
    }

    /// The shaped reward of the state, in [0, 1] (1 on success; robosuite's staging).
    pub fn dense_reward(&self) -> f64 {
        match self {
            Measures::Lift(m) => m.dense_reward(),
            Measures::Stack(m) => m.dense_reward(),
            Measures::Square(m) => m.dense_reward(),
        }
    }
}

/// The outcome of [`Task::evaluate`]: what the task measured, success derived from it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Evaluation {
    pub measures: Measures,
}

impl From<Measures> for Evaluation {
    fn from(measures: Measures) -> Self {
        Self { measures }
    }
}

impl Evaluation {
    /// Whether the state is a success.
    pub fn success(&self) -> bool {
        self.measures.success()
    }

    /// The reward of `kind` for this state.
    pub fn reward(&self, kind: RewardKind) -> f64 {
        match kind {
            RewardKind::Sparse => self.success() as u8 as f64,
            RewardKind::Dense => self.measures.dense_reward(),
        }
    }
}

/// Which reward an environment returns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RewardKind {
    /// 1 on success, 0 otherwise.
    Sparse,
    /// A shaped reward in [0, 1] (robosuite-style reaching, grasping and lifting terms).
    Dense,
}

impl std::str::FromStr for RewardKind {
    type Err = EnvError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "sparse" => Ok(RewardKind::Sparse),
            "dense" => Ok(RewardKind::Dense),
            other => Err(EnvError::InvalidConfig(format!("reward must be 'sparse' or 'dense', got '{other}'"))),
        }
    }
}

/// The hooks every task implements.
pub trait Task: Send + Sync {
    /// Short identifier ("lift").
    fn id(&self) -> &'static str;
    /// Episode length in control steps (the table-top tasks' shared [`tabletop::HORIZON`]).
    fn horizon(&self) -> usize {
        tabletop::HORIZON
    }
    /// Names, slices and representations of the observation.
    fn observation_layout(&self) -> &Layout;
    /// Table and robot placement.
    fn scene_spec(&self) -> SceneSpec;
    /// Add the task's objects to a fresh scene.
    fn load_scene(&mut self, scene: &mut Scene);
    /// Sample the objects' initial state for a new episode.
    fn initialise_episode(&mut self, scene: &mut Scene, rng: &mut EpisodeRng);
    /// Write the observation (length = the layout's dimension).
    fn observe(&self, scene: &Scene, out: &mut [f64]);
    /// Success and the task's measurements (from which `info` and the dense reward come).
    fn evaluate(&self, scene: &Scene) -> Evaluation;
    /// The task's movable objects.
    fn objects(&self) -> &[TaskObject];
    /// Per-episode parameters that live outside the physics state (object sizes), for saving.
    /// Tasks whose episodes differ only in poses have none.
    fn episode_params(&self) -> Vec<f64> {
        Vec::new()
    }
    /// Restore parameters saved by [`Task::episode_params`] after the physics state (which
    /// already holds the matching shapes) has been restored.
    fn set_episode_params(&mut self, _scene: &mut Scene, params: &[f64]) -> Result<()> {
        if params.is_empty() {
            Ok(())
        } else {
            Err(EnvError::InvalidState(format!("task '{}' has no episode parameters, got {params:?}", self.id())))
        }
    }
}

/// Task options shared by the registry.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct TaskOptions {
    /// Reset distribution variant ("D0", "D1", "D2"; MimicGen's naming), None = the task's default.
    pub variant: Option<String>,
    /// Override of the initial-state ranges: (name, low, high) pairs, task-specific names.
    pub ranges: Vec<(String, f64, f64)>,
}

/// All task ids.
pub const TASK_IDS: &[&str] = &["lift", "stack", "square"];

/// Build a task by id.
pub fn make_task(id: &str, options: &TaskOptions) -> Result<Box<dyn Task>> {
    match id {
        "lift" => Ok(Box::new(lift::Lift::new(options)?)),
        "stack" => Ok(Box::new(stack::Stack::new(options)?)),
        "square" => Ok(Box::new(square::Square::new(options)?)),
        other => Err(EnvError::InvalidConfig(format!("unknown task '{other}'; known tasks: {TASK_IDS:?}"))),
    }
}

/// A named sampling range that callers may override.
pub(crate) fn range_option(options: &TaskOptions, name: &str, default: (f64, f64)) -> Result<(f64, f64)> {
    match options.ranges.iter().find(|(n, _, _)| n == name) {
        None => Ok(default),
        Some((_, lo, hi)) if lo.is_finite() && hi.is_finite() && lo <= hi => Ok((*lo, *hi)),
        Some((_, lo, hi)) => {
            Err(EnvError::InvalidConfig(format!("range '{name}' = [{lo}, {hi}] is not a finite interval")))
        }
    }
}

/// Reject range names a task does not know.
pub(crate) fn check_range_names(task: &str, options: &TaskOptions, known: &[&str]) -> Result<()> {
    for (name, _, _) in &options.ranges {
        if !known.contains(&name.as_str()) {
            return Err(EnvError::InvalidConfig(format!("{task} has no range '{name}' (known: {})", known.join(", "))));
        }
    }
    Ok(())
}

/// The variant a task runs, checked against the ones it offers.
pub(crate) fn variant<'a>(task: &str, options: &'a TaskOptions, default: &'a str, offered: &[&str]) -> Result<&'a str> {
    let v = options.variant.as_deref().unwrap_or(default);
    if offered.contains(&v) {
        Ok(v)
    } else {
        Err(EnvError::InvalidConfig(format!("{task} has no variant '{v}' (offered: {})", offered.join(", "))))
    }
}
