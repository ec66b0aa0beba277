"""The episode rules of the engine (Model's episode rules): the trap detector's two rules and their
boundaries, and the stepper's starts (worlds, absent robots, several robots per slot), ended slots that
stay put, and which outcome wins when several apply."""

from __future__ import annotations

import numpy as np

from apf_physics import world_from_dict
from apf_physics.sim.engine import COLLISION, REACHED, RUNNING, TIMEOUT, TRAPPED, Stepper, TrapDetector, TrapWatch
from apf_physics.world.kinematics import UnicycleLimits

from conftest import simple_world_dict


def _open(**overrides):
    return world_from_dict(simple_world_dict(obstacles=[], **overrides))


def _feed(watch, positions, potentials):
    """Reset slot 0 with the first entry, record the rest; which records said trapped."""
    slot = np.array([0])
    watch.reset(slot, np.array([positions[0]], float), np.array([potentials[0]], float))
    return [bool(watch.record(slot, np.array([p], float), np.array([u], float))[0])
            for p, u in zip(positions[1:], potentials[1:])]


FAR = [(10.0 * i, 0.0) for i in range(12)]          # never within any radius of their mean
STILL = [(3.0, 3.0)] * 12


# -- the trap detector --------------------------------------------------------------------------

def test_oscillation_is_judged_only_once_the_window_is_full_and_after_the_start_has_left_it():
    # reset + w records fill the window; the start's own entry is overwritten before any judgement
    said = _feed(TrapWatch(TrapDetector(window=4), 1), STILL[:8], [0.0] * 8)
    assert said == [False, False, False, True, True, True, True]


def test_oscillation_radius_is_strict():
    # two entries 3 apart: each 1.5 from their mean, exactly the radius: not "within"
    on_the_radius = [(0.0, 0.0), (0.0, 0.0), (3.0, 0.0), (0.0, 0.0), (3.0, 0.0)]
    assert _feed(TrapWatch(TrapDetector(window=2, radius=1.5), 1), on_the_radius, [0.0] * 5) == [False] * 4
    inside = [(0.0, 0.0), (0.0, 0.0), (2.9, 0.0), (0.0, 0.0)]
    assert _feed(TrapWatch(TrapDetector(window=2, radius=1.5), 1), inside, [0.0] * 4)[-2:] == [True, True]


def test_descent_rule_traps_a_robot_that_moves_but_no_longer_descends():
    # moving far (no oscillation), the potential flat after the start's 5: trapped once the start left the window
    detector = TrapDetector(rule="descent", window=3)
    assert _feed(TrapWatch(detector, 1), FAR[:6], [5.0, 9.0, 9.0, 9.0, 9.0, 9.0]) == [False, False, True, True, True]
    # the same with the oscillation rule: never
    assert _feed(TrapWatch(TrapDetector(window=3), 1), FAR[:6], [5.0, 9.0, 9.0, 9.0, 9.0, 9.0]) == [False] * 5


def test_descent_rule_keeps_the_oscillation_rule():
    # standing still while the potential keeps dropping: trapped by the oscillation part of the rule
    detector = TrapDetector(rule="descent", window=3)
    assert _feed(TrapWatch(detector, 1), STILL[:6], [9.0, 8.0, 7.0, 6.0, 5.0, 4.0]) == [False, False, True, True, True]


def test_descent_rule_a_drop_of_exactly_min_drop_is_enough():
    detector = TrapDetector(rule="descent", window=2, min_drop=0.25)
    # earlier lowest 10; the window's lowest 9.75 (binary-exact): at least min_drop below, so still descending
    assert _feed(TrapWatch(detector, 1), FAR[:4], [10.0, 9.75, 9.75, 9.75])[1] is False
    # a window a little above the earlier lowest: trapped (not within min_drop *above* it)
    assert _feed(TrapWatch(detector, 1), FAR[:4], [10.0, 10.125, 10.125, 10.125])[1] is True
    # a steady descent of more than min_drop per step: never trapped
    assert _feed(TrapWatch(detector, 1), FAR[:10], [10.0 - i for i in range(10)]) == [False] * 9


def test_descent_rule_remembers_the_lowest_potential_that_left_the_window():
    # the lowest potential (1) is the second entry: while it is in the window the robot has not risen above
    # it; once it has left, it still counts (the window's 4 is not below it)
    detector = TrapDetector(rule="descent", window=2)
    said = _feed(TrapWatch(detector, 1), FAR[:7], [5.0, 1.0, 4.0, 4.0, 4.0, 4.0, 4.0])
    assert said == [False, False, True, True, True, True]


