"""What a user of the installed package relies on: one exception hierarchy that pickles, one
options type (unknown options refused, ``horizon`` honoured through ``gymnasium.make``), envs
that pickle and deep-copy with their full state, multiprocess vector envs, shipped assets and a
stub file that matches the extension module."""

import copy
import pickle
import subprocess
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import equigym
from equigym import errors

ALL_IDS = list(equigym.ENV_IDS) + list(equigym.LATENT_ENV_IDS)
#: Steps before and after the copy in the continuation tests.
STEPS_BEFORE, STEPS_AFTER = 3, 4


def _actions(env, n, seed):
    space = env.action_space
    space.seed(seed)
    return [space.sample() for _ in range(n)]


# -- errors ---------------------------------------------------------------------------------
def test_every_exception_is_an_equigym_error_and_pickles():
    for name in errors.__all__:
        cls = getattr(equigym, name)
        assert cls is getattr(errors, name) and issubclass(cls, equigym.EquigymError)
        back = pickle.loads(pickle.dumps(cls("message")))
        assert type(back) is cls and str(back) == "message"
    assert issubclass(equigym.ResetNeeded, RuntimeError)
    assert issubclass(equigym.MissingFileError, FileNotFoundError)
    for name in ("InvalidInputError", "UrdfError", "InvalidStateError", "PolicyError"):
        assert issubclass(getattr(equigym, name), ValueError)


def test_rust_errors_arrive_as_the_python_classes(tmp_path):
    core = equigym.CoreEnv("lift")
    with pytest.raises(equigym.ResetNeeded) as reset_needed:
        core.step(np.zeros(10))
    assert type(pickle.loads(pickle.dumps(reset_needed.value))) is equigym.ResetNeeded
    with pytest.raises(equigym.MissingFileError) as missing:
        equigym.CoreEnv("lift", urdf=str(tmp_path / "none.urdf"))
    # Chosen from the typed error, with the path in the exception's own attribute.
    assert missing.value.filename == str(tmp_path / "none.urdf")
    with pytest.raises(equigym.InvalidInputError, match="unknown field `gravity`"):
        equigym.CoreEnv("lift", physics={"gravity": 1.0})
    with pytest.raises(equigym.InvalidInputError, match="unknown field `horizn`"):
        equigym.CoreEnv("lift", horizn=5)
    with pytest.raises(equigym.InvalidInputError, match="not finite"):
        equigym.CoreEnv("lift", init_joint_noise=float("nan"))
    with pytest.raises(equigym.InvalidInputError, match="controller must be 'joint' or 'cartesian', got 'telepathic'"):
        equigym.CoreEnv("lift", controller="telepathic")
    # An option a class cannot honour is refused, not dropped.
    with pytest.raises(equigym.InvalidInputError, match="reward must be 'sparse'"):
        gymnasium.make("EquiLift-Latent-v0", reward="dense")


# -- options --------------------------------------------------------------------------------
def test_options_reach_every_environment_class():
    opts = {"horizon": 7, "physics": {"substeps": 6}, "controller": "cartesian", "joint_limits": False}
    single = equigym.CoreEnv("lift", **opts)
    vec = equigym._core.VecEnv("lift", 2, threads=1, **opts)
    for spec in (single.spec, vec.spec):
        assert spec.horizon == 7 and spec.control_period == pytest.approx(6 / 240)
    kwargs = single.__getnewargs_ex__()[1]
    assert kwargs["controller"] == "cartesian" and kwargs["physics"]["joint_limits"] is False


@pytest.mark.parametrize("env_id", ["EquiLift-v0", "EquiLift-Latent-v0"])
def test_horizon_beyond_400_is_not_cut(env_id):
    env = gymnasium.make(env_id, horizon=440)
    assert env.unwrapped.horizon == 440
    env.reset(seed=0)
    steps, truncated = 0, False
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    if env_id == "EquiLift-v0":
        action = env.unwrapped.core.current_target().astype(np.float32)
    while not truncated:
        *_, truncated, info = env.step(action)
        steps += info.get("executed", 1)
    assert steps == 440


# -- pickling and copies ---------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ALL_IDS)
@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_envs_copy_with_their_full_state(env_id, how):
    env = gymnasium.make(env_id)
    env.reset(seed=5)
    for a in _actions(env, STEPS_BEFORE, 0):
        env.step(a)
    twin = pickle.loads(pickle.dumps(env)) if how == "pickle" else copy.deepcopy(env)
    assert type(twin.unwrapped) is type(env.unwrapped)
    for a in _actions(env, STEPS_AFTER, 1):
        want, got = env.step(a), twin.step(a)
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1:4] == want[1:4]
    # The gymnasium RNG came along too: unseeded resets draw the same episode.
    assert twin.reset()[1]["episode_seed"] == env.reset()[1]["episode_seed"]


def test_policies_pickle_as_their_bytes():
    policy = equigym.DiffusionPolicy(equigym.policy_path("lift"))
    back = pickle.loads(pickle.dumps(policy))
    obs = np.stack([equigym.CoreEnv("lift").reset(s) for s in range(2)])
    w = np.random.default_rng(0).normal(size=(2, policy.action_dim))
    np.testing.assert_array_equal(back.sample(obs, w), policy.sample(obs, w))


# -- multiprocess vector envs ------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ALL_IDS)
def test_async_vector_env_runs_every_id(env_id):
    envs = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(f"equigym:{env_id}")] * 2, context="spawn")
    try:
        obs, info = envs.reset(seed=3)
        ref = gymnasium.make(env_id)
        np.testing.assert_array_equal(obs[1], ref.reset(seed=4)[0])
        envs.action_space.seed(0)
        obs, rewards, term, trunc, info = envs.step(envs.action_space.sample())
        assert obs.shape[0] == 2 and np.all(np.isfinite(obs))
    finally:
        envs.close()


@pytest.mark.parametrize("env_id", ["EquiLift-v0", "EquiSquare-Latent-v0"])
def test_sb3_subproc_vec_env_runs(env_id):
    vec_env = pytest.importorskip("stable_baselines3.common.vec_env")
    # A fresh (forkserver) process imports equigym through the "module:id" form of the id.
    envs = vec_env.SubprocVecEnv([lambda: gymnasium.make(f"equigym:{env_id}")] * 2)
    try:
        obs = envs.reset()
        envs.step_async(np.stack([envs.action_space.sample() for _ in range(2)]))
        obs, rewards, dones, infos = envs.step_wait()
        assert obs.shape[0] == 2 and np.all(np.isfinite(obs)) and len(infos) == 2
    finally:
        envs.close()


# -- assets and stubs -------------------------------------------------------------------------
def test_shipped_files_are_found_inside_the_package():
    package = equigym.asset_path("panda", "panda.urdf").resolve()
    assert package.is_file() and package == equigym.urdf_path().resolve()
    for task in equigym.TASK_IDS:
        assert equigym.DiffusionPolicy(equigym.policy_path(task)).task == task
    with pytest.raises(equigym.MissingFileError, match="no shipped diffusion policy"):
        equigym.policy_path("juggle")


def test_stub_file_matches_the_extension_module():
    pytest.importorskip("mypy")
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "equigym._core", "--allowlist", "tests/stubtest_allowlist.txt"],
        capture_output=True,
        text=True,
        cwd=root,
    )
    assert result.returncode == 0, result.stdout + result.stderr
