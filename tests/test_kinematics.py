"""Unicycle kinematics (apf_physics.world.kinematics): exact arcs, substep velocities, limits, action mappings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics.control.shield import ACTIONS
from apf_physics.sim.physics import substeps_for
from apf_physics.world.kinematics import (UNICYCLE_ACTION_NAMES, UNICYCLE_ACTIONS, UnicycleLimits, arc_points,
                                    distance_bearing, holonomic_from_unit, holonomic_to_unit, integrate,
                                    substep_velocities, to_robot_frame, wrap_angle)

finite = st.floats(-10, 10, allow_nan=False)
turns = st.one_of(st.floats(-3, 3), st.sampled_from([0.0, 1e-12, -1e-9, 1e-7, 2e-6]))


def euler(state, v, omega, dt=1.0, n=20000):
    """The unicycle's ODE by many tiny midpoint steps (the reference for the closed form)."""
    x, y, th = state[:3]
    h = dt / n
    for _ in range(n):
        mid = th + 0.5 * omega * h
        x, y, th = x + v * h * math.cos(mid), y + v * h * math.sin(mid), th + omega * h
    return np.array([x, y])


@settings(max_examples=15, deadline=None)
@given(x=finite, y=finite, th=st.floats(-4, 4), v=st.floats(-1, 1), omega=turns)
def test_arc_is_the_ode_solution(x, y, th, v, omega):
    state = np.array([[x, y, th, 0.0, 0.0]])
    out = integrate(state, np.array([v]), np.array([omega]))
    np.testing.assert_allclose(out[0, :2], euler(state[0], v, omega, n=400), atol=1e-5)
    assert abs(wrap_angle(out[0, 2] - (th + omega))) < 1e-9
    assert -math.pi <= out[0, 2] < math.pi
    np.testing.assert_allclose(out[0, 3:], [v, omega])


def test_arc_in_closed_form_and_its_straight_limit():
    state = np.array([[1.0, 2.0, 0.3, 0.0, 0.0]] * 4)
    v, omega = np.array([0.8] * 4), np.array([0.9, 1e-8, 0.0, -1e-8])
    out = integrate(state, v, omega)
    th = 0.3
    expect = [1.0 + v[0] / omega[0] * (math.sin(th + omega[0]) - math.sin(th)),
              2.0 - v[0] / omega[0] * (math.cos(th + omega[0]) - math.cos(th))]
    np.testing.assert_allclose(out[0, :2], expect, atol=1e-14)
    straight = [1.0 + 0.8 * math.cos(th), 2.0 + 0.8 * math.sin(th)]
    for row in out[1:]:
        np.testing.assert_allclose(row[:2], straight, atol=1e-12)


def test_halves_compose_to_the_whole():
    rng = np.random.default_rng(0)
    state = np.column_stack([rng.normal(size=(50, 3)), np.zeros((50, 2))])
    v, omega = rng.uniform(-1, 1, 50), rng.uniform(-2, 2, 50)
    whole = integrate(state, v, omega)
    halves = integrate(integrate(state, v, omega, 0.5), v, omega, 0.5)
    np.testing.assert_allclose(halves[:, :2], whole[:, :2], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(halves[:, 2] - whole[:, 2]), 0.0, atol=1e-12)


@settings(max_examples=15, deadline=None)
@given(th=st.floats(-4, 4), v=st.floats(-1, 1), omega=turns, substeps=st.sampled_from([1, 2, 4, 8, 32]))
def test_substep_velocities_sweep_the_disc_along_the_arc(th, v, omega, substeps):
    """A free disc moved by the substep velocities (p += velocity · dt/S) is on the arc after
    every substep, never moves more than the arc's share per substep, and ends where the arc does."""
    state = np.array([[3.0, -2.0, th, 0.0, 0.0]])
    vel = substep_velocities(state, np.array([v]), np.array([omega]), substeps)
    assert vel.shape == (1, substeps, 2)
    where = state[:, None, :2] + np.concatenate([np.zeros((1, 1, 2)), np.cumsum(vel / substeps, axis=1)], axis=1)
    arc = arc_points(state, np.array([v]), np.array([omega]), substeps)
    np.testing.assert_allclose(where, arc, atol=1e-12)
    np.testing.assert_allclose(where[:, -1], integrate(state, [v], [omega])[:, :2], atol=1e-12)
    assert np.all(np.hypot(*vel[0].T) <= abs(v) + 1e-12)        # a chord is never longer than its arc
    if omega != 0 and abs(v) > 1e-6 and abs(omega) > 1e-3:     # every substep's end on the circle
        centre = state[0, :2] + v / omega * np.array([-math.sin(th), math.cos(th)])
        np.testing.assert_allclose(np.hypot(*(arc[0] - centre).T), abs(v / omega), rtol=1e-9)


