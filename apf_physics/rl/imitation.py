"""Training the map network from demonstrations: A* is the teacher, never the pilot.

The map network (:class:`~apf_physics.models.mapnet.MapNetwork`) is trained by imitation:
on generated worlds of many families and sizes (the phases' worlds and a pool redrawn every
:attr:`~apf_physics.rl.config.TrainConfig.refresh_every` updates), robots are put at random
free places; for each of its moves the teacher knows the grid A*'s cost to go from where the
move ends (:attr:`apf_physics.search.SearchGrid.cost_to_go`, one Dijkstra per world), and
its move probabilities are ``softmax(−cost / T)`` over the moves that keep the robot's
clearance (unsafe moves get none, so the network itself learns to keep clear, not only its
shield). The network's action values are trained to those probabilities by cross-entropy.
Each update is one world: one value iteration over its map view, a batch of positions.

Everything else is the DQN trainer's (:mod:`apf_physics.rl.trainer`): the locked run
folder, ``train.csv`` and its curve, ``best.pt`` picked by the greedy evaluation on the
validation set exactly as ``apf-physics eval --planner dqn --model best.pt`` runs it, and
``last.pt`` written atomically at every checkpoint for ``--resume``. The counters' steps are
updates.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from apf_physics.actions import MOVE_SAMPLES, MOVE_SETS, SAFETY
from apf_physics.errors import UserError
from apf_physics.evaluate import evaluate as run_planner
from apf_physics.models.files import model_meta, read_file, save_model, write_file
from apf_physics.models.mapnet import MapNetwork, sample_values
from apf_physics.models.policy import MapPolicy, map_scores, potential_change
from apf_physics.observation import MapView
from apf_physics.physics import CLEARANCE_CAP, CLEARANCE_RESOLUTION
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.rl import evaluation
from apf_physics.rl.config import TrainConfig, differing_fields
from apf_physics.rl.phases import Phase, draw_pool
from apf_physics.rl.rundir import RunDir
from apf_physics.rl.trainer import (Counters, Evaluations, TrainResult, next_multiple, run_training,
                                    save_curve, stop_reason)
from apf_physics.search import SearchGrid
from apf_physics.world import World


def map_network(config: TrainConfig) -> MapNetwork:
    """A freshly initialised map network for this configuration."""
    return MapNetwork(resolution=config.map_resolution, channels=config.map_channels, hidden=config.hidden,
                      negative_slope=config.negative_slope, moves=config.map_moves)


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


def quick_room(world: World, positions: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """:func:`~apf_physics.actions.move_clearance` minus the robot's radius and the safety margin,
    from the physics' clearance raster (a bound as well: its interpolation error is subtracted);
    static obstacles only. Cheap enough for thousands of labelled moves per update."""
    raster = world.clearance_raster(CLEARANCE_RESOLUTION, CLEARANCE_CAP)
    steps = np.linspace(0.0, 1.0, MOVE_SAMPLES + 1)
    points = positions[:, None, None, :] + steps[None, None, :, None] * moves[None, :, None, :]
    clearance = raster.sample(points.reshape(-1, 2)).reshape(len(positions), len(moves), -1).min(axis=2)
    bound = clearance - 0.5 * np.hypot(*moves.T)[None] / MOVE_SAMPLES - 0.71 / CLEARANCE_RESOLUTION
    return bound - (world.robot_radius + SAFETY)


def batch(teacher: Teacher, config: TrainConfig, rng: np.random.Generator) -> Optional[tuple]:
    """Positions, per-move features and teacher labels for one update in ``teacher``'s world."""
    world = teacher.world
    moves = MOVE_SETS[config.map_moves]
    candidates = rng.uniform((0.0, 0.0), world.size, size=(4 * config.demo_positions, 2))
    fits = quick_room(world, candidates, np.zeros((1, 2)))[:, 0] >= 0
    positions = candidates[fits][:config.demo_positions]
    if not len(positions):
        return None
    room = quick_room(world, positions, moves)
    target, ok = teacher.labels(positions, moves, room, config.label_temperature)
    if not ok.any():
        return None
    positions, room, target = positions[ok], room[ok], target[ok]
    return positions, room, potential_change(world, positions, moves), target


