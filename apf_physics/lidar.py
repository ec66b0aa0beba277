"""A range sensor: K beams cast from many robots at once against everything a robot can meet (issue 27).

A robot at pose ``(x, y, θ)`` casts :attr:`LidarConfig.beams` rays over its field of view and
reads, per beam, the distance from its **centre** to the first thing the ray meets, or
:attr:`LidarConfig.max_range` when it meets nothing that near:

- the world's static obstacles: polygons (their edges), discs, and an occupancy grid (the
  boundary of its occupied cells, cut into maximal straight runs,
  :func:`~apf_physics.geometry.grid_boundary`);
- the moving obstacles where their routes have them at step ``t`` (one step for all robots, or
  one per robot: the slots of a vector env are at different steps), and the world's crowd
  (:meth:`~apf_physics.world.World.among`);
- the map's edge (the rectangle ``[0, w] × [0, h]``);
- other robots: discs of the robot radius, given per robot (:func:`teammates` builds them from
  team labels, leaving each robot itself out).

A point obstacle (a disc of radius 0) is met only by a beam exactly through it: a beam has no
width. A robot whose centre is inside a disc reads 0 on every beam; one inside a polygon (it has
collided) does not see that polygon (only edges seen from outside are cast against).

Beams (:meth:`LidarConfig.angles`), relative to the heading, counter-clockwise: with a full
circle (360°), ``−π + 2πk/K`` (beam 0 straight back, beam ``K/2`` straight ahead); with a
narrower field of view, ``K`` beams evenly from ``−fov/2`` to ``+fov/2``, ends included.
Units: lengths in units, angles in radians (the field of view is given in degrees).

Everything is numpy, with no Python loop over robots or beams: each (robot, shape) pair is
turned into the beams within the angle the shape subtends from the robot, and only those
(robot, beam, shape) candidates are solved, exactly, the nearest hit of each beam kept; the
map's edge is solved for every beam in closed form. Robots are cast :data:`ROBOTS_PER_CAST` at
a time (bounding the temporaries). Each world's static segments and discs are built once and
kept with the world (:meth:`~apf_physics.world.World.cached`, one entry per world, shared by
the worlds of other targets on the same map); with many segments (a large map) each robot
casts only against the segments whose bounding box is within range of it.
Optional Gaussian noise (:attr:`LidarConfig.noise`) comes from a seeded generator; noisy ranges
are clipped to ``[0, max_range]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np

from apf_physics import geometry
from apf_physics.obstacles import CircleObstacle, GridObstacle, PolygonObstacle
from apf_physics.world import Moment, World

ROBOTS_PER_CAST = 2048
"""Robots cast at a time (bounds the temporaries)."""
CULL_ABOVE = 64
"""With more static segments than this, a robot casts only against those whose box is within range
(with fewer, testing the boxes costs more than it saves)."""


@dataclass(frozen=True)
class LidarConfig:
    """A range sensor's beams.

    Attributes:
        beams: Number of beams ``K``.
        fov: Field of view [degrees], ``0 < fov ≤ 360``, centred on the heading.
        max_range: Farthest reading [units]; a beam that meets nothing reads this.
        noise: Standard deviation of Gaussian noise added to each reading [units] (0: none).
    """

    beams: int = 64
    fov: float = 360.0
    max_range: float = 8.0
    noise: float = 0.0

    def __post_init__(self):
        if self.beams < 1:
            raise ValueError(f"lidar beams must be positive, got {self.beams}")
        if not 0 < self.fov <= 360:
            raise ValueError(f"lidar fov must be in (0, 360] degrees, got {self.fov}")
        if not self.max_range > 0:
            raise ValueError(f"lidar max_range must be positive, got {self.max_range}")
        if not self.noise >= 0:
            raise ValueError(f"lidar noise must be >= 0, got {self.noise}")

    def angles(self) -> np.ndarray:
        """(K,) beam angles relative to the heading [rad], counter-clockwise (module docstring)."""
        k = self.beams
        if self.fov >= 360:
            return -np.pi + 2 * np.pi * np.arange(k) / k
        half = np.deg2rad(self.fov) / 2
        return np.linspace(-half, half, k) if k > 1 else np.zeros(1)


class _Static(NamedTuple):
    """A world's static geometry as arrays: segments ``a → a + e`` and discs."""

    a: np.ndarray          # (S, 2)
    e: np.ndarray          # (S, 2)
    side: np.ndarray       # (S,) +1 a polygon's edge, 0 a grid's boundary (see _seen)
    lo: np.ndarray         # (S, 2) bounding boxes
    hi: np.ndarray
    centre: np.ndarray     # (C, 2)
    radius: np.ndarray     # (C,)


