"""What a robot sees (Model §2): windows of the potential around it, and optionally its memory.

One :class:`Observer` builds every observation in the project: the environments'
(``Navigate-v0``, its vector version, ``Formation-v0``) and the DQN planner's, from one
:class:`ObserverConfig` that is saved in every model file, so a network always gets what it
was trained on.

Channel ``"potential"``: window point ``[i, j]`` of a robot at ``(x, y)`` is
``(x + (j − k//2), y + (k//2 − i))`` (row 0 is the top, the highest y, as in an image); its
value is U there, sampled bilinearly from a padded raster of U built once per world, where
nodes inside an obstacle or outside the map read ``world.u_wall`` (the map's highest
potential), so blocked points always look impassable. All robots' windows, in any mix of
worlds, are one :class:`~apf_physics.world.field.Atlas` lookup.

Moving obstacles: the raster holds the static part of U; the terms of the moving obstacles
are added, at the step asked for, only at the window points within ``p0`` of where each of
them is, and points inside one read ``u_wall``. Channel ``"previous"``: the same window at
the step before (where the moving obstacles were), so that a policy can tell where they go.

Channel ``"memory"``: the robot's visits to the 1×1 cells of its map at the same points,
``min(n, cap) / cap`` (:class:`VisitMemory`); points outside the map read 1.

Other kinds of observation: the range sensor (:mod:`apf_physics.sensing.ranges`), the map
network's view of the whole map (:mod:`apf_physics.sensing.mapview`); every kind behind one
interface: :mod:`apf_physics.sensing.kinds`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from apf_physics.world import field as apf
from apf_physics.common.compiled import kernel
from apf_physics.world.field import Atlas, Grid, Raster, repulsive_term_at
from apf_physics.common.transforms import signed_log
from apf_physics.world.core import World
from apf_physics.world.freespace import RASTER_CHUNK

CHANNELS = ("potential", "previous", "memory")
"""Channels an observer can build, in the order they are stacked."""
SCALES = ("raw", "log")
"""Values of :attr:`ObserverConfig.scale`."""


@dataclass(frozen=True)
class ObserverConfig:
    """How observations are built (saved with every model).

    Attributes:
        size: Window side ``k`` (odd) [points, spacing 1 world unit].
        resolution: Raster nodes per world unit the potential is sampled from.
        channels: Which channels, from :data:`CHANNELS`, in that order.
        memory_cap: Visits at which a memory cell reads 1.
        scale: ``"raw"``: the potential as it is (unbounded; the package's networks transform
            it themselves); ``"log"``: ``sign(d)·log(1 + |d|) / log(1 + D)`` with
            ``d = U − U(robot)`` and ``D`` the world's range of U (``u_wall − min U``), in
            ``[-1, 1]``: bounded, 0 at the robot, uphill positive, walls near 1.
    """

    size: int = 11
    resolution: int = 4
    channels: tuple[str, ...] = ("potential",)
    memory_cap: int = 4
    scale: str = "raw"

    def __post_init__(self):
        if self.size < 1 or self.size % 2 == 0:
            raise ValueError(f"observation size must be odd and positive, got {self.size}")
        if self.resolution < 1:
            raise ValueError(f"observation resolution must be positive, got {self.resolution}")
        if not self.channels or len(set(self.channels)) != len(self.channels) or \
                any(c not in CHANNELS for c in self.channels) or self.channels[0] != "potential":
            raise ValueError(f"observation channels must start with 'potential' and be among {CHANNELS}, "
                             f"got {self.channels}")
        if self.memory_cap < 1:
            raise ValueError(f"memory_cap must be positive, got {self.memory_cap}")
        if self.scale not in SCALES:
            raise ValueError(f"observation scale must be one of {SCALES}, got {self.scale!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(C, k, k)``."""
        return (len(self.channels), self.size, self.size)

    @property
    def memory(self) -> bool:
        return "memory" in self.channels

    @property
    def bounds(self) -> tuple[float, float]:
        """Lowest and highest value of any observation element, whatever the world (infinite for the
        raw potential; :meth:`Observer.value_bounds` gives the finite ones of an observer's worlds)."""
        return (-1.0, 1.0) if self.scale == "log" else (-np.inf, np.inf)

    @classmethod
    def of(cls, size: int = 11, resolution: int = 4, previous: bool = False, memory: bool = False,
           memory_cap: int = 4, scale: str = "raw") -> "ObserverConfig":
        """The configuration with the potential and the optional channels asked for, stacked in
        :data:`CHANNELS`' order (the one place that order is decided)."""
        wanted = {"potential": True, "previous": previous, "memory": memory}
        return cls(size=int(size), resolution=int(resolution), channels=tuple(c for c in CHANNELS if wanted[c]),
                   memory_cap=int(memory_cap), scale=scale)

    def to_dict(self) -> dict[str, Any]:
        return {"size": self.size, "resolution": self.resolution, "channels": list(self.channels),
                "memory_cap": self.memory_cap, "scale": self.scale}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ObserverConfig":
        return cls(size=int(data["size"]), resolution=int(data["resolution"]), channels=tuple(data["channels"]),
                   memory_cap=int(data.get("memory_cap", 4)), scale=str(data.get("scale", "raw")))


