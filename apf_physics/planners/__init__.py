"""Planners: policies that turn robot positions into velocity commands.

Planners are found by name through :data:`PLANNERS` (string entry points, as Gymnasium
registers environments), so that naming ``gradient`` never loads torch for ``dqn``.
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
    "astar": ("apf_physics.planners.astar:AStarPlanner", {}),
    "sipp": ("apf_physics.planners.astar:SIPPPlanner", {}),
    "escape": ("apf_physics.planners.escape:EscapePlanner", {}),
}
"""Command-line name → (``module:class``, keyword arguments)."""
LEARNED = ("dqn", "dqn-unshielded", "dqn-known")
"""Planners that take a model file."""


def make_planner(name: str, model: str | None = None) -> Planner:
    """Build a planner by its command-line name.

    Args:
        name: One of :data:`PLANNERS`.
        model: For ``dqn`` and ``dqn-unshielded``: a model file; the shipped model for the
            world's field is used when None. ``dqn`` never picks a move that would touch an
            obstacle (:class:`~apf_physics.planners.dqn.DQNPlanner`'s shield);
            ``dqn-unshielded`` takes the network's choice as it is; ``dqn-known`` is ``dqn`` whose
            shield knows the moving obstacles' motion instead of predicting it.

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
