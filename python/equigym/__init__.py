"""equigym: symmetry-aware robot-manipulation environments written in Rust.

Importing the package registers the gymnasium ids (gymnasium 1.x has no plugin entry points):

>>> import gymnasium, equigym
>>> env = gymnasium.make("EquiLift-v0", render_mode="rgb_array")
>>> obs, info = env.reset(seed=0)
>>> envs = gymnasium.make_vec("EquiLift-v0", num_envs=16)   # B envs stepped in Rust
"""

from equigym import errors
from equigym._core import TASK_IDS, DiffusionPolicy, EnvSpec, Expert, __version__
from equigym._core import Env as CoreEnv
from equigym.assets import asset_path, policy_path, urdf_path
from equigym.envs import ENV_IDS, EquiEnv, register_envs
from equigym.errors import *  # noqa: F403 (the exception classes, listed once in errors.__all__)
from equigym.latent import LATENT_ENV_IDS, EquiLatentEnv, EquiLatentVectorEnv, register_latent_envs
from equigym.rendering import save_gif
from equigym.symmetry import Symmetry, measure_breaking
from equigym.vector import EquiVectorEnv
from equigym.wrappers import SymmetryWrapper, TerminateOnSuccess

register_envs()
register_latent_envs()

__all__ = [
    "ENV_IDS",
    "LATENT_ENV_IDS",
    "TASK_IDS",
    "CoreEnv",
    "DiffusionPolicy",
    "EnvSpec",
    "EquiEnv",
    "EquiLatentEnv",
    "EquiLatentVectorEnv",
    "EquiVectorEnv",
    "Expert",
    "Symmetry",
    "SymmetryWrapper",
    "TerminateOnSuccess",
    *errors.__all__,
    "__version__",
    "asset_path",
    "measure_breaking",
    "policy_path",
    "register_envs",
    "register_latent_envs",
    "save_gif",
    "urdf_path",
]
