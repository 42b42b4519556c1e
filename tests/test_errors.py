"""Bad input raises clear Python exceptions and never crashes the interpreter."""

import gymnasium
import numpy as np
import pytest

import equigym
from equigym import EquigymError, InvalidStateError, ResetNeeded, UrdfError


def test_step_before_reset_raises_reset_needed():
    core = equigym.CoreEnv("lift")
    with pytest.raises(ResetNeeded, match="before reset"):
        core.step(np.zeros(10))
    with pytest.raises(gymnasium.error.ResetNeeded):
        gymnasium.make("EquiLift-v0").step(np.zeros(10, dtype=np.float32))


def test_step_after_the_horizon_raises():
    core = equigym.CoreEnv("lift", horizon=2)
    core.reset(0)
    hold = core.current_target()
    core.step(hold)
    *_, truncated, _ = core.step(hold)
    assert truncated
    with pytest.raises(ResetNeeded, match="call reset"):
        core.step(hold)


@pytest.mark.parametrize(
    "action, exc, match",
    [
        (np.zeros(9), ValueError, r"shape \(10,\)"),
        (np.zeros((2, 5)), ValueError, r"shape \(10,\)"),
        (np.full(10, np.nan), ValueError, "NaN"),
        (np.r_[np.zeros(9), np.inf], ValueError, "NaN or infinity"),
        (np.array(["a"] * 10), TypeError, "numeric"),
        (np.array([None] * 10), TypeError, "numeric"),
    ],
)
def test_bad_actions(lift, action, exc, match):
    lift.reset(seed=0)
    with pytest.raises(exc, match=match):
        lift.step(action)
    # The environment is still usable afterwards.
    lift.step(lift.unwrapped.core.current_target())


def test_core_rejects_bad_actions_too():
    core = equigym.CoreEnv("lift")
    core.reset(0)
    with pytest.raises(EquigymError, match="expected 10 values, got 3"):
        core.step(np.zeros(3))
    with pytest.raises(EquigymError, match="element 2 is not finite"):
        core.step(np.array([0, 0, np.nan, 1, 0, 0, 0, 1, 0, 0.04]))
    with pytest.raises(TypeError):
        core.step([0.0] * 10)  # the core takes float64 arrays; gymnasium envs convert


@pytest.mark.parametrize("seed", [-1, 1.5, "7"])
def test_bad_seeds(lift, seed):
    with pytest.raises(ValueError, match="seed must be None or a non-negative integer"):
        lift.reset(seed=seed)


def test_bad_states(lift):
    lift.reset(seed=0)
    with pytest.raises(InvalidStateError, match="not an equigym state"):
        lift.unwrapped.set_state(b"garbage")
    state = lift.unwrapped.get_state()
    with pytest.raises(InvalidStateError):
        lift.unwrapped.set_state(state[: len(state) // 3])
    with pytest.raises(TypeError):
        lift.unwrapped.set_state("not bytes")
    lift.unwrapped.set_state(state)


def test_bad_construction_arguments(tmp_path):
    with pytest.raises(ValueError, match="unknown task 'juggle'"):
        equigym.CoreEnv("juggle")
    with pytest.raises(ValueError, match="reward must be 'sparse' or 'dense'"):
        gymnasium.make("EquiLift-v0", reward="shaped")
    with pytest.raises(ValueError, match="render_mode"):
        equigym.EquiEnv("lift", render_mode="human")
    with pytest.raises(ValueError, match="action_mode"):
        gymnasium.make("EquiLift-v0", action_mode="delta")
    with pytest.raises(ValueError, match="unknown field `gravity`"):
        gymnasium.make("EquiLift-v0", physics={"gravity": 1.0})
    with pytest.raises(ValueError, match="timestep must be positive"):
        gymnasium.make("EquiLift-v0", physics={"timestep": 0.0})
    with pytest.raises(ValueError, match=r"joint_limit_scale must be in \(0, 10\]"):
        gymnasium.make("EquiLift-v0", physics={"joint_limit_scale": -1.0})
    with pytest.raises(ValueError, match="lift has no range 'peg_xy'"):
        gymnasium.make("EquiLift-v0", ranges={"peg_xy": (0, 1)})
    with pytest.raises(ValueError, match="image size"):
        equigym.CoreEnv("lift").render(0, 10)


def test_bad_urdf_paths_and_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        gymnasium.make("EquiLift-v0", urdf=str(tmp_path / "missing.urdf"))
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'/>")
    with pytest.raises(UrdfError, match="not a valid URDF"):
        gymnasium.make("EquiLift-v0", urdf=str(broken))
    no_hand = tmp_path / "no_hand.urdf"
    no_hand.write_text(
        "<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='revolute'>"
        "<parent link='a'/><child link='b'/><axis xyz='0 0 1'/>"
        "<limit lower='-1' upper='1' effort='1' velocity='1'/></joint></robot>"
    )
    with pytest.raises(UrdfError, match="no hand found"):
        gymnasium.make("EquiLift-v0", urdf=str(no_hand))


def test_shipped_urdf_loads_from_a_path():
    env = gymnasium.make("EquiLift-v0", urdf=equigym.urdf_path())
    env.reset(seed=0)