def update(network: MapNetwork, optimizer: torch.optim.Optimizer, teacher: Teacher, config: TrainConfig,
           rng: np.random.Generator) -> Optional[float]:
    """One gradient step on one world's demonstrations; the loss, or None without any."""
    data = batch(teacher, config, rng)
    if data is None:
        return None
    positions, room, du, target = data
    view = teacher.view
    v = network.values(torch.from_numpy(view.features), torch.from_numpy(view.free), torch.from_numpy(view.goal),
                       grad_iterations=config.grad_iterations)
    scores = map_scores(network, view, v, positions, MOVE_SETS[config.map_moves], room, du)
    loss = -(torch.from_numpy(target).float() * F.log_softmax(scores, dim=1)).sum(dim=1).mean()
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(network.parameters(), config.max_grad_norm or 10.0)
    optimizer.step()
    return float(loss.detach())


def evaluate_map(network: MapNetwork, config: TrainConfig, phase: Phase) -> dict:
    """The figures of the network on the phase's validation set (``apf-physics eval --planner dqn``)."""
    planner = DQNPlanner(policy=MapPolicy(network), shield=config.eval_shield)
    return evaluation.summarise(run_planner(planner, phase.validation.worlds).episodes, phase.validation)


def train_imitation(config: TrainConfig, phases: Sequence[Phase], out_dir: str | Path | RunDir | None = None,
                    resume: bool = False, progress: bool = False) -> TrainResult:
    """Train a map network by imitation through ``phases`` (see the module's docstring).

    Arguments and result as :func:`apf_physics.rl.trainer.train`; steps count updates.
    """
    return run_training(_train, config, phases, out_dir, resume, progress)


def _train(config: TrainConfig, phases: list[Phase], run: Optional[RunDir], resume: bool,
           progress: bool) -> TrainResult:
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    network = map_network(config)
    optimizer = torch.optim.Adam(network.parameters(), lr=config.learning_rate)
    c, evals = Counters(), Evaluations()
    losses: list[float] = []
    if resume:
        _restore(run, config, phases, network, optimizer, c, evals, rng)
        reason = stop_reason(config, phases, c, c.wall_time)
        if reason is not None:
            return TrainResult(config, c, c.global_step, evals.best, evals.latest, reason, True, run.path, [],
                               network, evals.best_state)
    if run is not None:
        run.start_log(c.global_step if resume else None)
    teachers = Demonstrations(config.map_resolution)
    history: list[dict] = []
    elapsed_before, start = c.wall_time, time.perf_counter()
    next_eval = next_multiple(c.global_step, config.eval_every)
    next_log = next_multiple(c.global_step, config.log_every)
    next_checkpoint = next_multiple(c.global_step, config.checkpoint_every)
    reason = None
    try:
        while reason is None:
            phase = phases[min(c.phase, len(phases) - 1)]
            worlds = list(phase.worlds) + (draw_pool(config, c.pool_draws) if phase.pool else [])
            teachers.use(worlds)
            next_refresh = next_multiple(c.phase_steps, config.refresh_every) if phase.pool else None
            while True:
                world = worlds[int(rng.integers(len(worlds)))]
                loss = update(network, optimizer, teachers.of(world), config, rng)
                if loss is not None:
                    losses.append(loss)
                c.global_step += 1
                c.phase_steps += 1
                c.episodes += config.demo_positions
                phase_over = phase.steps is not None and c.phase_steps >= phase.steps
                redraw = next_refresh is not None and c.phase_steps >= next_refresh
                if phase_over:
                    c.phase, c.phase_steps = c.phase + 1, 0
                elif redraw:
                    c.pool_draws += 1
                c.wall_time = elapsed_before + time.perf_counter() - start
                summary = None
                if c.global_step >= next_eval:
                    next_eval = next_multiple(c.global_step, config.eval_every)
                    summary = evaluate_map(network, config, phase)
                    c.wall_time = elapsed_before + time.perf_counter() - start
                    if evals.record(summary, c, network, config) and run is not None:
                        save_model(run.best, network, _meta(network, config, phases, c, evals.best))
                        run.wrote(run.best)
                if summary is not None or c.global_step >= next_log:
                    next_log = next_multiple(c.global_step, config.log_every)
                    history.append(_log(run, c, phase, losses, summary))
                    losses = []
                    if progress:
                        _print_progress(c, config, evals.latest)
                reason = stop_reason(config, phases, c, c.wall_time)
                if reason is not None or phase_over or redraw or c.global_step >= next_checkpoint:
                    break
            if reason is None:
                _checkpoint(run, config, phases, network, optimizer, c, evals, rng)
                next_checkpoint = next_multiple(c.global_step, config.checkpoint_every)
        if c.last_eval_step != c.global_step:
            phase = phases[min(c.phase, len(phases) - 1)]
            summary = evaluate_map(network, config, phase)
            if evals.record(summary, c, network, config) and run is not None:
                save_model(run.best, network, _meta(network, config, phases, c, evals.best))
                run.wrote(run.best)
            history.append(_log(run, c, phase, losses, summary))
        c.wall_time = elapsed_before + time.perf_counter() - start
        _checkpoint(run, config, phases, network, optimizer, c, evals, rng)
    except KeyboardInterrupt:
        c.wall_time = elapsed_before + time.perf_counter() - start
        _checkpoint(run, config, phases, network, optimizer, c, evals, rng)
        raise
    save_curve(run)
    return TrainResult(config, c, c.global_step, evals.best, evals.latest, reason, False,
                       None if run is None else run.path, [] if run is None else list(run.written), network,
                       evals.best_state, history)


