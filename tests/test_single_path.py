"""One step path: the single environment, a vector environment of one copy, and a robot among
others give the same episodes to the last bit: observations, rewards and their terms, ends,
positions, distances.
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
    single = gym.make("apf_physics/Navigate-v0", world=world, starts="random", **options)
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


def test_a_stepper_of_one_reports_as_a_slot_of_a_batch(worlds_dir):
    """The same commands to a stepper of one slot and to slot 0 of a stepper of two: the same reports."""
    world = load_world(worlds_dir / "fixed20.yaml")
    trap = TrapDetector("descent", window=6)
    one = Stepper([world], 1, max_steps=30, trap=trap)
    two = Stepper([world], 2, max_steps=30, trap=trap)
    rng = np.random.default_rng(0)
    starts = world.random_free_positions(rng, 200)
    k = 0
    one.start([0], starts[k][None, None])
    two.start([0, 1], np.stack([starts[k], starts[-1]])[:, None])
    outcomes = set()
    for _ in range(1500):
        command = rng.integers(-1, 2, (1, 1, 2)).astype(float)
        a, b = one.step(command), two.step(np.concatenate([command, -command]))
        np.testing.assert_array_equal(a.positions[0], b.positions[0])
        for field in ("moved", "collided", "reached", "ended", "distance"):
            np.testing.assert_array_equal(getattr(a, field)[0], getattr(b, field)[0], field)
        assert a.contacts.any[0] == b.contacts.any[0]
        assert one.outcome[0] == two.outcome[0] and one.steps[0] == two.steps[0]
        if a.ended[0]:
            outcomes.add(int(one.outcome[0]))
            k += 1
            one.start([0], starts[k % 200][None, None])
            two.start([0], starts[k % 200][None, None])
        if b.ended[1]:
            two.start([1], starts[(-k - 1) % 200][None, None])
    assert len(outcomes) >= 3
