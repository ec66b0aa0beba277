"""Stable-Baselines3 on the robots of ``Navigate-v0``: its checker, and two learners that learn.

- SB3's ``check_env`` passes for every combination of action × kinematics × observation, with
  no warning but the ones SB3 gives every float window of shape (1, k, k) (it takes any 3-D
  ``Box`` for an image; ``MlpPolicy`` flattens it, ``CnnPolicy`` is not for these windows).
- ``apf_physics.envs.sb3.SB3VecEnv`` (the vector env seen by SB3) steps as SB3's ``DummyVecEnv``
  of single envs does, to the last bit.
- Observations stay inside the observation space over random episodes (SAC and PPO do not
  check it, and a lidar value outside the ``Box`` would go unnoticed).
- SAC (continuous actions, lidar of 8 beams) and PPO (nine moves, the 5 × 5 potential window on
  the log scale) learn to reach the target of an open 8 × 8 world from random starts within a
  few thousand env steps (8 copies of ``NavigateVectorEnv`` seen by SB3 through
  ``SB3VecEnv``; rewards: ``thesis-fixed`` × 0.01): their deterministic
  success over 30 evaluation episodes (the same 30 random starts) rises to a floor of 20 that
  the same model, untrained, stays far below (at most 10; measured in the same test).
"""

import warnings

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import torch  # noqa: E402
from stable_baselines3 import PPO, SAC  # noqa: E402
from stable_baselines3.common.env_checker import check_env  # noqa: E402

import apf_physics  # noqa: E402,F401  (registers the ids)
from apf_physics import world_from_dict  # noqa: E402
from apf_physics.envs import NavigateVectorEnv  # noqa: E402
from apf_physics.envs.sb3 import SB3VecEnv, WindowCNN  # noqa: E402

COMBINATIONS = [(a, k, o) for a in ("discrete", "continuous") for k in ("holonomic", "unicycle")
                for o in ("window", "lidar", "window+lidar")]
# What SB3's checker says of every (1, k, k) float32 Box: it takes it for an image.
IMAGE_WARNINGS = ("is an image but its `dtype`", "is an image but the upper and lower bounds",
                  "minimal resolution for an image")


@pytest.mark.parametrize("action,kinematics,observation", COMBINATIONS)
def test_sb3_check_env(action, kinematics, observation):
    env = gym.make("apf_physics/Navigate-v0", world="fixed20", action=action, kinematics=kinematics,
                   observation=observation, lidar={"beams": 16})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, warn=True)
        check_env(env.unwrapped, warn=True)
    others = [str(w.message) for w in caught
              if not any(s in str(w.message) for s in IMAGE_WARNINGS)]
    assert others == []
    if "window" not in observation:
        assert len(caught) == 0


@pytest.mark.parametrize("action,kinematics,observation",
                         [c for c in COMBINATIONS if c[2] == "window+lidar"])
def test_observations_stay_in_their_space(action, kinematics, observation):
    env = gym.make("apf_physics/Navigate-v0", world="fixed20", action=action, kinematics=kinematics,
                   observation=observation, lidar={"beams": 16, "noise": 0.05}, starts="random")
    env.action_space.seed(0)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for _ in range(600):
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs), obs
        if terminated or truncated:
            obs, _ = env.reset()
            assert env.observation_space.contains(obs)


def open_world():
    """8 × 8, no obstacles, the target in a corner: nothing to learn but the way to it."""
    return world_from_dict({"name": "open8", "size": [8, 8], "robot_radius": 0.25, "goal_tolerance": 0.75,
                            "field": {"katt": 2, "krep": 20, "kstr": 8, "p0": 0.5, "ps": 8, "u_max": 100},
                            "obstacles": [], "targets": [[7, 7]]})


