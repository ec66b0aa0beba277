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
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

from apf_physics.world.bundled import resolve_world
from apf_physics.errors import UserError, WorldError
from apf_physics.world.field import FieldParams
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, Motion, Obstacle, PolygonObstacle
from apf_physics.common.safefile import MAX_FILE_BYTES, open_regular_file, read_regular_file  # noqa: F401 (public here too)
from apf_physics.common.safefile import write_text
from apf_physics.common.safeyaml import MAX_DEPTH, MAX_NODES, MAX_SCALAR_CHARS  # noqa: F401 (public here too)
from apf_physics.common.safeyaml import read_yaml_file, shortened
from apf_physics.world.core import FormationSpec, FormationTask, World
from apf_physics.world.io.schema import (MAX_FOLLOWERS, MAX_FORMATIONS, MAX_NAME_CHARS,  # noqa: F401 (public here too)
                                     MAX_OBSTACLES, MAX_POLYGON_VERTICES, MAX_PROBLEMS, MAX_ROUTE_POINTS, MAX_SIDE,
                                     MAX_STARTS, MAX_TARGETS, MAX_VERTICES, MIN_SIDE)
from apf_physics.world.io.schema import (MAX_POTENTIAL, MIN_GOAL_TOLERANCE, MIN_ROBOT_RADIUS, Checker, TooMany,
                                     parse_world)

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


def raster_memory(size: Sequence[float], targets: int) -> float:
    """Estimated peak memory [bytes] of the rasters an evaluation of a world builds.

    The potential and observation rasters and the A* grid (4 nodes per unit) over the map and
    :data:`RASTER_MARGIN` beyond
    it: :data:`RASTER_BYTES_PER_UNIT2` plus :data:`RASTER_BYTES_PER_TARGET` per target, per
    square unit (measured peaks, rounded up).
    """
    area = (float(size[0]) + 2 * RASTER_MARGIN) * (float(size[1]) + 2 * RASTER_MARGIN)
    return area * (RASTER_BYTES_PER_UNIT2 + RASTER_BYTES_PER_TARGET * int(targets))


