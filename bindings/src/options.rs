//! The one conversion of environment options between Python and Rust.
//!
//! Keyword arguments become a `serde_json::Value` generically (no option or physics field is
//! named here) and deserialise into [`EnvOptions`], whose `deny_unknown_fields` turns a
//! misspelt option into an error. The reverse direction gives the keyword arguments that
//! rebuild an environment (pickling, copies).

use equigym_envs::{EnvConfig, EnvOptions};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use pyo3::IntoPyObjectExt;
use serde_json::{Map, Number, Value};

use crate::errors::{invalid_input, to_py};

/// A Python value as JSON-like data: None, bool, int, float, str, path-like, sequences and
/// string-keyed mappings. `at` names the value in errors.
fn to_value(obj: &Bound<'_, PyAny>, at: &str) -> PyResult<Value> {
    if obj.is_none() {
        return Ok(Value::Null);
    }
    if obj.is_instance_of::<PyBool>() {
        return Ok(Value::Bool(obj.extract()?));
    }
    if obj.is_instance_of::<PyInt>() {
        return match obj.extract::<i64>() {
            Ok(v) => Ok(Value::from(v)),
            Err(_) => {
                Ok(Value::from(obj.extract::<u64>().map_err(|_| invalid_input(format!("{at}: integer out of range")))?))
            }
        };
    }
    if obj.is_instance_of::<PyFloat>() {
        let v: f64 = obj.extract()?;
        return Number::from_f64(v).map(Value::Number).ok_or_else(|| invalid_input(format!("{at}: {v} is not finite")));
    }
    if obj.is_instance_of::<PyString>() {
        return Ok(Value::String(obj.extract()?));
    }
    if let Ok(dict) = obj.cast::<PyDict>() {
        let mut map = Map::new();
        for (k, v) in dict.iter() {
            let key: String =
                k.extract().map_err(|_| invalid_input(format!("{at}: keys must be strings, got {k:?}")))?;
            let value = to_value(&v, &format!("{at}.{key}"))?;
            map.insert(key, value);
        }
        return Ok(Value::Object(map));
    }
    if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
        let items = obj.try_iter()?.enumerate().map(|(i, item)| to_value(&item?, &format!("{at}[{i}]")));
        return items.collect::<PyResult<Vec<_>>>().map(Value::Array);
    }
    if obj.hasattr("__fspath__")? {
        return Ok(Value::String(obj.py().import("os")?.call_method1("fspath", (obj,))?.extract()?));
    }
    // numpy scalars and other numbers: integers through __index__, reals through __float__.
    if let Ok(v) = obj.extract::<i64>() {
        return Ok(Value::from(v));
    }
    if let Ok(v) = obj.extract::<f64>() {
        return Number::from_f64(v).map(Value::Number).ok_or_else(|| invalid_input(format!("{at}: {v} is not finite")));
    }
    Err(invalid_input(format!("{at}: unsupported value {obj:?}")))
}

/// JSON-like data as Python values (objects become dicts, arrays lists).
fn to_python<'py>(py: Python<'py>, value: &Value) -> PyResult<Bound<'py, PyAny>> {
    match value {
        Value::Null => Ok(py.None().into_bound(py)),
        Value::Bool(b) => b.into_bound_py_any(py),
        Value::Number(n) => match (n.as_i64(), n.as_u64(), n.as_f64()) {
            (Some(i), _, _) => i.into_bound_py_any(py),
            (None, Some(u), _) => u.into_bound_py_any(py),
            (None, None, Some(f)) => f.into_bound_py_any(py),
            _ => Err(invalid_input(format!("unrepresentable number {n}"))),
        },
        Value::String(s) => s.into_bound_py_any(py),
        Value::Array(items) => PyList::new(py, items.iter().map(|v| to_python(py, v)).collect::<PyResult<Vec<_>>>()?)?
            .into_bound_py_any(py),
        Value::Object(map) => {
            let dict = PyDict::new(py);
            for (k, v) in map {
                dict.set_item(k, to_python(py, v)?)?;
            }
            dict.into_bound_py_any(py)
        }
    }
}

/// The environment options given as keyword arguments (absent: all defaults).
pub(crate) fn env_options(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<EnvOptions> {
    let value = match kwargs {
        None => Value::Object(Map::new()),
        Some(kwargs) => to_value(kwargs.as_any(), "options")?,
    };
    serde_json::from_value(value).map_err(|e| invalid_input(format!("invalid environment option: {e}")))
}

/// The configuration of `task` from keyword-argument options.
pub(crate) fn env_config(task: &str, kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<EnvConfig> {
    env_options(kwargs)?.into_config(task).map_err(to_py)
}

/// The keyword arguments that rebuild an environment with `config`.
pub(crate) fn options_kwargs<'py>(py: Python<'py>, config: &EnvConfig) -> PyResult<Bound<'py, PyDict>> {
    let value = serde_json::to_value(EnvOptions::from_config(config))
        .map_err(|e| invalid_input(format!("cannot serialise the options: {e}")))?;
    Ok(to_python(py, &value)?.cast_into::<PyDict>()?)
}
