"""Navigate-v0 and its vectorised version."""

import gymnasium as gym
import numpy as np
import pytest

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics import world_from_dict
from apf_physics.control.shield import ACTIONS
from apf_physics.envs import NavigateVectorEnv, register_envs
from apf_physics.errors import UserError


@pytest.fixture
def fixed20(worlds_dir):
    return str(worlds_dir / "fixed20.yaml")


def test_registration_is_idempotent():
    register_envs()
    register_envs()
    assert "apf_physics/Navigate-v0" in gym.registry
    assert gym.registry["apf_physics/Navigate-v0"].max_episode_steps == 100


@pytest.mark.parametrize("options", [{}, {"memory": True}, {"world": "moving_obstacles", "previous": True},
                                     {"obs_scale": "log"}])
def test_gymnasium_env_checker_passes_without_warnings(fixed20, options):
    import warnings
    from gymnasium.utils.env_checker import check_env

    env = gym.make("apf_physics/Navigate-v0", **{"world": fixed20, **options})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=False)
    assert [str(w.message) for w in caught] == []
    low, high = env.observation_space.low, env.observation_space.high
    assert np.isfinite(low).all() and np.isfinite(high).all()      # bounded, also in the raw scale
    env.reset(seed=0)
    for _ in range(60):                                             # and every observation lies within them
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        if terminated or truncated:
            env.reset()


def test_sb3_env_checker_says_nothing_but_its_image_advice(fixed20):
    import warnings
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3.check_env(gym.make("apf_physics/Navigate-v0", world=fixed20).unwrapped, warn=True)
    assert caught and all("image" in str(w.message) for w in caught), [str(w.message) for w in caught]


def test_observation_is_the_potential_window(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20)
    obs, info = env.reset(seed=0, options={"start": 0})
    world = env.unwrapped.world
    assert obs.shape == (1, 11, 11) and obs.dtype == np.float32
    x, y = info["position"]
    # centre of the window is U at the robot; the cell above-right is U at (x+1, y+1)
    assert obs[0, 5, 5] == pytest.approx(world.potential(np.array([[x, y]]))[0], abs=0.05)
    assert obs[0, 4, 6] == pytest.approx(world.potential(np.array([[x + 1, y + 1]]))[0], abs=0.05)
    # the start (1, 1) sees outside the map in its lower-left: impassable
    assert np.all(obs[0, -1, :] == pytest.approx(world.u_wall))
    assert np.all(obs[0, :, 0] == pytest.approx(world.u_wall))


def test_actions_follow_table_1(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20, starts=[[10.0, 16.0]])
    for action, move in enumerate(ACTIONS):
        env.reset(seed=0)
        _, _, terminated, _, info = env.step(action)
        np.testing.assert_allclose(info["position"], np.array([10.0, 16.0]) + move, atol=1e-9)


def test_reward_terms_sum_and_presets(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20, reward="thesis-general", starts=[[10.0, 16.0]])
    env.reset(seed=0)
    u0 = env.unwrapped.world.potential(np.array([[10.0, 16.0]]))[0]
    _, reward, terminated, _, info = env.step(3)  # right
    u1 = env.unwrapped.world.potential(np.array([[11.0, 16.0]]))[0]
    terms = info["reward_terms"]
    assert set(terms) == {"collision", "target", "step", "potential", "revisit", "length"}
    assert terms["revisit"] == 0 and terms["length"] == 0
    assert reward == pytest.approx(sum(terms.values()))
    assert terms["step"] == -0.2 and terms["collision"] == 0 and terms["target"] == 0
    assert terms["potential"] == pytest.approx(-20 * (u1 - u0), rel=1e-3, abs=0.2)


def test_collision_terminates_with_w1(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20, starts=[[1.0, 10.0]])
    env.reset(seed=0)
    for _ in range(3):
        _, reward, terminated, truncated, info = env.step(2)  # left, into the map's edge
        if terminated:
            break
    assert terminated and info["collision"] and not info["success"]
    assert info["reward_terms"]["collision"] == -1000


