//! Typed errors of the symmetry layer; environment errors pass through unchanged.

use equigym_envs::EnvError;
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum Error {
    /// An error of the underlying environment (shapes, NaN, call order, configuration).
    #[error(transparent)]
    Env(#[from] EnvError),
    /// A group or group element that does not exist.
    #[error("invalid group: {0}")]
    InvalidGroup(String),
    /// A policy file that is missing, corrupt, truncated or does not fit the task.
    #[error("policy {path}: {reason}")]
    Policy { path: String, reason: String },
    /// A policy file that does not exist.
    #[error("policy {0}: no such file")]
    PolicyNotFound(String),
}

pub type Result<T> = std::result::Result<T, Error>;
