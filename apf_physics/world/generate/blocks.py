"""Building blocks of the structure families: structures placed on the map in frames of their own.

A :class:`Block` is a structure's wall polygons with the places for targets and starts in it
(rooms, cells, a cup's inside): a building of rooms (:func:`rooms_block`), a grid maze
(:func:`maze_block`) or nested cups (:func:`cups_block`); dense clutter is loose polygons
(:func:`clutter_polygons`). Walls are rectangles along grid lines with doors cut out
(:func:`wall_pieces`, :func:`line_walls`); a :class:`LocalFrame` turns and places a block
(:func:`fit_frame`).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from apf_physics.common import geometry
from apf_physics.world.generate.shapes import thick_polyline

DOOR_WIDTH = (1.6, 3.2)     # doors between rooms [units]
CUP_SPACING = (1.8, 4.0)    # free width between nested cups [units]
TARGET_CLEARANCE = 1.0      # the target keeps this clearance from obstacles [units]


class LocalFrame:
    """A placement: local points ``p`` go to ``origin + R(angle) p``."""

    def __init__(self, origin: np.ndarray, angle: float):
        self.origin = np.asarray(origin, float)
        self.rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(points, float) @ self.rot.T


def box_corners(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def rotated_extent(w: float, h: float, angle: float) -> np.ndarray:
    """Width and height of the bounding box of a ``w`` x ``h`` box turned by ``angle``."""
    c, s = abs(math.cos(angle)), abs(math.sin(angle))
    return np.array([w * c + h * s, w * s + h * c])


def fit_frame(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, angle: float, size: float,
               pad: float) -> LocalFrame | None:
    """A frame at ``angle`` putting the local box [lo, hi] at a random place in the map, ``pad`` from its edge."""
    corners = box_corners(lo[0], hi[0], lo[1], hi[1])
    turned = corners @ LocalFrame(np.zeros(2), angle).rot.T
    low, high = turned.min(axis=0), turned.max(axis=0)
    room = (size - 2 * pad) - (high - low)
    if np.any(room < 0):
        return None
    origin = pad - low + rng.uniform(0, 1, 2) * room
    return LocalFrame(origin, angle)


def wall_pieces(extent: tuple[float, float], holes: list[tuple[float, float]], shortest: float = 0.5
                 ) -> list[tuple[float, float]]:
    """The intervals of ``extent`` left once ``holes`` are cut out (pieces shorter than ``shortest`` dropped)."""
    pieces, at = [], extent[0]
    for lo, hi in sorted(holes):
        if lo > at:
            pieces.append((at, min(lo, extent[1])))
        at = max(at, hi)
    if at < extent[1]:
        pieces.append((at, extent[1]))
    return [(a, b) for a, b in pieces if b - a >= shortest]


def merge_intervals(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Overlapping or touching intervals joined."""
    out: list[list[float]] = []
    for lo, hi in sorted(intervals):
        if out and lo <= out[-1][1] + 1e-9:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([lo, hi])
    return [(a, b) for a, b in out]


def line_walls(xs: np.ndarray, ys: np.ndarray, t: float, vertical: dict[int, list[tuple[float, float]]],
                horizontal: dict[int, list[tuple[float, float]]]) -> list[np.ndarray]:
    """Rectangles of thickness ``t`` along grid lines: ``vertical[i]`` are the solid intervals (in y) on x = xs[i]."""
    out = []
    for i, pieces in vertical.items():
        out += [box_corners(xs[i] - t / 2, xs[i] + t / 2, a, b) for a, b in pieces]
    for j, pieces in horizontal.items():
        out += [box_corners(a, b, ys[j] - t / 2, ys[j] + t / 2) for a, b in pieces]
    return out


def spanning_tree(rng: np.random.Generator, n: int, edges: list[tuple[int, int]]) -> set[int]:
    """Indices of the edges of a random spanning forest of ``n`` nodes (Kruskal's algorithm, random order)."""
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    tree = set()
    for k in rng.permutation(len(edges)).tolist():
        a, b = root(edges[k][0]), root(edges[k][1])
        if a != b:
            parent[a] = b
            tree.add(k)
    return tree


