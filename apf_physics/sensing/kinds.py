"""Observation kinds: each a class with ``space()`` and ``observe()``, as highway-env's observation types are.

A task (a Gymnasium environment, a crowd of formations, a fleet) makes one with
:func:`make_observation` and hands it, every step, what the sensors know of the robots it
observes (:class:`Robots`); it never asks which kind it has. The kinds:

- ``"window"`` (:class:`WindowObservation`): the potential around the robot (Model §2), and the
  channels its :class:`~apf_physics.sensing.observation.ObserverConfig` adds (the field a step
  earlier, the visit memory);
- ``"lidar"`` (:class:`RangeObservation`): the range sensor's vector
  (:class:`~apf_physics.sensing.ranges.RangeObserver`);
- ``"window+lidar"`` (:class:`CombinedObservation`): both, as a ``Dict`` space.

Other robots (a formation's, a crowd's, a fleet's) come in two lists, each robot its own: the
robots a sensor can see (:attr:`Robots.others`: the lidar casts its beams against them) and the
robots that repel in its field (:attr:`Robots.discs`: the window reads them as discs, like
obstacles; a leader's own followers, which follow it, are not among them).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from gymnasium import spaces

from apf_physics.sensing.lidar import LidarConfig
from apf_physics.sensing.observation import Observer
from apf_physics.sensing.ranges import RangeObserver
from apf_physics.world.core import World
from apf_physics.world.kinematics import UnicycleLimits

OBSERVATIONS = ("window", "lidar", "window+lidar")
"""The observation kinds, by name (:func:`make_observation`)."""


@dataclass
class Robots:
    """What the sensors know of the robots being observed, one row each.

    Attributes:
        positions: (n, 2) their centres.
        rows: (n,) their rows in the observation (its robots are numbered from 0); None: all, in order.
        steps: The control step of each one's episode, (n,) or one for all (where moving obstacles are).
        headings: (n,) their headings [rad] (None: 0, holonomic robots, whose frame is the map's).
        velocity: (n, 2) a unicycle's last ``(v, ω)``, or a holonomic robot's last displacement (None: at rest).
        others: (n, D, 2) the other robots each one can see (rows of NaN: none), or None.
        discs: (n, E, 2) the other robots in each one's field, repelling like obstacles (rows of
            NaN: none), or None.
    """

    positions: np.ndarray
    rows: np.ndarray | None = None
    steps: np.ndarray | float = 0.0
    headings: np.ndarray | None = None
    velocity: np.ndarray | None = None
    others: np.ndarray | None = None
    discs: np.ndarray | None = None

    def poses(self) -> np.ndarray:
        """(n, 3) ``(x, y, θ)``."""
        theta = np.zeros(len(self.positions)) if self.headings is None else self.headings
        return np.column_stack([self.positions, theta])


class ObservationKind(ABC):
    """What ``num`` robots observe: one kind of observation (see the module docstring)."""

    @abstractmethod
    def space(self) -> spaces.Space:
        """One robot's observation space."""

    @abstractmethod
    def observe(self, robots: Robots) -> np.ndarray | dict:
        """The observations of ``robots``: an array with a row per robot, or a dict of such arrays."""

    def reset(self, rows: np.ndarray, positions: np.ndarray, worlds: Sequence[World]) -> None:
        """Robots ``rows`` start an episode at ``positions`` in ``worlds`` (one each)."""

    def centre_potential(self, observation: np.ndarray | dict) -> np.ndarray | None:
        """(n,) U at each robot, where the observation holds it as it is (None: it does not)."""
        return None

    reads_velocity = False
    """It reads :attr:`Robots.velocity` (the caller may leave it None otherwise)."""

    def seed(self, seeds: Sequence[int | None]) -> None:
        """Restart robot ``i``'s noise from ``seeds[i]`` (kinds with noise)."""


