"""The range-sensor observation: a lidar scan, the target's distance and bearing, the robot's own velocity."""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from apf_physics.sensing.lidar import Lidar, LidarConfig
from apf_physics.world.core import World
from apf_physics.world.kinematics import UnicycleLimits, distance_bearing


class RangeObserver:
    """The range-sensor observation of ``num`` robots: a vector of ``K + 5`` values in ``[-1, 1]``.

    - ``[0, K)``: the ranges of the K lidar beams (:func:`apf_physics.sensing.lidar.scan`: static and
      moving obstacles, the map's edge, other robots), divided by the maximum range: 1 where a
      beam meets nothing. Beam ``k`` points ``−π + 2πk/K`` from the robot's heading (a full
      circle; beam K/2 straight ahead), or spreads evenly over a narrower field of view.
    - ``K``: the nearest target's distance ``d`` as ``tanh(d / max_range)`` (0 on the target,
      near 1 far away).
    - ``K + 1``, ``K + 2``: the target's bearing in the robot's frame as ``(sin, cos)`` (0, 1:
      straight ahead).
    - ``K + 3``, ``K + 4``: the robot's own velocity. A unicycle: its last command ``(v, ω)``,
      ``v`` over the top speed (forward; over the reverse speed backward) and ``ω`` over the top
      turn rate. A holonomic robot (no heading: its frame is the map's): the last step's
      displacement ``(dx, dy)`` over √2, the longest move.

    Args:
        config: The beams (noise included).
        num: Robots observed.
        unicycle: The robots' limits if they are unicycles, else None.

    The noise of robot ``i`` comes from a generator of its own (:meth:`seed`), so that copy ``i``
    of a vector env seeded ``seed + i`` reads what a single env seeded ``seed + i`` reads.
    """

    def __init__(self, config: LidarConfig, num: int, unicycle: UnicycleLimits | None = None):
        self.config = config
        self.num = int(num)
        self.unicycle = unicycle
        self.lidar = Lidar(replace(config, noise=0.0))
        self.size = config.beams + 5
        self.rngs = [np.random.default_rng() for _ in range(self.num)]

    def seed(self, seeds: Sequence[int | None]) -> None:
        """Restart robot ``i``'s noise generator from ``seeds[i]``."""
        self.rngs = [np.random.default_rng(s) for s in seeds]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` (size,) float32: the ranges and the distance in ``[0, 1]``, the rest in ``[-1, 1]``."""
        low = np.full(self.size, -1.0, np.float32)
        low[:self.config.beams + 1] = 0.0
        return low, np.ones(self.size, np.float32)

    def observe(self, worlds: Sequence[World], world_of: np.ndarray, poses: np.ndarray, velocity: np.ndarray,
                t: np.ndarray | float = 0.0, others: np.ndarray | None = None,
                robots: np.ndarray | None = None) -> np.ndarray:
        """(n, size) float32 observations of ``robots`` (default all).

        Args:
            worlds, world_of: Robot ``i`` is in ``worlds[world_of[i]]``.
            poses: (n, 3) ``(x, y, θ)`` (θ = 0 for holonomic robots).
            velocity: (n, 2) a unicycle's last ``(v, ω)``, or a holonomic robot's last displacement.
            t: The control step of each robot's episode (where the moving obstacles are).
            others: (n, D, 2) the other robots each one sees (:func:`~apf_physics.sensing.lidar.teammates`).
        """
        poses = np.asarray(poses, float).reshape(-1, 3)
        world_of = np.asarray(world_of, np.intp).reshape(-1)
        k = self.config.beams
        out = np.empty((len(poses), self.size), np.float32)
        ranges = self.lidar.scan_worlds(worlds, world_of, poses, t, others)
        if self.config.noise > 0:
            rows = range(self.num) if robots is None else np.asarray(robots, np.intp).reshape(-1).tolist()
            ranges = np.stack([self.config.noisy(ranges[n], self.rngs[i]) for n, i in enumerate(rows)])
        out[:, :k] = ranges / self.config.max_range
        target = np.empty((len(poses), 2))
        for w in np.unique(world_of).tolist():
            mine = world_of == w
            target[mine] = worlds[w].nearest_target(poses[mine, :2])
        distance, bearing = distance_bearing(poses, target)
        out[:, k] = np.tanh(distance / self.config.max_range)
        out[:, k + 1] = np.sin(bearing)
        out[:, k + 2] = np.cos(bearing)
        velocity = np.asarray(velocity, float).reshape(-1, 2)
        if self.unicycle is None:
            out[:, k + 3:] = np.clip(velocity / np.sqrt(2.0), -1.0, 1.0)
        else:
            out[:, k + 3:] = self.unicycle.to_unit(velocity[:, 0], velocity[:, 1])
        return out
