//! # equigym-agents: steering agents in pure Rust
//!
//! DSRL, Equi-DSRL and Approx-Equi-DSRL (soft actor-critic in the latent-noise space of an
//! equivariant diffusion policy) trained in-process on the Rust latent-action environments,
//! with bit-reproducible numerics:
//!
//! - [`nn`] (the `equigym-nn` crate): f32 / f64 kernels with one summation order per output;
//! - [`equi`]: bases of C8-equivariant linear maps between the task's rho0 / rho1 fields and
//!   regular hidden fields, expanded once per optimiser step;
//! - [`fourier`]: regular -> regular layers in the Fourier basis (14 instead of 64 multiply-adds
//!   per field pair), used by Equi-DSRL's hidden layers;
//! - [`net`]: networks over one parameter vector (plain, equivariant, RPP layers; LayerNorm,
//!   plain or field-tied; Tanh, ReLU; the invariant pooling head);
//! - [`models`]: each method's actor and twin critics, parameter-matched as the SB3 baselines;
//! - [`sac`]: the SAC update as SB3 runs it;
//! - [`replay`], [`rng`] (seeded streams with documented tags);
//! - [`run`]: the training loop with evaluation, `log.csv`, `train.csv` (the learner's state),
//!   checkpoints and resume.
//!
//! The `steer` binary and `python -m equigym.steer` are the command-line entry points.

pub use equigym_nn as nn;
/// The C8 Fourier-basis layers' kernels live with the other kernels, in `equigym-nn`.
pub use equigym_nn::fourier;

pub mod equi;
pub mod error;
pub mod evaluation;
pub mod gradcheck;
pub mod models;
pub mod net;
pub mod replay;
pub mod rng;
pub mod run;
pub mod sac;

pub use error::{Error, Result};
pub use evaluation::{evaluate_base, BaseEvaluation, EVAL_SEED, STALL_MOVE};
pub use models::Method;
pub use run::{run, Preset, RunConfig, RunSummary, TimeSplit};
