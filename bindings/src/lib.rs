//! `equigym._core`: thin pyo3 bindings over `equigym-envs`.
//!
//! This crate only converts types and errors; every behaviour lives in the Rust crates.
//! Error mapping: shapes, NaN/inf, configuration, states and robot descriptions raise
//! `ValueError` subclasses; calls out of order raise `ResetNeeded` (a `RuntimeError`); a missing
//! file raises `FileNotFoundError`.

mod latent;
mod steer;
mod symmetry;

use std::path::PathBuf;

use equigym_envs::experts::{make_expert, Expert as RustExpert, ExpertOptions};
use equigym_envs::tasks::{Evaluation, TASK_IDS};
use equigym_envs::{Env as RustEnv, EnvConfig, EnvError, RewardKind, TaskOptions};
use numpy::{IntoPyArray, PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::{PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};

mod vector;

create_exception!(_core, EquigymError, PyValueError, "Invalid input to an equigym environment.");
create_exception!(_core, UrdfError, PyValueError, "The robot description (URDF) cannot be used.");
create_exception!(_core, InvalidStateError, PyValueError, "A saved state cannot be restored.");
create_exception!(_core, ResetNeeded, PyRuntimeError, "The environment must be reset before this call.");
create_exception!(_core, PolicyError, PyValueError, "A diffusion-policy file is corrupt, truncated or does not fit the task.");

fn to_py(e: EnvError) -> PyErr {
    let msg = e.to_string();
    match e {
        EnvError::CallOrder(_) => ResetNeeded::new_err(msg),
        EnvError::Urdf { ref reason, .. } if reason.starts_with("cannot read file") => PyFileNotFoundError::new_err(msg),
        EnvError::Urdf { .. } => UrdfError::new_err(msg),
        EnvError::InvalidState(_) => InvalidStateError::new_err(msg),
        EnvError::Io(_) => PyRuntimeError::new_err(msg),
        EnvError::WrongLength { .. } | EnvError::NonFinite { .. } | EnvError::InvalidConfig(_) => {
            EquigymError::new_err(msg)
        }
    }
}

fn info_dict<'py>(py: Python<'py>, evaluation: &Evaluation) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("success", evaluation.success)?;
    // Stable-Baselines3 reads this key for success-rate logging.
    d.set_item("is_success", evaluation.success)?;
    for (k, v) in &evaluation.terms {
        d.set_item(*k, *v)?;
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
    #[new]
    #[pyo3(signature = (task, *, reward="sparse", urdf=None, joint_limits=true, init_joint_noise=0.02, horizon=None, physics=None, ranges=None, variant=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        task: &str,
        reward: &str,
        urdf: Option<PathBuf>,
        joint_limits: bool,
        init_joint_noise: f64,
        horizon: Option<usize>,
        physics: Option<&Bound<'_, PyDict>>,
        ranges: Option<&Bound<'_, PyDict>>,
        variant: Option<String>,
    ) -> PyResult<Self> {
        let mut config = EnvConfig::new(task);
        config.reward = reward.parse::<RewardKind>().map_err(to_py)?;
        config.urdf = urdf;
        config.physics.joint_limits = joint_limits;
        config.init_joint_noise = init_joint_noise;
        config.horizon = horizon;
        if let Some(physics) = physics {
            for (key, value) in physics.iter() {
                let key: String = key.extract()?;
                let p = &mut config.physics;
                match key.as_str() {
                    "timestep" => p.timestep = value.extract()?,
                    "substeps" => p.substeps = value.extract()?,
                    "solver_iterations" => p.solver_iterations = value.extract()?,
                    "friction" => p.friction = value.extract()?,
                    "max_hand_force" => p.max_hand_force = value.extract()?,
                    "max_hand_torque" => p.max_hand_torque = value.extract()?,
                    "max_finger_force" => p.max_finger_force = value.extract()?,
                    "finger_speed" => p.finger_speed = value.extract()?,
                    "servo_time_constant" => p.servo_time_constant = value.extract()?,
                    "cartesian_control" => p.cartesian_control = value.extract()?,
                    other => return Err(EquigymError::new_err(format!("unknown physics option '{other}'"))),
                }
            }
        }
        config.task_options.variant = variant;
        if let Some(ranges) = ranges {
            let mut options = TaskOptions { variant: config.task_options.variant.clone(), ..TaskOptions::default() };
            for (key, value) in ranges.iter() {
                let (lo, hi): (f64, f64) = value.extract().map_err(|_| {
                    EquigymError::new_err(format!("range '{key}' must be a (low, high) pair of numbers"))
                })?;
                options.ranges.push((key.extract()?, lo, hi));
            }
            config.task_options = options;
        }
        Ok(Self { inner: RustEnv::new(config).map_err(to_py)? })
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
        let action = action.as_slice().map_err(|e| EquigymError::new_err(format!("action: {e}")))?.to_vec();
        let inner = &mut self.inner;
        let (result, obs) = py.detach(|| {
            let r = inner.step(&action)?;
            Ok::<_, EnvError>((r, inner.observe().to_vec()))
        })
        .map_err(to_py)?;
        Ok((obs.into_pyarray(py), result.reward, result.terminated, result.truncated, info_dict(py, &result.evaluation)?))
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
        Ok(flat.reshape([image.height, image.width, 3])?)
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
    fn elapsed_steps(&self) -> usize {
        self.inner.elapsed_steps()
    }
    #[getter]
    fn observation_dim(&self) -> usize {
        self.inner.observation_layout().dim()
    }
    #[getter]
    fn max_gripper_width(&self) -> f64 {
        self.inner.max_gripper_width()
    }
    /// Control period in seconds.
    #[getter]
    fn control_period(&self) -> f64 {
        self.inner.config().physics.control_period()
    }
    #[getter]
    fn action_low<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.action_bounds().0.to_vec().into_pyarray(py)
    }
    #[getter]
    fn action_high<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.action_bounds().1.to_vec().into_pyarray(py)
    }

    /// Observation fields: list of dicts with name, start, len, kind and rep.
    #[getter]
    fn observation_layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        layout_list(py, self.inner.observation_layout())
    }
    #[getter]
    fn action_layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        layout_list(py, &self.inner.action_layout())
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

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<Env>()?;
    m.add_class::<Expert>()?;
    m.add_class::<symmetry::TaskSymmetry>()?;
    m.add_class::<latent::DiffusionPolicy>()?;
    m.add_class::<latent::LatentEnv>()?;
    m.add_class::<latent::LatentVecEnv>()?;
    m.add("PolicyError", py.get_type::<PolicyError>())?;
    m.add_function(wrap_pyfunction!(symmetry::measure_symmetry_breaking, m)?)?;
    m.add_class::<vector::VecEnv>()?;
    m.add_function(wrap_pyfunction!(steer::steer_run, m)?)?;
    m.add_function(wrap_pyfunction!(steer::steer_gradcase, m)?)?;
    m.add("EquigymError", py.get_type::<EquigymError>())?;
    m.add("UrdfError", py.get_type::<UrdfError>())?;
    m.add("InvalidStateError", py.get_type::<InvalidStateError>())?;
    m.add("ResetNeeded", py.get_type::<ResetNeeded>())?;
    m.add("TASK_IDS", TASK_IDS.to_vec())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
