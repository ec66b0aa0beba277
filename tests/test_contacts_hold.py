"""Contacts that hold: at the end of every control step no robot is more than 0.01 inside an
obstacle or past the map's edge, no two robots overlap by more than 0.02, and no robot's
centre passes through another robot (issue 25, item 2). Crowds are pushed at random into thin
walls and into each other: robots alone in their slots, formations (several robots per slot),
crowds of slots, and every robot of the multi-agent environment."""

import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics import world_from_dict
from apf_physics.sim.physics import Physics
from conftest import WORLDS, simple_world_dict
from contacts_check import assert_contacts_hold, overlaps

EXAMPLES = int(os.environ.get("APF_CONTACT_EXAMPLES", 4))


def thin_walls(rng: np.random.Generator, count: int = 6):
    """A 20 × 20 world with ``count`` bars 0.005–0.1 thick at random angles."""
    obstacles = []
    for _ in range(count):
        c = rng.uniform(3, 17, 2)
        angle, length, width = rng.uniform(0, math.pi), rng.uniform(2, 6), rng.uniform(0.005, 0.1)
        u = np.array([math.cos(angle), math.sin(angle)])
        n = np.array([-u[1], u[0]])
        corners = [c - u * length / 2 - n * width / 2, c + u * length / 2 - n * width / 2,
                   c + u * length / 2 + n * width / 2, c - u * length / 2 + n * width / 2]
        obstacles.append({"polygon": np.clip(np.array(corners), 0.5, 19.5).tolist()})
    return world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19.5, 19.5]],
                            "obstacles": obstacles})


def random_headings(rng, n, steps, hold=10):
    """(steps, n, 2) velocities: a random heading per robot, at speed 1 or √2, each changed
    with probability 1 / ``hold`` per step (held about ``hold`` steps)."""
    heading = rng.uniform(0, 2 * math.pi, n)
    speed = rng.choice([1.0, math.sqrt(2)], n)
    out = []
    for _ in range(steps):
        change = rng.random(n) < 1 / hold
        heading[change] = rng.uniform(0, 2 * math.pi, int(change.sum()))
        out.append(np.column_stack([np.cos(heading), np.sin(heading)]) * speed[:, None])
    return out


def drive(physics, velocities):
    for v in velocities:
        before = physics.positions
        physics.step(v)
        assert_contacts_hold(physics, before)


def test_three_in_a_row_against_the_edge_do_not_pass_through_each_other():
    # The example: the second stops against the first; the third must not go through it.
    world = world_from_dict(simple_world_dict(obstacles=[]))
    physics = Physics([world], robots_per_slot=3)
    physics.place([0, 1, 2], [[0.3, 10.0], [0.85, 10.0], [1.4, 10.0]])
    for _ in range(4):
        before = physics.positions
        physics.step(np.tile([-1.0, 0.0], (3, 1)))
        assert_contacts_hold(physics, before)
        x = physics.positions[:, 0]
        assert x[0] < x[1] < x[2], "the robots changed order"


def test_a_robot_hitting_a_wall_ends_the_step_outside_it():
    # at full speed into a thin bar, and into the map's edge, from every distance in one substep's travel
    world = world_from_dict(simple_world_dict(obstacles=[{"polygon": [[10, 2], [10.01, 2], [10.01, 18], [10, 18]]}]))
    starts = np.column_stack([np.linspace(8.0, 8.4, 40), np.full(40, 10.0)])
    edge = np.column_stack([np.linspace(1.3, 1.7, 40), np.full(40, 5.0)])
    physics = Physics([world] * 80)
    physics.place(np.arange(80), np.vstack([starts, edge]))
    velocities = np.vstack([np.tile([math.sqrt(2), 0.0], (40, 1)), np.tile([-math.sqrt(2), 0.0], (40, 1))])
    for _ in range(3):
        before = physics.positions
        physics.step(velocities)
        assert_contacts_hold(physics, before)


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000))
def test_robots_alone_in_their_slots_end_every_step_outside_thin_walls(seed):
    rng = np.random.default_rng(seed)
    worlds = [thin_walls(rng) for _ in range(3)]
    slots = 96
    physics = Physics([worlds[s % 3] for s in range(slots)])
    for s in range(slots):
        physics.place([s], worlds[s % 3].random_free_positions(rng, 1))
    drive(physics, random_headings(rng, slots, 30))


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([3, 16, 64]))
def test_formations_pushed_into_walls_and_each_other_hold(seed, robots):
    # the crowd: 64 robots per world with random headings held about ten steps
    rng = np.random.default_rng(seed)
    slots = 2
    worlds = [thin_walls(rng) for _ in range(slots)]
    physics = Physics(worlds, robots_per_slot=robots)
    for s, world in enumerate(worlds):
        physics.place(np.arange(s * robots, (s + 1) * robots), world.random_free_positions(rng, robots))
    drive(physics, random_headings(rng, slots * robots, 30))


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000))
def test_a_crowd_of_slots_pushed_together_holds(seed):
    # several formations of 4 in one world: robots of different slots meet
    rng = np.random.default_rng(seed)
    world = thin_walls(rng)
    slots, m = 8, 4
    physics = Physics([world] * slots, robots_per_slot=m, crowds=[0] * slots)
    physics.place(np.arange(slots * m), world.random_free_positions(rng, slots * m))
    # half of the robots head for the middle at full speed: a pile-up; the others wander
    towards = rng.random(slots * m) < 0.5
    for v in random_headings(rng, slots * m, 30, hold=5):
        middle = np.array([10.0, 10.0]) - physics.positions
        v[towards] = middle[towards] / np.maximum(np.hypot(*middle[towards].T), 1e-9)[:, None] * math.sqrt(2)
        before = physics.positions
        physics.step(v)
        assert_contacts_hold(physics, before)


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000))
def test_every_robot_of_the_multi_agent_env_holds(seed):
    pytest.importorskip("pettingzoo")
    from apf_physics.envs import FormationsParallelEnv

    env = FormationsParallelEnv(world=WORLDS / "four_formations.yaml", agents="all")
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    physics = env.task.stepper.physics
    for _ in range(40):
        if not env.agents:
            env.reset()
        before = physics.positions
        env.step({a: int(rng.integers(9)) for a in env.agents})
        assert_contacts_hold(physics, before)


def test_the_check_sees_a_pass_through():
    # the assertion itself: the pass-through and overlaps are caught
    world = world_from_dict(simple_world_dict(obstacles=[]))
    physics = Physics([world], robots_per_slot=2)
    physics.place([0, 1], [[5.0, 10.0], [6.0, 10.0]])
    before = physics.positions
    jumped = [[5.0, 10.0], [4.9, 10.0]]   # robot 1 jumped through robot 0
    obstacle, robot, crossed = overlaps(physics, before, after=jumped)
    assert crossed.all() and robot.max() > 0.3
    obstacle, _, _ = overlaps(physics, before, after=[[0.1, 10.0], [6.0, 10.0]])
    assert obstacle[0] == pytest.approx(0.15)
