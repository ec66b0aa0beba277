"""Observations among moving obstacles: the terms added where they are, exactly as before.

``Observer._add_near`` was rewritten for speed (the window points of each robot and shape
found with one ``nonzero``, the sums by one ``bincount`` without sorting). The implementation
it replaced is kept here as the reference: from random robots, steps, discs, polygons and
other robots' discs, both give the same observations to the last bit. That numpy version was
replaced in turn by compiled loops; it is kept here too (``numpy_add_near``, what
``tools/bench_moving.py`` times as "before"; ``tests/test_observation_kernel.py`` compares all three).
And ``Observer._add_moving`` as it was before the compiled loops read the world's motion table
where it is (``reference_add_moving``: each robot in each shape's frame, ``local``, computed by
numpy from ``World.moving_offsets``), which the observers of the reference use.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import apf_physics
from apf_physics.world import field as apf
from apf_physics.world.obstacles import CircleObstacle, Motion, PolygonObstacle
from apf_physics.sensing.observation import Observer, ObserverConfig
from apf_physics.world.core import MOTION_TABLE_STEPS, World  # noqa: F401 (World: the reference's annotations)
from apf_physics.world.io.worldfile import load_world


def reference_add_near(self, values: np.ndarray, mine: np.ndarray, local: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              centre: np.ndarray, radius: np.ndarray, shapes: list, world: World, lattice: bool) -> None:
    """Add, in place, the repulsive terms of M shapes to the windows of robots ``mine``.

    ``local`` (m, M, 2): each robot in each shape's frame; ``lo``, ``hi`` (M, 2): the shapes'
    boxes in their frames; discs by ``centre`` and ``radius`` (NaN radius: a polygon,
    measured by ``shapes[i].signed_distance``).
    """
    k, h = self.config.size, self.config.size // 2
    field = world.field
    reach = max(field.p0, world.robot_radius)   # p0, and the cap where the robot touches (Model §1)
    if lattice:   # window columns dx / rows dy within reach of each shape's box, clipped to the window
        first = np.clip(np.ceil(lo - reach - local), -h, h + 1).astype(np.intp)
        last = np.clip(np.floor(hi + reach - local), -h - 1, h).astype(np.intp)
    else:
        first = np.zeros(local.shape, np.intp)
        inside_box = np.all((local >= lo - reach) & (local <= hi + reach), axis=-1)
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
    term = apf.repulsive_term(apf.contact_distance(d, world.robot_radius), field.krep, field.p0, field.u_max)
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
    """Add, in place, the repulsive terms of M shapes to the windows of robots ``mine``: the rule in
    plain numpy, an independent reference for the compiled loops (and their baseline in
    ``tools/bench_moving.py``).

    ``local`` (m, M, 2): each robot in each shape's frame; ``lo``, ``hi`` (M, 2): the shapes'
    boxes in their frames; discs by ``centre`` and ``radius`` (NaN radius: a polygon,
    measured by ``shapes[i].signed_distance``).
    """
    k, h = self.config.size, self.config.size // 2
    field = world.field
    reach = max(field.p0, world.robot_radius)   # p0, and the cap where the robot touches (Model §1)
    if lattice:   # window columns dx / rows dy within reach of each shape's box, clipped to the window
        first = np.clip(np.ceil(lo - reach - local), -h, h + 1).astype(np.intp)
        last = np.clip(np.floor(hi + reach - local), -h - 1, h).astype(np.intp)
    else:
        first = np.zeros(local.shape, np.intp)
        inside_box = np.all((local >= lo - reach) & (local <= hi + reach), axis=-1)
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
    term = apf.repulsive_term(apf.contact_distance(d, world.robot_radius), field.krep, field.p0, field.u_max)
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


def reference_moving_shapes(world: World) -> tuple[list, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The world's moving obstacles where they are written: the shapes, their bounding boxes
    ``lo``, ``hi`` ``(M, 2)``, and the discs' centres ``(M, 2)`` and radii ``(M,)`` (NaN for polygons)."""
    shapes = [world.obstacles[i] for i in world.moving]
    boxes = [s.bounds for s in shapes]
    lo = np.array([lo for lo, _ in boxes], float).reshape(-1, 2)
    hi = np.array([hi for _, hi in boxes], float).reshape(-1, 2)
    centre = np.array([getattr(s, "center", (np.nan, np.nan)) for s in shapes], float).reshape(-1, 2)
    radius = np.array([getattr(s, "radius", np.nan) for s in shapes], float)
    return shapes, lo, hi, centre, radius


