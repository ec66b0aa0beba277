"""Training sweeps on Ray Tune: a recipe file, one trainer run per trial, ASHA, the best model copied out.

A sweep file (YAML) names what to train on, a preset and changes to it, the values to try
(grids and distributions), the seeds, each trial's budget, and the figure to compare::

    world: local_minimum            # or curriculum: worlds/curricula/thesis.yaml (paths: beside this file, here, or bundled)
    preset: fast                    # default: as `apf-physics train` (fast on a world, general-revisit on a curriculum)
    overrides: {obs_size: 5}        # TrainConfig fields, as `train --set`
    grid:                           # every combination (Tune's grid_search); `preset` may be one of the keys
      learning_rate: [1.0e-3, 3.0e-4]
    sample:                         # drawn `samples` times (uniform, loguniform, randint [low, high), choice)
      tau: {loguniform: [0.001, 0.05]}
    samples: 1
    seeds: [0, 1]                   # every combination is trained with every seed
    budget: {total_steps: 3000}     # per trial: total_steps, total_episodes or time_limit (seconds)
    reports: 3                      # evaluations reported per trial: the rungs of ASHA
    metric: success                 # success or spl, of the validation set (higher is better)
    asha: {grace_period: 1, reduction_factor: 2}   # or false: every trial gets its whole budget
    trial_cpus: 1
    max_concurrent: null

A trial is :func:`~apf_physics.rl.trainer.train` run in ``reports`` legs, each to a further
share of the budget, the next resuming the last from its ``last.pt`` (the budget fields are
:data:`~apf_physics.rl.config.RESUMABLE`). Each leg ends with an evaluation; the trial
reports the figures of its ``best.pt`` so far (the evaluation its ``select`` prefers), and the
trial's folder (``best.pt``, ``last.pt``, ``train.csv``: the trainer's own atomically written
files) as the Tune checkpoint. ASHA stops the weaker trials at the rungs. An interrupted
sweep continues with ``Tuner.restore``: every unfinished trial from its latest checkpoint.
Without ``overrides: {save_buffer: true}`` (large checkpoints) a leg starts with an empty
experience pool, which it refills for ``learning_starts`` transitions before learning on.

At the end the output folder holds ``results.csv`` (a row per trial), ``best.pt`` (the best
trial's model) and ``best.json`` (its values, figures and full configuration), beside
``tune/`` (Tune's experiment) and ``sweep.json`` (the recipe as read, to resume it).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from apf_physics.bundled import resolve_world
from apf_physics.campaign import connect, import_ray
from apf_physics.curriculum import load_curriculum
from apf_physics.errors import UserError
from apf_physics.rl.config import CURRICULUM_DEFAULT, PRESETS, WORLD_DEFAULT, TrainConfig, _did_you_mean, preset
from apf_physics.rl.phases import phases_for_curriculum, phases_for_world
from apf_physics.rl.trainer import train
from apf_physics.worldfile import load_world, read_yaml_file

KEYS = ("world", "curriculum", "preset", "overrides", "grid", "sample", "samples", "seeds", "budget", "reports",
        "metric", "asha", "trial_cpus", "max_concurrent")
"""Keys of a sweep file."""
BUDGETS = ("total_steps", "total_episodes", "time_limit")
"""What a trial's budget may count: transitions, searches or seconds (fields of :class:`TrainConfig`)."""
METRICS = ("success", "spl")
"""Figures a sweep may compare (of the validation set; higher is better)."""
DISTRIBUTIONS = ("uniform", "loguniform", "randint", "choice")
"""Distributions of ``sample`` (Tune's of the same names; ``randint``'s upper end is excluded)."""
SET_BY_SWEEP = frozenset(BUDGETS) | {"seed", "preset"}
"""Fields the sweep sets itself (from ``budget``, ``seeds`` and ``preset``), so not in ``overrides`` or ``sample``."""
FIGURES = ("success", "spl", "trap_success", "collisions", "length_ratio", "random_success")
"""Figures of an evaluation reported per leg (those present)."""
ENDED = "ended.json"
"""In the output folder: the trials Tune saw end (finished, stopped by ASHA, failed), over every session.
An interrupted trial never ends; Tune marks it terminated all the same, so this is how it is told apart."""
PROGRESS = "sweep-progress.json"
"""In a trial's folder: the legs done, so a restored trial knows where it stands."""
SAMPLE_SEED = 0
"""Seed of Tune's draws from the distributions: the same file gives the same trials."""


