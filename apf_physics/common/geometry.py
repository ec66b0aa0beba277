"""Vectorised planar geometry: distances to polygons and circles, containment, simplicity.

Every function takes arrays of points ``(N, 2)`` and works on all of them at once.
"""

from __future__ import annotations

import numpy as np


def polygon_area(vertices: np.ndarray) -> float:
    """Signed area of a polygon (positive when counter-clockwise; ±inf or nan, silently, when the
    coordinates are so large that it overflows: the world file's checks report such a polygon)."""
    x, y = vertices[:, 0], vertices[:, 1]
    with np.errstate(over="ignore", invalid="ignore"):
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


SMALL_POLYGON = 16
"""Up to this many vertices, :func:`polygon_is_simple` tests every pair in plain Python."""


def polygon_is_simple(vertices: np.ndarray, chunk: int = 65536) -> bool:
    """True when no two non-adjacent edges of the polygon touch or cross, and no vertex repeats.

    Only pairs of edges whose bounding boxes overlap can meet: a sweep over the edges sorted
    by their lowest x finds them, and they are tested ``chunk`` pairs at a time, so memory
    stays bounded and typical polygons cost far less than all n² pairs.
    """
    n = len(vertices)
    if n <= SMALL_POLYGON:
        return _polygon_is_simple_small(vertices)
    a = np.asarray(vertices, dtype=float)
    b = np.concatenate([a[1:], a[:1]])
    if np.any(np.all(np.isclose(a, b), axis=1)):
        return False
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.argsort(lo[:, 0], kind="stable")
    # Edge order[k] can only meet the edges order[k+1 : stop[k]] later in the sweep.
    stop = np.searchsorted(lo[order, 0], hi[order, 0], side="right")
    counts = np.maximum(stop - np.arange(n) - 1, 0)
    ends = np.cumsum(counts)
    first = 0
    while first < n:
        # the next block of sweep positions whose candidate pairs fit in one chunk
        last = max(first + 1, int(np.searchsorted(ends, ends[first] - counts[first] + chunk, side="right")))
        ks = np.arange(first, min(last, n))
        c = counts[ks]
        if c.sum():
            k = np.repeat(ks, c)
            step = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c) + 1
            i, j = order[k], order[k + step]
            meet = (lo[i, 1] <= hi[j, 1]) & (lo[j, 1] <= hi[i, 1])
            gap = np.abs(i - j)
            meet &= (gap != 1) & (gap != n - 1)   # adjacent edges share a vertex; they may only meet there
            if _edges_meet(a[i[meet]], b[i[meet]], a[j[meet]], b[j[meet]]):
                return False
        first = int(ks[-1]) + 1
    return True


def _edges_meet(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> bool:
    """Whether any segment ``p1[k]–p2[k]`` crosses or touches ``q1[k]–q2[k]``."""
    if not len(p1):
        return False
    o1, o2 = _orientation(p1, p2, q1), _orientation(p1, p2, q2)
    o3, o4 = _orientation(q1, q2, p1), _orientation(q1, q2, p2)
    proper = (o1 != o2) & (o3 != o4)

    def on_segment(p, q, r):  # r collinear with p-q and inside its box
        return (np.minimum(p[:, 0], q[:, 0]) <= r[:, 0]) & (r[:, 0] <= np.maximum(p[:, 0], q[:, 0])) & (
            np.minimum(p[:, 1], q[:, 1]) <= r[:, 1]) & (r[:, 1] <= np.maximum(p[:, 1], q[:, 1]))

    touching = ((o1 == 0) & on_segment(p1, p2, q1)) | ((o2 == 0) & on_segment(p1, p2, q2)) | (
        (o3 == 0) & on_segment(q1, q2, p1)) | ((o4 == 0) & on_segment(q1, q2, p2))
    return bool(np.any(proper | touching))


def _polygon_is_simple_small(vertices: np.ndarray) -> bool:
    """:func:`polygon_is_simple` for a few vertices, in plain Python (numpy's per-call cost dominates there)."""
    pts = [tuple(p) for p in np.asarray(vertices, dtype=float).tolist()]
    n = len(pts)
    edges = [(pts[k], pts[(k + 1) % n]) for k in range(n)]
    if any(abs(p[0] - q[0]) <= 1e-8 + 1e-5 * abs(q[0]) and abs(p[1] - q[1]) <= 1e-8 + 1e-5 * abs(q[1]) for p, q in edges):
        return False   # as np.isclose

    def orient(p, q, r):
        v = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
        return (v > 0) - (v < 0)

    def on_segment(p, q, r):
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])

    for i in range(n):
        for j in range(i + 2, n - (i == 0)):
            (p1, p2), (q1, q2) = edges[i], edges[j]
            o1, o2, o3, o4 = orient(p1, p2, q1), orient(p1, p2, q2), orient(q1, q2, p1), orient(q1, q2, p2)
            if (o1 != o2 and o3 != o4) or (o1 == 0 and on_segment(p1, p2, q1)) or (o2 == 0 and on_segment(p1, p2, q2)) \
                    or (o3 == 0 and on_segment(q1, q2, p1)) or (o4 == 0 and on_segment(q1, q2, p2)):
                return False
    return True


