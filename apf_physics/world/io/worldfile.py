"""World files: reading, validating and writing the YAML world-file contract (docs/world-files.md).

:func:`load_world` reads a file (YAML, or JSON being YAML) and :func:`world_from_dict`
validates a mapping and builds the :class:`~apf_physics.world.World`: the schema
(:func:`~apf_physics.world.io.schema.parse_world`) checks each key and value, then the limits
that depend on several values are checked (:func:`raster_memory` among them), the values are
converted to steps, and the world's targets and starts are checked against its obstacles.
Every problem found is reported, one line each, in one :class:`~apf_physics.errors.WorldError`:
``<file>: <key>: <what is wrong>``, with values shortened. :func:`save_world` writes a file
that reads back to the same world.

Hostile or broken input gets a clear refusal, never a traceback, a hang or a raw memory
error: only regular files of at most :data:`MAX_FILE_BYTES` are read; the YAML parser's
events are checked for depth, length and node count (aliases expanded) before any Python
object is built (:mod:`apf_physics.common.safeyaml`); and the limits (:mod:`apf_physics.world.io.schema`,
and the memory budget here) are checked before the work they protect (the rasters the physics
and the planners build, the physics' substeps, the field's values). The limits and
:func:`read_yaml_file` are importable from here too.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

from apf_physics.world.bundled import resolve_world
from apf_physics.errors import UserError, WorldError
from apf_physics.world.field import FieldParams
from apf_physics.world.obstacles import GridObstacle, Motion
from apf_physics.common.safefile import MAX_FILE_BYTES, open_regular_file, read_regular_file  # noqa: F401 (public here too)
from apf_physics.common.safefile import paths_confined, write_text
from apf_physics.common.safeyaml import MAX_DEPTH, MAX_NODES, MAX_SCALAR_CHARS  # noqa: F401 (public here too)
from apf_physics.common.safeyaml import read_yaml_file, shortened
from apf_physics.world.core import Fleet, Frame, FormationTask, World
from apf_physics.world.io.units import (formation_to_steps, obstacle_to_steps, points_to_steps, show_length,
                                        show_point, unit_suffix, world_to_file)
from apf_physics.world.io.schema import (MAX_FOLLOWERS, MAX_FORMATIONS, MAX_NAME_CHARS,  # noqa: F401 (public here too)
                                     MAX_OBSTACLES, MAX_POLYGON_VERTICES, MAX_PROBLEMS, MAX_ROUTE_POINTS, MAX_SIDE,
                                     MAX_STARTS, MAX_TARGETS, MAX_VERTICES, MIN_SIDE)
from apf_physics.world.kinematics import HOLONOMIC_SPEED, MAX_SUBSTEPS, physics_substeps
from apf_physics.world.io.schema import (MAX_POTENTIAL, MIN_GOAL_TOLERANCE, MIN_ROBOT_RADIUS, Checker, TooMany,
                                     join_key, obstacle_place, parse_world)

# -- limits that depend on several values (docs/world-files.md) ---------------------------


MEMORY_BUDGET = 2 * 2**30
"""Default peak memory the rasters of one world may take [bytes]; the environment variable
``APF_PHYSICS_MEMORY_BUDGET`` (bytes, or a number with K, M, G or T) overrides it."""
MEMORY_BUDGET_VARIABLE = "APF_PHYSICS_MEMORY_BUDGET"
RASTER_MARGIN = 16.0
"""How far beyond the map rasters reach [units] (observation windows of up to 29 × 29)."""
RASTER_BYTES_PER_UNIT2 = 4_000
"""Peak bytes per square unit of rasters (map plus margin) an evaluation builds, computed in
chunks. The A* grid and the potential and observation rasters at 4 nodes per unit dominate:
1,100–1,600 bytes per square unit on 150 × 150 maps (``tests/test_world.py``). The budget keeps
more than twice that, so that a world it admits never fails in an allocation whichever planners
run on it (the physics indexes static shapes, :mod:`apf_physics.sim.swept`, and needs no raster)."""
RASTER_BYTES_PER_TARGET = 1_500
"""Further peak bytes per square unit per target: U is computed from a column per target
(measured 370 at the default 4 nodes per unit; 1,500 covers a model's observer at 8)."""
RASTER_BYTES_PER_FORMATION = 300
"""Further bytes per square unit per formation of a world's ``formations:``: each formation plans
in a world of its own target, which keeps its own rasters while the evaluation runs. Measured
(``tools/bench_warehouse.py``, BENCHMARKS.md "Many formations in a warehouse"): the map network
(the default leader) keeps its values and goal nodes, about 20 (its map view's clearance is
shared by every formation); the window network ``general.pt`` its observation raster of U at 4
nodes per unit, about 130. A model observing at 8 nodes per unit keeps four times that: raise
the budget for many formations of one. What depends on the map alone (the obstacles' index,
clearance) is shared and counted once, in :data:`RASTER_BYTES_PER_UNIT2`."""


def memory_budget() -> int:
    """The peak memory the rasters of one world may take [bytes]: :data:`MEMORY_BUDGET`, or
    ``APF_PHYSICS_MEMORY_BUDGET`` (bytes, or a number with K, M, G or T, binary units).

    Raises:
        UserError: the variable is set to something else.
    """
    text = os.environ.get(MEMORY_BUDGET_VARIABLE, "").strip()
    if not text:
        return MEMORY_BUDGET
    scale = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}.get(text[-1:].upper(), 1)
    number = text[:-1] if scale > 1 else text
    try:
        value = float(number) * scale
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise UserError(f"{MEMORY_BUDGET_VARIABLE}: expected a size such as 8G or 500M, got {shortened(text)}")
    return int(value)