@dataclass(frozen=True)
class Sweep:
    """A sweep file, read and checked (:func:`load_sweep`).

    Attributes:
        source: The file.
        world: The world file trained on (or None).
        curriculum: The curriculum file trained through (or None).
        preset: The preset (of every trial without ``preset`` in :attr:`grid`).
        overrides: :class:`TrainConfig` fields changed in every trial.
        grid: Field → values, every combination tried.
        sample: Field → (distribution, its arguments), drawn :attr:`samples` times.
        samples: Draws of :attr:`sample` (Tune's ``num_samples``; each draw with the whole grid).
        seeds: Seeds every combination is trained with.
        budget: The field that stops a trial (one of :data:`BUDGETS`) and its value.
        reports: Legs of a trial, each ending with a report (ASHA's rungs).
        metric: The figure compared (one of :data:`METRICS`).
        asha: ASHA's ``grace_period`` and ``reduction_factor``; None: no early stopping.
        trial_cpus: CPUs a trial holds.
        max_concurrent: Most trials at a time (None: as many as the CPUs allow).
    """

    source: str
    world: Optional[str]
    curriculum: Optional[str]
    preset: str
    overrides: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    sample: dict = field(default_factory=dict)
    samples: int = 1
    seeds: tuple[int, ...] = (0,)
    budget: tuple[str, float] = ("total_steps", 100_000)
    reports: int = 4
    metric: str = "success"
    asha: Optional[dict] = None
    trial_cpus: float = 1.0
    max_concurrent: Optional[int] = None

    def leg_budget(self, leg: int) -> float:
        """The budget's value at the end of leg ``leg`` (1 to :attr:`reports`)."""
        name, total = self.budget
        value = total * leg / self.reports
        return value if name == "time_limit" else max(1, int(round(value)))

    def config(self, params: dict, leg: int) -> TrainConfig:
        """The trial's configuration for leg ``leg``: its preset, the overrides, its values, its seed and budget."""
        values = {k: v for k, v in params.items() if k not in ("preset", "seed")}
        limits = {name: None for name in BUDGETS}
        limits[self.budget[0]] = self.leg_budget(leg)
        return preset(params.get("preset", self.preset), **{**self.overrides, **values, **limits,
                                                            "seed": params.get("seed", self.seeds[0])})

    def param_space(self) -> dict:
        """Tune's ``param_space``: the grid, the distributions and the seeds (Ray is imported here)."""
        from ray import tune
        space: dict[str, Any] = {k: tune.grid_search(list(v)) for k, v in self.grid.items()}
        for key, (kind, args) in self.sample.items():
            space[key] = tune.choice(list(args)) if kind == "choice" else getattr(tune, kind)(*args)
        space["seed"] = tune.grid_search(list(self.seeds))
        return space

    def varied(self) -> list[str]:
        """The keys that differ between trials, seed last."""
        return [*self.grid, *self.sample, "seed"]

    def to_dict(self) -> dict:
        """Plain values, for ``sweep.json`` (and for telling a resumed sweep from another)."""
        return {"world": self.world, "curriculum": self.curriculum, "preset": self.preset,
                "overrides": self.overrides, "grid": self.grid,
                "sample": {k: {kind: list(args)} for k, (kind, args) in self.sample.items()},
                "samples": self.samples, "seeds": list(self.seeds), "budget": {self.budget[0]: self.budget[1]},
                "reports": self.reports, "metric": self.metric, "asha": self.asha, "trial_cpus": self.trial_cpus,
                "max_concurrent": self.max_concurrent}

    def target(self):
        """What the trials train on: the world, or the curriculum's stages."""
        return load_world(self.world) if self.world is not None else load_curriculum(self.curriculum)


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def load_sweep(path: str | Path) -> Sweep:
    """Read and check a sweep file (see the module's notes).

    Every value is checked as the trainer would take it, so that a mistake is found here, not
    minutes later in a trial.

    Raises:
        UserError: The file is missing or not YAML, or a key is unknown (with the nearest
            name), missing or of the wrong kind, or a value is not a usable training option;
            one line naming the file and the key.
    """
    path = Path(path)
    source = str(path)

    def fail(key: str, problem: str) -> UserError:
        return UserError(f"{source}: {key}: {problem}")

    data: Any = read_yaml_file(path, "sweep")
    if not isinstance(data, dict):
        raise UserError(f"{source}: a sweep file must be a mapping (world or curriculum, preset, grid, budget, "
                        f"metric ...), got {type(data).__name__}")
    for key in data:
        if key not in KEYS:
            raise fail(str(key), f"unknown key{_did_you_mean(str(key), KEYS)}; the keys are {', '.join(KEYS)}")

    where = [k for k in ("world", "curriculum") if data.get(k) is not None]
    if len(where) != 1:
        raise UserError(f"{source}: name exactly one of world or curriculum (what the trials train on)")
    kind = where[0]
    if not isinstance(data[kind], str) or not data[kind].strip():
        raise fail(kind, f"must be a file name, got {data[kind]!r}")
    beside = path.parent / data[kind]
    try:
        located = str((beside if beside.exists() else resolve_world(data[kind])).resolve())
    except UserError as exc:
        raise fail(kind, str(exc)) from None

    name = data.get("preset", WORLD_DEFAULT if kind == "world" else CURRICULUM_DEFAULT)
    if not isinstance(name, str) or name not in PRESETS:
        raise fail("preset", f"unknown preset {name!r}{_did_you_mean(str(name), PRESETS)}; "
                             f"choose one of {', '.join(PRESETS)}")

    def mapping(key: str) -> dict:
        value = data.get(key) or {}
        if not isinstance(value, dict):
            raise fail(key, f"must be a mapping, got {type(value).__name__}")
        return {str(k): v for k, v in value.items()}

    def check(key: str, values: dict, base: str = name) -> None:
        """Each value as a training option, one at a time (the error names the option)."""
        for option, value in values.items():
            if option in SET_BY_SWEEP and not (key == "grid" and option == "preset"):
                hint = {"seed": "seeds", "preset": "preset (or grid: {preset: [...]})"}.get(option, "budget")
                raise fail(key, f"{option} is set by the sweep's {hint}, not here")
            try:
                preset(base, **{option: value})
            except UserError as exc:
                raise fail(key, str(exc)) from None

    overrides = mapping("overrides")
    check("overrides", overrides)

    grid = mapping("grid")
    for option, values in grid.items():
        if not isinstance(values, list) or not values:
            raise fail("grid", f"{option}: must be a non-empty list of values to try, got {values!r}")
        if option == "preset":
            for p in values:
                if not isinstance(p, str) or p not in PRESETS:
                    raise fail("grid", f"preset: unknown preset {p!r}{_did_you_mean(str(p), PRESETS)}; "
                                       f"choose among {', '.join(PRESETS)}")
        else:
            for value in values:
                check("grid", {option: value})

    sample: dict[str, tuple[str, tuple]] = {}
    for option, spec in mapping("sample").items():
        if option in grid or option in overrides:
            raise fail("sample", f"{option} is also in {'grid' if option in grid else 'overrides'}")
        if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
            raise fail("sample", f"{option}: must be one of {', '.join(f'{{{d}: [...]}}' for d in DISTRIBUTIONS)}, "
                                 f"got {spec!r}")
        dist, args = next(iter(spec.items()))
        if not isinstance(args, list) or not args:
            raise fail("sample", f"{option}: {dist} needs a list, got {args!r}")
        if dist != "choice":
            low_high = len(args) == 2 and all(_number(a) for a in args) and args[0] < args[1]
            if not low_high or (dist == "loguniform" and args[0] <= 0) or (
                    dist == "randint" and not all(isinstance(a, int) for a in args)):
                what = {"uniform": "numbers", "loguniform": "positive numbers", "randint": "whole numbers"}[dist]
                raise fail("sample", f"{option}: {dist} needs [low, high], {what} with low < high, got {args!r}")
        for value in (args if dist == "choice" else [args[0], args[1] - 1 if dist == "randint" else args[1]]):
            check("sample", {option: value})
        sample[option] = (dist, tuple(args))
    for option in overrides:
        if option in grid:
            raise fail("grid", f"{option} is also in overrides")

    def whole(key: str, default: Optional[int], low: int = 1, optional: bool = False) -> Optional[int]:
        value = data.get(key, default)
        if value is None and optional:
            return None
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise fail(key, f"must be a whole number of at least {low}{' or null' if optional else ''}, got {value!r}")
        return value

    samples = whole("samples", 1)
    if samples > 1 and not sample:
        raise fail("samples", "more than 1 needs distributions to draw from (sample: ...)")
    reports = whole("reports", 4)
    max_concurrent = whole("max_concurrent", None, optional=True)

    seeds = data.get("seeds", [0])
    if (not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds)
            or len(set(seeds)) != len(seeds)):
        raise fail("seeds", f"must be a non-empty list of different whole numbers, got {seeds!r}")

    budget = data.get("budget")
    if not isinstance(budget, dict) or len(budget) != 1 or next(iter(budget)) not in BUDGETS:
        raise fail("budget", f"must be one of {', '.join(f'{{{b}: N}}' for b in BUDGETS)} (each trial's), "
                             f"got {budget!r}")
    limit, amount = next(iter(budget.items()))
    if not _number(amount) or amount <= 0 or (limit != "time_limit" and not float(amount).is_integer()):
        raise fail("budget", f"{limit} must be a positive {'number' if limit == 'time_limit' else 'whole number'}, "
                             f"got {amount!r}")
    if limit != "time_limit" and amount < reports:
        raise fail("reports", f"{reports} reports need a budget of at least {reports} {limit}, got {amount}")

    metric = data.get("metric", "success")
    if metric not in METRICS:
        raise fail("metric", f"must be one of {', '.join(METRICS)} (of the validation set), got {metric!r}")

    asha = data.get("asha", {})
    if asha is False or asha is None:
        asha = None
    elif isinstance(asha, dict):
        unknown = sorted(set(map(str, asha)) - {"grace_period", "reduction_factor"})
        if unknown:
            raise fail("asha", f"unknown key {unknown[0]!r} (allowed: grace_period, reduction_factor)")
        grace = asha.get("grace_period", 1)
        factor = asha.get("reduction_factor", 2)
        if not isinstance(grace, int) or isinstance(grace, bool) or not 1 <= grace <= reports:
            raise fail("asha", f"grace_period must be a whole number from 1 to reports ({reports}), got {grace!r}")
        if not _number(factor) or factor <= 1:
            raise fail("asha", f"reduction_factor must be a number above 1, got {factor!r}")
        asha = {"grace_period": grace, "reduction_factor": factor}
    else:
        raise fail("asha", f"must be a mapping (grace_period, reduction_factor) or false, got {asha!r}")

    cpus = data.get("trial_cpus", 1)
    if not _number(cpus) or cpus <= 0:
        raise fail("trial_cpus", f"must be a positive number, got {cpus!r}")

    sweep = Sweep(source, located if kind == "world" else None, located if kind == "curriculum" else None, name,
                  overrides, grid, sample, samples, tuple(seeds), (limit, float(amount) if limit == "time_limit"
                                                                   else int(amount)),
                  reports, metric, asha, float(cpus), max_concurrent)
    # every combination of the grid, with the distributions' first values, as a whole configuration
    first = {k: args[0] for k, (_, args) in sample.items()}
    for combo in itertools.islice(itertools.product(*grid.values()), 1000):
        params = {**dict(zip(grid, combo)), **first}
        try:
            sweep.config(params, 1)
        except UserError as exc:
            shown = ", ".join(f"{k}: {v!r}" for k, v in params.items())
            raise UserError(f"{source}: {'grid ' + shown + ': ' if shown else ''}{exc}") from None
    return sweep


