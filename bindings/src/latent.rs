//! Bindings of the latent-action environments, single and batched (the policy they decode with
//! is `policy.rs`).

use equigym_envs::AutoresetMode;
use equigym_envs::Env as RustEnv;
use equigym_wrappers::latent::{latent_batch, LatentBatchEnv, LatentEnv as RustLatentEnv, DEFAULT_LATENT_BOUND};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};

use crate::errors::{invalid_input, to_py};
use crate::options::{env_config, options_kwargs};
use crate::policy::{ddim_steps, policy_object, DiffusionPolicy};
use crate::{info_dict, Spec};

/// A task whose action is the diffusion policy's latent noise (see `equigym.latent`).
#[pyclass(module = "equigym._core", name = "LatentEnv")]
pub struct LatentEnv {
    inner: RustLatentEnv,
    policy: Py<DiffusionPolicy>,
}

#[pymethods]
impl LatentEnv {
    /// `task` driven through `policy` (a `DiffusionPolicy` or a path), with the options of
    /// `Env` as keyword arguments.
    #[new]
    #[pyo3(signature = (task, policy, *, bound=DEFAULT_LATENT_BOUND, ddim_steps=None, **options))]
    fn new(
        py: Python<'_>,
        task: &str,
        policy: &Bound<'_, PyAny>,
        bound: f64,
        ddim_steps: Option<usize>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let policy = policy_object(py, policy)?;
        let rust_policy = policy.get().inner.clone();
        let env = RustEnv::new(env_config(task, options)?).map_err(to_py)?;
        let steps = self::ddim_steps(&rust_policy, ddim_steps);
        Ok(Self { inner: RustLatentEnv::new(env, rust_policy, bound, steps).map_err(to_py)?, policy })
    }

    /// Pickling: the arguments that rebuild this environment (the policy pickles as its bytes) ...
    fn __getnewargs_ex__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyTuple>, Bound<'py, PyDict>)> {
        let args = PyTuple::new(
            py,
            [self.inner.env().task().id().into_pyobject(py)?.into_any(), self.policy.bind(py).clone().into_any()],
        )?;
        let kwargs = options_kwargs(py, self.inner.env().config())?;
        kwargs.set_item("bound", self.inner.bound())?;
        kwargs.set_item("ddim_steps", self.inner.ddim_steps())?;
        Ok((args, kwargs))
    }
    /// ... and the simulator's full state, so an unpickled copy continues bit for bit.
    fn __getstate__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        self.get_state(py)
    }
    fn __setstate__(&mut self, state: &[u8]) -> PyResult<()> {
        self.set_state(state)
    }

    /// The policy this environment denoises with.
    #[getter]
    fn policy(&self, py: Python<'_>) -> Py<DiffusionPolicy> {
        self.policy.clone_ref(py)
    }

    fn reset<'py>(&mut self, py: Python<'py>, seed: u64) -> PyResult<Bound<'py, PyArray1<f64>>> {
        Ok(self.inner.reset(seed).map_err(to_py)?.into_pyarray(py))
    }

    /// One latent step: (obs, reward, terminated, truncated, info); info has `success`
    /// (any primitive step), `executed` (primitive steps) and the task's terms.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        latent: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, f64, bool, bool, Bound<'py, PyDict>)> {
        let w = latent.as_slice().map_err(|e| invalid_input(format!("latent: {e}")))?.to_vec();
        let inner = &mut self.inner;
        let (r, obs) = py
            .detach(|| {
                let r = inner.step(&w)?;
                Ok::<_, equigym_wrappers::Error>((r, inner.env_mut().observe().to_vec()))
            })
            .map_err(to_py)?;
        let info = info_dict(py, &r.evaluation)?;
        info.set_item("success", r.success)?;
        info.set_item("is_success", r.success)?;
        info.set_item("executed", r.executed)?;
        Ok((obs.into_pyarray(py), r.reward, r.terminated, r.truncated, info))
    }

    /// The action chunk of `latent` at the current observation, without stepping.
    fn decode<'py>(
        &mut self,
        py: Python<'py>,
        latent: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let w = latent.as_slice().map_err(|e| invalid_input(format!("latent: {e}")))?.to_vec();
        Ok(self.inner.decode(&w).map_err(to_py)?.into_pyarray(py))
    }

    fn last_chunk<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.last_chunk().to_vec().into_pyarray(py)
    }
    fn observe<'py>(&mut self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.env_mut().observe().to_vec().into_pyarray(py)
    }
    fn get_state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        Ok(PyBytes::new(py, &self.inner.env().get_state().map_err(to_py)?))
    }
    fn set_state(&mut self, state: &[u8]) -> PyResult<()> {
        self.inner.env_mut().set_state(state).map_err(to_py)
    }
    /// The read-only description of the task environment.
    #[getter]
    fn spec(&self) -> Spec {
        Spec(self.inner.env().spec())
    }
    #[getter]
    fn task(&self) -> &'static str {
        self.inner.env().task().id()
    }
    #[getter]
    fn latent_dim(&self) -> usize {
        self.inner.latent_dim()
    }
    #[getter]
    fn chunk_len(&self) -> usize {
        self.inner.chunk_len()
    }
    #[getter]
    fn bound(&self) -> f64 {
        self.inner.bound()
    }
    #[getter]
    fn horizon(&self) -> usize {
        self.inner.env().horizon()
    }
    #[getter]
    fn elapsed_steps(&self) -> usize {
        self.inner.env().elapsed_steps()
    }
    #[getter]
    fn observation_dim(&self) -> usize {
        self.inner.env().observation_layout().dim()
    }
}

