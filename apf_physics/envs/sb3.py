"""Stable-Baselines3 on the navigation environments: the vector env as an SB3 ``VecEnv``, and the thesis's window network.

Needs the ``[sb3]`` extra (``pip install -e ".[sb3]"``). SB3 steps environments through its own
``VecEnv`` interface; :class:`SB3VecEnv` gives it a :class:`~apf_physics.envs.NavigateVectorEnv`,
all copies in one physics and one observation call per step (SB3's ``make_vec_env`` would run
``Navigate-v0`` copies one by one in a ``DummyVecEnv``). :class:`WindowCNN` is a features
extractor of the thesis's 2×2 convolutions for ``CnnPolicy`` (whose own NatureCNN needs images
of at least 36×36).

Example::

    from stable_baselines3 import DQN
    from apf_physics.envs.sb3 import SB3VecEnv, WindowCNN

    env = SB3VecEnv(num_envs=16, world="fixed20", starts="random", reward_scale=1e-3)
    model = DQN("CnnPolicy", env, policy_kwargs=WindowCNN.policy_kwargs(), device="cpu")
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from gymnasium.vector import AutoresetMode

try:
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from stable_baselines3.common.vec_env import VecEnv
except ImportError as error:  # the extra is not installed
    raise ImportError("apf_physics.envs.sb3 needs Stable-Baselines3: pip install -e \".[sb3]\" "
                      "(or pip install stable-baselines3)") from error

from apf_physics.envs.vector import NavigateVectorEnv
from apf_physics.models.network import QNetwork

__all__ = ["SB3VecEnv", "ThesisLeakyReLU", "WindowCNN"]


class SB3VecEnv(VecEnv):
    """A :class:`~apf_physics.envs.NavigateVectorEnv` seen by Stable-Baselines3 as a ``VecEnv``.

    Build it from the vector env's options (``SB3VecEnv(num_envs=16, world="fixed20",
    starts="random")``) or around a vector env made with ``autoreset_mode="same_step"``.

    SB3 resets an ended copy in the step that ends it: the step returns the new episode's
    observation, the final one in ``infos[i]["terminal_observation"]``, and a step limit's end
    is marked ``infos[i]["TimeLimit.truncated"]`` (SB3 bootstraps from it). The ``infos`` of
    ended episodes also carry ``success`` (and ``is_success``, which SB3's logger and
    ``EvalCallback`` read) and ``collision``. ``seed(s)`` seeds copy ``i`` with ``s + i`` at the
    next reset, as SB3's own vector envs do: copy ``i`` then starts as ``Navigate-v0`` does after
    ``reset(seed=s + i)``.

    Args:
        env: The vector env to wrap (``autoreset_mode="same_step"``); None: build one from ``options``.
        reward_scale: Rewards are multiplied by this (the presets' ±1000 make large Q-values otherwise).
        seed: Seed of the first reset (None: unseeded).
        **options: :class:`~apf_physics.envs.NavigateVectorEnv`'s options when ``env`` is None.

    Raises:
        ValueError: ``env`` resets on the next step (Gymnasium's default), which SB3 does not expect.
    """

    def __init__(self, env: Optional[NavigateVectorEnv] = None, reward_scale: float = 1.0,
                 seed: Optional[int] = None, **options: Any):
        if env is None:
            env = NavigateVectorEnv(**{**options, "autoreset_mode": "same_step"})
        elif options:
            raise ValueError("give either a vector env or its options, not both")
        if env.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError("SB3VecEnv needs NavigateVectorEnv(..., autoreset_mode='same_step'): SB3 expects an "
                             "ended copy to restart in the step that ends it")
        self.env = env
        self.reward_scale = float(reward_scale)
        self.render_mode = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self._actions: Optional[np.ndarray] = None
        if seed is not None:
            self.seed(seed)

    def reset(self) -> np.ndarray:
        seeds = None if self._seeds[0] is None else [int(s) for s in self._seeds]
        obs, _ = self.env.reset(seed=seeds)
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        done = terminated | truncated
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done).tolist():   # restarted in this step (same_step): how they ended
            success = bool(info["success"][i])
            infos[i] = {"terminal_observation": info["final_obs"][i],
                        "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                        "success": success, "is_success": success, "collision": bool(info["collision"][i])}
        return obs, (reward * self.reward_scale).astype(np.float32), done, infos

    def close(self) -> None:
        self.env.close()

    def get_images(self) -> Sequence[Optional[np.ndarray]]:
        return [None] * self.num_envs

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        if attr_name == "render_mode":
            return [None] * len(self._indices(indices))
        return [getattr(self.env, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
        return [getattr(self.env, method_name)(*method_args, **method_kwargs)] * len(self._indices(indices))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: Any = None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices: Any) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices


class ThesisLeakyReLU(torch.nn.LeakyReLU):
    """Leaky ReLU with the thesis's slope λ = 0.001 (an ``activation_fn`` for SB3's layers after the extractor)."""

    def __init__(self, inplace: bool = False):
        super().__init__(negative_slope=0.001, inplace=inplace)


class WindowCNN(BaseFeaturesExtractor):
    """The thesis's window network as an SB3 features extractor: its 2×2 convolutions and first hidden layer.

    The observation transform (``"relative-log"``: the signed log of U relative to the robot's
    cell) is part of the extractor, so it reads ``Navigate-v0``'s raw windows. With
    ``net_arch=[32]`` and :class:`ThesisLeakyReLU` SB3 adds the second hidden layer and the action
    head: the network of ``apf-physics train``'s ``fast`` preset (:meth:`policy_kwargs`).

    Args:
        observation_space: The env's ``Box`` of ``(C, k, k)`` windows.
        features_dim: Width of the hidden layer it ends with.
        filters: Output channels of each 2×2 convolution.
        obs_transform: :class:`~apf_physics.models.network.QNetwork`'s transform.
        negative_slope: Leaky ReLU slope.
    """

    def __init__(self, observation_space: gym.spaces.Box, features_dim: int = 32,
                 filters: Sequence[int] = (10, 10, 20), obs_transform: str = "relative-log",
                 negative_slope: float = 0.001):
        super().__init__(observation_space, features_dim)
        self.window = QNetwork(obs_shape=observation_space.shape, filters=filters, hidden=(), n_actions=features_dim,
                               negative_slope=negative_slope, obs_transform=obs_transform)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return F.leaky_relu(self.window(observations), self.window.negative_slope)

    @staticmethod
    def policy_kwargs(**extractor: Any) -> dict[str, Any]:
        """``policy_kwargs`` for ``CnnPolicy`` with this extractor (``extractor``: its options), one more
        32-unit layer and the thesis's activation: the ``fast`` preset's network. The windows are read as
        they are (they are not images)."""
        return dict(features_extractor_class=WindowCNN, features_extractor_kwargs=extractor, net_arch=[32],
                    activation_fn=ThesisLeakyReLU, normalize_images=False)
