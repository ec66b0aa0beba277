"""The observation of SPEC §2: a k×k window of the potential around each robot.

Window point ``[i, j]`` of a robot at ``(x, y)`` is ``(x + (j − k//2), y + (k//2 − i))``: row 0
is the top (highest y), as in an image. Values come from a padded raster of U built once per
world; nodes inside an obstacle or outside the map read ``world.u_wall``, the map's highest
potential, so blocked points always look impassable. Because the window's spacing (1 unit)
is a whole number of raster cells, every point of a window shares the same bilinear weights:
sampling N windows is four gathers and a weighted sum, for robots in any mix of worlds.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from apf_physics.field import Grid, Raster
from apf_physics.world import World


def observation_raster(world: World, margin: int, resolution: int = 4) -> Raster:
    """U over the map plus ``margin`` units on every side, blocked nodes set to ``world.u_wall``.

    Built once per world and cached.
    """
    key = ("observation", int(margin), int(resolution))
    if key not in world._cache:
        grid = Grid.covering((-margin, -margin), (world.size[0] + margin, world.size[1] + margin), resolution)
        nodes = grid.node_points()
        values = world.potential(nodes)
        blocked = (world.edge_distance(nodes) < 0) | (world.obstacle_distance(nodes) <= 0)
        values[blocked] = world.u_wall
        world._cache[key] = Raster(grid, values.reshape(grid.shape))
    return world._cache[key]


class WindowSampler:
    """Samples k×k potential windows for batches of robots, each robot in its own world.

    Args:
        worlds: Worlds the robots may be in; more can be added with :meth:`add_world`.
        size: Window side ``k`` (odd).
        resolution: Raster nodes per unit.
    """

    def __init__(self, worlds: Sequence[World] = (), size: int = 11, resolution: int = 4):
        if size < 1 or size % 2 == 0:
            raise ValueError(f"observation size must be odd and positive, got {size}")
        self.size = int(size)
        self.resolution = int(resolution)
        self.margin = self.size // 2 + 2
        self.worlds: list[World] = []
        self._ids: dict[int, int] = {}
        self._values = np.zeros(0)
        self._start: list[int] = []
        self._cols: list[int] = []
        self._origin: list[tuple[float, float]] = []
        self._shape: list[tuple[int, int]] = []
        half = self.size // 2
        steps = np.arange(self.size) - half
        self._dx = steps[None, :] * self.resolution           # (1, k) columns, left → right
        self._dy = -steps[:, None] * self.resolution          # (k, 1) rows, top → bottom
        for world in worlds:
            self.add_world(world)

    def add_world(self, world: World) -> int:
        """Register a world (once) and return its index."""
        key = id(world)
        if key in self._ids and self.worlds[self._ids[key]] is world:
            return self._ids[key]
        raster = observation_raster(world, self.margin, self.resolution)
        self._ids[key] = len(self.worlds)
        self.worlds.append(world)
        self._start.append(len(self._values))
        self._cols.append(raster.grid.shape[1])
        self._origin.append(raster.grid.origin)
        self._shape.append(raster.grid.shape)
        self._values = np.concatenate([self._values, raster.values.ravel()])
        self._grids = [self._values[a:a + r * c].reshape(r, c) for a, (r, c) in zip(self._start, self._shape)]
        self._start_arr = np.asarray(self._start)
        self._cols_arr = np.asarray(self._cols)
        self._origin_arr = np.asarray(self._origin, dtype=float)
        self._shape_arr = np.asarray(self._shape)
        return self._ids[key]

    def world_index(self, world: World) -> int:
        return self.add_world(world)

    def sample(self, positions: np.ndarray, world_ids: np.ndarray | int = 0) -> np.ndarray:
        """Windows around ``positions`` (N, 2), robot n in world ``world_ids[n]``.

        Returns:
            (N, k, k) float64.
        """
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        if len(positions) == 1:
            return self._sample_one(positions[0], int(np.asarray(world_ids).ravel()[0]))
        ids = np.asarray(world_ids, dtype=np.intp)
        if ids.ndim == 0:
            ids = np.full(len(positions), int(ids))
        c0, r0, fx, fy = self._corner(positions, ids)
        cols = self._cols_arr[ids][:, None, None]
        base = (self._start_arr[ids] + r0 * self._cols_arr[ids] + c0)[:, None, None]
        idx = base + self._dy[None] * cols + self._dx[None]          # (N, k, k)
        v = self._values
        fx = fx[:, None, None]
        fy = fy[:, None, None]
        top = v[idx + cols]
        top += fx * (v[idx + cols + 1] - top)
        bottom = v[idx]
        bottom += fx * (v[idx + 1] - bottom)
        bottom += fy * (top - bottom)
        return bottom

    def _corner(self, positions: np.ndarray, ids: np.ndarray):
        """Lower-left raster node of each window's centre cell, and the bilinear weights."""
        res = self.resolution
        index = (positions - self._origin_arr[ids]) * res            # continuous (col, row)
        shape = self._shape_arr[ids]
        # Keep every window inside its padded raster (robots never leave their map).
        reach = self.size // 2 * res
        col = np.clip(index[:, 0], reach, shape[:, 1] - 2 - reach)
        row = np.clip(index[:, 1], reach, shape[:, 0] - 2 - reach)
        c0 = col.astype(np.intp)
        r0 = row.astype(np.intp)
        return c0, r0, col - c0, row - r0

    def _sample_one(self, position: np.ndarray, world_id: int) -> np.ndarray:
        """One window from strided views of the raster: no index arrays at all."""
        res, reach = self.resolution, self.size // 2 * self.resolution
        rows, cols = self._shape[world_id]
        ox, oy = self._origin[world_id]
        col = min(max((position[0] - ox) * res, reach), cols - 2 - reach)
        row = min(max((position[1] - oy) * res, reach), rows - 2 - reach)
        c0, r0 = int(col), int(row)
        fx, fy = col - c0, row - r0
        grid = self._grids[world_id]
        rs = slice(r0 - reach, r0 + reach + 1, res)
        rs1 = slice(r0 + 1 - reach, r0 + reach + 2, res)
        cs = slice(c0 - reach, c0 + reach + 1, res)
        cs1 = slice(c0 + 1 - reach, c0 + reach + 2, res)
        out = grid[rs, cs] * ((1 - fx) * (1 - fy))
        out += grid[rs, cs1] * (fx * (1 - fy))
        out += grid[rs1, cs] * ((1 - fx) * fy)
        out += grid[rs1, cs1] * (fx * fy)
        return out[None, ::-1]