class _Moving(NamedTuple):
    """A world's moving obstacles where they are written (route offset 0), as arrays."""

    a: np.ndarray          # (Sm, 2) polygon edges
    e: np.ndarray
    seg_owner: np.ndarray  # (Sm,) index in World.moving
    centre: np.ndarray     # (Cm, 2)
    radius: np.ndarray     # (Cm,)
    disc_owner: np.ndarray  # (Cm,)


def _polygon_edges(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return vertices, np.roll(vertices, -1, axis=0) - vertices


def static_geometry(world: World) -> _Static:
    """The world's static obstacles as segments and discs (built once per world; the map's edge is cast on its own)."""
    def build() -> _Static:
        a_list, e_list, sides = [np.zeros((0, 2))], [np.zeros((0, 2))], [np.zeros(0)]
        centres, radii = [], []
        for obstacle in world.static_obstacles:
            if isinstance(obstacle, PolygonObstacle):
                a, e = _polygon_edges(obstacle.vertices)
                a_list.append(a)
                e_list.append(e)
                sides.append(np.ones(len(a)))
            elif isinstance(obstacle, CircleObstacle):
                centres.append(obstacle.center)
                radii.append(obstacle.radius)
            elif isinstance(obstacle, GridObstacle):
                ga, gb = geometry.grid_boundary(obstacle.occupied)
                origin = np.asarray(obstacle.origin, float)
                a_list.append(ga * obstacle.cell + origin)
                e_list.append((gb - ga) * obstacle.cell)
                sides.append(np.zeros(len(ga)))
        a, e = np.vstack(a_list).astype(float), np.vstack(e_list).astype(float)
        return _Static(a, e, np.concatenate(sides).astype(float), np.minimum(a, a + e), np.maximum(a, a + e),
                       np.asarray(centres, float).reshape(-1, 2), np.asarray(radii, float))
    return world.cached("lidar_static", build, static=True)


def moving_geometry(world: World) -> _Moving:
    """The world's moving obstacles at route offset 0 as segments and discs (built once per world)."""
    def build() -> _Moving:
        a_list, e_list, seg_owner, centres, radii, disc_owner = [], [], [], [], [], []
        for k, i in enumerate(world.moving):
            obstacle = world.obstacles[i]
            if isinstance(obstacle, PolygonObstacle):
                a, e = _polygon_edges(obstacle.vertices)
                a_list.append(a)
                e_list.append(e)
                seg_owner.extend([k] * len(a))
            else:
                centres.append(obstacle.center)
                radii.append(obstacle.radius)
                disc_owner.append(k)
        return _Moving(np.vstack(a_list) if a_list else np.zeros((0, 2)),
                       np.vstack(e_list) if e_list else np.zeros((0, 2)),
                       np.asarray(seg_owner, np.intp), np.asarray(centres, float).reshape(-1, 2),
                       np.asarray(radii, float), np.asarray(disc_owner, np.intp))
    return world.cached("lidar_moving", build)


# -- the ray casts ------------------------------------------------------------------------------
#
# Each (robot, shape) pair is first turned into the beams that can meet the shape: those whose
# angle lies within the angle the shape subtends from the robot (widened by a hair against
# rounding), so that a beam is tested only against the few shapes in its direction rather than
# against all of them. Every (pair, beam) candidate is then solved exactly, and the nearest hit
# of each beam kept (a scatter-min).

WIDEN = 1e-9
"""How far [beam spacings] a shape's angular interval is widened before picking the beams in it;
the exact test of each candidate decides (a beam through a corner is a candidate of both edges)."""


class _Beams:
    """The beams of N robots, worked in each robot's frame (x ahead, y left): the beams' directions
    are one table of K, the shapes are turned into the frames of the robots that see them."""

    def __init__(self, config: LidarConfig, theta: np.ndarray):
        self.k = config.beams
        self.full = config.fov >= 360
        self.first = -np.pi if self.full else -np.deg2rad(config.fov) / 2
        self.spacing = 2 * np.pi / self.k if self.full else (np.deg2rad(config.fov) / (self.k - 1) if self.k > 1 else 1.0)
        angles = config.angles()
        self.cos_beam, self.sin_beam = np.cos(angles), np.sin(angles)       # (K,)
        self.cos, self.sin = np.cos(theta), np.sin(theta)                   # (N,)

    def local(self, robot: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectors ``v`` (P, 2) in the frames of robots ``robot`` (P,): ``(x, y)``."""
        c, s = self.cos[robot], self.sin[robot]
        return c * v[:, 0] + s * v[:, 1], c * v[:, 1] - s * v[:, 0]

    def candidates(self, robot: np.ndarray, low: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every beam of ``robot[i]`` within the angles ``[low, low + width]`` of its frame
        (``0 ≤ width < 2π``): the pair's index, the beam's index ``k`` and its flat index ``robot·K + k``."""
        rel = (low - self.first + np.pi) % (2 * np.pi) - np.pi      # from the first beam, [-π, π)
        shifts = (0.0,) if self.full else (0.0, 2 * np.pi)
        pairs, beams = [], []
        for shift in shifts:
            x0 = (rel + shift) / self.spacing
            lo = np.ceil(x0 - WIDEN).astype(np.intp)
            hi = np.floor(x0 + width / self.spacing + WIDEN).astype(np.intp)
            if self.full:
                hi = np.minimum(hi, lo + self.k - 1)
            else:
                lo, hi = np.maximum(lo, 0), np.minimum(hi, self.k - 1)
            count = np.maximum(hi - lo + 1, 0)
            total = int(count.sum())
            if not total:
                continue
            pair = np.repeat(np.arange(len(robot)), count)
            k = np.arange(total) + np.repeat(lo - (np.cumsum(count) - count), count)
            pairs.append(pair)
            beams.append(k % self.k if self.full else k)
        if not pairs:
            empty = np.zeros(0, np.intp)
            return empty, empty, empty
        pair, k = (np.concatenate(pairs), np.concatenate(beams)) if len(pairs) > 1 else (pairs[0], beams[0])
        return pair, k, robot[pair] * self.k + k


def _cast_segments(beams: _Beams, out: np.ndarray, pos: np.ndarray, robot: np.ndarray, a: np.ndarray,
                   e: np.ndarray) -> None:
    """Lower ``out`` (N·K,) to the hits of each robot's beams on segments ``a → a + e`` (one per pair, (P, 2))."""
    if not len(robot):
        return
    wx, wy = beams.local(robot, a - pos[robot])            # the segment's start and direction in the robot's frame
    ex, ey = beams.local(robot, e)
    bx, by = wx + ex, wy + ey
    phi_a = np.arctan2(wy, wx)
    sweep = np.arctan2(wx * by - wy * bx, wx * bx + wy * by)
    pair, k, flat = beams.candidates(robot, np.where(sweep >= 0, phi_a, phi_a + sweep), np.abs(sweep))
    if not len(pair):
        return
    cx, cy = beams.cos_beam[k], beams.sin_beam[k]
    ex, ey, wx, wy = ex[pair], ey[pair], wx[pair], wy[pair]
    denom = cx * ey - cy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / denom
        t = (wx * ey - wy * ex) * inverse
        u = (wx * cy - wy * cx) * inverse
    ok = (u >= 0) & (u <= 1) & (t >= 0)                        # a parallel segment: inf or nan, never ok
    np.minimum.at(out, flat[ok], t[ok])


def _cast_discs(beams: _Beams, out: np.ndarray, pos: np.ndarray, robot: np.ndarray, centre: np.ndarray,
                radius: np.ndarray) -> None:
    """Lower ``out`` to the hits of each robot's beams on discs (one per pair); from inside a disc: 0."""
    if not len(robot):
        return
    fx, fy = beams.local(robot, pos[robot] - centre)        # the robot from the disc's centre, in its frame
    d = np.hypot(fx, fy)
    inside = d <= radius
    half = np.arcsin(np.clip(radius / np.where(d > 0, d, 1.0), 0.0, 1.0))
    towards = np.arctan2(-fy, -fx)
    low = np.where(inside, towards - np.pi, towards - half)
    width = np.where(inside, 2 * np.pi - 1e-12, 2 * half)
    pair, k, flat = beams.candidates(robot, low, width)
    if not len(pair):
        return
    fx, fy, r = fx[pair], fy[pair], radius[pair]
    b = fx * beams.cos_beam[k] + fy * beams.sin_beam[k]
    q = fx * fx + fy * fy - r * r
    disc = b * b - q
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    hit = np.where(q <= 0, 0.0, np.where((disc >= 0) & (t >= 0), t, np.inf))
    np.minimum.at(out, flat, hit)


def _edge_ranges(beams: _Beams, pos: np.ndarray, size: tuple[float, float]) -> np.ndarray:
    """(N, K) distance along each beam to the map's edge (the rectangle ``[0, w] × [0, h]``, seen from inside)."""
    cb, sb = beams.cos_beam[None, :], beams.sin_beam[None, :]
    c, s = beams.cos[:, None], beams.sin[:, None]
    dx, dy = c * cb - s * sb, s * cb + c * sb                            # the beams' directions in the world
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, (size[0] - pos[:, 0, None]) / dx, np.where(dx < 0, -pos[:, 0, None] / dx, np.inf))
        ty = np.where(dy > 0, (size[1] - pos[:, 1, None]) / dy, np.where(dy < 0, -pos[:, 1, None] / dy, np.inf))
    return np.maximum(np.minimum(tx, ty), 0.0)


def _seen(pos: np.ndarray, a: np.ndarray, e: np.ndarray, side: np.ndarray, lo: np.ndarray | None = None,
          hi: np.ndarray | None = None, reach: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """(robot, segment) pairs that can hold a beam's first hit.

    A polygon's edge seen from outside (``side`` +1: its outline is counter-clockwise, the
    inside on the edge's left), a grid's boundary from either side (0); with boxes ``lo``, ``hi``
    (S, 2), only segments whose box is within ``reach``.

    Args:
        pos: (N, 2) robot centres.
        a, e: segments ``a → a + e``: (S, 2) for all robots, or ``a`` (N, S, 2) per robot.
        side: (S,).
    """
    wx = pos[:, 0, None] - a[..., 0]                                      # (N, S)
    wy = pos[:, 1, None] - a[..., 1]
    cross = e[:, 0] * wy - e[:, 1] * wx                                   # > 0: the robot is left of the edge
    mask = (side == 0) | (side * cross < 0)
    if lo is not None:
        gx = np.maximum(np.maximum(lo[:, 0] - pos[:, 0, None], pos[:, 0, None] - hi[:, 0]), 0.0)
        gy = np.maximum(np.maximum(lo[:, 1] - pos[:, 1, None], pos[:, 1, None] - hi[:, 1]), 0.0)
        mask &= gx * gx + gy * gy <= reach * reach
    return np.nonzero(mask)


def _near_discs(pos: np.ndarray, centre: np.ndarray, radius: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """(robot, disc) pairs whose disc (centres (C, 2) or (N, C, 2)) reaches within ``reach`` of the robot."""
    gap = np.hypot(pos[:, 0, None] - centre[..., 0], pos[:, 1, None] - centre[..., 1]) - radius
    return np.nonzero(gap <= reach)


def teammates(positions: np.ndarray, team: np.ndarray) -> np.ndarray:
    """(N, D, 2) for each robot the centres of the other robots of its team (NaN-padded), for :func:`scan`'s ``others``.

    Args:
        positions: (N, 2) robot centres.
        team: (N,) labels: robots with the same label see each other (a formation's slot, a
            crowd); a robot never sees itself.
    """
    positions = np.asarray(positions, float).reshape(-1, 2)
    team = np.asarray(team).reshape(-1)
    n = len(positions)
    order = np.argsort(team, kind="stable")
    labels, first, size = np.unique(team[order], return_index=True, return_counts=True)
    d = int(size.max()) - 1 if n else 0
    out = np.full((n, max(d, 0), 2), np.nan)
    if d <= 0:
        return out
    group = np.searchsorted(labels, team)                         # each robot's team number
    rank = np.empty(n, np.intp)
    rank[order] = np.arange(n) - np.repeat(first, size)           # place within its team
    members = np.full((len(labels), d + 1), -1, np.intp)
    members[group, rank] = np.arange(n)
    # robot i's others: its team's members but itself
    cols = np.arange(d + 1)[None, :]
    keep = cols != rank[:, None]
    mates = members[group][keep].reshape(n, d)
    ok = mates >= 0
    out[ok] = positions[mates[ok]]
    return out


def _cast(world: World, poses: np.ndarray, config: LidarConfig, t: np.ndarray,
          others: np.ndarray | None) -> np.ndarray:
    """(n, K) ranges, without noise: :func:`scan` for a few robots."""
    n, k = len(poses), config.beams
    pos = poses[:, :2]
    beams = _Beams(config, poses[:, 2])
    out = np.minimum(_edge_ranges(beams, pos, world.size), float(config.max_range)).ravel()
    reach = config.max_range
    geo = static_geometry(world)
    if len(geo.a) > CULL_ABOVE:
        robot, shape = _seen(pos, geo.a, geo.e, geo.side, geo.lo, geo.hi, reach)
    else:
        robot, shape = _seen(pos, geo.a, geo.e, geo.side)
    _cast_segments(beams, out, pos, robot, geo.a[shape], geo.e[shape])
    if len(geo.radius):
        robot, shape = _near_discs(pos, geo.centre, geo.radius, reach)
        _cast_discs(beams, out, pos, robot, geo.centre[shape], geo.radius[shape])
    if world.moving:
        mov = moving_geometry(world)
        shift = np.broadcast_to(world.moving_offsets(t), (n, len(world.moving), 2))      # (n, M, 2)
        if len(mov.a):
            a = mov.a[None] + shift[:, mov.seg_owner]                                       # (n, Sm, 2)
            robot, shape = _seen(pos, a, mov.e, np.ones(len(mov.a)))
            _cast_segments(beams, out, pos, robot, a[robot, shape], mov.e[shape])
        if len(mov.centre):
            centre = mov.centre[None] + shift[:, mov.disc_owner]                          # (n, Cm, 2)
            robot, shape = _near_discs(pos, centre, mov.radius, reach)
            _cast_discs(beams, out, pos, robot, centre[robot, shape], mov.radius[shape])
    discs = []
    if len(world.crowd):
        discs.append(np.broadcast_to(world.crowd[None], (n,) + world.crowd.shape))
    if others is not None:
        discs.append(others)
    if discs:
        centre = np.concatenate(discs, axis=1)                                              # (n, D, 2)
        robot, shape = np.nonzero(~np.isnan(centre[..., 0]))
        _cast_discs(beams, out, pos, robot, centre[robot, shape], np.full(len(robot), world.robot_radius))
    return out.reshape(n, k)


def scan(where: World | Moment, poses: np.ndarray, config: LidarConfig = LidarConfig(),
         t: np.ndarray | float | None = None, others: np.ndarray | None = None,
         rng: np.random.Generator | None = None) -> np.ndarray:
    """(N, K) float ranges of the beams of robots at ``poses`` (N, 3) ``(x, y, θ)`` (module docstring).

    Args:
        where: A world, or the world at a step (:meth:`World.at`): its step is ``t``'s default.
        poses: (N, 3) robot centres and headings [units, rad].
        config: The beams.
        t: The control step the moving obstacles are placed at: one for all robots, or (N,)
            (default: the moment's step, else 0).
        others: (N, D, 2) centres of the other robots each robot sees (NaN rows: none), discs of
            the world's robot radius (:func:`teammates`).
        rng: Generator of the noise (required when ``config.noise > 0``).
    """
    world = where.world if isinstance(where, Moment) else where
    if t is None:
        t = where.t if isinstance(where, Moment) else 0.0
    poses = np.asarray(poses, float).reshape(-1, 3)
    n = len(poses)
    t = np.broadcast_to(np.asarray(t, float), (n,))
    others = None if others is None or not np.size(others) else np.asarray(others, float).reshape(n, -1, 2)
    best = np.empty((n, config.beams))
    for first in range(0, n, ROBOTS_PER_CAST):
        part = slice(first, min(first + ROBOTS_PER_CAST, n))
        best[part] = _cast(world, poses[part], config, t[part], None if others is None else others[part])
    ranges = best
    if config.noise > 0:
        if rng is None:
            raise ValueError("lidar noise needs a random generator (rng)")
        ranges = np.clip(ranges + rng.normal(0.0, config.noise, ranges.shape), 0.0, config.max_range)
    return ranges


class Lidar:
    """A range sensor with its own seeded noise generator: :func:`scan` with a config and an ``rng``.

    Args:
        config: The beams.
        seed: Seed of the noise generator (Gymnasium envs pass their reset seed).
    """

    def __init__(self, config: LidarConfig = LidarConfig(), seed: int | None = None):
        self.config = config
        self.rng = np.random.default_rng(seed)

    def seed(self, seed: int | None) -> None:
        """Restart the noise generator."""
        self.rng = np.random.default_rng(seed)

    def scan(self, where: World | Moment, poses: np.ndarray, t: np.ndarray | float | None = None,
             others: np.ndarray | None = None) -> np.ndarray:
        """(N, K) ranges: :func:`scan`."""
        return scan(where, poses, self.config, t, others, self.rng)

    def scan_worlds(self, worlds: Sequence[World], world_of: np.ndarray, poses: np.ndarray,
                    t: np.ndarray | float = 0.0, others: np.ndarray | None = None) -> np.ndarray:
        """(N, K) ranges of robots each in a world of its own (``worlds[world_of[n]]``), one cast per world."""
        poses = np.asarray(poses, float).reshape(-1, 3)
        world_of = np.asarray(world_of, np.intp).reshape(-1)
        t = np.broadcast_to(np.asarray(t, float), (len(poses),))
        out = np.empty((len(poses), self.config.beams))
        for w in np.unique(world_of).tolist():
            mine = np.flatnonzero(world_of == w)
            out[mine] = self.scan(worlds[w], poses[mine], t[mine], None if others is None else np.asarray(others)[mine])
        return out
