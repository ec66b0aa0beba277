"""A world at a moment (``World.at``): the queries of one control step, moving obstacles placed once."""

from __future__ import annotations

import numpy as np
import pytest

from apf_physics.world import field as apf
from apf_physics import load_world
from apf_physics.control.shield import ACTIONS, move_clearance
from apf_physics.world.obstacles import CircleObstacle, PolygonObstacle, obstacle_at
from apf_physics.planners import make_planner
from apf_physics.experiments.rollout import rollout
from apf_physics.world.core import Moment


@pytest.fixture(scope="module")
def moving():
    world = load_world("moving_obstacles")
    assert world.moving
    return world


def points_of(world, count=400, seed=0):
    return np.random.default_rng(seed).uniform((0, 0), world.size, size=(count, 2))


def reference_clearance(world, points, t):
    """Clearance from every obstacle placed at ``t`` (and the crowd's discs) and the map's edge, one by one."""
    best = np.full(len(points), np.inf)
    for obstacle in world.obstacles:
        best = np.minimum(best, obstacle_at(obstacle, t).signed_distance(points)[0])
    for c in world.others:
        best = np.minimum(best, np.hypot(*(points - c).T) - world.robot_radius)
    return np.minimum(np.minimum(best, world.reach), world.edge_distance(points))


@pytest.mark.parametrize("t", [0, 7, 12.5, 300])
def test_a_moments_field_is_the_field_of_the_obstacles_where_they_are(moving, t):
    points = points_of(moving)
    moment = moving.at(t)
    placed = [obstacle_at(o, t) for o in moving.obstacles]
    np.testing.assert_allclose(moment.potential(points),
                               apf.potential(points, moving.targets, placed, moving.field), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(moment.gradient(points),
                               apf.gradient(points, moving.targets, placed, moving.field), rtol=1e-12, atol=1e-9)
    # the world's conveniences are the moment's
    np.testing.assert_array_equal(moving.potential(points, t), moment.potential(points))
    np.testing.assert_array_equal(moving.gradient(points, t), moment.gradient(points))


@pytest.mark.parametrize("t", [0, 7, 12.5])
def test_a_moments_clearance_and_obstacles(moving, t):
    points = points_of(moving, seed=1)
    moment = moving.at(t)
    np.testing.assert_allclose(moment.clearance(points), reference_clearance(moving, points, t), atol=1e-9)
    np.testing.assert_array_equal(moving.clearance(points, t), moment.clearance(points))
    np.testing.assert_array_equal(moment.obstacle_distance(points, static=True),
                                  moving.obstacle_distance(points, static=True))
    assert len(moment.obstacles) == len(moving.obstacles)
    for placed, obstacle in zip(moment.obstacles, moving.obstacles):
        if obstacle.motion is None:
            assert placed is obstacle
        else:
            np.testing.assert_allclose(placed.bounds[0], obstacle_at(obstacle, t).bounds[0])


def test_path_clearance_takes_the_obstacles_along_the_move(moving):
    """During a move of step t → t + 1, a sample a fraction s along it meets the obstacles at t + s."""
    rng = np.random.default_rng(2)
    a = points_of(moving, 50, seed=3)
    b = a + rng.uniform(-1, 1, size=a.shape)
    t = 9
    moment = moving.at(t)
    during = moment.path_clearance(a, b, 0.125)
    frozen = moment.path_clearance(a, b, 0.125, during=False)
    s = np.linspace(0, 1, 9)
    for k in range(len(a)):
        samples = a[k] + s[:, None] * (b[k] - a[k])
        along = min(moment.world.at(t + f).clearance(p[None], near=True)[0] for f, p in zip(s, samples))
        assert during[k] == pytest.approx(along, abs=1e-12)
        assert frozen[k] == pytest.approx(moment.clearance(samples, near=True).min(), abs=1e-12)
    np.testing.assert_array_equal(moving.path_clearance(a, b, 0.125, t=t), during)
    np.testing.assert_array_equal(moving.path_clearance(a, b, 0.125), moving.static_path_clearance(a, b, 0.125))
    # the shield's bound of the nine moves: the moment's along each move, the world's for the static obstacles
    room = move_clearance(moment, a)
    assert room.shape == (len(a), len(ACTIONS))
    assert np.all(room <= move_clearance(moving, a) + 1e-12)


def test_the_world_keeps_its_recent_moments(moving):
    assert moving.at(5) is moving.at(5.0)
    assert moving.at(5) is not moving.at(6)
    assert isinstance(moving.at(5), Moment) and moving.at(5).t == 5.0 and moving.at(5).world is moving
    other = moving.among(np.array([[10.0, 10.0]]))
    assert other.at(5) is not moving.at(5)          # a view with a crowd has moments of its own


def test_moving_obstacles_are_placed_once_per_moment(moving, monkeypatch):
    moved = []
    for cls in (PolygonObstacle, CircleObstacle):
        original = cls.moved
        monkeypatch.setattr(cls, "moved", lambda self, offset, original=original: moved.append(1) or original(self, offset))
    moment = Moment(moving, 3)
    points = points_of(moving, 50)
    for _ in range(3):
        moment.potential(points)
        moment.gradient(points)
        moment.obstacles
    assert len(moved) == len(moving.moving)


@pytest.mark.parametrize("name", ["gradient", "escape"])
def test_a_rollout_places_the_moving_obstacles_once_per_step(moving, monkeypatch, name):
    """Each control step's queries (potential, gradient, the trap rule's U) share one placement."""
    moved = []
    for cls in (PolygonObstacle, CircleObstacle):
        original = cls.moved
        monkeypatch.setattr(cls, "moved", lambda self, offset, original=original: moved.append(1) or original(self, offset))
    episodes = rollout(moving, make_planner(name), moving.starts, max_steps=60)
    steps = max(e.steps for e in episodes)
    assert 0 < len(moved) <= len(moving.moving) * (steps + 1)


def test_a_static_world_moment_places_nothing():
    world = load_world("fixed20")
    points = points_of(world)
    moment = world.at(42)
    assert moment.movers == () and moment.obstacles == world.obstacles
    np.testing.assert_array_equal(moment.potential(points), world.potential(points))
    np.testing.assert_array_equal(moment.clearance(points), world.clearance(points))


def test_a_crowds_discs_are_in_the_moment():
    world = load_world("fixed20")
    crowd = np.array([[10.0, 16.0]])
    view = world.among(crowd)
    moment = view.at(0)
    point = np.array([[10.0, 16.6]])
    assert moment.clearance(point)[0] == pytest.approx(0.6 - world.robot_radius)
    assert moment.potential(point)[0] > world.potential(point)[0]
    assert len(moment.obstacles) == len(world.obstacles) + 1
    # robots keep clear of one another by the right of way, not the clearance of moves (a world without movers)
    a, b = np.array([[10.0, 15.0]]), np.array([[10.0, 17.0]])
    np.testing.assert_array_equal(moment.path_clearance(a, b, 0.1), world.static_path_clearance(a, b, 0.1))
