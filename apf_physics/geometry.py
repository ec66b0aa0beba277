"""Vectorised planar geometry: distances to polygons and circles, containment, simplicity.

Every function takes arrays of points ``(N, 2)`` and works on all of them at once.
"""

from __future__ import annotations

import numpy as np


def polygon_area(vertices: np.ndarray) -> float:
    """Signed area of a polygon (positive when counter-clockwise)."""
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def segments_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each point to the nearest of several segments, and that nearest point.

    Args:
        points: (N, 2) query points.
        a: (E, 2) segment start points.
        b: (E, 2) segment end points.

    Returns:
        ``(distance (N,), nearest (N, 2))``.
    """
    # One pass per segment over contiguous x and y columns: segments are few, points many.
    px, py = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
    best = np.full(len(points), np.inf)
    nx = np.zeros(len(points))
    ny = np.zeros(len(points))
    for (ax, ay), (bx, by) in zip(a.tolist(), b.tolist()):
        dx, dy = bx - ax, by - ay
        length2 = max(dx * dx + dy * dy, 1e-300)
        t = ((px - ax) * dx + (py - ay) * dy) / length2
        np.clip(t, 0.0, 1.0, out=t)
        qx = ax + t * dx
        qy = ay + t * dy
        d2 = (px - qx) ** 2 + (py - qy) ** 2
        closer = d2 < best
        best = np.where(closer, d2, best)
        nx = np.where(closer, qx, nx)
        ny = np.where(closer, qy, ny)
    return np.sqrt(best), np.column_stack([nx, ny])


def points_in_polygon(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Even-odd rule containment test (points on the boundary may fall either way)."""
    x, y = points[:, 0:1], points[:, 1:2]
    x1, y1 = vertices[:, 0], vertices[:, 1]
    x2, y2 = np.roll(x1, -1), np.roll(y1, -1)
    crosses = (y1 > y) != (y2 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
    return np.count_nonzero(crosses & (x < x_at), axis=1) % 2 == 1


def polygon_signed_distance(points: np.ndarray, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance to a polygon's boundary (negative inside) and the nearest boundary point."""
    a = vertices
    b = np.roll(vertices, -1, axis=0)
    dist, nearest = segments_distance(points, a, b)
    inside = points_in_polygon(points, vertices)
    return np.where(inside, -dist, dist), nearest


def circle_signed_distance(points: np.ndarray, center: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance to a circle's rim (to its centre when the radius is 0) and the nearest rim point."""
    diff = points - center
    r = np.hypot(diff[:, 0], diff[:, 1])
    safe = np.where(r > 0, r, 1.0)
    direction = np.where(r[:, None] > 0, diff / safe[:, None], np.array([1.0, 0.0]))
    return r - radius, center + direction * radius


def _orientation(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))


def polygon_is_simple(vertices: np.ndarray) -> bool:
    """True when no two non-adjacent edges of the polygon touch or cross, and no vertex repeats."""
    n = len(vertices)
    a = vertices
    b = np.roll(vertices, -1, axis=0)
    if np.any(np.all(np.isclose(a, b), axis=1)):
        return False
    i, j = np.triu_indices(n, k=1)
    # Adjacent edges share a vertex; they may only meet there.
    adjacent = (j == i + 1) | ((i == 0) & (j == n - 1))
    i, j = i[~adjacent], j[~adjacent]
    if len(i) == 0:
        return True
    p1, p2, q1, q2 = a[i], b[i], a[j], b[j]
    o1, o2 = _orientation(p1, p2, q1), _orientation(p1, p2, q2)
    o3, o4 = _orientation(q1, q2, p1), _orientation(q1, q2, p2)
    proper = (o1 != o2) & (o3 != o4)

    def on_segment(p, q, r):  # r collinear with p-q and inside its box
        return (np.minimum(p[:, 0], q[:, 0]) <= r[:, 0]) & (r[:, 0] <= np.maximum(p[:, 0], q[:, 0])) & (
            np.minimum(p[:, 1], q[:, 1]) <= r[:, 1]) & (r[:, 1] <= np.maximum(p[:, 1], q[:, 1]))

    touching = ((o1 == 0) & on_segment(p1, p2, q1)) | ((o2 == 0) & on_segment(p1, p2, q2)) | (
        (o3 == 0) & on_segment(q1, q2, p1)) | ((o4 == 0) & on_segment(q1, q2, p2))
    # Collinear consecutive edges (o == 0 everywhere) of adjacent pairs are excluded above.
    return not bool(np.any(proper | touching))
