"""A world file's units and coordinates, both ways: where positions and lengths cross between a user and the world.

A world is laid out in **steps**: one unit is the robot's travel per control step and the origin
is the map's lower-left corner (:class:`~apf_physics.world.core.Frame`); everything inside the
package works in them. What a user writes and reads is in the world file's own units and
coordinates: the world file itself (read by :mod:`~apf_physics.world.io.worldfile` through the
inbound functions here), a start given to an environment, and everything shown back (``eval``'s
table and JSON, video captions, an environment's ``info``, messages, the ``worlds`` listing, the
axes of a field figure), which goes out through the outbound functions here. A point is
``x_file = x · unit + offset``; a length ``l_file = l · unit``. Counts of control steps stay steps.

The unit's name (``units: m`` in a world file; ``m`` for a ROS map, whose resolution is in
metres) is :attr:`Frame.name`; empty when the file names none.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from apf_physics.world.core import FormationSpec, Frame, World
from apf_physics.world.field import FIELD_PRESETS
from apf_physics.world.kinematics import LIMIT_KEYS
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, Motion, Obstacle, PolygonObstacle


# -- inbound: the file's units to steps ------------------------------------------------------
def points_to_steps(frame: Frame, points) -> np.ndarray:
    """Points (..., 2) in the file's coordinates, in the world's (steps from the map's corner)."""
    return (np.asarray(points, float) - np.asarray(frame.offset, float)) / frame.unit


def length_to_steps(frame: Frame, length):
    """A length (or an array of them) in the file's units, in steps."""
    return np.asarray(length, float) / frame.unit if np.ndim(length) else float(length) / frame.unit


def obstacle_to_steps(frame: Frame, obstacle: Obstacle) -> Obstacle:
    """An obstacle as written in the file (and its route), in steps."""
    if frame.unit == 1.0 and not any(frame.offset):
        return obstacle
    unit, offset = frame.unit, np.asarray(frame.offset, float)
    motion = obstacle.motion
    if motion is not None:
        motion = Motion(np.asarray(motion.path, float) / unit, motion.speed / unit, motion.loop, motion.phase / unit)
    if isinstance(obstacle, CircleObstacle):
        return CircleObstacle((obstacle.center - offset) / unit, obstacle.radius / unit, motion, obstacle.name)
    return PolygonObstacle((obstacle.vertices - offset) / unit, motion, obstacle.name)


def formation_to_steps(frame: Frame, spec: FormationSpec) -> FormationSpec:
    """A formation's lengths (range, spacing, offsets) as written in the file, in steps."""
    unit = frame.unit
    if unit == 1.0:
        return spec
    return replace(spec, comm_range=spec.comm_range / unit, spacing=spec.spacing / unit,
                   offsets=tuple((a / unit, b / unit) for a, b in spec.offsets))


# -- outbound: steps to the file's units -----------------------------------------------------
def points_to_file(frame: Frame, points) -> np.ndarray:
    """Points (..., 2) of the world, in the file's coordinates (:meth:`Frame.to_file`)."""
    return frame.to_file(points)


def length_to_file(frame: Frame, length):
    """A length (or an array of them) in steps, in the file's units."""
    return np.asarray(length, float) * frame.unit if np.ndim(length) else float(length) * frame.unit


def unit_suffix(frame: Frame) -> str:
    """``" m"`` to write after a length in the file's units, or ``""`` when the file names no unit."""
    return f" {frame.name}" if frame.name else ""


def show_point(frame: Frame, point, digits: int = 4) -> str:
    """A point of the world as a user wrote it: ``[6.5, -0.5]`` in the file's coordinates (rounded)."""
    return str([round(float(v), digits) for v in points_to_file(frame, point).reshape(2)])


def show_length(frame: Frame, length: float, digits: int = 4) -> str:
    """A length in steps as a user reads it: ``0.2 m`` (or ``0.2``), in the file's units."""
    return f"{round(length_to_file(frame, length), digits):g}{unit_suffix(frame)}"


def same_units(frames: Sequence[Frame]) -> Frame | None:
    """The frame of lengths shared by ``frames`` (one unit, one name), or None when they differ:
    a mean length over worlds in other units has no unit."""
    scales = {(f.unit, f.name) for f in frames}
    return frames[0] if len(scales) == 1 else None


# -- a whole world, as its file -------------------------------------------------------------
def world_to_file(world: World) -> dict[str, Any]:
    """The world as the world-file contract's mapping, in the file's units and coordinates (read
    back by :func:`~apf_physics.world.io.worldfile.world_from_dict`, the same world)."""
    frame, u = world.frame, world.frame.unit
    grids = [o for o in world.obstacles if isinstance(o, GridObstacle)]
    data: dict[str, Any] = {"name": world.name, **({"units": frame.name} if frame.name else {})}
    if grids:
        data["grid"] = dict(grids[0].spec)
    else:
        data["size"] = [world.size[0] * u, world.size[1] * u]
        if any(frame.offset):
            data["origin"] = list(frame.offset)
    data.update({
        "robot": _robot_to_file(world),
        "goal_tolerance": world.goal_tolerance * u,
        # a preset by its name: its values in file units would not read back to the bit
        "field": next((name for name in FIELD_PRESETS if world.field.equals_preset(name)),
                      frame.field_to_file(world.field)),
        "obstacles": [obstacle_to_file(frame, o) for o in world.obstacles if not isinstance(o, GridObstacle)],
        "targets": frame.to_file(world.targets).tolist(),
        "starts": frame.to_file(world.starts).tolist(),
    })
    if world.robots is not None:
        robots = world.robots
        if len(world.targets) == len(robots) and np.array_equal(world.targets, robots.targets):
            del data["targets"]   # a file of robots alone: its targets are theirs
        data["robots"] = [{"start": frame.to_file(s).tolist(), "target": frame.to_file(t).tolist()}
                          for s, t in zip(robots.starts, robots.targets)]
    if world.formation is not None:
        data["formation"] = _formation_to_file(world.formation.to_dict(), u)
    if world.formations:
        data["formations"] = [{**_formation_to_file(task.spec.to_dict(), u),
                               "start": frame.to_file(task.start).tolist(),
                               "target": frame.to_file(task.target).tolist()} for task in world.formations]
    return data


def _robot_to_file(world: World) -> dict[str, Any]:
    u = world.frame.unit
    robot: dict[str, Any] = {"radius": world.robot_radius * u, "step": u}
    if world.unicycle is not None:
        limits = world.unicycle.scaled(1.0 / u)
        robot.update({"kinematics": "unicycle", **{k: float(getattr(limits, k)) for k in LIMIT_KEYS}})
    return robot


def _formation_to_file(spec: dict[str, Any], unit: float) -> dict[str, Any]:
    spec = dict(spec, comm_range=spec["comm_range"] * unit, spacing=spec["spacing"] * unit)
    if "offsets" in spec:
        spec["offsets"] = (np.asarray(spec["offsets"], float) * unit).tolist()
    return spec


def obstacle_to_file(frame: Frame, obstacle: Obstacle) -> dict[str, Any]:
    """An obstacle's world-file mapping (its shape, name and route), in the file's units: the
    inverse of :func:`obstacle_to_steps`."""
    u = frame.unit
    moved = obstacle.moved(np.zeros(2))   # the shape alone
    if isinstance(moved, CircleObstacle):
        data: dict[str, Any] = {"circle": {"center": frame.to_file(moved.center).tolist(), "radius": moved.radius * u}}
    else:
        data = {"polygon": frame.to_file(moved.vertices).tolist()}
    if getattr(obstacle, "name", None) is not None:
        data["name"] = obstacle.name
    if obstacle.motion is not None:
        motion = obstacle.motion.to_dict()
        motion["path"] = (np.asarray(motion["path"], float) * u).tolist()
        motion["speed"] = motion["speed"] * u
        if "phase" in motion:
            motion["phase"] = motion["phase"] * u
        data["motion"] = motion
    return data
