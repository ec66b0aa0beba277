"""Robots as real robots are driven: unicycles in the one engine, continuous actions and the range
sensor in every environment.

- A unicycle alone in open space drives exactly the arc of :func:`kinematics.integrate`, through
  the same :class:`Stepper` and physics as every robot.
- Unicycles driven at random into thin walls and into each other end every step outside the
  walls and each other (the contact bounds of ``tests/contacts_check.py``), alone or in slots
  of several.
- Gymnasium's checker passes for every combination of action, kinematics and observation, in
  ``Navigate-v0`` and ``Formation-v0``; the vector env's copy ``i`` seeded ``seed + i`` repeats
  ``Navigate-v0`` seeded ``seed + i`` for a unicycle with continuous actions and lidar.
- The world file's ``robot: {kinematics: unicycle, ...}`` reaches the environment, and bad
  values are named.
"""

import math
import os

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import apf_physics
from apf_physics import world_from_dict
from apf_physics.sim.engine import Stepper
from apf_physics.errors import UserError
from apf_physics.world.kinematics import UnicycleLimits, integrate
from conftest import simple_world_dict
from contacts_check import assert_contacts_hold
from test_contacts_hold import thin_walls

EXAMPLES = int(os.environ.get("APF_CONTACT_EXAMPLES", 4))
COMBINATIONS = [(a, k, o) for a in ("discrete", "continuous") for k in ("holonomic", "unicycle")
                for o in ("window", "lidar", "window+lidar")]


def test_a_free_unicycle_drives_the_exact_arc():
    world = world_from_dict(simple_world_dict(obstacles=[], size=[40, 40], targets=[[38, 38]]))
    limits = UnicycleLimits()
    stepper = Stepper([world], 3, unicycle=limits)
    starts = np.array([[10.0, 10.0], [20.0, 12.0], [12.0, 25.0]])
    stepper.start(np.arange(3), starts[:, None, :], headings=np.array([[0.0], [1.0], [-2.0]]))
    state = stepper.states()[:, 0]
    rng = np.random.default_rng(0)
    for _ in range(8):
        command = np.column_stack([rng.uniform(-0.5, 1.0, 3), rng.uniform(-1.5, 1.5, 3)])
        v, omega = limits.clamp(command[:, 0], command[:, 1], state[:, 3], state[:, 4])
        state = integrate(state, v, omega)
        report = stepper.step(command[:, None, :])
        assert not report.collided.any()
        np.testing.assert_allclose(stepper.states()[:, 0], state, atol=1e-9)


def test_the_limits_bound_speed_turn_and_acceleration():
    world = world_from_dict(simple_world_dict(obstacles=[], size=[40, 40], targets=[[38, 38]]))
    limits = UnicycleLimits(max_speed=0.8, max_reverse=0.3, max_turn_rate=1.0, max_accel=0.25, max_turn_accel=0.5)
    stepper = Stepper([world], 1, unicycle=limits)
    stepper.start([0], [[[20.0, 20.0]]], headings=[[0.0]])
    for _ in range(6):
        stepper.step(np.array([[[5.0, 5.0]]]))
    np.testing.assert_allclose(stepper.drive[0, 0], [0.8, 1.0])
    stepper.start([0], [[[20.0, 20.0]]], headings=[[0.0]])
    stepper.step(np.array([[[5.0, -5.0]]]))
    np.testing.assert_allclose(stepper.drive[0, 0], [0.25, -0.5])   # one step from rest


def random_drives(rng, n, steps, hold=5):
    """(steps, n, 2) commands ``(v, ω)`` beyond the limits at random, each held about ``hold`` steps."""
    command = np.column_stack([rng.uniform(-1, 1.5, n), rng.uniform(-2, 2, n)])
    out = []
    for _ in range(steps):
        change = rng.random(n) < 1 / hold
        command[change] = np.column_stack([rng.uniform(-1, 1.5, int(change.sum())), rng.uniform(-2, 2, int(change.sum()))])
        out.append(command.copy())
    return out


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([1, 3, 16]))
def test_unicycles_driven_into_walls_and_each_other_hold(seed, robots):
    rng = np.random.default_rng(seed)
    slots = 48 if robots == 1 else 2
    world = thin_walls(rng)
    stepper = Stepper([world], slots, robots, unicycle=UnicycleLimits(max_speed=math.sqrt(2)))
    starts = np.stack([world.random_free_positions(rng, robots) for _ in range(slots)])
    stepper.start(np.arange(slots), starts, headings=rng.uniform(-math.pi, math.pi, (slots, robots)))
    physics = stepper.physics
    for command in random_drives(rng, slots * robots, 25):
        before = physics.positions
        stepper.outcome[:] = 0   # keep every robot moving after it touches: the physics is what is checked
        stepper.step(command.reshape(slots, robots, 2))
        assert_contacts_hold(physics, before)