def test_reaching_the_target_terminates_with_w2(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20, starts=[[14.0, 14.0]])
    env.reset(seed=0)
    _, _, terminated, _, info = env.step(6)
    assert not terminated
    _, reward, terminated, _, info = env.step(6)  # right-up twice: (16, 16)
    assert terminated and info["success"] and info["reward_terms"]["target"] == 1000


def test_truncation_at_tt(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20, starts=[[10.0, 16.0]])
    env.reset(seed=0)
    for step in range(100):
        _, _, terminated, truncated, _ = env.step(8)  # stay
    assert truncated and not terminated


def test_same_seed_same_rollout(fixed20):
    def roll(seed):
        env = gym.make("apf_physics/Navigate-v0", world=fixed20, starts="random")
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(7)
        out = [obs]
        for _ in range(60):
            obs, r, te, tr, info = env.step(int(rng.integers(9)))
            out.append(np.concatenate([obs.ravel(), [r], info["position"]]))
            if te or tr:
                obs, _ = env.reset()
                out.append(obs)
        return out

    a, b = roll(3), roll(3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    c = roll(4)
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))


def test_world_list_draws_per_reset(worlds_dir):
    worlds = [str(worlds_dir / "fixed20.yaml"), str(worlds_dir / "local_minimum.yaml")]
    env = gym.make("apf_physics/Navigate-v0", world=worlds, obs_size=9)
    names = set()
    env.reset(seed=0)
    for _ in range(20):
        names.add(env.unwrapped.world.name)
        env.reset()
    assert names == {"fixed20", "local_minimum"}


