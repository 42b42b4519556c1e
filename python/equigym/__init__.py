"""equigym: symmetry-aware robot-manipulation environments written in Rust.

Importing the package registers the gymnasium ids (gymnasium 1.x has no plugin entry points):

>>> import gymnasium, equigym
>>> env = gymnasium.make("EquiLift-v0", render_mode="rgb_array")
>>> obs, info = env.reset(seed=0)
>>> envs = gymnasium.make_vec("EquiLift-v0", num_envs=16)   # B envs stepped in Rust
"""

from equigym._core import (
    TASK_IDS,
    EquigymError,
    InvalidStateError,
    ResetNeeded,
    UrdfError,
    __version__,
)
from equigym._core import Env as CoreEnv
from equigym._core import DiffusionPolicy, Expert, PolicyError
from equigym.envs import ENV_IDS, EquiEnv, register_envs
from equigym.latent import LATENT_ENV_IDS, EquiLatentEnv, EquiLatentVectorEnv, register_latent_envs
from equigym.rendering import save_gif
from equigym.symmetry import Symmetry, measure_breaking
from equigym.wrappers import SymmetryWrapper
from equigym.vector import EquiVectorEnv

register_envs()
register_latent_envs()

__all__ = [
    "CoreEnv",
    "DiffusionPolicy",
    "EquiLatentEnv",
    "EquiLatentVectorEnv",
    "LATENT_ENV_IDS",
    "PolicyError",
    "ENV_IDS",
    "EquiEnv",
    "EquiVectorEnv",
    "EquigymError",
    "Expert",
    "InvalidStateError",
    "ResetNeeded",
    "TASK_IDS",
    "UrdfError",
    "__version__",
    "register_envs",
    "save_gif",
    "Symmetry",
    "SymmetryWrapper",
    "measure_breaking",
]
