//! Bindings of the symmetry layer (`equigym-wrappers`): the group action on arrays and on
//! simulator states, and the symmetry-breaking measurement. Python's `equigym.symmetry`
//! builds its friendlier API on these.

use equigym_envs::TaskOptions;
use equigym_wrappers::breaking::{measure, BreakingConfig};
use equigym_wrappers::{transform_state, Block, Group, PlanarRotation, Representation, TaskSymmetry as RustSymmetry};
use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArray2, PyArrayDyn, PyReadonlyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::errors::{invalid_input, to_py};
use crate::options::env_options;
use crate::{layout_list, Env};

/// A task's group action on observations, actions, action chunks, latent noise and states.
#[pyclass(module = "equigym._core", name = "TaskSymmetry")]
pub struct TaskSymmetry {
    inner: RustSymmetry,
}

impl TaskSymmetry {
    fn representation(&self, space: &str) -> PyResult<&Representation> {
        match space {
            "observation" => Ok(&self.inner.observation),
            "action" => Ok(&self.inner.action),
            "chunk" | "latent" => Ok(&self.inner.chunk),
            other => Err(invalid_input(format!(
                "unknown space '{other}' (use 'observation', 'action', 'chunk' or 'latent')"
            ))),
        }
    }

    fn elements_from_indices(&self, indices: &[i64]) -> PyResult<Vec<PlanarRotation>> {
        indices
            .iter()
            .map(|&k| {
                let k = usize::try_from(k)
                    .map_err(|_| invalid_input(format!("group element index must be >= 0, got {k}")))?;
                self.inner.group.element(k).map_err(to_py)
            })
            .collect()
    }

    /// Apply per-row (or one shared) elements to an array whose last axis is the space's dim.
    fn apply<'py>(
        &self,
        py: Python<'py>,
        space: &str,
        data: PyReadonlyArrayDyn<'py, f64>,
        elements: Vec<PlanarRotation>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let rep = self.representation(space)?;
        let shape = data.shape().to_vec();
        let last = shape.last().copied().unwrap_or(0);
        if shape.is_empty() || last != rep.dim() {
            return Err(invalid_input(format!(
                "{space}: expected an array whose last axis has {} values, got shape {shape:?}",
                rep.dim()
            )));
        }
        let rows: usize = shape[..shape.len() - 1].iter().product();
        let mut values: Vec<f64> = data.as_array().iter().copied().collect();
        match elements.len() {
            1 => rep.act_batch(&elements[0], &mut values).map_err(to_py)?,
            n if n == rows => rep.act_each(&elements, &mut values).map_err(to_py)?,
            n => {
                return Err(invalid_input(format!(
                    "{space}: got {n} group elements for {rows} rows (give one, or one per row)"
                )))
            }
        }
        let out = ArrayD::from_shape_vec(IxDyn(&shape), values).map_err(|e| invalid_input(e.to_string()))?;
        Ok(out.into_pyarray(py))
    }
}

#[pymethods]
impl TaskSymmetry {
    #[new]
    #[pyo3(signature = (task, *, group="C8", chunk_len=4, variant=None))]
    fn new(task: &str, group: &str, chunk_len: usize, variant: Option<String>) -> PyResult<Self> {
        let group: Group = group.parse().map_err(to_py)?;
        let options = TaskOptions { variant, ..Default::default() };
        Ok(Self { inner: RustSymmetry::new(task, &options, group, chunk_len).map_err(to_py)? })
    }