def build_phases(sweep: Sweep, target: Any, config: TrainConfig) -> list:
    """The trainer's phases of a trial: of the sweep's world, or through its curriculum."""
    return phases_for_world(target, config) if sweep.world is not None else phases_for_curriculum(target, config)


def check_phases(sweep: Sweep, target: Any, most: int = 12) -> None:
    """Build the phases of the first ``most`` grid combinations, on a small scale, before any trial starts.

    What the trainer would refuse for the world or curriculum (a curriculum preset on a world,
    starts that need a single world ...) is found here, in one line naming the file, rather
    than in every trial. The validation set is cut to one world (or the world to one start)
    so that this takes moments.

    Raises:
        UserError: The phases cannot be built for a combination.
    """
    small = target
    if sweep.world is not None and len(target.starts):
        small = dataclasses.replace(target, starts=target.starts[:1], _cache={})
    first = {k: args[0] for k, (_, args) in sweep.sample.items()}
    for combo in itertools.islice(itertools.product(*sweep.grid.values()), most):
        params = {**dict(zip(sweep.grid, combo)), **first}
        config = dataclasses.replace(sweep.config(params, 1), validation_worlds=1, validation_starts=1,
                                     eval_random_starts=0)
        try:
            build_phases(sweep, small, config)
        except UserError as exc:
            shown = ", ".join(f"{k}: {v!r}" for k, v in params.items())
            raise UserError(f"{sweep.source}: {'grid ' + shown + ': ' if shown else ''}{exc}") from None


