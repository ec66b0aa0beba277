"""Episode starts: the batch draw gives each row what a single draw gives, and a single
environment over several worlds starts (and steps) exactly as the vector env's array path.

A world list makes the stepper change a slot's world between episodes (only slots that change
worlds are sent to the physics' ``set_world``); ``starts="world"`` draws from the worlds' start
lists, ``"random"`` from their free cells.
"""

import gymnasium as gym
import numpy as np
import pytest

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics.envs import NavigateVectorEnv
from apf_physics.envs.options import StartChooser
from apf_physics.world.io.worldfile import load_world


@pytest.mark.parametrize("starts", ["world", "random"])
@pytest.mark.parametrize("names", [["fixed20"], ["fixed20", "moving_obstacles", "local_minimum"]])
def test_a_batch_draw_gives_each_row_its_own_draw(worlds_dir, starts, names):
    chooser = StartChooser(starts, [load_world(worlds_dir / f"{n}.yaml") for n in names])
    uniforms = np.random.default_rng(0).random((300, 4))
    worlds, points = chooser.draw(uniforms)
    assert worlds.shape == (300,) and points.shape == (300, 2) and points.dtype == float
    assert set(worlds.tolist()) == set(range(len(names)))
    for u, w, p in zip(uniforms, worlds, points):
        (w1,), (p1,) = chooser.draw(u)
        assert w1 == w and (p1 == p).all()


@pytest.mark.parametrize("starts", ["world", "random"])
def test_single_env_over_a_world_list_is_a_vector_env_of_one(worlds_dir, starts):
    world = [str(worlds_dir / "fixed20.yaml"), str(worlds_dir / "moving_obstacles.yaml")]
    vec = NavigateVectorEnv(world=world, num_envs=1, starts=starts, max_episode_steps=100)
    single = gym.make("apf_physics/Navigate-v0", world=world, starts=starts)
    obs, info = vec.reset(seed=7)
    o, inf = single.reset(seed=7)
    np.testing.assert_array_equal(obs[0], o)
    rng = np.random.default_rng(1)
    pending, worlds = False, set()
    for _ in range(400):
        action = int(rng.integers(0, 9))
        obs, reward, terminated, truncated, info = vec.step(np.array([action]))
        if pending:   # NEXT_STEP autoreset: this step is the reset
            o, inf = single.reset()
        else:
            o, r, te, tr, inf = single.step(action)
            assert reward[0] == np.float32(r) and terminated[0] == te and (truncated[0] == tr or te)
        np.testing.assert_array_equal(obs[0], o)
        np.testing.assert_array_equal(info["position"][0], inf["position"])
        assert info["world"][0] == inf["world"] and info["distance"][0] == inf["distance"]
        targets = single.unwrapped.world.targets   # the episode's world's, after every change of world
        assert inf["distance"] == np.hypot(*(inf["position"] - targets).T).min()
        worlds.add(inf["world"])
        pending = bool(terminated[0] or truncated[0])
    assert worlds == {"fixed20", "moving_obstacles"}
