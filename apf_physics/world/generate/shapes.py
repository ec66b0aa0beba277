"""Obstacle shapes of the generated worlds, as world-file mappings or polygons.

The families that draw around an axis place shapes in a frame: origin ``c``, axis ``u``
(toward the starts), ``v`` = u rotated +90° (:func:`axis_point`).
"""

from __future__ import annotations

import math

import numpy as np


def thick_polyline(points: np.ndarray, thickness: float) -> np.ndarray:
    """A simple polygon of the given thickness around an open polyline of 2 or 3 points.

    Consecutive segments are joined with a mitre on the outside of the bend, so a bent line
    stays a simple polygon for bend angles of up to about 150°.
    """
    points = np.asarray(points, float)
    half = thickness / 2
    dirs = np.diff(points, axis=0)
    dirs /= np.hypot(dirs[:, 0], dirs[:, 1])[:, None]
    normals = np.column_stack([-dirs[:, 1], dirs[:, 0]])
    left, right = [], []
    for k, p in enumerate(points):
        if k == 0:
            n = normals[0]
            left.append(p + half * n)
            right.append(p - half * n)
        elif k == len(points) - 1:
            n = normals[-1]
            left.append(p + half * n)
            right.append(p - half * n)
        else:
            # Mitre joint: offset along the bisector of the two normals.
            bis = normals[k - 1] + normals[k]
            bis /= np.hypot(*bis)
            scale = half / max(np.dot(bis, normals[k]), 0.2)
            left.append(p + scale * bis)
            right.append(p - scale * bis)
    return np.vstack([left, right[::-1]])


def axis_point(c: np.ndarray, u: np.ndarray, a: float, b: float) -> np.ndarray:
    """World point ``c + a·u + b·v``."""
    v = np.array([-u[1], u[0]])
    return c + a * u + b * v


def thin_line(rng: np.random.Generator, c: np.ndarray, u: np.ndarray, length: tuple[float, float]) -> dict:
    """A straight thin line centred at ``c``, roughly across ``u`` (tilted up to 30°)."""
    half = rng.uniform(*length) / 2
    tilt = rng.uniform(-math.pi / 6, math.pi / 6)
    along = np.array([math.cos(tilt), math.sin(tilt)])  # in (u, v) coordinates, mostly along v
    a = axis_point(c, u, -half * along[1], -half * along[0])
    b = axis_point(c, u, half * along[1], half * along[0])
    return {"polygon": thick_polyline(np.array([a, b]), rng.uniform(0.3, 0.6)).tolist()}


def bent_line(rng: np.random.Generator, c: np.ndarray, u: np.ndarray, arm: tuple[float, float]) -> dict:
    """A bent thin line (V or L) with its apex at ``c`` pointing at the target, arms toward the starts."""
    opening = math.radians(rng.uniform(60, 150))    # angle between the two arms
    skew = rng.uniform(-0.3, 0.3)
    arms = []
    for sign in (-1, 1):
        angle = sign * opening / 2 + skew
        length = rng.uniform(*arm)
        arms.append(axis_point(c, u, length * math.cos(angle), length * math.sin(angle)))
    return {"polygon": thick_polyline(np.array([arms[0], c, arms[1]]), rng.uniform(0.3, 0.6)).tolist()}


def cup(rng: np.random.Generator, c: np.ndarray, u: np.ndarray) -> dict:
    """A U-shaped cup: back wall across ``u`` at ``c``, arms reaching toward the starts."""
    width = rng.uniform(6, 14)
    depth = rng.uniform(3, 8)
    t = rng.uniform(0.5, 1.0)
    w = width / 2
    # (a, b) in the frame; the opening is at a = +depth (toward the starts).
    outline = [(0, -w), (depth, -w), (depth, -w + t), (t, -w + t), (t, w - t), (depth, w - t), (depth, w), (0, w)]
    return {"polygon": [axis_point(c, u, a, b).tolist() for a, b in outline]}


def disc(center: np.ndarray, radius: float) -> dict:
    return {"circle": {"center": [float(center[0]), float(center[1])], "radius": float(radius)}}


def random_box(rng: np.random.Generator, c: np.ndarray) -> dict:
    w, h = rng.uniform(0.5, 4, size=2)
    angle = rng.uniform(0, math.pi)
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2
    return {"polygon": (c + corners @ rot.T).tolist()}


def clip_convex(poly: np.ndarray, size: float) -> np.ndarray:
    """A convex polygon clipped to the map [0, size]² (Sutherland–Hodgman)."""
    pts = [np.asarray(p, float) for p in poly]
    for axis, bound, keep_below in ((0, 0.0, False), (0, size, True), (1, 0.0, False), (1, size, True)):
        inside = (lambda p: p[axis] <= bound) if keep_below else (lambda p: p[axis] >= bound)
        out = []
        for k, p in enumerate(pts):
            q = pts[k - 1]
            if inside(p):
                if not inside(q):
                    out.append(q + (p - q) * (bound - q[axis]) / (p[axis] - q[axis]))
                out.append(p)
            elif inside(q):
                out.append(q + (p - q) * (bound - q[axis]) / (p[axis] - q[axis]))
        pts = out
        if not pts:
            return np.zeros((0, 2))
    clipped = np.clip(np.round(np.array(pts), 3), 0.0, size)
    keep = np.hypot(*(clipped - np.roll(clipped, 1, axis=0)).T) > 1e-3
    return clipped[keep]
