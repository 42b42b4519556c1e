//! # equigym-wrappers
//!
//! The symmetry layer on top of `equigym-envs`:
//!
//! - [`group`]: SO(2) about the table centre and its cyclic subgroups C_N.
//! - [`representation`]: rho0 / rho1 representations on flat vectors, built from a task's
//!   field [`Layout`](equigym_envs::Layout).
//! - [`symmetry`]: a task's group action on observations, actions, action chunks, latent noise
//!   and simulator states.
//! - [`breaking`]: measuring how much a task breaks the symmetry (transition-invariance error,
//!   rotated demonstrations).
//! - [`edp`]: the exported equivariant diffusion policy (safetensors) and batched DDIM.
//! - [`latent`]: the latent-action MDP (DSRL): latent noise -> DDIM -> action chunk -> steps.
//! - [`steerability`]: how much the latent noise changes success, measured with the base policy
//!   (the diagnostic to run before training steering agents).
//!
//! ```no_run
//! use equigym_wrappers::{Group, TaskSymmetry};
//! use equigym_envs::{Env, EnvConfig};
//! let mut env = Env::new(EnvConfig::new("lift")).unwrap();
//! let sym = TaskSymmetry::for_env(&env, Group::cyclic(8).unwrap(), 4).unwrap();
//! let g = sym.group.element(1).unwrap(); // 45 degrees
//! let mut obs = env.reset(0).unwrap().to_vec();
//! sym.act_observation(&g, &mut obs).unwrap();
//! ```

pub mod breaking;
pub mod edp;
pub mod error;
pub mod group;
pub mod latent;
pub mod representation;
pub mod steerability;
pub mod symmetry;

pub use edp::DiffusionPolicy;
pub use equigym_envs as envs;
pub use error::{Error, Result};
pub use group::{Group, PlanarRotation};
pub use latent::{latent_batch, LatentBatchEnv, LatentDecoder, LatentEnv, LatentStep, DEFAULT_LATENT_BOUND};
pub use representation::{Block, Representation};
pub use symmetry::{transform_state, TaskSymmetry, DEFAULT_CHUNK_LEN, ROTATION_CENTRE};
