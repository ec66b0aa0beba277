"""Trained networks as policies: a Q-network over batches of observations, a map network over a world."""

from __future__ import annotations

import itertools
import os
import weakref
from typing import Any, Callable, Sequence

import numpy as np
import torch

from apf_physics.common.transforms import signed_log
from apf_physics.sim.nodegraph import NodeGraph, node_moves, resolution_for
from apf_physics.control.shield import MOVE_SAMPLES, MOVE_SETS, SAFETY, move_clearance
from apf_physics.models.files import SavedModel, load_model, observer_of
from apf_physics.models.mapnet import UNREACHED, MapNetwork, move_features, replan, sample_values, values_between
from apf_physics.models.network import QNetwork
from apf_physics.sensing.mapview import MapView
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.world.core import Moment, World
from apf_physics.world.field import Grid
from apf_physics.world.kinematics import NODE_MOVES


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

    def kept(self) -> list:
        """Each kept policy's ``[last use, values]``: for measuring what a world holds in memory."""
        return list(self._entries.values())

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


MAP_MARGIN = 0.05
"""Clearance beyond its radius a robot needs at a node of its map view (:meth:`MapView.of`'s margin)."""
OTHERS_PATCH = 6.0
"""Half-side [units] of the square around a robot over which a map policy plans its values again
among other robots (a world's :attr:`~apf_physics.world.World.others`: other formations' robots);
beyond it the values are the static map's."""
OTHERS_ROOM = 0.5
"""Beyond touching, how far around another robot [units] passing costs :data:`OTHERS_COST` more."""
OTHERS_COST = 8.0
"""Extra cost per unit length of passing within :data:`OTHERS_ROOM` of another robot (the learned
cost map's are about 1 in the open): a robot goes round another where going round is short, and
passes it where the way round is long (a warehouse's aisle). :data:`OTHERS_PATCH`, :data:`OTHERS_ROOM`
and this were chosen on a validation set of crossing formations (``generate --family crossing
--count 60 --seed 8``) and warehouse-like maps (``tools/bench_warehouse.py``); BENCHMARKS.md has
the figures."""