class Block:
    """A structure placed on the map: its wall polygons and the regions where targets and starts go.

    Attributes:
        polygons: Wall polygons, world coordinates.
        spots: Local boxes ``(x0, x1, y0, y1)`` (rooms, cells, a cup's inside) in ``frame``.
        frame: Local to world.
        inner: Index in ``spots`` of the place for a target (a room, a cell, the innermost cup).
        outer: Local box the structure covers (for keeping blocks apart and drawing starts).
    """

    def __init__(self, polygons: list[np.ndarray], spots: list[tuple[float, float, float, float]], frame: LocalFrame,
                 inner: int, outer: tuple[float, float, float, float]):
        self.polygons, self.spots, self.frame, self.inner, self.outer = polygons, spots, frame, inner, outer

    def point_in(self, rng: np.random.Generator, k: int, margin: float) -> np.ndarray | None:
        """A random point of spot ``k``, ``margin`` inside its box (None if the box is too small)."""
        x0, x1, y0, y1 = self.spots[k]
        if x1 - x0 < 2 * margin or y1 - y0 < 2 * margin:
            return None
        local = np.array([rng.uniform(x0 + margin, x1 - margin), rng.uniform(y0 + margin, y1 - margin)])
        return self.frame(local[None])[0]

    def around(self, rng: np.random.Generator, reach: float) -> np.ndarray:
        """A random point of the local box ``outer`` grown by ``reach``."""
        x0, x1, y0, y1 = self.outer
        local = np.array([rng.uniform(x0 - reach, x1 + reach), rng.uniform(y0 - reach, y1 + reach)])
        return self.frame(local[None])[0]

    def in_a_spot(self, rng: np.random.Generator, margin: float) -> np.ndarray | None:
        """A random point of a random spot (:meth:`point_in`)."""
        return self.point_in(rng, int(rng.integers(len(self.spots))), margin)

    def proposer(self, rng: np.random.Generator, outside: float, reach: float,
                 margin: float) -> Callable[[], np.ndarray | None]:
        """Start candidates: with probability ``outside`` (never when it is 0) a point around the
        block (:meth:`around`), else one in a random spot, ``margin`` inside it."""

        def propose() -> np.ndarray | None:
            if outside and rng.random() < outside:
                return self.around(rng, reach)
            return self.in_a_spot(rng, margin)

        return propose


def rooms_block(rng: np.random.Generator, w: float, h: float, frame: LocalFrame, outer: bool, most: int) -> Block:
    """A building of rooms in the local box [0, w] x [0, h] (with outside walls if ``outer``)."""
    t = rng.uniform(0.3, 0.7)
    room = rng.uniform(7, 16)
    nx = int(np.clip(round(w / room), 1, most))
    ny = int(np.clip(round(h / rng.uniform(0.7, 1.4) / room), 1, most))
    if nx * ny < 2:
        nx = 2
    xs = np.linspace(0, w, nx + 1)
    ys = np.linspace(0, h, ny + 1)
    xs[1:-1] += rng.uniform(-0.2, 0.2, nx - 1) * w / nx
    ys[1:-1] += rng.uniform(-0.2, 0.2, ny - 1) * h / ny
    # Walls between neighbouring rooms: (vertical?, line, segment, room a, room b).
    walls = [(True, i, j, j * nx + i - 1, j * nx + i) for i in range(1, nx) for j in range(ny)]
    walls += [(False, j, i, (j - 1) * nx + i, j * nx + i) for j in range(1, ny) for i in range(nx)]
    tree = spanning_tree(rng, nx * ny, [(a, b) for _, _, _, a, b in walls])
    p_door = rng.uniform(0.05, 0.4)
    holes: dict[tuple[bool, int], list[tuple[float, float]]] = {}

    def cut(vertical: bool, line: int, seg: int, whole: bool) -> None:
        cuts = ys if vertical else xs
        a, b = cuts[seg] + t / 2, cuts[seg + 1] - t / 2
        width = rng.uniform(*DOOR_WIDTH)
        if whole or b - a - 1.2 < width:
            hole = (a, b)
        else:
            lo = rng.uniform(a + 0.6, b - 0.6 - width)
            hole = (lo, lo + width)
        holes.setdefault((vertical, line), []).append(hole)

    for k, (vertical, line, seg, _, _) in enumerate(walls):
        u = rng.random()
        if k in tree:
            cut(vertical, line, seg, whole=u < 0.1)
        elif u < p_door:
            cut(vertical, line, seg, whole=False)
    lines_v = list(range(nx + 1)) if outer else list(range(1, nx))
    lines_h = list(range(ny + 1)) if outer else list(range(1, ny))
    if outer:   # 1-3 doors to the outside
        sides = [(True, 0, j) for j in range(ny)] + [(True, nx, j) for j in range(ny)]
        sides += [(False, 0, i) for i in range(nx)] + [(False, ny, i) for i in range(nx)]
        for k in rng.choice(len(sides), size=min(len(sides), int(rng.integers(1, 4))), replace=False).tolist():
            cut(*sides[k], whole=False)
    pad = t / 2 if outer else 0.0
    vertical = {i: wall_pieces((ys[0] - pad, ys[-1] + pad), holes.get((True, i), [])) for i in lines_v}
    horizontal = {j: wall_pieces((xs[0] - pad, xs[-1] + pad), holes.get((False, j), [])) for j in lines_h}
    polygons = [frame(p) for p in line_walls(xs, ys, t, vertical, horizontal)]
    spots = [(xs[i] + t / 2, xs[i + 1] - t / 2, ys[j] + t / 2, ys[j + 1] - t / 2) for j in range(ny) for i in range(nx)]
    return Block(polygons, spots, frame, int(rng.integers(len(spots))), (0.0, w, 0.0, h))


