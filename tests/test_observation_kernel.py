"""The compiled loops of ``Observer._add_near`` against the numpy implementations they replaced.

``tests/test_moving_observation.py`` compares whole observations in real worlds; here the
terms are added to random windows by random shapes, many times over, so that every branch
meets the cases that could differ by a bit: points exactly ``p0`` from a disc or on its rim,
several shapes' terms summed at one point, values at ``u_wall`` (and its float32 rounding,
which may lie above it), windows of one point (the float64 values of ``potential_at``),
polygons among discs, robots listed out of order, several robots at one row of the offsets'
table. The compiled loops read each robot in each shape's frame as ``where[r] − table[steps[r], s]``;
the numpy implementations are given that ``local`` computed by numpy. ``==`` throughout. And
the memory channel's windows (``VisitMemory.window``, a compiled loop too) against its numpy version.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from apf_physics.sensing import observation
from apf_physics.world.field import FieldParams
from apf_physics.world.obstacles import PolygonObstacle
from apf_physics.sensing.observation import Observer, ObserverConfig, Repellers, VisitMemory
from test_moving_observation import numpy_add_near, reference_add_near

FIELDS = [FieldParams(katt=2.0, krep=20.0, kstr=8.0, p0=0.5, ps=8.0, u_max=100.0),
          FieldParams(katt=1.0, krep=3.7, kstr=8.0, p0=1.3, ps=8.0, u_max=25.0)]


def random_case(rng: np.random.Generator, size: int, lattice: bool, polygons: bool):
    """Robots and shapes of one random call of ``_add_near``: ``(values, mine, (where, table, steps),
    (local, lo, hi, centre, radius, shapes), world)``: the compiled loops' robots and offsets, and
    the numpy implementations' arguments, ``local = where[:, None] − table[steps]``."""
    field = FIELDS[int(rng.integers(len(FIELDS)))]
    u_wall = float(rng.choice([field.u_max * 3 + 0.1, 311.3, 1e3 / 3]))
    # the robot's size: none, small, one that touches beyond p0 (the cap where it touches: Model §1)
    radius_of_robot = float(rng.choice([0.0, 0.25, 0.8, field.p0 + 0.3]))
    world = SimpleNamespace(field=field, u_wall=u_wall, robot_radius=radius_of_robot)
    robots, count = int(rng.integers(1, 40)), int(rng.integers(1, 9))
    n = robots + int(rng.integers(0, 5))
    mine = rng.permutation(n)[:robots]
    # discs of varied radii, some centred on whole or half coordinates (points exactly on the rim
    # or exactly p0 from it), all near the robots, which stand in one place to crowd their windows
    radius = rng.choice([0.25, 0.5, 0.75, rng.uniform(0.1, 1.5)], count)
    centre = rng.uniform(-3, 3, (count, 2))
    snapped = rng.random(count) < 0.5
    centre[snapped] = np.round(centre[snapped] * 2) / 2
    shapes: list = [None] * count
    if polygons:
        for s in rng.choice(count, max(1, count // 3), replace=False).tolist():
            corner = centre[s] - rng.uniform(0, 1, 2)
            quad = corner + np.array([[0.0, 0.0], [rng.uniform(0.5, 2), 0.0],
                                      [rng.uniform(0.5, 2), rng.uniform(0.5, 2)], [0.0, rng.uniform(0.5, 2)]])
            shapes[s] = PolygonObstacle(quad)
            radius[s], centre[s] = np.nan, np.nan
    lo = np.array([s.bounds[0] if s is not None else c - r for s, c, r in zip(shapes, centre, radius)])
    hi = np.array([s.bounds[1] if s is not None else c + r for s, c, r in zip(shapes, centre, radius)])
    # robots, some at whole coordinates, and the shapes' offsets (some whole, some zero), in a
    # table of fewer rows than robots (rows shared) or of one row per robot
    where = rng.uniform(-4, 4, (robots, 2))
    whole = rng.random(robots) < 0.4
    where[whole] = np.round(where[whole])
    rows = int(rng.choice([1, max(1, robots // 3), robots]))
    table = rng.uniform(-1.5, 1.5, (rows, count, 2)) * (rng.random((rows, count, 1)) < 0.8)
    whole = rng.random((rows, count)) < 0.4
    table[whole] = np.round(table[whole])
    steps = rng.integers(0, rows, robots) if rows < robots else rng.permutation(robots)
    if not lattice:   # a single point: put half of them near a shape (each robot its own row of offsets)
        near = rng.random((robots, count)) < 0.5
        r, s = np.nonzero(near)
        aim = (lo + rng.uniform(-0.6, 0.6, (count, 2)) * (hi - lo + 2 * field.p0) + (hi - lo) / 2)[s]
        table = np.zeros((robots, count, 2)) if rows < robots else table
        steps = np.arange(robots) if rows < robots else steps
        table[steps[r], s] = where[r] - aim
    local = where[:, None, :] - table[steps]
    q = size * size if lattice else 1
    if lattice:
        values = rng.uniform(-50, u_wall, (n, q)).astype(np.float32)
        values[rng.random((n, q)) < 0.1] = np.float32(u_wall)      # may round above u_wall
    else:
        values = rng.uniform(-50, u_wall, (n, q))
        values[rng.random((n, q)) < 0.1] = u_wall
    return values, mine, (where, table, steps), (local, lo, hi, centre, radius, shapes), world


def add_compiled(observer: Observer, values, mine, robots, shaped, world, lattice: bool) -> None:
    """``observer._add_near`` with the arguments of :func:`random_case`."""
    _, lo, hi, centre, radius, shapes = shaped
    observer._add_near(values, mine, *robots, Repellers(shapes, lo, hi, centre, radius), world, lattice)


@pytest.mark.parametrize("polygons", [False, True])
@pytest.mark.parametrize("lattice", [True, False])
@pytest.mark.parametrize("size", [3, 11])
def test_terms_match_the_replaced_implementations(size, lattice, polygons):
    observer = Observer(ObserverConfig(size=size), 1)
    rng = np.random.default_rng([size, lattice, polygons])
    for trial in range(150):
        values, mine, robots, shaped, world = random_case(rng, size, lattice, polygons)
        new, old, before = values.copy(), values.copy(), values.copy()
        add_compiled(observer, new, mine, robots, shaped, world, lattice)
        reference_add_near(observer, old, mine, *shaped, world, lattice)
        numpy_add_near(observer, before, mine, *shaped, world, lattice)
        np.testing.assert_array_equal(new, old, err_msg=f"trial {trial}")
        np.testing.assert_array_equal(new, before, err_msg=f"trial {trial}")
        assert new.dtype == values.dtype


def test_many_points_at_once():
    """Thousands of robots among hundreds of discs: hypot and the term over ~10⁵ points, as numpy gives them."""
    observer = Observer(ObserverConfig(size=11), 1)
    rng = np.random.default_rng(7)
    world = SimpleNamespace(field=FIELDS[1], u_wall=250.0, robot_radius=0.3)
    robots, count = 3000, 40
    centre = rng.uniform(0, 30, (count, 2))
    radius = rng.uniform(0.1, 1.0, count)
    positions = rng.uniform(0, 30, (robots, 2))
    local = np.broadcast_to(positions[:, None, :], (robots, count, 2))    # as other robots' discs were given
    values = rng.uniform(-20, 200, (robots, 121)).astype(np.float32)
    new, old = values.copy(), values.copy()
    shaped = (local, centre - radius[:, None], centre + radius[:, None], centre, radius, [None] * count)
    # as they are given now: offsets of zero
    add_compiled(observer, new, np.arange(robots), (positions, np.zeros((1, count, 2)), np.zeros(robots, np.intp)),
                 shaped, world, True)
    reference_add_near(observer, old, np.arange(robots), *shaped, world, True)
    assert (new != values).sum() > 10_000
    np.testing.assert_array_equal(new, old)


def test_python_source_is_the_compiled_rule(monkeypatch):
    """The kernels' Python originals (what a reader reads) give what the compiled ones give."""
    observer = Observer(ObserverConfig(size=5), 1)
    rng = np.random.default_rng(3)
    for lattice in (True, False):
        values, *args = random_case(rng, 5, lattice, polygons=True)
        compiled = values.copy()
        add_compiled(observer, compiled, *args, lattice)
        with monkeypatch.context() as patch:
            for name in ("_window_span", "repulsive_term_at", "_polygon_points", "_add_terms"):
                patch.setattr(observation, name, getattr(observation, name).py_func)
            python = values.copy()
            add_compiled(observer, python, *args, lattice)
        np.testing.assert_array_equal(compiled, python)
    memory = VisitMemory(3, 5, 2)
    memory.reset(np.arange(3), np.array([[0.5, 0.5], [3.2, 1.5], [6.0, 6.9]]), [SimpleNamespace(size=(7, 7))] * 3)
    positions = np.array([[1.5, 0.5], [3.2, 2.5], [6.5, 6.9]])
    memory.visit(positions)
    compiled = memory.window(positions)
    with monkeypatch.context() as patch:
        patch.setattr(observation, "_memory_windows", observation._memory_windows.py_func)
        np.testing.assert_array_equal(memory.window(positions), compiled)


def numpy_memory_window(memory, positions: np.ndarray, robots: np.ndarray) -> np.ndarray:
    """``VisitMemory.window`` in plain numpy: an independent reference for its compiled loop."""
    c0, r0 = memory._cell(positions, robots)
    steps = np.arange(memory.size) - memory.size // 2
    dc = np.broadcast_to(steps[None, :], (memory.size, memory.size))
    dr = np.broadcast_to(-steps[:, None], (memory.size, memory.size))
    dims = memory.dims[robots]
    c = c0[:, None, None] + dc[None]
    r = r0[:, None, None] + dr[None]
    cols, rows = dims[:, 0, None, None], dims[:, 1, None, None]
    outside = (c < 0) | (c >= cols) | (r < 0) | (r >= rows)
    counts = memory.counts[robots[:, None, None], np.clip(c, 0, cols - 1), np.clip(r, 0, rows - 1)]
    values = np.minimum(counts, memory.cap).astype(np.float32) / np.float32(memory.cap)
    values[outside] = 1.0
    return values


@pytest.mark.parametrize("size,cap", [(11, 4), (5, 3), (1, 7)])
def test_memory_windows_match_the_numpy_version(size, cap):
    rng = np.random.default_rng([size, cap])
    memory = VisitMemory(60, size, cap)
    worlds = [SimpleNamespace(size=(float(rng.uniform(1, 30)), float(rng.uniform(1, 30)))) for _ in range(60)]
    memory.reset(np.arange(60), rng.uniform(0, 1, (60, 2)), worlds)
    memory.counts[:] = rng.integers(0, 2 * cap, memory.counts.shape)
    for _ in range(20):
        robots = rng.choice(60, int(rng.integers(1, 60)))
        positions = rng.uniform(-3, 33, (len(robots), 2))      # off the map too: clipped to its edge
        window = memory.window(positions, robots)
        assert window.dtype == np.float32 and window.shape == (len(robots), size, size)
        np.testing.assert_array_equal(window, numpy_memory_window(memory, positions, robots))


@pytest.mark.parametrize("field", FIELDS)
def test_points_at_the_edges_of_the_shortcut_read_as_by_hypot(field):
    """``_add_terms`` skips ``hypot`` where a point's squared distance from a disc's centre is a
    relative 1e-9 beyond ``(r + p0)²`` or within ``r²``: points at every distance around those
    (a few ulps to a relative 1e-6 either side, and on the rim and at ``p0`` exactly), in every
    direction, read as the numpy implementations read them."""
    observer = Observer(ObserverConfig(size=1), 1)
    world = SimpleNamespace(field=field, u_wall=field.u_max * 3 + 0.1, robot_radius=0.0)   # the shortcut's edges
    radius = np.array([0.25, 0.5, 1.0 / 3.0, 0.7])
    centre = np.array([[0.0, 0.0], [3.0, -2.0], [-1.5, 0.5], [0.1, 0.2]])
    shaped_for = []
    rel = np.concatenate([[0.0], np.ldexp(1.0, np.arange(-53, -48)), 10.0 ** np.arange(-12.0, -5.0)])
    rel = np.concatenate([-rel[::-1], rel[1:]])
    for s, r in enumerate(radius):
        for rho in np.concatenate([r * (1 + rel), (r + field.p0) * (1 + rel)]):
            for angle in (0.0, 0.3, np.pi / 4, 2.0, np.pi):
                shaped_for.append((s, centre[s] + rho * np.array([np.cos(angle), np.sin(angle)])))
    where = np.array([p for _, p in shaped_for])
    robots = len(where)
    # each robot measured against its own disc: the others' offsets put them far away
    table = np.full((robots, len(radius), 2), 1e3)
    for i, (s, _) in enumerate(shaped_for):
        table[i, s] = 0.0
    steps = np.arange(robots)
    local = where[:, None, :] - table[steps]
    lo, hi = centre - radius[:, None], centre + radius[:, None]
    shaped = (local, lo, hi, centre, radius, [None] * len(radius))
    values = np.random.default_rng(0).uniform(-50, 50, (robots, 1))
    values[::2] = 0.0       # where the faint terms just within p0 (~1e-20) show
    new, old, before = values.copy(), values.copy(), values.copy()
    add_compiled(observer, new, np.arange(robots), (where, table, steps), shaped, world, False)
    reference_add_near(observer, old, np.arange(robots), *shaped, world, False)
    numpy_add_near(observer, before, np.arange(robots), *shaped, world, False)
    assert (new != values).sum() > robots // 3
    np.testing.assert_array_equal(new, old)
    np.testing.assert_array_equal(new, before)
