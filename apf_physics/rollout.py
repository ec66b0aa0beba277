"""Run a planner from a batch of starts through the physics and decide how each episode ends.

All starts of a world run at once: one physics slot per start, one ``space.step`` per
substep for all of them.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from apf_physics.physics import Physics
from apf_physics.planners.base import Planner
from apf_physics.world import World

OUTCOMES = ("reached", "collision", "trapped", "timeout")


@dataclass
class Episode:
    """One robot's run from one start.

    Attributes:
        world: The world's name.
        start: Start position.
        outcome: ``"reached"``, ``"collision"``, ``"trapped"`` or ``"timeout"``.
        steps: Control steps taken.
        path: ``(steps + 1, 2)`` positions, the start first.
        contacts: What the robot touched when it collided (``"obstacle"``, ``"wall"``, ``"robot"``).
    """

    world: str
    start: np.ndarray
    outcome: str
    steps: int
    path: np.ndarray
    contacts: list[str] = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.outcome == "reached"

    @property
    def path_length(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.path, axis=0).T))) if len(self.path) > 1 else 0.0

    def to_dict(self) -> dict:
        return {
            "world": self.world,
            "start": [float(v) for v in self.start],
            "success": self.success,
            "collision": self.outcome == "collision",
            "trapped": self.outcome == "trapped",
            "outcome": self.outcome,
            "steps": int(self.steps),
            "path_length": round(self.path_length, 4),
            "final_position": [round(float(v), 4) for v in self.path[-1]],
        }


@dataclass(frozen=True)
class TrapDetector:
    """Decides when a robot is stuck, from its recent history.

    Attributes:
        window: Control steps looked back over.
        radius: Oscillating: every position of the window lies within this distance of their mean.
        min_drop: ``"descent"`` rule only: trapped when the lowest potential of the window is not
            at least this much below the lowest potential before it.
    """

    window: int = 10
    radius: float = 1.5
    min_drop: float = 1e-3

    def watch(self, rule: str, starts: np.ndarray, potentials: np.ndarray, window: int | None = None) -> TrapWatch:
        """Follow a batch of robots from their starts (and the potential there).

        ``window`` replaces :attr:`window` when given (a planner's own, :attr:`Planner.trap_window`).
        """
        detector = self if window is None else dataclasses.replace(self, window=int(window))
        return TrapWatch(detector, rule, starts, potentials)


class TrapWatch:
    """Per-robot recent history for :class:`TrapDetector`: constant work per step, however long the episode."""

    def __init__(self, detector: TrapDetector, rule: str, starts: np.ndarray, potentials: np.ndarray):
        self.detector, self.rule = detector, rule
        w = detector.window
        self.recent = [deque([np.asarray(p, float)], maxlen=w) for p in starts]
        self.recent_u = [deque([float(u)], maxlen=w) for u in potentials]
        self.earlier_min_u = [np.inf] * len(starts)   # lowest potential before the window
        self.length = [1] * len(starts)

    def step(self, i: int, position: np.ndarray, potential: float) -> bool:
        """Record robot ``i``'s new position; True when it is trapped."""
        d = self.detector
        if len(self.recent_u[i]) == d.window:  # the oldest entry leaves the window
            self.earlier_min_u[i] = min(self.earlier_min_u[i], self.recent_u[i][0])
        self.recent[i].append(np.asarray(position, float))
        self.recent_u[i].append(float(potential))
        self.length[i] += 1
        if self.length[i] <= d.window:
            return False
        recent = np.array(self.recent[i])
        if np.max(np.hypot(*(recent - recent.mean(axis=0)).T)) < d.radius:
            return True
        if self.rule == "descent":
            return min(self.recent_u[i]) > self.earlier_min_u[i] - d.min_drop
        return False


def default_max_steps(world: World) -> int:
    """A generous step limit: four times the map's perimeter-half."""
    return int(4 * (world.size[0] + world.size[1]))


def rollout(world: World, planner: Planner, starts: Sequence[Sequence[float]] | np.ndarray,
            max_steps: int | None = None, trap: TrapDetector = TrapDetector()) -> list[Episode]:
    """Run ``planner`` from every start in ``world``, all at once, through the physics.

    An episode ends when the robot's centre comes within ``world.goal_tolerance`` of a target
    (reached), when it touches an obstacle or the map's edge (collision), when the trap rule
    fires (trapped), or after ``max_steps`` control steps (timeout).
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    n = len(starts)
    if n == 0:
        return []
    max_steps = default_max_steps(world) if max_steps is None else int(max_steps)
    physics = Physics([world] * n)
    physics.place(np.arange(n), starts)
    planner.reset(world, starts.copy())

    paths = [[s.copy()] for s in starts]
    watch = trap.watch(planner.trap_rule, starts, world.potential(starts), planner.trap_window)
    outcome: list[str | None] = [None] * n
    contacts: list[list[str]] = [[] for _ in range(n)]
    steps = np.zeros(n, int)
    active = np.ones(n, bool)
    positions = starts.copy()
    at_target = np.min(np.linalg.norm(starts[:, None, :] - world.targets[None], axis=2), axis=1) <= world.goal_tolerance
    for i in np.flatnonzero(at_target):
        outcome[i] = "reached"
        active[i] = False
    for _ in range(max_steps):
        if not active.any():
            break
        command = planner.act(positions, active)
        command[~active] = 0.0
        gave_up = planner.stuck()
        if gave_up is not None:
            for i in np.flatnonzero(gave_up & active):
                outcome[i] = "trapped"
                active[i] = False
            command[~active] = 0.0
        log = physics.step(command)
        positions = physics.positions
        # Robots whose episode ended stay where they are, whatever the solver did to them.
        u = world.potential(positions)
        dist = np.min(np.linalg.norm(positions[:, None, :] - world.targets[None], axis=2), axis=1)
        for i in np.flatnonzero(active):
            steps[i] += 1
            paths[i].append(positions[i].copy())
            if log.any[i]:
                outcome[i] = "collision"
                contacts[i] = sorted({c.kind for c in log.contacts if c.robot == i})
            elif dist[i] <= world.goal_tolerance:
                outcome[i] = "reached"
            elif watch.step(i, positions[i], u[i]):
                outcome[i] = "trapped"
            if outcome[i] is not None:
                active[i] = False
    return [Episode(world.name, starts[i], outcome[i] or "timeout", int(steps[i]), np.asarray(paths[i]), contacts[i])
            for i in range(n)]
