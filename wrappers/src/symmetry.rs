//! A task's symmetry: the group with its action on observations, actions, action chunks,
//! latent noise and whole simulator states.
//!
//! The group rotates the scene about the world z axis through the table centre. Observations
//! and actions transform by the representations their field layouts declare (the paper's
//! appendix tables). The latent noise of the diffusion policy has exactly the action chunk's
//! layout. Acting on a simulator state moves every object, the hand and the fingers; the robot
//! base stays put, so the arm must reach the rotated hand: its reach and joint limits are what
//! break the symmetry.

use equigym_envs::robot::IkReport;
use equigym_envs::tasks::{make_task, TaskOptions};
use equigym_envs::{Env, EnvError, Layout};

use crate::error::Result;
use crate::group::{Group, PlanarRotation};
use crate::representation::Representation;

/// The point the group rotates about (the table centre, in world x, y).
pub const ROTATION_CENTRE: [f64; 2] = [0.0, 0.0];

/// Number of actions in a diffusion policy's action chunk (the paper's setting).
pub const DEFAULT_CHUNK_LEN: usize = 4;

/// The group action on everything a task exchanges with an agent.
#[derive(Clone, Debug)]
pub struct TaskSymmetry {
    pub task: String,
    pub group: Group,
    pub observation_layout: Layout,
    pub action_layout: Layout,
    pub chunk_layout: Layout,
    pub observation: Representation,
    pub action: Representation,
    /// Also the latent noise's representation.
    pub chunk: Representation,
}

impl TaskSymmetry {
    /// The symmetry of a task (its observation layout may depend on its options).
    pub fn new(task: &str, options: &TaskOptions, group: Group, chunk_len: usize) -> Result<Self> {
        let layout = make_task(task, options)?.observation_layout().clone();
        Self::from_layouts(task, layout, group, chunk_len)
    }

    /// The symmetry of an environment's task.
    pub fn for_env(env: &Env, group: Group, chunk_len: usize) -> Result<Self> {
        Self::from_layouts(env.task().id(), env.observation_layout().clone(), group, chunk_len)
    }

    fn from_layouts(task: &str, observation_layout: Layout, group: Group, chunk_len: usize) -> Result<Self> {
        if chunk_len == 0 {
            return Err(EnvError::InvalidConfig("the action chunk needs at least one action".into()).into());
        }
        let action_layout = Layout::action();
        let chunk_layout = action_layout.repeat(chunk_len);
        Ok(Self {
            task: task.to_string(),
            group,
            observation: Representation::from_layout(&observation_layout),
            action: Representation::from_layout(&action_layout),
            chunk: Representation::from_layout(&chunk_layout),
            observation_layout,
            action_layout,
            chunk_layout,
        })
    }

    pub fn chunk_len(&self) -> usize {
        self.chunk.dim() / self.action.dim()
    }

    /// g . obs (batched rows).
    pub fn act_observation(&self, g: &PlanarRotation, obs: &mut [f64]) -> Result<()> {
        self.observation.act_batch(g, obs)
    }
    /// g . action (batched rows of 10).
    pub fn act_action(&self, g: &PlanarRotation, action: &mut [f64]) -> Result<()> {
        self.action.act_batch(g, action)
    }
    /// g . chunk (batched rows of chunk_len x 10).
    pub fn act_chunk(&self, g: &PlanarRotation, chunk: &mut [f64]) -> Result<()> {
        self.chunk.act_batch(g, chunk)
    }
    /// g . w for latent noise (the chunk's representation).
    pub fn act_latent(&self, g: &PlanarRotation, latent: &mut [f64]) -> Result<()> {
        self.chunk.act_batch(g, latent)
    }
}

/// g . s: rotate the environment's whole state about the table centre (objects, hand and
/// fingers with their velocities; the arm re-solved for the moved hand, the base fixed).
/// Returns how well the arm reaches the rotated hand.
pub fn transform_state(env: &mut Env, g: &PlanarRotation) -> Result<IkReport> {
    Ok(env.transform_scene(&g.isometry(ROTATION_CENTRE))?)
}
