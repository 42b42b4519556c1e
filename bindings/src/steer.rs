//! Binding of the Rust steering agents (`equigym-agents`): one run, the GIL released.

use std::path::PathBuf;

use equigym_agents::{run, Method, Preset, RunConfig};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::to_py;

fn agents_err(e: equigym_agents::Error) -> PyErr {
    to_py(e)
}

/// Train one steering agent in Rust (see `python -m equigym.steer run --help`); returns a dict
/// with the run directory, the log rows, step counts, seconds and a hash of the final weights.
#[pyfunction]
#[pyo3(signature = (method, task, seed, steps, out, *, threads=1, preset="cpu", joint_limits=true, controller=None, eval_every=2000, eval_episodes=50, policy=None, ent_init=None, horizon=None, progress=false, stop_after_evals=None))]
#[allow(clippy::too_many_arguments)]
pub fn steer_run<'py>(
    py: Python<'py>,
    method: &str,
    task: &str,
    seed: u64,
    steps: usize,
    out: PathBuf,
    threads: usize,
    preset: &str,
    joint_limits: bool,
    controller: Option<&str>,
    eval_every: usize,
    eval_episodes: usize,
    policy: Option<PathBuf>,
    ent_init: Option<f64>,
    horizon: Option<usize>,
    progress: bool,
    stop_after_evals: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut cfg =
        RunConfig::new(Method::parse(method).map_err(agents_err)?, task, seed, steps, out).map_err(agents_err)?;
    cfg.threads = threads;
    cfg.preset = Preset::named(preset).map_err(agents_err)?;
    cfg.joint_limits = joint_limits;
    cfg.cartesian = match controller {
        None => None,
        Some("joint") => Some(false),
        Some("cartesian") => Some(true),
        Some(other) => {
            return Err(crate::errors::invalid_input(format!(
                "controller must be 'joint' or 'cartesian', got '{other}'"
            )))
        }
    };
    cfg.eval_every = eval_every;
    cfg.eval_episodes = eval_episodes;
    cfg.policy = policy;
    cfg.ent_init = ent_init;
    cfg.horizon = horizon;
    cfg.progress = progress;
    cfg.stop_after_evals = stop_after_evals;
    let s = py.detach(|| run(&cfg)).map_err(agents_err)?;
    let d = PyDict::new(py);
    d.set_item("run_dir", s.run_dir)?;
    let rows: Vec<(u64, f64, f64, f64)> =
        s.rows.iter().map(|r| (r.env_steps, r.success_rate, r.mean_q, r.seconds)).collect();
    d.set_item("rows", rows)?;
    d.set_item("env_steps", s.env_steps)?;
    d.set_item("grad_steps", s.grad_steps)?;
    d.set_item("seconds", s.seconds)?;
    let split = PyDict::new(py);
    split.set_item("rollout", s.time.rollout)?;
    split.set_item("train", s.time.train)?;
    split.set_item("eval", s.time.eval)?;
    d.set_item("seconds_this_invocation", split)?;
    d.set_item("params_hash", format!("{:016x}", s.params_hash))?;
    d.set_item("fields", s.fields)?;
    d.set_item("params_actor", s.params_actor)?;
    d.set_item("params_critic", s.params_critic)?;
    Ok(d)
}

