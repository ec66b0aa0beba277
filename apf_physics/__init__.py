"""apf-physics: artificial-potential-field path planning with pymunk physics, DQN planners and Gymnasium environments."""

from apf_physics import _compat
from apf_physics.errors import ModelError, UserError, WorldError
from apf_physics.version import __version__
from apf_physics.world.field import FieldParams
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import load_world, load_worlds, save_world, world_from_dict

from apf_physics.envs import register_envs as _register_envs  # noqa: E402

_register_envs()
_compat.install()

__all__ = ["FieldParams", "ModelError", "UserError", "World", "WorldError", "load_world", "load_worlds",
           "save_world", "world_from_dict", "__version__"]
