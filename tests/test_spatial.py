"""Distances through the bucket index and the grid search equal the exact ones within reach."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from apf_physics.world import field as apf
from apf_physics.world.field import FieldParams
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, PolygonObstacle
from apf_physics.world.spatial import LOOSE_AT_MOST, ShapeSet


def random_shapes(rng: np.random.Generator, count: int, size: float = 20.0):
    """Boxes, triangles, L-shapes (concave), big rooms and circles, overlapping at random."""
    shapes = []
    for _ in range(count):
        c = rng.uniform(0, size, 2)
        kind = rng.integers(5)
        if kind == 0:
            w, h = rng.uniform(0.1, 2.0, 2)
            shapes.append(PolygonObstacle(np.array([c, c + [w, 0], c + [w, h], c + [0, h]])))
        elif kind == 1:
            shapes.append(PolygonObstacle(np.array([c, c + [1.5, 0.2], c + [0.4, 1.1]])))
        elif kind == 2:   # concave L
            s = rng.uniform(0.5, 3.0)
            shapes.append(PolygonObstacle(c + s * np.array([[0, 0], [2, 0], [2, 0.5], [0.5, 0.5], [0.5, 2], [0, 2]])))
        elif kind == 3:   # a large block: points deep inside it are farther than reach from its edges
            s = rng.uniform(4.0, 9.0)
            shapes.append(PolygonObstacle(c + np.array([[0, 0], [s, 0], [s, s], [0, s]])))
        else:
            shapes.append(CircleObstacle(c, float(rng.choice([0.0, rng.uniform(0.1, 1.5)]))))
    return shapes


def brute_distance(shapes, points):
    return np.min([s.signed_distance(points)[0] for s in shapes], axis=0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(LOOSE_AT_MOST + 1, 60), reach=st.sampled_from([0.5, 2.0, 3.0]))
def test_index_distance_is_exact_within_reach(seed, count, reach):
    rng = np.random.default_rng(seed)
    shapes = random_shapes(rng, count)
    points = rng.uniform(-4, 28, (400, 2))
    got = ShapeSet(shapes, reach).distance(points)
    want = np.clip(brute_distance(shapes, points), -reach, reach)
    np.testing.assert_allclose(got, want, atol=1e-9)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 40))
def test_field_through_the_index_equals_the_sum_over_every_obstacle(seed, count):
    rng = np.random.default_rng(seed)
    shapes = random_shapes(rng, count)
    params = FieldParams(katt=1, krep=20, kstr=8, p0=3, ps=8, u_max=100)
    points = rng.uniform(-2, 24, (300, 2))
    want = np.zeros(len(points))
    want_grad = np.zeros((len(points), 2))
    for s in shapes:
        d, nearest = s.signed_distance(points)
        want += apf.repulsive_term(d, params.krep, params.p0, params.u_max)
        slope = apf.repulsive_term_slope(d, params.krep, params.p0, params.u_max)
        want_grad += (slope / np.where(d > 0, d, 1.0))[:, None] * (points - nearest)
    np.testing.assert_allclose(apf.repulsive(points, shapes, params), want, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(apf.repulsive_gradient(points, shapes, params), want_grad, rtol=1e-9, atol=1e-9)


def grid_brute(occupied: np.ndarray, cell: float, origin, points: np.ndarray) -> np.ndarray:
    """Signed distance to the union of occupied squares, from every square (and every free one inside)."""
    rows, cols = np.nonzero(occupied)
    lo = np.column_stack([cols, rows]) * cell + origin
    hi = lo + cell

    def to_boxes(lo, hi):
        dx = np.maximum(np.maximum(lo[None, :, 0] - points[:, None, 0], points[:, None, 0] - hi[None, :, 0]), 0)
        dy = np.maximum(np.maximum(lo[None, :, 1] - points[:, None, 1], points[:, None, 1] - hi[None, :, 1]), 0)
        return np.hypot(dx, dy).min(axis=1)

    outside = to_boxes(lo, hi) if len(lo) else np.full(len(points), np.inf)
    # inside: the distance to the nearest free square of the grid padded by one free ring
    padded = np.pad(occupied, 1, constant_values=False)
    frows, fcols = np.nonzero(~padded)
    flo = np.column_stack([fcols - 1, frows - 1]) * cell + origin
    inside = to_boxes(flo, flo + cell)
    return np.where(outside > 0, outside, -inside)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(1, 24), st.integers(1, 24)),
       density=st.floats(0.0, 0.9), cell=st.sampled_from([1.0, 0.25, 0.05]))
def test_grid_distance_is_exact(seed, shape, density, cell):
    rng = np.random.default_rng(seed)
    occupied = rng.random(shape) < density
    origin = np.array([0.5, -1.0]) * cell
    grid = GridObstacle(occupied, cell, tuple(origin))
    extent = np.array(shape[::-1]) * cell
    points = origin + rng.uniform(-0.3, 1.3, (300, 2)) * extent
    got, nearest = grid.signed_distance(points)
    want = grid_brute(occupied, cell, origin, points)
    if not occupied.any():
        assert np.all(np.isinf(want)) and np.all(got >= 0)
        return
    np.testing.assert_allclose(got, want, atol=1e-9)
    # the nearest point is on the boundary, at that distance
    np.testing.assert_allclose(np.hypot(*(points - nearest).T), np.abs(want), atol=1e-9)
    # within a reach, the same up to it
    reach = 3 * cell
    np.testing.assert_allclose(grid.signed_distance(points, reach)[0], np.clip(want, -reach, reach), atol=1e-9)


def test_two_boxes_side_by_side_repel_as_one_wall_in_a_grid():
    """Cut into two rectangles, a wall repels twice at the seam; as grid cells it is one obstacle."""
    params = FieldParams(katt=0, krep=20, kstr=0, p0=3, ps=8, u_max=100)
    halves = [PolygonObstacle(np.array([[0, 0], [2, 0], [2, 1], [0, 1]], float)),
              PolygonObstacle(np.array([[2, 0], [4, 0], [4, 1], [2, 1]], float))]
    grid = GridObstacle(np.ones((1, 4), bool), 1.0)
    whole = PolygonObstacle(np.array([[0, 0], [4, 0], [4, 1], [0, 1]], float))
    seam = np.array([[2.0, 1.5]])
    u_grid = apf.repulsive(seam, [grid], params)[0]
    assert u_grid == apf.repulsive(seam, [whole], params)[0]
    assert apf.repulsive(seam, halves, params)[0] == 2 * u_grid


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(LOOSE_AT_MOST + 1, 80), reach=st.sampled_from([0.5, 1.75, 3.0]))
def test_pruned_lists_give_the_same_least_distance(seed, count, reach):
    """The pruned bucket lists (a few candidates per point) lose no least distance, inside or out."""
    rng = np.random.default_rng(seed)
    shapes = random_shapes(rng, count)
    points = rng.uniform(-4, 28, (600, 2))
    shape_set = ShapeSet(shapes, reach)
    who, _, d, _ = shape_set.pairs(points)
    full = np.full(len(points), reach)
    np.minimum.at(full, who, d)
    np.testing.assert_allclose(shape_set.distance(points), full, atol=1e-9)
    pruned, _, _, _ = shape_set.pairs(points, nearest_only=True)
    assert len(pruned) <= len(who)