def triangulate(vertices: np.ndarray) -> list[np.ndarray]:
    """Split a simple counter-clockwise polygon into convex pieces (ear clipping; convex stays whole)."""
    n = len(vertices)
    edges = np.concatenate([vertices[1:], vertices[:1]]) - vertices
    following = np.concatenate([edges[1:], edges[:1]])
    turn = edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]
    if np.all(turn >= -1e-12):
        return [vertices]
    idx = list(range(n))
    pieces = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10 * n * n:
        guard += 1
        m = len(idx)
        for k in range(m):
            i0, i1, i2 = idx[(k - 1) % m], idx[k], idx[(k + 1) % m]
            a, b, c = vertices[i0], vertices[i1], vertices[i2]
            if cross(a, b, c) <= 1e-12:
                continue  # reflex or degenerate corner
            ear = True
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = vertices[j]
                if cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0:
                    ear = False
                    break
            if ear:
                pieces.append(np.array([a, b, c]))
                idx.pop(k)
                break
        else:  # numerically stuck: fall back to a fan of what is left
            break
    if len(idx) >= 3:
        rest = vertices[idx]
        pieces.extend(np.array([rest[0], rest[i], rest[i + 1]]) for i in range(1, len(rest) - 1))
    return pieces


def segment_samples(a: np.ndarray, b: np.ndarray, spacing: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Evenly spaced points along each segment ``a[i] → b[i]``, both ends included.

    Segment ``i`` is cut into ``max(1, ceil(length / spacing))`` equal intervals, so that no
    two neighbouring samples are more than ``spacing`` apart.

    Args:
        a: (K, 2) segment starts.
        b: (K, 2) segment ends.
        spacing: Scalar or (K,) largest distance between neighbouring samples (> 0).

    Returns:
        ``(points (P, 2), owner (P,))``: the samples and the segment each belongs to, in order.
    """
    a = np.asarray(a, float).reshape(-1, 2)
    b = np.asarray(b, float).reshape(-1, 2)
    spacing = np.broadcast_to(np.asarray(spacing, float), (len(a),))
    length = np.hypot(*(b - a).T)
    intervals = np.maximum(1, np.ceil(length / spacing - 1e-9).astype(np.intp))
    if len(a) and np.all(intervals == intervals[0]):  # one shape for all: broadcast
        t = np.linspace(0.0, 1.0, int(intervals[0]) + 1)
        points = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]
        return points.reshape(-1, 2), np.repeat(np.arange(len(a)), len(t))
    counts = intervals + 1
    owner = np.repeat(np.arange(len(a)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(len(owner)) - first) / intervals[owner]
    return a[owner] + t[:, None] * (b - a)[owner], owner


def convex_width(vertices: np.ndarray) -> float:
    """Least width of a convex polygon: the smallest distance between parallel lines enclosing it.

    (The minimum over its edges of the farthest vertex from the edge's line.)
    """
    a = vertices
    edges = np.roll(vertices, -1, axis=0) - a
    length = np.hypot(edges[:, 0], edges[:, 1])
    keep = length > 1e-12
    if not keep.any():
        return 0.0
    a, edges, length = a[keep], edges[keep], length[keep]
    rel = vertices[None, :, :] - a[:, None, :]
    dist = np.abs(edges[:, None, 0] * rel[:, :, 1] - edges[:, None, 1] * rel[:, :, 0]) / length[:, None]
    return float(dist.max(axis=1).min())


def near_any(points: np.ndarray, centres: np.ndarray, reach: float) -> np.ndarray:
    """(N,) bool: points within ``reach`` of one of ``centres`` (M, 2), through a spatial hash.

    Points and centres are binned into square cells of side ``reach``; only the points in a
    centre's cell or the eight around it are measured, so the work grows with how many are
    near, not with N × M.
    """
    points = np.asarray(points, float).reshape(-1, 2)
    centres = np.asarray(centres, float).reshape(-1, 2)
    if not len(points) or not len(centres):
        return np.zeros(len(points), bool)
    cell_p = np.floor(points / reach).astype(np.int64)
    cell_c = np.floor(centres / reach).astype(np.int64)
    width = int(max(cell_p[:, 0].max(), cell_c[:, 0].max()) - min(cell_p[:, 0].min(), cell_c[:, 0].min())) + 3
    offset = min(cell_p[:, 0].min(), cell_c[:, 0].min()) - 1
    key_p = (cell_p[:, 1] * width) + (cell_p[:, 0] - offset)
    around = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    neighbours = (cell_c[:, None, :] + around[None]).reshape(-1, 2)
    keys_c = np.unique(neighbours[:, 1] * width + (neighbours[:, 0] - offset))
    candidates = np.flatnonzero(np.isin(key_p, keys_c))
    out = np.zeros(len(points), bool)
    if len(candidates):
        d = np.hypot(points[candidates, None, 0] - centres[None, :, 0], points[candidates, None, 1] - centres[None, :, 1])
        out[candidates] = d.min(axis=1) <= reach
    return out


def nearest_in_rows(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a boolean grid, the nearest set column at or left of, and at or right of, each column.

    Returns:
        ``(left, right)``, each ``(rows, cols)`` int32: ``-2**30`` or ``2**30`` where there is none.
    """
    rows, cols = mask.shape
    index = np.arange(cols, dtype=np.int32)
    none = np.int32(2**30)
    left = np.maximum.accumulate(np.where(mask, index, -none), axis=1).astype(np.int32)
    right = np.minimum.accumulate(np.where(mask, index, none)[:, ::-1], axis=1)[:, ::-1].astype(np.int32)
    return left, right


def nearest_cell_distance(u: np.ndarray, left: np.ndarray, right: np.ndarray,
                          limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points to the nearest set cell of a grid of unit cells, and the nearest point of it.

    Cell ``[r, c]`` is the square ``[c, c+1] × [r, r+1]``. Rows are visited outward from each
    point's own; in each, the nearest set cell is the nearest set column on the left or on
    the right (:func:`nearest_in_rows`). A point is done once the next row is no nearer than
    its best so far, so the work grows with the distance searched, not the grid's size.

    Args:
        u: (N, 2) points in cell units.
        left, right: The tables of :func:`nearest_in_rows`.
        limit: Distances beyond this are not searched: such points get ``limit``.

    Returns:
        ``(distance (N,), nearest (N, 2))`` in cell units (a point with none within ``limit``:
        ``limit`` and itself).
    """
    rows, cols = left.shape
    n = len(u)
    best2 = np.full(n, np.inf)
    nearest = u.copy()
    x, y = u[:, 0], u[:, 1]
    col = np.clip(np.floor(x), 0, cols - 1).astype(np.intp)
    row0 = np.floor(y).astype(np.intp)
    active = np.arange(n)
    cap = float(limit) if np.isfinite(limit) else float(rows + cols + abs(y).max(initial=0) + abs(x).max(initial=0))
    k = 0
    while len(active):
        for r in ((row0[active] + k,) if k == 0 else (row0[active] - k, row0[active] + k)):
            ok = (r >= 0) & (r < rows)
            if not ok.any():
                continue
            who, rr = active[ok], r[ok]
            dy = np.maximum(np.maximum(rr - y[who], y[who] - (rr + 1)), 0.0)
            for table in (left, right):
                c = table[rr, col[who]]
                found = np.abs(c) < 2**29
                dx = np.maximum(np.maximum(c - x[who], x[who] - (c + 1)), 0.0)
                d2 = np.where(found, dx * dx + dy * dy, np.inf)
                better = d2 < best2[who]
                if better.any():
                    b = who[better]
                    best2[b] = d2[better]
                    cb, rb = c[better], rr[better]
                    nearest[b, 0] = np.clip(x[b], cb, cb + 1)
                    nearest[b, 1] = np.clip(y[b], rb, rb + 1)
        k += 1
        # the rows k away are at least k - 1 (plus the part of a row) away: stop once that is no nearer
        gap = float(k - 1)
        active = active[(gap * gap < np.minimum(best2[active], cap * cap)) & (gap <= cap)]
    distance = np.sqrt(best2)
    far = ~(distance <= cap)
    distance[far] = cap
    nearest[far] = u[far]
    return distance, nearest


def grid_boundary(occupied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The boundary of a grid's occupied cells (cells beyond the grid are free) as maximal
    straight segments, in cell units: ``(a (K, 2), b (K, 2))``.

    Cell ``[r, c]`` is the square ``[c, c+1] × [r, r+1]``; a cell side between an occupied and
    a free cell is on the boundary, and runs of them along one line are one segment.
    """
    padded = np.pad(np.asarray(occupied, bool), 1, constant_values=False)
    ends_a, ends_b = [], []
    for axis in (0, 1):
        # sides across ``axis``: between padded[i] and padded[i + 1] along that axis
        crossing = np.diff(padded.astype(np.int8), axis=axis) != 0
        lines = crossing if axis == 0 else crossing.T          # (line, position along it)
        lines = lines[:, 1:-1]                                   # positions of the grid's own cells
        edge = np.diff(np.pad(lines.astype(np.int8), ((0, 0), (1, 1))), axis=1)
        line, first = np.nonzero(edge == 1)
        _, last = np.nonzero(edge == -1)                         # runs [first, last) along each line
        position = line.astype(float)                            # the line's offset, in cells
        if axis == 0:    # horizontal sides at y = line, x from first to last
            ends_a.append(np.column_stack([first, position]))
            ends_b.append(np.column_stack([last, position]))
        else:            # vertical sides at x = line, y from first to last
            ends_a.append(np.column_stack([position, first]))
            ends_b.append(np.column_stack([position, last]))
    return np.vstack(ends_a).astype(float), np.vstack(ends_b).astype(float)


def swept_distance(p: np.ndarray, dp: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Smallest distance between two points moving linearly over one step (broadcasting)."""
    r0 = p - q
    dr = dp - dq
    a = np.sum(dr * dr, axis=-1)
    t = np.clip(np.where(a > 0, -np.sum(r0 * dr, axis=-1) / np.where(a > 0, a, 1.0), 0.0), 0.0, 1.0)
    closest = r0 + t[..., None] * dr
    return np.sqrt(np.sum(closest * closest, axis=-1))


# -- rectangles --------------------------------------------------------------------------

def occupancy_rectangles(occupied: np.ndarray) -> np.ndarray:
    """Rectangles that tile the occupied cells exactly, without overlap.

    Each row's horizontal runs of occupied cells, each run merged with the identical run (same
    first and last column) in the row above, so a solid block is one rectangle.

    Returns:
        ``(R, 4)`` int64 ``[col0, row0, col1, row1]``: the half-open cell ranges
        ``[col0, col1) × [row0, row1)``, sorted by ``row0`` then ``col0``.
    """
    occupied = np.asarray(occupied, dtype=bool)
    if occupied.ndim != 2:
        raise ValueError(f"occupied must be a 2-D array, got shape {occupied.shape}")
    rows, cols = occupied.shape
    padded = np.zeros((rows, cols + 2), dtype=np.int8)
    padded[:, 1:-1] = occupied
    step = np.diff(padded, axis=1)
    run_row, col0 = np.nonzero(step == 1)     # row-major: the k-th start and the k-th end are one run
    _, col1 = np.nonzero(step == -1)
    if run_row.size == 0:
        return np.zeros((0, 4), dtype=np.int64)
    # Runs with the same columns in consecutive rows are one rectangle: sort by columns, then row.
    order = np.lexsort((run_row, col1, col0))
    r, c0, c1 = run_row[order], col0[order], col1[order]
    continues = np.zeros(r.size, dtype=bool)
    continues[1:] = (c0[1:] == c0[:-1]) & (c1[1:] == c1[:-1]) & (r[1:] == r[:-1] + 1)
    first = np.flatnonzero(~continues)
    last = np.append(first[1:], r.size) - 1
    boxes = np.stack([c0[first], r[first], c1[first], r[last] + 1], axis=1).astype(np.int64)
    return boxes[np.lexsort((boxes[:, 0], boxes[:, 1]))]
