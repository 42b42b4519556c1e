//! The one mapping from the Rust crates' typed errors to Python exceptions.
//!
//! The exception classes live in Python (`equigym.errors`), so that they pickle by reference,
//! may have two bases (e.g. `ResetNeeded` is an `EquigymError` and a `RuntimeError`) and are the
//! same objects as `equigym.EquigymError`, ... Nothing else in the bindings builds a Python
//! exception: Rust errors go through [`to_py`], and inputs the bindings themselves check go
//! through [`invalid_input`].

use equigym_agents::Error as AgentsError;
use equigym_envs::EnvError;
use equigym_wrappers::Error as WrappersError;
use pyo3::prelude::*;

pyo3::import_exception!(equigym.errors, InvalidInputError);
pyo3::import_exception!(equigym.errors, UrdfError);
pyo3::import_exception!(equigym.errors, InvalidStateError);
pyo3::import_exception!(equigym.errors, ResetNeeded);
pyo3::import_exception!(equigym.errors, PolicyError);
pyo3::import_exception!(equigym.errors, MissingFileError);
pyo3::import_exception!(equigym.errors, EquigymIOError);
pyo3::import_exception!(equigym.errors, PhysicsError);

/// `errno` of a missing file (POSIX `ENOENT`), for `FileNotFoundError`'s `errno` attribute.
const ENOENT: i32 = 2;

/// Every Rust error the bindings can meet.
pub(crate) enum Error {
    Env(EnvError),
    Wrappers(WrappersError),
    Agents(AgentsError),
}

impl From<AgentsError> for Error {
    fn from(e: AgentsError) -> Self {
        match e {
            AgentsError::Wrappers(w) => w.into(),
            other => Error::Agents(other),
        }
    }
}

impl From<EnvError> for Error {
    fn from(e: EnvError) -> Self {
        Error::Env(e)
    }
}

impl From<WrappersError> for Error {
    fn from(e: WrappersError) -> Self {
        match e {
            WrappersError::Env(e) => Error::Env(e),
            other => Error::Wrappers(other),
        }
    }
}

fn missing_file(message: String, path: String) -> PyErr {
    MissingFileError::new_err((ENOENT, message, path))
}

/// The Python exception for a Rust error (see `equigym.errors` for the classes).
pub(crate) fn to_py(e: impl Into<Error>) -> PyErr {
    match e.into() {
        Error::Env(e) => {
            let message = e.to_string();
            match e {
                EnvError::WrongLength { .. } | EnvError::NonFinite { .. } | EnvError::InvalidConfig(_) => {
                    InvalidInputError::new_err(message)
                }
                EnvError::CallOrder(_) => ResetNeeded::new_err(message),
                EnvError::Urdf { .. } => UrdfError::new_err(message),
                EnvError::FileNotFound { path, .. } => missing_file(message, path),
                EnvError::InvalidState(_) => InvalidStateError::new_err(message),
                EnvError::Io(_) => EquigymIOError::new_err(message),
                EnvError::Physics(_) => PhysicsError::new_err(message),
            }
        }
        Error::Wrappers(e) => {
            let message = e.to_string();
            match e {
                WrappersError::Env(e) => to_py(e),
                WrappersError::InvalidGroup(_) => InvalidInputError::new_err(message),
                WrappersError::Policy { .. } => PolicyError::new_err(message),
                WrappersError::PolicyNotFound(path) => missing_file(message, path),
            }
        }
        Error::Agents(e) => {
            let message = e.to_string();
            match e {
                AgentsError::Wrappers(w) => to_py(w),
                AgentsError::InvalidOption(_) => InvalidInputError::new_err(message),
                AgentsError::Checkpoint { .. } => InvalidStateError::new_err(message),
                AgentsError::Io { .. } | AgentsError::Diverged(_) => EquigymIOError::new_err(message),
            }
        }
    }
}

/// An input the bindings check themselves (array shapes, indices, option values).
pub(crate) fn invalid_input(message: impl Into<String>) -> PyErr {
    InvalidInputError::new_err(message.into())
}