def trial_name(trial: Any) -> str:
    """A trial's name and folder: its Tune id (``results.csv`` and ``ended.json`` name trials by it)."""
    return trial.trial_id


def trial_folder() -> Path:
    """The trainer's output folder of the running trial, inside Tune's trial folder."""
    from ray import tune
    return Path(tune.get_context().get_trial_dir()) / "run"


def run_trial(params: dict, sweep: Sweep, target: Any) -> None:
    """One trial (run by Tune on a worker): the trainer in :attr:`Sweep.reports` legs, each reported.

    Args:
        params: The trial's values (Tune's config): grid and sampled fields, ``seed``, maybe ``preset``.
        sweep: The sweep.
        target: What to train on: a world, or a curriculum's stages.
    """
    from ray import tune
    out = trial_folder()
    if out.exists():   # what an interrupted attempt left: the checkpoint is what counts
        shutil.rmtree(out)
    done = 0
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        with checkpoint.as_directory() as folder:
            shutil.copytree(folder, out)
        done = json.loads((out / PROGRESS).read_text())["legs"]
    phases = None
    for leg in range(done + 1, sweep.reports + 1):
        config = sweep.config(params, leg)
        if phases is None:
            phases = build_phases(sweep, target, config)
        result = train(config, phases, out_dir=out, resume=(out / "last.pt").is_file())
        reason = result.stop_reason or ""
        finished = leg == sweep.reports or not reason.startswith(sweep.budget[0])
        (out / PROGRESS).write_text(json.dumps({"legs": leg, "finished": finished}))
        best, latest = result.best or {}, result.latest or {}
        metrics = {name: best[name] for name in FIGURES if best.get(name) is not None}
        metrics.update({f"latest_{name}": latest[name] for name in FIGURES if latest.get(name) is not None})
        metrics.setdefault(sweep.metric, 0.0)
        metrics.update(global_step=result.global_step, episodes=result.episodes, train_seconds=result.wall_time,
                       best_step=result.counters.best_step or 0, legs=leg, finished=finished, stop_reason=reason)
        tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(str(out)))
        if finished:
            break