def raster_memory(size: Sequence[float], targets: int, formations: int = 0) -> float:
    """Estimated peak memory [bytes] of the rasters an evaluation of a world builds.

    The potential and observation rasters and the A* grid (4 nodes per unit) over the map and
    :data:`RASTER_MARGIN` beyond
    it: :data:`RASTER_BYTES_PER_UNIT2` plus :data:`RASTER_BYTES_PER_TARGET` per target, per
    square unit (measured peaks, rounded up); with ``formations`` (a world's ``formations:``,
    each planning to its own target: ``targets`` is then 1), :data:`RASTER_BYTES_PER_FORMATION`
    per formation.
    """
    area = (float(size[0]) + 2 * RASTER_MARGIN) * (float(size[1]) + 2 * RASTER_MARGIN)
    return area * (RASTER_BYTES_PER_UNIT2 + RASTER_BYTES_PER_TARGET * int(targets)
                   + RASTER_BYTES_PER_FORMATION * int(formations))


def raster_memory_problem(size: Sequence[float], targets: int, formations: int = 0) -> str | None:
    """What to say when the rasters of a map of ``size`` with ``targets`` targets (or ``formations``
    formations, each with its own) exceed :func:`memory_budget`, else None."""
    need, budget = raster_memory(size, targets, formations), memory_budget()
    if need <= budget:
        return None
    if not math.isfinite(need):
        return f"a map of {size[0]:g} x {size[1]:g} steps is too large for any memory budget"
    what = f"{formations} formations" if formations else f"{targets} target(s)"
    return (f"a map of {size[0]:g} x {size[1]:g} steps with {what} needs about {_gib(need)} of rasters "
            f"(the planners' at 4 nodes per unit), over the budget of {_gib(budget)}; "
            f"use a smaller map, or set {MEMORY_BUDGET_VARIABLE} (e.g. {math.ceil(need / 2**30)}G) on a machine "
            f"with that much memory")


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def _field_bounds(params: FieldParams, size: tuple[float, float], targets: int,
                  obstacles: int) -> dict[str, tuple[float, float]]:
    """Upper bounds of |U| and |∇U| from each term of the field anywhere the rasters reach.

    ``U_att ≤ katt/2 · T · D²`` and ``|∇U_att| ≤ katt · T · D`` with ``D`` the diagonal of the
    map and margin; ``|U_bh| ≤ kstr/2 · T · ps²``, ``|∇U_bh| ≤ kstr · T · ps``; each repulsive
    term is capped at ``u_max`` and grows only where ``(1/d − 1/p0)² < 2 u_max / krep``, so
    its slope ``krep (1/d − 1/p0) / d²`` stays below ``krep · s · (1/p0 + s)²`` with ``s = √(2 u_max / krep)``.
    """
    with np.errstate(all="ignore"):
        f = {k: np.float64(v) for k, v in params.as_dict().items()}
        reach = np.float64(math.hypot(size[0] + 2 * RASTER_MARGIN, size[1] + 2 * RASTER_MARGIN))
        s = np.sqrt(2 * f["u_max"] / f["krep"]) if f["krep"] > 0 else np.float64(0.0)
        rep_slope = obstacles * f["krep"] * s * (1 / f["p0"] + s) ** 2 if f["krep"] > 0 else np.float64(0.0)
        return {
            "katt": (f["katt"] / 2 * targets * reach**2, f["katt"] * targets * reach),
            "kstr and ps": (f["kstr"] / 2 * targets * f["ps"] ** 2, f["kstr"] * targets * f["ps"]),
            "krep, p0 and u_max": (obstacles * f["u_max"], rep_slope),
        }


