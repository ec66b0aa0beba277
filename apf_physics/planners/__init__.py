"""Planners: policies that turn robot positions into velocity commands."""

from __future__ import annotations

from apf_physics.planners.base import Planner
from apf_physics.planners.gradient import GradientPlanner

PLANNERS = ("gradient", "dqn", "dqn-unshielded", "astar", "escape")


def make_planner(name: str, model: str | None = None) -> Planner:
    """Build a planner by its command-line name.

    Args:
        name: One of :data:`PLANNERS`.
        model: For ``dqn`` and ``dqn-unshielded``: a model file; the shipped model for the
            world's field is used when None. ``dqn`` never picks a move that would touch an
            obstacle (:class:`~apf_physics.planners.dqn.DQNPlanner`'s shield);
            ``dqn-unshielded`` takes the network's choice as it is.
    """
    from apf_physics.errors import UserError

    if name == "gradient":
        return GradientPlanner()
    if name in ("dqn", "dqn-unshielded"):
        from apf_physics.planners.dqn import DQNPlanner
        return DQNPlanner(model, shield=name == "dqn")
    if name == "astar":
        from apf_physics.planners.astar import AStarPlanner
        return AStarPlanner()
    if name == "escape":
        from apf_physics.planners.escape import EscapePlanner
        return EscapePlanner()
    raise UserError(f"--planner: unknown planner {name!r} (known: {', '.join(PLANNERS)})")


__all__ = ["GradientPlanner", "Planner", "PLANNERS", "make_planner"]
