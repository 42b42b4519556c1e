//! Typed errors. The crate never panics on user input: every fallible call returns [`EnvError`].

use thiserror::Error;

/// Everything that can go wrong when building or driving an environment.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum EnvError {
    /// An array had the wrong number of elements.
    #[error("{what}: expected {expected} values, got {got}")]
    WrongLength { what: String, expected: usize, got: usize },
    /// An input contained NaN or infinity.
    #[error("{what}: element {index} is not finite ({value})")]
    NonFinite { what: String, index: usize, value: f64 },
    /// A method was called before the environment was ready for it.
    #[error("{0}")]
    CallOrder(String),
    /// A configuration value is outside its allowed set or range.
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    /// The robot description could not be used.
    #[error("robot description {source_name}: {reason}")]
    Urdf { source_name: String, reason: String },
    /// A saved state could not be restored.
    #[error("invalid state: {0}")]
    InvalidState(String),
    /// A file that an option names does not exist (e.g. a URDF path).
    #[error("{what} {path}: no such file")]
    FileNotFound { what: String, path: String },
    /// The physics engine failed inside a step (it can only meet a state it could not have
    /// produced itself, e.g. from hand-made state bytes); the episode has ended.
    #[error("physics engine failure ({0}); the episode has ended, call reset()")]
    Physics(String),
    /// Writing an image failed.
    #[error("i/o error: {0}")]
    Io(String),
}

/// Result alias used throughout the crate.
pub type Result<T> = std::result::Result<T, EnvError>;

/// Check a slice's length and that every element is finite.
pub fn check_finite(what: &str, values: &[f64], expected_len: usize) -> Result<()> {
    if values.len() != expected_len {
        return Err(EnvError::WrongLength { what: what.into(), expected: expected_len, got: values.len() });
    }
    if let Some((index, value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(EnvError::NonFinite { what: what.into(), index, value: *value });
    }
    Ok(())
}
