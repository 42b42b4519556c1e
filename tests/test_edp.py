"""Demonstrations, the equivariant diffusion policy (training, export, Rust runtime) and the
latent-action environments."""

import json
import pickle

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import equigym
from equigym import DiffusionPolicy, PolicyError, Symmetry

torch = pytest.importorskip("torch")
pytest.importorskip("escnn")
h5py = pytest.importorskip("h5py")

from baselines.edp import EDPConfig, ExportedPolicy, build_net, count_params, train  # noqa: E402
from equigym.demos import load, record  # noqa: E402


@pytest.fixture(scope="module")
def lift_demos(tmp_path_factory):
    path = tmp_path_factory.mktemp("demos") / "lift.hdf5"
    summary = record("lift", 3, path, progress=False)
    assert summary["kept"] == 3
    return path


@pytest.fixture(scope="module")
def tiny_policy(lift_demos, tmp_path_factory):
    out = tmp_path_factory.mktemp("edp") / "lift.safetensors"
    cfg = EDPConfig(steps=30, hidden_fields=4, hidden_layers=2, batch_size=32)
    train(cfg, lift_demos, out, progress=False)
    return out


def test_killed_training_resumes_bitwise_from_its_checkpoint(lift_demos, tmp_path):
    cfg = dict(steps=12, hidden_fields=2, hidden_layers=1, batch_size=16)
    whole, parts = tmp_path / "whole.safetensors", tmp_path / "parts.safetensors"
    train(EDPConfig(**cfg), lift_demos, whole, progress=False, checkpoint_every=4)
    # Stopped after 5 steps (mid-interval, checkpointed there), then resumed to the end.
    assert train(EDPConfig(**cfg), lift_demos, parts, progress=False, checkpoint_every=4, stop_after=5) == {
        "stopped_at": 5
    }
    assert not parts.exists()
    train(EDPConfig(**cfg), lift_demos, parts, progress=False, checkpoint_every=4)
    a = torch.load(whole.with_suffix(".ckpt"), weights_only=False)
    b = torch.load(parts.with_suffix(".ckpt"), weights_only=False)
    assert a["step"] == b["step"] == 12 and a["losses"] == b["losses"]
    for k in a["ema"]:
        assert torch.equal(a["ema"][k], b["ema"][k]), k
    # A different config does not pick up the checkpoint: it starts from step 0.
    other = EDPConfig(**{**cfg, "lr": 5e-4})
    stopped = train(other, lift_demos, parts, progress=False, checkpoint_every=4, stop_after=2)
    assert stopped == {"stopped_at": 2}


def test_demos_use_robomimics_layout(lift_demos):
    with h5py.File(lift_demos) as f:
        env_args = json.loads(f["data"].attrs["env_args"])
        assert env_args["env_name"] == "EquiLift-v0"
        demo = f["data/demo_0"]
        n = demo.attrs["num_samples"]
        assert demo["actions"].shape == (n, 10)
        assert demo["obs/cube_pos"].shape == (n, 3) and demo["obs/gripper_rot6d"].shape == (n, 6)
        assert demo["rewards"].shape == (n,) and demo["dones"][-1] == 1 and demo["rewards"][-1] == 1
        assert f["data"].attrs["total"] == sum(f[f"data/demo_{i}"].attrs["num_samples"] for i in range(3))
    data = load(lift_demos)
    assert data["task"] == "lift" and data["demos"][0]["obs"].shape[1] == 22
    # Replaying the recorded actions from the recorded seed reproduces the demo exactly.
    env = equigym.CoreEnv("lift")
    d = data["demos"][1]
    obs = [env.reset(d["seed"])]
    for a in d["actions"][:-1]:
        obs.append(env.step(a)[0])
    np.testing.assert_array_equal(np.asarray(obs, dtype=np.float32), d["obs"].astype(np.float32))