class MapPolicy:
    """Action values of a :class:`~apf_physics.models.mapnet.MapNetwork` for robots in a world.

    The network's values over the world's :class:`~apf_physics.sensing.mapview.MapView` depend
    only on the world's static obstacles and targets, so they are computed once per world
    (kept with the world, :class:`MapValues`) and every step only samples them at the
    robots' moves.

    Among other robots (a world's :attr:`~apf_physics.world.World.others`: the robots of other
    formations, as one leader sees them), each robot's values over the square of :data:`OTHERS_PATCH` around it are planned
    again (:func:`~apf_physics.models.mapnet.replan`) with the other robots' discs blocking and
    the ring of :data:`OTHERS_ROOM` around them costing :data:`OTHERS_COST` more, the square's edge
    held at the map's values: the robot goes round the others as the window network does, where
    the static values alone would lead it into them.

    Args:
        network: The map network; it is put in eval mode.
        model: The file it came from, if any.
    """

    def __init__(self, network: MapNetwork, model: SavedModel | None = None):
        self.network = network.eval()
        self.model = model
        self.on_nodes = network.arch["moves"] == NODE_MOVES
        """Whether the moves are each robot's own (:meth:`candidates`: to the nodes of its
        :class:`~apf_physics.nodegraph.NodeGraph` within one step), not one fixed set."""
        self.moves = None if self.on_nodes else MOVE_SETS[network.arch["moves"]]
        """(M, 2) the moves the action values are for (None: each robot's own, :meth:`candidates`)."""
        self.lengths = None if self.moves is None else np.hypot(*self.moves.T)

    def resolution(self, world: World) -> int:
        """Nodes per step of the grid the network plans on in ``world``: its own, or for moves onto
        nodes finer where the robot is small (:func:`~apf_physics.nodegraph.resolution_for`)."""
        if not self.on_nodes:
            return self.network.resolution
        return resolution_for(world, self.network.resolution, self.network.least_resolution)

    def graph(self, world: World) -> NodeGraph | None:
        """The node graph the network plans on (None for a network with a fixed set of moves)."""
        return NodeGraph.of(world, self.resolution(world), SAFETY) if self.on_nodes else None

    def candidates(self, world: World, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each robot's moves: ``moves`` (N, M, 2), ``usable`` (N, M) and ``ends`` (N, M) node indices
        (:func:`~apf_physics.nodegraph.node_moves`); a fixed set: the same moves for every robot."""
        positions = np.asarray(positions, float).reshape(-1, 2)
        if self.on_nodes:
            return node_moves(self.graph(world), positions)
        n, m = len(positions), len(self.moves)
        return (np.broadcast_to(self.moves, (n, m, 2)), np.ones((n, m), bool), np.full((n, m), -1, np.intp))

    @property
    def field(self) -> dict[str, float] | None:
        """Field parameters of the world the network was trained on (None if unknown)."""
        return None if self.model is None else self.model.field

    def values(self, world: World) -> tuple[MapView, torch.Tensor]:
        """The world's map view and the network's V over it (kept with the world: :class:`MapValues`)."""
        view, v, _ = self._planned(world)
        return view, v

    def _planned(self, world: World) -> tuple[MapView, torch.Tensor, torch.Tensor]:
        """The world's map view, V and the cost map κ (kept with the world: :class:`MapValues`)."""
        def build():
            resolution = self.resolution(world)
            view = MapView.of(world, resolution, MAP_MARGIN)
            graph = self.graph(world)
            with _threads_for(1), torch.inference_mode():
                v, kappa = self.network.values(torch.from_numpy(view.features), torch.from_numpy(view.free),
                                               torch.from_numpy(view.goal),
                                               links=None if graph is None else torch.from_numpy(graph.links),
                                               resolution=resolution, with_cost=True)
            return view, v, kappa
        return world.cached("map_values", MapValues).get(self, build)

    def q_values(self, world: World, positions: np.ndarray, room: np.ndarray, du: np.ndarray,
                 candidates: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(N, M) action values of robots at ``positions`` for their moves.

        Args:
            world: The world (with other robots in it: each robot's values planned again among them).
            positions: (N, 2) robot centres.
            room: (N, M) clearance along each move beyond the robot's radius and the safety margin.
            du: (N, M) signed-log change of U over each move (:func:`potential_change`).
            candidates: The robots' moves (:meth:`candidates`); None: :attr:`moves`. Moves that
                are not usable get ``−inf``.
        """
        view, v, kappa = self._planned(world)
        positions = np.asarray(positions, float).reshape(-1, 2)
        with _threads_for(1), torch.inference_mode():
            if candidates is not None:
                return self._node_values(world, view, v, kappa, positions, candidates, room, du)
            if not len(world.others):
                return map_scores(self.network, view, v, positions, self.moves, room, du).numpy()
            out = np.empty((len(positions), len(self.moves)))
            for i, position in enumerate(positions):
                patch, patch_v, _ = self.among_others(world, view, v, position)
                out[i] = map_scores(self.network, patch, patch_v, position[None], self.moves, room[i:i + 1],
                                    du[i:i + 1]).numpy()[0]
            return out

    def _node_values(self, world: World, view: MapView, v: torch.Tensor, kappa: torch.Tensor, positions: np.ndarray,
                     candidates: tuple[np.ndarray, np.ndarray, np.ndarray], room: np.ndarray,
                     du: np.ndarray) -> np.ndarray:
        """:meth:`q_values` for moves onto nodes: V read at each move's end node; a robot with
        others near reads the values planned again among them (:meth:`among_others`) there."""
        moves, usable, ends = candidates
        q = node_scores(self.network, view, v, kappa, positions, moves, ends, room, du).numpy()
        for i, position in enumerate(positions if len(world.others) else ()):
            patch, patch_v, (rs, cs) = self.among_others(world, view, v, position)
            if patch is view:
                continue
            # the patch's values in place of the map's for this robot, put back at once (the map's
            # values are kept with the world: a copy of them per robot would cost the whole map)
            kept = v[rs, cs].clone()
            v[rs, cs] = patch_v
            try:
                q[i] = node_scores(self.network, view, v, kappa, position[None], moves[i:i + 1], ends[i:i + 1],
                                   room[i:i + 1], du[i:i + 1]).numpy()[0]
            finally:
                v[rs, cs] = kept
        return np.where(usable, q, -np.inf)

    def node_values(self, world: World, goal: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(K,) float32 V at ``points`` of the map's values toward a target at ``goal`` (:data:`UNREACHED`
        where no way leads): a fleet robot's table (:mod:`apf_physics.control.fleet`). The values are
        planned in a view of ``world`` with that target alone, dropped afterwards (what the map alone
        determines stays shared)."""
        view, v = self.values(world.with_task(np.asarray(goal, float).reshape(1, 2), np.zeros((0, 2))))
        points = np.asarray(points, float).reshape(-1, 2)
        with _threads_for(1), torch.inference_mode():
            sampled, found = sample_values(v, torch.from_numpy(view.free), view.grid.origin, view.grid.resolution,
                                           torch.from_numpy(points).to(v.dtype))
        out = np.where(found.numpy(), sampled.numpy(), UNREACHED).astype(np.float32)
        if self.on_nodes:   # V read on the nodes themselves, as its moves read it (node_scores)
            rows, cols = view.grid.shape
            index = view.grid.to_index(points)
            near = np.rint(index)
            on = (np.all(np.abs(index - near) <= 1e-6, axis=1) & (near[:, 0] >= 0) & (near[:, 0] < cols)
                  & (near[:, 1] >= 0) & (near[:, 1] < rows))
            out[on] = v.numpy()[near[on, 1].astype(np.intp), near[on, 0].astype(np.intp)]
        return out

    def move_scores(self, here: np.ndarray, there: np.ndarray, moves: np.ndarray, room: np.ndarray,
                    du: np.ndarray) -> np.ndarray:
        """(N, M) action values from V sampled at the robots (``here``, (N,)) and at the ends of their
        ``moves`` (``there``, (N, M); :data:`UNREACHED` where none was found): what :meth:`q_values`
        computes from the map, for callers that read V from tables of their own (a fleet's)."""
        with _threads_for(1), torch.inference_mode():
            there_t = torch.from_numpy(np.asarray(there, np.float32))
            features = move_features(torch.from_numpy(np.asarray(here, np.float32)), there_t, there_t > UNREACHED / 2,
                                     torch.from_numpy(np.hypot(*np.asarray(moves, float).T)).float(),
                                     torch.from_numpy(np.asarray(room, np.float32)),
                                     torch.from_numpy(np.asarray(du, np.float32)), self.network.dv_clip)
            return self.network.scores(features).numpy()

    def among_others(self, world: World, view: MapView, v: torch.Tensor,
                    position: np.ndarray) -> tuple[MapView, torch.Tensor, tuple[slice, slice]]:
        """The map view and values over the square of :data:`OTHERS_PATCH` around ``position``,
        planned again among the world's other robots (see the class), and the square's rows and
        columns in ``view``; the whole map's when none is near."""
        r = world.robot_radius
        others = world.others
        others = others[np.max(np.abs(others - position), axis=1) < OTHERS_PATCH + 2 * r + OTHERS_ROOM]
        if not len(others):
            return view, v, (slice(None), slice(None))
        grid = view.grid
        rows, cols = grid.shape
        c0, r0 = np.floor(grid.to_index(position)).astype(int)
        half = int(np.ceil(OTHERS_PATCH * grid.resolution))
        cs = slice(max(0, c0 - half), min(cols, c0 + half + 2))
        rs = slice(max(0, r0 - half), min(rows, r0 + half + 2))
        patch_grid = Grid(tuple(grid.to_world((cs.start, rs.start)).tolist()), grid.resolution,
                          (rs.stop - rs.start, cs.stop - cs.start))
        nodes = patch_grid.node_points()
        gap = np.full(len(nodes), np.inf)      # from each node to the nearest other robot's disc
        for centre in others:
            gap = np.minimum(gap, np.hypot(nodes[:, 0] - centre[0], nodes[:, 1] - centre[1]) - r)
        gap = gap.reshape(patch_grid.shape)
        # the discs enter the clearance feature as obstacles do, block where the robot would touch them,
        # and cost more within OTHERS_ROOM beyond that
        clearance = np.minimum(view.clearance[rs, cs], np.clip((gap - r) / 2.0, -0.5, 1.0)).astype(np.float32)
        free = view.free[rs, cs] & (gap >= r + MAP_MARGIN)
        goal = view.goal[rs, cs] & free
        patch = MapView(patch_grid, clearance, free, goal)
        held = np.zeros(patch_grid.shape, bool)
        held[[0, -1], :] = held[:, [0, -1]] = True
        extra = torch.from_numpy(np.where(gap < r + OTHERS_ROOM, OTHERS_COST, 0.0).astype(np.float32))
        graph = self.graph(world)
        patch_v = replan(self.network, torch.from_numpy(patch.features), torch.from_numpy(free),
                         torch.from_numpy(held | goal), v[rs, cs], extra, grid.resolution,
                         None if graph is None else torch.from_numpy(graph.links[:, rs, cs]))
        return patch, patch_v, (rs, cs)

def robot_move_inputs(where: Moment | World, positions: np.ndarray,
                      moves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`move_inputs` for moves of each robot's own: ``moves`` (N, M, 2).

    ``room`` is the bound :func:`~apf_physics.control.shield.move_clearance` computes for a move (the
    clearance sampled at :data:`~apf_physics.control.shield.MOVE_SAMPLES` points, less half their
    spacing), beyond the robot's radius and the safety margin.
    """
    world = where.world if isinstance(where, Moment) else where
    positions = np.asarray(positions, float).reshape(-1, 2)
    moves = np.asarray(moves, float)
    n, m = moves.shape[:2]
    spacing = np.hypot(moves[..., 0], moves[..., 1]).ravel() / MOVE_SAMPLES
    start = np.repeat(positions, m, axis=0)
    end = start + moves.reshape(-1, 2)
    clear = where.path_clearance(start, end, np.where(spacing > 0, spacing, 1.0)) - 0.5 * spacing
    room = clear.reshape(n, m) - (world.robot_radius + SAFETY)
    d = where.potential(end).reshape(n, m) - where.potential(positions)[:, None]
    return room, signed_log(d) / 4.0


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
                             torch.from_numpy(np.asarray(du)).to(v.dtype), network.dv_clip)
    return network.scores(features)


def node_scores(network: MapNetwork, view: MapView, v: torch.Tensor, kappa: torch.Tensor, positions: np.ndarray,
                moves: np.ndarray, ends: np.ndarray, room: np.ndarray, du: np.ndarray) -> torch.Tensor:
    """(N, M) the network's action values for moves of each robot's own that end on nodes
    (differentiable in ``v``, ``kappa`` and the head's weights).

    V is read at each move's end node exactly (``ends``; −1: staying, or not a move), and where
    the robot is: at its node when it stands on one, else from the nodes around it less the
    learned cost of the way there (:func:`~apf_physics.models.mapnet.values_between`).
    """
    positions = np.asarray(positions, float).reshape(-1, 2)
    flat = v.reshape(-1)
    rows, cols = v.shape
    index = view.grid.to_index(positions)
    near = np.rint(index)
    on = np.all(np.abs(index - near) / view.grid.resolution <= 1e-6, axis=1)
    node = (np.clip(near[:, 1], 0, rows - 1) * cols + np.clip(near[:, 0], 0, cols - 1)).astype(np.intp)
    between = values_between(v, kappa, torch.from_numpy(view.free), view.grid.origin, view.grid.resolution,
                             torch.from_numpy(positions).to(v.dtype))
    here = torch.where(torch.from_numpy(on), flat[torch.from_numpy(node)], between)
    ends_t = torch.from_numpy(np.asarray(ends, np.intp))
    there = torch.where(ends_t >= 0, flat[ends_t.clamp_min(0)], here[:, None].expand(-1, ends_t.shape[1]))
    found = there > UNREACHED / 2
    moves_t = torch.from_numpy(np.array(moves, float)).to(v.dtype)
    lengths = torch.hypot(moves_t[..., 0], moves_t[..., 1])
    features = move_features(here, there, found, lengths, torch.from_numpy(np.asarray(room)).to(v.dtype),
                             torch.from_numpy(np.asarray(du)).to(v.dtype), network.dv_clip)
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
