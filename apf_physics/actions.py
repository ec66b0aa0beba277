"""The nine moves of SPEC §2 (thesis Table 1), in the thesis's order."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from apf_physics.world import World

ACTION_NAMES = ("up", "down", "left", "right", "left-up", "left-down", "right-up", "right-down", "stay")
ACTIONS = np.array(
    [(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (-1, -1), (1, 1), (1, -1), (0, 0)], dtype=float
)  # displacement per control step, world units

SAFETY = 0.05
"""Clearance kept beyond touching by planners that check their moves [world units]."""
MOVE_SAMPLES = 8
"""Points sampled along a move by :func:`move_clearance`, after its start."""


def move_clearance(world: World, positions: np.ndarray, moves: np.ndarray = ACTIONS) -> np.ndarray:
    """A lower bound of the clearance of a robot's centre along each straight move.

    The world's clearance (distance to the nearest obstacle or the map's edge) is sampled at
    the start and at :data:`MOVE_SAMPLES` evenly spaced points of the move, and the least of
    them is lowered by half the spacing: clearance changes no faster than distance, so no
    point between two samples is nearer than that. A move whose bound is at least the
    robot's radius cannot touch anything (the physics moves the disc along the segment).

    Args:
        world: The world.
        positions: (N, 2) robot centres.
        moves: (M, 2) displacements (default: the nine moves of :data:`ACTIONS`).

    Returns:
        (N, M) clearance bounds.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    moves = np.asarray(moves, dtype=float).reshape(-1, 2)
    t = np.linspace(0.0, 1.0, MOVE_SAMPLES + 1)
    points = positions[:, None, None, :] + t[None, None, :, None] * moves[None, :, None, :]   # (N, M, S+1, 2)
    clear = world.clearance(points.reshape(-1, 2)).reshape(len(positions), len(moves), -1).min(axis=2)
    return clear - 0.5 * np.hypot(*moves.T)[None, :] / MOVE_SAMPLES