def test_reset_forgets_the_previous_episode_of_that_slot_only():
    detector = TrapDetector(rule="descent", window=2)
    watch = TrapWatch(detector, 2)
    both = np.array([0, 1])
    watch.reset(both, np.array([FAR[0], FAR[0]]), np.array([0.0, 0.0]))
    for i in range(1, 4):                                   # both slots: far above their earlier lowest
        said = watch.record(both, np.array([FAR[i], FAR[i]]), np.array([9.0, 9.0]))
    assert said.tolist() == [True, True]
    watch.reset(np.array([0]), np.array([FAR[5]]), np.array([20.0]))   # a new episode in slot 0
    said = watch.record(both, np.array([FAR[6], FAR[6]]), np.array([19.0, 9.0]))
    assert said.tolist() == [False, True]


# -- the stepper ----------------------------------------------------------------------------------

def test_a_robot_climbing_away_is_trapped_by_the_descent_rule_only():
    world = _open(targets=[[2.0, 10.0]], starts=[[4.0, 10.0]])
    away = np.array([[[1.0, 0.0]]])
    outcomes = {}
    for rule in ("descent", "oscillation"):
        stepper = Stepper([world], 1, max_steps=12, trap=TrapDetector(rule=rule, window=5))
        stepper.start(np.array([0]), np.array([[[4.0, 10.0]]]))
        while stepper.running.any():
            stepper.step(away)
        outcomes[rule] = (int(stepper.outcome[0]), int(stepper.steps[0]))
    assert outcomes == {"descent": (TRAPPED, 5), "oscillation": (TIMEOUT, 12)}


def test_a_start_in_another_world_uses_that_worlds_targets_and_tolerance():
    near = _open(name="near", targets=[[5.0, 5.0]], goal_tolerance=0.5)
    far = _open(name="far", targets=[[15.0, 5.0]], goal_tolerance=1.5)
    stepper = Stepper([near, far], 2, max_steps=20)
    stepper.start(np.array([0, 1]), np.array([[[2.0, 5.0]], [[2.0, 5.0]]]), world_ids=np.array([1, 0]))
    np.testing.assert_allclose(stepper.last_distance, [13.0, 3.0])
    right = np.tile([[[1.0, 0.0]]], (2, 1, 1))
    report = stepper.step(right)
    np.testing.assert_allclose(report.distance, [12.0, 2.0])
    while stepper.running.any():
        stepper.step(right)
    # slot 1 (near) reached x = 5 in 3 steps; slot 0 (far) within 1.5 of x = 15 at x = 14, after 12
    assert stepper.outcome.tolist() == [REACHED, REACHED] and stepper.steps.tolist() == [12, 3]


def test_robots_of_a_later_slot_are_placed_and_moved_as_their_own():
    world = _open()
    stepper = Stepper([world], 2, robots_per_slot=2, max_steps=5)
    start = np.array([[[2.0, 2.0], [2.0, 4.0]], [[10.0, 2.0], [10.0, 4.0]]])
    stepper.start(np.array([1]), start[1:])
    stepper.start(np.array([0]), start[:1])
    np.testing.assert_allclose(stepper.physics.positions.reshape(2, 2, 2), start)
    commands = np.array([[[1.0, 0.0], [0.0, 1.0]], [[-1.0, 0.0], [0.0, -1.0]]])
    report = stepper.step(commands)
    np.testing.assert_allclose(report.positions, start + commands, atol=1e-9)


def test_an_absent_robot_neither_moves_nor_touches_anything():
    world = _open()
    stepper = Stepper([world], 2, robots_per_slot=2, max_steps=5)
    # slot 1's second robot is absent, and stands where its leader goes: present, it would collide
    start = np.array([[[2.0, 2.0], [2.0, 4.0]], [[10.0, 10.0], [11.0, 10.0]]])
    stepper.start(np.array([0, 1]), start, present=np.array([[True, True], [True, False]]))
    assert stepper.physics.present.tolist() == [True, True, True, False]
    report = stepper.step(np.array([[[0.0, 0.0], [0.0, 0.0]], [[1.0, 0.0], [1.0, 0.0]]]))
    assert not report.collided.any() and stepper.outcome.tolist() == [RUNNING, RUNNING]
    np.testing.assert_allclose(report.positions[1, 0], [11.0, 10.0], atol=1e-9)


