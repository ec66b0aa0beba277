"""A trained Q-network as a greedy policy over batches of observations."""

from __future__ import annotations

import os
from typing import Any, Sequence

import numpy as np
import torch

from apf_physics.models.files import SavedModel, load_model, observer_of
from apf_physics.models.network import QNetwork
from apf_physics.observation import ObserverConfig


SMALL_BATCH = 256
"""Batches smaller than this run on one torch thread."""


class DQNPolicy:
    """Greedy (argmax) actions of a Q-network.

    Args:
        network: The Q-network; it is put in eval mode.
        observer: How its observations are built (default: the model file's, else windows of
            U at resolution 4 with as many channels as the network takes).
        model: The file it came from, if any (see :meth:`load`).
    """

    def __init__(self, network: QNetwork, observer: ObserverConfig | None = None, model: SavedModel | None = None):
        self.network = network.eval()
        self.model = model
        self.obs_shape: tuple[int, int, int] = tuple(network.arch["obs_shape"])
        """(C, k, k) observation shape expected by :meth:`act`."""
        if observer is None:
            observer = model.observer if model is not None else observer_of({"obs_shape": self.obs_shape})
        self.observer = observer
        """How the observations fed to :meth:`act` must be built."""

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        expect_obs_shape: Sequence[int] | None = None,
        expect_field: Any = None,
    ) -> "DQNPolicy":
        """Load a policy from a model file (see :func:`~apf_physics.models.files.load_model`).

        Raises:
            ModelError: The file is unusable or does not fit the expected shape or field.
        """
        model = load_model(path, expect_obs_shape=expect_obs_shape, expect_field=expect_field)
        return cls(model.network, model.observer, model)

    @property
    def field(self) -> dict[str, float] | None:
        """Field parameters of the world the network was trained on (None if unknown)."""
        return None if self.model is None else self.model.field

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Action values for a batch of raw observations.

        Args:
            obs: (N, C, k, k) float32 observations.

        Returns:
            (N, 9) float32 action values.
        """
        return self._forward(np.asarray(obs, np.float32)).numpy()

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Greedy actions for a batch of raw observations.

        Args:
            obs: (N, C, k, k) float32 observations.

        Returns:
            (N,) int64 action indices (SPEC Table 1 order, 0-based).
        """
        obs = np.asarray(obs, np.float32)
        if obs.shape[1:] != self.obs_shape:
            raise ValueError(f"expected observations of shape (N, {', '.join(map(str, self.obs_shape))}), got {obs.shape}")
        return self._forward(obs).argmax(1).numpy()

    def _forward(self, obs: np.ndarray) -> torch.Tensor:
        """The network on a batch; small batches on one thread (two threads on a busy machine
        wait on each other longer than a small network takes)."""
        threads = torch.get_num_threads()
        small = len(obs) < SMALL_BATCH and threads > 1
        if small:
            torch.set_num_threads(1)
        try:
            with torch.inference_mode():
                return self.network(torch.from_numpy(np.ascontiguousarray(obs)))
        finally:
            if small:
                torch.set_num_threads(threads)