def test_a_pure_turn_does_not_move_the_disc():
    state = np.array([[1.0, 1.0, 0.0, 0.0, 0.0]])
    assert not substep_velocities(state, [0.0], [1.5], 8).any()
    np.testing.assert_allclose(integrate(state, [0.0], [1.5])[0, :3], [1.0, 1.0, 1.5])


def test_limits_clamp_speed_turn_and_acceleration():
    lim = UnicycleLimits(max_speed=1.0, max_reverse=0.5, max_turn_rate=1.0, max_accel=0.25, max_turn_accel=0.5)
    v, omega = lim.clamp(np.array([3.0, -3.0, 0.5]), np.array([-9.0, 9.0, 0.2]))
    np.testing.assert_allclose(v, [1.0, -0.5, 0.5])
    np.testing.assert_allclose(omega, [-1.0, 1.0, 0.2])
    v, omega = lim.clamp(np.array([1.0, -0.5]), np.array([1.0, -1.0]), np.array([0.0, 0.5]), np.array([0.0, 0.0]))
    np.testing.assert_allclose(v, [0.25, 0.25])
    np.testing.assert_allclose(omega, [0.5, -0.5])
    for bad in ({"max_speed": 0}, {"max_turn_rate": -1}, {"max_accel": 0}, {"max_reverse": -0.1}):
        with pytest.raises(ValueError):
            UnicycleLimits(**bad)


def test_defaults_are_todays_unit_move():
    lim = UnicycleLimits()
    assert lim.max_speed == 1.0
    v, omega = lim.discrete(np.arange(len(UNICYCLE_ACTIONS)))
    assert len(UNICYCLE_ACTION_NAMES) == len(UNICYCLE_ACTIONS) == 9 and UNICYCLE_ACTION_NAMES[-1] == "stop"
    named = dict(zip(UNICYCLE_ACTION_NAMES, zip(v.tolist(), omega.tolist())))
    assert named["forward"] == (1.0, 0.0) and named["stop"] == (0.0, 0.0)
    assert named["back"] == (-lim.max_reverse, 0.0)
    assert named["turn-left"] == (0.0, lim.max_turn_rate) and named["turn-right"] == (0.0, -lim.max_turn_rate)
    assert named["forward-left"][1] > 0 > named["forward-right"][1]
    # every discrete action is reachable from standstill within the default acceleration limits
    cv, co = lim.clamp(v, omega, np.zeros(9), np.zeros(9))
    np.testing.assert_array_equal(cv, v)
    np.testing.assert_array_equal(co, omega)


def test_unit_box_mappings():
    lim = UnicycleLimits()
    box = np.array([[1.0, 1.0], [-1.0, -1.0], [0.5, 0.0], [2.0, -3.0]])
    v, omega = lim.from_unit(box)
    np.testing.assert_allclose(v, [1.0, -lim.max_reverse, 0.5, 1.0])
    np.testing.assert_allclose(omega, [lim.max_turn_rate, -lim.max_turn_rate, 0.0, -lim.max_turn_rate])
    np.testing.assert_allclose(lim.to_unit(v, omega), np.clip(box, -1, 1))
    # holonomic: the box's corners and edge midpoints are Table 1's nine moves
    units = np.array([(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (-1, -1), (1, 1), (1, -1), (0, 0)], float)
    np.testing.assert_array_equal(holonomic_from_unit(units), ACTIONS)
    np.testing.assert_array_equal(holonomic_to_unit(ACTIONS), units)
    np.testing.assert_allclose(holonomic_from_unit([[0.5, -2.0]], max_speed=2.0), [[1.0, -2.0]])


def test_robot_frame_and_bearing():
    state = np.array([[1.0, 1.0, math.pi / 2, 0.0, 0.0]])
    np.testing.assert_allclose(to_robot_frame(state, np.array([[1.0, 3.0]])), [[2.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(to_robot_frame(state, np.array([[[0.0, 1.0], [1.0, 0.0]]])),
                               [[[0.0, 1.0], [-1.0, 0.0]]], atol=1e-12)
    d, b = distance_bearing(state, np.array([[0.0, 1.0]]))
    np.testing.assert_allclose([d[0], b[0]], [1.0, math.pi / 2])


def test_the_physics_substeps_keep_a_turning_robot_from_tunnelling():
    """With the substep count the physics picks for the unicycle's top speed, no substep's chord
    is longer than 0.9 of the robot's radius, whatever the turn."""
    lim, radius = UnicycleLimits(), 0.25
    substeps = substeps_for(radius, lim.max_speed)
    rng = np.random.default_rng(0)
    state = np.column_stack([rng.normal(size=(200, 2)), rng.uniform(-4, 4, 200), np.zeros((200, 2))])
    v, omega = lim.from_unit(rng.uniform(-1, 1, (200, 2)))
    chords = np.hypot(*substep_velocities(state, v, omega, substeps).transpose(2, 0, 1)) / substeps
    assert chords.max() <= 0.9 * radius
