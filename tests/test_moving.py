"""Moving obstacles: routes, the field at step t, the physics, observations and planners."""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from apf_physics import world_from_dict
from apf_physics.sim.engine import Stepper
from apf_physics.world.obstacles import CircleObstacle, Motion, PolygonObstacle
from apf_physics.sensing.observation import Observer, ObserverConfig
from apf_physics.planners import make_planner
from apf_physics.experiments.rollout import rollout

from conftest import simple_world_dict


def with_moving(world, *moving):
    """``world`` with extra moving obstacles."""
    return dataclasses.replace(world, obstacles=world.obstacles + tuple(moving))


def bar(x0, y0, length, thickness, path, speed, **kw):
    vertices = np.array([[x0, y0], [x0 + length, y0], [x0 + length, y0 + thickness], [x0, y0 + thickness]])
    return PolygonObstacle(vertices, Motion(np.asarray(path, float), speed, **kw))


# -- routes ------------------------------------------------------------------------------------

def test_ping_pong_and_loop_routes():
    there_and_back = Motion(np.array([[0.0, 12.0]]), 0.4)
    np.testing.assert_allclose(there_and_back.offset([0, 1, 30, 31, 60, 61]),
                               [[0, 0], [0, 0.4], [0, 12], [0, 11.6], [0, 0], [0, 0.4]], atol=1e-12)
    loop = Motion(np.array([[10.0, 0.0], [10.0, 10.0]]), 0.3, loop=True, phase=4.0)
    assert loop.period == pytest.approx(20 + math.sqrt(200))
    np.testing.assert_allclose(loop.offset([0, 20, 100 / 3]), [[4, 0], [10, 0], [10, 4]], atol=1e-9)
    # round again: the same place one period later
    np.testing.assert_allclose(loop.offset(7.5), loop.offset(7.5 + loop.period / loop.speed), atol=1e-9)


def test_the_field_moves_with_the_obstacle():
    world = with_moving(world_from_dict(simple_world_dict(obstacles=[])),
                        CircleObstacle(np.array([10.0, 5.0]), 1.0, Motion(np.array([[0.0, 8.0]]), 0.5)))
    point = np.array([[10.0, 7.3]])   # 1.3 above the disc's rim at step 0; 1.3 below it... inside by step 4
    assert world.obstacle_distance(point, 0)[0] == pytest.approx(1.3)
    assert world.obstacle_distance(point, 4)[0] == pytest.approx(-0.7)
    assert world.potential(point, 4)[0] > world.potential(point, 0)[0]
    np.testing.assert_allclose(world.obstacle_distance(point, np.array([0.0, 4.0]))[:1], [1.3])


def test_observation_adds_moving_terms_and_previous_channel():
    base = world_from_dict(simple_world_dict(field="thesis-general"))
    world = with_moving(base, CircleObstacle(np.array([10.0, 12.0]), 1.0, Motion(np.array([[0.0, -6.0]]), 0.5)))
    positions = np.array([[10.0, 9.0], [3.0, 19.0]])
    observer = Observer(ObserverConfig(channels=("potential", "previous")), 2, [world])
    observer.reset(np.arange(2), positions, [world] * 2)
    obs = observer.observe(positions, t=np.array([4.0, 4.0]))
    points = (positions[:, None, :] + observer._offsets[None]).reshape(-1, 2)
    for channel, t in ((0, 4.0), (1, 3.0)):
        exact = world.potential(points, t)
        blocked = (world.edge_distance(points) < 0) | (world.obstacle_distance(points, t) <= 0)
        exact = np.where(blocked, world.u_wall, np.minimum(exact, world.u_wall)).reshape(2, 11, 11)
        # robot 0 sees the moving disc (exact terms, where the static raster is smooth); robot 1 does not
        near = np.abs(obs[0, channel] - exact[0])
        assert np.median(near) < 0.05 and obs[0, channel].max() == pytest.approx(world.u_wall)
        np.testing.assert_allclose(obs[1, channel], obs[1, 0])
    assert np.any(obs[0, 0] != obs[0, 1])   # the disc moved between step 3 and step 4


# -- physics -------------------------------------------------------------------------------------

def test_a_standing_robot_hit_by_a_moving_obstacle_has_collided():
    world = with_moving(world_from_dict(simple_world_dict(obstacles=[])),
                        bar(2.0, 5.0, 10.0, 0.1, [[0.0, 10.0]], 0.8))
    stepper = Stepper([world], 2, max_steps=30)
    stepper.start(np.arange(2), np.array([[[5.0, 9.0]], [[15.0, 9.0]]]))
    kinds = set()
    while stepper.running.any():
        report = stepper.step(np.zeros((2, 1, 2)))
        kinds |= {c.kind for c in report.contacts.contacts}
    assert stepper.outcome.tolist() == [2, 4]     # collision; the robot beside the bar's sweep: timeout
    assert kinds == {"moving_obstacle"}


