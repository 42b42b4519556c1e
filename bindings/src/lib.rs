//! `equigym._core`: thin pyo3 bindings over `equigym-envs` and `equigym-wrappers`.
//!
//! This crate only converts types and errors; every behaviour lives in the Rust crates.
//! - Options: one conversion of keyword arguments into the one options type
//!   (`equigym_envs::EnvOptions`), in [`options`]; every environment class takes it.
//! - Errors: one mapping from the crates' typed errors to the exception classes of
//!   `equigym.errors` (all subclasses of `EquigymError`), in [`errors`].
//! - Metadata: from `equigym_envs::EnvSpec`, a read-only description (no extra simulator).
//! - Pickling: environments pickle as their options plus their bit-exact `get_state` bytes;
//!   diffusion policies as the bytes of their file.

mod errors;
mod latent;
mod options;
mod policy;
mod steer;
mod symmetry;
mod vector;

use equigym_envs::experts::{make_expert, Expert as RustExpert, ExpertOptions};
use equigym_envs::tasks::{Evaluation, TASK_IDS};
use equigym_envs::{Env as RustEnv, EnvError, EnvSpec};
use numpy::{IntoPyArray, PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};

use crate::errors::{invalid_input, to_py};
use crate::options::{env_config, options_kwargs};

fn info_dict<'py>(py: Python<'py>, evaluation: &Evaluation) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("success", evaluation.success())?;
    // Stable-Baselines3 reads this key for success-rate logging.
    d.set_item("is_success", evaluation.success())?;
    for (k, v) in evaluation.measures.terms() {
        d.set_item(k, v)?;
    }
    Ok(d)
}

/// One environment (see `equigym.EquiEnv` for the gymnasium interface built on it).
#[pyclass(module = "equigym._core", name = "Env")]
pub struct Env {
    inner: RustEnv,
}

#[pymethods]
impl Env {
    /// Build `task` with keyword options (see `equigym_envs::EnvOptions`: reward, urdf,
    /// joint_limits, controller, init_joint_noise, horizon, physics, ranges, variant).
    #[new]
    #[pyo3(signature = (task, **options))]
    fn new(task: &str, options: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        Ok(Self { inner: RustEnv::new(env_config(task, options)?).map_err(to_py)? })
    }

    /// Pickling: the arguments that rebuild this environment ...
    fn __getnewargs_ex__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyTuple>, Bound<'py, PyDict>)> {
        Ok((PyTuple::new(py, [self.inner.task().id()])?, options_kwargs(py, self.inner.config())?))
    }
    /// ... and its full state (`get_state`), so an unpickled copy continues bit for bit.
    fn __getstate__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        self.get_state(py)
    }
    fn __setstate__(&mut self, state: &[u8]) -> PyResult<()> {
        self.set_state(state)
    }

    /// Start an episode from `seed`; returns the observation (float64).
    fn reset<'py>(&mut self, py: Python<'py>, seed: u64) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let obs = self.inner.reset(seed).map_err(to_py)?.to_vec();
        Ok(obs.into_pyarray(py))
    }

    /// Apply one absolute 10-d action: (obs, reward, terminated, truncated, info).
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        action: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, f64, bool, bool, Bound<'py, PyDict>)> {
        let action = action.as_slice().map_err(|e| invalid_input(format!("action: {e}")))?.to_vec();
        let inner = &mut self.inner;
        let (result, obs) = py
            .detach(|| {
                let r = inner.step(&action)?;
                Ok::<_, EnvError>((r, inner.observe().to_vec()))
            })
            .map_err(to_py)?;
        Ok((
            obs.into_pyarray(py),
            result.reward,
            result.terminated,
            result.truncated,
            info_dict(py, &result.evaluation)?,
        ))
    }

    /// The current observation.
    fn observe<'py>(&mut self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.observe().to_vec().into_pyarray(py)
    }

    /// Success and reward terms of the current state.
    fn evaluate<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        info_dict(py, &self.inner.evaluate())
    }

    /// The action that holds the robot where it is.
    fn current_target<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.current_target().to_vec().into_pyarray(py)
    }

    /// The full state (physics, controller, random stream) as bytes.
    fn get_state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        Ok(PyBytes::new(py, &self.inner.get_state().map_err(to_py)?))
    }

    /// Restore bytes from `get_state`; continuing is bitwise identical.
    fn set_state(&mut self, state: &[u8]) -> PyResult<()> {
        self.inner.set_state(state).map_err(to_py)
    }

    /// An RGB image (height, width, 3), uint8, row 0 at the top.
    #[pyo3(signature = (width=256, height=256))]
    fn render<'py>(&mut self, py: Python<'py>, width: usize, height: usize) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let inner = &mut self.inner;
        let image = py.detach(|| inner.render(width, height)).map_err(to_py)?;
        let flat = image.data.into_pyarray(py);
        flat.reshape([image.height, image.width, 3])
    }

    #[getter]
    fn elapsed_steps(&self) -> usize {
        self.inner.elapsed_steps()
    }
    /// The read-only description: task, horizon, dimensions, action bounds, layouts.
    #[getter]
    fn spec(&self) -> Spec {
        Spec(self.inner.spec())
    }
    #[getter]
    fn task(&self) -> &'static str {
        self.inner.task().id()
    }
    #[getter]
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }
    #[getter]
    fn observation_dim(&self) -> usize {
        self.inner.observation_layout().dim()
    }
}