def _check_together(check: Checker, size, robot_radius, goal_tolerance, params, obstacles, targets,
                    formations: int = 0, frame: Frame = Frame(), radius_key: str = "robot.radius") -> None:
    """The limits that depend on several values (each checked when its values are valid); the values
    are in steps, the messages in the file's units (``frame``), naming the radius as the file gave it."""
    def file(length: float) -> str:
        return show_length(frame, length)

    if size is not None:
        sides = f"{file(size[0])} x {file(size[1])}"
        if robot_radius is not None and robot_radius >= min(size) / 2:
            check.bad(radius_key, f"{file(robot_radius)} does not fit in the {sides} map "
                                  "(it must be less than half its shorter side)")
        half_diagonal = math.hypot(*size) / 2
        if goal_tolerance is not None and goal_tolerance >= half_diagonal:
            check.bad("goal_tolerance", f"{file(goal_tolerance)} is not less than half the map's diagonal "
                                        f"({half_diagonal * frame.unit:.4g}{unit_suffix(frame)}): nearly every point would count "
                                        "as reached")
    if size is not None and targets is not None:
        # formations plan each to its own target, in worlds of their own
        problem = raster_memory_problem(size, 1, formations) if formations else raster_memory_problem(size, len(targets))
        if problem:
            check.bad("size", problem)
    if size is not None and targets is not None and params is not None and obstacles is not None:
        bounds = _field_bounds(params, size, len(targets), len(obstacles))
        for index, what in ((0, "|U|"), (1, "the slope of U")):
            worst = max(bounds, key=lambda k: np.nan_to_num(bounds[k][index], nan=np.inf))
            value = bounds[worst][index]
            if not np.isfinite(value) or value > MAX_POTENTIAL:
                shown = f"about {value:.1e}" if np.isfinite(value) else "infinity"
                check.bad("field", f"{what} would reach {shown} on this map (from {worst}); "
                                   f"it must stay below {MAX_POTENTIAL:.0e}")
                break
    if robot_radius is not None and robot_radius < MIN_ROBOT_RADIUS:
        step = "" if frame.unit == 1.0 else f", {MIN_ROBOT_RADIUS:g} of a step of {file(1.0)}"
        check.bad(radius_key, f"must be at least {file(MIN_ROBOT_RADIUS)}{step} (smaller robots need more than 256 "
                              f"physics substeps per step), got {file(robot_radius)}")
    if goal_tolerance is not None and goal_tolerance < MIN_GOAL_TOLERANCE:
        step = "" if frame.unit == 1.0 else f", {MIN_GOAL_TOLERANCE:g} of a step of {file(1.0)}"
        check.bad("goal_tolerance", f"must be at least {file(MIN_GOAL_TOLERANCE)}{step} (the A* grid's spacing), "
                                    f"got {file(goal_tolerance)}")


