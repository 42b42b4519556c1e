"""Type stubs for the Rust extension module ``equigym._core``."""

from os import PathLike
from typing import Any, Literal, TypeAlias, final, type_check_only

import numpy as np
import numpy.typing as npt

__all__ = [
    "Env",
    "EnvSpec",
    "Expert",
    "TaskSymmetry",
    "DiffusionPolicy",
    "LatentEnv",
    "LatentVecEnv",
    "VecEnv",
    "measure_symmetry_breaking",
    "steer_run",
    "steer_preset",
    "steer_gradcase",
    "evaluate_base",
    "wilson",
    "EVAL_SEED",
    "STALL_MOVE",
    "TASK_IDS",
    "__version__",
]

__version__: str
TASK_IDS: list[str]
#: Seed of evaluation episode 0: episode k of every evaluation (steering runs, base policy,
#: narrow-noise controls) starts from seed ``EVAL_SEED + k``.
EVAL_SEED: int
#: A chunk whose commanded hand position (its actions' mean position) moved less than this
#: from the previous chunk's counts as stalled (metres; ``failures_stalled`` of ``steer eval``).
STALL_MOVE: float

# Environment options (``**options`` below) are declared once, in Rust
# (``equigym_envs::EnvOptions``); ``equigym.envs.OPTIONS_DOC`` documents them.

@final
class EnvSpec:
    """What an environment is, without its simulator (read-only)."""

    @property
    def task(self) -> str: ...
    @property
    def horizon(self) -> int: ...
    @property
    def observation_dim(self) -> int: ...
    @property
    def action_dim(self) -> int: ...
    @property
    def max_gripper_width(self) -> float: ...
    @property
    def control_period(self) -> float: ...
    @property
    def action_low(self) -> npt.NDArray[np.float64]: ...
    @property
    def action_high(self) -> npt.NDArray[np.float64]: ...
    @property
    def observation_layout(self) -> list[dict[str, Any]]: ...
    @property
    def action_layout(self) -> list[dict[str, Any]]: ...

@type_check_only
class _TaskInfo:
    """What every environment class reports of its task (a typing-only base: at runtime each
    class has its own)."""

    @property
    def spec(self) -> EnvSpec: ...
    @property
    def task(self) -> str: ...
    @property
    def horizon(self) -> int: ...
    @property
    def observation_dim(self) -> int: ...

@final
class Env(_TaskInfo):
    def __new__(cls, task: str, **options: Any) -> Env: ...
    def __getnewargs_ex__(self) -> tuple[tuple[str], dict[str, Any]]: ...
    def __getstate__(self) -> bytes: ...
    def __setstate__(self, state: bytes) -> None: ...
    def reset(self, seed: int) -> npt.NDArray[np.float64]: ...
    def step(
        self, action: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.float64], float, bool, bool, dict[str, Any]]: ...
    def observe(self) -> npt.NDArray[np.float64]: ...
    def evaluate(self) -> dict[str, Any]: ...
    def current_target(self) -> npt.NDArray[np.float64]: ...
    def get_state(self) -> bytes: ...
    def set_state(self, state: bytes) -> None: ...
    def render(self, width: int = 256, height: int = 256) -> npt.NDArray[np.uint8]: ...
    @property
    def elapsed_steps(self) -> int: ...

@final
class Expert:
    def __new__(cls, task: str, *, position_noise: float = 0.0, yaw_noise: float = 0.0) -> Expert: ...
    def reset(self, env: Env, seed: int) -> None: ...
    def act(self, env: Env) -> npt.NDArray[np.float64]: ...
    @property
    def phase(self) -> str: ...

