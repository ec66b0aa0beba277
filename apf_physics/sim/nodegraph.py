"""The robot's configuration space as a graph of grid nodes, and the moves that keep a robot on it.

A learned planner that plans on a grid (the map network, :mod:`apf_physics.models.mapnet`) must
be able to go where its plan goes. Two things break that when the robot is large against its step
or the gaps are barely wider than the robot: a plan through free nodes whose straight link grazes
an obstacle, and a robot whose moves (fixed lengths from wherever it started) never land in a
corridor a tenth of a step wide. This module answers both:

- :class:`NodeGraph`: the nodes of a grid over the map (``resolution`` per step) where the robot
  fits with ``margin`` to spare (clearance measured from its surface, as every query here is),
  and the **links** between neighbouring nodes (8 directions) that the robot can follow: the
  exact least distance between the link and the static obstacles (:class:`~apf_physics.sim.swept.SweptDistances`,
  the physics' own compiled test) is at least ``radius + margin + length / 16``, so that the
  shield, whose sampled bound (:func:`~apf_physics.control.shield.move_clearance`, 8 samples) is at most
  ``length / 16`` below the exact value, admits every link the graph holds.
- :func:`node_moves`: the moves of a robot are the displacements to the grid's nodes within one
  step of it (``|dx|, |dy| ≤ 1``) and staying put. A robot that makes them stands on a node after
  its first move and goes from node to node: whatever corridor the graph threads, its moves
  thread too, at any ratio of robot size to step. With two nodes per step that is 24 moves in 16
  directions (the nine unit moves and the eight half-length ones among them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from apf_physics.world.field import Grid
from apf_physics.world.search import RESOLUTION  # noqa: F401 (named in the docstring: the A* grid's)
from apf_physics.sim.swept import SweptDistances
from apf_physics.world.core import World

NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]
"""The 8 directions ``(row, col)`` of a node's links, in the map network's order."""
SLACK = 1.0 / 16.0
"""A link keeps ``length × SLACK`` beyond the margin: what the shield's sampled bound may lose."""
ON_NODE = 1e-6
"""A robot this close to a node stands on it [steps]."""


@dataclass(frozen=True, eq=False)
class NodeGraph:
    """The free nodes of a grid over a world and the links a robot can follow between them.

    Attributes:
        grid: The nodes (``Grid.covering((0, 0), world.size, resolution)``).
        clearance: (rows, cols) static clearance at each node.
        free: (rows, cols) bool: a robot centred there keeps ``radius + margin``.
        links: (8, rows, cols) bool: link ``k`` (:data:`NEIGHBOURS`) from the node is followable
            (both ends free, and the exact least distance along it is enough: module docstring).
        margin: The margin beyond the robot's radius.
    """

    grid: Grid
    clearance: np.ndarray
    free: np.ndarray
    links: np.ndarray
    margin: float

    @classmethod
    def of(cls, world: World, resolution: int, margin: float) -> "NodeGraph":
        """The (cached) graph of ``world``'s static obstacles for its robot."""
        return world.cached(("node_graph", int(resolution), float(margin)),
                            lambda: cls.build(world, resolution, margin), static=True)

    @classmethod
    def build(cls, world: World, resolution: int, margin: float) -> "NodeGraph":
        grid = Grid.covering((0.0, 0.0), world.size, resolution)
        clearance = world.node_clearance(resolution)
        need = world.robot_radius + margin
        free = clearance >= need
        rows, cols = free.shape
        links = np.zeros((8, rows, cols), bool)
        sweeps = SweptDistances()
        number = sweeps.add(world)
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            length = math.hypot(dr, dc) / resolution
            bar = need + length * SLACK
            r0, r1 = max(0, -dr), rows - max(0, dr)
            c0, c1 = max(0, -dc), cols - max(0, dc)
            a = (slice(r0, r1), slice(c0, c1))
            b = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
            both = free[a] & free[b]
            # every point of a link is within length/2 of an end: ends with that much more room are clear
            sure = both & (np.minimum(clearance[a], clearance[b]) >= bar + length / 2)
            ok = sure.copy()
            check = np.argwhere(both & ~sure)
            if len(check):
                start = grid.to_world(np.column_stack([check[:, 1] + c0, check[:, 0] + r0]))
                move = np.broadcast_to(np.array([dc, dr], float) / resolution, start.shape)
                near = sweeps.near(np.full(len(check), number, np.intp), start, move, np.full(len(check), bar))
                ok[check[:, 0], check[:, 1]] = ~near
            forward = NEIGHBOURS.index((dr, dc))
            backward = NEIGHBOURS.index((-dr, -dc))
            links[forward][a] = ok
            links[backward][b] = ok
        return cls(grid, clearance, free, links, float(margin))

    def node_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K,) flat index of the nearest node to each point, and whether the point stands on it (within :data:`ON_NODE`)."""
        rows, cols = self.grid.shape
        index = self.grid.to_index(np.asarray(points, float).reshape(-1, 2))
        near = np.rint(index)
        on = np.all(np.abs(index - near) * (1.0 / self.grid.resolution) <= ON_NODE, axis=1)
        c = np.clip(near[:, 0].astype(np.intp), 0, cols - 1)
        r = np.clip(near[:, 1].astype(np.intp), 0, rows - 1)
        return r * cols + c, on


MOST_NODES = 4_000_000
"""A graph finer than its network's own grid is made coarser rather than hold more nodes than this."""
MOST_REFINEMENT = 4
"""A graph has at most this many times its network's own nodes per step (each robot's moves grow
with the square: 325 at 8 nodes per step)."""