def test_render_rgb_array(fixed20):
    env = gym.make("apf_physics/Navigate-v0", world=fixed20, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(3)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.std() > 5


def test_bad_world_argument_is_clear(tmp_path):
    from apf_physics import WorldError

    with pytest.raises(WorldError, match="no such world file"):
        gym.make("apf_physics/Navigate-v0", world=str(tmp_path / "missing.yaml"))


def test_vector_matches_separate_envs(fixed20):
    n = 6
    vec = NavigateVectorEnv(world=fixed20, num_envs=n, starts="random", max_episode_steps=100)
    singles = [gym.make("apf_physics/Navigate-v0", world=fixed20, starts="random") for _ in range(n)]
    obs, info = vec.reset(seed=11)
    single_obs = [env.reset(seed=11 + i)[0] for i, env in enumerate(singles)]
    np.testing.assert_allclose(obs, np.stack(single_obs), atol=1e-4)
    rng = np.random.default_rng(0)
    pending = np.zeros(n, bool)
    episodes_ended = 0
    for _ in range(150):
        actions = rng.integers(0, 9, n)
        obs, rew, term, trunc, info = vec.step(actions)
        for i, env in enumerate(singles):
            if pending[i]:  # NEXT_STEP autoreset: this step is the reset
                o, _ = env.reset()
                assert rew[i] == 0 and not term[i] and not trunc[i]
            else:
                o, r, te, tr, inf = env.step(int(actions[i]))
                assert rew[i] == pytest.approx(r, rel=1e-5, abs=1e-3)
                assert term[i] == te and trunc[i] == tr
                np.testing.assert_allclose(info["position"][i], inf["position"], atol=1e-9)
            np.testing.assert_allclose(obs[i], o, atol=1e-3)
        pending = term | trunc
        episodes_ended += int(pending.sum())
    assert episodes_ended > 0


def test_make_vec_entry_point(fixed20):
    vec = gym.make_vec("apf_physics/Navigate-v0", num_envs=3, vectorization_mode="vector_entry_point", world=fixed20)
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (3, 1, 11, 11)
    obs, rew, term, trunc, info = vec.step(np.array([0, 3, 8]))
    assert rew.shape == (3,) and info["position"].shape == (3, 2)


def test_sb3_dqn_learns_to_reach_a_target():
    """Stable-Baselines3 trains on the env as it is (bounded observations) and does better than chance."""
    sb3 = pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    threads = torch.get_num_threads()
    torch.set_num_threads(1)   # two threads on a busy machine wait on each other

    world = world_from_dict({"name": "open", "size": [7, 7], "field": "thesis-fixed", "targets": [[3.5, 3.5]],
                             "starts": [[1.5, 1.5], [5.5, 1.5], [1.5, 5.5], [5.5, 5.5], [3.5, 1.5], [1.5, 3.5]]})
    env = gym.make("apf_physics/Navigate-v0", world=world, obs_scale="log", max_episode_steps=20, starts="random")
    sb3_check_env(env.unwrapped, warn=False)
    model = sb3.DQN("MlpPolicy", env, learning_starts=300, buffer_size=5000, batch_size=64, seed=0, train_freq=4,
                    exploration_fraction=0.5, target_update_interval=250, policy_kwargs={"net_arch": [64]},
                    device="cpu")
    model.learn(total_timesteps=2000)
    test = gym.make("apf_physics/Navigate-v0", world=world, obs_scale="log", max_episode_steps=20)

    def successes(act) -> int:
        reached = 0
        for start in range(len(world.starts)):
            obs, _ = test.reset(seed=start, options={"start": start})
            for _ in range(20):
                obs, _, terminated, truncated, info = test.step(act(obs))
                if terminated or truncated:
                    reached += info["success"]
                    break
        return reached

    rng = np.random.default_rng(0)
    learned = successes(lambda obs: int(model.predict(obs, deterministic=True)[0]))
    chance = successes(lambda obs: int(rng.integers(9)))
    torch.set_num_threads(threads)
    assert learned >= 5 and learned > chance


def test_same_step_autoreset_gives_what_next_step_gives_one_step_earlier():
    options = dict(world="fixed20", num_envs=6, starts="random", observation="window+lidar", lidar={"beams": 8})
    nxt = NavigateVectorEnv(**options)
    same = NavigateVectorEnv(autoreset_mode="same_step", **options)
    assert same.metadata["autoreset_mode"].value == "SameStep"
    nxt.reset(seed=7)
    same.reset(seed=7)
    rng = np.random.default_rng(0)
    ended_once = 0
    for _ in range(60):
        actions = rng.integers(0, 9, 6)
        actions[nxt.needs_reset] = 8   # ignored by the next-step env at its reset step
        o1, r1, te1, tr1, info1 = nxt.step(actions)
        if nxt.needs_reset.any():   # the next-step env resets them at its next step: catch up
            ended = te1 | tr1
            o2, r2, te2, tr2, info2 = same.step(actions)
            np.testing.assert_array_equal(info2["_final_obs"], ended)
            for i in np.flatnonzero(ended).tolist():
                np.testing.assert_array_equal(info2["final_obs"][i]["window"], o1["window"][i])
                assert info2["final_info"]["success"][i] == info1["success"][i]
            np.testing.assert_array_equal(r1, r2)
            o1, *_ = nxt.step(np.full(6, 8))   # resets the ended copies (the others stand still ...)
            for i in np.flatnonzero(ended).tolist():
                np.testing.assert_array_equal(o2["lidar"][i], o1["lidar"][i])
                np.testing.assert_array_equal(o2["window"][i], o1["window"][i])
            ended_once += int(ended.sum())
            # ... so the running copies of the two envs went apart: start both again alike
            nxt.reset(seed=ended_once)
            same.reset(seed=ended_once)
        else:
            o2, r2, *_ = same.step(actions)
            np.testing.assert_array_equal(o1["window"], o2["window"])
    assert ended_once > 3


def test_a_bad_autoreset_mode_is_named():
    with pytest.raises(UserError, match="autoreset_mode must be one of next_step, same_step"):
        NavigateVectorEnv(world="fixed20", num_envs=2, autoreset_mode="sometimes")