/// B latent-action environments behind one batched `reset` / `step`: one batched DDIM for all
/// B latent actions, then the chunks run in parallel (see `equigym.latent.EquiLatentVectorEnv`).
#[pyclass(module = "equigym._core", name = "LatentVecEnv")]
pub struct LatentVecEnv {
    inner: LatentBatchEnv,
    /// The task environments' read-only description.
    spec: equigym_envs::EnvSpec,
    stepping: f64,
}

crate::vector::batch_properties!(LatentVecEnv, "latent actions");

#[pymethods]
impl LatentVecEnv {
    /// `num_envs` latent environments of `task` sharing `policy`, with the options of `Env` as
    /// keyword arguments.
    #[new]
    #[pyo3(signature = (task, policy, num_envs, *, threads=0, autoreset_mode="next_step", bound=DEFAULT_LATENT_BOUND, ddim_steps=None, **options))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        task: &str,
        policy: &Bound<'_, PyAny>,
        num_envs: usize,
        threads: usize,
        autoreset_mode: &str,
        bound: f64,
        ddim_steps: Option<usize>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        if num_envs == 0 {
            return Err(invalid_input("num_envs must be at least 1"));
        }
        let mode = autoreset_mode.parse::<AutoresetMode>().map_err(to_py)?;
        let policy = policy_object(py, policy)?.get().inner.clone();
        let steps = self::ddim_steps(&policy, ddim_steps);
        let config = env_config(task, options)?;
        let envs = (0..num_envs)
            .map(|_| {
                let env = RustEnv::new(config.clone())?;
                RustLatentEnv::new(env, policy.clone(), bound, steps)
            })
            .collect::<Result<Vec<_>, equigym_wrappers::Error>>()
            .map_err(to_py)?;
        let spec = envs[0].env().spec();
        Ok(Self { inner: latent_batch(envs, threads, mode).map_err(to_py)?, spec, stepping: 0.0 })
    }

    /// Primitive steps each environment's last latent step executed (0 where it was reset).
    fn executed<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        (0..self.inner.num_envs())
            .map(|i| {
                let skipped =
                    self.inner.was_reset(i) == Some(true) && self.inner.autoreset_mode() == AutoresetMode::NextStep;
                if skipped {
                    0
                } else {
                    self.inner.env(i).map_or(0, |e| e.last_executed() as u64)
                }
            })
            .collect::<Vec<_>>()
            .into_pyarray(py)
    }

    /// The action chunks the last step executed, (B, latent_dim) absolute actions.
    fn last_chunks<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let flat: Vec<f64> = self.inner.envs().flat_map(|e| e.last_chunk().to_vec()).collect();
        numpy::ndarray::Array2::from_shape_vec((self.inner.num_envs(), self.inner.action_dim()), flat)
            .map(|a| a.into_pyarray(py))
            .map_err(|e| invalid_input(e.to_string()))
    }

    #[getter]
    fn latent_dim(&self) -> usize {
        self.inner.action_dim()
    }
    #[getter]
    fn chunk_len(&self) -> usize {
        self.inner.env(0).map_or(0, |e| e.chunk_len())
    }
    #[getter]
    fn bound(&self) -> f64 {
        self.inner.env(0).map_or(0.0, |e| e.bound())
    }
}
