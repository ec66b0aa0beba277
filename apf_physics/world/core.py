"""Worlds: the rectangular map, its obstacles, targets and starts, and the field's parameters.

A :class:`World` is an immutable, validated description; build one from a world file
with :func:`apf_physics.world.io.worldfile.load_world` or from a mapping with
:func:`apf_physics.world.io.worldfile.world_from_dict`. It answers the questions every layer above
asks of the map: the potential and its gradient at points (Model §1), clearance from
obstacles and the map's edge, free positions, and a cache of what is derived from it
(rasters, free cells, search grids) through :meth:`World.cached`.

With moving obstacles the field and the clearance depend on the control step: a
:class:`Moment`, made by :meth:`World.at`, is the world at one step. It places the moving
obstacles once and answers every query of that step (potential, gradient, clearance, the
clearance along moves, the obstacles where they are) while sharing what is static with its
world. Callers build one per control step and hand it down (the rollout to its planner, the
planner to :func:`~apf_physics.control.shield.move_clearance`); the world's own ``potential(points,
t)`` and the like are one-line conveniences over ``world.at(t)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Hashable, TypeVar

import numpy as np

from apf_physics.world import field as apf
from apf_physics.common import geometry
from apf_physics.common.compiled import kernel
from apf_physics.world.field import FieldParams
from apf_physics.world.freespace import RASTER_CHUNK, FreeSpace
from apf_physics.world.kinematics import UnicycleLimits
from apf_physics.world.obstacles import CircleObstacle, Obstacle
from apf_physics.world.spatial import ShapeSet

T = TypeVar("T")

CLEARANCE_REACH = 2.5
"""Clearance is measured exactly up to this much beyond a robot's radius (the map network's
clearance feature saturates at 2 beyond the radius)."""
MOVE_REACH = 1.5
"""Clearance along moves (:meth:`World.path_clearance`) is exact up to this much beyond a robot's
radius: every test of a move asks about less (the shield's room saturates at 1 beyond its margin)."""
MOMENTS_KEPT = 8
"""Moments a world keeps (:meth:`World.at`): the steps of the slots of a batch in one world, at most."""
MOTION_TABLE_STEPS = 1 << 16
"""Whole steps up to this are read from a world's table of its moving obstacles' offsets
(:meth:`World.motion_table`); later ones are computed, so that a far step never builds a table
the size of its number."""


@dataclass(frozen=True)
class Frame:
    """How a world file's coordinates become the world's (docs/real-maps.md: units).

    The world is laid out in **steps**: one unit is the robot's travel per control step, and
    the map's lower-left corner is the origin. A world file in metres with ``robot: {step:
    0.25}`` and a ROS map whose origin is ``[-10, -5]`` read ``(x_file − offset) / unit``.

    Attributes:
        offset: File coordinates of the world's origin.
        unit: File units per step.
        name: The file's unit of length (``units:``; ``m`` for a ROS map), or ``""`` when it names none.
    """

    offset: tuple[float, float] = (0.0, 0.0)
    unit: float = 1.0
    name: str = ""

    def to_file(self, points: np.ndarray) -> np.ndarray:
        """Points in the world file's coordinates."""
        return np.asarray(points, float) * self.unit + np.asarray(self.offset, float)

    def field_to_file(self, params: FieldParams) -> dict[str, float]:
        """The field's parameters in file units (U keeps its values at corresponding points)."""
        u = self.unit
        return {"katt": params.katt / u**2, "krep": params.krep * u**2, "kstr": params.kstr / u**2,
                "p0": params.p0 * u, "ps": params.ps * u, "u_max": params.u_max}

    def field_from_file(self, values: dict[str, float]) -> dict[str, float]:
        """The inverse of :meth:`field_to_file`."""
        u = self.unit
        return {"katt": values["katt"] * u**2, "krep": values["krep"] / u**2, "kstr": values["kstr"] * u**2,
                "p0": values["p0"] / u, "ps": values["ps"] / u, "u_max": values["u_max"]}


@dataclass(frozen=True)
class FormationSpec:
    """A leader and followers in a chain (Model §3).

    Attributes:
        followers: Number of followers.
        comm_range: Communication range: each follower must stay this close to the robot it follows [units].
        spacing: Preferred distance between consecutive robots [units].
        shape: ``"line"`` (each follows the previous robot), ``"wedge"``, or ``"offsets"``.
        offsets: For ``shape: offsets``: per follower ``[back, left]`` relative to the leader's heading.
    """

    followers: int = 2
    comm_range: float = 3.0
    spacing: float = 1.0
    shape: str = "line"
    offsets: tuple[tuple[float, float], ...] = ()

    @property
    def followed(self) -> list[int]:
        """For each follower, the robot it follows (0 is the leader): the previous one in a line, else the leader."""
        return list(range(self.followers)) if self.shape == "line" else [0] * self.followers

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"followers": self.followers, "comm_range": self.comm_range,
                                "spacing": self.spacing, "shape": self.shape}
        if self.offsets:
            data["offsets"] = [list(o) for o in self.offsets]
        return data