def maze_block(rng: np.random.Generator, nx: int, ny: int, cx: float, cy: float, frame: LocalFrame,
                outer: bool) -> Block:
    """A grid maze of ``nx`` x ``ny`` cells of ``cx`` x ``cy`` in the local box [0, nx·cx] x [0, ny·cy]."""
    t = rng.uniform(0.3, 0.7)
    xs, ys = np.arange(nx + 1) * cx, np.arange(ny + 1) * cy
    walls = [(True, i, j, j * nx + i - 1, j * nx + i) for i in range(1, nx) for j in range(ny)]
    walls += [(False, j, i, (j - 1) * nx + i, j * nx + i) for j in range(1, ny) for i in range(nx)]
    pairs = [(a, b) for _, _, _, a, b in walls]
    if rng.random() < 0.5:
        open_ = spanning_tree(rng, nx * ny, pairs)
    else:   # depth-first walk: long winding corridors
        neighbours: dict[int, list[tuple[int, int]]] = {}
        for k, (a, b) in enumerate(pairs):
            neighbours.setdefault(a, []).append((b, k))
            neighbours.setdefault(b, []).append((a, k))
        first = int(rng.integers(nx * ny))
        seen, stack, open_ = {first}, [first], set()
        while stack:
            options = [(c, k) for c, k in neighbours.get(stack[-1], []) if c not in seen]
            if not options:
                stack.pop()
                continue
            c, k = options[int(rng.integers(len(options)))]
            open_.add(k)
            seen.add(c)
            stack.append(c)
    p_loop = rng.uniform(0.05, 0.3)
    loops = rng.random(len(walls)) < p_loop
    segments: dict[tuple[bool, int], list[tuple[float, float]]] = {}
    for k, (vertical, line, seg, _, _) in enumerate(walls):
        if k not in open_ and not loops[k]:
            cuts = ys if vertical else xs
            segments.setdefault((vertical, line), []).append((cuts[seg] - t / 2, cuts[seg + 1] + t / 2))
    if outer:   # the outside wall, with 1-3 entrances of one cell each
        sides = [(True, 0, j) for j in range(ny)] + [(True, nx, j) for j in range(ny)]
        sides += [(False, 0, i) for i in range(nx)] + [(False, ny, i) for i in range(nx)]
        gates = set(rng.choice(len(sides), size=int(rng.integers(1, 4)), replace=False).tolist())
        for k, (vertical, line, seg) in enumerate(sides):
            if k not in gates:
                cuts = ys if vertical else xs
                segments.setdefault((vertical, line), []).append((cuts[seg] - t / 2, cuts[seg + 1] + t / 2))
    span_y, span_x = (ys[0], ys[-1]), (xs[0], xs[-1])
    if outer:
        span_y, span_x = (ys[0] - t / 2, ys[-1] + t / 2), (xs[0] - t / 2, xs[-1] + t / 2)

    def clip(pieces: list[tuple[float, float]], span: tuple[float, float]) -> list[tuple[float, float]]:
        return [(max(a, span[0]), min(b, span[1])) for a, b in merge_intervals(pieces)]

    vertical = {i: clip(p, span_y) for (v, i), p in segments.items() if v}
    horizontal = {j: clip(p, span_x) for (v, j), p in segments.items() if not v}
    polygons = [frame(p) for p in line_walls(xs, ys, t, vertical, horizontal)]
    spots = [(xs[i] + t / 2, xs[i + 1] - t / 2, ys[j] + t / 2, ys[j + 1] - t / 2) for j in range(ny) for i in range(nx)]
    return Block(polygons, spots, frame, int(rng.integers(len(spots))), (0.0, xs[-1], 0.0, ys[-1]))


def _cup_outline(rng: np.random.Generator, ax: float, ay: float, side: int, round_: bool) -> np.ndarray:
    """The centre line of a cup around the origin (half-extents ``ax``, ``ay``) open on ``side`` (0 = +x, 1 = +y, ...).

    U-shaped (the whole side open) or with a partial opening (at least 1.8 wide) at a random
    place on that side; rectangular or round (an ellipse).
    """
    turn = LocalFrame(np.zeros(2), side * math.pi / 2).rot
    if side % 2:            # work with the opening on +x, then turn
        ax, ay = ay, ax
    if round_:
        half = rng.uniform(0.35, 1.0) * math.pi / 2      # half the opening angle
        half = max(half, math.asin(min(1.0, 1.3 / ay)))   # an opening at least ~2.6 wide
        angles = np.linspace(half, 2 * math.pi - half, 24)
        line = np.column_stack([ax * np.cos(angles), ay * np.sin(angles)])
    else:
        f = 1.0 if rng.random() < 0.5 else rng.uniform(0.3, 0.8)
        width = max(f * 2 * ay, 1.8)
        if width >= 2 * ay - 0.6:   # U: the whole side open
            line = np.array([[ax, ay], [-ax, ay], [-ax, -ay], [ax, -ay]])
        else:
            lo = rng.uniform(-ay + 0.3, ay - 0.3 - width)
            line = np.array([[ax, lo + width], [ax, ay], [-ax, ay], [-ax, -ay], [ax, -ay], [ax, lo]])
    return line @ turn.T