def _check_placement(check: Checker, world: World, index: Mapping[str, Sequence[int]] | None = None) -> None:
    """Targets and starts inside the map and outside the obstacles; starts not yet at a target.

    ``index``: for a world built of the entries that parsed, each list's indices in the file
    (``starts``, ``targets``, ``obstacles``), so the problems name the file's entries.
    """
    with np.errstate(over="ignore", invalid="ignore"):   # (points converted to infinity: far outside the map)
        _place(check, world, index or {})


def _place(check: Checker, world: World, index: Mapping[str, Sequence[int]]) -> None:
    size, radius, frame = world.size, world.robot_radius, world.frame
    for key, pts, margin in (("targets", world.targets, 0.0), ("starts", world.starts, radius)):
        if not len(pts) or (key == "targets" and world.robots is not None and pts is world.robots.targets):
            continue   # (a fleet's targets are checked as its robots': _check_robots)
        if not len(pts):
            continue
        edge = world.edge_distance(pts)
        inside = np.full(len(pts), np.inf)
        in_map = np.flatnonzero(edge >= margin)
        inside[in_map] = world.obstacle_distance(pts[in_map], near=True)   # (exact beyond the robot's radius)
        # (a formation's start is checked against its own target: _check_formations)
        reached = (world.distance_to_target(pts) <= world.goal_tolerance if key == "starts" and not world.formations
                   else np.zeros(len(pts), bool))
        for i in np.flatnonzero((edge < margin) | (inside < margin) | (inside <= 0) | reached).tolist():
            where = f"{key}[{index[key][i] if key in index else i}]"
            at = show_point(frame, pts[i], 9)
            if not np.all(np.isfinite(pts[i])):
                lo, hi = frame.to_file([0.0, 0.0]), frame.to_file(size)
                check.bad(where, f"the point is far outside the map [{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}]")
            elif edge[i] < 0:
                lo, hi = frame.to_file([0.0, 0.0]), frame.to_file(size)
                check.bad(where, f"{at} is outside the map [{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}]")
            elif edge[i] < margin:
                check.bad(where, f"{at} is closer than the robot radius {show_length(frame, radius)} to the map's edge")
            elif inside[i] <= 0:
                check.bad(where, f"{at} is inside {_nearest_obstacle(world, pts[i], index.get('obstacles'))}")
            elif inside[i] < margin:
                check.bad(where, f"{at} is closer than the robot radius {show_length(frame, radius)} to "
                                 f"{_nearest_obstacle(world, pts[i], index.get('obstacles'))}")
            else:
                check.bad(where, f"{at} is already within goal_tolerance {show_length(frame, world.goal_tolerance)} "
                                 "of a target")


def _nearest_obstacle(world: World, point: np.ndarray, index: Sequence[int] | None = None) -> str:
    """Which obstacle of the file is nearest ``point`` at step 0 (a placement error names it):
    ``obstacles[k]`` as the file lists them (``index``: the file's index of each of the world's
    obstacles), or the grid map. Only on the error path: one pass over the obstacles."""
    placed = world.at(0.0).obstacles[:len(world.obstacles)]
    distances = [float(o.signed_distance(point[None])[0][0]) for o in placed]
    k = int(np.argmin(distances))
    if isinstance(placed[k], GridObstacle):
        return "the grid map's occupied cells"
    name = getattr(world.obstacles[k], "name", None)
    if index is not None and k >= len(index):   # not one of the file's list: the SDF world's
        return f"the SDF world's collision {name!r}"
    return obstacle_place(index[k] if index is not None else k, name)


