"""Gymnasium environments: ``apf_physics/Navigate-v0`` (and its vectorised version) and ``apf_physics/Formation-v0``;
several formations and a fleet as PettingZoo ``ParallelEnv`` classes (:class:`FormationsParallelEnv`,
:class:`FleetParallelEnv`, with the ``[pettingzoo]`` extra)."""

from gymnasium.envs.registration import register, registry

from apf_physics.envs.navigate import ACTIONS, NavigateEnv
from apf_physics.envs.formation import FormationEnv
from apf_physics.envs.parallel import FleetParallelEnv, FormationsParallelEnv
from apf_physics.envs.vector import NavigateVectorEnv


def register_envs() -> None:
    """Register the ``apf_physics/...`` ids (safe to call more than once)."""
    if "apf_physics/Navigate-v0" not in registry:
        register(
            id="apf_physics/Navigate-v0",
            entry_point="apf_physics.envs.navigate:NavigateEnv",
            vector_entry_point="apf_physics.envs.vector:NavigateVectorEnv",
            max_episode_steps=100,  # tt, thesis Tables 3–4
        )
    if "apf_physics/Formation-v0" not in registry:
        register(
            id="apf_physics/Formation-v0",
            entry_point="apf_physics.envs.formation:FormationEnv",
            max_episode_steps=100,
        )


__all__ = ["ACTIONS", "FleetParallelEnv", "FormationEnv", "FormationsParallelEnv", "NavigateEnv", "NavigateVectorEnv", "register_envs"]