def test_an_ended_slots_robots_stay_where_the_episode_ended():
    world = _open(targets=[[3.0, 2.0]], goal_tolerance=0.5)
    stepper = Stepper([world], 2, max_steps=10)
    stepper.start(np.array([0, 1]), np.array([[[2.0, 2.0]], [[10.0, 10.0]]]))
    stepper.step(np.array([[[1.0, 0.0]], [[0.0, 1.0]]]))
    assert stepper.outcome.tolist() == [REACHED, RUNNING]
    ended_at = stepper.physics.positions[0].copy()
    for _ in range(3):    # slot 0 is still sent commands: they are ignored, in the report and in the physics
        report = stepper.step(np.array([[[1.0, 0.0]], [[0.0, 1.0]]]))
        assert report.moved.tolist() == [False, True]
        assert report.reached.tolist() == [False, False] and report.ended.tolist() == [False, False]
    np.testing.assert_allclose(stepper.physics.positions[0], ended_at)
    np.testing.assert_allclose(report.positions[0, 0], ended_at)
    assert stepper.steps.tolist() == [1, 4]


def test_collision_beats_reached_and_reached_beats_trapped_and_timeout():
    # a target right at the wall: the robot ends within the tolerance but touched the edge on the way
    world = _open(targets=[[19.5, 10.0]], goal_tolerance=0.9)
    stepper = Stepper([world], 1, max_steps=1, trap=TrapDetector(window=1, radius=100.0))
    stepper.start(np.array([0]), np.array([[[18.5, 10.0]]]))
    report = stepper.step(np.array([[[1.4, 0.0]]]))
    assert report.reached.tolist() == [False] and report.collided.tolist() == [True]
    assert stepper.outcome.tolist() == [COLLISION]
    # reached, on the step where the trap window is full and the step limit is hit
    world = _open(targets=[[5.0, 5.0]], goal_tolerance=0.5)
    stepper = Stepper([world], 1, max_steps=1, trap=TrapDetector(window=1, radius=100.0))
    stepper.start(np.array([0]), np.array([[[4.0, 5.0]]]))
    stepper.step(np.array([[[1.0, 0.0]]]))
    assert stepper.outcome.tolist() == [REACHED]
    # trapped beats timeout on the same step
    stepper.start(np.array([0]), np.array([[[2.0, 2.0]]]))
    stepper.step(np.array([[[0.0, 0.0]]]))
    assert stepper.outcome.tolist() == [TRAPPED]


def test_a_planner_that_gives_up_ends_trapped_without_moving():
    world = _open()
    stepper = Stepper([world], 2, max_steps=10)
    stepper.start(np.array([0, 1]), np.array([[[2.0, 2.0]], [[10.0, 10.0]]]))
    report = stepper.step(np.array([[[1.0, 0.0]], [[1.0, 0.0]]]), gave_up=np.array([True, False]))
    assert stepper.outcome.tolist() == [TRAPPED, RUNNING] and report.moved.tolist() == [False, True]
    np.testing.assert_allclose(report.positions[:, 0], [[2.0, 2.0], [11.0, 10.0]], atol=1e-9)
    assert stepper.steps.tolist() == [0, 1]


def test_the_goal_tolerance_is_inclusive():
    world = _open(targets=[[5.0, 5.0]], goal_tolerance=1.0)
    stepper = Stepper([world], 1, max_steps=10)
    stepper.start(np.array([0]), np.array([[[3.0, 5.0]]]))
    report = stepper.step(np.array([[[1.0, 0.0]]]))           # ends exactly 1.0 from the target
    assert report.distance.tolist() == [1.0] and stepper.outcome.tolist() == [REACHED]


def test_a_collision_ends_the_episode_without_a_step_limit_or_trap_detector():
    world = _open()
    stepper = Stepper([world], 2, robots_per_slot=2)
    # slot 1's second robot runs into the map's right edge; slot 0 moves freely
    stepper.start(np.array([0, 1]), np.array([[[2.0, 2.0], [2.0, 4.0]], [[10.0, 10.0], [19.0, 10.0]]]))
    report = stepper.step(np.array([[[1.0, 0.0], [1.0, 0.0]], [[0.0, 1.0], [1.4, 0.0]]]))
    assert report.collided.tolist() == [False, True] and report.ended.tolist() == [False, True]
    assert stepper.outcome.tolist() == [RUNNING, COLLISION]


