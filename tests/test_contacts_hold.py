"""Contacts that hold: at the end of every control step no robot is more than 0.01 inside an
obstacle or past the map's edge, no two robots overlap by more than 0.02, and no robot's
centre passes through another robot or through a wall. Crowds are pushed at random into thin
walls and into each other: robots alone in their slots, formations (several robots per slot),
crowds of slots, and every robot of the multi-agent environment; and unicycles, alone, in
formations and in crowds, at the highest speed a world file accepts, among bars down to 0.001
thick (the physics probe's worlds, ``tools/probe_contacts.py``)."""

import importlib.util
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics import world_from_dict
from apf_physics.sim.physics import Physics
from apf_physics.world.kinematics import MAX_UNICYCLE_SPEED, UnicycleLimits, substep_velocities, wrap_angle
from conftest import WORLDS, simple_world_dict
from contacts_check import assert_contacts_hold, overlaps, tunnelled

EXAMPLES = int(os.environ.get("APF_CONTACT_EXAMPLES", 4))

_PROBE = importlib.util.spec_from_file_location(
    "apf_probe_contacts_tool", Path(__file__).resolve().parent.parent / "tools" / "probe_contacts.py")
probe_contacts = importlib.util.module_from_spec(_PROBE)
_PROBE.loader.exec_module(probe_contacts)
bars = probe_contacts.bars   # the probe's worlds: bars 0.001 to 0.1 thick, and their centre lines


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


# -- unicycles at the highest speed a world file accepts ------------------------------------------

def drive_unicycles(rng, physics, worlds, lines, world_of, speed, steps, robots_meet):
    """Random full-speed commands (forward or back, any turn within π per step) for ``steps`` steps,
    never reset; after each, contacts hold and no robot went through a bar."""
    n = physics.num_robots
    limits = UnicycleLimits(max_speed=speed, max_reverse=speed, max_turn_rate=math.pi, max_accel=2 * speed,
                            max_turn_accel=2 * math.pi)
    state = np.zeros((n, 5))
    state[:, 2] = rng.uniform(-math.pi, math.pi, n)
    reach = speed * (2 if robots_meet else 1) + worlds[0].robot_radius
    for _ in range(steps):
        before = physics.positions
        v, w = limits.clamp(rng.choice([-1.0, 1.0], n) * speed, rng.uniform(-math.pi, math.pi, n),
                            state[:, 3], state[:, 4])
        state[:, :2] = before
        physics.step(substep_velocities(state, v, w, physics.substeps))
        state[:, 2], state[:, 3], state[:, 4] = wrap_angle(state[:, 2] + w), v, w
        obstacle, robot, _ = overlaps(physics, before)   # (straight paths say nothing of arcs: see the probe)
        assert obstacle.max() <= 0.01 and robot.max(initial=0) <= 0.02, (obstacle.max(), robot.max(initial=0))
        for i, world in enumerate(worlds):
            mine = world_of == i
            assert not tunnelled(lines[i], before[mine], physics.positions[mine], reach).any(), "through a bar"


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([3.0, MAX_UNICYCLE_SPEED]))
def test_unicycles_alone_at_full_speed_neither_sink_into_nor_pass_through_bars(seed, speed):
    rng = np.random.default_rng(seed)
    made = [bars(rng) for _ in range(2)]
    worlds, lines = [w for w, _ in made], [b for _, b in made]
    world_of = np.arange(32) % 2
    physics = Physics([worlds[i] for i in world_of], max_speed=speed)
    for s in range(32):
        physics.place([s], worlds[world_of[s]].random_free_positions(rng, 1))
    drive_unicycles(rng, physics, worlds, lines, world_of, speed, 60, robots_meet=False)


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000), st.booleans())
def test_unicycles_in_formations_and_crowds_at_full_speed_hold(seed, crowd):
    rng = np.random.default_rng(seed)
    world, lines = bars(rng)
    slots, m = 6, 4
    physics = Physics([world] * slots, robots_per_slot=m, max_speed=MAX_UNICYCLE_SPEED,
                      crowds=[0] * slots if crowd else None)
    if crowd:
        physics.place(np.arange(slots * m), world.random_free_positions(rng, slots * m))
    else:
        for s in range(slots):
            physics.place(np.arange(s * m, (s + 1) * m), world.random_free_positions(rng, m))
    drive_unicycles(rng, physics, [world], [lines], np.zeros(slots * m, np.intp), MAX_UNICYCLE_SPEED, 40,
                    robots_meet=True)


