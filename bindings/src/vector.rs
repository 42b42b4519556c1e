//! `equigym._core.VecEnv`: B environments stepped in Rust per call (see `equigym_envs::batch`).
//!
//! One call crosses the Python boundary per batch: actions come in as one (B, action_dim)
//! float64 array, observations go out as one (B, obs_dim) float32 array, and the GIL is
//! released while the environments step on the batch's thread pool.

use std::time::Instant;

use equigym_envs::batch::ActionDecoder;
use equigym_envs::{AutoresetMode, BatchEnv, BatchMember, Env as RustEnv, EnvSpec};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{invalid_input, to_py};
use crate::options::env_config;

/// What `step` returns: (obs, rewards, terminated, truncated, success, reset, final_obs).
pub(crate) type StepOut<'py> = (
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Option<Bound<'py, PyArray2<f32>>>,
);

/// B environments of one task behind a single batched `reset` / `step`
/// (see `equigym.vector.EquiVectorEnv` for the gymnasium interface built on it).
#[pyclass(module = "equigym._core", name = "VecEnv")]
pub struct VecEnv {
    inner: BatchEnv,
    /// What the environments are (task, horizon, bounds, layouts), read-only.
    spec: EnvSpec,
    /// Seconds spent inside the Rust batched step (GIL released), for overhead measurements.
    stepping: f64,
}

pub(crate) fn obs_array<'a, E: BatchMember, D: ActionDecoder>(
    batch: &'a BatchEnv<E, D>,
    rows: impl Fn(usize) -> Option<&'a [f64]>,
) -> Array2<f32> {
    let (n, d) = (batch.num_envs(), batch.observation_dim());
    let mut out = Array2::<f32>::zeros((n, d));
    for (i, mut row) in out.rows_mut().into_iter().enumerate() {
        if let Some(values) = rows(i) {
            for (o, &x) in row.iter_mut().zip(values) {
                *o = x as f32;
            }
        }
    }
    out
}

/// A (B, dim) array as one row-major vector.
fn flat_rows(a: &PyReadonlyArray2<'_, f64>) -> Vec<f64> {
    match a.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => a.as_array().iter().copied().collect(),
    }
}

/// Reset a batch (all, or where `mask` is true) with the GIL released; the observations.
pub(crate) fn reset_batch<'py, E: BatchMember, D: ActionDecoder>(
    py: Python<'py>,
    batch: &mut BatchEnv<E, D>,
    seeds: Vec<u64>,
    mask: Option<Vec<bool>>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    py.detach(|| match mask {
        None => batch.reset(&seeds),
        Some(mask) => batch.reset_masked(&seeds, &mask),
    })
    .map_err(to_py)?;
    Ok(obs_array(batch, |i| batch.obs(i)).into_pyarray(py))
}

/// Step a batch with a (B, action_dim) array (`what` names the actions in the shape error) with
/// the GIL released, adding the seconds spent in Rust to `stepping`.
pub(crate) fn step_batch<'py, E: BatchMember, D: ActionDecoder>(
    py: Python<'py>,
    batch: &mut BatchEnv<E, D>,
    what: &str,
    actions: PyReadonlyArray2<'py, f64>,
    stepping: &mut f64,
) -> PyResult<StepOut<'py>> {
    let shape = actions.shape();
    let (n, dim) = (batch.num_envs(), batch.action_dim());
    if shape != [n, dim] {
        return Err(invalid_input(format!("{what} must have shape ({n}, {dim}), got {shape:?}")));
    }
    let flat = flat_rows(&actions);
    let (result, secs) = py.detach(|| {
        let start = Instant::now();
        let result = batch.step(&flat);
        (result, start.elapsed().as_secs_f64())
    });
    *stepping += secs;
    result.map_err(to_py)?;
    Ok(step_outputs(py, batch))
}

/// The arrays a batched step returns (see `VecEnv.step`).
fn step_outputs<'py, E: BatchMember, D: ActionDecoder>(py: Python<'py>, b: &BatchEnv<E, D>) -> StepOut<'py> {
    let n = b.num_envs();
    let obs = obs_array(b, |i| b.obs(i));
    let steps: Vec<_> = (0..n).map(|i| b.last_step(i).unwrap_or_default()).collect();
    let reset: Vec<bool> = (0..n).map(|i| b.was_reset(i).unwrap_or_default()).collect();
    let final_obs = (b.autoreset_mode() == AutoresetMode::SameStep && reset.iter().any(|r| *r))
        .then(|| obs_array(b, |i| b.final_obs(i)).into_pyarray(py));
    (
        obs.into_pyarray(py),
        steps.iter().map(|s| s.reward).collect::<Vec<_>>().into_pyarray(py),
        steps.iter().map(|s| s.terminated).collect::<Vec<_>>().into_pyarray(py),
        steps.iter().map(|s| s.truncated).collect::<Vec<_>>().into_pyarray(py),
        steps.iter().map(|s| s.success).collect::<Vec<_>>().into_pyarray(py),
        reset.into_pyarray(py),
        final_obs,
    )
}