def test_a_start_within_the_goal_tolerance_is_reached_at_once_and_reported_by_the_next_step_only():
    world = _open(targets=[[5.0, 5.0]], goal_tolerance=1.0)
    stepper = Stepper([world], 3, max_steps=10)
    # exactly at the tolerance (inclusive), inside it, and outside it
    stepper.start(np.arange(3), np.array([[[4.0, 5.0]], [[5.0, 5.5]], [[2.0, 5.0]]]))
    assert stepper.outcome.tolist() == [REACHED, REACHED, RUNNING] and stepper.steps.tolist() == [0, 0, 0]
    report = stepper.step(np.array([[[1.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]]]))
    assert report.ended.tolist() == [True, True, False] and report.reached.tolist() == [True, True, False]
    assert report.moved.tolist() == [False, False, True]
    np.testing.assert_allclose(report.positions[:2, 0], [[4.0, 5.0], [5.0, 5.5]])    # not moved
    report = stepper.step(np.array([[[1.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]]]))
    assert report.ended.tolist() == [False, False, False] and report.reached.tolist() == [False, False, False]


def test_a_start_reported_reached_is_not_reported_again_when_another_slot_starts():
    world = _open(targets=[[5.0, 5.0]], goal_tolerance=1.0)
    stepper = Stepper([world], 3, max_steps=10)
    stepper.start(np.arange(3), np.array([[[5.0, 5.0]], [[2.0, 5.0]], [[2.0, 2.0]]]))
    up = np.array([[[0.0, 1.0]]] * 3)
    assert stepper.step(up).reached.tolist() == [True, False, False]
    stepper.start(np.array([1]), np.array([[[2.0, 8.0]]]))        # a new episode in slot 1, away from the target
    report = stepper.step(up)
    assert report.ended.tolist() == [False, False, False] and report.reached.tolist() == [False, False, False]
    assert stepper.outcome.tolist() == [REACHED, RUNNING, RUNNING]


def test_a_start_without_world_ids_among_several_worlds_is_in_the_first():
    near = _open(name="near", targets=[[5.0, 5.0]], goal_tolerance=0.5)
    far = _open(name="far", targets=[[15.0, 5.0]], goal_tolerance=1.5)
    stepper = Stepper([near, far], 2, max_steps=20)
    stepper.start(np.array([0, 1]), np.array([[[2.0, 5.0]], [[4.0, 5.0]]]))
    assert stepper.world(0) is near and stepper.world(1) is near
    np.testing.assert_allclose(stepper.last_distance, [3.0, 1.0])
    report = stepper.step(np.array([[[1.0, 0.0]], [[0.5, 0.0]]]))
    assert report.reached.tolist() == [False, True]              # within near's 0.5 (far's target is 10 away)


def test_unicycles_start_at_rest_headed_as_given_or_toward_the_target_nearest_their_leader():
    world = _open(targets=[[15.0, 5.0], [5.0, 15.0]])
    stepper = Stepper([world], 3, robots_per_slot=2, unicycle=UnicycleLimits())
    start = np.array([[[5.0, 5.0], [4.0, 5.0]], [[14.0, 12.0], [13.0, 12.0]], [[5.0, 12.0], [5.0, 11.0]]])
    stepper.start(np.arange(3), start)
    # the nearest target of slot 0's leader is [15, 5] (east), of slot 1's [15, 5] too (7.1 away; [5, 15] is
    # 9.5), of slot 2's [5, 15] (north); a follower faces where its leader does
    toward = np.array([0.0, np.arctan2(-7.0, 1.0), np.pi / 2])
    np.testing.assert_allclose(stepper.poses()[..., 2], np.repeat(toward[:, None], 2, axis=1), atol=1e-12)
    np.testing.assert_array_equal(stepper.states()[..., 3:], 0.0)
    stepper.start(np.array([1]), start[1:2], headings=np.array([[1.0, 7.0]]))     # given, wrapped to [-π, π)
    np.testing.assert_allclose(stepper.poses()[1, :, 2], [1.0, 7.0 - 2 * np.pi])
    np.testing.assert_allclose(stepper.poses()[[0, 2], :, 2], np.repeat(toward[[0, 2], None], 2, axis=1), atol=1e-12)
