"""The field against Model §1's formulas, the gradient against finite differences, the raster against potential()."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import apf_physics
from apf_physics.world import field as apf
from apf_physics import world_from_dict
from apf_physics.common.geometry import points_in_polygon
from conftest import simple_world_dict

WORLD = world_from_dict(simple_world_dict(
    field={"katt": 2, "krep": 20, "kstr": 8, "p0": 1.5, "ps": 8, "u_max": 100},
    obstacles=[{"polygon": [[5, 5], [8, 5], [8, 9], [6, 9]]},
               {"polygon": [[10, 10], [14, 10], [14, 13], [13, 13], [13, 11], [10, 11]]},  # concave L
               {"circle": {"center": [12, 4], "radius": 0.5}},
               {"circle": {"center": [3, 12], "radius": 0}}],
    targets=[[15, 15], [4, 16]]))


def reference_potential(world, p):
    """Model §1 written out term by term for one point, with brute-force boundary distances."""
    f = world.field
    u = 0.0
    for t in world.targets:
        d = np.hypot(*(p - t))
        u += f.katt / 2 * d * d
        if d <= f.ps:
            u -= f.kstr / 2 * (f.ps - d) ** 2
    for o in world.obstacles:
        if hasattr(o, "vertices"):
            v = o.vertices
            inside = points_in_polygon(p[None], v)[0]
            # dense sampling of the boundary
            d = min(np.min(np.hypot(*(np.linspace(a, b, 4001) - p).T)) for a, b in zip(v, np.roll(v, -1, axis=0)))
        else:
            r = np.hypot(*(p - o.center))
            inside = r < o.radius
            d = abs(r - o.radius)
        if inside or d <= 0:
            u += f.u_max
        elif d <= f.p0:
            u += min(f.krep / 2 * (1 / d - 1 / f.p0) ** 2, f.u_max)
    return u


@settings(max_examples=150, deadline=None)
@given(st.floats(0, 20), st.floats(0, 20))
def test_potential_matches_formula(x, y):
    p = np.array([x, y])
    expected = reference_potential(WORLD, p)
    got = WORLD.potential(p[None])[0]
    assert got == pytest.approx(expected, rel=2e-3, abs=2e-3)


def test_potential_near_and_inside_obstacles():
    rng = np.random.default_rng(1)
    pts = np.vstack([rng.uniform([4.5, 4.5], [8.5, 9.5], (200, 2)), rng.uniform([9.5, 9.5], [14.5, 13.5], (200, 2)),
                     rng.uniform([11, 3], [13, 5], (100, 2))])
    for p in pts:
        assert WORLD.potential(p[None])[0] == pytest.approx(reference_potential(WORLD, p), rel=2e-3, abs=2e-3)
    from apf_physics.world import field as apf

    inside = np.array([[6.5, 7.0], [12, 4], [13.5, 12]])
    f = WORLD.field
    att_bh = apf.attractive(inside, WORLD.targets, f.katt) + apf.black_hole(inside, WORLD.targets, f.kstr, f.ps)
    np.testing.assert_allclose(WORLD.potential(inside), att_bh + f.u_max)
    np.testing.assert_allclose(apf.repulsive_gradient(inside, WORLD.obstacles, f), 0.0)


def test_terms_by_hand():
    from apf_physics.world.field import black_hole, repulsive_term
    from apf_physics.world import field as apf

    t = np.array([[0.0, 0.0]])
    p = np.array([[3.0, 4.0]])
    assert apf.attractive(p, t, 2.0)[0] == pytest.approx(25.0)
    assert black_hole(p, t, 8.0, 8.0)[0] == pytest.approx(-4 * 9)
    assert black_hole(np.array([[9.0, 0.0]]), t, 8.0, 8.0)[0] == 0.0
    assert repulsive_term(np.array([0.25]), 20, 0.5, 100)[0] == pytest.approx(10 * (4 - 2) ** 2)
    assert repulsive_term(np.array([0.6]), 20, 0.5, 100)[0] == 0.0
    assert repulsive_term(np.array([0.01]), 20, 0.5, 100)[0] == 100
    assert repulsive_term(np.array([-0.3]), 20, 0.5, 100)[0] == 100


def test_several_targets_sum():
    one = world_from_dict(simple_world_dict(obstacles=[], targets=[[15, 15]]))
    two = world_from_dict(simple_world_dict(obstacles=[], targets=[[15, 15], [4, 4]]))
    three = world_from_dict(simple_world_dict(obstacles=[], targets=[[4, 4]]))
    p = np.random.default_rng(0).uniform(0, 20, (50, 2))
    np.testing.assert_allclose(two.potential(p), one.potential(p) + three.potential(p))


@settings(max_examples=200, deadline=None)
@given(st.floats(0.2, 19.8), st.floats(0.2, 19.8))
def test_gradient_matches_finite_differences(x, y):
    p = np.array([[x, y]])
    h = 1e-6
    u = WORLD.potential
    # Leave out points where a finite difference straddles a kink (the cap, p0, a polygon's medial
    # axis, e.g. (12, 12), as far from both inner edges of the L): there the distance's second
    # difference over ±1e-3 is of order 1e-3 rather than at most 1e-6 / distance.
    probe = np.array([[1e-3, 0.0], [0.0, 1e-3]])
    for o in WORLD.obstacles:
        dd, _ = o.signed_distance(p)
        assume(abs(dd[0] - WORLD.field.p0) >= 1e-3 and dd[0] >= 0.35)
        ahead, _ = o.signed_distance(p + probe)
        behind, _ = o.signed_distance(p - probe)
        assume(np.all(np.abs(ahead + behind - 2 * dd[0]) < 1e-5))
    numeric = np.array([(u(p + [[h, 0]]) - u(p - [[h, 0]]))[0], (u(p + [[0, h]]) - u(p - [[0, h]]))[0]]) / (2 * h)
    analytic = WORLD.gradient(p)[0]
    np.testing.assert_allclose(analytic, numeric, rtol=1e-4, atol=1e-3)


def test_gradient_check_leaves_out_the_medial_axis_of_the_l():
    """The point hypothesis once drew, (12, 12), is equidistant from two edges of the L: the check above skips it."""
    p = np.array([[12.0, 12.0]])
    d, _ = WORLD.obstacles[1].signed_distance(p)
    probe = np.array([[1e-3, 0.0], [0.0, 1e-3]])
    ahead, _ = WORLD.obstacles[1].signed_distance(p + probe)
    behind, _ = WORLD.obstacles[1].signed_distance(p - probe)
    assert d[0] == pytest.approx(1.0) and np.any(np.abs(ahead + behind - 2 * d[0]) >= 1e-5)


def test_raster_equals_potential_at_nodes_and_interpolates():
    raster = WORLD.raster(resolution=5)
    nodes = raster.grid.node_points()
    np.testing.assert_array_equal(raster.values.ravel(), WORLD.potential(nodes))
    assert raster.grid.shape == (101, 101)
    assert WORLD.raster(resolution=5) is raster  # cached
    np.testing.assert_allclose(raster.sample(nodes[::37]), WORLD.potential(nodes[::37]))
    # bilinear between nodes: exact for the quadratic attraction up to the grid's curvature error
    mid = np.array([[10.1, 2.1], [17.3, 18.9]])
    assert np.all(np.abs(raster.sample(mid) - WORLD.potential(mid)) < 0.5)


def test_grid_conversion_round_trips():
    from apf_physics.world.field import Grid

    grid = Grid.covering((-3, -2), (10, 8), 4)
    pts = np.random.default_rng(0).uniform(-3, 8, (20, 2))
    np.testing.assert_allclose(grid.to_world(grid.to_index(pts)), pts)
    assert grid.shape == (41, 53)


def test_atlas_samples_every_raster_as_raster_sample_does():
    # several rasters of different shapes in one image, sampled in one call: bilinear with float
    # weights (OpenCV >= 5; 4.x rounds positions to 1/32 of a cell, which this would catch)
    rasters = [WORLD.raster(4), apf.Raster(apf.Grid.covering((-3.0, -3.0), (9.0, 5.0), 4),
                                           np.random.default_rng(0).normal(0, 50, (33, 49)))]
    atlas = apf.Atlas(4)
    ids = [atlas.add(r) for r in rasters]
    rng = np.random.default_rng(1)
    points = np.vstack([rng.uniform(0.5, 19.5, (50, 2)), rng.uniform([-2, -2], [8, 4], (50, 2))])
    which = np.repeat(ids, 50)
    expected = np.concatenate([rasters[0].sample(points[:50]), rasters[1].sample(points[50:])])
    np.testing.assert_allclose(atlas.sample(points, which), expected, rtol=1e-5, atol=2e-3)
    offsets = np.array([[0.0, 0.0], [1.0, -1.0], [-0.5, 0.25]])
    windows = atlas.sample(points[:50], 0, offsets)
    np.testing.assert_allclose(windows, rasters[0].sample((points[:50, None] + offsets[None]).reshape(-1, 2))
                               .reshape(50, 3), rtol=1e-5, atol=2e-3)


# -- boundaries of the terms (each found by a mutant that no earlier test told apart) -------------------------

def test_a_capped_repulsive_term_has_no_slope_and_the_boundary_no_nan():
    f = WORLD.field
    d = np.array([0.05, 0.1, 0.2, 0.5, 1.0, 1.5, 2.0])
    u = apf.repulsive_term(d, f.krep, f.p0, f.u_max)
    capped = u == f.u_max
    assert capped.tolist() == [True, True, True, False, False, False, False]
    slope = apf.repulsive_term_slope(d, f.krep, f.p0, f.u_max)
    assert np.all(slope[capped] == 0) and np.all(slope[3:5] < 0) and slope[5] == 0 and slope[6] == 0
    # beside the circle of radius 0.5 at (12, 4): within the cap no repulsive gradient; on the rim (d = 0
    # exactly) none either, and a finite gradient
    params = apf.FieldParams(**f.as_dict())
    circle = [o for o in WORLD.obstacles if getattr(o, "radius", None) == 0.5]
    points = np.array([[12.6, 4.0], [12.5, 4.0], [12.0, 3.45]])
    with np.errstate(all="raise"):
        g = apf.repulsive_gradient(points, circle, params)
    assert np.all(np.isfinite(g)) and np.all(g == 0.0)
    assert np.all(np.isfinite(WORLD.gradient(points)))


def test_the_black_hole_has_no_gradient_at_its_target_and_computes_it_without_a_division_by_zero():
    targets = np.array([[15.0, 15.0], [4.0, 16.0]])
    with np.errstate(all="raise"):
        g = apf.black_hole_gradient(targets, targets, 8.0, 8.0)
    # at each target its own term is 0; only the other target's (farther than ps) would pull: none
    np.testing.assert_array_equal(g, np.zeros((2, 2)))


def test_a_shape_set_too_short_for_p0_is_refused_by_name():
    from apf_physics.world.spatial import ShapeSet

    short = ShapeSet(WORLD.obstacles, 0.5)
    with pytest.raises(ValueError, match=r"reach 0\.5 cannot give a field of range p0 = 1\.5"):
        apf.repulsive(np.array([[1.0, 1.0]]), short, WORLD.field)


def test_discs_repel_as_circle_obstacles_do():
    from apf_physics.world.obstacles import CircleObstacle

    params = WORLD.field
    centres = np.array([[6.0, 6.0], [7.5, 6.5], [14.0, 3.0]])
    radius = 0.25
    circles = [CircleObstacle(c, radius) for c in centres]
    rng = np.random.default_rng(3)
    points = np.vstack([rng.uniform(4.0, 16.0, (300, 2)), centres + [[0.3, 0.0], [0.0, -1.0], [2.0, 0.0]]])
    points = points[np.min(np.hypot(*(points[:, None] - centres[None]).transpose(2, 0, 1)), axis=1) > radius + 1e-3]
    np.testing.assert_allclose(apf.discs_repulsive(points, centres, radius, params),
                               apf.repulsive(points, circles, params), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(apf.discs_repulsive_gradient(points, centres, radius, params),
                               apf.repulsive_gradient(points, circles, params), rtol=1e-7, atol=1e-7)
    # a point at a disc's centre: capped, no gradient, no NaN
    with np.errstate(all="raise"):
        at_centre = apf.discs_repulsive_gradient(centres[:1], centres[:1], radius, params)
    assert apf.discs_repulsive(centres[:1], centres[:1], radius, params)[0] == params.u_max
    np.testing.assert_array_equal(at_centre, [[0.0, 0.0]])


def test_grid_nodes_of_an_origin_off_the_diagonal():
    grid = apf.Grid.covering((1.0, -2.0), (2.0, 0.0), 2)
    assert grid.shape == (5, 3)
    nodes = grid.node_points()
    np.testing.assert_array_equal(nodes[:3], [[1.0, -2.0], [1.5, -2.0], [2.0, -2.0]])
    np.testing.assert_array_equal(nodes[-1], [2.0, 0.0])
    np.testing.assert_array_equal(grid.to_index(np.array([[2, 0]])), [[2.0, 4.0]])     # integer points too
    np.testing.assert_array_equal(grid.to_world(np.array([[2, 4]])), [[2.0, 0.0]])


def test_raster_sample_clamps_points_outside_to_the_edge():
    grid = apf.Grid.covering((0.0, 0.0), (3.0, 2.0), 1)                  # 3 rows × 4 columns
    values = np.arange(12.0).reshape(3, 4) ** 2                           # not linear: no extrapolation fits it
    raster = apf.Raster(grid, values)
    inside = np.array([[0.0, 1.0], [3.0, 1.0], [1.5, 0.0], [1.5, 2.0], [0.0, 0.0], [3.0, 2.0]])
    outside = inside + np.array([[-2.0, 0.0], [2.5, 0.0], [0.0, -1.5], [0.0, 3.0], [-1.0, -1.0], [4.0, 4.0]])
    np.testing.assert_allclose(raster.sample(outside), raster.sample(inside))
    # the edge's own values: row 1 at its ends, rows 0 and 2 halfway between columns 1 and 2, two corners
    np.testing.assert_allclose(raster.sample(inside), [16.0, 49.0, 2.5, 90.5, 0.0, 121.0])


def test_point_samples_are_the_same_in_rows_as_in_a_column_and_beyond_remaps_row_limit():
    # Atlas.sample hands remap rows of SAMPLE_ROW points (a column of one point per row is slower,
    # and remap refuses 32,767 rows or more): the values are those of one point per row, exactly
    import cv2
    world = apf_physics.load_world("fixed20")
    atlas = apf.Atlas(4)
    i = atlas.add(world.raster(resolution=4))
    points = np.random.default_rng(0).random((40_001, 2)) * 22 - 1
    got = atlas.sample(points, i)
    index = (points * atlas.resolution + atlas._shift[i]).astype(np.float32)
    column = np.concatenate([cv2.remap(atlas._image, part.reshape(-1, 1, 2), None, cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_REPLICATE)[:, 0]
                             for part in np.array_split(index, 4)])
    assert got.shape == (40_001,) and np.array_equal(got, column)
