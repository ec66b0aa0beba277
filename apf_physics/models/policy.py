"""Trained networks as policies: a Q-network over batches of observations, a map network over a world."""

from __future__ import annotations

import itertools
import os
import weakref
from typing import Any, Callable, Sequence

import numpy as np
import torch

from apf_physics.control.shield import MOVE_SETS, SAFETY, move_clearance
from apf_physics.models.files import SavedModel, load_model, observer_of
from apf_physics.models.mapnet import MapNetwork, move_features, sample_values
from apf_physics.models.network import QNetwork
from apf_physics.sensing.mapview import MapView
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.common.transforms import signed_log
from apf_physics.world.core import Moment, World


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
            (N,) int64 action indices (Model Table 1 order, 0-based).
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


MAP_VALUES_PER_WORLD = 4
"""Most map policies whose values one world keeps; the least recently used go first."""


class MapValues:
    """One world's map values, per :class:`MapPolicy`: kept in the world's cache (``"map_values"``).

    An entry lives while both its world and its policy do: the world's cache holds it (a
    world that is gone takes its values with it, and views of a world made by
    :meth:`~apf_physics.world.World.among` share them), and it is keyed by a weak reference to
    the policy (a policy that is gone, e.g. a network's evaluation during training, leaves
    nothing behind). At most :data:`MAP_VALUES_PER_WORLD` policies' values are kept; a
    pickled or copied world starts without any (values are cheap to rebuild, large to ship).
    """

    def __init__(self):
        self._entries: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()   # policy -> [last use, values]
        self._clock = itertools.count()

    def __len__(self) -> int:
        return len(self._entries)

    def __reduce__(self):
        return MapValues, ()

    def get(self, policy: "MapPolicy", build: Callable[[], Any]) -> Any:
        """``policy``'s values: kept, or ``build()`` (making room by dropping the least recently used)."""
        entry = self._entries.get(policy)
        if entry is None:
            while len(self._entries) >= MAP_VALUES_PER_WORLD:
                oldest = min(self._entries.items(), key=lambda item: item[1][0])[0]
                del self._entries[oldest]
            entry = [0, build()]
            self._entries[policy] = entry
        entry[0] = next(self._clock)
        return entry[1]


class MapPolicy:
    """Action values of a :class:`~apf_physics.models.mapnet.MapNetwork` for robots in a world.

    The network's values over the world's :class:`~apf_physics.sensing.mapview.MapView` depend
    only on the world's static obstacles and targets, so they are computed once per world
    (kept with the world, :class:`MapValues`) and every step only samples them at the
    robots' moves.

    Args:
        network: The map network; it is put in eval mode.
        model: The file it came from, if any.
    """

    def __init__(self, network: MapNetwork, model: SavedModel | None = None):
        self.network = network.eval()
        self.model = model
        self.moves = MOVE_SETS[network.arch["moves"]]
        """(M, 2) the moves the action values are for."""
        self.lengths = np.hypot(*self.moves.T)

    @property
    def field(self) -> dict[str, float] | None:
        """Field parameters of the world the network was trained on (None if unknown)."""
        return None if self.model is None else self.model.field

    def values(self, world: World) -> tuple[MapView, torch.Tensor]:
        """The world's map view and the network's V over it (kept with the world: :class:`MapValues`)."""
        def build():
            view = MapView.of(world, self.network.resolution)
            with _threads_for(1), torch.inference_mode():
                v = self.network.values(torch.from_numpy(view.features), torch.from_numpy(view.free),
                                        torch.from_numpy(view.goal))
            return view, v
        return world.cached("map_values", MapValues).get(self, build)

    def q_values(self, world: World, positions: np.ndarray, room: np.ndarray, du: np.ndarray) -> np.ndarray:
        """(N, M) action values of robots at ``positions`` for :attr:`moves`.

        Args:
            world: The world.
            positions: (N, 2) robot centres.
            room: (N, M) clearance along each move beyond the robot's radius and the safety margin.
            du: (N, M) signed-log change of U over each move (:func:`potential_change`).
        """
        view, v = self.values(world)
        positions = np.asarray(positions, float).reshape(-1, 2)
        with _threads_for(1), torch.inference_mode():
            return map_scores(self.network, view, v, positions, self.moves, room, du).numpy()


def move_inputs(where: Moment | World, positions: np.ndarray, moves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map network's per-move inputs: one function for when it acts and when it is trained.

    ``where``: the world at the control step the moves start at (:meth:`World.at`), or a world:
    its static obstacles, U at step 0 (as training labels them).

    Returns:
        ``room`` (N, M): the clearance along each move (:func:`~apf_physics.control.shield.move_clearance`)
        beyond the robot's radius and the safety margin (negative: the move is unsafe), which the
        shield judges moves by too; and ``du`` (N, M): the signed-log change of U over each move
        (:func:`potential_change`).
    """
    world = where.world if isinstance(where, Moment) else where
    room = move_clearance(where, positions, moves) - (world.robot_radius + SAFETY)
    return room, potential_change(where, positions, moves)


def potential_change(where: Moment | World, positions: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """(N, M) ``sign(d)·log(1 + |d|) / 4`` of ``d = U(p + a, t) − U(p, t)`` for each robot and move.

    ``where``: the world at step ``t`` (:meth:`World.at`), or a world (at step 0).
    """
    positions = np.asarray(positions, float).reshape(-1, 2)
    ends = (positions[:, None, :] + moves[None]).reshape(-1, 2)
    d = where.potential(ends).reshape(len(positions), -1) - where.potential(positions)[:, None]
    return signed_log(d) / 4.0


def map_scores(network: MapNetwork, view: MapView, v: torch.Tensor, positions: np.ndarray, moves: np.ndarray,
               room: np.ndarray, du: np.ndarray) -> torch.Tensor:
    """(N, M) the network's action values (differentiable in ``v`` and the head's weights)."""
    n, m = len(positions), len(moves)
    points = torch.from_numpy(np.concatenate([positions, (positions[:, None, :] + moves[None]).reshape(-1, 2)]))
    sampled, found = sample_values(v, torch.from_numpy(view.free), view.grid.origin, view.grid.resolution,
                                   points.to(v.dtype))
    here, there, ok = sampled[:n], sampled[n:].reshape(n, m), found[n:].reshape(n, m)
    lengths = torch.from_numpy(np.hypot(*moves.T)).to(v.dtype)
    features = move_features(here, there, ok, lengths, torch.from_numpy(np.asarray(room)).to(v.dtype),
                             torch.from_numpy(np.asarray(du)).to(v.dtype))
    return network.scores(features)


class _threads_for:
    """Run a block on ``count`` torch threads (small work: more threads only wait on each other)."""

    def __init__(self, count: int):
        self.count = count

    def __enter__(self):
        self.saved = torch.get_num_threads()
        if self.saved != self.count:
            torch.set_num_threads(self.count)

    def __exit__(self, *exc):
        if self.saved != self.count:
            torch.set_num_threads(self.saved)


def load_policy(path: str | os.PathLike, expect_field: Any = None) -> "DQNPolicy | MapPolicy":
    """The policy of a model file, whichever kind of network it holds."""
    model = load_model(path, expect_field=expect_field)
    return MapPolicy(model.network, model) if model.is_map else DQNPolicy(model.network, model.observer, model)
