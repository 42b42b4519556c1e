"""EquiStack-v0 and EquiSquare-v0: API conformance, layouts, variants, determinism, state."""

import gymnasium
import numpy as np
import pytest
from conftest import expert_episodes
from gymnasium.utils.env_checker import check_env

import equigym


@pytest.mark.parametrize("env_id, dim", [("EquiStack-v0", 35), ("EquiSquare-v0", 32)])
def test_env_checker_and_spaces(env_id, dim):
    env = gymnasium.make(env_id, render_mode="rgb_array", render_width=64, render_height=48)
    # The env truncates at its own horizon; no TimeLimit can cut a longer one.
    assert env.spec.max_episode_steps is None and env.unwrapped.horizon == 400
    assert env.observation_space.shape == (dim,)
    check_env(env.unwrapped, skip_render_check=False)


def test_square_layout_matches_the_papers_table():
    env = gymnasium.make("EquiSquare-v0").unwrapped
    layout = [(f["name"], f["len"], f["rep"]) for f in env.observation_layout]
    assert layout == [
        ("nut_pos", 3, "rho1 + rho0"),
        ("nut_rot6d", 6, "rho1^3"),
        ("gripper_to_nut_pos", 3, "rho0^3"),
        ("gripper_to_nut_rot6d", 6, "rho0^6"),
        ("peg_pos", 3, "rho1 + rho0"),
        ("gripper_pos", 3, "rho1 + rho0"),
        ("gripper_rot6d", 6, "rho1^3"),
        ("gripper_joint_pos", 2, "rho0^2"),
    ]


def test_stack_layout_has_both_cubes():
    env = gymnasium.make("EquiStack-v0").unwrapped
    names = [f["name"] for f in env.observation_layout]
    assert names[:6] == [
        "cubeA_pos",
        "cubeB_pos",
        "cubeA_rot6d",
        "cubeB_rot6d",
        "gripper_to_cubeA_pos",
        "gripper_to_cubeB_pos",
    ]


@pytest.mark.parametrize(
    "env_id, field, limit",
    [
        ("EquiStack-v0", "cubeA_pos", {"D0": 0.08, "D1": 0.20, "D2": 0.25}),
        ("EquiSquare-v0", "nut_pos", {"D0": 0.08, "D1": 0.15, "D2": 0.25}),
    ],
)
def test_variants_set_the_reset_ranges(env_id, field, limit):
    for variant, r in limit.items():
        env = gymnasium.make(env_id, variant=variant).unwrapped
        xy = np.array([env.reset(seed=s)[0][env.observation_fields[field]][:2] for s in range(60)])
        assert np.abs(xy).max() <= r + 1e-6
        assert np.abs(xy).max() > 0.6 * r
    with pytest.raises(ValueError, match="no variant 'D7'"):
        gymnasium.make(env_id, variant="D7")


def test_square_peg_is_replaced_at_every_reset():
    env = gymnasium.make("EquiSquare-v0").unwrapped
    f = env.observation_fields["peg_pos"]
    pegs = {tuple(np.round(env.reset(seed=s)[0][f], 4)) for s in range(10)}
    assert len(pegs) == 10


@pytest.mark.parametrize("env_id", ["EquiStack-v0", "EquiSquare-v0"])
def test_determinism_and_state_round_trip(env_id):
    def run():
        env = gymnasium.make(env_id).unwrapped
        env.action_space.seed(4)
        env.reset(seed=9)
        acts = [env.action_space.sample() for _ in range(25)]
        for a in acts[:10]:
            env.step(a)
        state = env.get_state()
        out = [env.step(a)[0] for a in acts[10:]]
        return state, acts, np.concatenate(out)

    state, acts, trace = run()
    assert run()[2].tobytes() == trace.tobytes()
    env = gymnasium.make(env_id).unwrapped
    env.set_state(state)
    again = np.concatenate([env.step(a)[0] for a in acts[10:]])
    assert again.tobytes() == trace.tobytes()
    other = gymnasium.make("EquiLift-v0").unwrapped
    with pytest.raises(equigym.InvalidStateError, match="from task"):
        other.set_state(state)


def test_stack_expert_succeeds():
    wins, _ = expert_episodes("EquiStack-v0", "stack", range(10), 400)
    assert wins >= 9