def _check_formations(check: Checker, world: World) -> None:
    """Several formations: their targets and starts placed like the world's, leaders apart."""
    if not world.formations:
        return
    r = world.robot_radius
    for i, task in enumerate(world.formations):
        for what, point, margin in (("target", task.target, 0.0), ("start", task.start, r)):
            clear = float(world.clearance(point[None])[0])
            if clear < margin or clear <= 0:
                check.bad(f"formations[{i}].{what}", f"{show_point(world.frame, point, 9)} is "
                          + ("not clear of the obstacles and the map's edge by the robot radius" if what == "start"
                             else "inside an obstacle or outside the map"))
        if np.hypot(*(task.start - task.target)) <= world.goal_tolerance:
            check.bad(f"formations[{i}].start", f"already within goal_tolerance "
                                                f"{show_length(world.frame, world.goal_tolerance)} of its target")
        for j in range(i):
            if np.hypot(*(task.start - world.formations[j].start)) < 2 * r:
                check.bad(f"formations[{i}].start", f"overlaps the leader of formations[{j}]")


def _check_routes(check: Checker, world: World) -> None:
    """Moving obstacles: a route of some length, and no target anywhere they sweep."""
    for i in world.moving:
        obstacle = world.obstacles[i]
        motion = obstacle.motion
        where = join_key(obstacle_place(i, getattr(obstacle, "name", None)), "motion")
        if motion.length <= 1e-9:
            check.bad(f"{where}.path", "the route has no length (every offset is [0, 0])")
            continue
        # where the obstacle is along its route, at most 0.05 apart (it moves in straight legs)
        travel = np.linspace(0.0, motion.period, max(2, int(np.ceil(motion.period / 0.05)) + 1))
        offsets = Motion(motion.path, 1.0, motion.loop).offset(travel)
        for k, target in enumerate(world.targets):
            d, _ = obstacle.signed_distance(target[None] - offsets)
            if d.min() <= 0:
                check.bad(where, f"the obstacle sweeps over targets[{k}] {show_point(world.frame, target, 9)}")


def _build(check: Checker, data: Any, source: str, confine: bool = False) -> World | None:
    """The world of the world-file mapping ``data``, or None when it has problems (recorded)."""
    parts = parse_world(check, data, source, confine)
    if parts is None:
        return None
    # everything in steps, from the map's lower-left corner (docs/real-maps.md: units)
    frame, grid = parts.frame, parts.grid

    def to_world(pts: Any) -> np.ndarray:
        with np.errstate(over="ignore"):   # a point ~1e308 away in a file of small steps: outside the map (reported)
            return points_to_steps(frame, pts)
    size = None if parts.size is None else (parts.size[0] / frame.unit, parts.size[1] / frame.unit)
    robot_radius = None if parts.robot_radius is None else parts.robot_radius / frame.unit
    goal_tolerance = None if parts.goal_tolerance is None else parts.goal_tolerance / frame.unit
    targets = None if parts.targets is None else to_world(parts.targets)
    starts = None if parts.starts is None else to_world(parts.starts).reshape(-1, 2)
    obstacles = None if parts.obstacles is None or parts.sdf is None else parts.obstacles + parts.sdf
    if obstacles is not None:
        obstacles = tuple(obstacle_to_steps(frame, o) for o in obstacles)
        if grid is not None:
            obstacles += (GridObstacle(grid.occupied, grid.cell / frame.unit, (0.0, 0.0),
                                       spec=_grid_spec(data["grid"], source)),)
    formation = None if parts.formation is None else formation_to_steps(frame, parts.formation)
    formations = tuple(FormationTask(to_world(t.start), to_world(t.target), formation_to_steps(frame, t.spec))
                       for t in parts.formations or ())
    robots = None if parts.robots is None else Fleet(to_world(parts.robots.starts), to_world(parts.robots.targets))
    if robots is not None and parts.targets is parts.robots.targets:
        targets = robots.targets
    radius_key = "robot_radius" if isinstance(data, Mapping) and "robot_radius" in data else "robot.radius"
    # a fleet plans each robot to its own target, from tables within a budget of their own: one target's rasters
    _check_together(check, size, robot_radius, goal_tolerance, parts.params, obstacles,
                    targets if robots is None or targets is None else targets[:1], len(formations), frame, radius_key)
    if check.problems:
        _check_what_parsed(check, parts, size, robot_radius, goal_tolerance, obstacles, targets, starts, to_world,
                           (data.get("grid") if isinstance(data, Mapping) else None), source)
        return None
    unicycle = None if parts.unicycle is None else parts.unicycle.scaled(frame.unit)
    world = World(parts.name, size, robot_radius, goal_tolerance, parts.params, obstacles, targets, starts, formation,
                  source, formations, frame=frame, unicycle=unicycle, robots=robots)
    _check_substeps(check, world)
    # with an SDF world, a placement problem tells the file's obstacles from the SDF world's
    _check_placement(check, world, {"obstacles": list(range(len(parts.obstacles)))} if parts.sdf else None)
    _check_routes(check, world)
    _check_formations(check, world)
    _check_robots(check, world)
    return world