thin = st.floats(0.01, 0.3)


@settings(max_examples=int(os.environ.get("APF_TUNNEL_EXAMPLES", 40)), deadline=None)
@given(st.floats(3, 14), st.floats(3, 14), st.floats(1.0, 5.0), thin, st.floats(0, 2 * math.pi), st.floats(0.1, 1.0),
       st.integers(0, 10_000), st.booleans())
def test_no_robot_passes_through_a_sweeping_bar(x, y, length, thickness, heading, speed, seed, standing):
    # a thin bar sweeps back and forth across the map; robots stand or run at full speed
    direction = np.array([math.cos(heading), math.sin(heading)])
    route = np.clip(np.array([x, y]) + 6 * direction, 1.0, 19.0 - length) - np.array([x, y])
    assume(np.hypot(*route) > 1.0)
    world = with_moving(world_from_dict(simple_world_dict(obstacles=[], starts=[], targets=[[0.3, 0.3]])),
                        bar(x, y, length, thickness, [route], speed))
    rng = np.random.default_rng(seed)
    starts = world.random_free_positions(rng, 8, margin=0.6)
    stepper = Stepper([world], 8, max_steps=40)
    stepper.start(np.arange(8), starts[:, None, :])
    velocity = np.zeros((8, 1, 2)) if standing else rng.uniform(-1, 1, (8, 1, 2))
    sides = was_inside = None   # (which side of the bar each robot was on at the last step, and in its span)
    while stepper.running.any():
        report = stepper.step(velocity)
        t = stepper.steps[:, None].astype(float)
        p = report.positions[:, 0]
        assert np.all(world.obstacle_distance(p, stepper.steps.astype(float)) > 0), "a centre inside the bar"
        assert np.all(world.edge_distance(p) > 0), "a centre outside the map"
        # which side of the bar's long axis each robot is on, in the bar's own frame
        local = p - world.obstacles[-1].motion.offset(stepper.steps.astype(float))
        side = np.sign(local[:, 1] - (y + thickness / 2))
        inside_span = (local[:, 0] > x) & (local[:, 0] < x + length)
        if sides is not None:
            crossed = inside_span & was_inside & (side != sides) & report.moved
            assert not crossed.any(), "a robot crossed the bar"
        sides, was_inside = side, inside_span
        del t


# -- planners ----------------------------------------------------------------------------------

def _rim_distance(world, path):
    """(len(path),) the distance of each position of an episode's path (one per step) from the moving obstacles."""
    return np.array([world.obstacle_distance(p[None], float(t))[0] for t, p in enumerate(path)])


def test_planners_run_on_the_field_at_step_t():
    base = world_from_dict(simple_world_dict(obstacles=[], field="thesis-general", targets=[[18.0, 10.0]],
                                             starts=[[2.0, 10.0], [2.0, 4.0], [2.0, 16.0]]))
    # a disc rising along x = 10 from y = 3 to y = 17 (0.5 per step) across the way of the start (2, 4)
    disc = CircleObstacle(np.array([10.0, 3.0]), 1.0, Motion(np.array([[0.0, 14.0]]), 0.5))
    world = with_moving(base, disc)
    centre = lambda t: np.array([10.0, 3.0]) + disc.motion.offset(float(t))
    runs = {name: rollout(world, make_planner(name), world.starts, max_steps=80) for name in ("gradient", "escape", "astar")}
    for name in ("gradient", "escape"):
        for e in runs[name]:
            assert e.outcome != "collision"
            # the robot never overlaps the disc where it is at each step
            assert _rim_distance(world, e.path).min() > world.robot_radius, (name, e.start)
            assert len(e.path) == e.steps + 1 and e.steps < 80
    # gradient descent (measured): the starts the disc does not cross reach the target; from (2, 4) the robot
    # runs into the rising disc's repulsion and is declared trapped within 10 steps, just before the disc where
    # it is *then* (1.15 from its rim at step 9), far from where it was at step 0
    gradient = runs["gradient"]
    assert [e.outcome for e in gradient] == ["reached", "trapped", "reached"]
    trapped = gradient[1]
    assert trapped.steps <= 12
    end = trapped.path[-1]
    assert end[0] < 10.0 - 1.0 and np.hypot(*(end - centre(trapped.steps))) - 1.0 < 1.5
    assert np.hypot(*(end - centre(0))) - 1.0 > 3.0
    # the escape planner follows the gradient up to the trap, then gets past the disc: it crosses x = 10 below it
    escape = runs["escape"]
    assert [e.outcome for e in escape] == ["reached"] * 3
    np.testing.assert_allclose(escape[1].path[:trapped.steps + 1], trapped.path)
    cross = int(np.argmax(escape[1].path[:, 0] >= 10.0))
    assert cross > trapped.steps and escape[1].path[cross, 1] < centre(cross)[1] - 1.0
    # replanning A* reaches from the starts away from the disc's sweep
    assert [e.success for e in runs["astar"]][::2] == [True, True]