/// What an environment is, without its simulator (`equigym_envs::EnvSpec`): every class's
/// metadata comes from one of these.
#[pyclass(module = "equigym._core", name = "EnvSpec", frozen)]
pub struct Spec(pub(crate) EnvSpec);

#[pymethods]
impl Spec {
    #[getter]
    fn task(&self) -> &'static str {
        self.0.task
    }
    /// Episode length in control steps.
    #[getter]
    fn horizon(&self) -> usize {
        self.0.horizon
    }
    #[getter]
    fn observation_dim(&self) -> usize {
        self.0.observation_layout.dim()
    }
    #[getter]
    fn action_dim(&self) -> usize {
        self.0.action_layout.dim()
    }
    #[getter]
    fn max_gripper_width(&self) -> f64 {
        self.0.max_gripper_width
    }
    /// Control period in seconds.
    #[getter]
    fn control_period(&self) -> f64 {
        self.0.control_period
    }
    /// Lower bounds of the raw (absolute) action.
    #[getter]
    fn action_low<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.0.action_low.to_vec().into_pyarray(py)
    }
    /// Upper bounds of the raw (absolute) action.
    #[getter]
    fn action_high<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.0.action_high.to_vec().into_pyarray(py)
    }
    /// Observation fields: list of dicts with name, start, len, kind and rep.
    #[getter]
    fn observation_layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        layout_list(py, &self.0.observation_layout)
    }
    /// Action fields, as `observation_layout`.
    #[getter]
    fn action_layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        layout_list(py, &self.0.action_layout)
    }
}

fn layout_list<'py>(py: Python<'py>, layout: &equigym_envs::Layout) -> PyResult<Bound<'py, PyList>> {
    let list = PyList::empty(py);
    for f in layout.fields() {
        let d = PyDict::new(py);
        d.set_item("name", &f.name)?;
        d.set_item("start", f.start)?;
        d.set_item("len", f.len)?;
        d.set_item("kind", format!("{:?}", f.kind))?;
        d.set_item("rep", f.reps())?;
        list.append(d)?;
    }
    Ok(list)
}

/// A task's scripted expert.
#[pyclass(module = "equigym._core", name = "Expert")]
pub struct Expert {
    inner: Box<dyn RustExpert>,
}

#[pymethods]
impl Expert {
    #[new]
    #[pyo3(signature = (task, *, position_noise=0.0, yaw_noise=0.0))]
    fn new(task: &str, position_noise: f64, yaw_noise: f64) -> PyResult<Self> {
        Ok(Self { inner: make_expert(task, ExpertOptions { position_noise, yaw_noise }).map_err(to_py)? })
    }

    /// Prepare for the episode that `env` has just been reset to.
    fn reset(&mut self, env: &Env, seed: u64) {
        self.inner.reset(&env.inner, seed);
    }

    /// The next absolute action for `env`.
    fn act<'py>(&mut self, py: Python<'py>, env: &Env) -> Bound<'py, PyArray1<f64>> {
        self.inner.act(&env.inner).to_vec().into_pyarray(py)
    }

    #[getter]
    fn phase(&self) -> &'static str {
        self.inner.phase()
    }
}

/// Wilson score interval (95 %) of `successes` out of `n`: `(low, high)`; (0, 1) when n is 0.
#[pyfunction]
fn wilson(successes: usize, n: usize) -> PyResult<(f64, f64)> {
    if successes > n {
        return Err(errors::invalid_input(format!("successes ({successes}) must be at most n ({n})")));
    }
    Ok(equigym_wrappers::steerability::wilson(successes, n))
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Env>()?;
    m.add_class::<Spec>()?;
    m.add_class::<Expert>()?;
    m.add_class::<symmetry::TaskSymmetry>()?;
    m.add_class::<policy::DiffusionPolicy>()?;
    m.add_class::<latent::LatentEnv>()?;
    m.add_class::<latent::LatentVecEnv>()?;
    m.add_class::<vector::VecEnv>()?;
    m.add_function(wrap_pyfunction!(symmetry::measure_symmetry_breaking, m)?)?;
    m.add_function(wrap_pyfunction!(steer::steer_run, m)?)?;
    m.add_function(wrap_pyfunction!(steer::steer_preset, m)?)?;
    m.add_function(wrap_pyfunction!(steer::steer_gradcase, m)?)?;
    m.add_function(wrap_pyfunction!(steer::evaluate_base, m)?)?;
    m.add_function(wrap_pyfunction!(wilson, m)?)?;
    m.add("EVAL_SEED", equigym_agents::EVAL_SEED)?;
    m.add("STALL_MOVE", equigym_agents::STALL_MOVE)?;
    m.add("TASK_IDS", TASK_IDS.to_vec())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