def _check_substeps(check: Checker, world: World) -> None:
    """The physics' substeps per control step (:func:`~apf_physics.world.kinematics.physics_substeps`)
    within :data:`~apf_physics.world.kinematics.MAX_SUBSTEPS`: the robot's top speed against its radius."""
    top = max(HOLONOMIC_SPEED, world.unicycle.top_speed) if world.unicycle is not None else HOLONOMIC_SPEED
    obstacle_speed = max((world.obstacles[i].motion.speed for i in world.moving), default=0.0)
    meet = bool(world.formations) or (world.formation is not None and world.formation.followers > 0)
    substeps = physics_substeps(world.robot_radius, top, obstacle_speed, meet)
    if substeps <= MAX_SUBSTEPS:
        return
    u = world.frame.unit
    why = " (robots of a formation close in on each other at twice that)" if meet else ""
    why += f" (obstacles move at up to {obstacle_speed * u:g})" if obstacle_speed else ""
    check.bad("robot", f"a robot of radius {world.robot_radius * u:g} moving at up to {top * u:g} per control step"
                       f"{why} needs {substeps:,} physics substeps per step, over the limit of {MAX_SUBSTEPS}: "
                       "a larger radius or a lower max_speed/max_reverse")


def _check_robots(check: Checker, world: World) -> None:
    """A fleet: every start clear of the obstacles and the map's edge by the robot radius, every
    target inside the map and outside the obstacles, no two starts (nor two targets) on one spot."""
    fleet = world.robots
    if fleet is None:
        return
    r, frame = world.robot_radius, world.frame
    for what, points, margin in (("start", fleet.starts, r), ("target", fleet.targets, 0.0)):
        clear = world.clearance(points)
        for i in np.flatnonzero((clear < margin) | (clear <= 0)).tolist():
            check.bad(f"robots[{i}].{what}", f"{show_point(frame, points[i], 9)} is " + (
                "not clear of the obstacles and the map's edge by the robot radius" if what == "start"
                else "inside an obstacle or outside the map"))
        for i, j in _close_pairs(points, 2 * r if what == "start" else 1e-9):
            check.bad(f"robots[{j}].{what}", f"{show_point(frame, points[j], 9)} is on robots[{i}]'s {what} "
                                             f"(two robots need {show_length(frame, 2 * r)} between their centres)"
                      if what == "start" else f"{show_point(frame, points[j], 9)} is robots[{i}]'s target too")


