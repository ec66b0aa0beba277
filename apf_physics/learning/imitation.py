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

from apf_physics.control.shield import MOVE_SAMPLES, MOVE_SETS, SAFETY
from apf_physics.models.mapnet import MapNetwork, sample_values
from apf_physics.models.policy import MapPolicy, map_scores, move_inputs
from apf_physics.sensing.mapview import MapView
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.learning.config import ImitationConfig, TrainConfig
from apf_physics.learning.learner import Counters, Learner
from apf_physics.learning.phases import Phase
from apf_physics.world.search import SearchGrid
from apf_physics.world.core import World

DEFAULT_GRAD_NORM = 10.0
"""Gradient norm the map network is clipped to when ``max_grad_norm`` is not set."""


def map_network(config: TrainConfig) -> MapNetwork:
    """A freshly initialised map network for this configuration."""
    return MapNetwork(resolution=config.imitation.map_resolution, channels=config.imitation.map_channels,
                      hidden=config.network.hidden, negative_slope=config.network.negative_slope,
                      moves=config.imitation.map_moves)


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


class Demonstrations:
    """Teachers for the worlds of a phase (built on first use, kept while the worlds are)."""

    def __init__(self, resolution: int):
        self.resolution = resolution
        self._teachers: dict[int, Teacher] = {}

    def use(self, worlds: Sequence[World]) -> None:
        keep = {id(w) for w in worlds}
        self._teachers = {k: v for k, v in self._teachers.items() if k in keep}

    def of(self, world: World) -> Teacher:
        if id(world) not in self._teachers:
            self._teachers[id(world)] = Teacher.of(world, self.resolution)
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
    raster = world.clearance_raster(TEACHER_RESOLUTION, TEACHER_CAP)
    steps = np.linspace(0.0, 1.0, MOVE_SAMPLES + 1)
    points = positions[:, None, None, :] + steps[None, None, :, None] * moves[None, :, None, :]
    clearance = raster.sample(points.reshape(-1, 2)).reshape(len(positions), len(moves), -1).min(axis=2)
    bound = clearance - 0.5 * np.hypot(*moves.T)[None] / MOVE_SAMPLES - 0.71 / TEACHER_RESOLUTION
    return bound - (world.robot_radius + SAFETY)


def batch(teacher: Teacher, config: ImitationConfig, rng: np.random.Generator) -> Optional[tuple]:
    """Positions, per-move inputs (:func:`~apf_physics.models.policy.move_inputs`) and teacher labels for
    one update in ``teacher``'s world; None when it has none."""
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
    positions, room, du, target = data
    view = teacher.view
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
        self.teachers = Demonstrations(config.imitation.map_resolution)
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