    #[getter]
    fn task(&self) -> &str {
        &self.inner.task
    }
    /// "C8", "SO2", ...
    #[getter]
    fn group(&self) -> String {
        self.inner.group.name()
    }
    /// N for C_N, None for SO(2).
    #[getter]
    fn group_order(&self) -> Option<usize> {
        self.inner.group.order()
    }
    #[getter]
    fn chunk_len(&self) -> usize {
        self.inner.chunk_len()
    }
    /// Dimension of a space ('observation', 'action', 'chunk', 'latent').
    fn dim(&self, space: &str) -> PyResult<usize> {
        Ok(self.representation(space)?.dim())
    }
    /// Fields of a space: list of dicts with name, start, len, kind and rep.
    fn layout<'py>(&self, py: Python<'py>, space: &str) -> PyResult<Bound<'py, PyList>> {
        match space {
            "observation" => layout_list(py, &self.inner.observation_layout),
            "action" => layout_list(py, &self.inner.action_layout),
            "chunk" | "latent" => layout_list(py, &self.inner.chunk_layout),
            _ => self.representation(space).map(|_| unreachable!()),
        }
    }
    /// The irreducible blocks of a space, in order: (frequency, indices) with frequency 0 for
    /// rho0 (one index) and 1 for rho1 (an (x, y) index pair). Equivariant networks permute
    /// inputs into this order so that each rho1 pair is contiguous.
    fn blocks(&self, space: &str) -> PyResult<Vec<(u32, Vec<usize>)>> {
        Ok(self
            .representation(space)?
            .blocks()
            .iter()
            .map(|b| match *b {
                Block::Trivial { index } => (0, vec![index]),
                Block::Rotating { x, y, frequency } => (frequency, vec![x, y]),
            })
            .collect())
    }
    /// Angle (rad) of element k of C_N.
    fn element_angle(&self, k: usize) -> PyResult<f64> {
        Ok(self.inner.group.element(k).map_err(to_py)?.angle())
    }
    /// g . x for elements given by index (one, or one per row).
    fn act_elements<'py>(
        &self,
        py: Python<'py>,
        space: &str,
        data: PyReadonlyArrayDyn<'py, f64>,
        elements: PyReadonlyArray1<'py, i64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let elements = self.elements_from_indices(elements.as_slice()?)?;
        self.apply(py, space, data, elements)
    }
    /// g . x for rotations given by angle in radians (one, or one per row).
    fn act_angles<'py>(
        &self,
        py: Python<'py>,
        space: &str,
        data: PyReadonlyArrayDyn<'py, f64>,
        angles: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let elements =
            angles.as_slice()?.iter().map(|a| PlanarRotation::new(*a)).collect::<Result<Vec<_>, _>>().map_err(to_py)?;
        self.apply(py, space, data, elements)
    }
    /// The representation matrix of element `element` (index) or of rotation `angle`.
    #[pyo3(signature = (space, *, element=None, angle=None))]
    fn matrix<'py>(
        &self,
        py: Python<'py>,
        space: &str,
        element: Option<usize>,
        angle: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let g = self.one_element(element, angle)?;
        let rep = self.representation(space)?;
        let d = rep.dim();
        let m =
            numpy::ndarray::Array2::from_shape_vec((d, d), rep.matrix(&g)).map_err(|e| invalid_input(e.to_string()))?;
        Ok(m.into_pyarray(py))
    }
    /// g . s: rotate the environment's state in place (objects, hand, fingers; the base
    /// stays). Returns how well the arm reaches the rotated hand.
    #[pyo3(signature = (env, *, element=None, angle=None))]
    fn transform_state<'py>(
        &self,
        py: Python<'py>,
        env: &mut Env,
        element: Option<usize>,
        angle: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        if env.inner.task().id() != self.inner.task {
            return Err(invalid_input(format!(
                "this symmetry is for task '{}', the environment runs '{}'",
                self.inner.task,
                env.inner.task().id()
            )));
        }
        let g = self.one_element(element, angle)?;
        let fit = transform_state(&mut env.inner, &g).map_err(to_py)?;
        let d = PyDict::new(py);
        d.set_item("position_error", fit.position_error)?;
        d.set_item("rotation_error", fit.rotation_error)?;
        d.set_item("reachable", fit.position_error < 1e-3)?;
        Ok(d)
    }
}

impl TaskSymmetry {
    fn one_element(&self, element: Option<usize>, angle: Option<f64>) -> PyResult<PlanarRotation> {
        match (element, angle) {
            (Some(k), None) => self.inner.group.element(k).map_err(to_py),
            (None, Some(a)) => PlanarRotation::new(a).map_err(to_py),
            _ => Err(invalid_input("give exactly one of element= (an index) or angle= (radians)")),
        }
    }
}

/// Measure a task's symmetry breaking (see `equigym_wrappers::breaking`) in the environment
/// that the options `env` (the environments' keyword arguments) build; returns JSON.
#[pyfunction]
#[pyo3(signature = (task, *, env=None, group_order=8, episodes=20, states_per_episode=4, probe_steps=1, replay_slack=30, seed=0))]
#[allow(clippy::too_many_arguments)]
pub fn measure_symmetry_breaking(
    py: Python<'_>,
    task: &str,
    env: Option<&Bound<'_, PyDict>>,
    group_order: usize,
    episodes: usize,
    states_per_episode: usize,
    probe_steps: usize,
    replay_slack: usize,
    seed: u64,
) -> PyResult<String> {
    let config = BreakingConfig {
        task: task.into(),
        env: env_options(env)?,
        group_order,
        episodes,
        states_per_episode,
        probe_steps,
        replay_slack,
        seed,
    };
    let report = py.detach(|| measure(&config)).map_err(to_py)?;
    serde_json::to_string(&report).map_err(|e| invalid_input(e.to_string()))
}
