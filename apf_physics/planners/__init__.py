"""Planners: policies that turn robot positions into velocity commands.

Planners are found by name through :data:`PLANNERS` (string entry points, as Gymnasium
registers environments), so that naming ``gradient`` never loads torch for ``dqn``.

The learned planners, by what they are:

- ``dqn``: the default learned planner, the best shipped network for the world's field,
  whatever its kind (the map network on Table 4's field, the thesis's window Q-network on
  Table 3's: :data:`~apf_physics.models.SHIPPED`); ``eval`` says which one ran;
- ``mapnet``: the map network (a value-iteration network trained by imitation of A*);
- ``window-dqn``: the thesis's deep Q-network on a window of the potential.

Each with ``-unshielded`` (the network's first choice, unchecked); ``dqn-known`` is ``dqn``
whose shield knows the moving obstacles' motion.
"""

from __future__ import annotations

import importlib

from apf_physics.errors import UserError
from apf_physics.planners.base import Planner
from apf_physics.planners.gradient import GradientPlanner

PLANNERS = {
    "gradient": ("apf_physics.planners.gradient:GradientPlanner", {}),
    "dqn": ("apf_physics.planners.dqn:DQNPlanner", {"shield": True}),
    "dqn-unshielded": ("apf_physics.planners.dqn:DQNPlanner", {"shield": False}),
    "dqn-known": ("apf_physics.planners.dqn:DQNPlanner", {"shield": True, "prediction": "known"}),
    "mapnet": ("apf_physics.planners.dqn:DQNPlanner", {"shield": True, "network": "map"}),
    "mapnet-unshielded": ("apf_physics.planners.dqn:DQNPlanner", {"shield": False, "network": "map"}),
    "window-dqn": ("apf_physics.planners.dqn:DQNPlanner", {"shield": True, "network": "window"}),
    "window-dqn-unshielded": ("apf_physics.planners.dqn:DQNPlanner", {"shield": False, "network": "window"}),
    "astar": ("apf_physics.planners.astar:AStarPlanner", {}),
    "sipp": ("apf_physics.planners.astar:SIPPPlanner", {}),
    "escape": ("apf_physics.planners.escape:EscapePlanner", {}),
}
"""Command-line name → (``module:class``, keyword arguments)."""
LEARNED = ("dqn", "dqn-unshielded", "dqn-known", "mapnet", "mapnet-unshielded", "window-dqn", "window-dqn-unshielded")
"""Planners that take a model file."""


def make_planner(name: str, model: str | None = None) -> Planner:
    """Build a planner by its command-line name.

    Args:
        name: One of :data:`PLANNERS`.
        model: For the learned planners (:data:`LEARNED`): a model file; the shipped model for the
            world's field is used when None (of the planner's kind of network, for ``mapnet`` and
            ``window-dqn``). ``dqn`` never picks a move that would touch an obstacle
            (:class:`~apf_physics.planners.dqn.DQNPlanner`'s shield); ``dqn-unshielded`` takes
            the network's choice as it is; ``dqn-known`` is ``dqn`` whose shield knows the moving
            obstacles' motion instead of predicting it.

    Raises:
        UserError: An unknown name.
    """
    if name not in PLANNERS:
        raise UserError(f"--planner: unknown planner {name!r} (known: {', '.join(PLANNERS)})")
    entry, kwargs = PLANNERS[name]
    module, cls = entry.split(":")
    if name in LEARNED:
        kwargs = {**kwargs, "model": model}
    return getattr(importlib.import_module(module), cls)(**kwargs)


__all__ = ["GradientPlanner", "LEARNED", "PLANNERS", "Planner", "make_planner"]