fn layer_dict<'py>(py: Python<'py>, l: &equigym_agents::gradcheck::LayerSpec) -> PyResult<Bound<'py, PyDict>> {
    use equigym_agents::gradcheck::LayerSpec as L;
    let d = PyDict::new(py);
    match l {
        L::Dense { n_in, n_out, w, b } => {
            d.set_item("kind", "dense")?;
            d.set_item("n_in", n_in)?;
            d.set_item("n_out", n_out)?;
            d.set_item("w", w)?;
            d.set_item("b", b)?;
        }
        L::Equi { n_in, n_out, w, n_weights, entries, pidx, coefs, bias_out, bias_pidx, plain } => {
            d.set_item("kind", "equi")?;
            d.set_item("n_in", n_in)?;
            d.set_item("n_out", n_out)?;
            d.set_item("w", w)?;
            d.set_item("n_weights", n_weights)?;
            d.set_item("entries", entries.clone())?;
            d.set_item("pidx", pidx.clone())?;
            d.set_item("coefs", coefs.clone())?;
            d.set_item("bias_out", bias_out.clone())?;
            d.set_item("bias_pidx", bias_pidx.clone())?;
            d.set_item("plain", *plain)?;
        }
        L::Norm { fields, order, g, s } => {
            d.set_item("kind", "norm")?;
            d.set_item("fields", fields)?;
            d.set_item("order", order)?;
            d.set_item("g", g)?;
            d.set_item("s", s)?;
        }
        L::Tanh => d.set_item("kind", "tanh")?,
        L::Relu => d.set_item("kind", "relu")?,
        L::PoolHead { fields, order, w, b, plain } => {
            d.set_item("kind", "pool_head")?;
            d.set_item("fields", fields)?;
            d.set_item("order", order)?;
            d.set_item("w", w)?;
            d.set_item("b", b)?;
            d.set_item("plain", *plain)?;
        }
        L::Circulant { f_in, f_out, w, b } => {
            d.set_item("kind", "circulant")?;
            d.set_item("f_in", f_in)?;
            d.set_item("f_out", f_out)?;
            d.set_item("w", w)?;
            d.set_item("b", b)?;
        }
    }
    Ok(d)
}

fn net_dict<'py>(
    py: Python<'py>,
    net: &(Vec<equigym_agents::gradcheck::LayerSpec>, Vec<f64>),
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let layers = net.0.iter().map(|l| layer_dict(py, l)).collect::<PyResult<Vec<_>>>()?;
    d.set_item("layers", layers)?;
    d.set_item("params", net.1.clone())?;
    Ok(d)
}

/// A SAC gradient case in float64 (small nets): network descriptions, inputs, noise and the
/// Rust losses and gradients, for parity tests against an independent implementation.
#[pyfunction]
#[pyo3(signature = (method, task="lift", seed=0, rows=6))]
pub fn steer_gradcase<'py>(
    py: Python<'py>,
    method: &str,
    task: &str,
    seed: u64,
    rows: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let c = equigym_agents::gradcheck::grad_case(Method::parse(method).map_err(agents_err)?, task, seed, rows)
        .map_err(agents_err)?;
    let d = PyDict::new(py);
    d.set_item("obs_dim", c.obs_dim)?;
    d.set_item("latent_dim", c.latent_dim)?;
    d.set_item("rows", c.rows)?;
    d.set_item("actor", net_dict(py, &c.actor)?)?;
    d.set_item("critics", vec![net_dict(py, &c.critics[0])?, net_dict(py, &c.critics[1])?])?;
    d.set_item("log_std_index", c.log_std_index)?;
    d.set_item("log_std_range", c.log_std_range)?;
    d.set_item("radial", c.radial)?;
    for (k, v) in [
        ("obs", c.obs),
        ("act", c.act),
        ("reward", c.reward),
        ("next_obs", c.next_obs),
        ("done", c.done),
        ("eps1", c.eps1),
        ("eps2", c.eps2),
        ("y", c.y),
        ("logp", c.logp),
        ("actor_grad", c.actor_grad),
    ] {
        d.set_item(k, v)?;
    }
    d.set_item("critic_grads", vec![c.critic_grads[0].clone(), c.critic_grads[1].clone()])?;
    d.set_item("log_alpha", c.log_alpha)?;
    d.set_item("gamma", c.gamma)?;
    d.set_item("actor_loss", c.actor_loss)?;
    d.set_item("critic_losses", c.critic_losses.to_vec())?;
    d.set_item("alpha_loss", c.alpha_loss)?;
    d.set_item("alpha_grad", c.alpha_grad)?;
    Ok(d)
}