def test_rust_runtime_matches_pytorch(tiny_policy):
    # The dense kernel runs the file's own matrices: PyTorch's float64 map to 1e-9.
    policy = DiffusionPolicy(tiny_policy, kernel="dense")
    assert policy.task == "lift" and policy.chunk_len == 4 and policy.action_dim == 40 and policy.group == "C8"
    rng = np.random.default_rng(0)
    env = equigym.CoreEnv("lift")
    obs = np.stack([env.reset(s) for s in range(8)])
    w = rng.normal(size=(8, 40))
    rust64 = policy.sample(obs, w, precision="f64").reshape(8, 40)
    np.testing.assert_allclose(rust64, ExportedPolicy(tiny_policy, torch.float64).sample(obs, w), atol=1e-9)
    rust = policy.sample(obs, w).reshape(8, 40)  # float32 network, the default
    np.testing.assert_allclose(rust, ExportedPolicy(tiny_policy, torch.float32).sample(obs, w), atol=1e-4)
    np.testing.assert_allclose(rust, rust64, atol=1e-4)
    # Other step counts work; 0 is an error.
    assert policy.sample(obs, w, steps=10).shape == (8, 4, 10)
    with pytest.raises(ValueError, match="DDIM steps"):
        policy.sample(obs, w, steps=0)
    # The default kernel runs the C8 hidden layers in the Fourier basis, projected from the file's
    # blocks (circulant to float32 rounding): the same map up to that rounding.
    fourier = DiffusionPolicy(tiny_policy)
    assert fourier.kernel == "fourier" and fourier.fourier_layers
    assert not np.array_equal(fourier.sample(obs, w), policy.sample(obs, w))
    np.testing.assert_allclose(fourier.sample(obs, w, precision="f64").reshape(8, 40), rust64, atol=1e-5)
    np.testing.assert_allclose(fourier.sample(obs, w).reshape(8, 40), rust64, atol=1e-4)
    assert [pickle.loads(pickle.dumps(p)).kernel for p in (policy, fourier)] == ["dense", "fourier"]
    with pytest.raises(ValueError, match="kernel must be"):
        DiffusionPolicy(tiny_policy, kernel="fft")


def test_loaded_policy_is_equivariant(tiny_policy):
    policy = DiffusionPolicy(tiny_policy)
    sym = Symmetry("lift")
    rng = np.random.default_rng(1)
    env = equigym.CoreEnv("lift")
    obs = np.stack([env.reset(s) for s in range(6)])
    w = rng.normal(size=(6, 40))
    chunk = policy.sample(obs, w).reshape(6, 40)
    for g in sym.elements:
        rotated = policy.sample(sym.act_observation(obs, g=g), sym.act_latent(w, g=g)).reshape(6, 40)
        np.testing.assert_allclose(rotated, sym.act_chunk(chunk, g=g), atol=1e-4)