@dataclass
class TrialRow:
    """One trial in the results."""

    trial: str
    values: dict
    status: str
    metrics: dict
    checkpoint: Any = None
    error: str = ""


@dataclass
class SweepResult:
    """What a sweep did.

    Attributes:
        rows: A row per trial, best first (by the metric; errors last).
        best: The best trial's row (None: no trial reported).
        out: The output folder.
        interrupted: The sweep was interrupted (continue it with ``resume``).
        written: Files written in ``out``.
    """

    rows: list[TrialRow]
    best: Optional[TrialRow]
    out: Path
    interrupted: bool
    written: list[Path] = field(default_factory=list)


def read_ended(path: Path) -> set[str]:
    """The trial ids in ``ENDED`` (none if there is no such file yet)."""
    return set(json.loads(path.read_text())) if path.is_file() else set()


def ended_callback(path: Path) -> Any:
    """A Tune callback noting in ``path`` every trial that ends: finished, stopped by ASHA, or failed.

    Tune keeps the callback with the experiment (a restored sweep runs a copy of it), so it
    holds nothing but the path and reads the file before adding to it.
    """
    from ray import tune

    class Ended(tune.Callback):
        def _note(self, trial: Any) -> None:
            ids = read_ended(path) | {trial.trial_id}
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text(json.dumps(sorted(ids)))
            tmp.replace(path)

        def on_trial_complete(self, iteration, trials, trial, **info):
            self._note(trial)

        def on_trial_error(self, iteration, trials, trial, **info):
            self._note(trial)

    return Ended()