class VisitMemory:
    """Per-robot visit counts over the 1×1 cells of each robot's world: the memory channel.

    Cell ``(c, r)`` of a world covers ``[c, c + 1) × [r, r + 1)`` of its map. :meth:`reset`
    clears a robot's counts and counts its start cell; :meth:`visit` counts the cells the
    robots are in (call it after every step). :meth:`window` reads the counts at the same
    points as :class:`WindowSampler` (point ``[i, j]`` is ``(x + j − k//2, y + k//2 − i)``)
    as ``min(count, cap) / cap``; points outside the map read 1, like a cell visited often.

    Args:
        num: Number of robots.
        size: Window side ``k`` (odd).
        cap: Count at which a cell reads 1.
    """

    def __init__(self, num: int, size: int = 11, cap: int = 4):
        if size < 1 or size % 2 == 0:
            raise ValueError(f"window size must be odd and positive, got {size}")
        self.num = int(num)
        self.size = int(size)
        self.cap = int(cap)
        self.dims = np.ones((self.num, 2), dtype=np.intp)          # cells per robot's map: (columns, rows)
        self.counts = np.zeros((self.num, 1, 1), dtype=np.int32)   # (N, columns, rows), grown as needed
        half = self.size // 2
        steps = np.arange(self.size) - half
        self._dc = np.broadcast_to(steps[None, :], (self.size, self.size))   # column offset of [i, j]: j − k//2
        self._dr = np.broadcast_to(-steps[:, None], (self.size, self.size))  # row offset of [i, j]: k//2 − i

    @staticmethod
    def cells_of(world: World) -> tuple[int, int]:
        """(columns, rows) of 1×1 cells covering a world's map."""
        return max(1, int(np.ceil(world.size[0]))), max(1, int(np.ceil(world.size[1])))

    def _cell(self, positions: np.ndarray, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cell = np.floor(np.asarray(positions, dtype=float).reshape(-1, 2)).astype(np.intp)
        dims = self.dims[slots]
        return np.clip(cell[:, 0], 0, dims[:, 0] - 1), np.clip(cell[:, 1], 0, dims[:, 1] - 1)

    def reset(self, slots: np.ndarray, positions: np.ndarray, worlds: Sequence[World]) -> None:
        """Start new episodes for ``slots``: robot ``slots[m]`` in ``worlds[m]`` at ``positions[m]``."""
        slots = np.asarray(slots, dtype=np.intp).reshape(-1)
        for m, slot in enumerate(slots):
            self.dims[slot] = self.cells_of(worlds[m])
        need = self.dims.max(axis=0)
        if need[0] > self.counts.shape[1] or need[1] > self.counts.shape[2]:
            grown = np.zeros((self.num, max(need[0], self.counts.shape[1]), max(need[1], self.counts.shape[2])),
                             dtype=np.int32)
            grown[:, :self.counts.shape[1], :self.counts.shape[2]] = self.counts
            self.counts = grown
        self.counts[slots] = 0
        self.visit(positions, slots)

    def visit(self, positions: np.ndarray, slots: np.ndarray | None = None) -> None:
        """Count the cell each robot is in (``slots``: which robots ``positions`` are; default all)."""
        slots = np.arange(self.num) if slots is None else np.asarray(slots, dtype=np.intp).reshape(-1)
        c, r = self._cell(positions, slots)
        self.counts[slots, c, r] += 1

    def count(self, positions: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        """(N,) visits so far of the cell each robot is in, at most ``cap`` (robots ``slots``, default all)."""
        slots = np.arange(self.num) if slots is None else np.asarray(slots, dtype=np.intp).reshape(-1)
        c, r = self._cell(positions, slots)
        return np.minimum(self.counts[slots, c, r], self.cap)

    def window(self, positions: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        """(N, k, k) float32 memory windows around ``positions`` (robots ``slots``, default all)."""
        slots = np.arange(self.num) if slots is None else np.asarray(slots, dtype=np.intp).reshape(-1)
        c0, r0 = self._cell(positions, slots)
        dims = self.dims[slots]
        c = c0[:, None, None] + self._dc[None]
        r = r0[:, None, None] + self._dr[None]
        cols, rows = dims[:, 0, None, None], dims[:, 1, None, None]
        outside = (c < 0) | (c >= cols) | (r < 0) | (r >= rows)
        counts = self.counts[slots[:, None, None], np.clip(c, 0, cols - 1), np.clip(r, 0, rows - 1)]
        values = np.minimum(counts, self.cap).astype(np.float32) / np.float32(self.cap)
        values[outside] = 1.0
        return values
