"""What the generated-world families share: the robot, the tolerances, the attempts, and the
checks and rounding of the obstacle mappings they draw."""

from __future__ import annotations

from typing import Any

import numpy as np

ROBOT_RADIUS = 0.25
# ≥ √2/2: a robot moving in unit steps (Model Table 1) from any start passes within √2/2 of
# every point, so every target is reachable within this tolerance (0.5 is only from aligned starts).
GOAL_TOLERANCE = 0.75
START_CLEARANCE = 0.75   # starts keep this clearance from obstacles and the map's edge [units]
MAX_ATTEMPTS = 200       # worlds drawn per requested world before giving up


def route_points(obstacle: dict) -> np.ndarray:
    """The obstacle's outline points at every vertex of its route (bounds everywhere it goes)."""
    if "polygon" in obstacle:
        outline = np.asarray(obstacle["polygon"], float)
    else:
        c, r = np.asarray(obstacle["circle"]["center"], float), obstacle["circle"]["radius"]
        outline = c + r * np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float)
    offsets = np.vstack([[0.0, 0.0], np.asarray(obstacle.get("motion", {}).get("path", []), float).reshape(-1, 2)])
    return (outline[None] + offsets[:, None]).reshape(-1, 2)


def inside_map(obstacle: dict, size: float, pad: float) -> bool:
    pts = route_points(obstacle)
    return bool(pts.min() >= pad and pts.max() <= size - pad)


def clear_of_target(obstacle: dict, target: np.ndarray, room: float) -> bool:
    """Whether a moving obstacle's swept region stays ``room`` away from the target (its bounding box does)."""
    if "motion" not in obstacle:
        return True
    pts = route_points(obstacle)
    lo, hi = pts.min(axis=0) - room, pts.max(axis=0) + room
    return not bool(np.all((target >= lo) & (target <= hi)))


def world_data(family: str, name: str | None, size: float, robot_radius: float, field: str, obstacles: list[dict],
               target: np.ndarray) -> dict[str, Any]:
    """The world-file mapping of a generated world of ``family`` with one target and no starts yet
    (the target rounded; the obstacles as given)."""
    return {
        "name": name or family,
        "size": [size, size],
        "robot_radius": robot_radius,
        "goal_tolerance": GOAL_TOLERANCE,
        "field": field,
        "obstacles": obstacles,
        "targets": round_coordinates([np.asarray(target, float).tolist()]),
        "starts": [],
    }


def round_coordinates(value: Any) -> Any:
    """Round coordinates to 3 decimals so written files read back to the same world."""
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, list):
        return [round_coordinates(v) for v in value]
    if isinstance(value, dict):
        return {k: round_coordinates(v) for k, v in value.items()}
    return value