def cups_block(rng: np.random.Generator, frame_at: Callable[[np.ndarray, np.ndarray], LocalFrame | None],
                grow: float) -> Block | None:
    """Two or three nested cups around the origin of the local frame, openings alternating."""
    t = rng.uniform(0.3, 0.7)
    count = 2 if rng.random() < 0.5 else 3
    ax, ay = rng.uniform(2.2, 4.5 * grow, 2)
    side = int(rng.integers(4))
    round_ = rng.random() < 0.3
    lines, extents = [], []
    for k in range(count):
        lines.append(_cup_outline(rng, ax, ay, side, round_))
        extents.append((ax, ay))
        side = (side + 2) % 4 if rng.random() < 0.75 else (side + int(rng.choice([1, 3]))) % 4
        ax += t + rng.uniform(CUP_SPACING[0], CUP_SPACING[1] * grow)
        ay += t + rng.uniform(CUP_SPACING[0], CUP_SPACING[1] * grow)
    ex, ey = extents[-1][0] + t, extents[-1][1] + t
    frame = frame_at(np.array([-ex, -ey]), np.array([ex, ey]))
    if frame is None:
        return None
    polygons = [frame(thick_polyline(line, t)) for line in lines]
    ix, iy = extents[0][0] - t / 2, extents[0][1] - t / 2
    if round_:   # the box inside the innermost ellipse
        ix, iy = ix / math.sqrt(2), iy / math.sqrt(2)
    return Block(polygons, [(-ix, ix, -iy, iy)], frame, 0, (-ex, ex, -ey, ey))


def _clutter_polygon(rng: np.random.Generator, c: np.ndarray, grow: float) -> np.ndarray:
    """One polygon of dense clutter at ``c``: a random convex polygon, a box, a bar or an L."""
    kind = rng.choice(4, p=[0.35, 0.3, 0.2, 0.15])
    angle = rng.uniform(0, 2 * math.pi)
    if kind == 0:
        n = int(rng.integers(3, 8))
        angles = np.sort(rng.uniform(0, 2 * math.pi, n))
        angles = angles[np.diff(np.append(angles, angles[0] + 2 * math.pi)) > 0.2]
        if len(angles) < 3:
            angles = np.array([0.0, 2.1, 4.2])
        radius = rng.uniform(0.6, 2.2) * grow * rng.uniform(0.7, 1.0, len(angles))
        local = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    elif kind == 1:
        w, h = rng.uniform(0.6, 3.5, 2) * grow
        local = box_corners(-w / 2, w / 2, -h / 2, h / 2)
    elif kind == 2:
        length, thick = rng.uniform(2, 6) * grow, rng.uniform(0.3, 0.6)
        local = box_corners(-length / 2, length / 2, -thick / 2, thick / 2)
    else:
        a, b = rng.uniform(2, 5, 2) * grow
        thick = rng.uniform(0.4, 0.8)
        local = np.array([[0, 0], [a, 0], [a, thick], [thick, thick], [thick, b], [0, b]]) - [a / 3, b / 3]
    return LocalFrame(c, angle)(local)


def clutter_polygons(rng: np.random.Generator, count: int, region: Callable[[], np.ndarray], size: float,
                      keep_out: np.ndarray | None, grow: float) -> list[np.ndarray]:
    """``count`` clutter polygons at points drawn by ``region``, inside the map and 1.5 from ``keep_out``."""
    out = []
    for _ in range(20 * count):
        if len(out) == count:
            break
        poly = _clutter_polygon(rng, region(), grow)
        if poly.min() < 0.5 or poly.max() > size - 0.5:
            continue
        if keep_out is not None and _polygon_distance(poly, keep_out) < TARGET_CLEARANCE + 0.5:
            continue
        out.append(poly)
    return out


def _polygon_distance(poly: np.ndarray, point: np.ndarray) -> float:
    """Distance from ``point`` to a simple polygon's boundary, negative inside."""
    d, _ = geometry.polygon_signed_distance(np.asarray(point, float)[None], np.asarray(poly, float))
    return float(d[0])
