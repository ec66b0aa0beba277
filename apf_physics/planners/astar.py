"""The A* planner: executes the shortest grid path of :mod:`apf_physics.search` through the physics."""

from __future__ import annotations

import numpy as np

from apf_physics.planners.base import Planner
from apf_physics.search import LOS_MARGIN, LOS_SPACING, shortest_path
from apf_physics.world import World


class AStarPlanner(Planner):
    """Executes the shortest grid path (see the module docstring) through the physics.

    Each control step a robot moves straight toward its current waypoint, at most one unit
    along each axis (the direction kept, the length scaled down). A waypoint is passed once the
    robot is on it or once the next one is in sight (clearance ``robot_radius + LOS_MARGIN``
    along the segment from the robot). A robot from whose start no target can be reached is
    reported by :meth:`stuck`.

    It is the oracle for path length: its paths are near-shortest among those that keep the
    robot's radius plus a small margin from everything.
    """

    name = "astar"
    trap_rule = "oscillation"
    arrive = 0.05  # a waypoint is passed when the robot is this close to it [units]

    def reset(self, world: World, positions: np.ndarray) -> None:
        super().reset(world, positions)
        positions = np.asarray(positions, float).reshape(-1, 2)
        self.paths = [shortest_path(world, p) for p in positions]
        self._waypoint = np.ones(len(positions), int)
        self._no_path = np.array([p is None for p in self.paths], bool)

    def stuck(self) -> np.ndarray:
        """Robots from whose start no target can be reached."""
        return self._no_path

    def act(self, positions: np.ndarray, active: np.ndarray) -> np.ndarray:
        positions = np.asarray(positions, float).reshape(-1, 2)
        step = np.zeros_like(positions)
        movers = [i for i in np.flatnonzero(active) if not self._no_path[i] and len(self.paths[i]) > 1]
        if not movers:
            return step
        # Pass waypoints the robot is on.
        for i in movers:
            path, k = self.paths[i], self._waypoint[i]
            while k < len(path) - 1 and np.hypot(*(path[k] - positions[i])) <= self.arrive:
                k += 1
            self._waypoint[i] = k
        # Skip a waypoint when the one after it is already in sight (one check per robot, batched).
        ahead = [i for i in movers if self._waypoint[i] < len(self.paths[i]) - 1]
        if ahead:
            a = positions[ahead]
            b = np.array([self.paths[i][self._waypoint[i] + 1] for i in ahead])
            threshold = np.minimum(self.world.robot_radius + LOS_MARGIN, self.world.clearance(a))
            for i, ok in zip(ahead, self.world.path_clearance(a, b, LOS_SPACING) >= threshold):
                if ok:
                    self._waypoint[i] += 1
        for i in movers:
            d = self.paths[i][self._waypoint[i]] - positions[i]
            step[i] = d / max(1.0, float(np.max(np.abs(d))))
        return step
