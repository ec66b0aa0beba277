"""Training the map network from demonstrations, as a :class:`~apf_physics.learning.learner.Learner`: A* is the teacher, never the pilot.

The map network (:class:`~apf_physics.models.mapnet.MapNetwork`) is trained by imitation:
on generated worlds of many families and sizes (the phases' worlds and a pool redrawn every
:attr:`~apf_physics.learning.config.ScheduleConfig.refresh_every` updates), robots are put at random
free places; for each of its moves the teacher knows the grid A*'s cost to go from where the
move ends (:attr:`apf_physics.world.search.SearchGrid.cost_to_go`, one Dijkstra per world), and
its move probabilities are ``softmax(−cost / T)`` over the moves that keep the robot's
clearance (unsafe moves get none, so the network itself learns to keep clear, not only its
shield). The network's action values are trained to those probabilities by cross-entropy.
Each step of the loop is one update on one world: one value iteration over its map view, a
batch of positions. The network's per-move inputs are :func:`~apf_physics.models.policy.move_inputs`,
the very function the planner calls when it acts.

Everything else is the training loop's (:mod:`apf_physics.learning.trainer`): the locked run
folder, ``train.csv`` and its curve, ``best.pt`` picked by the greedy evaluation on the
validation set exactly as ``apf-physics eval --planner dqn --model best.pt`` runs it, and
``last.pt`` written atomically at every checkpoint for ``--resume``. Its steps are updates.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from apf_physics.sim.nodegraph import NEIGHBOURS, NodeGraph, node_moves, resolution_for
from apf_physics.control.shield import MOVE_SAMPLES, MOVE_SETS, SAFETY
from apf_physics.models.mapnet import MapNetwork, sample_values
from apf_physics.models.policy import MapPolicy, map_scores, move_inputs, node_scores, robot_move_inputs
from apf_physics.sensing.mapview import MapView
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.learning.config import ImitationConfig, TrainConfig
from apf_physics.learning.learner import Counters, Learner
from apf_physics.learning.phases import Phase
from apf_physics.world.kinematics import NODE_MOVES
from apf_physics.world.search import SearchGrid, shortest_paths
from apf_physics.world.core import World

DEFAULT_GRAD_NORM = 10.0
"""Gradient norm the map network is clipped to when ``max_grad_norm`` is not set."""


def map_network(config: TrainConfig) -> MapNetwork:
    """A freshly initialised map network for this configuration."""
    return MapNetwork(resolution=config.imitation.map_resolution, channels=config.imitation.map_channels,
                      hidden=config.network.hidden, negative_slope=config.network.negative_slope,
                      moves=config.imitation.map_moves, dv_clip=config.imitation.map_dv_clip,
                      least_resolution=config.imitation.map_least_resolution)


@dataclasses.dataclass
class Teacher:
    """A world's demonstrations: its map view and the cost to go of A*'s search over the same grid."""

    world: World
    view: MapView
    search: SearchGrid
    cost: torch.Tensor      # (rows, cols) −cost to go (the teacher's V), UNREACHED where none
    reachable: torch.Tensor  # (rows, cols) bool

    @classmethod
    def of(cls, world: World, resolution: int) -> "Teacher":
        # A* on the network's own grid (its nodes, its clearance margin): the moves it is shown
        # are ones its values can express
        search = SearchGrid.of(world, resolution, SAFETY)
        cost = search.cost_to_go.reshape(search.grid.shape)
        finite = np.isfinite(cost)
        return cls(world, MapView.of(world, resolution), search,
                   torch.from_numpy(np.where(finite, -cost, -1e6)).float(), torch.from_numpy(search.free & finite))

    def labels(self, positions: np.ndarray, moves: np.ndarray, room: np.ndarray,
               temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """(N, M) the teacher's move probabilities, and (N,) which positions have any safe move toward a target."""
        n, m = len(positions), len(moves)
        ends = torch.from_numpy((positions[:, None, :] + moves[None]).reshape(-1, 2)).float()
        value, found = sample_values(self.cost, self.reachable, self.search.grid.origin, self.search.grid.resolution,
                                     ends)
        value, found = value.numpy().reshape(n, m).astype(float), found.numpy().reshape(n, m)
        # a move that ends at a target beats every other; staying is never a way there
        ends = ends.numpy().reshape(n, m, 2).astype(float)
        near = np.min(np.hypot(ends[..., None, 0] - self.world.targets[:, 0], ends[..., None, 1] - self.world.targets[:, 1]),
                      axis=-1)
        value = np.where(near <= self.world.goal_tolerance, 1.0, value) - 0.25 * (np.hypot(*moves.T) == 0)[None]
        usable = found & (room >= 0)
        logits = np.where(usable, value / temperature, -np.inf)
        ok = usable.any(axis=1)
        logits[~ok] = 0.0
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        return p / p.sum(axis=1, keepdims=True), ok


