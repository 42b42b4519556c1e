//! Typed errors of the agents: bad options, checkpoints that do not fit, I/O, and errors of the
//! environment and symmetry layers passed through. The agents never panic on user input.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum Error {
    /// An error of the symmetry layer, the diffusion policy or the environment.
    #[error(transparent)]
    Wrappers(#[from] equigym_wrappers::Error),
    /// An option with a value the agents cannot use.
    #[error("invalid option: {0}")]
    InvalidOption(String),
    /// A checkpoint that cannot be read or was written by another run configuration.
    #[error("checkpoint {path}: {reason}")]
    Checkpoint { path: String, reason: String },
    /// A file or directory that cannot be written or read.
    #[error("{path}: {reason}")]
    Io { path: String, reason: String },
    /// Training produced a non-finite number (a diverged run).
    #[error("training diverged: {0}")]
    Diverged(String),
}

impl From<equigym_envs::EnvError> for Error {
    fn from(e: equigym_envs::EnvError) -> Self {
        Error::Wrappers(e.into())
    }
}

pub type Result<T> = std::result::Result<T, Error>;

pub(crate) fn io_err(path: &std::path::Path, e: impl std::fmt::Display) -> Error {
    Error::Io { path: path.display().to_string(), reason: e.to_string() }
}