@final
class TaskSymmetry:
    def __new__(
        cls, task: str, *, group: str = "C8", chunk_len: int = 4, variant: str | None = None
    ) -> TaskSymmetry: ...
    @property
    def task(self) -> str: ...
    @property
    def group(self) -> str: ...
    @property
    def group_order(self) -> int | None: ...
    @property
    def chunk_len(self) -> int: ...
    def dim(self, space: str) -> int: ...
    def layout(self, space: str) -> list[dict[str, Any]]: ...
    def blocks(self, space: str) -> list[tuple[int, list[int]]]: ...
    def element_angle(self, k: int) -> float: ...
    def act_elements(
        self, space: str, data: npt.NDArray[np.float64], elements: npt.NDArray[np.int64]
    ) -> npt.NDArray[np.float64]: ...
    def act_angles(
        self, space: str, data: npt.NDArray[np.float64], angles: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]: ...
    def matrix(
        self, space: str, *, element: int | None = None, angle: float | None = None
    ) -> npt.NDArray[np.float64]: ...
    def transform_state(
        self, env: Env, *, element: int | None = None, angle: float | None = None
    ) -> dict[str, Any]: ...

def measure_symmetry_breaking(
    task: str,
    *,
    env: dict[str, Any] | None = None,
    group_order: int = 8,
    episodes: int = 20,
    states_per_episode: int = 4,
    probe_steps: int = 1,
    replay_slack: int = 30,
    seed: int = 0,
) -> str: ...

@final
class DiffusionPolicy:
    def __new__(
        cls,
        source: str | PathLike[str] | bytes,
        origin: str | None = None,
        kernel: Literal["fourier", "dense"] | None = None,
    ) -> DiffusionPolicy:
        """An exported EDP; ``kernel`` runs its regular-to-regular layers in the Fourier basis
        (``None``: the default) or dense (``"dense"``: the file's own matrices, the same map up to
        float rounding, several times slower to decode for the shipped policies; the kernel of the runs
        recorded before the Fourier one, which replay only on it)."""
    def __getnewargs__(self) -> tuple[bytes, str, str]: ...
    @property
    def kernel(self) -> Literal["fourier", "dense"]: ...
    @property
    def fourier_layers(self) -> list[int]: ...
    @property
    def task(self) -> str: ...
    @property
    def chunk_len(self) -> int: ...
    @property
    def obs_dim(self) -> int: ...
    @property
    def action_dim(self) -> int: ...
    @property
    def group(self) -> str: ...
    @property
    def default_ddim_steps(self) -> int: ...
    @property
    def metadata(self) -> dict[str, str]: ...
    def sample(
        self,
        obs: npt.NDArray[np.float64],
        latent: npt.NDArray[np.float64],
        steps: int | None = None,
        precision: Literal["f32", "f64"] | None = None,
    ) -> npt.NDArray[np.float64]: ...