class WindowObservation(ObservationKind):
    """The potential window (Model §2) and its channels, built by an :class:`~apf_physics.sensing.observation.Observer`.

    It reads the observer of the task that made it, which the task resets (the task also asks it
    for the potential at the robots, the reward's W4, and for their visits): :meth:`reset` leaves
    it alone.
    """

    def __init__(self, observer: Observer):
        self.observer = observer
        self._centre = observer.config.size // 2

    def space(self) -> spaces.Box:
        low, high = self.observer.value_bounds()  # finite: from the worlds' U
        return spaces.Box(low, high, self.observer.config.shape, np.float32)

    def centre_potential(self, observation: np.ndarray) -> np.ndarray | None:
        if self.observer.config.scale != "raw":
            return None   # a scaled window reads 0 at the robot
        return observation[:, 0, self._centre, self._centre]

    def observe(self, robots: Robots) -> np.ndarray:
        observer = self.observer
        if robots.discs is None:
            return observer.observe(robots.positions, robots.rows, robots.steps)
        # each robot's own discs: a call each (the robots of a crowd see different ones)
        rows = np.arange(len(robots.positions)) if robots.rows is None else np.asarray(robots.rows, np.intp)
        steps = np.broadcast_to(np.asarray(robots.steps, float), (len(rows),))
        out = np.empty((len(rows), *observer.config.shape), np.float32)
        for n in range(len(rows)):
            discs = robots.discs[n]
            discs = discs[~np.isnan(discs[:, 0])]
            out[n] = observer.observe(robots.positions[n:n + 1], rows[n:n + 1], steps[n], discs)[0]
        return out


class RangeObservation(ObservationKind):
    """The range sensor's vector (:class:`~apf_physics.sensing.ranges.RangeObserver`).

    Args:
        ranges: The range observer.
        worlds: The worlds robots may be in; ``world_of`` (num,) each robot's, set at :meth:`reset`.
    """

    reads_velocity = True

    def __init__(self, ranges: RangeObserver, worlds: Sequence[World]):
        self.ranges = ranges
        self.worlds = list(worlds)
        self.world_of = np.zeros(ranges.num, np.intp)

    def space(self) -> spaces.Box:
        low, high = self.ranges.bounds()
        return spaces.Box(low, high, low.shape, np.float32)

    def seed(self, seeds: Sequence[int | None]) -> None:
        self.ranges.seed(seeds)

    def reset(self, rows: np.ndarray, positions: np.ndarray, worlds: Sequence[World]) -> None:
        for world in worlds:
            if all(world is not w for w in self.worlds):
                self.worlds.append(world)
        index = {id(w): i for i, w in enumerate(self.worlds)}
        self.world_of[np.asarray(rows, np.intp).reshape(-1)] = [index[id(w)] for w in worlds]

    def observe(self, robots: Robots) -> np.ndarray:
        rows = slice(None) if robots.rows is None else robots.rows
        velocity = np.zeros((len(robots.positions), 2)) if robots.velocity is None else robots.velocity
        return self.ranges.observe(self.worlds, self.world_of[rows], robots.poses(), velocity, robots.steps,
                                   robots.others, robots.rows)


class CombinedObservation(ObservationKind):
    """Several kinds at once, as a ``Dict`` space (``{"window": ..., "lidar": ...}``)."""

    def __init__(self, parts: dict[str, ObservationKind]):
        self.parts = parts
        self.reads_velocity = any(part.reads_velocity for part in parts.values())

    def space(self) -> spaces.Dict:
        return spaces.Dict({name: part.space() for name, part in self.parts.items()})

    def seed(self, seeds: Sequence[int | None]) -> None:
        for part in self.parts.values():
            part.seed(seeds)

    def reset(self, rows: np.ndarray, positions: np.ndarray, worlds: Sequence[World]) -> None:
        for part in self.parts.values():
            part.reset(rows, positions, worlds)

    def centre_potential(self, observation: dict) -> np.ndarray | None:
        for name, part in self.parts.items():
            u = part.centre_potential(observation[name])
            if u is not None:
                return u
        return None

    def observe(self, robots: Robots) -> dict:
        return {name: part.observe(robots) for name, part in self.parts.items()}


def make_observation(kind: str, observer: Observer, lidar: LidarConfig = LidarConfig(),
                     unicycle: UnicycleLimits | None = None, worlds: Sequence[World] = ()) -> ObservationKind:
    """The observation of ``kind`` (:data:`OBSERVATIONS`) for the robots of ``observer``.

    Args:
        kind: Which kind.
        observer: The window observer of the robots (the window kind is it; the others use its
            number of robots).
        lidar: The range sensor's beams (the ``lidar`` kinds).
        unicycle: The robots' limits if they are unicycles (their velocity is read as ``(v, ω)``).
        worlds: The worlds robots may be in.

    Raises:
        ValueError: An unknown kind.
    """
    window = WindowObservation(observer)
    ranges = RangeObservation(RangeObserver(lidar, observer.num, unicycle), worlds)
    made = {"window": window, "lidar": ranges,
            "window+lidar": CombinedObservation({"window": window, "lidar": ranges})}
    if kind not in made:
        raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {kind!r}")
    return made[kind]
