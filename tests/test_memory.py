"""The visit-memory observation channel: VisitMemory, the environments' ``memory`` option,
the ``relative-log-memory`` transform and the DQN planner with a two-channel model."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics import load_world
from apf_physics.envs import NavigateEnv, NavigateVectorEnv
from apf_physics.models.files import model_meta, save_model
from apf_physics.models.network import QNetwork, relative_log
from apf_physics.sensing.observation import Observer, ObserverConfig, VisitMemory
from apf_physics.planners.dqn import DQNPlanner


@pytest.fixture
def fixed20(worlds_dir):
    return str(worlds_dir / "fixed20.yaml")


def test_visit_memory_counts_orientation_outside_and_reset(worlds_dir):
    world = load_world(worlds_dir / "fixed20.yaml")
    cols, rows = VisitMemory.cells_of(world)
    memory = VisitMemory(2, size=5, cap=4)
    start = np.array([[2.5, 2.5], [10.2, 10.7]])
    memory.reset(np.arange(2), start, [world, world])
    assert memory.counts[0, 2, 2] == 1 and memory.counts[1, 10, 10] == 1
    # robot 0 steps right to (3.5, 2.5), then up to (3.5, 3.5); robot 1 stays
    memory.visit(np.array([[3.5, 2.5], [10.2, 10.7]]))
    memory.visit(np.array([[3.5, 3.5], [10.2, 10.7]]))
    memory.visit(np.array([[3.5, 3.5], [10.2, 10.7]]))
    w = memory.window(np.array([[2.5, 2.5], [10.2, 10.7]]))
    assert w.shape == (2, 5, 5) and w.dtype == np.float32
    # point [i, j] is (x + j − 2, y + 2 − i): the centre is [2, 2], right is [2, 3], up-right is [1, 3]
    assert w[0, 2, 2] == pytest.approx(0.25)
    assert w[0, 2, 3] == pytest.approx(0.25)
    assert w[0, 1, 3] == pytest.approx(0.5)
    assert w[0, 3, 3] == 0.0 and w[0, 2, 1] == 0.0
    assert w[1, 2, 2] == 1.0                      # 4 visits: capped at 1
    assert w[1].sum() == 1.0                      # nothing else visited
    # robot 0 at (0.5, 0.5): the two left columns and the two bottom rows are outside the map
    corner = memory.window(np.array([[0.5, 0.5]]), np.array([0]))[0]
    np.testing.assert_array_equal(corner[:, :2], 1.0)
    np.testing.assert_array_equal(corner[3:, :], 1.0)
    assert corner[2, 2] == 0.0 and corner[1, 3] == 0.0
    # and at the far corner the right columns and top rows are outside
    far = memory.window(np.array([[cols - 0.5, rows - 0.5]]), np.array([0]))[0]
    np.testing.assert_array_equal(far[:, 3:], 1.0)
    np.testing.assert_array_equal(far[:2, :], 1.0)
    # reset clears only the reset robot, and counts its new start
    memory.reset(np.array([1]), np.array([[5.5, 5.5]]), [world])
    assert memory.counts[1].sum() == 1 and memory.counts[1, 5, 5] == 1
    assert memory.counts[0].sum() == 4


def test_env_with_memory_passes_checker(fixed20):
    from gymnasium.utils.env_checker import check_env

    env = gym.make("apf_physics/Navigate-v0", world=fixed20, memory=True)
    assert env.observation_space.shape == (2, 11, 11)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (2, 11, 11)
    plain = NavigateEnv(world=fixed20)
    np.testing.assert_array_equal(plain.reset(seed=3)[0][0], obs[0])   # channel 0 unchanged
    assert obs[1, 5, 5] == pytest.approx(0.25)                          # the start cell, counted once
    obs, *_ = env.step(8)                                               # stay
    assert obs[1, 5, 5] == pytest.approx(0.5)
    assert NavigateEnv(world=fixed20).observation_space.shape == (1, 11, 11)


def test_vector_with_memory_matches_separate_envs(fixed20):
    n = 4
    vec = NavigateVectorEnv(world=fixed20, num_envs=n, starts="random", max_episode_steps=30, memory=True)
    assert vec.single_observation_space.shape == (2, 11, 11)
    singles = [gym.make("apf_physics/Navigate-v0", world=fixed20, starts="random", memory=True,
                        max_episode_steps=30) for _ in range(n)]
    obs, _ = vec.reset(seed=21)
    np.testing.assert_allclose(obs, np.stack([env.reset(seed=21 + i)[0] for i, env in enumerate(singles)]),
                               atol=1e-4)
    rng = np.random.default_rng(1)
    pending = np.zeros(n, bool)
    ended = 0
    for _ in range(80):
        actions = rng.integers(0, 9, n)
        obs, rew, term, trunc, info = vec.step(actions)
        for i, env in enumerate(singles):
            if pending[i]:
                o, _ = env.reset()
            else:
                o, r, te, tr, _ = env.step(int(actions[i]))
                assert term[i] == te and trunc[i] == tr
            np.testing.assert_allclose(obs[i], o, atol=1e-3)
            assert obs[i, 1].max() <= 1.0
        pending = term | trunc
        ended += int(pending.sum())
    assert ended > 0


def test_transform_leaves_memory_channel_untouched():
    torch.manual_seed(0)
    obs = torch.randn(3, 2, 11, 11) * 50
    seen = {}
    net = QNetwork((2, 11, 11), obs_transform="relative-log-memory")
    hook = net.convs[0].register_forward_pre_hook(lambda module, args: seen.setdefault("x", args[0].clone()))
    net(obs)
    hook.remove()
    torch.testing.assert_close(seen["x"][:, 1], obs[:, 1])
    torch.testing.assert_close(seen["x"][:, :1], relative_log(obs[:, :1]))
    with pytest.raises(ValueError):
        QNetwork((2, 11, 11), obs_transform="no-such-transform")


def test_planner_observation_matches_environment(fixed20):
    """The planner's observer, fed the positions, sees what the environment gave the network."""
    env = NavigateEnv(world=fixed20, starts="random", memory=True)
    obs, info = env.reset(seed=5)
    observer = Observer(env.observer, 1, [env.world])
    observer.reset(np.arange(1), info["position"][None], [env.world])
    rng = np.random.default_rng(2)
    for step in range(25):
        if step > 0:
            observer.visit(info["position"][None])
        np.testing.assert_allclose(observer.observe(info["position"][None])[0], obs, atol=1e-3)
        obs, _, terminated, _, info = env.step(int(rng.integers(0, 8)))
        if terminated:
            break