def test_a_unicycle_that_hits_a_bar_and_turns_away_is_no_faster_than_its_top_speed():
    # The probe's tunnel: a contact took the part of the command heading into the bar, and the
    # arc's later turn, added on top, left the body faster than the speed its substeps were sized
    # for (up to 3.65 units in a step at a top speed of 3); a second bar then let its centre through.
    world = world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19.5, 19.5]],
                             "obstacles": [{"polygon": [[10, 2], [10.001, 2], [10.001, 18], [10, 18]]}]})
    rng = np.random.default_rng(0)
    n = 400
    x0 = rng.uniform(9.0, 9.74, n)                          # from touching the bar to a step and a half away
    state = np.column_stack([x0, np.full(n, 10.0), rng.uniform(-math.pi / 2, math.pi / 2, n), np.zeros((n, 2))])
    omega = rng.choice([-1, 1], n) * rng.uniform(1.5, math.pi, n)
    physics = Physics([world] * n, max_speed=3.0)
    physics.place(np.arange(n), state[:, :2])
    physics.step(substep_velocities(state, np.full(n, 3.0), omega, physics.substeps))
    moved = np.hypot(*(physics.positions - state[:, :2]).T)
    assert moved.max() <= 3.0 + 1e-9
    assert np.all(physics.positions[:, 0] < 10.0 - world.robot_radius + 0.01)   # all still on their side


@pytest.mark.parametrize("half_angle", [2.0, 3.0, 4.0])
def test_a_crowd_pressed_into_a_narrow_v_of_bars_holds(half_angle):
    # Pushed toward the apex, the first robot wedges where the V is as wide as it, and the others
    # press it on: the pushes free it only a little at a time along the V. Before, it ended up to
    # 0.045 inside a bar, and one put back alone where it started seemed to have been passed through.
    t = math.radians(half_angle)
    apex = np.array([15.0, 10.0])

    def bar(a, b, width=0.01):
        u = (b - a) / np.hypot(*(b - a))
        n = np.array([-u[1], u[0]]) * width / 2
        return {"polygon": [(a - n).tolist(), (b - n).tolist(), (b + n).tolist(), (a + n).tolist()]}

    sides = [bar(apex + 12 * np.array([-math.cos(t), s * math.sin(t)]), apex + np.array([0.05, s * 0.05 * math.tan(t)]))
             for s in (1, -1)]
    world = world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19.5, 19.5]], "obstacles": sides})
    slots, m = 4, 2
    physics = Physics([world] * slots, robots_per_slot=m, crowds=[0] * slots)
    physics.place(np.arange(slots * m), np.column_stack([3.5 + 0.52 * np.arange(slots * m), np.full(slots * m, 10.0)]))
    rng = np.random.default_rng(0)
    for _ in range(40):
        before = physics.positions
        physics.step(np.tile([math.sqrt(2), 0.0], (slots * m, 1)) + rng.normal(0, 0.3, (slots * m, 2)))
        assert_contacts_hold(physics, before)

def test_hundreds_of_fleet_robots_crossing_in_corridors_never_touch(tmp_path):
    # a warehouse of aisles two cells wide: 300 robots, the western half's bound east and the eastern
    # half's west; every step, every pair of discs keeps 2r + SAFETY apart all along the moves
    from apf_physics.control.fleet import Lattice
    from apf_physics.control.shield import SAFETY
    from apf_physics.experiments.fleet import rollout_fleet
    from apf_physics.experiments.movingai import map_world
    from apf_physics.planners import make_planner
    from apf_physics.world.core import Fleet
    from conftest import write_warehouse_map

    path = tmp_path / "wh.map"
    write_warehouse_map(path, blocks=(6, 5), shelf=8, aisle=2, border=2)
    world = map_world(path)
    lattice = Lattice.of(world, (0.5, 0.5))
    free = np.flatnonzero(lattice.free)
    points = lattice.points(free)
    middle = world.size[0] / 2
    rng = np.random.default_rng(0)
    west, east = rng.permutation(free[points[:, 0] < middle]), rng.permutation(free[points[:, 0] >= middle])
    count = 150
    starts = np.concatenate([west[:count], east[:count]])
    goals = np.concatenate([east[count:2 * count], west[count:2 * count]])
    run = rollout_fleet(world, make_planner("astar"), Fleet(lattice.points(starts), lattice.points(goals)))
    s = run.summary()
    assert s["robot_robot_collisions"] == 0 and s["robot_obstacle_collisions"] == 0
    assert s["arrived"] >= 0.99 * 2 * count
    p = run.positions
    for t in range(run.steps):
        before, move = p[t], p[t + 1] - p[t]
        d = before[:, None, :] - before[None, :, :]
        v = move[:, None, :] - move[None, :, :]
        a = np.sum(v * v, axis=-1)
        u = np.clip(np.where(a > 0, -np.sum(d * v, axis=-1) / np.where(a > 0, a, 1.0), 0.0), 0.0, 1.0)
        gap = np.hypot(*(d + u[..., None] * v).transpose(2, 0, 1))
        np.fill_diagonal(gap, np.inf)
        assert gap.min() >= 2 * world.robot_radius + SAFETY - 1e-6
        assert np.all(world.static_clearance(p[t + 1]) >= world.robot_radius)