def _close_pairs(points: np.ndarray, within: float) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``, of points closer than ``within`` (a grid of cells of that size)."""
    cells: dict[tuple[int, int], list[int]] = {}
    pairs = []
    size = max(within, 1e-9)
    for j, p in enumerate(points):
        cx, cy = int(np.floor(p[0] / size)), int(np.floor(p[1] / size))
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for i in cells.get((cx + dx, cy + dy), ()):
                    if np.hypot(*(points[i] - p)) < within:
                        pairs.append((i, j))
        cells.setdefault((cx, cy), []).append(j)
    return sorted(pairs)


def _check_what_parsed(check: Checker, parts: Any, size, robot_radius, goal_tolerance, obstacles, targets, starts,
                       to_world: Callable[[Any], np.ndarray], grid_value: Any, source: str) -> None:
    """A file with problems: still check the placement of the starts and targets that parsed, among the
    obstacles that parsed, so one report lists every problem (each named by its index in the file)."""
    if size is None or robot_radius is None or goal_tolerance is None or parts.params is None or parts.formations:
        return
    if check.keys & {"size", "origin", "robot", "robot_radius", "goal_tolerance", "field", "grid", "sdf"}:
        return                                  # the map or the robot itself is wrong: placement would mislead
    index: dict[str, list[int]] = {"obstacles": list(range(len(parts.obstacles)))} if parts.sdf and parts.obstacles is not None else {}
    if obstacles is None:
        if "obstacles" not in check.partial:
            return
        kept, index["obstacles"] = check.partial["obstacles"]
        frame = parts.frame
        obstacles = tuple(obstacle_to_steps(frame, o) for o in tuple(kept) + tuple(parts.sdf or ()))
        if parts.grid is not None:
            obstacles += (GridObstacle(parts.grid.occupied, parts.grid.cell / frame.unit, (0.0, 0.0),
                                       spec=_grid_spec(grid_value, source)),)
    points = {"targets": targets, "starts": starts}
    for key in points:
        if points[key] is None:
            if key not in check.partial:
                return
            kept, index[key] = check.partial[key]
            points[key] = to_world(np.array(kept, float).reshape(-1, 2))
    if not len(points["targets"]):
        return
    try:
        world = World(parts.name or "world", size, robot_radius, goal_tolerance, parts.params, obstacles,
                      points["targets"], points["starts"], None, source, (), frame=parts.frame)
    except (ValueError, TypeError):             # what did parse does not make a world: nothing more to say
        return
    _check_placement(check, world, index)


def _grid_spec(value: Mapping[str, Any], source: str) -> dict[str, Any]:
    """The ``grid:`` mapping with its file names made absolute (so a world saved elsewhere still finds them)."""
    folder = Path(source).parent if source != "<dict>" else Path.cwd()
    return {k: (os.path.realpath(folder / v) if k in ("image", "map", "movingai") else v) for k, v in value.items()}


def world_from_dict(data: Any, source: str = "<dict>", confine: bool | None = None) -> World:
    """Validate a world-file mapping and build the :class:`World`.

    Args:
        data: The mapping.
        source: The file it was read from (file names in it are relative to its folder), for messages.
        confine: The files the world names (its grid's map, image) must be inside the folder of
            ``source``, symbolic links followed; None: as ``APF_PHYSICS_CONFINE_PATHS`` says
            (:func:`~apf_physics.common.safefile.paths_confined`).

    Raises:
        WorldError: one line per problem (the first :data:`MAX_PROBLEMS`, then how many
            more), each naming ``source``, the key and what is wrong.
    """
    check = Checker(source)
    confine = paths_confined() if confine is None else confine
    try:
        world = _build(check, data, source, confine)
    except TooMany:
        world = None
    if check.problems or world is None:
        raise check.error()
    return world


def load_world(path: str | Path, confine: bool | None = None) -> World:
    """Read and validate a world file (YAML, or JSON being YAML).

    ``confine``: the files the world names must be inside its folder (see :func:`world_from_dict`).

    Raises:
        WorldError: the file is missing, not a regular file, too large, not YAML, or breaks
            the contract (every problem, one line each).
    """
    path = resolve_world(path)
    if _is_image(path):
        beside = Path(path).with_suffix(".yaml")
        ros = (f"; {beside.name} beside it looks like its ROS map YAML: write 'grid: {{map: {beside.name}}}' instead"
               if beside.is_file() else "")
        raise WorldError(f"{path}: an image alone is not a world (it has no scale, origin or target): write a world "
                         f"file with 'grid: {{image: {Path(path).name}, resolution: R, origin: [x, y, 0]}}' (R: map "
                         f"units per pixel), robot: {{radius, step}}, a field and targets{ros}")
    if Path(path).suffix.lower() == ".map":
        raise WorldError(f"{path}: a MovingAI map alone has no target: evaluate its scenarios with "
                         f"`apf-physics eval {path} --scen {path}.scen`, or write a world file with "
                         f"'grid: {{movingai: {Path(path).name}}}' and targets")
    data = read_yaml_file(path, "world", WorldError)
    if isinstance(data, Mapping) and "image" in data and "resolution" in data:
        raise WorldError(f"{path}: a ROS map alone has no target: write a world file with "
                         f"'grid: {{map: {Path(path).name}}}', robot: {{radius, step}}, a field and targets")
    return world_from_dict(data, str(path), confine)


IMAGE_SUFFIXES = (".pgm", ".pbm", ".ppm", ".png", ".bmp", ".jpg", ".jpeg", ".gif", ".tif", ".tiff", ".webp")
IMAGE_SIGNATURES = (b"\x89PNG", b"\xff\xd8\xff", b"GIF8", b"II*\x00", b"MM\x00*", b"P5\n", b"P5 ", b"P2\n", b"P2 ",
                    b"P5\r", b"P2\r", b"BM")
"""How images start (PNG, JPEG, GIF, TIFF, PGM binary and plain, BMP)."""


def _is_image(path: Path) -> bool:
    """Whether ``path`` is an image (by its name, or by how it starts), not a world file."""
    if Path(path).suffix.lower() in IMAGE_SUFFIXES:
        return True
    try:
        with open_regular_file(path, "world", WorldError) as (fd, _):
            head = os.read(fd, 8)
    except (WorldError, OSError):   # (reported by the YAML reader, which opens it again)
        return False
    if head.startswith(b"BM"):   # a bitmap's header is binary; a world file starting "BM" is text
        try:
            head.decode("ascii")
            return False
        except UnicodeDecodeError:
            return True
    return head.startswith(IMAGE_SIGNATURES)


class _WorldDumper(yaml.SafeDumper):
    """Writes points and small mappings inline (``[x, y]``), everything else as blocks."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) for v in data) or all(
        isinstance(v, list) and all(isinstance(x, (int, float)) for x in v) for v in data) and len(data) <= 8
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