@dataclass(frozen=True, eq=False)
class FormationTask:
    """One of several formations of a world, each with its own start and target (a world file's ``formations:``).

    Attributes:
        start: The leader's start.
        target: The formation's target.
        spec: Its shape, followers, spacing and communication range.
    """

    start: np.ndarray
    target: np.ndarray
    spec: FormationSpec

    def to_dict(self) -> dict[str, Any]:
        return {"start": self.start.tolist(), "target": self.target.tolist(), **self.spec.to_dict()}


@dataclass(frozen=True, eq=False)
class Fleet:
    """Robots that share one map, each with its own start and target (a world file's ``robots:``, or
    the first lines of a MovingAI scenario file).

    Attributes:
        starts: (N, 2) each robot's start.
        targets: (N, 2) each robot's target.
        labels: How messages name each robot (``robots[3]``, ``FILE.scen: line 7``).
        optimal: (N,) each robot's shortest path length alone on the map, when known (a scenario's
            octile optimum), else None.
    """

    starts: np.ndarray
    targets: np.ndarray
    labels: tuple[str, ...] = ()
    optimal: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "starts", np.asarray(self.starts, float).reshape(-1, 2))
        object.__setattr__(self, "targets", np.asarray(self.targets, float).reshape(-1, 2))
        if len(self.starts) != len(self.targets):
            raise ValueError(f"{len(self.starts)} starts for {len(self.targets)} targets")
        if not self.labels:
            object.__setattr__(self, "labels", tuple(f"robots[{i}]" for i in range(len(self.starts))))

    def __len__(self) -> int:
        return len(self.starts)

    def first(self, count: int) -> Fleet:
        """The first ``count`` robots."""
        optimal = None if self.optimal is None else self.optimal[:count]
        return Fleet(self.starts[:count], self.targets[:count], self.labels[:count], optimal)