/// The methods and properties every batched environment class shares, defined once: the class
/// holds the batch as `inner` (a [`BatchEnv`] of any member), its task's `spec` and the
/// `stepping` clock; `$what` names its actions in error messages. (A second `#[pymethods]`
/// block per class: pyo3's `multiple-pymethods` feature.)
macro_rules! batch_properties {
    ($class:ty, $what:literal) => {
        #[pymethods]
        impl $class {
            /// Reset the environments (all, or those where `mask` is true) with one seed each;
            /// returns the observations, (B, obs_dim) float32.
            #[pyo3(signature = (seeds, mask=None))]
            fn reset<'py>(
                &mut self,
                py: Python<'py>,
                seeds: Vec<u64>,
                mask: Option<Vec<bool>>,
            ) -> PyResult<Bound<'py, PyArray2<f32>>> {
                $crate::vector::reset_batch(py, &mut self.inner, seeds, mask)
            }

            /// Step all B environments with a (B, action_dim) float64 array:
            /// (obs, rewards, terminated, truncated, success, reset, final_obs).
            /// `reset[i]`: environment i was reset during this call (next_step: its action was
            /// ignored and obs is its reset observation; same_step: its episode ended, obs is the
            /// reset observation and `final_obs[i]` the last one of the ended episode).
            /// `final_obs` is None in next_step mode or when nothing ended.
            fn step<'py>(
                &mut self,
                py: Python<'py>,
                actions: PyReadonlyArray2<'py, f64>,
            ) -> PyResult<$crate::vector::StepOut<'py>> {
                $crate::vector::step_batch(py, &mut self.inner, $what, actions, &mut self.stepping)
            }

            /// Current observations, (B, obs_dim) float32.
            fn observe<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
                $crate::vector::obs_array(&self.inner, |i| self.inner.obs(i)).into_pyarray(py)
            }

            /// Seed of each environment's current episode (a single env's `reset(seed)`
            /// reproduces it).
            fn episode_seeds<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
                self.inner.episode_seeds().into_pyarray(py)
            }

            /// Total seconds spent inside the Rust batched step since construction (or the last
            /// assignment, e.g. `core.stepping_seconds = 0.0`); the rest of a step's time is Python.
            #[getter]
            fn stepping_seconds(&self) -> f64 {
                self.stepping
            }
            #[setter]
            fn set_stepping_seconds(&mut self, value: f64) {
                self.stepping = value;
            }
            #[getter]
            fn num_envs(&self) -> usize {
                self.inner.num_envs()
            }
            #[getter]
            fn threads(&self) -> usize {
                self.inner.threads()
            }
            #[getter]
            fn autoreset_mode(&self) -> &'static str {
                self.inner.autoreset_mode().as_str()
            }
            /// The read-only description shared by every environment of the batch.
            #[getter]
            fn spec(&self) -> $crate::Spec {
                $crate::Spec(self.spec.clone())
            }
            #[getter]
            fn task(&self) -> &'static str {
                self.spec.task
            }
            #[getter]
            fn horizon(&self) -> usize {
                self.spec.horizon
            }
            #[getter]
            fn observation_dim(&self) -> usize {
                self.inner.observation_dim()
            }
        }
    };
}
pub(crate) use batch_properties;

batch_properties!(VecEnv, "actions");

#[pymethods]
impl VecEnv {
    /// `num_envs` environments of `task` with the options of `Env` as keyword arguments.
    #[new]
    #[pyo3(signature = (task, num_envs, *, threads=0, autoreset_mode="next_step", **options))]
    fn new(
        task: &str,
        num_envs: usize,
        threads: usize,
        autoreset_mode: &str,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        if num_envs == 0 {
            return Err(invalid_input("num_envs must be at least 1"));
        }
        let mode = autoreset_mode.parse::<AutoresetMode>().map_err(to_py)?;
        let config = env_config(task, options)?;
        let envs = (0..num_envs).map(|_| RustEnv::new(config.clone())).collect::<Result<Vec<_>, _>>().map_err(to_py)?;
        let spec = envs[0].spec();
        Ok(Self { inner: BatchEnv::new(envs, threads, mode).map_err(to_py)?, spec, stepping: 0.0 })
    }

    /// The actions that hold every robot where it is, (B, action_dim) float64.
    fn current_targets<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let flat: Vec<f64> = self.inner.envs().flat_map(|e| e.current_target()).collect();
        let a = Array2::from_shape_vec((self.inner.num_envs(), equigym_envs::ACTION_DIM), flat)
            .map_err(|e| invalid_input(e.to_string()))?;
        Ok(a.into_pyarray(py))
    }

    /// The full state of environment `i` (as `Env.get_state`).
    fn get_state<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Bound<'py, pyo3::types::PyBytes>> {
        let env = self.inner.env(i).ok_or_else(|| invalid_input(format!("environment index {i} out of range")))?;
        Ok(pyo3::types::PyBytes::new(py, &env.get_state().map_err(to_py)?))
    }

    #[getter]
    fn action_dim(&self) -> usize {
        self.inner.action_dim()
    }
}