PROGRESS = 1.5
"""A node teacher weighs the length to go after a move this many times its length: of the moves
along a shortest path (which tie on length plus length to go), the longest is preferred, by
``(PROGRESS − 1) × length``; a move off it loses its extra length."""


@dataclasses.dataclass
class NodeTeacher:
    """A world's demonstrations for a network that moves onto nodes: its map view and node graph
    (at the resolution the network plans at there, :func:`~apf_physics.nodegraph.resolution_for`),
    and the shortest length to go from every node over the graph's links (one search per world)."""

    world: World
    view: MapView
    graph: NodeGraph
    cost: np.ndarray       # (rows * cols,) length to go over the links, inf where no target is reached

    @classmethod
    def of(cls, world: World, base: int, least: int | None = None) -> "NodeTeacher":
        resolution = resolution_for(world, base, least)
        view = MapView.of(world, resolution)
        graph = NodeGraph.of(world, resolution, SAFETY)
        steps = [(dr, dc, np.where(graph.links[k], np.hypot(dr, dc) / resolution, np.inf))
                 for k, (dr, dc) in enumerate(NEIGHBOURS)]
        cost, _ = shortest_paths(graph.free, np.flatnonzero(view.goal.ravel()), steps)
        return cls(world, view, graph, cost)

    def labels(self, positions: np.ndarray, moves: np.ndarray, usable: np.ndarray, ends: np.ndarray,
               room: np.ndarray, temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """(N, M) the teacher's move probabilities, and (N,) which positions have any safe move toward a target.

        A move is worth minus its length and :data:`PROGRESS` times the length to go from its end
        node: the shortest way, and on it the longest move (every move along a shortest path
        costs its length in length to go, and gains ``PROGRESS − 1`` times its length over the
        others). One that ends within the goal tolerance beats every other; staying is worth
        what a move of length 0 would be, less 0.25 (never a way to the target)."""
        lengths = np.hypot(moves[..., 0], moves[..., 1])
        to_go = np.where(ends >= 0, self.cost[np.maximum(ends, 0)], np.inf)
        value = -(lengths + PROGRESS * to_go)
        ends_xy = positions[:, None, :] + moves
        near = np.min(np.hypot(ends_xy[..., None, 0] - self.world.targets[:, 0],
                               ends_xy[..., None, 1] - self.world.targets[:, 1]), axis=-1)
        value = np.where((ends >= 0) & (near <= self.world.goal_tolerance), 1.0, value)
        moving = ends >= 0
        # staying: the length to go from here (the best move's length and length to go)
        here = np.where(moving, lengths + to_go, np.inf).min(axis=1)
        value[:, -1] = -PROGRESS * here - 0.25          # staying (the last move)
        usable = usable & np.isfinite(value) & (room >= 0)
        logits = np.where(usable, value / temperature, -np.inf)
        ok = (usable & moving).any(axis=1)
        logits[~ok] = 0.0
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        return p / p.sum(axis=1, keepdims=True), ok


class Demonstrations:
    """Teachers for the worlds of a phase (built on first use, kept while the worlds are)."""

    def __init__(self, resolution: int, on_nodes: bool = False, least: int | None = None):
        self.resolution = resolution
        self.on_nodes = on_nodes
        self.least = least
        self._teachers: dict[int, Teacher | NodeTeacher] = {}

    def use(self, worlds: Sequence[World]) -> None:
        keep = {id(w) for w in worlds}
        self._teachers = {k: v for k, v in self._teachers.items() if k in keep}

    def of(self, world: World) -> Teacher | NodeTeacher:
        if id(world) not in self._teachers:
            self._teachers[id(world)] = (NodeTeacher.of(world, self.resolution, self.least) if self.on_nodes
                                         else Teacher.of(world, self.resolution))
        return self._teachers[id(world)]


TEACHER_RESOLUTION = 8
"""Nodes per unit of the static clearance raster the teacher's rule samples (:func:`teacher_room`;
the raster the physics once used, kept so that the labels stay as the shipped models were taught)."""
TEACHER_CAP = 4.0
"""Clearance beyond this is not measured by that raster."""


def teacher_room(world: World, positions: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """Which moves the teacher demonstrates as safe (``>= 0``): a lower bound, within the room the
    network reads (up to 1), of the room :func:`~apf_physics.models.policy.move_inputs` gives, from
    the static obstacles' clearance raster.

    The teacher keeps a wider berth than the shield: the raster is sampled at the move's
    :data:`~apf_physics.control.shield.MOVE_SAMPLES` points and lowered by half their spacing and by the
    raster's interpolation error. Labels on the exact room made the network alone collide (3 of
    72 validation starts) and do worse on large maps (BENCHMARKS.md). This is the teacher's rule,
    not an input: the network reads ``move_inputs`` when it trains as when it acts.
    """
    raster = world.clearance_raster(TEACHER_RESOLUTION, max(TEACHER_CAP, world.robot_radius + 1.5))
    steps = np.linspace(0.0, 1.0, MOVE_SAMPLES + 1)
    each = moves if moves.ndim == 3 else np.broadcast_to(moves, (len(positions), *moves.shape))   # (N, M, 2)
    points = positions[:, None, None, :] + steps[None, None, :, None] * each[:, :, None, :]
    clearance = raster.sample(points.reshape(-1, 2)).reshape(*each.shape[:2], -1).min(axis=2)
    length = np.hypot(each[..., 0], each[..., 1])
    bound = clearance - 0.5 * length / MOVE_SAMPLES - 0.71 / TEACHER_RESOLUTION
    return bound - (world.robot_radius + SAFETY)


NODE_SHARE = 0.75
"""Of the positions a node teacher labels, the share on free nodes (where the robot stands after its
first move); the others anywhere free (where it starts)."""


def node_batch(teacher: NodeTeacher, config: ImitationConfig, rng: np.random.Generator) -> Optional[tuple]:
    """:func:`batch` for a network that moves onto nodes: positions, their moves, per-move inputs and labels."""
    world, graph = teacher.world, teacher.graph
    nodes = np.flatnonzero(graph.free.ravel() & np.isfinite(teacher.cost))
    if not len(nodes):
        return None
    count = config.demo_positions
    on = graph.grid.to_world(np.column_stack(np.divmod(rng.choice(nodes, int(count * NODE_SHARE)), graph.grid.shape[1])[::-1]))
    candidates = rng.uniform((0.0, 0.0), world.size, size=(4 * count, 2))
    fits = teacher_room(world, candidates, np.zeros((1, 2)))[:, 0] >= 0
    positions = np.vstack([on, candidates[fits][:count - len(on)]])
    moves, usable, ends = node_moves(graph, positions)
    room, du = robot_move_inputs(world, positions, moves)
    # the moves demonstrated are those the shield admits (the room the network reads, at least 0):
    # the graph's links are exactly such moves, and its narrowest passages need every one of them
    target, ok = teacher.labels(positions, moves, usable, ends, room, config.label_temperature)
    if not ok.any():
        return None
    return positions[ok], moves[ok], usable[ok], ends[ok], room[ok], du[ok], target[ok]


def batch(teacher: Teacher | NodeTeacher, config: ImitationConfig, rng: np.random.Generator) -> Optional[tuple]:
    """Positions, per-move inputs (:func:`~apf_physics.models.policy.move_inputs`) and teacher labels for
    one update in ``teacher``'s world; None when it has none."""
    if isinstance(teacher, NodeTeacher):
        return node_batch(teacher, config, rng)
    world = teacher.world
    moves = MOVE_SETS[config.map_moves]
    candidates = rng.uniform((0.0, 0.0), world.size, size=(4 * config.demo_positions, 2))
    fits = teacher_room(world, candidates, np.zeros((1, 2)))[:, 0] >= 0
    positions = candidates[fits][:config.demo_positions]
    if not len(positions):
        return None
    room, du = move_inputs(world, positions, moves)
    target, ok = teacher.labels(positions, moves, teacher_room(world, positions, moves), config.label_temperature)
    if not ok.any():
        return None
    return positions[ok], room[ok], du[ok], target[ok]


def update(network: MapNetwork, optimizer: torch.optim.Optimizer, teacher: Teacher, data: tuple,
           config: TrainConfig) -> float:
    """One gradient step on one world's demonstrations (:func:`batch`); the loss."""
    view = teacher.view
    if isinstance(teacher, NodeTeacher):
        positions, moves, usable, ends, room, du, target = data
        v, kappa = network.values(torch.from_numpy(view.features), torch.from_numpy(view.free),
                                  torch.from_numpy(view.goal), grad_iterations=config.imitation.grad_iterations,
                                  links=torch.from_numpy(teacher.graph.links),
                                  resolution=teacher.graph.grid.resolution, with_cost=True)
        scores = node_scores(network, view, v, kappa, positions, moves, ends, room, du)
        scores = torch.where(torch.from_numpy(usable), scores, torch.full_like(scores, -1e9))   # not moves at all
    else:
        positions, room, du, target = data
        v = network.values(torch.from_numpy(view.features), torch.from_numpy(view.free), torch.from_numpy(view.goal),
                           grad_iterations=config.imitation.grad_iterations)
        scores = map_scores(network, view, v, positions, MOVE_SETS[config.imitation.map_moves], room, du)
    loss = -(torch.from_numpy(target).float() * F.log_softmax(scores, dim=1)).sum(dim=1).mean()
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(network.parameters(), config.network.max_grad_norm or DEFAULT_GRAD_NORM)
    optimizer.step()
    return float(loss.detach())


class ImitationLearner(Learner):
    """The map network taught by A* (see the module's docstring); a step is one update on one world."""

    def __init__(self, config: TrainConfig):
        self.config = config
        self.network = map_network(config)
        self.observer = None
        self.optimizer = torch.optim.Adam(self.network.parameters(), lr=config.network.learning_rate)
        self.teachers = Demonstrations(config.imitation.map_resolution, config.imitation.map_moves == NODE_MOVES,
                                       config.imitation.map_least_resolution)
        self.worlds: list[World] = []
        self.losses: list[float] = []
        self._batch: Optional[tuple] = None
        self.updates = 0
        """Gradient updates made."""

    def begin(self, worlds: Sequence[World], phase: Phase, seed: tuple[int, int]) -> None:
        self.worlds = list(worlds)
        self.teachers.use(self.worlds)

    def collect(self, c: Counters, rng: np.random.Generator) -> tuple[int, int]:
        teacher = self.teachers.of(self.worlds[int(rng.integers(len(self.worlds)))])
        data = batch(teacher, self.config.imitation, rng)
        self._batch = None if data is None else (teacher, data)
        return 1, self.config.imitation.demo_positions

    def update(self, c: Counters, rng: np.random.Generator) -> None:
        if self._batch is not None:
            self.losses.append(update(self.network, self.optimizer, *self._batch, self.config))
            self.updates += 1
            self._batch = None

    def planner(self, shield: bool) -> DQNPlanner:
        return DQNPlanner(policy=MapPolicy(self.network), shield=shield)

    def log_values(self, c: Counters) -> dict[str, Any]:
        loss = float(np.mean(self.losses)) if self.losses else None
        self.losses = []
        return {"epsilon": "", "mean_return": "", "training_success": "", "loss": loss}

    def state(self, with_buffer: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        return {"losses": self.losses, "updates": self.updates}, {"q_network": self.network.state_dict(),
                                         "optimizer": self.optimizer.state_dict()}

    def load(self, state: dict[str, Any], tensors: dict[str, Any]) -> None:
        self.network.load_state_dict(tensors["q_network"])
        self.optimizer.load_state_dict(tensors["optimizer"])
        self.losses = list(state["losses"])
        self.updates = int(state["updates"])