@dataclass(frozen=True, eq=False)
class World(FreeSpace):
    """A validated world.

    Attributes:
        name: Short name, used in tables and file names.
        size: ``(width, height)``; the origin is the lower-left corner, y up.
        robot_radius: Radius of each robot's disc.
        goal_tolerance: A target is reached when the robot's centre is this close to it.
        field: The potential field's parameters.
        obstacles: The obstacles (those with a ``motion`` move along their route).
        targets: ``(T, 2)`` target positions (at least one).
        starts: ``(S, 2)`` evaluation start positions (may be empty).
        formation: The formation, if the world file defines one.
        source: The file the world came from, for messages.
        formations: Several formations, each to its own target (the world file's ``formations:``).
        frame: How the world file's coordinates map to the world's (its units and origin).
        others: ``(K, 2)`` centres of other robots, discs of :attr:`robot_radius` that repel and
            block like obstacles: the robots of other formations, as one leader sees them
            (:meth:`among`). Empty for a world as read from its file.
        unicycle: The robots are unicycles with these limits (``robot: {kinematics: unicycle,
            ...}``), in steps; None: holonomic, the thesis's robot.
        robots: A fleet: robots each with its own start and target, run all at once (the world
            file's ``robots:``); None for a world without one.
    """

    name: str
    size: tuple[float, float]
    robot_radius: float
    goal_tolerance: float
    field: FieldParams
    obstacles: tuple[Obstacle, ...]
    targets: np.ndarray
    starts: np.ndarray
    formation: FormationSpec | None = None
    source: str | None = None
    formations: tuple[FormationTask, ...] = ()
    others: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    frame: Frame = Frame()
    unicycle: UnicycleLimits | None = None
    robots: Fleet | None = None
    # Caches of what is built from the world (rasters, indexes). Not constructor arguments: a
    # world made by dataclasses.replace (other obstacles, targets, radius, ...) starts with its
    # own; only the views below share them, on purpose.
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _static: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _moments: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def label(self) -> str:
        """What messages call the world: its file, else its name."""
        return self.source or self.name

    def among(self, robots: np.ndarray) -> World:
        """This world with other robots at ``robots`` (K, 2) as discs in the field and in the way.

        A view: it shares this world's cache (rasters of the static field stay valid; the
        other robots' discs are added where they are, like moving obstacles).
        """
        return self._sharing(replace(self, others=np.asarray(robots, float).reshape(-1, 2)), everything=True)

    def with_task(self, targets: np.ndarray, starts: np.ndarray, name: str | None = None) -> World:
        """This world with other targets and starts, sharing what is built from its static
        obstacles alone (indexes, clearance rasters): many scenarios on one map cost one map."""
        return self._sharing(replace(self, name=name or self.name, targets=np.asarray(targets, float).reshape(-1, 2),
                                     starts=np.asarray(starts, float).reshape(-1, 2)))

    def formation_world(self, index: int) -> World:
        """The world as formation ``index`` sees it: its own target and start (and formation); cached."""
        def build() -> World:
            task = self.formations[index]
            return self._sharing(replace(self, name=f"{self.name}#{index}", targets=task.target.reshape(1, 2),
                                         starts=task.start.reshape(1, 2), formation=task.spec, formations=()))
        return self.cached(("formation_world", int(index)), build)

    def _sharing(self, view: World, everything: bool = False) -> World:
        """``view`` (this world with other targets, starts or robots) sharing this world's cache
        of what depends on the map alone, and with ``everything`` its whole cache."""
        object.__setattr__(view, "_static", self._static)
        if everything:
            object.__setattr__(view, "_cache", self._cache)
        return view

    def cached(self, key: Hashable, build: Callable[[], T], static: bool = False) -> T:
        """What ``build()`` returns, built once per world and key (rasters, free cells, search grids).

        A world is immutable, so anything derived from it alone can be kept with it. ``static``:
        it depends only on the map, its static obstacles and the robot's radius, and is shared
        with the worlds of other targets made by :meth:`with_task`.
        """
        cache = self._static if static else self._cache
        if key not in cache:
            cache[key] = build()
        return cache[key]

    def peek(self, key: Hashable, static: bool = False) -> Any:
        """What :meth:`cached` keeps under ``key``, or None if nothing is built yet (nothing is built)."""
        return (self._static if static else self._cache).get(key)

    def kept(self) -> list:
        """What this world keeps of its own (:meth:`cached`'s values, not those shared by :meth:`with_task`):
        for measuring what a world holds in memory."""
        return list(self._cache.values())

    @property
    def cache_size(self) -> int:
        """How many things this world keeps of its own (not counting those shared by :meth:`with_task`)."""
        return len(self._cache)

    def forget(self) -> None:
        """Drop everything built from this world (it is rebuilt when next asked for): for benchmarks
        that time a world's first use."""
        self._cache.clear()
        self._static.clear()
        self._moments.clear()

    # -- obstacles in time -----------------------------------------------------------------
    @property
    def static_obstacles(self) -> tuple[Obstacle, ...]:
        """The obstacles that do not move."""
        return self.cached("static", lambda: tuple(o for o in self.obstacles if o.motion is None), static=True)

    @property
    def static_numbers(self) -> np.ndarray:
        """Index in :attr:`obstacles` of each of :attr:`static_obstacles` (and so of :attr:`shapes`' obstacles)."""
        return self.cached("static_numbers", lambda: np.array([i for i, o in enumerate(self.obstacles)
                                                               if o.motion is None], np.intp), static=True)

    @property
    def moving(self) -> tuple[int, ...]:
        """Indices (in :attr:`obstacles`) of the obstacles that move."""
        moving = self._cache.get("moving")   # read on every observation: no closure built to ask for it
        if moving is None:
            moving = self._cache["moving"] = tuple(i for i, o in enumerate(self.obstacles) if o.motion is not None)
        return moving

    def moving_offsets(self, t: np.ndarray | float) -> np.ndarray:
        """``(..., M, 2)``: the route offset of each moving obstacle (in :attr:`moving` order) at steps ``t``.

        The rows of :meth:`motion_table` at ``t``.
        """
        t = np.asarray(t, float)
        if not self.moving:
            return np.zeros(t.shape + (0, 2))
        table, rows = self.motion_table(t.ravel())
        return table.reshape(len(table), 2 * len(self.moving)).take(rows, axis=0).reshape(t.shape + table.shape[1:])

    def motion_table(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(table, rows)``: the route offset of moving obstacle ``s`` (in :attr:`moving` order) at
        step ``t[i]`` (``t`` 1-D floats) is ``table[rows[i], s]``; ``table`` is ``(T, M, 2)`` (a
        world with moving obstacles).

        Whole steps (episodes are at whole steps) are rows of a table built once and grown as
        needed, up to :data:`MOTION_TABLE_STEPS`, so that a caller reads the offsets where they are
        instead of copying them (the observations do); if a step is fractional or beyond the
        table's reach, the offsets are computed (the same values), one row per step.
        """
        if len(t) == 1:   # one step (one robot): the rule of _table_rows on a Python float, a compiled call less
            step = float(t[0])
            last = int(step) + 1 if -1.0 <= step < MOTION_TABLE_STEPS and step == int(step) else -1
            rows = np.array([last], np.intp)
        else:
            rows, last = _table_rows(t)                         # the table starts at step -1
        if last < 0 or not len(t):
            return np.stack([self.obstacles[i].motion.offset(t) for i in self.moving], axis=-2), np.arange(len(t))
        table = self._cache.get("motion_table")
        if table is None or last >= table.shape[0]:
            length = max(256, 2 * last + 1)
            at = np.arange(length) - 1.0
            table = np.stack([self.obstacles[i].motion.offset(at) for i in self.moving], axis=1)   # (T, M, 2)
            self._cache["motion_table"] = table
        return table, rows

    def at(self, t: float = 0.0) -> Moment:
        """The world at control step ``t`` (fractional steps allowed): see :class:`Moment`.

        Cheap: a moment places its moving obstacles only when a query first needs them. The
        last few moments asked for are kept, so that callers of the conveniences below (and of
        :meth:`at`) with the step a caller already built a moment for share its placed obstacles.
        """
        key = float(t)
        moment = self._moments.get(key)
        if moment is None:
            if len(self._moments) >= MOMENTS_KEPT:
                del self._moments[next(iter(self._moments))]   # the oldest
            moment = self._moments[key] = Moment(self, key)
        return moment

    def obstacles_at(self, t: float = 0.0) -> tuple[Obstacle, ...]:
        """Every obstacle where it is at control step ``t`` (and the other robots' discs): ``at(t).obstacles``."""
        return self.at(t).obstacles

    # -- the field ---------------------------------------------------------------------
    @property
    def reach(self) -> float:
        """How far distances to obstacles are exact: the field's range ``p0``, and
        :data:`CLEARANCE_REACH` beyond the robot's radius, whichever is farther."""
        return max(self.field.p0, self.robot_radius + CLEARANCE_REACH)

    @property
    def shapes(self) -> ShapeSet:
        """The static obstacles, indexed for distance queries within :attr:`reach` (built once)."""
        return self.cached("shapes", lambda: ShapeSet(self.static_obstacles, self.reach), static=True)

    @property
    def near_shapes(self) -> ShapeSet:
        """The static obstacles indexed for the clearance of moves: exact up to :data:`MOVE_REACH`
        beyond the robot's radius, fewer candidates per point than :attr:`shapes` (built once)."""
        return self.cached("near_shapes", lambda: ShapeSet(self.static_obstacles, self.robot_radius + MOVE_REACH),
                           static=True)

    def potential(self, points: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Total potential U at ``(N, 2)`` points at control step ``t`` (Model §1): ``at(t).potential``."""
        return self.at(t).potential(points)

    def gradient(self, points: np.ndarray, t: float = 0.0) -> np.ndarray:
        """``∇U`` at ``(N, 2)`` points at control step ``t``: ``at(t).gradient``."""
        return self.at(t).gradient(points)

    def raster(self, resolution: int = 4) -> apf.Raster:
        """U at step 0 at the nodes of a grid over the map, ``resolution`` nodes per unit; built once and cached."""
        def build() -> apf.Raster:
            grid = apf.Grid.covering((0.0, 0.0), self.size, resolution)
            return apf.Raster(grid, grid.map_nodes(lambda nodes: self.potential(nodes), RASTER_CHUNK))
        return self.cached(("potential", int(resolution)), build)

    @property
    def u_wall(self) -> float:
        """The value impassable points (inside obstacles, outside the map) read in observations.

        The highest potential anywhere on the map (at the raster's resolution 4), and at
        least ``u_max`` above the lowest, so that blocked points always read as a maximum.
        """
        def build() -> float:
            kept = self._cache.get(("potential", 4))   # else U at those nodes, not kept: two numbers are needed
            values = kept.values if kept is not None else apf.Grid.covering((0.0, 0.0), self.size, 4).map_nodes(
                lambda nodes: self.potential(nodes), RASTER_CHUNK)
            return float(max(values.max(), values.min() + self.field.u_max))
        return self.cached("u_wall", build)

    def distance_to_target(self, points: np.ndarray) -> np.ndarray:
        """(N,) distance from each point to the nearest target."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        d = np.full(len(points), np.inf)
        for tx, ty in self.targets.tolist():
            d = np.minimum(d, np.hypot(points[:, 0] - tx, points[:, 1] - ty))
        return d

    def reached(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: a robot centred at each point has reached a target (within :attr:`goal_tolerance`
        of the nearest, Model §2's episode rule)."""
        return self.distance_to_target(points) <= self.goal_tolerance

    def nearest_target(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) the target nearest each point."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        d = points[:, None, :] - self.targets[None]
        return self.targets[np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)]

    # -- geometry ----------------------------------------------------------------------
    def obstacle_distance(self, points: np.ndarray, t: np.ndarray | float = 0.0, static: bool = False,
                          near: bool = False) -> np.ndarray:
        """Signed distance to the nearest obstacle's boundary (negative inside); +inf without obstacles.

        Exact up to :attr:`reach`; a point farther from every static obstacle reads :attr:`reach`
        (:class:`~apf_physics.world.spatial.ShapeSet`). For one step, ``at(t).obstacle_distance``.

        Args:
            points: (N, 2) points.
            t: Control step at which moving obstacles are taken: one for all points, or (N,).
            static: Leave the moving obstacles out.
            near: Exact only up to :data:`MOVE_REACH` beyond the robot's radius (:attr:`near_shapes`), for
                the clearance of moves.
        """
        if static:
            points = np.asarray(points, dtype=float).reshape(-1, 2)
            return (self.near_shapes if near else self.shapes).distance(points)
        if np.ndim(t) == 0:
            return self.at(float(t)).obstacle_distance(points, near=near)
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        offsets = [self.obstacles[i].motion.offset(t) for i in self.moving]
        return _with_moving(self, points, (self.near_shapes if near else self.shapes).distance(points), offsets)

    def edge_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the map's edge (negative outside)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        w, h = self.size
        return np.minimum.reduce([points[:, 0], w - points[:, 0], points[:, 1], h - points[:, 1]])

    def clearance(self, points: np.ndarray, t: np.ndarray | float = 0.0, near: bool = False) -> np.ndarray:
        """Distance from each point to the nearest obstacle (at step ``t``, one for all points or (N,)) or
        the map's edge (negative when blocked). For one step, ``at(t).clearance``.

        ``near``: exact only up to :data:`MOVE_REACH` beyond the robot's radius (see :meth:`obstacle_distance`).
        """
        return np.minimum(self.obstacle_distance(points, t, near=near), self.edge_distance(points))

    def path_clearance(self, a: np.ndarray, b: np.ndarray, spacing: np.ndarray | float,
                       t: float | None = None, during: bool = True) -> np.ndarray:
        """Least clearance sampled along each straight segment ``a[i] → b[i]``.

        ``t`` None: the static obstacles only (:meth:`static_path_clearance`); a step:
        ``at(t).path_clearance(a, b, spacing, during)`` (:meth:`Moment.path_clearance`).
        """
        if t is None:
            return self.static_path_clearance(a, b, spacing)
        return self.at(t).path_clearance(a, b, spacing, during)

    def static_path_clearance(self, a: np.ndarray, b: np.ndarray, spacing: np.ndarray | float) -> np.ndarray:
        """Least clearance from the static obstacles and the map's edge sampled along each straight
        segment ``a[i] → b[i]``.

        Samples are at most ``spacing`` apart, ends included (:func:`~apf_physics.common.geometry.segment_samples`).
        Exact up to :data:`MOVE_REACH` beyond the robot's radius; more clearance reads as that.
        Clearance changes no faster than distance, so no point of a segment is nearer to a
        static obstacle than the returned value minus ``spacing / 2``: subtract that for a bound.

        Args:
            a: (K, 2) segment starts.
            b: (K, 2) segment ends.
            spacing: Scalar or (K,) largest distance between samples (> 0).

        Returns:
            (K,) sampled minimum clearance of each segment.
        """
        a = np.asarray(a, float).reshape(-1, 2)
        points, owner = geometry.segment_samples(a, b, spacing)
        return _least_per_segment(len(a), owner, self.static_clearance(points, near=True))

    def static_clearance(self, points: np.ndarray, near: bool = False) -> np.ndarray:
        """Distance from each point to the nearest static obstacle or the map's edge (negative when blocked).

        ``near``: exact only up to :data:`MOVE_REACH` beyond the robot's radius (see :meth:`obstacle_distance`).
        """
        return np.minimum(self.obstacle_distance(points, static=True, near=near), self.edge_distance(points))


class Moment:
    """A world at one control step: the queries of Model §1's ``U(·, t)`` and the clearance at ``t``.

    Made by :meth:`World.at`. The moving obstacles are placed at step :attr:`t` once (their
    route offsets, the moved shapes, and their index for the field, each when a query first
    needs it), and every query of the step uses them; what is static is the world's own,
    built once per world and shared by all its moments (:attr:`World.shapes`,
    :attr:`World.near_shapes`, rasters, caches). A world without moving obstacles has nothing
    to place: its moments cost an object each.

    The other robots' discs (:meth:`World.among`) are in the field, the obstacle list and the
    clearance at points; like the static obstacles' they are not in :meth:`path_clearance` of
    a world without moving obstacles (robots keep clear of one another by the right of way).

    Attributes:
        world: The world.
        t: The control step (a float; fractional steps allowed).
    """

    __slots__ = ("world", "t", "_offsets", "_movers", "_obstacles", "_field_shapes")

    def __init__(self, world: World, t: float = 0.0):
        self.world = world
        self.t = float(t)
        self._offsets: tuple[np.ndarray, ...] | None = None
        self._movers: tuple[Obstacle, ...] | None = None
        self._obstacles: tuple[Obstacle, ...] | None = None
        self._field_shapes: ShapeSet | None = None

    def __repr__(self) -> str:
        return f"Moment({self.world.name!r}, t={self.t:g})"

    @property
    def offsets(self) -> tuple[np.ndarray, ...]:
        """The route offset (2,) of each moving obstacle, in :attr:`World.moving` order."""
        if self._offsets is None:
            self._offsets = tuple(self.world.obstacles[i].motion.offset(self.t) for i in self.world.moving)
        return self._offsets

    @property
    def movers(self) -> tuple[Obstacle, ...]:
        """The moving obstacles where they are (in :attr:`World.moving` order), then the other robots' discs."""
        if self._movers is None:
            world = self.world
            self._movers = (tuple(world.obstacles[i].moved(shift) for i, shift in zip(world.moving, self.offsets))
                            + tuple(CircleObstacle(c, world.robot_radius) for c in world.others))
        return self._movers

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        """Every obstacle where it is, in :attr:`World.obstacles` order, then the other robots' discs."""
        if self._obstacles is None:
            world = self.world
            placed = list(world.obstacles)
            for k, i in enumerate(world.moving):
                placed[i] = self.movers[k]
            self._obstacles = tuple(placed) + self.movers[len(world.moving):]
        return self._obstacles

    def _field_set(self) -> ShapeSet | None:
        """:attr:`movers` indexed for the field (reach ``p0``); None when there are none."""
        if self._field_shapes is None and self.movers:
            self._field_shapes = ShapeSet(self.movers, max(self.world.field.p0, self.world.robot_radius))
        return self._field_shapes

    # -- the field ---------------------------------------------------------------------
    def potential(self, points: np.ndarray) -> np.ndarray:
        """Total potential U at ``(N, 2)`` points (Model §1)."""
        points = np.asarray(points, float).reshape(-1, 2)
        world = self.world
        r = world.robot_radius     # the cap where the robot touches (Model §1 as the README states it)
        u = apf.potential(points, world.targets, world.shapes, world.field, r)
        movers = self._field_set()
        return u + apf.repulsive(points, movers, world.field, r) if movers is not None else u

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """``∇U`` at ``(N, 2)`` points."""
        points = np.asarray(points, float).reshape(-1, 2)
        world = self.world
        r = world.robot_radius
        g = apf.gradient(points, world.targets, world.shapes, world.field, r)
        movers = self._field_set()
        return g + apf.repulsive_gradient(points, movers, world.field, r) if movers is not None else g

    # -- geometry ----------------------------------------------------------------------
    def obstacle_distance(self, points: np.ndarray, static: bool = False, near: bool = False) -> np.ndarray:
        """Signed distance to the nearest obstacle's boundary (negative inside); see :meth:`World.obstacle_distance`.

        ``static``: leave the moving obstacles (and the other robots) out. ``near``: exact only up to
        :data:`MOVE_REACH` beyond the robot's radius.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        world = self.world
        best = (world.near_shapes if near else world.shapes).distance(points)
        return best if static else _with_moving(world, points, best, self.offsets)

    def clearance(self, points: np.ndarray, near: bool = False) -> np.ndarray:
        """Distance from each point to the nearest obstacle or the map's edge (negative when blocked).

        ``near``: exact only up to :data:`MOVE_REACH` beyond the robot's radius.
        """
        return np.minimum(self.obstacle_distance(points, near=near), self.world.edge_distance(points))

    def path_clearance(self, a: np.ndarray, b: np.ndarray, spacing: np.ndarray | float,
                       during: bool = True) -> np.ndarray:
        """Least clearance sampled along each straight segment ``a[i] → b[i]``, the moving obstacles included.

        As :meth:`World.static_path_clearance` (samples at most ``spacing`` apart, exact up to
        :data:`MOVE_REACH` beyond the robot's radius), with the moving obstacles where they are
        at this step (``during`` False), or, with ``during`` (each segment is a move made during
        control step ``t → t + 1``), where they are at ``t + s`` for a sample a fraction ``s``
        along it. A world without moving obstacles: the static clearance.

        Returns:
            (K,) sampled minimum clearance of each segment.
        """
        world = self.world
        if not world.moving:
            return world.static_path_clearance(a, b, spacing)
        a = np.asarray(a, float).reshape(-1, 2)
        points, owner = geometry.segment_samples(a, b, spacing)
        if not during:
            clearance = self.clearance(points, near=True)
        else:
            along = np.hypot(*(points - a[owner]).T)
            length = np.hypot(*(np.asarray(b, float).reshape(-1, 2) - a).T)[owner]
            when = self.t + np.where(length > 0, along / np.where(length > 0, length, 1.0), 0.0)
            offsets = [world.obstacles[i].motion.offset(when) for i in world.moving]
            clearance = np.minimum(_with_moving(world, points, world.near_shapes.distance(points), offsets),
                                   world.edge_distance(points))
        return _least_per_segment(len(a), owner, clearance)


@kernel
def _table_rows(t):
    """``(rows, last)``: each step of ``t`` (1-D) as a row of the motion table (the step + 1) and
    the last row needed, or ``last`` −1 if a step is not whole or not from step −1 to
    :data:`MOTION_TABLE_STEPS`."""
    rows = np.empty(t.shape[0], np.intp)
    last = 0
    for i in range(t.shape[0]):
        if not (-1.0 <= t[i] < MOTION_TABLE_STEPS and t[i] == np.floor(t[i])):
            return rows, -1
        rows[i] = int(t[i]) + 1
        last = max(last, rows[i])
    return rows, last


def _with_moving(world: World, points: np.ndarray, best: np.ndarray, offsets) -> np.ndarray:
    """``best`` (N,) lowered to the signed distance to each moving obstacle, shifted by its offset in
    ``offsets`` ((2,) or (N, 2) each, in :attr:`World.moving` order), and to the other robots' discs.

    Measured in each obstacle's own frame: the points moved back by its offset.
    """
    for i, shift in zip(world.moving, offsets):
        d, _ = world.obstacles[i].signed_distance(points - shift)
        best = np.minimum(best, d)
    if len(world.others):
        others = world.others
        gap = np.hypot(points[:, None, 0] - others[None, :, 0], points[:, None, 1] - others[None, :, 1])
        best = np.minimum(best, gap.min(axis=1) - world.robot_radius)
    return best


def _least_per_segment(count: int, owner: np.ndarray, clearance: np.ndarray) -> np.ndarray:
    """(count,) the least ``clearance`` of each segment's samples (``owner``: each sample's segment)."""
    out = np.full(count, np.inf)
    np.minimum.at(out, owner, clearance)
    return out
