//! Binding of the diffusion-policy runtime (`equigym_wrappers::DiffusionPolicy`): a loaded policy
//! that samples chunks in Rust and pickles with its file's bytes. The latent-action
//! environments (`latent.rs`) take one of these, or a path to load one from.

use std::path::PathBuf;
use std::sync::Arc;

use equigym_wrappers::edp::Kernel;
use equigym_wrappers::DiffusionPolicy as RustPolicy;
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray3, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::errors::{invalid_input, to_py};

/// An exported equivariant diffusion policy, run in Rust (batched deterministic DDIM).
/// Keeps the bytes of its file, so it pickles without the file.
#[pyclass(module = "equigym._core", name = "DiffusionPolicy", frozen)]
pub struct DiffusionPolicy {
    pub(crate) inner: Arc<RustPolicy>,
    bytes: Arc<Vec<u8>>,
    origin: String,
}

/// `"fourier"` or `"dense"` as the runtime's kernel; `None` is the runtime's default (Fourier).
pub(crate) fn kernel(name: Option<&str>) -> PyResult<Kernel> {
    name.map_or(Ok(Kernel::default()), |n| n.parse().map_err(to_py))
}

#[pymethods]
impl DiffusionPolicy {
    /// Load from a file path, or from the bytes of a policy file (`origin` names it in errors);
    /// `kernel` runs the regular-to-regular layers in the Fourier basis (`None`: the default) or
    /// dense (`"dense"`: the file's own matrices, the kernel of runs recorded before the Fourier one).
    #[new]
    #[pyo3(signature = (source, origin=None, kernel=None))]
    fn new(source: &Bound<'_, PyAny>, origin: Option<String>, kernel: Option<&str>) -> PyResult<Self> {
        let kernel = self::kernel(kernel)?;
        let (bytes, origin) = match source.cast::<PyBytes>() {
            Ok(b) => (b.as_bytes().to_vec(), origin.unwrap_or_else(|| "<bytes>".into())),
            Err(_) => {
                let path: PathBuf = source.extract()?;
                (RustPolicy::read_file(&path).map_err(to_py)?, origin.unwrap_or_else(|| path.display().to_string()))
            }
        };
        let mut inner = RustPolicy::from_bytes(&bytes, &origin).map_err(to_py)?;
        inner.kernel = kernel;
        Ok(Self { inner: Arc::new(inner), bytes: Arc::new(bytes), origin })
    }
    /// Pickling: the file's bytes, its name and the kernel.
    fn __getnewargs__<'py>(&self, py: Python<'py>) -> (Bound<'py, PyBytes>, String, &'static str) {
        (PyBytes::new(py, &self.bytes), self.origin.clone(), self.inner.kernel.as_str())
    }
    /// `"fourier"` or `"dense"`.
    #[getter]
    fn kernel(&self) -> &'static str {
        self.inner.kernel.as_str()
    }
    /// The layers the Fourier kernel runs in the Fourier basis (the regular-to-regular ones).
    #[getter]
    fn fourier_layers(&self) -> Vec<usize> {
        self.inner.fourier_layers()
    }
    #[getter]
    fn task(&self) -> &str {
        &self.inner.task
    }
    #[getter]
    fn chunk_len(&self) -> usize {
        self.inner.chunk_len
    }
    #[getter]
    fn obs_dim(&self) -> usize {
        self.inner.obs_dim()
    }
    #[getter]
    fn action_dim(&self) -> usize {
        self.inner.action_dim()
    }
    #[getter]
    fn group(&self) -> &str {
        &self.inner.group
    }
    #[getter]
    fn default_ddim_steps(&self) -> usize {
        self.inner.default_ddim_steps
    }
    #[getter]
    fn metadata(&self) -> std::collections::HashMap<String, String> {
        self.inner.metadata.clone()
    }
    /// Denoise: `obs` (B, obs_dim) and `latent` (B, action_dim) -> chunks (B, chunk_len, 10);
    /// `precision` "f32" (default) or "f64" is the network's arithmetic.
    #[pyo3(signature = (obs, latent, steps=None, precision=None))]
    fn sample<'py>(
        &self,
        py: Python<'py>,
        obs: PyReadonlyArrayDyn<'py, f64>,
        latent: PyReadonlyArrayDyn<'py, f64>,
        steps: Option<usize>,
        precision: Option<&str>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let precision: equigym_wrappers::edp::Precision = match precision {
            Some(p) => p.parse().map_err(to_py)?,
            None => self.inner.precision,
        };
        let (od, ad) = (self.inner.obs_dim(), self.inner.action_dim());
        let (os, ls) = (obs.shape().to_vec(), latent.shape().to_vec());
        if os.len() != 2 || ls.len() != 2 || os[1] != od || ls[1] != ad || os[0] != ls[0] {
            return Err(invalid_input(format!(
                "expected obs (B, {od}) and latent (B, {ad}) with the same B, got {os:?} and {ls:?}"
            )));
        }
        let o: Vec<f64> = obs.as_array().iter().copied().collect();
        let w: Vec<f64> = latent.as_array().iter().copied().collect();
        let steps = steps.unwrap_or(self.inner.default_ddim_steps);
        let mut out = vec![0.0; w.len()];
        let policy = self.inner.clone();
        py.detach(|| policy.sample_with(precision, &o, &w, steps, &mut out)).map_err(to_py)?;
        let chunk = self.inner.chunk_len;
        let arr = Array3::from_shape_vec((ls[0], chunk, ad / chunk), out).map_err(|e| invalid_input(e.to_string()))?;
        Ok(arr.into_pyarray(py))
    }
}

/// A loaded `DiffusionPolicy` (shared) or a path to load one from (on the default kernel).
pub(crate) fn policy_object(py: Python<'_>, policy: &Bound<'_, PyAny>) -> PyResult<Py<DiffusionPolicy>> {
    match policy.cast::<DiffusionPolicy>() {
        Ok(p) => Ok(p.clone().unbind()),
        Err(_) => Py::new(py, DiffusionPolicy::new(policy, None, None)?),
    }
}

/// `ddim_steps` or the policy's default.
pub(crate) fn ddim_steps(policy: &RustPolicy, steps: Option<usize>) -> usize {
    steps.unwrap_or(policy.default_ddim_steps)
}
