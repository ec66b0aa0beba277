"""The map network's view: the whole map as a grid of nodes, the robot's clearance and where the target is.

Built once per world and resolution (:meth:`MapView.of`), shared by the map network's planner
(:mod:`apf_physics.models.policy`) and its imitation learner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apf_physics.world.core import World
from apf_physics.world.field import Grid


@dataclass(frozen=True)
class MapView:
    """What a robot sees of the whole (static) map: the observation of map-planning networks.

    A grid over the map at ``resolution`` nodes per unit (node ``[r, c]`` at
    ``grid.to_world((c, r))``), each node with :data:`~apf_physics.models.mapnet.MAP_FEATURES`
    features: the robot's clearance there beyond its radius (``(clearance − radius) / 2``,
    clipped to ``[−0.5, 1]``) and whether a target is within reach (the goal tolerance).

    Attributes:
        grid: The nodes.
        features: (2, rows, cols) float32 node features.
        free: (rows, cols) bool: the robot fits there with ``margin`` to spare.
        goal: (rows, cols) bool: free nodes within ``0.9 ×`` the goal tolerance of a target.
    """

    grid: Grid
    features: np.ndarray
    free: np.ndarray
    goal: np.ndarray

    @classmethod
    def of(cls, world: World, resolution: int = 2, margin: float = 0.05) -> "MapView":
        """The (cached) map view of ``world``'s static obstacles."""
        def build() -> MapView:
            grid = Grid.covering((0.0, 0.0), world.size, resolution)
            points = grid.node_points()
            clearance = world.node_clearance(resolution)
            free = clearance >= world.robot_radius + margin
            goal = (world.distance_to_target(points).reshape(grid.shape) <= 0.9 * world.goal_tolerance) & free
            features = np.stack([np.clip((clearance - world.robot_radius) / 2.0, -0.5, 1.0),
                                 goal.astype(float)]).astype(np.float32)
            return cls(grid, features, free, goal)
        return world.cached(("map_view", int(resolution), float(margin)), build)
