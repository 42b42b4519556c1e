"""EquiLift-v0 through gymnasium: API conformance, determinism, state, rendering, experts."""

import gymnasium
import numpy as np
import pytest
from conftest import expert_episodes
from gymnasium.utils.env_checker import check_env

import equigym


def test_registered_horizon_and_float32_boxes(lift):
    assert lift.spec.max_episode_steps is None and lift.unwrapped.horizon == 400
    assert lift.observation_space.shape == (22,)
    assert lift.observation_space.dtype == np.float32
    assert lift.action_space.shape == (10,)
    assert lift.action_space.dtype == np.float32
    obs, info = lift.reset(seed=0)
    assert obs.dtype == np.float32 and lift.observation_space.contains(obs)


def test_observation_fields_follow_the_papers_lift_table(lift):
    fields = lift.unwrapped.observation_fields
    assert list(fields) == [
        "cube_pos",
        "cube_rot6d",
        "gripper_to_cube_xy",
        "gripper_pos",
        "gripper_rot6d",
        "gripper_joint_pos",
    ]
    assert [s.stop - s.start for s in fields.values()] == [3, 6, 2, 3, 6, 2]
    reps = [f["rep"] for f in lift.unwrapped.observation_layout]
    assert reps == ["rho1 + rho0", "rho1^3", "rho1", "rho1 + rho0", "rho1^3", "rho0^2"]
    obs, _ = lift.reset(seed=3)
    f = fields
    np.testing.assert_allclose(
        obs[f["gripper_to_cube_xy"]], obs[f["cube_pos"]][:2] - obs[f["gripper_pos"]][:2], atol=1e-6
    )
    assert 0.8 < obs[f["cube_pos"]][2] < 0.83  # resting on the table


@pytest.mark.parametrize("action_mode", ["absolute", "normalized"])
def test_gymnasium_env_checker_passes(action_mode):
    env = gymnasium.make(
        "EquiLift-v0", action_mode=action_mode, render_mode="rgb_array", render_width=64, render_height=48
    )
    check_env(env.unwrapped, skip_render_check=False)


def test_stable_baselines3_env_checker_passes_with_normalized_actions():
    sb3_check = pytest.importorskip("stable_baselines3.common.env_checker").check_env
    env = gymnasium.make("EquiLift-v0", action_mode="normalized")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at all for the normalized space
        sb3_check(env.unwrapped, warn=True)


def test_same_seed_same_rollout_bitwise():
    def rollout():
        env = gymnasium.make("EquiLift-v0")
        env.action_space.seed(123)
        obs, _ = env.reset(seed=42)
        trace = [obs]
        for _ in range(40):
            obs, r, *_ = env.step(env.action_space.sample())
            trace.append(obs)
            trace.append(np.float32(r))
        return np.concatenate([np.atleast_1d(t) for t in trace])

    a, b = rollout(), rollout()
    assert a.tobytes() == b.tobytes()


def test_unseeded_resets_continue_a_reproducible_stream():
    e1, e2 = gymnasium.make("EquiLift-v0"), gymnasium.make("EquiLift-v0")
    e1.reset(seed=5)
    e2.reset(seed=5)
    o1, _ = e1.reset()
    o2, _ = e2.reset()
    assert o1.tobytes() == o2.tobytes()


def test_state_round_trip_is_bitwise(lift):
    lift.reset(seed=1)
    lift.action_space.seed(0)
    for _ in range(10):
        lift.step(lift.action_space.sample())
    state = lift.unwrapped.get_state()
    actions = [lift.action_space.sample() for _ in range(20)]
    end = [lift.step(a)[0] for a in actions][-1]
    other = gymnasium.make("EquiLift-v0").unwrapped
    other.set_state(state)
    for a in actions:
        obs, *_ = other.step(a)
    assert obs.tobytes() == end.tobytes()


def test_expert_through_python_lifts_the_cube():
    wins, info = expert_episodes("EquiLift-v0", "lift", range(20), 150)
    assert wins >= 19
    assert info["is_success"] and info["cube_height"] > 0.015  # height of the cube's underside


def test_dense_reward_and_info_terms():
    env = gymnasium.make("EquiLift-v0", reward="dense")
    env.reset(seed=0)
    _, r, terminated, truncated, info = env.step(env.unwrapped.core.current_target())
    assert 0.0 <= r <= 1.0 and not terminated and not truncated
    assert {"success", "cube_height", "reach_distance", "grasped"} <= set(info)


def test_episode_truncates_at_400_steps(lift):
    lift.reset(seed=0)
    hold = lift.unwrapped.core.current_target().astype(np.float32)
    for t in range(400):  # noqa: B007 (checked after the loop)
        _, _, terminated, truncated, _ = lift.step(hold)
        assert not terminated
    assert truncated and t == 399


def test_render_rgb_array():
    env = gymnasium.make("EquiLift-v0", render_mode="rgb_array", render_width=320, render_height=240)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # a scene, not a blank image
    # The red cube is visible.
    red = (frame[..., 0] > 150) & (frame[..., 1] < 80) & (frame[..., 2] < 80)
    assert red.sum() > 30


def test_normalized_actions_map_to_absolute():
    env = gymnasium.make("EquiLift-v0", action_mode="normalized").unwrapped
    env.reset(seed=0)
    target = env.core.current_target()
    env.step(env.normalize_action(target))
    assert np.allclose(env.core.current_target()[:3], target[:3], atol=0.01)


def test_vector_env_runs(lift):
    envs = gymnasium.make_vec("EquiLift-v0", num_envs=2, vectorization_mode="sync")
    obs, _ = envs.reset(seed=[1, 2])
    assert obs.shape == (2, 22)
    obs, r, term, trunc, _ = envs.step(envs.action_space.sample())
    assert obs.shape == (2, 22) and r.shape == (2,)
    envs.close()


def test_terminate_on_success_ends_the_episode_at_the_first_success():
    # The same expert episode with and without the wrapper: the wrapped one terminates at the
    # step whose info reports success, and only there; the plain env never terminates.
    plain, wrapped = gymnasium.make("EquiLift-v0"), equigym.TerminateOnSuccess(gymnasium.make("EquiLift-v0"))
    ends = []
    for env in (plain, wrapped):
        core = env.unwrapped.core
        expert = equigym.Expert("lift")
        env.reset(seed=0)
        expert.reset(core, 0)
        for t in range(150):
            _, _, terminated, truncated, info = env.step(expert.act(core))
            if terminated or info["success"]:
                ends.append((t, terminated, info["success"]))
                break
    assert ends[0][0] == ends[1][0]
    assert ends[0][1:] == (False, True) and ends[1][1:] == (True, True)
