"""The A* planner: executes the shortest grid path of :mod:`apf_physics.world.search` through the physics."""

from __future__ import annotations

import numpy as np

from apf_physics.control.fleet import Lattice, goal_columns
from apf_physics.planners.base import Planner
from apf_physics.world.search import LOS_MARGIN, LOS_SPACING, SearchGrid, timed_path
from apf_physics.world.core import Moment, World

HORIZON = 4.0
"""How far ahead (along the path, in units) a replanning robot checks its path against the moving obstacles."""


class AStarPlanner(Planner):
    """Executes the shortest grid path (:class:`~apf_physics.world.search.SearchGrid`) through the physics.

    Each control step a robot moves straight toward its current waypoint, at most one unit
    along each axis (the direction kept, the length scaled down). A waypoint is passed once the
    robot is on it or once the next one is in sight (clearance ``robot_radius + LOS_MARGIN``
    along the segment from the robot). A robot from whose start no target can be reached is
    reported by :meth:`stuck`.

    In a world without moving obstacles it is the oracle for path length: its paths are
    near-shortest among those that keep the robot's radius plus a small margin from
    everything. With moving obstacles it is the reactive baseline: every step, a robot whose
    path (over the next :data:`HORIZON` units) runs into a moving obstacle where it is now
    plans again around the obstacles as they stand (A* on the grid); it does not predict
    where they go. When no path exists around them, it waits.
    """

    name = "astar"
    trap_rule = "oscillation"
    arrive = 0.05  # a waypoint is passed when the robot is this close to it [units]

    def reset(self, world: World, positions: np.ndarray) -> None:
        super().reset(world, positions)
        positions = np.asarray(positions, float).reshape(-1, 2)
        self.search = SearchGrid.of(world)
        self.paths = [self.search.path(p) for p in positions]
        self._waypoint = np.ones(len(positions), int)
        self._no_path = np.array([p is None for p in self.paths], bool)

    def stuck(self) -> np.ndarray:
        """Robots from whose start no target can be reached."""
        return self._no_path

    def fleet_values(self, lattice: Lattice, nodes: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """A* on a fleet's lattice, from every node at once: each robot's moves ranked by the shortest
        way from where they end to its goal node (a Dijkstra search per goal, kept within the budget of
        :meth:`goal_tables`). With the fleet's rule this is PIBT as its authors run it."""
        return -goal_columns(self.goal_tables(lattice), nodes, goals, lattice.distances)

    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        positions = np.asarray(positions, float).reshape(-1, 2)
        moment = self._moment(moment)
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
        moving = bool(self.world.moving)
        if moving:
            waiting = self._replan(positions, movers, moment)
            movers = [i for i in movers if i not in waiting]
        # Skip a waypoint when the one after it is already in sight (one check per robot, batched).
        ahead = [i for i in movers if self._waypoint[i] < len(self.paths[i]) - 1]
        if ahead:
            a = positions[ahead]
            b = np.array([self.paths[i][self._waypoint[i] + 1] for i in ahead])
            if moving:
                now = moment.clearance(a)
                sight = moment.path_clearance(a, b, LOS_SPACING, during=False)
            else:
                now = self.world.static_clearance(a)
                sight = self.world.static_path_clearance(a, b, LOS_SPACING)
            threshold = np.minimum(self.world.robot_radius + LOS_MARGIN, now)
            for i, ok in zip(ahead, sight >= threshold):
                if ok:
                    self._waypoint[i] += 1
        for i in movers:
            d = self.paths[i][self._waypoint[i]] - positions[i]
            step[i] = d / max(1.0, float(np.max(np.abs(d))))
        return step

    def _replan(self, positions: np.ndarray, movers: list[int], moment: Moment) -> set[int]:
        """Plan again for the robots whose path ahead meets a moving obstacle now (at ``moment``); returns those that wait."""
        waiting = set()
        bar = self.world.robot_radius + LOS_MARGIN
        for i in movers:
            path = np.vstack([positions[i], self.paths[i][self._waypoint[i]:]])
            lengths = np.hypot(*np.diff(path, axis=0).T)
            keep = int(np.searchsorted(np.cumsum(lengths), HORIZON)) + 1
            a, b = path[:-1][:keep], path[1:][:keep]
            static = self.world.static_path_clearance(a, b, LOS_SPACING)
            now = moment.path_clearance(a, b, LOS_SPACING, during=False) if len(a) else static
            # blocked by a moving obstacle (not by the static ones, which the path already respects)
            if len(a) and np.any((now < bar) & (now < static)):
                new = self.search.path(positions[i], moment.t)
                if new is None or len(new) < 2:
                    waiting.add(i)
                    continue
                self.paths[i] = new
                self._waypoint[i] = 1
        return waiting


class SIPPPlanner(Planner):
    """The oracle that knows the future: a plan in space and time on the known motion, executed through the physics.

    At the start of each episode, one search per robot (:func:`~apf_physics.world.search.timed_path`: A*
    over the time-expanded graph of the nine unit moves, waiting included, every moving obstacle
    where the physics will have it at each moment of each step, with a margin of
    :data:`MARGIN` beyond the robot's radius). Each control step the robot makes its plan's next
    move (toward the plan's next position, should it be off it). A robot for which no plan is
    found waits where it is (reported by :meth:`stuck`). The learned planner never consults it.
    """

    name = "sipp"
    trap_rule = "oscillation"
    trap_window = 1000   # waiting for an obstacle to pass is part of a plan, not being trapped
    MARGIN = 0.05
    """Clearance kept beyond the robot's radius by a plan's moves [units]."""

    def reset(self, world: World, positions: np.ndarray) -> None:
        super().reset(world, positions)
        positions = np.asarray(positions, float).reshape(-1, 2)
        limit = int(4 * (world.size[0] + world.size[1]))
        self.plans = [timed_path(world, p, 0, margin=self.MARGIN, max_steps=limit) for p in positions]
        self._no_plan = np.array([p is None for p in self.plans], bool)

    def stuck(self) -> np.ndarray:
        """Robots for which no plan was found."""
        return self._no_plan

    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        positions = np.asarray(positions, float).reshape(-1, 2)
        k = int(self._moment(moment).t)
        step = np.zeros_like(positions)
        for i in np.flatnonzero(active).tolist():
            plan = self.plans[i]
            if plan is None or len(plan) < 2:
                continue
            d = plan[min(k + 1, len(plan) - 1)] - positions[i]
            step[i] = d / max(1.0, float(np.max(np.abs(d))))
        return step
