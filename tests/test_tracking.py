"""Tracking (apf_physics.control.tracking): unicycle robots driving holonomic plans, geometrically (no physics)."""

from __future__ import annotations

import functools
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics.control.formation import formation_spec, initial_followers
from apf_physics.world.kinematics import UnicycleLimits, arc_points, integrate
from apf_physics.planners.astar import AStarPlanner
from apf_physics.control.tracking import (PathFollower, UnicycleFollowers, cross_track_error, point_at, pursue, slot_points,
                                  track_moves)
from apf_physics.world.core import FormationSpec
from apf_physics.world.io.worldfile import load_world

from conftest import WORLDS

SUBSTEPS = 16
"""Points per step at which the swept arcs are checked."""


@functools.lru_cache(maxsize=None)
def fixed20():
    return load_world(WORLDS / "fixed20.yaml")


def unit_move_paths(world, starts, steps=60) -> np.ndarray:
    """(N, steps + 1, 2) the holonomic A* planner's positions, a move (at most one unit per axis) per step."""
    planner = AStarPlanner()
    planner.reset(world, starts)
    where = [np.asarray(starts, float)]
    for _ in range(steps):
        where.append(where[-1] + planner.act(where[-1], np.ones(len(starts), bool)))
    return np.stack(where, axis=1)


def test_unicycles_follow_unit_move_paths_around_fixed20():
    """Every start of fixed20: the unicycle ends on the path's end (within the target's tolerance),
    its swept arcs stay within 0.25 of the path and never touch an obstacle."""
    world = fixed20()
    paths = unit_move_paths(world, world.starts)
    assert np.all(np.hypot(*(paths[:, -1] - world.targets[0]).T) <= world.goal_tolerance)
    n = len(paths)
    state = np.column_stack([world.starts, np.zeros((n, 3))])          # all facing +x, standing
    follower = PathFollower(paths)
    worst, least = np.zeros(n), np.full(n, np.inf)
    for _ in range(150):
        v, omega = follower.commands(state)
        lim = follower.limits
        assert np.all((v <= lim.max_speed + 1e-12) & (v >= -lim.max_reverse - 1e-12))
        assert np.all(np.abs(omega) <= lim.max_turn_rate + 1e-12)
        swept = arc_points(state, v, omega, SUBSTEPS)                                   # (N, S + 1, 2)
        off = np.stack([cross_track_error(swept[:, j], paths) for j in range(SUBSTEPS + 1)], axis=1)
        worst = np.maximum(worst, off.max(axis=1))
        least = np.minimum(least, world.clearance(swept.reshape(-1, 2)).reshape(n, -1).min(axis=1))
        state = integrate(state, v, omega)
        if follower.done(state, 1e-9).all():
            break
    assert follower.done(state, 1e-9).all()
    assert np.all(np.hypot(*(state[:, :2] - world.targets[0]).T) <= world.goal_tolerance)
    assert worst.max() <= 0.25, worst.max()
    assert least.min() >= world.robot_radius, least.min()


def test_a_replanning_planner_through_track_moves():
    """A holonomic planner deciding a move per step from where the unicycle is: it still arrives."""
    world = fixed20()
    starts = world.starts[::4]
    planner = AStarPlanner()
    planner.reset(world, starts)
    state = np.column_stack([starts, np.zeros((len(starts), 3))])
    for _ in range(120):
        moves = planner.act(state[:, :2], np.ones(len(starts), bool))
        v, omega = track_moves(state, moves)
        state = integrate(state, v, omega)
    assert np.all(np.hypot(*(state[:, :2] - world.targets[0]).T) <= world.goal_tolerance)


