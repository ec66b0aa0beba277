"""The episode rules in one place: an environment episode and an ``eval`` rollout of the same
planner from the same start end the same way, at the same step (reached, also at the start;
collision; trapped, with the environment's trap detector; moving obstacles)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from apf_physics import load_world
from apf_physics.control.shield import ACTIONS
from apf_physics.sim.engine import TrapDetector
from apf_physics.envs import NavigateVectorEnv
from apf_physics.errors import UserError
from apf_physics.planners import make_planner
from apf_physics.planners.base import Planner
from apf_physics.experiments.rollout import default_max_steps, rollout

UP, DOWN, LEFT = 0, 1, 2


class Scripted(Planner):
    """Moves of Model Table 1 by index, repeated in turn."""

    name = "scripted"
    trap_rule = "oscillation"

    def __init__(self, *actions: int):
        self.actions = actions

    def reset(self, world, positions):
        super().reset(world, positions)
        self.count = 0

    def act(self, positions, active, moment=None):
        move = ACTIONS[self.actions[self.count % len(self.actions)]]
        self.count += 1
        return np.where(active[:, None], move, 0.0)


def detector_of(planner: Planner) -> TrapDetector:
    """The trap detector ``eval`` gives ``planner`` (its rule and window)."""
    return TrapDetector(planner.trap_rule, planner.trap_window or TrapDetector().window)


def env_episode(world, planner: Planner, start, trap) -> dict:
    """``planner`` steering ``Navigate-v0`` from ``start`` (its moves as the env's actions) until the episode ends."""
    env = gym.make("apf_physics/Navigate-v0", world=world, trap=trap, max_episode_steps=default_max_steps(world))
    _, info = env.reset(seed=0, options={"start": list(start)})
    stepper = env.unwrapped.task.stepper
    planner.reset(world, np.asarray(start, float)[None])
    path = [info["position"]]
    while True:
        move = planner.act(info["position"][None], np.ones(1, bool), stepper.moment(0))[0]
        action = int(np.flatnonzero(np.all(ACTIONS == move, axis=1))[0])
        _, reward, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
        path.append(info["position"])
    if info["success"]:
        outcome = "reached"
    elif info["collision"]:
        outcome = "collision"
    elif info.get("trapped"):
        outcome = "trapped"
    else:
        outcome = "timeout"
    if not np.array_equal(info["position"], path[-1]):
        path.append(info["position"])
    return {"outcome": outcome, "steps": int(stepper.steps[0]), "path": np.array(path), "terminated": terminated,
            "truncated": truncated, "reward": reward, "info": info}


def eval_episode(world, planner: Planner, start):
    (episode,) = rollout(world, planner, np.asarray(start, float)[None])
    return episode


def assert_same_end(world, make, start, expected: str, trap: str | TrapDetector | None = "planner") -> dict:
    """The env (with the planner's trap detector unless ``trap`` says otherwise) and eval end alike."""
    episode = eval_episode(world, make(), start)
    planner = make()
    if trap == "planner":
        planner.reset(world, np.asarray(start, float)[None])   # a planner's window may depend on its model
        trap = detector_of(planner)
    run = env_episode(world, planner, start, trap)
    assert episode.outcome == expected
    assert (run["outcome"], run["steps"]) == (episode.outcome, episode.steps)
    np.testing.assert_array_equal(run["path"], episode.path)
    return run


def test_reached_the_same_way():
    world = load_world("fixed20")
    run = assert_same_end(world, lambda: make_planner("dqn", "fixed20"), world.starts[0], "reached")
    assert run["terminated"] and not run["truncated"] and run["info"]["success"]


def test_reached_among_moving_obstacles_the_same_way():
    world = load_world("moving_obstacles")
    assert world.moving
    assert_same_end(world, lambda: make_planner("dqn", "moving"), world.starts[0], "reached")


def test_start_at_the_target_ends_at_once_everywhere():
    world = load_world("fixed20")
    start = world.targets[0] + [0.5, 0.25]            # within the goal tolerance (0.75), free
    assert world.distance_to_target(start[None])[0] <= world.goal_tolerance
    episode = eval_episode(world, make_planner("gradient"), start)
    assert (episode.outcome, episode.steps) == ("reached", 0)
    for trap in (None, "oscillation"):
        run = env_episode(world, Scripted(LEFT), start, trap)
        assert (run["outcome"], run["steps"]) == ("reached", 0)
        assert run["terminated"] and not run["truncated"] and run["reward"] == 0.0
        np.testing.assert_array_equal(run["info"]["position"], start)   # not moved
        assert all(v == 0.0 for v in run["info"]["reward_terms"].values())


def test_start_at_the_target_in_the_vector_env():
    world = load_world("fixed20")
    start = world.targets[0] + [0.5, 0.25]
    vec = NavigateVectorEnv(world=world, num_envs=2, starts=np.array([start]))
    vec.reset(seed=0)
    for _ in range(2):   # ended at the start, reported by the next step; restarted (NEXT_STEP) the step after
        _, reward, terminated, truncated, info = vec.step(np.array([LEFT, LEFT]))
        assert terminated.all() and not truncated.any() and (reward == 0.0).all()
        assert info["success"].all() and info["_success"].all() and not info["collision"].any()
        np.testing.assert_array_equal(info["position"], [start, start])
        _, reward, terminated, _, info = vec.step(np.array([LEFT, LEFT]))
        assert (reward == 0.0).all() and not terminated.any() and not info["_success"].any()


def test_collision_the_same_way():
    world = load_world("fixed20")
    run = assert_same_end(world, lambda: Scripted(LEFT), world.starts[1], "collision")
    assert run["terminated"] and run["info"]["collision"] and not run["info"]["success"]


@pytest.mark.parametrize("trap", ["oscillation", TrapDetector("oscillation", window=10)])
def test_trapped_the_same_way_with_the_detector_on(trap):
    world = load_world("fixed20")
    start = np.array([2.0, 10.0])
    run = assert_same_end(world, lambda: Scripted(UP, DOWN), start, "trapped", trap=trap)
    assert run["truncated"] and not run["terminated"] and run["info"]["trapped"]
    assert run["steps"] == TrapDetector().window


def test_trapped_with_a_planners_own_window():
    """The memory network's planner is judged over 40 steps; the env given that detector agrees."""
    world = load_world("fixed20")
    planner = Scripted(UP, DOWN)
    planner.trap_window = 40
    episode = eval_episode(world, planner, [2.0, 10.0])
    run = env_episode(world, planner, [2.0, 10.0], detector_of(planner))
    assert (run["outcome"], run["steps"]) == (episode.outcome, episode.steps) == ("trapped", 40)


def test_no_trap_rule_by_default():
    """Without ``trap`` (training's default) the oscillating robot runs to the step limit."""
    world = load_world("fixed20")
    run = env_episode(world, Scripted(UP, DOWN), [2.0, 10.0], None)
    assert run["outcome"] == "timeout" and run["steps"] == default_max_steps(world)
    assert "trapped" not in run["info"]


def test_vector_env_reports_trapped():
    world = load_world("fixed20")
    vec = NavigateVectorEnv(world=world, num_envs=2, starts=np.array([[2.0, 10.0]]), trap="oscillation")
    vec.reset(seed=0)
    for k in range(TrapDetector().window):
        _, _, terminated, truncated, info = vec.step(np.array([UP, DOWN]) if k % 2 == 0 else np.array([DOWN, UP]))
    assert truncated.all() and not terminated.any()
    assert info["trapped"].all() and info["_trapped"].all()


def test_formation_env_takes_the_trap_option():
    env = gym.make("apf_physics/Formation-v0", world="fixed20", trap="oscillation")
    env.reset(seed=0, options={"start": [2.0, 10.0]})
    for k in range(TrapDetector().window):
        _, _, terminated, truncated, info = env.step(UP if k % 2 == 0 else DOWN)
    assert truncated and not terminated and info["trapped"]


def test_unknown_trap_rule_is_refused():
    with pytest.raises(UserError, match="trap must be"):
        gym.make("apf_physics/Navigate-v0", world="fixed20", trap="sometimes")
