"""Observations among moving obstacles: the terms added where they are, exactly as before.

``Observer._add_near`` was rewritten for speed (the window points of each robot and shape
found with one ``nonzero``, the sums by one ``bincount`` without sorting). The implementation
it replaced is kept here as the reference: from random robots, steps, discs, polygons and
other robots' discs, both give the same observations to the last bit. That numpy version was
replaced in turn by compiled loops; it is kept here too (``numpy_add_near``, what
``tools/bench_moving.py`` times as "before"; ``tests/test_observation_kernel.py`` compares all three).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import apf_physics
from apf_physics import field as apf
from apf_physics.obstacles import CircleObstacle, Motion, PolygonObstacle
from apf_physics.observation import Observer, ObserverConfig
from apf_physics.world import World  # noqa: F401 (the reference's annotations)
from apf_physics.worldfile import load_world


def reference_add_near(self, values: np.ndarray, mine: np.ndarray, local: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              centre: np.ndarray, radius: np.ndarray, shapes: list, world: World, lattice: bool) -> None:
    """Add, in place, the repulsive terms of M shapes to the windows of robots ``mine``.

    ``local`` (m, M, 2): each robot in each shape's frame; ``lo``, ``hi`` (M, 2): the shapes'
    boxes in their frames; discs by ``centre`` and ``radius`` (NaN radius: a polygon,
    measured by ``shapes[i].signed_distance``).
    """
    k, h = self.config.size, self.config.size // 2
    field = world.field
    if lattice:   # window columns dx / rows dy within p0 of each shape's box, clipped to the window
        first = np.clip(np.ceil(lo - field.p0 - local), -h, h + 1).astype(np.intp)
        last = np.clip(np.floor(hi + field.p0 - local), -h - 1, h).astype(np.intp)
    else:
        first = np.zeros(local.shape, np.intp)
        inside_box = np.all((local >= lo - field.p0) & (local <= hi + field.p0), axis=-1)
        last = np.where(inside_box[..., None], first, -1)
    robot, shape = np.nonzero((first[..., 0] <= last[..., 0]) & (first[..., 1] <= last[..., 1]))
    if not len(robot):
        return
    first, last, base = first[robot, shape], last[robot, shape], local[robot, shape]
    span = (last - first).max(axis=0) + 1
    a, b = np.indices((int(span[0]), int(span[1]))).reshape(2, 1, -1)
    dx = first[:, None, 0] + a                                                      # (pairs, S)
    dy = first[:, None, 1] + b
    valid = (dx <= last[:, None, 0]) & (dy <= last[:, None, 1])
    px, py = base[:, None, 0] + dx, base[:, None, 1] + dy                           # in the shape's frame
    # discs all at once; polygons one by one
    d = np.hypot(px - centre[shape, 0, None], py - centre[shape, 1, None]) - radius[shape, None]
    polygon = np.isnan(radius[shape])
    for index in (np.unique(shape[polygon]).tolist() if polygon.any() else ()):
        pairs = shape == index
        dist, _ = shapes[index].signed_distance(np.stack([px[pairs], py[pairs]], -1).reshape(-1, 2))
        d[pairs] = dist.reshape(-1, dx.shape[1])
    d = d[valid]
    term = apf.repulsive_term(d, field.krep, field.p0, field.u_max)
    flat = (h - dy) * k + (dx + h) if lattice else np.zeros_like(dx)                # window point [h - dy, h + dx]
    q = values.shape[1]
    cell = (mine[robot][:, None] * q + flat)[valid]        # index into values as one (n·Q,) row
    cells, at = np.unique(cell, return_inverse=True)
    row, col = np.divmod(cells, q)
    # u_wall stays the highest reading: points inside read it, none above it
    values[row, col] = np.minimum(values[row, col] + np.bincount(at, weights=term), world.u_wall)
    inside = d <= 0
    if inside.any():
        row, col = np.divmod(cell[inside], q)
        values[row, col] = world.u_wall


def numpy_add_near(self, values: np.ndarray, mine: np.ndarray, local: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   centre: np.ndarray, radius: np.ndarray, shapes: list, world: World, lattice: bool) -> None:
    """Add, in place, the repulsive terms of M shapes to the windows of robots ``mine`` (numpy: the
    implementation of 2026-11-25 that the compiled loops replaced, timed by ``tools/bench_moving.py``).

    ``local`` (m, M, 2): each robot in each shape's frame; ``lo``, ``hi`` (M, 2): the shapes'
    boxes in their frames; discs by ``centre`` and ``radius`` (NaN radius: a polygon,
    measured by ``shapes[i].signed_distance``).
    """
    k, h = self.config.size, self.config.size // 2
    field = world.field
    if lattice:   # window columns dx / rows dy within p0 of each shape's box, clipped to the window
        first = np.clip(np.ceil(lo - field.p0 - local), -h, h + 1).astype(np.intp)
        last = np.clip(np.floor(hi + field.p0 - local), -h - 1, h).astype(np.intp)
    else:
        first = np.zeros(local.shape, np.intp)
        inside_box = np.all((local >= lo - field.p0) & (local <= hi + field.p0), axis=-1)
        last = np.where(inside_box[..., None], first, -1)
    robot, shape = np.nonzero((first[..., 0] <= last[..., 0]) & (first[..., 1] <= last[..., 1]))
    if not len(robot):
        return
    first, last, base = first[robot, shape], last[robot, shape], local[robot, shape]
    span = (last - first).max(axis=0) + 1
    a, b = np.indices((int(span[0]), int(span[1]))).reshape(2, -1)
    # the window points of each (robot, shape) pair within its box: pair, and place in the box
    pair, at = np.nonzero((first[:, None, 0] + a <= last[:, None, 0]) & (first[:, None, 1] + b <= last[:, None, 1]))
    dx, dy = first[pair, 0] + a[at], first[pair, 1] + b[at]
    px, py = base[pair, 0] + dx, base[pair, 1] + dy                                 # in the shape's frame
    shape = shape[pair]
    # discs all at once; polygons one by one
    d = np.hypot(px - centre[shape, 0], py - centre[shape, 1]) - radius[shape]
    polygon = np.isnan(radius[shape])
    for index in (np.unique(shape[polygon]).tolist() if polygon.any() else ()):
        mine_ = shape == index
        d[mine_], _ = shapes[index].signed_distance(np.stack([px[mine_], py[mine_]], -1))
    term = apf.repulsive_term(d, field.krep, field.p0, field.u_max)
    n, q = values.shape
    cell = mine[robot[pair]] * q + ((h - dy) * k + (dx + h) if lattice else 0)    # window point [h - dy, h + dx]
    # each point's terms summed in the order above (bincount adds in input order), then added to
    # U there; u_wall stays the highest reading: points inside read it, none above it
    added = np.bincount(cell, weights=term, minlength=n * q)
    hit = np.zeros(n * q, bool)
    hit[cell] = True
    assert values.flags.c_contiguous   # so that flat is a view of it
    flat = values.reshape(-1)
    flat[hit] = np.minimum(flat[hit] + added[hit], world.u_wall)
    inside = d <= 0
    if inside.any():
        flat[cell[inside]] = world.u_wall


def crowded_world():
    """fixed20 with 8 moving discs and 2 moving polygons."""
    base = apf_physics.load_world("fixed20")
    rng = np.random.default_rng(0)
    extra = []
    for k in range(8):
        centre = np.array([2.0 + 2.0 * k, rng.uniform(3, 6)])
        extra.append(CircleObstacle(centre, 0.5, Motion(np.array([[0.0, 10.0]]), float(rng.uniform(0.15, 0.6)),
                                                        phase=float(rng.uniform(0, 10)))))
    for x in (4.0, 12.0):
        square = np.array([[x, 8.0], [x + 1.0, 8.0], [x + 1.0, 9.2], [x, 8.7]])
        extra.append(PolygonObstacle(square, Motion(np.array([[3.0, 0.0]]), 0.3)))
    return dataclasses.replace(base, obstacles=base.obstacles + tuple(extra))


@pytest.mark.parametrize("scale,channels", [("raw", ("potential",)), ("log", ("potential", "previous"))])
@pytest.mark.parametrize("robots", [1, 7, 120])
def test_moving_terms_are_added_as_before(worlds_dir, scale, channels, robots):
    worlds = [crowded_world(), load_world(worlds_dir / "moving_obstacles.yaml")]
    config = ObserverConfig(channels=channels, scale=scale)
    new = Observer(config, robots, worlds)
    old = Observer(config, robots, worlds)
    old._add_near = reference_add_near.__get__(old)
    rng = np.random.default_rng(robots)
    for trial in range(6):
        which = rng.integers(0, 2, robots)
        positions = np.concatenate([w.random_free_positions(rng, 1) for w in [worlds[i] for i in which]])
        for observer in (new, old):
            observer.reset(np.arange(robots), positions, [worlds[i] for i in which])
        t = rng.integers(0, 60, robots).astype(float) if trial % 2 else float(rng.integers(0, 60))
        discs = positions[:3] + 0.7 if trial == 5 else None
        np.testing.assert_array_equal(new.observe(positions, t=t, discs=discs),
                                      old.observe(positions, t=t, discs=discs))
        np.testing.assert_array_equal(new.potential_at(positions, t=t, discs=discs),
                                      old.potential_at(positions, t=t, discs=discs))