def resolution_for(world: World, base: int, least: int | None = None) -> int:
    """Nodes per step of the graph a network whose own grid has ``base`` plans on in ``world``.

    At least ``least`` (default ``base``; the A* grid's :data:`~apf_physics.world.search.RESOLUTION`,
    4, makes the graph, with its smaller margin, hold every passage A*'s grid does). Doubled
    further while the nodes are more than the robot's diameter apart, up to
    :data:`MOST_REFINEMENT` times ``base``. Halved (not below ``base``) while the graph would hold
    more than :data:`MOST_NODES` nodes."""
    resolution = max(int(base), int(least or base))
    while 1.0 / resolution > 2.0 * world.robot_radius and resolution < MOST_REFINEMENT * base:
        resolution *= 2
    area = (world.size[0] + 1) * (world.size[1] + 1)
    while resolution > base and area * resolution ** 2 > MOST_NODES:
        resolution //= 2
    return resolution


def move_count(resolution: int) -> int:
    """How many moves :func:`node_moves` gives each robot: the nodes of a ``(2R + 2)²`` block, and staying."""
    return (2 * int(resolution) + 2) ** 2 + 1


def node_moves(graph: NodeGraph, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each robot's moves: to every free node within one step along each axis, and staying put (last).

    Args:
        graph: The world's node graph.
        positions: (N, 2) robot centres.

    Returns:
        ``moves`` (N, M, 2) displacements (components in [−1, 1]), ``usable`` (N, M) bool (the end is a
        free node within reach; staying always), and ``ends`` (N, M) the flat index of the node each
        move ends at (−1 for staying and unusable moves). ``M = move_count(resolution)``.
    """
    positions = np.asarray(positions, float).reshape(-1, 2)
    n = len(positions)
    res = graph.grid.resolution
    rows, cols = graph.grid.shape
    index = graph.grid.to_index(positions)
    base = np.floor(index - res).astype(np.intp)            # the block's lower-left node
    span = np.arange(2 * res + 2)
    c = base[:, None, 0, None] + span[None, None, :]          # (N, 1, S)
    r = base[:, None, 1, None] + span[None, :, None]          # (N, S, 1)
    c, r = np.broadcast_arrays(c, r)
    c, r = c.reshape(n, -1), r.reshape(n, -1)
    inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
    flat = np.where(inside, r * cols + c, 0)
    ends_xy = graph.grid.to_world(np.stack([c, r], axis=-1).reshape(-1, 2).astype(float)).reshape(n, -1, 2)
    moves = ends_xy - positions[:, None, :]
    reach = np.all(np.abs(moves) <= 1.0 + 1e-9, axis=2) & (np.hypot(moves[..., 0], moves[..., 1]) > ON_NODE)
    usable = inside & reach & graph.free.ravel()[flat]          # (the node the robot stands on: staying, last)
    moves = np.clip(moves, -1.0, 1.0)
    ends = np.where(usable, flat, -1)
    moves = np.concatenate([np.where(usable[..., None], moves, 0.0), np.zeros((n, 1, 2))], axis=1)
    usable = np.concatenate([usable, np.ones((n, 1), bool)], axis=1)
    ends = np.concatenate([ends, np.full((n, 1), -1, np.intp)], axis=1)
    return moves, usable, ends
