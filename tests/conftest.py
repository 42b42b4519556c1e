import gymnasium
import pytest

import equigym  # noqa: F401  (registers the ids)


@pytest.fixture
def lift():
    env = gymnasium.make("EquiLift-v0")
    yield env
    env.close()


def expert_episodes(env_id: str, task: str, seeds: range, max_steps: int) -> tuple[int, dict]:
    """Run the task's scripted expert through the gymnasium env `env_id` from each seed, to its
    first success, truncation or `max_steps`; returns the successes and the last step's info."""
    env = gymnasium.make(env_id)
    core = env.unwrapped.core
    expert = equigym.Expert(task)
    wins, info = 0, {}
    for seed in seeds:
        env.reset(seed=seed)
        expert.reset(core, seed)
        for _ in range(max_steps):
            *_, truncated, info = env.step(expert.act(core))
            if info["success"] or truncated:
                break
        wins += bool(info["success"])
    env.close()
    return wins, info
