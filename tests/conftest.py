import gymnasium
import pytest

import equigym  # noqa: F401  (registers the ids)


@pytest.fixture
def lift():
    env = gymnasium.make("EquiLift-v0")
    yield env
    env.close()