def raster_memory_problem(size: Sequence[float], targets: int) -> str | None:
    """What to say when the rasters of a map of ``size`` with ``targets`` targets exceed :func:`memory_budget`, else None."""
    need, budget = raster_memory(size, targets), memory_budget()
    if need <= budget:
        return None
    return (f"a {size[0]:g} x {size[1]:g} map with {targets} target(s) needs about {_gib(need)} of rasters "
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


def _check_together(check: Checker, size, robot_radius, goal_tolerance, params, obstacles, targets) -> None:
    """The limits that depend on several values (each checked when its values are valid)."""
    if size is not None:
        if robot_radius is not None and robot_radius >= min(size) / 2:
            check.bad("robot_radius", f"{robot_radius:g} does not fit in the {size[0]:g} x {size[1]:g} map "
                                      "(it must be less than half its shorter side)")
        half_diagonal = math.hypot(*size) / 2
        if goal_tolerance is not None and goal_tolerance >= half_diagonal:
            check.bad("goal_tolerance", f"{goal_tolerance:g} is not less than half the map's diagonal "
                                        f"({half_diagonal:.4g}): nearly every point would count as reached")
    if size is not None and targets is not None:
        problem = raster_memory_problem(size, len(targets))
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
        check.bad("robot_radius", f"must be at least {MIN_ROBOT_RADIUS:g} (smaller robots need more than 256 physics "
                                  f"substeps per step), got {robot_radius:g}")
    if goal_tolerance is not None and goal_tolerance < MIN_GOAL_TOLERANCE:
        check.bad("goal_tolerance", f"must be at least {MIN_GOAL_TOLERANCE:g} (the A* grid's spacing), "
                                    f"got {goal_tolerance:g}")


def _check_placement(check: Checker, world: World, index: Mapping[str, Sequence[int]] | None = None) -> None:
    """Targets and starts inside the map and outside the obstacles; starts not yet at a target.

    ``index``: for a world built of the entries that parsed, each list's indices in the file
    (``starts``, ``targets``, ``obstacles``), so the problems name the file's entries.
    """
    index = index or {}
    size, radius = world.size, world.robot_radius
    for key, pts, margin in (("targets", world.targets, 0.0), ("starts", world.starts, radius)):
        if not len(pts):
            continue
        edge = world.edge_distance(pts)
        inside = np.full(len(pts), np.inf)
        in_map = np.flatnonzero(edge >= margin)
        inside[in_map] = world.obstacle_distance(pts[in_map])
        # (a formation's start is checked against its own target: _check_formations)
        reached = (world.distance_to_target(pts) <= world.goal_tolerance if key == "starts" and not world.formations
                   else np.zeros(len(pts), bool))
        for i in np.flatnonzero((edge < margin) | (inside < margin) | (inside <= 0) | reached).tolist():
            where = f"{key}[{index[key][i] if key in index else i}]"
            at = [round(v, 9) for v in world.frame.to_file(pts[i]).tolist()]
            if edge[i] < 0:
                lo, hi = world.frame.to_file([0.0, 0.0]), world.frame.to_file(size)
                check.bad(where, f"{at} is outside the map [{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}]")
            elif edge[i] < margin:
                check.bad(where, f"{at} is closer than the robot radius {radius * world.frame.unit:g} to the map's edge")
            elif inside[i] <= 0:
                check.bad(where, f"{at} is inside {_nearest_obstacle(world, pts[i], index.get('obstacles'))}")
            elif inside[i] < margin:
                check.bad(where, f"{at} is closer than the robot radius {radius * world.frame.unit:g} to "
                                 f"{_nearest_obstacle(world, pts[i], index.get('obstacles'))}")
            else:
                check.bad(where, f"{at} is already within goal_tolerance {world.goal_tolerance * world.frame.unit:g} "
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
    return f"obstacles[{index[k] if index is not None else k}]" + (f" {name!r}" if name is not None else "")


def _check_formations(check: Checker, world: World) -> None:
    """Several formations: their targets and starts placed like the world's, leaders apart."""
    if not world.formations:
        return
    r = world.robot_radius
    for i, task in enumerate(world.formations):
        for what, point, margin in (("target", task.target, 0.0), ("start", task.start, r)):
            clear = float(world.clearance(point[None])[0])
            if clear < margin or clear <= 0:
                check.bad(f"formations[{i}].{what}", f"{point.tolist()} is "
                          + ("not clear of the obstacles and the map's edge by the robot radius" if what == "start"
                             else "inside an obstacle or outside the map"))
        if np.hypot(*(task.start - task.target)) <= world.goal_tolerance:
            check.bad(f"formations[{i}].start", f"already within goal_tolerance {world.goal_tolerance:g} of its target")
        for j in range(i):
            if np.hypot(*(task.start - world.formations[j].start)) < 2 * r:
                check.bad(f"formations[{i}].start", f"overlaps the leader of formations[{j}]")


def _check_routes(check: Checker, world: World) -> None:
    """Moving obstacles: a route of some length, and no target anywhere they sweep."""
    for i in world.moving:
        obstacle = world.obstacles[i]
        motion = obstacle.motion
        if motion.length <= 1e-9:
            check.bad(f"obstacles[{i}].motion.path", "the route has no length (every offset is [0, 0])")
            continue
        # where the obstacle is along its route, at most 0.05 apart (it moves in straight legs)
        travel = np.linspace(0.0, motion.period, max(2, int(np.ceil(motion.period / 0.05)) + 1))
        offsets = Motion(motion.path, 1.0, motion.loop).offset(travel)
        for k, target in enumerate(world.targets):
            d, _ = obstacle.signed_distance(target[None] - offsets)
            if d.min() <= 0:
                check.bad(f"obstacles[{i}].motion", f"the obstacle sweeps over targets[{k}] {target.tolist()}")


def _build(check: Checker, data: Any, source: str) -> World | None:
    """The world of the world-file mapping ``data``, or None when it has problems (recorded)."""
    parts = parse_world(check, data, source)
    if parts is None:
        return None
    # everything in steps, from the map's lower-left corner (docs/real-maps.md: units)
    frame, grid = parts.frame, parts.grid
    offset, u = np.asarray(frame.offset, float), frame.unit
    to_world = (lambda pts: (np.asarray(pts, float) - offset) / u)
    size = None if parts.size is None else (parts.size[0] / u, parts.size[1] / u)
    robot_radius = None if parts.robot_radius is None else parts.robot_radius / u
    goal_tolerance = None if parts.goal_tolerance is None else parts.goal_tolerance / u
    targets = None if parts.targets is None else to_world(parts.targets)
    starts = None if parts.starts is None else to_world(parts.starts).reshape(-1, 2)
    obstacles = parts.obstacles
    if obstacles is not None:
        obstacles = tuple(_obstacle_to_world(o, offset, u) for o in obstacles)
        if grid is not None:
            obstacles += (GridObstacle(grid.occupied, grid.cell / u, (0.0, 0.0), spec=_grid_spec(data["grid"], source)),)
    formation = None if parts.formation is None else _formation_to_world(parts.formation, u)
    formations = tuple(FormationTask(to_world(t.start), to_world(t.target), _formation_to_world(t.spec, u))
                       for t in parts.formations or ())
    _check_together(check, size, robot_radius, goal_tolerance, parts.params, obstacles, targets)
    if check.problems:
        _check_what_parsed(check, parts, size, robot_radius, goal_tolerance, obstacles, targets, starts, to_world,
                           (data.get("grid") if isinstance(data, Mapping) else None), source)
        return None
    unicycle = None if parts.unicycle is None else parts.unicycle.scaled(u)
    world = World(parts.name, size, robot_radius, goal_tolerance, parts.params, obstacles, targets, starts, formation,
                  source, formations, frame=frame, unicycle=unicycle)
    _check_placement(check, world)
    _check_routes(check, world)
    _check_formations(check, world)
    return world


def _check_what_parsed(check: Checker, parts: Any, size, robot_radius, goal_tolerance, obstacles, targets, starts,
                       to_world: Callable[[Any], np.ndarray], grid_value: Any, source: str) -> None:
    """A file with problems: still check the placement of the starts and targets that parsed, among the
    obstacles that parsed, so one report lists every problem (each named by its index in the file)."""
    if size is None or robot_radius is None or goal_tolerance is None or parts.params is None or parts.formations:
        return
    if check.keys & {"size", "robot", "robot_radius", "goal_tolerance", "field", "grid"}:
        return                                  # the map or the robot itself is wrong: placement would mislead
    index: dict[str, list[int]] = {}
    if obstacles is None:
        if "obstacles" not in check.partial:
            return
        kept, index["obstacles"] = check.partial["obstacles"]
        frame = parts.frame
        obstacles = tuple(_obstacle_to_world(o, np.asarray(frame.offset, float), frame.unit) for o in kept)
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
    return {k: (str((folder / v).resolve()) if k in ("image", "map", "movingai") else v) for k, v in value.items()}


def _obstacle_to_world(obstacle: Obstacle, offset: np.ndarray, unit: float) -> Obstacle:
    if unit == 1.0 and not offset.any():
        return obstacle
    motion = obstacle.motion
    if motion is not None:
        motion = Motion(np.asarray(motion.path, float) / unit, motion.speed / unit, motion.loop, motion.phase / unit)
    if isinstance(obstacle, CircleObstacle):
        return CircleObstacle((obstacle.center - offset) / unit, obstacle.radius / unit, motion)
    return PolygonObstacle((obstacle.vertices - offset) / unit, motion)


def _formation_to_world(spec: FormationSpec, unit: float) -> FormationSpec:
    if unit == 1.0:
        return spec
    return replace(spec, comm_range=spec.comm_range / unit, spacing=spec.spacing / unit,
                   offsets=tuple((a / unit, b / unit) for a, b in spec.offsets))


def world_from_dict(data: Any, source: str = "<dict>") -> World:
    """Validate a world-file mapping and build the :class:`World`.

    Raises:
        WorldError: one line per problem (the first :data:`MAX_PROBLEMS`, then how many
            more), each naming ``source``, the key and what is wrong.
    """
    check = Checker(source)
    try:
        world = _build(check, data, source)
    except TooMany:
        world = None
    if check.problems or world is None:
        raise check.error()
    return world


def load_world(path: str | Path) -> World:
    """Read and validate a world file (YAML, or JSON being YAML).

    Raises:
        WorldError: the file is missing, not a regular file, too large, not YAML, or breaks
            the contract (every problem, one line each).
    """
    path = resolve_world(path)
    if Path(path).suffix.lower() == ".map":
        raise WorldError(f"{path}: a MovingAI map alone has no target: evaluate its scenarios with "
                         f"`apf-physics eval {path} --scen {path}.scen`, or write a world file with "
                         f"'grid: {{movingai: {Path(path).name}}}' and targets")
    data = read_yaml_file(path, "world", WorldError)
    if isinstance(data, Mapping) and "image" in data and "resolution" in data:
        raise WorldError(f"{path}: a ROS map alone has no target: write a world file with "
                         f"'grid: {{map: {Path(path).name}}}', robot: {{radius, step}}, a field and targets")
    return world_from_dict(data, str(path))


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
    return yaml.dump(_tidy(world.to_dict()), Dumper=_WorldDumper, sort_keys=False, width=120)


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
