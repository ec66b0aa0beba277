"""What a run trains on, in order: phases.

A :class:`Phase` is a set of worlds, where its searches start, a budget (searches or
transitions; none: until the run stops), optionally a pool of generated worlds redrawn as it
goes, and its **validation starts**: the starts its networks are evaluated from, which choose
``best.pt`` and measure ``target_success``. The trainer runs the phases in turn with one loop
(:func:`apf_physics.learning.trainer.train`):

- one world (:func:`phases_for_world`) is one phase. Its validation starts are random free
  starts that no training search starts from (``eval_random_starts`` of them), and the
  world's own starts (the **world starts**) are evaluated and reported beside them; without
  ``eval_random_starts`` the world starts are the validation starts;
- a curriculum (:func:`phases_for_curriculum`) is one phase per stage, stage ``i`` training its
  worlds with every earlier stage's (rehearsal, Model §2), then, with
  :attr:`~apf_physics.learning.config.TrainConfig.families`, a phase of generated worlds plus all the
  curriculum's; all validated on the starts of one set of generated worlds.

Every action moves the robot by an integer vector (Model Table 1), so from a start ``p`` it
only ever stands at ``p + (i, j)`` until a collision ends the search: with a goal tolerance
below √2/2 some starts can never succeed (:func:`reachable_mask`). ``train_starts="lattice"``
(the free points at integer offsets from the target) and ``"reachable"`` (random starts that
can succeed) draw only starts that can.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from apf_physics.learning.curriculum import Stage
from apf_physics.errors import UserError
from apf_physics.world.generate import FAMILIES, generate_world
from apf_physics.learning.config import TrainConfig
from apf_physics.learning.validation import EvalSet
from apf_physics.world.core import World
from apf_physics.world.io.units import world_to_file
from apf_physics.world.io.worldfile import world_from_dict

POOL_STREAM = 0x9E11
"""Tag mixed into the seed of every pool draw, so no pool equals a set drawn from an integer seed."""


@dataclass(frozen=True)
class Phase:
    """One phase of training.

    Attributes:
        name: The world's or stage's name, or ``"randomised"``.
        worlds: The fixed worlds trained (a stage's rehearsal set); one is drawn per search.
        starts: Where searches start: ``"world"``, ``"random"`` or an (S, 2) array (see
            :class:`~apf_physics.envs.NavigateVectorEnv`); a share of the envs
            (:attr:`~apf_physics.learning.config.TrainConfig.world_start_fraction`) always uses ``"world"``.
        episodes: Searches in this phase (None: no limit of that kind).
        steps: Transitions in this phase (None: no limit of that kind). With neither, the
            phase runs until the run stops.
        validation: The validation starts: what its networks are evaluated on, which chooses
            ``best.pt`` (``target_success`` refers to it).
        pool: Whether generated worlds (:func:`draw_pool`) join ``worlds``, redrawn every
            :attr:`~apf_physics.learning.config.TrainConfig.refresh_every` transitions.
        world_starts: The world's own starts, evaluated and reported beside the validation starts
            (figures ``world_starts_success``, ``world_starts_collisions``; None: a curriculum). The
            validation set itself when the world's starts are the validation starts.
    """

    name: str
    worlds: tuple[World, ...]
    starts: Any
    episodes: Optional[int]
    steps: Optional[int]
    validation: EvalSet
    pool: bool = False
    world_starts: Optional[EvalSet] = None

    @property
    def open_ended(self) -> bool:
        return self.episodes is None and self.steps is None


def phases_for_world(world: World, config: TrainConfig) -> list[Phase]:
    """One phase: ``world`` until the run stops, validated on ``eval_random_starts`` random free starts
    (:func:`validation_starts`; without them, on the world's own starts), the world starts beside them.

    Raises:
        UserError: The world has no starts, or the configuration trains on generated worlds.
    """
    schedule = config.schedule
    if schedule.families or schedule.stage_episodes is not None or schedule.stage_steps is not None:
        raise UserError(f"preset {config.preset!r} trains a curriculum (stages or generated worlds); "
                        "give it a curriculum file, or choose a preset for one world")
    if not len(world.starts):
        raise UserError(f"{world.label}: the world has no starts to evaluate from")
    world_starts = EvalSet.of([world])
    validation = world_starts
    if config.evaluation.eval_random_starts:
        points = validation_starts(world, config.evaluation.eval_random_starts, config.run.seed)
        validation = EvalSet.unlabelled([world_from_dict({**world_to_file(world), "name": f"{world.name}-validation",
                                                          "starts": points.tolist()}, source=world.label,
                                                         confine=False)])
    return [Phase(world.name, (world,), training_starts(world, config.env.train_starts, config.run.seed), None, None,
                  validation, world_starts=world_starts)]


def phases_for_curriculum(stages: Sequence[Stage], config: TrainConfig) -> list[Phase]:
    """A phase per stage (its rehearsal set), then the randomised phase; validated on generated worlds.

    Stage phases last :attr:`~TrainConfig.stage_episodes` searches or
    :attr:`~TrainConfig.stage_steps` transitions; without either, the stages' worlds only join
    the randomised phase. Without :attr:`~TrainConfig.families` the last stage runs on until
    the run stops, if the run has a limit of its own.

    Raises:
        UserError: Nothing to train, or starts that need a single world.
    """
    if config.env.train_starts not in ("world", "random"):
        raise UserError(f"train_starts {config.env.train_starts!r} needs a single world; "
                        "a curriculum trains with 'world' or 'random'")
    staged = config.schedule.stage_episodes is not None or config.schedule.stage_steps is not None
    if not (staged and stages) and not config.schedule.families:
        raise UserError(f"preset {config.preset!r} trains one world: give it --world, or set stage_episodes, "
                        "stage_steps or families for a curriculum")
    if config.env.failure_starts:
        raise UserError("failure_starts draws the starts of one world; a curriculum trains with failure_starts=0")
    validation = validation_set(config)
    phases = []
    if staged:
        phases = [Phase(s.name, tuple(s.training_worlds), config.env.train_starts, config.schedule.stage_episodes,
                        config.schedule.stage_steps, validation) for s in stages]
    if config.schedule.families:
        everything = tuple(stages[-1].training_worlds) if stages else ()
        phases.append(Phase("randomised", everything, config.env.train_starts, None, None, validation, pool=True))
    elif any(v is not None for v in (config.schedule.total_steps, config.schedule.total_episodes,
                                     config.schedule.time_limit)):
        last = phases[-1]
        phases[-1] = Phase(last.name, last.worlds, last.starts, None, None, validation)
    return phases


def draw_pool(config: TrainConfig, draw: int) -> list[World]:
    """The ``draw``-th generated training pool (deterministic in the seed and ``draw``).

    Families and map sizes (:attr:`~TrainConfig.map_sizes`) are cycled. Its generator is
    seeded with ``[POOL_STREAM, seed, draw]``, a sequence, so it never coincides with a set
    generated from an integer seed (the held-out or validation set).
    """
    rng = np.random.default_rng([POOL_STREAM, config.run.seed, draw])
    fams, sizes = config.schedule.families, config.schedule.map_sizes
    return [generate_world(fams[k % len(fams)], rng, size=sizes[k % len(sizes)], n_starts=config.schedule.pool_starts,
                           name=f"pool{draw}_{fams[k % len(fams)]}_{k}")
            for k in range(config.schedule.pool_size)]


def validation_set(config: TrainConfig) -> EvalSet:
    """The generated validation worlds (the pool's families and map sizes in turn, or all static
    families without a pool, from ``validation_seed``), labelled."""
    rng = np.random.default_rng(config.evaluation.validation_seed)
    fams, sizes = config.schedule.families or FAMILIES, config.schedule.map_sizes
    ev = config.evaluation
    worlds = [generate_world(fams[k % len(fams)], rng, size=sizes[k % len(sizes)], n_starts=ev.validation_starts,
                             name=f"val_{fams[k % len(fams)]}_{k}") for k in range(ev.validation_worlds)]
    return EvalSet.of(worlds)


def reachable_mask(world: Any, points: np.ndarray) -> np.ndarray:
    """Which start points can end a step within the goal tolerance of a target.

    From ``p`` the robot only ever stands at ``p + (i, j)``, so it can succeed only if
    ``p − t`` is within the tolerance of an integer vector for a target ``t``: for uniformly
    random starts π·0.5² ≈ 79 % of them at tolerance 0.5, all of them at √2/2 or more.

    Args:
        world: The world (its ``targets`` and ``goal_tolerance``).
        points: (N, 2) start points.

    Returns:
        (N,) bool.
    """
    d = np.asarray(points, float)[:, None, :] - np.asarray(world.targets, float)[None]
    offset = d - np.round(d)
    return (np.linalg.norm(offset, axis=2) <= world.goal_tolerance).any(axis=1)


def _away_from_targets(world: World, points: np.ndarray) -> np.ndarray:
    return ~world.reached(points)


def validation_starts(world: World, count: int, seed: int) -> np.ndarray:
    """``count`` random free starts that can reach a target (for ``eval_random_starts``).

    Drawn like ``"reachable"`` training starts but from a generator of their own (seeded
    ``[seed, 13]``), farther than the goal tolerance from every target.
    """
    rng = np.random.default_rng([seed, 13])
    out = np.empty((0, 2))
    while len(out) < count:
        points = world.random_free_positions(rng, 4 * count)
        out = np.vstack([out, points[_away_from_targets(world, points) & reachable_mask(world, points)]])
    return out[:count]


def training_starts(world: World, kind: str, seed: int, count: int = 50_000) -> Any:
    """The training environments' ``starts`` for :attr:`~TrainConfig.train_starts` ``kind``.

    ``"world"`` and ``"random"`` are passed through; ``"reachable"`` gives up to ``count``
    random free positions (generator seeded ``[seed, 7]``) kept by :func:`reachable_mask`;
    ``"lattice"`` the free points at integer offsets from the targets. Both keep only points
    farther than the goal tolerance from every target.
    """
    if kind in ("world", "random"):
        return kind
    rng = np.random.default_rng([seed, 7])
    if kind == "reachable":
        points = world.random_free_positions(rng, count)
        points = points[reachable_mask(world, points)]
    else:
        w, h = world.size
        targets = np.asarray(world.targets, float)
        xs = [t[0] + np.arange(np.floor(-t[0]), np.ceil(w - t[0]) + 1) for t in targets]
        ys = [t[1] + np.arange(np.floor(-t[1]), np.ceil(h - t[1]) + 1) for t in targets]
        points = np.concatenate([np.stack(np.meshgrid(x, y), -1).reshape(-1, 2) for x, y in zip(xs, ys)])
        points = points[world.is_free(points)]
        points = rng.permutation(np.unique(points, axis=0))
    return points[_away_from_targets(world, points)]