ROBOTS = {   # the robot, what it sees, and its learner
    "sac": dict(action="continuous", observation="lidar", lidar={"beams": 8}),
    "ppo": dict(action="discrete", observation="window", obs_scale="log", obs_size=5),
}
STEP_LIMIT = 30   # an open 8 x 8: the target is at most 10 unit moves away


def successes(model, algo, episodes=30, seed=1000):
    """Deterministic successes of the first episodes of ``episodes`` copies, copy ``i`` seeded
    ``seed + i`` (the same random starts for every model)."""
    env = NavigateVectorEnv(num_envs=episodes, world=open_world(), starts="random", reward="thesis-fixed",
                            max_episode_steps=STEP_LIMIT, **ROBOTS[algo])
    obs, _ = env.reset(seed=seed)
    outcome = np.full(episodes, -1)
    while (outcome < 0).any():
        action, _ = model.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        ended = (terminated | truncated) & (outcome < 0)
        outcome[ended] = info["success"][ended]
    return int(outcome.sum())


def learner(algo, seed):
    """An untrained SB3 learner of ``algo`` on 8 copies of the open world (rewards × 0.01)."""
    env = NavigateVectorEnv(num_envs=8, world=open_world(), starts="random", reward="thesis-fixed",
                            max_episode_steps=STEP_LIMIT, autoreset_mode="same_step", **ROBOTS[algo])
    vec = SB3VecEnv(env, reward_scale=0.01, seed=seed)
    if algo == "sac":
        return SAC("MlpPolicy", vec, learning_rate=1e-3, learning_starts=400, batch_size=128, train_freq=1,
                   gradient_steps=2, policy_kwargs={"net_arch": [64, 64]}, seed=seed, device="cpu")
    return PPO("MlpPolicy", vec, n_steps=128, batch_size=256, n_epochs=10, learning_rate=1e-3, ent_coef=0.01,
               policy_kwargs={"net_arch": [64, 64]}, seed=seed, device="cpu")


def before_and_after(algo, seed, steps):
    """Successes (of 30) of the untrained and the trained learner."""
    torch.set_num_threads(1)
    model = learner(algo, seed)
    before = successes(model, algo)
    model.learn(steps)
    return before, successes(model, algo)


# Budgets and floors. Measured (successes of 30, untrained -> trained), seeds 0-7:
#   SAC 1,600 steps: 0->30, 3->30, 0->30, 3->30, 1->30, 0->30, 1->30, 3->30  (2 updates per 8 steps: ~300)
#   PPO 6,144 steps: 0->30, 0->30, 0->30, 3->30, 0->30, 0->30, 2->30, 0->29  (at 4,096 steps, seeds 0-7:
#   0->30, 0->30, 0->22, 3->26, 0->30, 0->30, 2->29, 0->28). About 3-6 s of CPU each; the wall clock is
#   what the machine's load makes it (5-50 s at load averages 1-11 on 2 cores).
SEED, FLOOR, UNTRAINED_AT_MOST = 0, 20, 10
SAC_STEPS, PPO_STEPS = 1600, 6144


def test_sac_learns_to_reach_the_target_with_lidar():
    before, after = before_and_after("sac", SEED, SAC_STEPS)
    assert before <= UNTRAINED_AT_MOST, before
    assert after >= FLOOR, (before, after)


def test_ppo_learns_to_reach_the_target_with_the_window():
    before, after = before_and_after("ppo", SEED, PPO_STEPS)
    assert before <= UNTRAINED_AT_MOST, before
    assert after >= FLOOR, (before, after)


def flat(observation):
    """An observation (or a batch), a Dict's entries in key order, as one flat array."""
    if isinstance(observation, dict):
        return np.concatenate([np.ravel(observation[k]) for k in sorted(observation)])
    return np.ravel(observation)


@pytest.mark.parametrize("robot", [dict(action="discrete", observation="window"),
                                   dict(action="continuous", kinematics="unicycle", observation="window+lidar",
                                        lidar={"beams": 16})])