def test_pursuit_cases():
    lim = UnicycleLimits()
    state = np.zeros((4, 5))
    waypoints = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [-1.0, 0.0]])
    v, omega = pursue(state, waypoints, lim)
    np.testing.assert_allclose(v, [1.0, 0.0, 0.0, 0.0])                   # ahead; beside: turn first; here; behind
    np.testing.assert_allclose(omega, [0.0, math.pi / 2, 0.0, lim.max_turn_rate])
    # a waypoint within reach ahead is driven onto exactly, along the arc through it
    state = np.array([[2.0, 3.0, 0.4, 0.5, 0.0]])
    goal = state[:, :2] + 0.8 * np.array([[math.cos(0.7), math.sin(0.7)]])
    v, omega = pursue(state, goal, lim)
    np.testing.assert_allclose(integrate(state, v, omega)[:, :2], goal, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(th=st.floats(-4, 4), v0=st.floats(-0.5, 1), w0=st.floats(-1.5, 1.5), gx=st.floats(-5, 5), gy=st.floats(-5, 5),
       accel=st.floats(0.05, 2), turn_accel=st.floats(0.05, 4))
def test_pursuit_keeps_the_limits(th, v0, w0, gx, gy, accel, turn_accel):
    lim = UnicycleLimits(max_accel=accel, max_turn_accel=turn_accel)
    state = np.array([[0.0, 0.0, th, v0, w0]])
    v, omega = pursue(state, np.array([[gx, gy]]), lim)
    assert -lim.max_reverse - 1e-12 <= v[0] <= lim.max_speed + 1e-12
    assert abs(omega[0]) <= lim.max_turn_rate + 1e-12
    assert abs(v[0] - v0) <= accel + 1e-12 or v[0] in (-lim.max_reverse, lim.max_speed)
    assert abs(omega[0] - w0) <= turn_accel + 1e-12 or abs(omega[0]) == lim.max_turn_rate


def test_path_points():
    paths = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [1.0, 2.0]]])
    np.testing.assert_allclose(point_at(paths, np.array([2.0])), [[1.0, 1.0]])
    np.testing.assert_allclose(point_at(paths, np.array([9.0])), [[1.0, 2.0]])
    np.testing.assert_allclose(cross_track_error(np.array([[0.5, 0.5]]), paths), [0.5])


def test_slots_follow_the_leaders_heading():
    leader = np.array([[5.0, 5.0, 0.0], [5.0, 5.0, math.pi / 2]])
    slots = slot_points(leader, np.array([[1.0, 0.0], [1.0, 1.0]]))
    np.testing.assert_allclose(slots[0], [[4.0, 5.0], [4.0, 6.0]], atol=1e-12)
    np.testing.assert_allclose(slots[1], [[5.0, 4.0], [4.0, 4.0]], atol=1e-12)


def test_a_formation_of_unicycles_keeps_its_links():
    """The leader follows its A* path; two followers in a line track the thesis's rule's waypoints:
    every link stays within communication range and no two robots ever overlap."""
    world = fixed20()
    spec = formation_spec(world)
    leader_start = np.array([3.0, 3.0])
    robots = np.vstack([leader_start, initial_followers(world, spec, leader_start)])
    state = np.column_stack([robots, np.zeros((len(robots), 3))])
    path = unit_move_paths(world, leader_start[None], steps=40)
    leader = PathFollower(path)
    followers = UnicycleFollowers(world, spec)
    followers.reset(state)
    r = world.robot_radius
    for _ in range(90):
        lv, lw = leader.commands(state[:1], followers.leader_cap(state))
        v, omega = followers.drive(state, lv[0], lw[0])
        swept = arc_points(state, v, omega, SUBSTEPS)                        # (3, S + 1, 2)
        gaps = np.hypot(*(swept[:, None] - swept[None, :]).transpose(3, 0, 1, 2))
        assert gaps[~np.eye(len(robots), dtype=bool)].min() >= 2 * r
        state = integrate(state, v, omega)
        links = np.hypot(*(state[1:, :2] - state[[0, 1], :2]).T)
        assert links.max() <= spec.comm_range
    assert np.hypot(*(state[0, :2] - world.targets[0])) <= world.goal_tolerance
    assert isinstance(spec, FormationSpec)
