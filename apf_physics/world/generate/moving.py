"""The moving family (:data:`MOVING_FAMILIES`): a static family's obstacles plus 3–8 moving obstacles.

The moving obstacles (discs and boxes) have routes that cross the axis between the starts and
the target, at 0.15–0.6 units per step: back and forth across it, or round a loop through
three points. The world is drawn as the static families' are (:func:`~apf_physics.world.generate.static.axis_world`).
"""

from __future__ import annotations

import math

import numpy as np

from apf_physics.world.generate.shapes import disc
from apf_physics.world.generate.static import STATIC_FAMILIES, axis_world, family_obstacles
from apf_physics.world.core import World

MOVING_FAMILIES = ("moving",)


def moving_world(rng: np.random.Generator, size: float, field: str, n_starts: int, name: str | None) -> World:
    """A world of the moving family with ``n_starts`` reachable starts behind its obstacles."""
    return axis_world("moving", _static_and_moving, rng, size, field, n_starts, name)


def _static_and_moving(rng: np.random.Generator, target: np.ndarray, u: np.ndarray, gap: float,
                       scale: float) -> list[dict]:
    """A random static family's obstacles, and the moving ones (:func:`movers`)."""
    base = STATIC_FAMILIES[int(rng.integers(len(STATIC_FAMILIES)))]
    return family_obstacles(base, rng, target, u, gap) + movers(rng, target, u, gap, scale)


def movers(rng: np.random.Generator, target: np.ndarray, u: np.ndarray, gap: float, scale: float) -> list[dict]:
    """3–8 moving obstacles whose routes cross the axis between the starts and the target."""
    v = np.array([-u[1], u[0]])
    out = []
    for _ in range(int(rng.integers(3, 9))):
        centre = target + rng.uniform(2.5, gap + 12) * scale * u
        speed = float(rng.uniform(0.15, 0.6))
        if rng.random() < 0.6:   # back and forth across the axis
            half = rng.uniform(3, 8) * scale
            shift = rng.uniform(-1, 1) * half
            first = centre + (shift - half) * v
            path = [(2 * half * v).tolist()]
            loop, length = False, 4 * half
        else:                    # round a loop through three points around the crossing
            corners = [centre + rng.uniform(2, 6) * scale * np.array([math.cos(a), math.sin(a)])
                       for a in rng.uniform(0, 2 * math.pi) + np.array([0.0, 2.1, 4.2]) + rng.uniform(-0.3, 0.3, 3)]
            first = corners[0]
            path = [(corners[1] - first).tolist(), (corners[2] - first).tolist()]
            loop = True
            length = sum(np.hypot(*(corners[(i + 1) % 3] - corners[i])) for i in range(3))
        motion = {"path": path, "speed": speed, "phase": float(rng.uniform(0, length))}
        if loop:
            motion["loop"] = True
        if rng.random() < 0.6:
            shape = disc(first, rng.uniform(0.4, 1.2))
        else:
            w, h = rng.uniform(0.6, 2.5), rng.uniform(0.4, 1.0)
            angle = rng.uniform(0, math.pi)
            rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
            shape = {"polygon": (first + (np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2) @ rot.T).tolist()}
        out.append({**shape, "motion": motion})
    return out
