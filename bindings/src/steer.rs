//! Binding of the Rust steering agents (`equigym-agents`): one run, the GIL released.

use std::path::PathBuf;

use equigym_agents::{evaluate_base as base_evaluation, run, Method, Preset, RunConfig};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::to_py;
use crate::options::env_options;

/// The network and schedule preset `name` (`"cpu"` or `"paper"`) as a dict: width, layers,
/// utd, utd_square (None where it is utd), batch, n_envs, warmup, ent_init. The one home of the
/// presets; the SB3 runner (`baselines.steer`) reads them from here.
#[pyfunction]
pub fn steer_preset<'py>(py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyDict>> {
    let p = Preset::named(name).map_err(to_py)?;
    let d = PyDict::new(py);
    d.set_item("width", p.width)?;
    d.set_item("layers", p.layers)?;
    d.set_item("utd", p.utd)?;
    d.set_item("utd_square", p.utd_square)?;
    d.set_item("batch", p.batch)?;
    d.set_item("n_envs", p.n_envs)?;
    d.set_item("warmup", p.warmup)?;
    d.set_item("ent_init", p.ent_init)?;
    Ok(d)
}

/// Train one steering agent in Rust (see `python -m equigym.steer run --help`); returns a dict
/// with the run directory, the log rows, step counts, seconds and a hash of the final weights.
/// `env` holds the environments' options (their keyword arguments: joint_limits, controller,
/// horizon, variant, physics, ...).
#[pyfunction]
#[pyo3(signature = (method, task, seed, steps, out, *, threads=1, preset="cpu", env=None, eval_every=2000, eval_episodes=50, policy=None, edp_kernel=None, ent_init=None, utd=None, terminate_on_success=false, noise_aliased=false, target_entropy=None, prior_kl=None, reward_scale=None, select=None, progress=false, stop_after_evals=None))]
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
    env: Option<&Bound<'py, PyDict>>,
    eval_every: usize,
    eval_episodes: usize,
    policy: Option<PathBuf>,
    edp_kernel: Option<&str>,
    ent_init: Option<f64>,
    utd: Option<usize>,
    terminate_on_success: bool,
    noise_aliased: bool,
    target_entropy: Option<f64>,
    prior_kl: Option<f64>,
    reward_scale: Option<f64>,
    select: Option<usize>,
    progress: bool,
    stop_after_evals: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut cfg = RunConfig::new(Method::parse(method).map_err(to_py)?, task, seed, steps, out).map_err(to_py)?;
    cfg.threads = threads;
    cfg.preset = Preset::named(preset).map_err(to_py)?;
    cfg.env = env_options(env)?;
    cfg.eval_every = eval_every;
    cfg.eval_episodes = eval_episodes;
    cfg.policy = policy;
    cfg.edp_kernel = crate::policy::kernel(edp_kernel)?;
    cfg.ent_init = ent_init;
    cfg.utd = utd;
    cfg.terminate_on_success = terminate_on_success;
    cfg.noise_aliased = noise_aliased;
    cfg.target_entropy = target_entropy;
    cfg.prior_kl = prior_kl;
    cfg.reward_scale = reward_scale;
    cfg.select = select;
    cfg.progress = progress;
    cfg.stop_after_evals = stop_after_evals;
    let s = py.detach(|| run(&cfg)).map_err(to_py)?;
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
    d.set_item("seconds_by_activity", split)?;
    d.set_item("eval_env_steps", s.eval_env_steps)?;
    d.set_item("params_hash", format!("{:016x}", s.params_hash))?;
    d.set_item("fields", s.fields)?;
    d.set_item("params_actor", s.params_actor)?;
    d.set_item("params_critic", s.params_critic)?;
    Ok(d)
}

/// The base policy on the pinned evaluation starts (seeds `EVAL_SEED + k`) with latent noise
/// N(0, scale^2 I) clipped to the bound, as a steering run of the same settings evaluates its
/// actor (`equigym_agents::evaluation`); `seed` seeds the noise streams. Returns a dict: task,
/// policy, scale, seed, first_start, successes / episodes / success_rate / low / high (Wilson
/// 95 %), and `outcomes`, one bool per episode in start order.
#[pyfunction]
#[pyo3(signature = (task, *, seed=0, episodes=200, scale=1.0, policy=None, edp_kernel=None, env=None, threads=1))]
#[allow(clippy::too_many_arguments)]
pub fn evaluate_base<'py>(
    py: Python<'py>,
    task: &str,
    seed: u64,
    episodes: usize,
    scale: f64,
    policy: Option<PathBuf>,
    edp_kernel: Option<&str>,
    env: Option<&Bound<'py, PyDict>>,
    threads: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let mut cfg = RunConfig::new(Method::Dsrl, task, seed, 0, PathBuf::new()).map_err(to_py)?;
    cfg.eval_episodes = episodes;
    cfg.policy = policy;
    cfg.edp_kernel = crate::policy::kernel(edp_kernel)?;
    cfg.env = env_options(env)?;
    cfg.threads = threads;
    let e = py.detach(|| base_evaluation(&cfg, scale)).map_err(to_py)?;
    let d = PyDict::new(py);
    d.set_item("task", &e.task)?;
    d.set_item("policy", &e.policy)?;
    d.set_item("scale", e.scale)?;
    d.set_item("seed", e.seed)?;
    d.set_item("first_start", e.first_start)?;
    d.set_item("successes", e.rate.successes)?;
    d.set_item("episodes", e.rate.n)?;
    d.set_item("success_rate", e.rate.rate)?;
    d.set_item("low", e.rate.low)?;
    d.set_item("high", e.rate.high)?;
    d.set_item("outcomes", e.successes)?;
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
) -> PyResult<Bound<'py, PyAny>> {
    let c =
        equigym_agents::gradcheck::grad_case(Method::parse(method).map_err(to_py)?, task, seed, rows).map_err(to_py)?;
    Ok(pythonize::pythonize(py, &c)?)
}