def observation_raster(world: World, margin: int, resolution: int) -> Raster:
    """U of the static obstacles over the map plus ``margin`` units on every side, blocked nodes set to ``world.u_wall``.

    Built once per world and cached.
    """
    def build() -> Raster:
        grid = Grid.covering((-margin, -margin), (world.size[0] + margin, world.size[1] + margin), resolution)

        def values_at(nodes: np.ndarray) -> np.ndarray:
            values = apf.potential(nodes, world.targets, world.shapes, world.field, world.robot_radius)
            blocked = (world.edge_distance(nodes) < 0) | (world.obstacle_distance(nodes, static=True) <= 0)
            values[blocked] = world.u_wall
            return values
        return Raster(grid, grid.map_nodes(values_at, RASTER_CHUNK))
    return world.cached(("observation", int(margin), int(resolution)), build)


class Repellers:
    """M shapes whose repulsive terms :meth:`Observer._add_near` adds to windows: a world's moving
    obstacles where they are written (their offsets apart), or other robots' discs.

    Attributes:
        shapes: The shapes (None for a disc given by its centre and radius alone).
        lo, hi: (M, 2) their bounding boxes.
        centre, radius: (M, 2), (M,) the discs; NaN for polygons, measured by
            ``shapes[s].signed_distance``.
        polygon: (M,) bool, which are polygons; polygons: whether any is.
    """

    def __init__(self, shapes: list, lo: np.ndarray, hi: np.ndarray, centre: np.ndarray, radius: np.ndarray):
        self.shapes = shapes
        self.lo, self.hi, self.centre, self.radius = lo, hi, centre, radius
        self.polygon = np.isnan(radius)
        self.polygons = bool(self.polygon.any())


def moving_repellers(world: World) -> Repellers:
    """The moving obstacles of ``world`` (in :attr:`World.moving` order) as :class:`Repellers`; cached."""
    def build() -> Repellers:
        shapes = [world.obstacles[i] for i in world.moving]
        boxes = [s.bounds for s in shapes]
        lo = np.array([lo for lo, _ in boxes], float).reshape(-1, 2)
        hi = np.array([hi for _, hi in boxes], float).reshape(-1, 2)
        centre = np.array([getattr(s, "center", (np.nan, np.nan)) for s in shapes], float).reshape(-1, 2)
        radius = np.array([getattr(s, "radius", np.nan) for s in shapes], float)
        return Repellers(shapes, lo, hi, centre, radius)
    return world.cached("moving_repellers", build)