def _represent_dict(dumper: yaml.SafeDumper, data: dict) -> yaml.Node:
    flow = all(isinstance(v, (int, float, str)) for v in data.values())
    return dumper.represent_mapping("tag:yaml.org,2002:map", data.items(), flow_style=flow)


def _tidy(value: Any) -> Any:
    """Integral floats as ints, so world files read as people write them."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, float):
        return round(value, 6)
    if isinstance(value, list):
        return [_tidy(v) for v in value]
    if isinstance(value, dict):
        return {k: _tidy(v) for k, v in value.items()}
    return value


_WorldDumper.add_representer(list, _represent_list)
_WorldDumper.add_representer(dict, _represent_dict)


def dump_world_yaml(world: World) -> str:
    """The world as YAML text in the world-file contract."""
    return yaml.dump(_tidy(world_to_file(world)), Dumper=_WorldDumper, sort_keys=False, width=120)


def save_world(world: World, path: str | Path) -> None:
    """Write a world file (atomically) that :func:`load_world` reads back to the same world."""
    write_text(path, dump_world_yaml(world))


def load_worlds(paths: Sequence[str | Path]) -> list[World]:
    """Load several world files; a directory stands for every ``*.yaml`` in it, sorted."""
    out: list[World] = []
    for p in paths:
        p = resolve_world(p)
        if p.is_dir():
            files = sorted(p.glob("*.yaml")) + sorted(p.glob("*.yml"))
            if not files:
                raise WorldError(f"{p}: directory holds no .yaml world files")
            out.extend(load_world(f) for f in files)
        else:
            out.append(load_world(p))
    return out