def reference_add_moving(self, values: np.ndarray, positions: np.ndarray, robots: np.ndarray, t, offsets: np.ndarray,
                         discs: np.ndarray | None = None, add_near=reference_add_near) -> np.ndarray:
    """``Observer._add_moving`` written plainly, each obstacle's offset computed from its motion
    rather than read from the world's motion table: an independent reference, adding the terms by
    ``add_near`` (``reference_add_near`` or ``numpy_add_near``)."""
    crowd = discs is not None and len(discs) > 0
    if not self._moving and not crowd:
        return values
    when = np.asarray(t, float)
    if when.ndim == 0:
        when = np.full(len(robots), float(when))
    worlds = self.world_of[robots]
    for w in np.unique(worlds).tolist():
        mine = np.flatnonzero(worlds == w)
        where, at = positions[mine], when[mine]
        world = self.worlds[w]
        if world.moving:
            shift = world.moving_offsets(at)                                        # (m, M, 2)
            shapes, lo, hi, centre, radius = reference_moving_shapes(world)
            local = np.repeat(where, len(shapes), axis=0).reshape(shift.shape) - shift
            add_near(self, values, mine, local, lo, hi, centre, radius, shapes, world, len(offsets) > 1)
        if crowd:
            centre = np.asarray(discs, float).reshape(-1, 2)
            r = np.full(len(centre), world.robot_radius)
            local = np.broadcast_to(where[:, None, :], (len(mine), len(centre), 2))
            add_near(self, values, mine, local, centre - world.robot_radius, centre + world.robot_radius,
                     centre, r, [None] * len(centre), world, len(offsets) > 1)
    return values


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
    old._add_moving = reference_add_moving.__get__(old)
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


@pytest.mark.parametrize("steps", ["whole", "fractional", "mixed", "early"])
@pytest.mark.parametrize("many_worlds", [False, True])
def test_table_rows_and_computed_offsets_as_before(worlds_dir, steps, many_worlds):
    """Whole steps are read from the world's motion table inside the compiled loop (rows past its
    first length grow it); a fractional step, or one before −1, has its offsets computed, one row
    per robot: both as the reference adds them, in the window, the previous channel (t − 1),
    ``potential_at`` and with other robots' discs, in one world or among several (one without
    moving obstacles)."""
    worlds = [crowded_world()]
    if many_worlds:
        worlds += [load_world(worlds_dir / "moving_obstacles.yaml"), apf_physics.load_world("fixed20")]
    robots = 40
    config = ObserverConfig(channels=("potential", "previous"), scale="log")
    new, old = Observer(config, robots, worlds), Observer(config, robots, worlds)
    old._add_moving = reference_add_moving.__get__(old)
    rng = np.random.default_rng([len(worlds), len(steps)])
    for trial in range(4):
        which = rng.integers(0, len(worlds), robots)
        positions = np.concatenate([worlds[i].random_free_positions(rng, 1) for i in which])
        for observer in (new, old):
            observer.reset(np.arange(robots), positions, [worlds[i] for i in which])
        t = {"whole": lambda: rng.integers(0, 400, robots).astype(float),
             "fractional": lambda: rng.uniform(0, 60, robots),
             "mixed": lambda: rng.integers(0, 60, robots) + rng.choice([0.0, 0.25], robots),
             "early": lambda: rng.integers(-4, 3, robots).astype(float)}[steps]()
        discs = positions[:4] + 0.6 if trial % 2 else None
        some = rng.permutation(robots)[:25]           # robots listed out of order
        np.testing.assert_array_equal(new.observe(positions[some], some, t[some], discs),
                                      old.observe(positions[some], some, t[some], discs))
        np.testing.assert_array_equal(new.potential_at(positions, t=t, discs=discs),
                                      old.potential_at(positions, t=t, discs=discs))
        one = some[:1]                                # one robot, one step for all
        np.testing.assert_array_equal(new.observe(positions[one], one, float(t[one[0]]), discs),
                                      old.observe(positions[one], one, float(t[one[0]]), discs))