def test_the_vector_env_seen_by_sb3_steps_as_sb3s_own_vector_of_single_envs(robot):
    """``SB3VecEnv`` (one ``NavigateVectorEnv``, ended copies restarted in the same step) and SB3's
    ``DummyVecEnv`` of ``Navigate-v0`` copies, seeded alike and given the same actions, return
    the same observations, rewards, ends and final observations."""
    from stable_baselines3.common.env_util import make_vec_env

    kwargs = dict(world="fixed20", starts="random", **robot)
    ours = SB3VecEnv(num_envs=4, **kwargs)
    theirs = make_vec_env("apf_physics/Navigate-v0", n_envs=4, env_kwargs=kwargs)
    ours.seed(7)
    theirs.seed(7)
    ours.action_space.seed(0)
    np.testing.assert_array_equal(flat(ours.reset()), flat(theirs.reset()))
    ended = 0
    for _ in range(150):
        actions = np.stack([ours.action_space.sample() for _ in range(4)])
        (a, ra, da, ia), (b, rb, db, ib) = ours.step(actions), theirs.step(actions)
        np.testing.assert_array_equal(flat(a), flat(b))
        np.testing.assert_allclose(ra, rb, rtol=1e-6)
        np.testing.assert_array_equal(da, db)
        for i in np.flatnonzero(da).tolist():
            ended += 1
            assert ia[i]["TimeLimit.truncated"] == ib[i].get("TimeLimit.truncated", False)
            np.testing.assert_array_equal(flat(ia[i]["terminal_observation"]), flat(ib[i]["terminal_observation"]))
    assert ended > 4


def test_sb3_vec_env_refuses_an_env_that_resets_on_the_next_step_and_two_ways_of_building_it():
    with pytest.raises(ValueError, match="autoreset_mode='same_step'"):
        SB3VecEnv(NavigateVectorEnv(num_envs=2, world="fixed20"))
    with pytest.raises(ValueError, match="either a vector env or its options"):
        SB3VecEnv(NavigateVectorEnv(num_envs=2, world="fixed20", autoreset_mode="same_step"), world="fixed20")


def test_window_cnn_is_the_window_networks_convolutions_and_first_layer():
    """SB3's DQN with ``WindowCNN`` has the layers of the ``fast`` preset's network (the thesis's Table 3
    convolutions, 32 and 32 hidden units, nine actions) and reads the raw windows through the same
    observation transform."""
    from stable_baselines3 import DQN

    from apf_physics.learning import preset
    from apf_physics.learning.dqn import q_network

    env = SB3VecEnv(num_envs=2, world="fixed20", seed=0)
    model = DQN("CnnPolicy", env, policy_kwargs=WindowCNN.policy_kwargs(), device="cpu")
    ours = q_network(preset("fast"))
    theirs = model.q_net
    assert sum(p.numel() for p in theirs.parameters()) == sum(p.numel() for p in ours.parameters())
    window = theirs.features_extractor.window
    assert window.arch["filters"] == [10, 10, 20] and window.obs_transform == ours.obs_transform == "relative-log"
    obs = torch.as_tensor(env.reset())
    with torch.no_grad():   # the same weights give the same action values
        for mine, sb3 in zip(ours.convs, window.convs):
            sb3.weight.copy_(mine.weight), sb3.bias.copy_(mine.bias)
        window.head.weight.copy_(ours.hidden[0].weight), window.head.bias.copy_(ours.hidden[0].bias)
        linear = [m for m in theirs.q_net if isinstance(m, torch.nn.Linear)]
        linear[0].weight.copy_(ours.hidden[1].weight), linear[0].bias.copy_(ours.hidden[1].bias)
        linear[1].weight.copy_(ours.head.weight), linear[1].bias.copy_(ours.head.bias)
        np.testing.assert_allclose(theirs(obs).numpy(), ours(obs).numpy(), rtol=1e-5, atol=1e-6)