# -- the world-file contract -------------------------------------------------------------------

def moving_world_dict(**motion):
    return simple_world_dict(obstacles=[
        {"circle": {"center": [10, 5], "radius": 1.0}, "motion": {"path": [[0, 8]], "speed": 0.4, **motion}},
        {"polygon": [[2, 12], [5, 12], [5, 13], [2, 13]],
         "motion": {"path": [[6, 0], [6, 3]], "speed": 0.3, "loop": True, "phase": 4.0}}])


def test_world_file_motion_round_trips(tmp_path):
    from apf_physics import load_world, save_world

    world = world_from_dict(moving_world_dict())
    assert world.moving == (0, 1)
    save_world(world, tmp_path / "m.yaml")
    again = load_world(tmp_path / "m.yaml")
    for t in (0, 7, 33.5):
        np.testing.assert_allclose(again.moving_offsets(t), world.moving_offsets(t))


@pytest.mark.parametrize("motion, problem", [
    ({"speed": 1.5}, "speed"),
    ({"speed": 0.0}, "speed"),
    ({"path": [[0, 0]]}, "no length"),
    ({"path": [[0, 40]]}, "outside the map"),
    ({"path": [[5, 10]]}, "sweeps over targets"),     # through the target at (15, 15)
    ({"phase": -1}, "phase"),
])
def test_world_file_motion_problems_are_one_line_each(motion, problem):
    from apf_physics import WorldError

    with pytest.raises(WorldError, match=problem):
        world_from_dict(moving_world_dict(**motion))


def test_a_start_touching_a_moving_obstacle_at_step_0_is_refused():
    from apf_physics import WorldError

    data = moving_world_dict()
    data["starts"] = [[10.0, 6.1]]
    with pytest.raises(WorldError, match=r"starts\[0\]"):
        world_from_dict(data)


def test_generated_moving_worlds_are_valid_and_solvable():
    from apf_physics.world.generate import generate_world
    from apf_physics.world.search import reachable

    rng = np.random.default_rng(3)
    for _ in range(4):
        world = generate_world("moving", rng, n_starts=3)
        assert 3 <= len(world.moving) <= 8 + 10
        speeds = [world.obstacles[i].motion.speed for i in world.moving]
        assert min(speeds) >= 0.15 and max(speeds) <= 0.6
        assert all(reachable(world, s) for s in world.starts)
        assert np.all(world.clearance(world.starts, 0.0) >= world.robot_radius)


def test_navigate_env_observes_the_field_at_its_own_step(tmp_path):
    from apf_physics.envs import NavigateEnv, NavigateVectorEnv

    world = with_moving(world_from_dict(simple_world_dict(field="thesis-general", obstacles=[])),
                        CircleObstacle(np.array([10.0, 14.0]), 1.0, Motion(np.array([[0.0, -4.0]]), 0.5)))
    start = np.array([10.0, 9.0])
    env = NavigateEnv(world=world, starts=start[None], previous=True)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2, 11, 11)
    observer = Observer(env.observer, 1, [world])
    observer.reset(np.arange(1), start[None], [world])
    for step in range(1, 6):
        obs, *_ = env.step(8)                         # stay: only the disc moves (down, towards the robot)
        expected = observer.observe(start[None], t=float(step))[0]
        np.testing.assert_allclose(obs, expected, rtol=1e-6)
        assert np.any(obs[0] != obs[1])
    vector = NavigateVectorEnv(world=world, num_envs=2, starts=start[None], previous=True)
    vector.reset(seed=0)
    for _ in range(3):
        obs, *_ = vector.step(np.array([8, 8]))
    np.testing.assert_allclose(obs[0], observer.observe(start[None], t=3.0)[0], rtol=1e-6)


def test_a_new_episode_is_placed_among_the_obstacles_where_they_are_at_step_0():
    # the disc has moved onto (10, 9) by step 6; a new episode starting there (free at step 0) is fine
    world = with_moving(world_from_dict(simple_world_dict(obstacles=[])),
                        CircleObstacle(np.array([10.0, 12.0]), 1.0, Motion(np.array([[0.0, -3.0]]), 0.5)))
    stepper = Stepper([world], 2, max_steps=50)
    stepper.start(np.arange(2), np.array([[[3.0, 3.0]], [[16.0, 3.0]]]))
    for _ in range(6):
        stepper.step(np.zeros((2, 1, 2)))
    assert world.clearance(np.array([[10.0, 9.0]]), 6.0)[0] < 0 < world.clearance(np.array([[10.0, 9.0]]), 0.0)[0]
    stepper.start(np.array([1]), np.array([[[10.0, 9.0]]]))
    assert stepper.steps.tolist() == [6, 0]
    report = stepper.step(np.zeros((2, 1, 2)))
    assert stepper.outcome[0] == 0 and report.positions[1, 0].tolist() == [10.0, 9.0]
