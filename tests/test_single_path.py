"""One robot: the single environment's scalar path gives exactly the array path's episodes.

A batch of one robot (``Navigate-v0``) is stepped by the scalar path of
:class:`~apf_physics.sim.engine.Stepper` and :class:`~apf_physics.envs.task.NavigationTask`
(``Stepper.scalar``); the vector environment by the array path. From the same seed and
actions both give the same episodes to the last bit: observations, rewards and their terms,
ends, positions, distances. The vector environment is compared with one copy (its array path
forced), so that only the two code paths differ, not the pymunk space around the robot.
"""

import gymnasium as gym
import numpy as np
import pytest

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics.sim.engine import Stepper, TrapDetector
from apf_physics.envs import NavigateVectorEnv
from apf_physics.world.io.worldfile import load_world

CASES = [
    ("fixed20.yaml", {}),
    ("fixed20.yaml", {"reward": "general", "memory": True, "obs_scale": "log"}),
    ("fixed20.yaml", {"trap": "descent"}),
    ("moving_obstacles.yaml", {"previous": True}),
    ("moving_obstacles.yaml", {"previous": True, "obs_scale": "log", "trap": "oscillation"}),
]


@pytest.mark.parametrize("name,options", CASES)
def test_single_env_gives_the_vector_env_episodes_exactly(worlds_dir, name, options):
    world = str(worlds_dir / name)
    vec = NavigateVectorEnv(world=world, num_envs=1, starts="random", max_episode_steps=100, **options)
    vec.task.stepper.scalar = False   # the array path
    single = gym.make("apf_physics/Navigate-v0", world=world, starts="random", **options)
    assert single.unwrapped.task.stepper.scalar
    obs, info = vec.reset(seed=5)
    o, inf = single.reset(seed=5)
    np.testing.assert_array_equal(obs[0], o)
    assert info["distance"][0] == inf["distance"]
    rng = np.random.default_rng(3)
    pending = False
    ended = 0
    for _ in range(600):
        action = int(rng.integers(0, 9))
        obs, reward, terminated, truncated, info = vec.step(np.array([action]))
        if pending:   # NEXT_STEP autoreset: this step is the reset
            o, inf = single.reset()
        else:
            o, r, te, tr, inf = single.step(action)
            assert reward[0] == np.float32(r)
            assert terminated[0] == te
            assert truncated[0] == tr or te   # Gymnasium's TimeLimit also truncates an episode ending at step 100
            assert inf["success"] == info["success"][0] and inf["collision"] == info["collision"][0]
            assert inf["reward_terms"] == {k: v[0] for k, v in info["reward_terms"].items() if not k.startswith("_")}
            if "trapped" in inf:
                assert inf["trapped"] == info["trapped"][0]
        np.testing.assert_array_equal(obs[0], o)
        np.testing.assert_array_equal(info["position"][0], inf["position"])
        assert info["distance"][0] == inf["distance"]
        pending = bool(terminated[0] or truncated[0])
        ended += pending
    assert ended > 3


def test_a_stepper_of_one_reports_as_the_array_path(worlds_dir):
    """The same commands to two steppers of one slot, one on the scalar path: the same reports."""
    world = load_world(worlds_dir / "fixed20.yaml")
    trap = TrapDetector("descent", window=6)
    one = Stepper([world], 1, max_steps=30, trap=trap)
    array = Stepper([world], 1, max_steps=30, trap=trap)
    array.scalar = False
    rng = np.random.default_rng(0)
    starts = world.random_free_positions(rng, 200)
    k = 0
    for stepper in (one, array):
        stepper.start([0], starts[k][None, None])
    outcomes = set()
    for _ in range(1500):
        command = rng.integers(-1, 2, (1, 1, 2)).astype(float)
        a, b = one.step(command), array.step(command)
        np.testing.assert_array_equal(a.positions, b.positions)
        for field in ("moved", "collided", "reached", "ended", "distance"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), field)
        np.testing.assert_array_equal(a.contacts.any, b.contacts.any)
        assert one.outcome[0] == array.outcome[0] and one.steps[0] == array.steps[0]
        if a.ended[0]:
            outcomes.add(int(one.outcome[0]))
            k += 1
            for stepper in (one, array):
                stepper.start([0], starts[k % 200][None, None])
    assert len(outcomes) >= 3
