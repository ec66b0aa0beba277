"""The nine moves of Model §2 (thesis Table 1), in the thesis's order, and a finer set with half-length moves."""

from __future__ import annotations

import numpy as np

from apf_physics.world import Moment, World

ACTION_NAMES = ("up", "down", "left", "right", "left-up", "left-down", "right-up", "right-down", "stay")
ACTIONS = np.array(
    [(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (-1, -1), (1, 1), (1, -1), (0, 0)], dtype=float
)  # displacement per control step, world units

FINE_ACTIONS = np.vstack([ACTIONS[:8], 0.5 * ACTIONS[:8], ACTIONS[8:]])
"""The nine moves and the eight half-length ones (stay last): a robot can thread a passage
narrower than a unit lattice allows."""
MOVE_SETS = {"unit": ACTIONS, "fine": FINE_ACTIONS}
"""Move sets of planners, by name."""

SAFETY = 0.05
"""Clearance kept beyond touching by planners that check their moves [world units]."""
MOVE_SAMPLES = 8
"""Points sampled along a move by :func:`move_clearance`, after its start."""


def move_clearance(where: Moment | World, positions: np.ndarray, moves: np.ndarray = ACTIONS) -> np.ndarray:
    """A lower bound of the clearance of a robot's centre along each straight move.

    The clearance is sampled at the start and at :data:`MOVE_SAMPLES` evenly spaced points of
    the move (:meth:`Moment.path_clearance`), and the least of them is lowered by half the
    spacing: clearance changes no faster than distance, so no point between two samples is
    nearer than that. A move whose bound is at least the robot's radius cannot touch anything
    (the physics moves the disc along the segment).

    Args:
        where: The world at the control step the moves start at (:meth:`World.at`): moving
            obstacles are taken where they are along the move. A :class:`World`: its static
            obstacles only (:meth:`World.static_path_clearance`).
        positions: (N, 2) robot centres.
        moves: (M, 2) displacements (default: the nine moves of :data:`ACTIONS`).

    Returns:
        (N, M) clearance bounds.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    moves = np.asarray(moves, dtype=float).reshape(-1, 2)
    spacing = np.hypot(*moves.T) / MOVE_SAMPLES                                   # (M,)
    start = np.repeat(positions, len(moves), axis=0)
    end = start + np.tile(moves, (len(positions), 1))
    # a move of length 0 is one point: any positive spacing samples it
    clear = where.path_clearance(start, end, np.tile(np.where(spacing > 0, spacing, 1.0), len(positions)))
    return clear.reshape(len(positions), len(moves)) - 0.5 * spacing[None, :]