def _equivariance_error(net, sym, cfg) -> float:
    """max over the group of |f(g x) - g f(x)| for the noise network's [obs, x_t, t-embedding] input."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    env = equigym.CoreEnv("lift")
    obs = np.stack([env.reset(s) for s in range(4)])
    chunk = rng.normal(size=(4, sym.dim("chunk")))
    emb = rng.normal(size=(4, cfg.time_dim))
    net.eval()

    def f(o, c):
        x = torch.as_tensor(np.concatenate([o, c, emb], axis=1), dtype=torch.float32)
        with torch.no_grad():
            return net(x).double().numpy()

    out = f(obs, chunk)
    return max(
        float(np.abs(f(sym.act_observation(obs, g=g), sym.act_chunk(chunk, g=g)) - sym.act_chunk(out, g=g)).max())
        for g in sym.elements
    )


def test_plain_variant_has_a_similar_size_and_is_not_equivariant():
    sym = Symmetry("lift")
    equi_cfg, plain_cfg = EDPConfig(hidden_fields=8), EDPConfig(hidden_fields=8, equivariant=False)
    equi, plain = build_net(equi_cfg, sym), build_net(plain_cfg, sym)
    assert abs(count_params(plain) - count_params(equi)) / count_params(equi) < 0.1
    # The equivariant net commutes with every rotation; the --plain one visibly does not.
    assert _equivariance_error(equi, sym, equi_cfg) < 1e-4
    assert _equivariance_error(plain, sym, plain_cfg) > 1e-2


def test_bad_policy_files_give_clear_errors(tiny_policy, tmp_path):
    data = tiny_policy.read_bytes()
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(PolicyError, match="truncated"):
        DiffusionPolicy(truncated)
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"not a policy at all")
    with pytest.raises(PolicyError):
        DiffusionPolicy(garbage)
    with pytest.raises(FileNotFoundError):
        DiffusionPolicy(tmp_path / "missing.safetensors")
    with pytest.raises(PolicyError, match="trained for task 'lift'"):
        gymnasium.make("EquiStack-Latent-v0", policy=tiny_policy)
    policy = DiffusionPolicy(tiny_policy)
    with pytest.raises(ValueError, match="expected obs"):
        policy.sample(np.zeros((2, 21)), np.zeros((2, 40)))
    with pytest.raises(ValueError, match="not finite"):
        policy.sample(np.zeros((1, 22)), np.full((1, 40), np.nan))


def test_latent_env_api_reward_and_horizon(tiny_policy):
    env = gymnasium.make("EquiLift-Latent-v0", policy=tiny_policy, horizon=10)
    check_env(env.unwrapped)
    assert env.action_space.shape == (40,) and env.action_space.high[0] == 1.5
    obs, _ = env.reset(seed=0)
    executed, rewards = [], []
    for _ in range(3):
        obs, r, term, trunc, info = env.step(env.action_space.sample())
        executed.append(info["executed"])
        rewards.append(r)
    assert executed == [4, 4, 2] and trunc and not term
    assert all(-info_e <= r <= 0 for r, info_e in zip(rewards, executed))
    with pytest.raises(equigym.ResetNeeded):
        env.step(np.zeros(40))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(39))


def test_latent_env_denoises_once_per_step_and_is_deterministic(tiny_policy):
    env = gymnasium.make("EquiLift-Latent-v0", policy=tiny_policy).unwrapped
    w = np.random.default_rng(2).uniform(-1.5, 1.5, size=(5, 40))
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=7)
        trace = [obs]
        for wi in w:
            chunk = env.decode(wi)
            trace.append(env.step(wi)[0])
            # The chunk executed is the one decoded from the observation before the step.
            np.testing.assert_array_equal(env.core.last_chunk().reshape(4, 10), chunk)
        runs.append(np.stack(trace))
    np.testing.assert_array_equal(runs[0], runs[1])
    # Latent actions beyond the bound are clipped to it.
    env.reset(seed=1)
    np.testing.assert_array_equal(env.decode(np.full(40, 9.0)), env.decode(np.full(40, 1.5)))


def test_latent_envs_run_in_vector_envs(tiny_policy):
    envs = gymnasium.make_vec("EquiLift-Latent-v0", num_envs=3, vectorization_mode="sync", policy=tiny_policy)
    obs, _ = envs.reset(seed=5)
    assert obs.shape == (3, 22)
    obs2, rewards, term, trunc, info = envs.step(np.zeros((3, 40), dtype=np.float32))
    assert rewards.shape == (3,) and np.all(info["executed"] == 4)
    # Sub-env i is seeded with 5 + i, like a single env with that seed.
    single = gymnasium.make("EquiLift-Latent-v0", policy=tiny_policy)
    o, _ = single.reset(seed=6)
    np.testing.assert_array_equal(obs[1], o)


def test_native_latent_vector_env_equals_single_envs(tiny_policy):
    """make_vec runs the latent envs natively (one batched DDIM per step) and gives, bit for bit,
    what B single latent envs give with the same seeds and latent actions, for any thread count."""
    from equigym.latent import EquiLatentVectorEnv

    n, steps = 5, 4
    rng = np.random.default_rng(1)
    latents = [rng.standard_normal((n, 40)).astype(np.float32) for _ in range(steps)]
    singles = []
    for k in range(n):
        env = gymnasium.make("EquiLift-Latent-v0", policy=tiny_policy, horizon=12)
        rows = [env.reset(seed=20 + k)[0]]
        for t in range(3):
            obs, reward, term, trunc, info = env.step(latents[t][k])
            rows.append((obs, reward, trunc, info["executed"]))
        singles.append(rows)
    for threads in (1, 2):
        envs = gymnasium.make_vec("EquiLift-Latent-v0", num_envs=n, policy=tiny_policy, horizon=12, threads=threads)
        assert isinstance(envs.unwrapped, EquiLatentVectorEnv)
        assert envs.single_action_space.shape == (40,) and envs.single_action_space.high[0] == np.float32(1.5)
        obs, info = envs.reset(seed=20)
        assert list(info["episode_seed"]) == [20 + k for k in range(n)]
        for k in range(n):
            np.testing.assert_array_equal(obs[k], singles[k][0])
        for t in range(3):
            obs, rewards, term, trunc, info = envs.step(latents[t])
            for k in range(n):
                s_obs, s_reward, s_trunc, s_exec = singles[k][t + 1]
                np.testing.assert_array_equal(obs[k], s_obs)
                assert rewards[k] == s_reward and trunc[k] == s_trunc and info["executed"][k] == s_exec
        assert trunc.all()  # horizon 12 = three chunks of four
        assert envs.unwrapped.last_chunks().shape == (n, 4, 10)
        # Next-step auto-reset: the following step resets every sub-env with reward 0.
        obs, rewards, term, trunc, info = envs.step(latents[3])
        assert info["_episode_seed"].all() and not rewards.any() and not info["executed"].any()
        with pytest.raises(ValueError, match="shape"):
            envs.step(np.zeros((n, 39)))
        bad = np.zeros((n, 40))
        bad[2, 3] = np.nan
        with pytest.raises(ValueError, match="environment 2"):
            envs.step(bad)
        envs.close()


def test_sb3_adapter_runs_latent_envs(tiny_policy):
    pytest.importorskip("stable_baselines3")
    from equigym.sb3 import EquiVecEnv

    venv = EquiVecEnv("EquiLift-Latent-v0", num_envs=2, policy=tiny_policy, horizon=8)
    venv.seed(3)
    obs = venv.reset()
    assert obs.shape == (2, 22)
    for _ in range(2):
        obs, rewards, dones, infos = venv.step(np.zeros((2, 40), dtype=np.float32))
    assert dones.all() and all(i["TimeLimit.truncated"] and i["executed"] == 4 for i in infos)
    assert all(i["terminal_observation"].shape == (22,) for i in infos)


def test_demos_can_hold_the_object_after_success(tmp_path):
    # hold_steps more expert steps after the first success, each demo still successful at its
    # end (the expert keeps the cube up); 0 keeps the demos as they were.
    import h5py

    record("lift", 2, tmp_path / "plain.hdf5", progress=False)
    record("lift", 2, tmp_path / "hold.hdf5", progress=False, hold_steps=7)
    with h5py.File(tmp_path / "plain.hdf5") as p, h5py.File(tmp_path / "hold.hdf5") as h:
        for k in ("demo_0", "demo_1"):
            assert h["data"][k].attrs["num_samples"] == p["data"][k].attrs["num_samples"] + 7
            assert h["data"][k].attrs["success"] and h["data"][k]["rewards"][-1] == 1.0
            n = p["data"][k].attrs["num_samples"]
            assert (h["data"][k]["actions"][:n] == p["data"][k]["actions"][:]).all()
    with pytest.raises(ValueError, match="hold_steps"):
        record("lift", 1, tmp_path / "bad.hdf5", progress=False, hold_steps=-1)


def test_base_evaluation_runs_on_the_pinned_starts_with_wilson_intervals():
    """``baselines.edp.evaluate`` (the shipped policies' base-success figure) runs the Rust
    evaluation protocol on the starts EVAL_SEED + k: the same outcomes for any thread count, a
    Wilson interval around the rate, and each episode as the latent env plays it from its start."""
    from baselines.edp import evaluate
    from equigym import _core
    from equigym.assets import asset_path

    policy = asset_path("edp", "lift.safetensors")
    res = evaluate(policy, episodes=6, horizon=80)
    assert res["first_start"] == _core.EVAL_SEED == 10_000
    assert res["episodes"] == 6 and len(res["outcomes"]) == 6
    assert res["successes"] == sum(res["outcomes"])
    assert res["low"] - 1e-12 <= res["success_rate"] <= res["high"]
    assert evaluate(policy, episodes=6, horizon=80, threads=2) == res
    # Scale 0 is the mean noise: one deterministic rollout per start, replayed here by hand.
    zero = evaluate(policy, episodes=3, scale=0.0, horizon=80)
    env = _core.LatentEnv("lift", _core.DiffusionPolicy(str(policy)), horizon=80)
    for k, outcome in enumerate(zero["outcomes"]):
        env.reset(_core.EVAL_SEED + k)
        success = False
        while True:
            _, _, term, trunc, info = env.step(np.zeros(env.latent_dim))
            success |= info["success"]
            if success or term or trunc:
                break
        assert success == outcome, k
    with pytest.raises(ValueError, match="noise scale"):
        evaluate(policy, episodes=2, scale=-1.0)


def test_predictability_separates_markov_actions_from_motion_dependent_ones(monkeypatch):
    """``baselines.edp predictability``: an action that is a smooth function of the observation
    is predicted on held-out demos (normalised error near 0, with or without history); one that
    is the observation's last change (a velocity the observation does not show) is not, until
    one step of history is given."""
    import baselines.edp as edp

    rng = np.random.default_rng(1)
    demos = []
    for _ in range(10):
        o = np.cumsum(rng.normal(size=(60, 3)) * 0.1, axis=0)
        vel = np.diff(o, axis=0, prepend=o[:1])
        demos.append({"obs": o, "actions": np.concatenate([np.tanh(o), vel], axis=1)})
    monkeypatch.setattr(edp, "load_demos", lambda path: {"demos": demos})
    rows = edp.predictability("synthetic", (0, 1), features=512)
    assert [r["history"] for r in rows] == [0, 1] and all(len(r["nmse"]) == 6 for r in rows)
    smooth0, vel0 = rows[0]["nmse"][:3], rows[0]["nmse"][3:]
    smooth1, vel1 = rows[1]["nmse"][:3], rows[1]["nmse"][3:]
    assert max(smooth0) < 0.2 and max(smooth1) < 0.2
    assert min(vel0) > 0.8, "without history the velocity is not in the observation"
    assert max(vel1) < 0.1
    assert edp.predictability("synthetic", (0,), features=512)[0] == rows[0]
    with pytest.raises(ValueError, match="held-out groups"):
        edp.predictability("synthetic", (0,), folds=20)


def test_dart_demos_record_the_clean_command_while_executing_a_perturbed_one(tmp_path):
    # Execution noise moves the arm off the expert's path (other states), while the recorded
    # actions stay the expert's own commands: no noise in the labels.
    record("lift", 1, tmp_path / "clean.hdf5", progress=False)
    record("lift", 1, tmp_path / "dart.hdf5", progress=False, execution_noise=0.01)
    with h5py.File(tmp_path / "clean.hdf5") as c, h5py.File(tmp_path / "dart.hdf5") as d:
        assert json.loads(d["data"].attrs["expert"])["execution_noise"] == 0.01
        oc, od = c["data/demo_0/obs/gripper_pos"][:], d["data/demo_0/obs/gripper_pos"][:]
        n = min(len(oc), len(od))
        assert np.abs(oc[:n] - od[:n]).max() > 0.003
        # While it approaches the cube (which has not moved) the expert's command does not depend
        # on where the arm is, so the recorded commands equal the clean demo's bit for bit.
        np.testing.assert_array_equal(d["data/demo_0/actions"][:5], c["data/demo_0/actions"][:5])
    with pytest.raises(ValueError, match="execution_noise"):
        record("lift", 1, tmp_path / "bad.hdf5", progress=False, execution_noise=-1.0)


def test_carry_direction_counts_only_commands_that_head_for_the_target():
    from baselines.edp import toward_target

    fields = {"nut_pos": 0, "peg_pos": 3, "gripper_pos": 6}
    obs = np.zeros((4, 9))
    obs[:, 3:5] = [0.3, 0.0]  # the peg, 30 cm along x
    obs[1:, 2] = obs[1:, 8] = 0.1  # steps 1-3: the nut raised 10 cm, in the hand
    actions = np.zeros((4, 10))
    actions[:, :2] = [[0.02, 0.0], [0.02, 0.0], [-0.02, 0.0], [0.0, 0.001]]
    # Step 0 is at the start height, step 3 barely moves: of steps 1 (towards) and 2 (away), one.
    assert toward_target(obs, actions, fields, "square") == (1, 2)
    assert toward_target(obs, actions, fields, "lift") == (0, 0)


def test_expert_under_execution_noise_counts_failures_by_phase():
    from baselines.edp import expert_under_noise

    clean = expert_under_noise("lift", 2, 0.0)
    assert clean["successes"] == 2 and clean["failed_in_phase"] == {}
    # 5 cm of position noise: the fingers miss the 5 cm cube, and each failure names its phases.
    noisy = expert_under_noise("lift", 2, 0.05)
    assert noisy["successes"] < 2
    assert sum(noisy["failed_in_phase"].values()) == 2 - noisy["successes"]
    assert all(p.startswith("approach") for p in noisy["failure_paths"])


def test_history_conditioned_policy_stays_equivariant(lift_demos, tmp_path):
    from baselines.edp import conditioning

    out = tmp_path / "h2.safetensors"
    train(
        EDPConfig(steps=20, hidden_fields=4, hidden_layers=2, batch_size=32, obs_history=2),
        lift_demos,
        out,
        progress=False,
    )
    policy = DiffusionPolicy(out)
    assert policy.metadata["obs_history"] == "2"
    # The latent environments hold one observation: they refuse the file, saying why.
    with pytest.raises(PolicyError, match="obs_history"):
        equigym._core.LatentEnv("lift", str(out))
    sym = Symmetry("lift")
    env = equigym.CoreEnv("lift")
    obs = np.stack([env.reset(s) for s in range(4)])
    rng = np.random.default_rng(2)
    prev = obs + rng.normal(scale=0.01, size=obs.shape)
    w = rng.normal(size=(4, 40))
    chunk = policy.sample(conditioning(obs, prev, 2), w)
    assert policy.obs_dim == 2 * obs.shape[1]
    for g in sym.elements:
        cond = conditioning(sym.act_observation(obs, g=g), sym.act_observation(prev, g=g), 2)
        np.testing.assert_allclose(policy.sample(cond, sym.act_latent(w, g=g)), sym.act_chunk(chunk, g=g), atol=1e-4)


def test_failure_breakdown_accounts_for_every_episode(tiny_policy):
    from baselines.edp import EVAL_EPISODES, FAILURE_KINDS, VALIDATION_SEED, failures

    res = failures(tiny_policy, episodes=3)
    assert res["task"] == "lift" and len(res["outcomes"]) == 3
    assert set(res["outcomes"]) <= set(FAILURE_KINDS)
    assert sum(res["counts"].values()) == 3
    # Lift has no place target: no episode can reach one, no step carries towards one.
    assert res["reached_target"] == 0 and res["carry_steps"] == res["toward_target"] == 0
    assert res["low"] - 1e-12 <= res["success_rate"] <= res["high"]
    # The same noise seed gives the same outcomes (the rollouts are deterministic).
    assert failures(tiny_policy, episodes=3)["outcomes"] == res["outcomes"]
    # Snapping the width commands to grasp / open changes what runs, not the bookkeeping.
    snapped = failures(tiny_policy, episodes=3, snap_gripper=True)
    assert snapped["snap_gripper"] and sum(snapped["counts"].values()) == 3
    # Model choice runs on validation starts, apart from the pinned evaluation starts.
    assert res["first_start"] == equigym._core.EVAL_SEED
    assert failures(tiny_policy, episodes=1, first_start=VALIDATION_SEED)["first_start"] == VALIDATION_SEED
    assert VALIDATION_SEED >= equigym._core.EVAL_SEED + 10 * EVAL_EPISODES


@pytest.mark.parametrize("task", ["lift", "stack", "square"])
def test_shipped_policies_are_equivariant_and_match_the_trainers_export(task):
    # On real states (resets of the policy's own variant, then a few steps of it) and random
    # noises: rotating the state and the noise rotates the chunk, to 1e-4; and the Rust runtime
    # gives the exported file's chunks as the trainer's float64 reference sampler does.
    from equigym.assets import asset_path

    path = asset_path("edp", f"{task}.safetensors")
    policy = DiffusionPolicy(path, kernel="dense")  # the file's own matrices
    sym = Symmetry(task)
    env = equigym.CoreEnv(task, variant=policy.metadata.get("variant") or None)
    rng = np.random.default_rng(3)
    obs = []
    for s in range(3):
        o = env.reset(s)
        obs.append(o)
        w = rng.normal(size=(1, policy.action_dim)).clip(-1.5, 1.5)
        for a in policy.sample(o[None], w).reshape(-1, 10):
            o = env.step(a)[0]
        obs.append(o)
    obs = np.stack(obs)
    w = rng.normal(size=(len(obs), policy.action_dim)).clip(-1.5, 1.5)
    n = len(obs)
    chunk = policy.sample(obs, w, precision="f64").reshape(n, -1)
    np.testing.assert_allclose(chunk, ExportedPolicy(path).sample(obs, w).reshape(n, -1), atol=1e-6)
    # The default (Fourier) kernel: the same map to the float32 rounding of the file's blocks.
    fourier = DiffusionPolicy(path)
    np.testing.assert_allclose(fourier.sample(obs, w, precision="f64").reshape(n, -1), chunk, atol=1e-5)
    for p in (policy, fourier):
        base = p.sample(obs, w, precision="f64").reshape(n, -1)
        for g in sym.elements:
            rotated = p.sample(sym.act_observation(obs, g=g), sym.act_latent(w, g=g), precision="f64")
            np.testing.assert_allclose(rotated.reshape(n, -1), sym.act_chunk(base, g=g), atol=1e-4)