@pytest.mark.parametrize("action,kinematics,observation", COMBINATIONS)
def test_navigate_passes_gymnasiums_checker(action, kinematics, observation):
    env = gym.make("apf_physics/Navigate-v0", world="fixed20", action=action, kinematics=kinematics,
                   observation=observation, lidar={"beams": 16})
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        if terminated or truncated:
            break


@pytest.mark.parametrize("action,kinematics,observation",
                         [c for c in COMBINATIONS if c[1] == "holonomic"])
def test_formation_passes_gymnasiums_checker(action, kinematics, observation):
    env = gym.make("apf_physics/Formation-v0", world="fixed20", action=action, kinematics=kinematics,
                   observation=observation, lidar={"beams": 16})
    check_env(env.unwrapped)


def test_the_vector_env_repeats_the_single_one_for_unicycles_with_lidar():
    options = dict(world="fixed20", action="continuous", kinematics="unicycle", observation="lidar",
                   lidar={"beams": 24, "noise": 0.05}, starts="random")
    vec = apf_physics.envs.NavigateVectorEnv(num_envs=3, **options)
    singles = [gym.make("apf_physics/Navigate-v0", **options) for _ in range(3)]
    obs, _ = vec.reset(seed=10)
    np.testing.assert_array_equal(obs[0], singles[0].reset(seed=10)[0])
    rng = np.random.default_rng(1)
    for _ in range(30):
        actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        obs, reward, terminated, truncated, info = vec.step(actions)
        out = singles[0].step(actions[0])
        np.testing.assert_allclose(obs[0], out[0], atol=1e-6)
        assert reward[0] == pytest.approx(out[1])
        if terminated[0] or truncated[0]:
            break


def test_the_world_files_robot_reaches_the_env():
    data = simple_world_dict(obstacles=[])
    data["robot"] = {"kinematics": "unicycle", "max_turn_rate": 1.0, "max_speed": 0.5}
    world = world_from_dict(data)
    env = gym.make("apf_physics/Navigate-v0", world=world, action="continuous")
    assert env.unwrapped.robot.unicycle == UnicycleLimits(max_speed=0.5, max_turn_rate=1.0)
    assert "heading" in env.reset(seed=0)[1]
    # the option overrides the file
    assert gym.make("apf_physics/Navigate-v0", world=world, kinematics="holonomic").unwrapped.robot.unicycle is None


@pytest.mark.parametrize("robot,message", [
    ({"kinematics": "car"}, "robot.kinematics: expected one of holonomic, unicycle"),
    ({"max_speed": 2}, "robot.max_speed: only for a unicycle robot"),
    ({"kinematics": "unicycle", "max_turn_rate": -1}, "robot.max_turn_rate: must be positive"),
    ({"kinematics": "unicycle", "wheels": 2}, "wheels"),
])
def test_bad_robot_keys_are_named(robot, message):
    data = simple_world_dict(obstacles=[])
    data["robot"] = robot
    with pytest.raises(UserError, match=message):
        world_from_dict(data)


@pytest.mark.parametrize("options,message", [
    ({"action": "analog"}, "action must be one of discrete, continuous"),
    ({"kinematics": "tank"}, "kinematics must be one of holonomic, unicycle"),
    ({"observation": "camera"}, "observation must be one of window, lidar, window[+]lidar"),
    ({"limits": {"max_speed": 2}}, "limits= is for unicycle robots"),
    ({"kinematics": "unicycle", "limits": {"top": 2}}, "limits: unknown keys"),
    ({"observation": "lidar", "lidar": {"beams": 0}}, "lidar beams must be positive"),
])
def test_bad_env_options_are_named(options, message):
    with pytest.raises(UserError, match=message):
        gym.make("apf_physics/Navigate-v0", world="fixed20", **options)