@final
class LatentEnv(_TaskInfo):
    def __new__(
        cls,
        task: str,
        policy: str | PathLike[str] | DiffusionPolicy,
        *,
        bound: float = ...,  # DEFAULT_LATENT_BOUND (1.5)
        ddim_steps: int | None = None,
        **options: Any,
    ) -> LatentEnv: ...
    def __getnewargs_ex__(self) -> tuple[tuple[str, DiffusionPolicy], dict[str, Any]]: ...
    def __getstate__(self) -> bytes: ...
    def __setstate__(self, state: bytes) -> None: ...
    @property
    def policy(self) -> DiffusionPolicy: ...
    def reset(self, seed: int) -> npt.NDArray[np.float64]: ...
    def step(
        self, latent: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.float64], float, bool, bool, dict[str, Any]]: ...
    def decode(self, latent: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def last_chunk(self) -> npt.NDArray[np.float64]: ...
    def observe(self) -> npt.NDArray[np.float64]: ...
    def get_state(self) -> bytes: ...
    def set_state(self, state: bytes) -> None: ...
    @property
    def latent_dim(self) -> int: ...
    @property
    def chunk_len(self) -> int: ...
    @property
    def bound(self) -> float: ...
    @property
    def elapsed_steps(self) -> int: ...

#: What a batch step returns, for the vector and the latent vector envs alike: observations
#: (float32), rewards, terminated, truncated, successes, the rows reset this step, and (in
#: same-step autoreset mode, when a row was reset) the final observations (None otherwise).
_BatchStep: TypeAlias = tuple[
    npt.NDArray[np.float32],
    npt.NDArray[np.float64],
    npt.NDArray[np.bool_],
    npt.NDArray[np.bool_],
    npt.NDArray[np.bool_],
    npt.NDArray[np.bool_],
    npt.NDArray[np.float32] | None,
]

@type_check_only
class _BatchCore(_TaskInfo):
    """What the two batched environments share (a typing-only base: at runtime they are
    separate classes)."""

    def reset(self, seeds: list[int], mask: list[bool] | None = None) -> npt.NDArray[np.float32]: ...
    def step(self, actions: npt.NDArray[np.float64]) -> _BatchStep: ...
    def observe(self) -> npt.NDArray[np.float32]: ...
    def episode_seeds(self) -> npt.NDArray[np.uint64]: ...
    stepping_seconds: float
    @property
    def num_envs(self) -> int: ...
    @property
    def threads(self) -> int: ...
    @property
    def autoreset_mode(self) -> str: ...

@final
class VecEnv(_BatchCore):
    """B environments of one task stepped in Rust per call (see ``equigym.vector``)."""

    def __new__(
        cls,
        task: str,
        num_envs: int,
        *,
        threads: int = 0,
        autoreset_mode: str = "next_step",
        **options: Any,
    ) -> VecEnv: ...
    def current_targets(self) -> npt.NDArray[np.float64]: ...
    def get_state(self, i: int) -> bytes: ...
    @property
    def action_dim(self) -> int: ...

@final
class LatentVecEnv(_BatchCore):
    """B latent-action environments: one batched DDIM per step, then the chunks in parallel
    (see ``equigym.latent.EquiLatentVectorEnv``)."""

    def __new__(
        cls,
        task: str,
        policy: str | PathLike[str] | DiffusionPolicy,
        num_envs: int,
        *,
        threads: int = 0,
        autoreset_mode: str = "next_step",
        bound: float = ...,  # DEFAULT_LATENT_BOUND (1.5)
        ddim_steps: int | None = None,
        **options: Any,
    ) -> LatentVecEnv: ...
    def executed(self) -> npt.NDArray[np.uint64]: ...
    def last_chunks(self) -> npt.NDArray[np.float64]: ...
    @property
    def latent_dim(self) -> int: ...
    @property
    def chunk_len(self) -> int: ...
    @property
    def bound(self) -> float: ...

def steer_preset(name: Literal["cpu", "paper"]) -> dict[str, Any]: ...
def steer_run(
    method: Literal["dsrl", "equi", "approx"],
    task: str,
    seed: int,
    steps: int,
    out: str | PathLike[str],
    *,
    threads: int = 1,
    preset: Literal["cpu", "paper"] = "cpu",
    env: dict[str, Any] | None = None,
    eval_every: int = 2000,
    eval_episodes: int = 50,
    policy: str | PathLike[str] | None = None,
    edp_kernel: Literal["fourier", "dense"] | None = None,
    ent_init: float | None = None,
    utd: int | None = None,
    terminate_on_success: bool = False,
    noise_aliased: bool = False,
    target_entropy: float | None = None,
    prior_kl: float | None = None,
    reward_scale: float | None = None,
    select: int | None = None,
    progress: bool = False,
    stop_after_evals: int | None = None,
) -> dict[str, Any]: ...
def steer_gradcase(
    method: Literal["dsrl", "equi", "approx"], task: str = "lift", seed: int = 0, rows: int = 6
) -> dict[str, Any]: ...
def evaluate_base(
    task: str,
    *,
    seed: int = 0,
    episodes: int = 200,
    scale: float = 1.0,
    policy: str | PathLike[str] | None = None,
    edp_kernel: Literal["fourier", "dense"] | None = None,
    env: dict[str, Any] | None = None,
    threads: int = 1,
) -> dict[str, Any]:
    """The base policy on the pinned evaluation starts with latent noise N(0, scale^2 I) clipped
    to the bound, evaluated as a steering run evaluates its actor, in the environment that the
    options ``env`` (the environments' keyword arguments) build. Keys: task, policy, scale,
    seed, first_start, successes, episodes, success_rate, low, high (Wilson 95 %), outcomes
    (one bool per episode, in start order)."""

def wilson(successes: int, n: int) -> tuple[float, float]:
    """Wilson score interval (95 %) of ``successes`` out of ``n``; (0, 1) when ``n`` is 0."""
