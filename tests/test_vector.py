"""Native vector environments: make_vec, determinism against single envs, auto-reset, errors, SB3."""

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import equigym
from equigym import EquiVectorEnv


def random_actions(space, steps, seed):
    space.seed(seed)
    return [space.sample() for _ in range(steps)]


@pytest.mark.parametrize("env_id", ["EquiLift-v0", "EquiStack-v0", "EquiSquare-v0"])
def test_make_vec_uses_the_native_vector_env(env_id):
    envs = gymnasium.make_vec(env_id, num_envs=3)
    assert isinstance(envs.unwrapped, EquiVectorEnv)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert envs.render_mode is None
    assert envs.horizon == 400
    single = gymnasium.make(env_id)
    assert envs.single_observation_space == single.observation_space
    assert envs.single_action_space == single.action_space
    assert envs.observation_space.shape == (3, *single.observation_space.shape)
    obs, info = envs.reset(seed=5)
    assert obs.shape == (3, single.observation_space.shape[0]) and obs.dtype == np.float32
    assert obs in envs.observation_space
    assert list(info["episode_seed"]) == [5, 6, 7]
    obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert obs.shape == envs.observation_space.shape and obs.dtype == np.float32
    assert rewards.shape == terminated.shape == truncated.shape == (3,)
    assert terminated.dtype == truncated.dtype == np.bool_
    assert info["success"].shape == (3,) and info["_success"].all()
    envs.close()


def test_same_seeds_give_the_same_rollouts_as_single_envs():
    n, steps = 4, 12
    envs = gymnasium.make_vec("EquiStack-v0", num_envs=n, threads=2, variant="D0")
    singles = [gymnasium.make("EquiStack-v0", variant="D0").unwrapped for _ in range(n)]
    seeds = [11, 3, 3, 42]
    obs, _ = envs.reset(seed=seeds)
    for i, env in enumerate(singles):
        o, _ = env.reset(seed=seeds[i])
        np.testing.assert_array_equal(obs[i], o)
    for a in random_actions(envs.action_space, steps, 0):
        obs, rewards, terminated, truncated, _ = envs.step(a)
        for i, env in enumerate(singles):
            o, r, te, tr, _ = env.step(a[i])
            assert obs[i].tobytes() == o.tobytes()
            assert (rewards[i], terminated[i], truncated[i]) == (r, te, tr)
    # Equal seeds, equal actions: equal rows.
    np.testing.assert_array_equal(obs[1], singles[1].core.observe().astype(np.float32))


def test_results_do_not_depend_on_the_thread_count():
    runs = []
    for threads in (1, 2):
        envs = EquiVectorEnv("lift", 6, threads=threads, horizon=5)
        assert envs.threads == threads
        envs.reset(seed=0)
        out = []
        for a in random_actions(envs.action_space, 12, 1):
            out.append([x.tobytes() if isinstance(x, np.ndarray) else x for x in envs.step(a)[:4]])
        runs.append(out)
    assert runs[0] == runs[1]


def test_next_step_autoreset_at_the_horizon():
    h = 3
    envs = gymnasium.make_vec("EquiLift-v0", num_envs=2, horizon=h)
    assert envs.horizon == h
    envs.reset(seed=[7, 8])
    acts = random_actions(envs.action_space, h + 2, 0)
    for t in range(h):
        obs, rewards, terminated, truncated, info = envs.step(acts[t])
        assert not terminated.any()
        assert truncated.all() == (t == h - 1)
    last_obs = obs
    seeds_before = envs.unwrapped.episode_seeds()
    # The next step resets (actions ignored): reset obs, reward 0, flags False.
    obs, rewards, terminated, truncated, info = envs.step(acts[h])
    assert not terminated.any() and not truncated.any() and (rewards == 0).all()
    assert info["_episode_seed"].all()
    new_seeds = info["episode_seed"]
    assert (new_seeds != seeds_before).all()
    assert not np.array_equal(obs, last_obs)
    # The auto-reset episode is the single env's episode with that seed.
    single = gymnasium.make("EquiLift-v0").unwrapped
    np.testing.assert_array_equal(obs[1], single.reset(seed=int(new_seeds[1]))[0])
    obs, *_ = envs.step(acts[h + 1])
    np.testing.assert_array_equal(obs[1], single.step(acts[h + 1][1])[0])


def test_max_episode_steps_truncates_and_same_step_mode_reports_final_obs():
    envs = gymnasium.make_vec("EquiLift-v0", num_envs=3, max_episode_steps=2, autoreset_mode="same_step")
    assert envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    ref = gymnasium.make_vec("EquiLift-v0", num_envs=3, max_episode_steps=2)
    envs.reset(seed=1)
    ref.reset(seed=1)
    acts = random_actions(envs.action_space, 3, 2)
    obs, _, _, truncated, info = envs.step(acts[0])
    assert not truncated.any() and "final_obs" not in info
    ref.step(acts[0])
    obs, _, _, truncated, info = envs.step(acts[1])
    ref_obs, *_ = ref.step(acts[1])
    assert truncated.all() and info["_final_obs"].all()
    np.testing.assert_array_equal(info["final_obs"], ref_obs)
    ref_reset, *_ = ref.step(acts[2])
    np.testing.assert_array_equal(obs, ref_reset)


