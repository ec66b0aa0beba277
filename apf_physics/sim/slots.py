"""Slots: the episodes the physics steps at once, each a world, its robots, and who meets whom.

Robot ``r`` of slot ``s`` has the global index ``s * robots_per_slot + r``. Robots of one slot (a
formation) meet each other; slots of one *crowd* (several formations in one world, or a fleet)
meet each other too; every other pair of robots never meets, whatever their coordinates.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from apf_physics.world.core import World


class Slots:
    """Per slot: its world, its step, its robots' radius, whether it meets other slots.

    Args:
        num_slots: Episodes stepped at once.
        robots_per_slot: Robots in each slot.
        crowds: Slots with the same crowd number meet (default: every slot on its own).

    Attributes:
        worlds: (S,) each slot's world (set by the physics).
        radius: (S,) its robots' radius; ``moving`` (S,) its world has moving obstacles.
        tile: (S,) its tile in the space; ``offset`` (S, 2) the tile's offset (world-local + offset
            = the space's coordinates).
        time: (S,) the control step its episode is at (where its moving obstacles are).
        crowd: (S,) crowd numbers; ``shared`` (S,) the slot meets other slots.
        crowd_robots: The global indices of the robots of each crowd of several slots.
        present: (N,) robots that exist (a formation smaller than the slot has absent ones).
    """

    def __init__(self, num_slots: int, robots_per_slot: int, crowds: Sequence[int] | None = None):
        self.count = int(num_slots)
        self.robots_per_slot = m = int(robots_per_slot)
        self.num_robots = self.count * m
        self.crowd = np.arange(self.count) if crowds is None else np.asarray(crowds, np.intp).reshape(self.count)
        numbers, size = np.unique(self.crowd, return_counts=True)
        self.shared = size[np.searchsorted(numbers, self.crowd)] > 1
        self.crowd_robots = [(np.flatnonzero(self.crowd == c)[:, None] * m + np.arange(m)).ravel()
                             for c in numbers[size > 1]]
        self.worlds: list[World] = [None] * self.count  # type: ignore[list-item]
        self.radius = np.zeros(self.count)
        self.moving = np.zeros(self.count, bool)
        self.tile = np.zeros(self.count, np.intp)
        self.offset = np.zeros((self.count, 2))
        self.time = np.zeros(self.count)
        self.present = np.ones(self.num_robots, bool)

    @property
    def meet(self) -> bool:
        """Some robots meet others (formations, crowds)."""
        return self.robots_per_slot > 1 or bool(self.crowd_robots)

    def of(self, robots: np.ndarray) -> np.ndarray:
        """The slot of each of ``robots`` (global indices)."""
        return robots // self.robots_per_slot

    def robots(self, slots: np.ndarray) -> np.ndarray:
        """The global indices of every robot of ``slots``, slot by slot."""
        m = self.robots_per_slot
        return (np.asarray(slots, np.intp)[:, None] * m + np.arange(m)).ravel()

    def group(self, robots: np.ndarray) -> np.ndarray:
        """A label per robot: robots with the same label meet each other (a crowd's, or a slot's own)."""
        slots = self.of(robots)
        return np.where(self.shared[slots], self.crowd[slots] - self.crowd.min(), -1 - slots)

    def solo(self, slots: np.ndarray) -> np.ndarray:
        """(k,) bool: slots whose single robot meets no robot and no moving obstacle (its proxy may
        share the world's tile with every other such robot's)."""
        return ~self.shared[slots] & ~self.moving[slots] & (self.robots_per_slot == 1)