class Observer:
    """Builds observations for ``num`` robots, each in a world of its own.

    Args:
        config: What to build.
        num: Number of robots observed.
        worlds: Worlds the robots may be in (more can be added with :meth:`add_world`).
        track_visits: Keep the robots' visit counts even without a memory channel (for a
            reward that charges revisits); they are always kept with one.

    Use: :meth:`reset` when robots start an episode, :meth:`visit` after every step that
    moves them (the memory counts the cells they are in; it returns how often each had been
    visited before), :meth:`observe` for their observations.
    """

    def __init__(self, config: ObserverConfig, num: int, worlds: Sequence[World] = (), track_visits: bool = False):
        self.config = config
        self.num = int(num)
        self.margin = config.size // 2 + 2
        self._atlas = Atlas(config.resolution)
        self._world_ids: dict[int, int] = {}
        self.worlds: list[World] = []
        self._log_range = np.zeros(0)
        self._range = (np.inf, -np.inf)      # least and highest U of the registered worlds' rasters
        self._moving = False
        self._movers: list[Repellers | None] = []   # each registered world's moving obstacles (None: none)
        self._everyone = np.arange(self.num)
        half = config.size // 2
        steps = np.arange(config.size, dtype=float) - half
        # window point [i, j] is (x + j − k//2, y + k//2 − i)
        self._offsets = np.column_stack([np.tile(steps, config.size), np.repeat(-steps, config.size)])
        self.world_of = np.zeros(self.num, np.intp)
        self.memory = VisitMemory(self.num, config.size, config.memory_cap) if config.memory or track_visits else None
        for world in worlds:
            self.add_world(world)

    def add_world(self, world: World) -> int:
        """Register a world (once) and return its index."""
        key = id(world)
        if key not in self._world_ids:
            raster = observation_raster(world, self.margin, self.config.resolution)
            self._world_ids[key] = self._atlas.add(raster)
            self.worlds.append(world)
            self._moving = self._moving or bool(world.moving)
            self._movers.append(moving_repellers(world) if world.moving else None)
            self._log_range = np.append(self._log_range, np.log1p(world.u_wall - raster.values.min()))
            self._range = (min(self._range[0], float(raster.values.min())), max(self._range[1], float(world.u_wall)))
        return self._world_ids[key]

    def value_bounds(self) -> tuple[float, float]:
        """Lowest and highest value any observation element can take in the registered worlds.

        ``"log"``: ``[-1, 1]``. ``"raw"``: from the least U of the worlds' rasters (the deepest
        black-hole well) to the highest ``u_wall`` (what blocked points read; moving obstacles'
        and other robots' repulsion is capped there), widened by a part in a million against
        rounding; a memory channel's ``[0, 1]`` is included. Finite, so a Gymnasium ``Box`` of
        them is bounded.
        """
        if self.config.scale == "log" or not self.worlds:
            return -1.0, 1.0
        low, high = self._range
        if "memory" in self.config.channels:
            low, high = min(low, 0.0), max(high, 1.0)
        pad = 1e-6 * max(abs(low), abs(high), 1.0)
        return low - pad, high + pad

    def reset(self, robots: np.ndarray, positions: np.ndarray, worlds: Sequence[World]) -> None:
        """Start episodes: robot ``robots[n]`` in ``worlds[n]`` at ``positions[n]``; memories cleared."""
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        self.world_of[robots] = [self.add_world(w) for w in worlds]
        if self.memory is not None:
            self.memory.reset(robots, positions, worlds)

    def visit(self, positions: np.ndarray, robots: np.ndarray | None = None) -> np.ndarray:
        """Count the cells ``robots`` (default all) are in; returns each cell's visits before this one (at most the cap)."""
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        if self.memory is None:
            return np.zeros(len(robots), np.int32)
        before = self.memory.count(positions, robots)
        self.memory.visit(positions, robots)
        return before

    def potential_at(self, positions: np.ndarray, robots: np.ndarray | None = None,
                     t: np.ndarray | float = 0.0, discs: np.ndarray | None = None) -> np.ndarray:
        """(n,) U at ``positions`` of ``robots`` (default all) at step ``t``, as the windows read it."""
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        positions = np.asarray(positions, float).reshape(-1, 2)
        u = self._atlas.sample(positions, self.world_of[robots]).astype(float)
        return self._add_moving(u[:, None], positions, robots, t, np.zeros((1, 2)), discs)[:, 0]

    def potential_windows(self, positions: np.ndarray, robots: np.ndarray | None = None,
                          t: np.ndarray | float = 0.0, centre: np.ndarray | None = None,
                          discs: np.ndarray | None = None) -> np.ndarray:
        """(n, k, k) float32 windows of U at step ``t`` around ``positions`` of ``robots`` (default all).

        ``centre``: with ``scale="log"``, the U the window is taken relative to (default its own centre).
        """
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        positions = np.asarray(positions, float).reshape(-1, 2)
        k = self.config.size
        windows = self._atlas.sample(positions, self.world_of[robots], self._offsets)
        windows = self._add_moving(windows, positions, robots, t, self._offsets, discs).reshape(-1, k, k)
        if self.config.scale == "log":
            middle = windows[:, k // 2, k // 2, None, None] if centre is None else centre[:, None, None]
            d = windows - middle
            windows = signed_log(d) / self._log_range[self.world_of[robots], None, None].astype(np.float32)
        return windows

    def _add_moving(self, values: np.ndarray, positions: np.ndarray, robots: np.ndarray, t: np.ndarray | float,
                    offsets: np.ndarray, discs: np.ndarray | None = None) -> np.ndarray:
        """Add the moving obstacles' terms at step ``t`` (and those of ``discs``, other robots) to
        ``values`` (n, Q) sampled at ``positions + offsets``.

        ``offsets`` is the window's lattice (``self._offsets``) or one point (``[[0, 0]]``). Only
        the window points within ``p0`` of an obstacle's box are measured (a few points of the
        k²), for all robots and obstacles of a world at once. The obstacles' offsets at whole
        steps are read from the world's motion table where they are (no per-robot copy).
        """
        crowd = discs is not None and len(discs) > 0
        if not self._moving and not crowd:
            return values
        lattice = len(offsets) > 1
        when = np.asarray(t, float)
        if when.ndim == 0:
            when = np.full(len(robots), float(when))
        # the robots of each world: their rows in values, positions and steps
        if len(self.worlds) == 1:
            groups = [(0, np.arange(len(robots)), positions, when)]
        else:
            worlds = self.world_of[robots]
            groups = []
            for w in np.unique(worlds).tolist():
                mine = np.flatnonzero(worlds == w)
                groups.append((w, mine, positions[mine], when[mine]))
        for w, mine, where, at in groups:
            world = self.worlds[w]
            movers = self._movers[w]
            if movers is not None:
                table, steps = world.motion_table(at)                     # (T, M, 2), (m,)
                self._add_near(values, mine, where, table, steps, movers, world, lattice)
            if crowd:   # other robots: discs of the robot radius where they are (in the world's frame)
                centre = np.asarray(discs, float).reshape(-1, 2)
                r = np.full(len(centre), world.robot_radius)
                still = np.zeros((1, len(centre), 2))                    # they do not move: offsets 0
                self._add_near(values, mine, where, still, np.zeros(len(mine), np.intp),
                               Repellers([None] * len(centre), centre - r[:, None], centre + r[:, None], centre, r),
                               world, lattice)
        return values

    def _add_near(self, values: np.ndarray, mine: np.ndarray, where: np.ndarray, table: np.ndarray,
                  steps: np.ndarray, near: Repellers, world: World, lattice: bool) -> None:
        """Add, in place, the repulsive terms of M shapes ``near`` to the windows of robots ``mine``.

        ``where`` (m, 2): the robots; ``table`` (T, M, 2), ``steps`` (m,): robot ``r`` is at
        ``where[r] − table[steps[r], s]`` in shape ``s``'s frame (the shapes' offsets: a world's
        motion table, or zeros). One compiled loop (:func:`_add_terms`), where numpy's fixed cost
        per call was most of the cost; the polygons' distances alone are numpy's, at the points
        :func:`_polygon_points` lists.
        """
        field = world.field
        half = self.config.size // 2 if lattice else 0   # one point (potential_at): a 1×1 window
        polygon_d = _NO_POINTS
        if near.polygons:
            shape, px, py = _polygon_points(where, table, steps, near.lo, near.hi, max(field.p0, world.robot_radius),
                                            half, near.polygon)
            polygon_d = np.empty(len(shape))
            for index in np.unique(shape).tolist():
                chosen = shape == index
                polygon_d[chosen], _ = near.shapes[index].signed_distance(np.stack([px[chosen], py[chosen]], -1))
        _add_terms(values, mine, where, table, steps, near.lo, near.hi, near.centre, near.radius, polygon_d,
                   field.krep, field.p0, field.u_max, world.u_wall, half, world.robot_radius)

    def observe(self, positions: np.ndarray, robots: np.ndarray | None = None,
                t: np.ndarray | float = 0.0, discs: np.ndarray | None = None) -> np.ndarray:
        """(n, C, k, k) float32 observations of ``robots`` (default all) at ``positions``, at step ``t``.

        ``discs``: (K, 2) centres of other robots (of other formations), seen as discs of the
        robot radius that repel like obstacles (the same for every robot observed).
        """
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        windows = self.potential_windows(positions, robots, t, discs=discs)
        channels = self.config.channels
        if len(channels) == 1:   # the window alone (a new array): no copy
            return windows[:, None]
        out = np.empty((len(robots), *self.config.shape), np.float32)
        out[:, 0] = windows
        if "previous" in channels:
            centre = self.potential_at(positions, robots, t, discs) if self.config.scale == "log" else None
            out[:, channels.index("previous")] = self.potential_windows(positions, robots, np.asarray(t) - 1.0, centre,
                                                                        discs)
        if self.config.memory:
            out[:, channels.index("memory")] = self.memory.window(positions, robots)
        return out


_NO_POINTS = np.zeros(0)   # the polygons' distances where there are none


@kernel
def _window_span(x, lo, hi, p0, half):
    """The whole offsets ``dx`` in ``[-half, half]`` that put ``x + dx`` within ``p0`` of
    ``[lo, hi]``: ``(first, last)``, none when ``first > last`` (one axis of a window)."""
    first = int(min(max(np.ceil(lo - p0 - x), -half), half + 1))
    last = int(min(max(np.floor(hi + p0 - x), -half - 1), half))
    return first, last


@kernel
def _near_window(where, table, steps, lo, hi, p0, half, r, s):
    """Robot ``r`` in shape ``s``'s frame, ``(x, y) = where[r] − table[steps[r], s]``, and the
    window offsets near the shape's box: ``(x, y, x0, x1, y0, y1)`` (:func:`_window_span` of each axis)."""
    x, y = where[r, 0] - table[steps[r], s, 0], where[r, 1] - table[steps[r], s, 1]
    x0, x1 = _window_span(x, lo[s, 0], hi[s, 0], p0, half)
    y0, y1 = _window_span(y, lo[s, 1], hi[s, 1], p0, half)
    return x, y, x0, x1, y0, y1


@kernel
def _polygon_points(where, table, steps, lo, hi, p0, half, polygon):
    """The window points near the shapes ``s`` with ``polygon[s]``, in the order :func:`_add_terms`
    meets them: ``(shape, x, y)``, each point's shape and where it is in that shape's frame
    (robot ``r`` at ``where[r] − table[steps[r], s]``, as there)."""
    count = 0
    for r in range(where.shape[0]):
        for s in range(table.shape[1]):
            if polygon[s]:
                _, _, x0, x1, y0, y1 = _near_window(where, table, steps, lo, hi, p0, half, r, s)
                count += max(x1 - x0 + 1, 0) * max(y1 - y0 + 1, 0)
    shape = np.empty(count, np.intp)
    px = np.empty(count)
    py = np.empty(count)
    i = 0
    for r in range(where.shape[0]):
        for s in range(table.shape[1]):
            if polygon[s]:
                x, y, x0, x1, y0, y1 = _near_window(where, table, steps, lo, hi, p0, half, r, s)
                for dx in range(x0, x1 + 1):
                    for dy in range(y0, y1 + 1):
                        shape[i], px[i], py[i] = s, x + dx, y + dy
                        i += 1
    return shape, px, py


@kernel
def _add_terms(values, rows, where, table, steps, lo, hi, centre, radius, polygon_d, krep, p0, u_max, u_wall, half,
               surface):
    """Add to each robot's window the repulsive terms of the shapes near it.

    Robot ``r``'s window is ``values[rows[r]]`` (``k²`` points, ``k = 2·half + 1``); it is at
    ``(x, y) = where[r] − table[steps[r], s]`` in shape ``s``'s frame (the shape moved by that
    offset), so its window point ``[half − dy, half + dx]`` is at ``(x + dx, y + dy)``. The
    points within ``max(p0, surface)`` of the shape's box ``[lo[s], hi[s]]`` are measured: their signed
    distance ``d`` to the disc ``centre[s]``, ``radius[s]``, or, for a polygon (NaN radius), the
    next of ``polygon_d`` (its points in the order met here: robots, shapes, ``dx``, ``dy``, as
    :func:`_polygon_points` lists them). A window point's terms (:func:`~apf_physics.world.field.repulsive_term_at`;
    the cap where a robot of radius ``surface`` there touches the shape) are
    summed in shape order, from 0, then added to its value, which stays at most ``u_wall``; a
    point inside a shape reads ``u_wall``. A disc's ``d`` is not measured where the squared
    distance from its centre settles the term (surely beyond ``p0``: 0; surely inside: ``u_max``).
    """
    k = 2 * half + 1
    reach = max(p0, surface)            # terms reach p0, and the cap where the robot touches
    added = np.empty(k * k)             # one robot's sums, by window point (where marked)
    mark = np.zeros(k * k, np.int8)     # 0: no shape near, 1: near, 2: inside one
    touched = np.empty(k * k, np.intp)  # the points near, in the order first met
    j = 0                               # the next polygon point
    for r in range(where.shape[0]):
        count = 0
        step = steps[r]
        for s in range(table.shape[1]):
            x = where[r, 0] - table[step, s, 0]
            x0, x1 = _window_span(x, lo[s, 0], hi[s, 0], reach, half)
            if x0 > x1:                 # no column of the window near it (most shapes)
                continue
            y = where[r, 1] - table[step, s, 1]
            y0, y1 = _window_span(y, lo[s, 1], hi[s, 1], reach, half)
            polygon = np.isnan(radius[s])
            # squared distances from the disc's centre beyond which a point is surely more than
            # p0 from its rim, and within which surely inside it (margins of 1e-9, a million
            # times the rounding of either side): there the term is 0, or u_max, whatever d is
            beyond = (radius[s] + reach) ** 2 * (1.0 + 1e-9)
            within = radius[s] ** 2 * (1.0 - 1e-9)
            for dx in range(x0, x1 + 1):
                for dy in range(y0, y1 + 1):
                    if polygon:
                        d = polygon_d[j]
                        j += 1
                    else:
                        ex, ey = x + dx - centre[s, 0], y + dy - centre[s, 1]
                        q = ex * ex + ey * ey
                        if (q > beyond) | (q < within):   # no hypot (half the loop's time): d only picks the term
                            d = -1.0 if q < within else reach + 1.0
                        else:
                            d = np.hypot(ex, ey) - radius[s]
                    c = (half - dy) * k + (half + dx)
                    term = repulsive_term_at(0.0 if d <= surface else d, krep, p0, u_max)
                    if mark[c] == 0:    # the first term here: 0 + term is term
                        added[c] = term
                        mark[c] = 1
                        touched[count] = c
                        count += 1
                    else:
                        added[c] += term
                    if d <= 0.0:
                        mark[c] = 2
        row = rows[r]
        for i in range(count):
            c = touched[i]
            values[row, c] = u_wall if mark[c] == 2 else min(values[row, c] + added[c], u_wall)
            mark[c] = 0


class VisitMemory:
    """Per-robot visit counts over the 1×1 cells of each robot's world: the memory channel.

    Cell ``(c, r)`` of a world covers ``[c, c + 1) × [r, r + 1)`` of its map. :meth:`reset`
    clears a robot's counts and counts its start cell; :meth:`visit` counts the cells the
    robots are in (call it after every step). :meth:`window` reads the counts at the same
    points as the potential window (point ``[i, j]`` is ``(x + j − k//2, y + k//2 − i)``) as
    ``min(count, cap) / cap``; points outside the map read 1, like a cell visited often.

    Args:
        num: Number of robots.
        size: Window side ``k`` (odd).
        cap: Count at which a cell reads 1.
    """

    def __init__(self, num: int, size: int = 11, cap: int = 4):
        self.num = int(num)
        self.size = int(size)
        self.cap = int(cap)
        self._everyone = np.arange(self.num)
        self.dims = np.ones((self.num, 2), dtype=np.intp)          # cells per robot's map: (columns, rows)
        self.counts = np.zeros((self.num, 1, 1), dtype=np.int32)   # (N, columns, rows), grown as needed

    @staticmethod
    def cells_of(world: World) -> tuple[int, int]:
        """(columns, rows) of 1×1 cells covering a world's map."""
        return max(1, int(np.ceil(world.size[0]))), max(1, int(np.ceil(world.size[1])))

    def _cell(self, positions: np.ndarray, robots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cell = np.floor(np.asarray(positions, dtype=float).reshape(-1, 2)).astype(np.intp)
        dims = self.dims[robots]
        return np.clip(cell[:, 0], 0, dims[:, 0] - 1), np.clip(cell[:, 1], 0, dims[:, 1] - 1)

    def reset(self, robots: np.ndarray, positions: np.ndarray, worlds: Sequence[World]) -> None:
        """Start new episodes for ``robots``: robot ``robots[n]`` in ``worlds[n]`` at ``positions[n]``."""
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        for n, robot in enumerate(robots):
            self.dims[robot] = self.cells_of(worlds[n])
        need = self.dims.max(axis=0)
        if need[0] > self.counts.shape[1] or need[1] > self.counts.shape[2]:
            grown = np.zeros((self.num, max(need[0], self.counts.shape[1]), max(need[1], self.counts.shape[2])),
                             dtype=np.int32)
            grown[:, :self.counts.shape[1], :self.counts.shape[2]] = self.counts
            self.counts = grown
        self.counts[robots] = 0
        self.visit(positions, robots)

    def visit(self, positions: np.ndarray, robots: np.ndarray | None = None) -> None:
        """Count the cell each robot is in (``robots``: which robots ``positions`` are; default all)."""
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        c, r = self._cell(positions, robots)
        self.counts[robots, c, r] += 1

    def count(self, positions: np.ndarray, robots: np.ndarray | None = None) -> np.ndarray:
        """(N,) visits so far of the cell each robot is in, at most ``cap`` (robots ``robots``, default all)."""
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        c, r = self._cell(positions, robots)
        return np.minimum(self.counts[robots, c, r], self.cap)

    def window(self, positions: np.ndarray, robots: np.ndarray | None = None) -> np.ndarray:
        """(N, k, k) float32 memory windows around ``positions`` (robots ``robots``, default all)."""
        robots = self._everyone if robots is None else np.asarray(robots, dtype=np.intp).reshape(-1)
        c0, r0 = self._cell(positions, robots)
        return _memory_windows(self.counts, robots, c0, r0, self.dims, self.size // 2, self.cap)


@kernel
def _memory_windows(counts, robots, c0, r0, dims, half, cap):
    """(n, k, k) float32 windows of visit counts, ``k = 2·half + 1``: point ``[i, j]`` of robot
    ``robots[n]`` (in cell ``(c0[n], r0[n])``) reads its cell ``(c0[n] + j − half, r0[n] + half − i)``
    as ``min(count, cap) / cap``, or 1 outside its map (``dims[robot]`` cells: columns, rows)."""
    k = 2 * half + 1
    out = np.empty((len(robots), k, k), np.float32)
    for n in range(len(robots)):
        robot = robots[n]
        for i in range(k):
            for j in range(k):
                c, r = c0[n] + j - half, r0[n] + half - i
                if 0 <= c < dims[robot, 0] and 0 <= r < dims[robot, 1]:
                    out[n, i, j] = np.float32(min(counts[robot, c, r], cap)) / np.float32(cap)
                else:
                    out[n, i, j] = 1.0
    return out
