//! # equigym-envs
//!
//! Robot-manipulation tasks on rapier3d physics with a Panda-style arm loaded from a URDF,
//! usable standalone from Rust:
//!
//! ```no_run
//! use equigym_envs::{Env, EnvConfig, experts::{make_expert, ExpertOptions}};
//! let mut env = Env::new(EnvConfig::new("lift")).unwrap();
//! let mut expert = make_expert("lift", ExpertOptions::default()).unwrap();
//! env.reset(7).unwrap();
//! expert.reset(&env, 7);
//! for _ in 0..env.horizon() {
//!     let action = expert.act(&env);
//!     let step = env.step(&action).unwrap();
//!     if step.evaluation.success() { break; }
//! }
//! ```
//!
//! Modules by domain: [`robot`] (URDF, kinematics, IK, the articulated rig, arm controllers),
//! [`world`] (physics settings, table), [`scene`] (world + robot + servo loop), [`tasks`]
//! (Lift, ...), [`env`] (reset/step/state), [`batch`] (B environments on a thread pool,
//! auto-reset), [`options`] (the one options type and the read-only spec), [`rng`] (seed
//! streams and their tags), [`experts`] (scripted demonstrators), [`render`] (CPU ray caster),
//! [`layout`] (named observation slices).

pub mod batch;
pub mod env;
pub mod error;
pub mod experts;
pub mod layout;
pub mod math;
pub mod options;
pub mod render;
pub mod rng;
pub mod robot;
pub mod scene;
pub mod tasks;
pub mod world;

pub use batch::{AutoresetMode, BatchEnv, BatchMember, MemberStep};
pub use env::{Env, EnvConfig, StepResult, ACTION_DIM};
pub use error::{EnvError, Result};
pub use layout::Action;
pub use layout::{Field, FieldKind, Layout};
pub use options::{Controller, EnvOptions, EnvSpec};
pub use tasks::{RewardKind, TaskOptions};
pub use world::PhysicsConfig;
