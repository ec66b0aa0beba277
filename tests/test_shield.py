"""Checked moves and stateful planners: move_clearance, the DQN planner's shield, planners'
own trap windows, and the revisit reward term (W5)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics import load_world
from apf_physics.control.shield import ACTIONS, SAFETY, move_clearance
from apf_physics.envs import NavigateVectorEnv
from apf_physics.envs.reward import REWARD_PRESETS, TERMS, RewardWeights
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.planners import make_planner
from apf_physics.planners.base import Planner
from apf_physics.planners.dqn import DQNPlanner, shielded_argmax
from apf_physics.sim.engine import TrapDetector
from apf_physics.experiments.rollout import rollout
from apf_physics.world.core import MOVE_REACH
from apf_physics.world.io.worldfile import world_from_dict

from conftest import simple_world_dict


class ConstantPolicy:
    """A stand-in for :class:`~apf_physics.models.policy.DQNPolicy` that always ranks the moves the same way."""

    def __init__(self, preference: np.ndarray, channels: int = 1, size: int = 5):
        self.preference = np.asarray(preference, np.float32)
        self.obs_shape = (channels, size, size)
        self.observer = ObserverConfig(size=size, channels=("potential", "memory")[:channels])

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        return np.tile(self.preference, (len(obs), 1))

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.q_values(obs).argmax(1)


@pytest.fixture(scope="module")
def world():
    return world_from_dict(simple_world_dict())


@settings(max_examples=60, deadline=None)
@given(x=st.floats(0.3, 19.7), y=st.floats(0.3, 19.7))
def test_move_clearance_is_a_lower_bound_along_the_whole_move(world, x, y):
    bound = move_clearance(world, np.array([[x, y]]))[0]
    t = np.linspace(0.0, 1.0, 401)
    for k, move in enumerate(ACTIONS):
        dense = world.clearance(np.array([x, y]) + t[:, None] * move).min()
        assert bound[k] <= dense + 1e-9
        # and not far below it, up to where a move's clearance is measured exactly
        exact_to = world.robot_radius + MOVE_REACH
        assert bound[k] >= min(dense, exact_to) - 0.5 * np.hypot(*move) / 8 - 0.1


def test_move_clearance_shape_and_stay(world):
    positions = np.array([[2.0, 2.0], [7.0, 4.0], [10.0, 15.0]])
    room = move_clearance(world, positions)
    assert room.shape == (3, 9)
    np.testing.assert_allclose(room[:, 8], world.clearance(positions, near=True))   # "stay" is the point itself
    # from (7, 4) the polygon's bottom edge (y = 5) is 1 above: moving up ends inside it
    assert room[1, 0] < 0 < room[1, 1]


def test_shielded_argmax_prefers_safe_moves_and_falls_back_to_the_most_room():
    q = np.array([[5.0, 4.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    room = np.array([[-0.1, 0.2, 0.3], [0.1, 0.1, 0.1], [-0.3, -0.1, -0.2]])
    np.testing.assert_array_equal(shielded_argmax(q, room), [1, 2, 1])


def test_shield_keeps_a_wall_seeking_policy_from_colliding(world):
    starts = np.array([[6.5, 3.2], [2.0, 1.5], [12.0, 2.5]])   # below the polygon, near the edge, below the circle
    wants_up_then_down = np.array([9, 8, 0, 0, 0, 0, 0, 0, 0], float)   # "up" first, "down" second
    raw = rollout(world, DQNPlanner(shield=False, policy=ConstantPolicy(wants_up_then_down)), starts, max_steps=30)
    # unshielded, each robot runs up into what is above it: the polygon, the map's top edge, the circle
    assert [e.outcome for e in raw] == ["collision"] * 3
    shielded = DQNPlanner(policy=ConstantPolicy(wants_up_then_down))
    episodes = rollout(world, shielded, starts, max_steps=30)
    up, down = ACTIONS[0], ACTIONS[1]
    need = world.robot_radius + SAFETY
    t = np.linspace(0.0, 1.0, 101)[:, None]
    for e, stop_below in zip(episodes, (5.0, 20.0, 3.5)):
        # not kept still: it pushes up to the last place from which "up" keeps SAFETY clear, then paces there
        assert e.outcome == "trapped" and e.steps >= 10
        for here, there in zip(e.path[:-1], e.path[1:]):
            up_is_safe = move_clearance(world, here[None])[0, 0] >= need
            # the policy's own choice whenever it is safe, its second choice otherwise
            np.testing.assert_allclose(there - here, up if up_is_safe else down, atol=1e-6)
            # and the whole move, not only where it ends, keeps the robot SAFETY clear
            assert world.clearance(here + t * (there - here)).min() >= need - 1e-6
        top = e.path[:, 1].max()
        assert stop_below - 1.0 - need <= top < stop_below - need     # within one move of what is above
        assert not move_clearance(world, e.path[e.path[:, 1].argmax()][None])[0, 0] >= need


def test_planner_names_for_the_shield():
    assert make_planner("dqn").name == "dqn" and make_planner("dqn").shield
    unshielded = make_planner("dqn-unshielded")
    assert unshielded.name == "dqn-unshielded" and not unshielded.shield


class Pacing(Planner):
    """Steps right and left forever."""

    def __init__(self, window: int | None):
        self.trap_window = window
        self.t = 0

    def act(self, positions, active, t=0):
        self.t += 1
        move = ACTIONS[3] if self.t % 2 else ACTIONS[2]
        return np.tile(move, (len(positions), 1)) * active[:, None]


@pytest.mark.parametrize("window", [None, 25])
def test_rollout_uses_the_planners_trap_window(world, window):
    (episode,) = rollout(world, Pacing(window), np.array([[2.0, 15.0]]), max_steps=100)
    assert episode.outcome == "trapped"
    assert episode.steps == (window or TrapDetector().window)


def test_a_memory_model_gets_the_long_trap_window(world):
    planner = DQNPlanner(policy=ConstantPolicy(np.zeros(9), channels=2))
    planner.reset(world, np.array([[2.0, 2.0]]))
    assert planner.trap_window == DQNPlanner.MEMORY_TRAP_WINDOW
    planner = DQNPlanner(policy=ConstantPolicy(np.zeros(9), channels=1))
    planner.reset(world, np.array([[2.0, 2.0]]))
    assert planner.trap_window is None


def test_revisit_term_counts_earlier_visits_up_to_the_cap(worlds_dir):
    weights = RewardWeights(w1=-1000, w2=1000, w3=-1, beta=-4, revisit=-10)
    env = NavigateVectorEnv(world=str(worlds_dir / "fixed20.yaml"), num_envs=2, reward=weights,
                            starts=[[10.3, 17.6]], max_episode_steps=50)
    assert env.single_observation_space.shape[0] == 1   # counted without showing the memory channel
    env.reset(seed=4)
    seen = []
    for t in range(8):   # robot 0 stays; robot 1 paces between two cells
        _, reward, terminated, truncated, info = env.step(np.array([8, 3 if t % 2 == 0 else 2]))
        assert not (terminated.any() or truncated.any())
        terms = info["reward_terms"]
        np.testing.assert_allclose(reward, sum(terms[name] for name in TERMS), rtol=1e-5)
        seen.append(terms["revisit"])
    seen = np.array(seen)
    # the start cell was counted at reset: staying there has been seen 1, 2, 3, then 4 (the cap) times
    np.testing.assert_array_equal(seen[:, 0], [-10, -20, -30, -40, -40, -40, -40, -40])
    # pacing enters a new cell first, then cells seen 1, 1, 2, 2, 3, 3, 4 times
    np.testing.assert_array_equal(seen[:, 1], [0, -10, -10, -20, -20, -30, -30, -40])


def test_thesis_rewards_have_no_revisit_term(worlds_dir):
    assert REWARD_PRESETS["thesis-fixed"].revisit == 0 and REWARD_PRESETS["thesis-general"].revisit == 0
    env = NavigateVectorEnv(world=str(worlds_dir / "fixed20.yaml"), num_envs=2, starts="random")
    env.reset(seed=0)
    for _ in range(3):
        *_, info = env.step(np.array([8, 8]))
    np.testing.assert_array_equal(info["reward_terms"]["revisit"], 0.0)


def test_formation_env_has_the_leaders_memory_and_revisit_term(worlds_dir):
    import gymnasium as gym

    import apf_physics  # noqa: F401

    env = gym.make("apf_physics/Formation-v0", world=str(worlds_dir / "fixed20.yaml"), memory=True,
                   reward=dict(w1=-1, w2=1, w3=-1, beta=0, revisit=-1))
    obs, _ = env.reset(options={"start": [10.3, 17.6]})
    assert obs.shape == (2, 11, 11) and obs[1, 5, 5] == 0.25     # the leader's start cell, counted once
    revisits = []
    for action in (8, 8, 3):                                      # stay twice, then a new cell
        obs, reward, terminated, truncated, info = env.step(action)
        assert not terminated
        revisits.append(info["reward_terms"]["revisit"])
    assert revisits == [-1, -2, 0]
    assert obs[1, 5, 4] == 0.75                                   # the cell left behind: seen three times


def test_shield_removes_collisions_at_little_cost_on_fixed20(worlds_dir):
    world = load_world(worlds_dir / "fixed20.yaml")
    starts = world.random_free_positions(np.random.default_rng(5), 120, away_from_targets=True)
    shielded = rollout(world, make_planner("dqn"), starts)
    alone = rollout(world, make_planner("dqn-unshielded"), starts)
    assert sum(e.outcome == "collision" for e in shielded) == 0
    assert sum(e.success for e in shielded) >= sum(e.success for e in alone) - 2
    # the moves the shield overrides are only those that would have touched something
    assert sum(e.success for e in shielded) >= 0.9 * len(starts)


def test_length_term_charges_the_distance_moved_and_shaping_discounts_the_next_potential(worlds_dir):
    weights = RewardWeights(w1=-1000, w2=1000, w3=-1, beta=-4, length=-20, potential_discount=0.9)
    env = NavigateVectorEnv(world=str(worlds_dir / "fixed20.yaml"), num_envs=3, reward=weights,
                            starts=[[10.0, 16.0], [10.0, 16.0], [10.0, 16.0]])
    env.reset(seed=0)
    world = env.worlds[0]
    before = world.potential(np.array([[10.0, 16.0]]))[0]
    _, reward, *_, info = env.step(np.array([3, 6, 8]))   # right, right-up, stay
    terms = info["reward_terms"]
    np.testing.assert_allclose(terms["length"], [-20, -20 * np.sqrt(2), 0], atol=0.05)
    after = world.potential(np.array([[11.0, 16.0], [11.0, 17.0], [10.0, 16.0]]))
    np.testing.assert_allclose(terms["potential"], -4 * (0.9 * after - before), rtol=1e-3, atol=0.5)
    np.testing.assert_allclose(reward, sum(terms[name] for name in TERMS), rtol=1e-5)


def test_a_move_with_exactly_no_room_to_spare_is_safe():
    # room >= 0 is safe: the best-valued move with room exactly 0 beats a worse one with more room
    q = np.array([[3.0, 2.0, 1.0]])
    np.testing.assert_array_equal(shielded_argmax(q, np.array([[0.0, 0.5, 1.0]])), [0])
    np.testing.assert_array_equal(shielded_argmax(q, np.array([[-1e-12, 0.5, 1.0]])), [1])


def test_move_clearance_takes_moving_obstacles_where_they_are_at_step_t():
    # (the world at step t, World.at(t); a World itself: its static obstacles only)
    import dataclasses

    from apf_physics.world.obstacles import CircleObstacle, Motion

    base = world_from_dict(simple_world_dict(obstacles=[]))
    disc = CircleObstacle(np.array([10.0, 14.0]), 1.0, Motion(np.array([[0.0, -8.0]]), 0.5))
    world = dataclasses.replace(base, obstacles=base.obstacles + (disc,))
    here = np.array([[10.0, 9.0]])
    # at step 0 the disc is 4 away (moving 0.5 nearer during the move); by step 6 it is 1 above, at 8 on the robot
    assert np.all(move_clearance(world.at(0), here) > 2.0)
    at6 = move_clearance(world.at(6), here)
    assert at6[0, 0] < world.robot_radius < at6[0, 1]           # up runs into it; down gets away
    for t in (3, 6):     # as if the disc stood where it is then (it moves 0.5 during the move)
        still = world_from_dict(simple_world_dict(obstacles=[{"circle": {"center": [10.0, 14.0 - 0.5 * t], "radius": 1.0}}]))
        exact_to = world.robot_radius + MOVE_REACH                # what either reads exactly
        np.testing.assert_allclose(np.minimum(move_clearance(world.at(t), here), exact_to),
                                   np.minimum(move_clearance(still, here), exact_to), atol=0.5 + 1e-9)