def _error_line(error: BaseException) -> str:
    """The message of a trial's error: the project's own (a UserError inside Ray's wrappers), else its last line."""
    seen, chain = error, []
    while seen is not None and seen not in chain and len(chain) < 10:
        chain.append(seen)
        seen = getattr(seen, "cause", None) or seen.__cause__ or seen.__context__
    own = [e for e in chain if isinstance(e, UserError) and type(e).__module__.startswith("apf_physics")]
    if own:
        return str(own[-1]).splitlines()[0] if str(own[-1]) else type(own[-1]).__name__
    lines = [s.strip() for s in str(chain[-1]).strip().splitlines() if s.strip()]
    return lines[-1] if lines else type(chain[-1]).__name__


def run_sweep(sweep: Sweep, out: str | Path, resume: bool = False, address: Optional[str] = None,
              verbose: int = 1) -> SweepResult:
    """Run (or with ``resume``, continue) a sweep on Ray Tune, writing into ``out``.

    Args:
        sweep: The sweep (:func:`load_sweep`).
        out: The output folder: Tune's experiment in ``out/tune``, then ``results.csv``,
            ``best.pt``, ``best.json``. On a cluster, a folder every node sees (Tune's
            ``storage_path``).
        resume: Continue the interrupted sweep in ``out`` (``Tuner.restore``): unfinished and
            failed trials go on from their latest checkpoints.
        address: Where Ray is (:func:`~apf_physics.campaign.connect`).
        verbose: Tune's verbosity (0: silent, 1: a status table now and then, 2: more).

    Raises:
        UserError: Ray is missing or unreachable; ``out`` holds another sweep (or, with
            ``resume``, none, or one of another recipe).
    """
    out = Path(out).resolve()
    experiment = out / "tune"
    recipe = out / "sweep.json"
    import_ray()
    from ray import tune   # Tuner.can_restore reads the folder; Ray need not run yet
    exists = tune.Tuner.can_restore(str(experiment))
    if resume and not exists:
        raise UserError(f"{out}: no sweep to resume there")
    if not resume and (exists or recipe.exists()):
        raise UserError(f"{out} already holds a sweep; continue it with --resume, or write into another --out")
    current = json.loads(json.dumps(sweep.to_dict()))
    if resume and recipe.is_file():
        saved = json.loads(recipe.read_text())
        if saved != current:
            differ = sorted(k for k in {*saved, *current} if saved.get(k) != current.get(k))
            raise UserError(f"{out}: was started from another recipe (it differs in {', '.join(differ)}); "
                            f"resume it with the recipe it was started from")
    target = sweep.target()
    check_phases(sweep, target)
    with connect(address):
        from ray.tune.schedulers import ASHAScheduler, FIFOScheduler
        from ray.tune.search.basic_variant import BasicVariantGenerator

        if not resume:
            out.mkdir(parents=True, exist_ok=True)
            recipe.write_text(json.dumps(current, indent=1))
        trainable = tune.with_resources(tune.with_parameters(run_trial, sweep=sweep, target=target),
                                        {"cpu": sweep.trial_cpus})
        if resume:
            tuner = tune.Tuner.restore(str(experiment), trainable, resume_unfinished=True, resume_errored=True)
        else:
            scheduler = (FIFOScheduler() if sweep.asha is None else
                         ASHAScheduler(max_t=sweep.reports, **sweep.asha))
            tuner = tune.Tuner(
                trainable, param_space=sweep.param_space(),
                tune_config=tune.TuneConfig(metric=sweep.metric, mode="max", scheduler=scheduler,
                                            num_samples=sweep.samples, max_concurrent_trials=sweep.max_concurrent,
                                            search_alg=BasicVariantGenerator(random_state=SAMPLE_SEED),
                                            trial_dirname_creator=trial_name, trial_name_creator=trial_name),
                run_config=tune.RunConfig(name=experiment.name, storage_path=str(out), verbose=verbose,
                                          callbacks=[ended_callback(out / ENDED)],
                                          checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
                                          failure_config=tune.FailureConfig(max_failures=0)))
        # the checkpoint of every leg forces a snapshot of the experiment (num_to_keep): wanted, not a warning
        os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
        grid = tuner.fit()
        result = _gather(sweep, grid, out, read_ended(out / ENDED))
    return result