def test_dqn_planner_runs_a_memory_model(tmp_path, fixed20):
    from apf_physics.experiments.rollout import rollout

    world = load_world(fixed20)
    torch.manual_seed(0)
    net = QNetwork((2, 11, 11), obs_transform="relative-log-memory")
    observer = ObserverConfig(channels=("potential", "memory"))
    path = save_model(tmp_path / "m.pt", net, model_meta(net, world.field, {}, {}, observer))
    planner = DQNPlanner(path)
    episodes = list(rollout(world, planner, world.starts[:2]))
    assert len(episodes) == 2
    assert planner.observer.memory is not None and planner.observer.memory.counts.sum() > 2


@pytest.mark.parametrize("name", ["general-memory", "general-revisit"])
def test_general_memory_presets_train_a_two_channel_network(tmp_path, name):
    from apf_physics.errors import UserError
    from apf_physics.models.files import load_model
    from apf_physics.learning import CURRICULUM_DEFAULT, TrainConfig, phases_for_curriculum, preset, train

    weights = preset(name).env.reward_weights
    if name == "general-revisit":
        assert name == CURRICULUM_DEFAULT
        assert weights.revisit < 0 and weights.length < 0 and weights.w2 == 1000
    else:
        assert weights.revisit == 0 and weights.length == 0
    config = preset(name, total_steps=300, time_limit=None, num_envs=4, batch_size=16, learning_starts=32,
                    buffer_size=2_000, pool_size=2, pool_starts=2, max_episode_steps=30, validation_worlds=1,
                    validation_starts=2, eval_every=200, log_every=100, checkpoint_every=200, seed=1)
    assert config.env.memory and config.network.obs_transform == "relative-log-memory" and config.observer.shape == (2, 11, 11)
    assert config.env.world_start_fraction == 0.5
    assert TrainConfig.from_dict(config.to_dict()) == config
    assert not preset("general").env.memory
    with pytest.raises(UserError, match="memory"):
        preset("general", memory=True)          # relative-log would transform the memory too
    result = train(config, phases_for_curriculum([], config), out_dir=tmp_path)
    assert result.global_step >= 300
    model = load_model(tmp_path / "best.pt", expect_obs_shape=(2, 11, 11))
    assert model.meta["config"]["env"]["memory"] is True and model.observer == config.observer