def _print_progress(c: Counters, config: TrainConfig, latest: Optional[dict]) -> None:
    """A line on stderr per log row, when it is a terminal."""
    if sys.stderr.isatty():
        latest = f", validation success {latest['success']:.1%}" if latest else ""
        print(f"  update {c.global_step:,} ({c.wall_time:.0f} s){latest}", file=sys.stderr, flush=True)


def _log(run: Optional[RunDir], c: Counters, phase: Phase, losses: list[float], summary: Optional[dict]) -> dict:
    s = {k: "" if v is None else round(v, 4) for k, v in (summary or {}).items()}
    row = {"global_step": c.global_step, "episodes": c.episodes, "phase": phase.name, "epsilon": "",
           "mean_return": "", "success_rate": "", "loss": round(float(np.mean(losses)), 6) if losses else "",
           "eval_success": s.get("success", ""), "eval_trap_success": s.get("trap_success", ""),
           "eval_collisions": s.get("collisions", ""), "eval_length_ratio": s.get("length_ratio", ""),
           "eval_spl": s.get("spl", ""), "eval_random_success": "", "pool_draws": c.pool_draws,
           "wall_time": round(c.wall_time, 3)}
    if run is not None:
        run.log(row)
    return row


def _meta(network: MapNetwork, config: TrainConfig, phases: Sequence[Phase], c: Counters,
          best: Optional[dict]) -> dict:
    training = {"phases": [p.name for p in phases], "global_step": c.global_step, "episodes": c.episodes,
                "updates": c.global_step, "wall_time": c.wall_time, "evaluation": best,
                "evaluation_step": c.best_step, "validation": [w.name for w in phases[0].validation.worlds]}
    return model_meta(network, phases[0].validation.worlds[0].field, config.to_dict(), training, None)


def _checkpoint(run: Optional[RunDir], config: TrainConfig, phases: Sequence[Phase], network: MapNetwork,
                optimizer: torch.optim.Optimizer, c: Counters, evals: Evaluations, rng: np.random.Generator) -> None:
    """Write ``last.pt``: everything a resumed run needs to go on."""
    if run is None:
        return
    meta = _meta(network, config, phases, c, evals.best)
    meta["kind"] = "checkpoint"
    meta["trainer"] = {"counters": dataclasses.asdict(c), "best": evals.best, "latest": evals.latest,
                       "numpy_rng": rng.bit_generator.state}
    tensors = {"q_network": network.state_dict(), "optimizer": optimizer.state_dict(),
               "torch_rng": torch.get_rng_state()}
    if evals.best_state is not None:
        tensors["best_state"] = evals.best_state
    write_file(run.last, meta, tensors)
    run.wrote(run.last)
    save_curve(run)


def _restore(run: RunDir, config: TrainConfig, phases: Sequence[Phase], network: MapNetwork,
             optimizer: torch.optim.Optimizer, c: Counters, evals: Evaluations, rng: np.random.Generator) -> None:
    if not run.last.is_file():
        raise UserError(f"{run.last}: nothing to resume (no checkpoint there)")
    meta, tensors = read_file(run.last)
    if meta.get("kind") != "checkpoint" or "trainer" not in meta:
        raise UserError(f"{run.last}: not a training checkpoint of this version")
    differ = differing_fields(TrainConfig.from_dict(meta["config"]), config)
    if differ:
        raise UserError(f"{run.last}: was trained with different options ({', '.join(differ)}); "
                        "resume with the same preset and options")
    network.load_state_dict(tensors["q_network"])
    optimizer.load_state_dict(tensors["optimizer"])
    state = meta["trainer"]
    for name, value in state["counters"].items():
        setattr(c, name, value)
    evals.best, evals.latest, evals.best_state = state["best"], state["latest"], tensors.get("best_state")
    rng.bit_generator.state = state["numpy_rng"]
    torch.set_rng_state(tensors["torch_rng"])
