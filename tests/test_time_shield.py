"""The shield over time: moves checked against where moving obstacles go, a continuation
for a few steps, the avoidability search, the time-aware baseline, and no change among static obstacles."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from apf_physics import load_world
from apf_physics.control.shield import (ACTIONS, HORIZON, SAFETY, assess_moves, every_sequence, move_clearance, predicted_offsets,
                                 shield_over_time)
from apf_physics.planners import make_planner
from apf_physics.planners.base import Planner
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.experiments.rollout import rollout
from apf_physics.world.search import escape_moves, physics_offsets, timed_move_clearance, timed_path
from apf_physics.world.io.worldfile import world_from_dict

from conftest import simple_world_dict


def test_among_static_obstacles_the_shield_over_time_is_the_shield_of_one_step():
    world = load_world("worlds/fixed20.yaml")
    assert not world.moving
    before = rollout(world, DQNPlanner(horizon=0), world.starts)   # the shield of one step
    after = rollout(world, make_planner("dqn"), world.starts)
    assert len(after) == 40
    for a, b in zip(before, after):
        assert a.outcome == b.outcome and a.steps == b.steps
        np.testing.assert_array_equal(a.path, b.path)
    assert all(e.success for e in after)


def crossing_world(start, heading, distance, radius, speed, phase=0.0, **extra):
    """A 30 × 30 world with one disc that runs from ``distance`` away along ``heading`` through ``start`` and back."""
    start = np.asarray(start, float)
    u = np.array([math.cos(heading), math.sin(heading)])
    centre = start - distance * u
    route = 2 * distance * u
    obstacles = [{"circle": {"center": centre.tolist(), "radius": radius},
                  "motion": {"path": [route.tolist()], "speed": speed, "phase": phase}}]
    data = simple_world_dict(size=[30, 30], obstacles=obstacles + extra.pop("static", []), starts=[],
                             targets=extra.pop("targets", [[1.0, 1.0]]), **extra)
    return world_from_dict(data)


def test_physics_offsets_are_where_the_engine_puts_moving_obstacles():
    world = crossing_world([15, 15], 0.3, 6.0, 0.8, 0.7, phase=11.5)
    motion = world.obstacles[0].motion
    for t in (0.0, 3.0, 16.0, 17.0):
        np.testing.assert_allclose(physics_offsets(world, t)[0], motion.offset(t), atol=1e-12)
    # between whole steps: the straight line between them (the route's end at 2·6·0.7... is cut)
    a, b = motion.offset(16.0), motion.offset(17.0)
    np.testing.assert_allclose(physics_offsets(world, 16.25)[0], a + 0.25 * (b - a), atol=1e-12)
    # velocity prediction: now plus the last step's displacement
    now, last = motion.offset(5.0), motion.offset(4.0)
    np.testing.assert_allclose(predicted_offsets(world, 5, np.array([2.0]), "velocity")[0, 0], now + 2 * (now - last))


def test_standing_still_is_not_safe_when_something_comes():
    # a disc comes straight at a standing robot: staying put is refused, and the robot gets out of the way
    world = crossing_world([15, 15], 0.0, 4.0, 1.0, 0.6)
    t = 4   # the disc's rim is 15 - (11 + 2.4) - 1 = 0.6 from the robot's centre, closing at 0.6 a step
    p = np.array([[15.0, 15.0]])
    assert world.at(t).clearance(p)[0] > world.robot_radius + SAFETY     # safe now, as the one-step shield sees it
    for prediction in ("velocity", "known"):
        a = assess_moves(world.at(t), p, ACTIONS, prediction)
        assert a.watched[0]
        assert not a.admitted[0, 8], prediction
        assert a.admitted[0].any(), prediction
    q = np.zeros((1, 9))
    q[0, 8] = 1.0   # the network wants to stay
    for prediction in ("velocity", "known"):
        chosen = shield_over_time(world.at(t), p, ACTIONS, q, prediction)
        assert chosen[0] != 8 and assess_moves(world.at(t), p, ACTIONS, prediction).admitted[0, chosen[0]]
    # the shield of one step sees nothing wrong with staying
    assert move_clearance(world.at(t), p)[0, 8] > world.robot_radius + SAFETY


def test_no_move_safe_takes_the_one_that_puts_contact_off_longest():
    # a wide disc almost on the robot, coming fast, the robot against the map's edge: nothing is admitted
    obstacles = [{"circle": {"center": [12.0, 15.0], "radius": 2.0}, "motion": {"path": [[-10.0, 0.0]], "speed": 1.0,
                                                                             "phase": 8.9}}]
    world = world_from_dict(simple_world_dict(size=[30, 30], obstacles=obstacles, starts=[], targets=[[25.0, 25.0]]))
    p = np.array([[0.6, 15.0]])
    a = assess_moves(world.at(0), p, ACTIONS, "known")
    assert not a.admitted.any()
    chosen = shield_over_time(world.at(0), p, ACTIONS, np.zeros((1, 9)), "known")
    assert a.contact[0, chosen[0]] == a.contact[0].max()
    assert a.contact[0, chosen[0]] > a.contact[0, 3]        # later than running into it


def _fatal(world, position, t, move, steps):
    """Every sequence of ``steps`` moves after ``move`` (from ``position`` at step ``t``) touches something at a sample."""
    first = timed_move_clearance(world, position[None], move[None], t, strict=False)[0, 0]
    if first <= world.robot_radius:
        return True
    return escape_moves(world, position + move, t + 1, steps, strict=False) is None


@settings(max_examples=int(os.environ.get("APF_SHIELD_EXAMPLES", 25)), deadline=None)
@given(heading=st.floats(0, 2 * math.pi), distance=st.floats(2.5, 7.0), radius=st.floats(0.3, 1.3),
       speed=st.floats(0.2, 1.0), phase=st.floats(0, 6), moving=st.booleans(),
       direction=st.integers(0, 7), wall=st.booleans())
def test_the_shield_with_known_motion_never_admits_a_fatal_move(heading, distance, radius, speed, phase, moving,
                                                               direction, wall):
    static = [{"polygon": [[17.0, 10.0], [18.0, 10.0], [18.0, 20.0], [17.0, 20.0]]}] if wall else []
    start = np.array([15.0, 15.0])
    world = crossing_world(start, heading, distance, radius, speed, phase, static=static)
    assume(world.at(0).clearance(start[None])[0] > world.robot_radius + SAFETY)
    q = np.zeros((1, 9))
    q[0, 8 if not moving else direction] = 1.0     # a robot that wants to stand, or to run one way
    p = start.copy()
    for t in range(8):
        a = assess_moves(world.at(t), p[None], ACTIONS, "known")
        for k in np.flatnonzero(a.admitted[0]):
            assert not _fatal(world, p, t, ACTIONS[k], HORIZON - 1), (t, p, ACTIONS[k])
        if not a.admitted[0].any():   # what the shield tries then: every sequence after each move
            rich = assess_moves(world.at(t), p[None], ACTIONS, "known", continuations=every_sequence(HORIZON),
                                samples=16)
            for k in np.flatnonzero(rich.admitted[0]):
                assert not _fatal(world, p, t, ACTIONS[k], HORIZON - 1), (t, p, ACTIONS[k])
            if not rich.admitted[0].any():
                break
        k = int(shield_over_time(world.at(t), p[None], ACTIONS, q, "known")[0])
        p = p + ACTIONS[k]


def test_avoidability_search_finds_the_sidestep_and_knows_a_cornered_robot():
    world = crossing_world([15, 15], 0.0, 4.0, 1.0, 0.6)
    # from step 3 standing still is fatal, stepping aside is not
    assert escape_moves(world, np.array([15.0, 15.0]), 3, 6, moves=np.zeros((1, 2))) is None
    chain = escape_moves(world, np.array([15.0, 15.0]), 3, 6)
    assert chain is not None and len(chain) == 6
    # a robot in a pocket the disc fills, faster than the robot: unavoidable
    pocket = [{"polygon": [[0.0, 13.0], [6.0, 13.0], [6.0, 13.6], [0.0, 13.6]]},
              {"polygon": [[0.0, 16.4], [6.0, 16.4], [6.0, 17.0], [0.0, 17.0]]}]
    pocket.append({"circle": {"center": [12.0, 15.0], "radius": 1.2},
                   "motion": {"path": [[-10.6, 0.0]], "speed": 1.0, "phase": 7.0}})
    cornered = world_from_dict(simple_world_dict(size=[30, 30], obstacles=pocket, starts=[], targets=[[25.0, 25.0]]))
    assert escape_moves(cornered, np.array([1.0, 15.0]), 0, 5, strict=False) is None


def test_sipp_plans_around_the_future_and_reaches_through_the_physics():
    world = crossing_world([15, 15], 0.5 * math.pi, 5.0, 1.0, 0.5, targets=[[15.0, 25.0]])
    plan = timed_path(world, np.array([15.0, 5.0]))
    assert plan is not None
    for t in range(len(plan) - 1):
        clear = timed_move_clearance(world, plan[t][None], (plan[t + 1] - plan[t])[None], t)[0, 0]
        assert clear >= world.robot_radius + SAFETY
    episode = rollout(world, make_planner("sipp"), np.array([[15.0, 5.0]]))[0]
    assert episode.outcome == "reached"


def test_dqn_known_is_the_dqn_planner_with_known_motion():
    planner = make_planner("dqn-known")
    assert planner.name == "dqn-known" and planner.prediction == "known" and planner.shield
    with pytest.raises(ValueError):
        DQNPlanner(prediction="psychic")


class Stand(Planner):
    """Stays put."""

    trap_window = 100

    def act(self, positions, active, moment=None):
        return np.zeros_like(np.asarray(positions, float))


def test_videos_mark_the_step_of_a_collision():
    from apf_physics.render.episodes import collision_events
    from apf_physics.render.video import trajectory_snapshots

    world = crossing_world([15, 15], 0.0, 4.0, 1.0, 0.6)
    standing = rollout(world, Stand(), np.array([[15.0, 15.0], [15.0, 25.0]]), max_steps=12)
    hit = [e for e in standing if e.outcome == "collision"]
    assert hit, [e.outcome for e in standing]
    events = collision_events(standing)
    assert [step for step, _ in events] == [e.steps for e in hit]
    lines = [s.overlay for s in trajectory_snapshots(np.zeros((hit[0].steps + 2, 2)), events=events)]
    assert not any("COLLISION" in line for line in lines[hit[0].steps - 1])
    assert any(f"COLLISION at step {hit[0].steps}" in line for line in lines[hit[0].steps])
