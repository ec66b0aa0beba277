"""The physics' exact swept distances (apf_physics.sim.swept): what decides who goes to pymunk, and
how robots alone in their slots are pushed out of what they overlap."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics import load_world
from apf_physics.world.obstacles import GridObstacle
from apf_physics.sim.physics import CONTACT_MARGIN, Physics
from apf_physics.sim.swept import SweptDistances, _segment_distance
from apf_physics.world.io.worldfile import world_from_dict

ROWS = ["............",     # row 0 is the lowest y
        "..####......",
        "..#.........",
        "..#....#....",
        ".......#....",
        "...#####....",
        "............",
        "..######..#.",
        "..#.........",
        "............"]


def _grid_world():
    """A 12 x 10 map of one grid obstacle (cells of 1), its cells as written above."""
    occupied = np.array([[c == "#" for c in row] for row in ROWS])
    base = world_from_dict({"size": [12, 10], "field": "thesis-general", "targets": [[11, 9]], "starts": []})
    return dataclasses.replace(base, obstacles=(GridObstacle(occupied, 1.0),))


def _worlds():
    mixed = world_from_dict({"size": [12, 12], "field": "thesis-general", "targets": [[11, 11]], "starts": [],
                             "obstacles": [{"circle": {"center": [4, 4], "radius": 1.2}},
                                           {"polygon": [[7, 2], [10, 2], [10, 3], [8, 3], [8, 6], [7, 6]]},
                                           {"circle": {"center": [3, 9], "radius": 0.0}},
                                           {"polygon": [[5, 8], [9, 8], [9, 8.05], [5, 8.05]]}]})
    return [load_world("fixed20"), mixed, _grid_world()]


def _sampled_distance(world, p, move, samples=2001):
    """Least clearance (distance to static obstacles and the edge) along each move, densely sampled."""
    t = np.linspace(0.0, 1.0, samples)
    path = p[:, None, :] + t[None, :, None] * move[:, None, :]
    return world.clearance(path.reshape(-1, 2)).reshape(len(p), samples).min(axis=1)


@pytest.mark.parametrize("which", [0, 1, 2])
def test_near_agrees_with_the_densely_sampled_clearance_along_the_move(which):
    world = _worlds()[which]
    rng = np.random.default_rng(which)
    n = 3000
    p = world.random_free_positions(rng, n)
    move = rng.uniform(-1.0, 1.0, (n, 2)) * rng.uniform(0.0, 2.0, (n, 1))
    distance = rng.uniform(0.0, 1.5, n)
    sweeps = SweptDistances()
    near = sweeps.near(np.full(n, sweeps.add(world)), p, move, distance)
    sampled = _sampled_distance(world, p, move)
    spacing = np.hypot(move[:, 0], move[:, 1]) / 2000
    # the sampled least is at most half a spacing above the true one
    assert np.all(near[sampled < distance - 1e-9])
    assert not np.any(near[sampled - spacing > distance + 1e-9])
    assert near.sum() > n / 10 and (~near).sum() > n / 10


def test_near_serves_robots_of_several_worlds_in_one_call():
    worlds = _worlds()
    sweeps = SweptDistances()
    numbers = [sweeps.add(w) for w in worlds]
    assert numbers == [0, 1, 2] and sweeps.add(worlds[1]) == 1
    rng = np.random.default_rng(7)
    which = rng.integers(0, 3, 900)
    p = np.empty((900, 2))
    for k, w in enumerate(worlds):
        p[which == k] = w.random_free_positions(rng, int((which == k).sum()))
    move = rng.uniform(-1.4, 1.4, (900, 2))
    distance = np.full(900, 0.5)
    together = sweeps.near(which, p, move, distance)
    for k, w in enumerate(worlds):
        alone = SweptDistances()
        mine = which == k
        np.testing.assert_array_equal(together[mine], alone.near(np.full(mine.sum(), alone.add(w)), p[mine],
                                                                 move[mine], distance[mine]))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-3, 3, allow_nan=False), min_size=8, max_size=8))
def test_segment_distance_is_the_least_over_both_segments(v):
    px, py, dx, dy, ax, ay, ex, ey = v
    s = np.linspace(0.0, 1.0, 401)
    a = np.column_stack([px + s * dx, py + s * dy])
    b = np.column_stack([ax + s * ex, ay + s * ey])
    sampled = np.min(np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]))
    exact = _segment_distance.py_func(px, py, dx, dy, ax, ay, ex, ey)
    assert exact <= sampled + 1e-9
    assert exact >= sampled - (math.hypot(dx, dy) + math.hypot(ex, ey)) / 400 - 1e-9
    assert _segment_distance(px, py, dx, dy, ax, ay, ex, ey) == exact   # compiled, to the bit


def test_the_physics_sends_to_pymunk_exactly_the_moves_that_come_near():
    world = _worlds()[1]
    rng = np.random.default_rng(3)
    n = 400
    physics = Physics([world] * n)
    p = world.random_free_positions(rng, n)
    physics.place(np.arange(n), p)
    p = physics.positions
    move = rng.uniform(-1.0, 1.0, (n, 2))
    needs = physics.needs_physics(move)
    sampled = _sampled_distance(world, p, move)
    keep_off = world.robot_radius + CONTACT_MARGIN
    assert np.all(needs[sampled < keep_off - 1e-9])
    assert not np.any(needs[sampled > keep_off + 1e-3])


def test_a_robot_pushed_into_a_corner_is_settled_against_both_walls():
    world = _grid_world()
    sweeps = SweptDistances()
    w = sweeps.add(world)
    r = world.robot_radius
    # the inner corner under row 7's wall (y from 7 to 8) and beside column 2's (x from 2 to 3, rows 7-8):
    # free for x > 3 and y < 7
    p = np.array([[3.0 + r - 0.08, 7.0 - r + 0.06]])
    out = sweeps.settle(np.array([w]), p, np.array([[4.5, 6.5]]), np.array([r]), np.array([0, 1]),
                        np.array([[1.0, 0.0, 0.08]]), 0.005, 6)
    assert world.clearance(out)[0] >= r - 0.005 - 1e-9
    assert np.hypot(*(out[0] - p[0])) < 0.2   # pushed out, not sent back


def test_a_robot_in_a_gap_narrower_than_itself_goes_back_where_it_started():
    # two walls 0.4 apart (the robot is 0.5 across): pushed out of one, it is in the other
    world = world_from_dict({"size": [10, 10], "field": "thesis-general", "targets": [[9, 9]], "starts": [],
                             "obstacles": [{"polygon": [[4, 4], [5, 4], [5, 6], [4, 6]]},
                                           {"polygon": [[5.4, 4], [6.4, 4], [6.4, 6], [5.4, 6]]}]})
    sweeps = SweptDistances()
    r = world.robot_radius
    assert 2 * r > 0.4
    before = np.array([[5.2, 3.0]])
    out = sweeps.settle(np.array([sweeps.add(world)]), np.array([[5.2, 5.0]]), before, np.array([r]),
                        np.array([0, 2]), np.array([[1.0, 0.0, r - 0.2], [-1.0, 0.0, r - 0.2]]), 0.005, 6)
    np.testing.assert_array_equal(out, before)