def _gather(sweep: Sweep, grid: Any, out: Path, ended: set) -> SweepResult:
    """The rows of a Tune ``ResultGrid``, the table and the best model written into ``out``."""
    ids = [Path(r.path).name for r in grid]   # trial folders are named by trial id (trial_dirname_creator)
    interrupted = any(i not in ended for i in ids)
    rows = []
    for trial_id, result in zip(ids, grid):
        metrics = dict(result.metrics or {})
        values = {k: result.config.get(k) for k in sweep.varied()} if result.config else {}
        if result.error is not None:
            status = "error"
        elif not metrics:
            status = "not started"
        elif metrics.get("finished"):
            status = "finished"
        elif trial_id not in ended:
            status = "interrupted"
        else:
            status = f"stopped by ASHA after {metrics.get('legs')} of {sweep.reports}"
        rows.append(TrialRow(str(trial_id), values, status,
                             metrics, result.checkpoint, "" if result.error is None else _error_line(result.error)))
    other = next(m for m in METRICS if m != sweep.metric)   # ties: the other figure, then the first trial
    rows.sort(key=lambda r: (sweep.metric not in r.metrics, -float(r.metrics.get(sweep.metric, 0.0)),
                             -float(r.metrics.get(other, 0.0)), r.trial))
    best = next((r for r in rows if sweep.metric in r.metrics and r.checkpoint is not None), None)
    written = [write_results(rows, sweep, out / "results.csv")]
    if best is not None and not interrupted:
        with best.checkpoint.as_directory() as folder:
            if (Path(folder) / "best.pt").is_file():
                shutil.copyfile(Path(folder) / "best.pt", out / ".best.pt.tmp")
                (out / ".best.pt.tmp").replace(out / "best.pt")
                written.append(out / "best.pt")
        config = sweep.config(best.values, sweep.reports)
        (out / "best.json").write_text(json.dumps(
            {"trial": best.trial, "values": best.values, "figures": {k: best.metrics.get(k) for k in FIGURES},
             "metric": sweep.metric, "global_step": best.metrics.get("global_step"),
             "config": config.to_dict()}, indent=1, default=str))
        written.append(out / "best.json")
    return SweepResult(rows, best, out, interrupted, written)


def write_results(rows: Sequence[TrialRow], sweep: Sweep, path: Path) -> Path:
    """``results.csv``: a row per trial (its values, status, steps and figures)."""
    columns = ["trial", *sweep.varied(), "status", "legs", "global_step", "train_seconds", *FIGURES, "error"]
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        for r in rows:
            writer.writerow({"trial": r.trial, **r.values, "status": r.status, "error": r.error,
                             **{k: r.metrics.get(k, "") for k in ("legs", "global_step", *FIGURES)},
                             "train_seconds": round(r.metrics["train_seconds"], 1) if "train_seconds" in r.metrics
                             else ""})
    tmp.replace(path)
    return path


def _show(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_show(v) for v in value) + "]"
    return str(value)


def format_results(result: SweepResult, sweep: Sweep) -> str:
    """The trials, best first, and with several seeds the mean of each combination over its seeds."""
    keys = sweep.varied()
    table = [["trial", *keys, "status", "steps", "success", "spl", "collisions"]]
    for r in result.rows:
        m = r.metrics
        table.append([r.trial, *(_show(r.values.get(k, "")) for k in keys), r.status + (f": {r.error}" if r.error else ""),
                      str(m.get("global_step", "-")), *(_show(m[k]) if k in m else "-"
                                                        for k in ("success", "spl", "collisions"))])
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in table]
    lines.insert(1, "-" * len(lines[0]))
    if len(sweep.seeds) > 1:
        groups: dict[tuple, list[float]] = {}
        for r in result.rows:
            if sweep.metric in r.metrics:
                key = tuple(_show(r.values.get(k, "")) for k in keys[:-1])
                groups.setdefault(key, []).append(float(r.metrics[sweep.metric]))
        lines.append("")
        lines.append(f"mean {sweep.metric} over seeds (trials stopped early count with their last figure):")
        for key, values in sorted(groups.items(), key=lambda kv: -sum(kv[1]) / len(kv[1])):
            shown = ", ".join(f"{k}={v}" for k, v in zip(keys[:-1], key)) or "(one recipe)"
            lines.append(f"  {shown}: {sum(values) / len(values):.4f} over {len(values)} seed(s)")
    return "\n".join(lines)