def test_reset_mask_and_normalized_actions():
    envs = EquiVectorEnv("lift", 3, action_mode="normalized")
    assert envs.single_action_space.low.min() == -1.0
    obs, _ = envs.reset(seed=0)
    hold = envs.normalize_action(envs.core.current_targets())
    envs.step(hold)
    obs2, info = envs.reset(seed=[0, 50, 0], options={"reset_mask": np.array([False, True, False])})
    assert list(info["_episode_seed"]) == [False, True, False]
    assert envs.core.episode_seeds()[1] == 50
    np.testing.assert_array_equal(obs2[1], gymnasium.make("EquiLift-v0").unwrapped.reset(seed=50)[0])


def test_bad_input_raises_and_loses_nothing():
    envs = gymnasium.make_vec("EquiLift-v0", num_envs=3)
    with pytest.raises(gymnasium.error.ResetNeeded):
        envs.step(np.zeros((3, 10)))
    obs, _ = envs.reset(seed=0)
    hold = envs.unwrapped.core.current_targets()
    with pytest.raises(ValueError, match=r"shape \(3, 10\)"):
        envs.step(hold[:2])
    with pytest.raises(ValueError, match=r"shape \(3, 10\)"):
        envs.step(hold.ravel())
    bad = hold.copy()
    bad[2, 4] = np.nan
    with pytest.raises(ValueError, match="action of environment 2: element 4 is not finite"):
        envs.step(bad)
    with pytest.raises(TypeError, match="numeric"):
        envs.step(np.full((3, 10), "a"))
    np.testing.assert_array_equal(envs.unwrapped.core.observe(), obs)  # nothing stepped
    envs.step(hold)
    for seed in (-1, 1.5, [1, 2], [1, 2, -3], "7"):
        with pytest.raises(ValueError, match="seed must be"):
            envs.reset(seed=seed)
    with pytest.raises(ValueError, match="num_envs"):
        EquiVectorEnv("lift", 0)
    with pytest.raises(ValueError, match="autoreset_mode"):
        EquiVectorEnv("lift", 2, autoreset_mode="sometimes")
    with pytest.raises(ValueError, match="unknown task"):
        EquiVectorEnv("juggle", 2)


def test_sb3_adapter_fills_terminal_observation_and_learns():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import is_wrapped  # noqa: F401  (SB3 importable)

    from equigym.sb3 import EquiVecEnv

    venv = EquiVecEnv("EquiLift-v0", num_envs=2, horizon=3, action_mode="normalized", reward="dense")
    venv.seed(4)
    obs = venv.reset()
    assert obs.shape == (2, 22) and venv.reset_infos[0]["episode_seed"] == 4
    ref = EquiVectorEnv("lift", 2, horizon=3, action_mode="normalized", reward="dense")
    ref.reset(seed=4)
    acts = random_actions(ref.action_space, 3, 0)
    for t, a in enumerate(acts):
        obs, rewards, dones, infos = venv.step(a)
        ref_obs, ref_r, _, ref_tr, _ = ref.step(a)
        np.testing.assert_allclose(rewards, ref_r.astype(np.float32))
        assert rewards.dtype == np.float32 and all("is_success" in i for i in infos)
        if t < 2:
            assert not dones.any() and "terminal_observation" not in infos[0]
    assert dones.all()
    for i in range(2):
        np.testing.assert_array_equal(infos[i]["terminal_observation"], ref_obs[i])
        assert infos[i]["TimeLimit.truncated"] is True
    # The returned observation is the next episode's first one.
    ref_reset, *_ = ref.step(acts[0])
    np.testing.assert_array_equal(obs, ref_reset)
    assert venv.get_attr("horizon") == [3, 3]
    model = SAC(
        "MlpPolicy",
        venv,
        learning_starts=8,
        batch_size=8,
        buffer_size=200,
        policy_kwargs={"net_arch": [16, 16]},
        seed=0,
        device="cpu",
    )
    model.learn(24)
    venv.close()


def test_sb3_adapter_rejects_next_step_vector_envs():
    pytest.importorskip("stable_baselines3")
    from equigym.sb3 import EquiVecEnv

    with pytest.raises(ValueError, match="same_step"):
        EquiVecEnv(EquiVectorEnv("lift", 2))


def test_vector_env_passes_gymnasium_vector_checks():
    from gymnasium.utils.env_checker import data_equivalence

    envs = gymnasium.make_vec("EquiLift-v0", num_envs=2)
    a = envs.action_space.sample()
    o1, _ = envs.reset(seed=123)
    s1 = envs.step(a)
    o2, _ = envs.reset(seed=123)
    s2 = envs.step(a)
    assert data_equivalence(o1, o2) and data_equivalence(s1, s2)
    assert equigym.EquiVectorEnv is EquiVectorEnv
