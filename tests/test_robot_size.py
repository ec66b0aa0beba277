"""The field respects the robot's size (Model §1): the cap wherever the robot would touch; gradient descent is trapped, not in a wall."""

from __future__ import annotations

import numpy as np

from apf_physics import load_world
from apf_physics.cli.eval import random_starts
from apf_physics.world.field import FieldParams, gradient, potential, repulsive_term
from apf_physics.world.obstacles import CircleObstacle, PolygonObstacle
from apf_physics.planners import make_planner
from apf_physics.experiments.rollout import rollout
from apf_physics.world.io.worldfile import world_from_dict

PARAMS = FieldParams.preset("thesis-general")


def test_the_cap_where_the_robot_touches_and_the_thesis_term_where_it_is_clear():
    box = PolygonObstacle(np.array([[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0]]))
    disc = CircleObstacle(np.array([10.0, 5.0]), 1.0)
    target = np.array([[0.0, 0.0]])
    r = 0.8
    # distances from the box's right side and the disc's rim: inside, touching, just clear, farther
    gaps = np.array([-0.3, 0.0, 0.5, 0.8 - 1e-9, 0.8 + 1e-9, 1.5, 2.9, 3.5])
    for obstacle, points in ((box, np.column_stack([6.0 + gaps, np.full(len(gaps), 5.0)])),
                             (disc, np.column_stack([11.0 + gaps, np.full(len(gaps), 5.0)]))):
        attraction = potential(points, target, [], PARAMS)
        u = potential(points, target, [obstacle], PARAMS, r) - attraction
        expected = np.where(gaps <= r, PARAMS.u_max, repulsive_term(gaps, PARAMS.krep, PARAMS.p0, PARAMS.u_max))
        np.testing.assert_allclose(u, expected, rtol=1e-9, atol=1e-12)
        # no push where it touches (the cap is flat); the thesis's push where it is clear
        g = gradient(points, target, [obstacle], PARAMS, r) - gradient(points, target, [], PARAMS)
        assert np.all(g[gaps <= r] == 0) and np.all(g[(gaps > r) & (gaps < PARAMS.p0), 0] < 0)
    # a point robot (r = 0) is the thesis's field
    points = np.array([[6.5, 5.0], [6.1, 5.0]])
    np.testing.assert_allclose(potential(points, target, [box], PARAMS, 0.0) - potential(points, target, [], PARAMS),
                               repulsive_term(np.array([0.5, 0.1]), PARAMS.krep, PARAMS.p0, PARAMS.u_max))


def test_a_robot_larger_than_p0_still_reads_the_cap_where_it_touches():
    world = world_from_dict({"size": [20, 20], "robot": {"radius": 4.0}, "field": "thesis-general",
                             "obstacles": [{"circle": {"center": [10, 10], "radius": 1.0}}], "targets": [[2, 2]]})
    points = np.array([[10.0 + 1.0 + 3.5, 10.0], [10.0 + 1.0 + 4.5, 10.0]])      # 3.5 from the rim (> p0): touching
    u = world.potential(points) - potential(points, world.targets, [], world.field)
    np.testing.assert_allclose(u, [world.field.u_max, 0.0])


def test_window_observations_read_the_cap_where_the_robot_touches():
    from apf_physics.sensing.observation import Observer, ObserverConfig
    world = world_from_dict({"size": [20, 20], "robot": {"radius": 0.8}, "field": "thesis-general",
                             "obstacles": [{"circle": {"center": [10, 10], "radius": 1.0}}], "targets": [[2, 2]]})
    observer = Observer(ObserverConfig(size=5, resolution=4), 1, [world])
    where = np.array([[12.5, 10.0]])                      # window points at x = 10.5 ... 14.5 on the row y = 10
    observer.reset(np.arange(1), where, [world])
    window = observer.observe(where)[0, 0]
    row = window[2]                                       # the robot's row
    xs = 12.5 + np.arange(-2, 3)
    expected = world.potential(np.column_stack([xs, np.full(5, 10.0)]))
    inside = np.hypot(xs - 10.0, 0) <= 1.0
    np.testing.assert_allclose(row[~inside], expected[~inside], rtol=1e-5)


def test_gradient_descent_is_trapped_not_in_a_wall_on_a_metric_map():
    """worlds/ros_arena.yaml: a 0.2 m robot, 0.25 m steps (0.8 steps in radius), p0 = 3 steps;
    before the robot's size entered the field 31 of these 50 starts ended in a wall."""
    world = load_world("ros_arena")
    episodes = rollout(world, make_planner("gradient"), random_starts(world, 50, 1))
    outcomes = [e.outcome for e in episodes]
    assert outcomes.count("collision") == 0
    assert outcomes.count("reached") >= 10 and outcomes.count("trapped") >= 10