def test_motion_table_rows_are_the_offsets():
    """``World.motion_table``: whole steps as rows of the table, others computed; ``moving_offsets`` reads it."""
    world = crowded_world()
    for t in (np.arange(-1.0, 600.0), np.array([3.5, 2.0]), np.array([-2.0]), np.zeros(0)):
        table, rows = world.motion_table(t)
        expected = np.stack([world.obstacles[i].motion.offset(t) for i in world.moving], axis=-2)
        np.testing.assert_array_equal(table[rows], expected)
        np.testing.assert_array_equal(world.moving_offsets(t), expected)
    assert world.motion_table(np.array([5.0, 7.0]))[0].shape[0] >= 600    # the grown table is kept
    # one step (read in Python) as in a batch (the compiled rule): rows of the table, or computed
    table = world.motion_table(np.array([5.0, 7.0]))[0]
    for step in (-1.0, -0.0, -0.5, 2.5, 7.0, 599.0, -2.0, np.nan, 2.0 ** 52, 2.0 ** 60):
        one, row = world.motion_table(np.array([step]))
        two, rows = world.motion_table(np.array([step, step]))
        assert (one is table) == (two is table) == (-1.0 <= step <= 599.0 and step == int(step))
        np.testing.assert_array_equal(one[row], two[rows][:1])
    np.testing.assert_array_equal(world.moving_offsets(3.0), world.moving_offsets(np.array([3.0]))[0])
    # a far whole step is computed, not read from a table grown to its size
    far = np.array([float(MOTION_TABLE_STEPS), 2.0 ** 40, 3.0])
    table, rows = world.motion_table(far)
    assert len(table) == 3
    np.testing.assert_array_equal(table[rows], np.stack([world.obstacles[i].motion.offset(far) for i in world.moving],
                                                        axis=-2))
    assert world.motion_table(np.array([5.0, 7.0]))[0].shape[0] <= 2 * MOTION_TABLE_STEPS


def test_one_robot_reads_what_it_reads_among_many(worlds_dir):
    """One robot's window (``Atlas.sample``'s one-window path, its shift as Python floats, one step's
    row of the motion table in Python) is its row of the windows of many, in any of several worlds."""
    worlds = [crowded_world(), apf_physics.load_world("fixed20"), load_world(worlds_dir / "moving_obstacles.yaml")]
    robots = 30
    observer = Observer(ObserverConfig(channels=("potential", "previous"), scale="log"), robots, worlds)
    rng = np.random.default_rng(5)
    which = rng.integers(0, len(worlds), robots)
    positions = np.concatenate([worlds[i].random_free_positions(rng, 1) for i in which])
    observer.reset(np.arange(robots), positions, [worlds[i] for i in which])
    t = np.concatenate([rng.integers(-1, 300, robots - 6).astype(float), [0.5, -1.5, -3.0, 2000.0, 7.25, 0.0]])
    everyone = observer.observe(positions, t=t)
    atlas = observer._atlas
    for r in range(robots):
        np.testing.assert_array_equal(observer.observe(positions[r], [r], t[r]), everyone[r:r + 1])
        np.testing.assert_array_equal(observer.observe(positions[r:r + 1], np.array([r]), t[r:r + 1]), everyone[r:r + 1])
        np.testing.assert_array_equal(atlas.sample(positions[r], int(which[r]), observer._offsets),
                                      atlas.sample(positions[r:r + 1], which[r:r + 1], observer._offsets))
        np.testing.assert_array_equal(atlas.sample(positions[r], int(which[r]), observer._offsets)[0],
                                      atlas.sample(positions, which, observer._offsets)[r])
    world = worlds[0]
    for step in t.tolist():
        table, rows = world.motion_table(np.array([step]))
        np.testing.assert_array_equal(table[rows], world.moving_offsets(np.array([step, step]))[:1])
