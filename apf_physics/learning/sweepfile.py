"""Sweep files: what a training sweep tries, read and checked before any trial runs.

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

Every value is checked as the trainer would take it (:func:`load_sweep`), so a mistake is
found here, in one line naming the file and the key, not minutes later in a trial. The
Tune runner is :mod:`apf_physics.learning.sweep`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from apf_physics.world.bundled import resolve_world
from apf_physics.learning.curriculum import load_curriculum
from apf_physics.errors import UserError, did_you_mean
from apf_physics.learning.config import CURRICULUM_DEFAULT, PRESETS, WORLD_DEFAULT, TrainConfig, preset
from apf_physics.world.io.worldfile import load_world, read_yaml_file

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


class _Reader:
    """A sweep file's mapping, read key by key; every problem one :class:`UserError` naming the file and key."""

    def __init__(self, path: Path, data: dict):
        self.path, self.source, self.data = path, str(path), data

    def fail(self, key: str, problem: str) -> UserError:
        return UserError(f"{self.source}: {key}: {problem}")

    def target(self) -> tuple[str, str]:
        """``("world" or "curriculum", the file's resolved path)``."""
        data = self.data
        where = [k for k in ("world", "curriculum") if data.get(k) is not None]
        if len(where) != 1:
            raise UserError(f"{self.source}: name exactly one of world or curriculum (what the trials train on)")
        kind = where[0]
        if not isinstance(data[kind], str) or not data[kind].strip():
            raise self.fail(kind, f"must be a file name, got {data[kind]!r}")
        beside = self.path.parent / data[kind]
        try:
            return kind, str((beside if beside.exists() else resolve_world(data[kind])).resolve())
        except UserError as exc:
            raise self.fail(kind, str(exc)) from None

    def preset_name(self, kind: str) -> str:
        name = self.data.get("preset", WORLD_DEFAULT if kind == "world" else CURRICULUM_DEFAULT)
        if not isinstance(name, str) or name not in PRESETS:
            raise self.fail("preset", f"unknown preset {name!r}{did_you_mean(str(name), PRESETS)}; "
                                      f"choose one of {', '.join(PRESETS)}")
        return name

    def mapping(self, key: str) -> dict:
        value = self.data.get(key) or {}
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a mapping, got {type(value).__name__}")
        return {str(k): v for k, v in value.items()}

    def check(self, key: str, values: dict, base: str) -> None:
        """Each value as a training option of preset ``base``, one at a time (the error names the option)."""
        for option, value in values.items():
            if option in SET_BY_SWEEP and not (key == "grid" and option == "preset"):
                hint = {"seed": "seeds", "preset": "preset (or grid: {preset: [...]})"}.get(option, "budget")
                raise self.fail(key, f"{option} is set by the sweep's {hint}, not here")
            try:
                preset(base, **{option: value})
            except UserError as exc:
                raise self.fail(key, str(exc)) from None

    def grid(self, base: str) -> dict:
        grid = self.mapping("grid")
        for option, values in grid.items():
            if not isinstance(values, list) or not values:
                raise self.fail("grid", f"{option}: must be a non-empty list of values to try, got {values!r}")
            if option == "preset":
                for p in values:
                    if not isinstance(p, str) or p not in PRESETS:
                        raise self.fail("grid", f"preset: unknown preset {p!r}{did_you_mean(str(p), PRESETS)}; "
                                                f"choose among {', '.join(PRESETS)}")
            else:
                for value in values:
                    self.check("grid", {option: value}, base)
        return grid

    def sample(self, base: str, grid: dict, overrides: dict) -> dict[str, tuple[str, tuple]]:
        sample: dict[str, tuple[str, tuple]] = {}
        for option, spec in self.mapping("sample").items():
            if option in grid or option in overrides:
                raise self.fail("sample", f"{option} is also in {'grid' if option in grid else 'overrides'}")
            if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
                raise self.fail("sample", f"{option}: must be one of "
                                          f"{', '.join(f'{{{d}: [...]}}' for d in DISTRIBUTIONS)}, got {spec!r}")
            dist, args = next(iter(spec.items()))
            if not isinstance(args, list) or not args:
                raise self.fail("sample", f"{option}: {dist} needs a list, got {args!r}")
            if dist != "choice":
                low_high = len(args) == 2 and all(_number(a) for a in args) and args[0] < args[1]
                if not low_high or (dist == "loguniform" and args[0] <= 0) or (
                        dist == "randint" and not all(isinstance(a, int) for a in args)):
                    what = {"uniform": "numbers", "loguniform": "positive numbers", "randint": "whole numbers"}[dist]
                    raise self.fail("sample", f"{option}: {dist} needs [low, high], {what} with low < high, "
                                              f"got {args!r}")
            for value in (args if dist == "choice" else [args[0], args[1] - 1 if dist == "randint" else args[1]]):
                self.check("sample", {option: value}, base)
            sample[option] = (dist, tuple(args))
        return sample

    def whole(self, key: str, default: Optional[int], low: int = 1, optional: bool = False) -> Optional[int]:
        value = self.data.get(key, default)
        if value is None and optional:
            return None
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise self.fail(key, f"must be a whole number of at least {low}{' or null' if optional else ''}, "
                                 f"got {value!r}")
        return value

    def seeds(self) -> tuple[int, ...]:
        seeds = self.data.get("seeds", [0])
        if (not isinstance(seeds, list) or not seeds or len(set(seeds)) != len(seeds)
                or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds)):
            raise self.fail("seeds", f"must be a non-empty list of different whole numbers, got {seeds!r}")
        return tuple(seeds)

    def budget(self, reports: int) -> tuple[str, float | int]:
        budget = self.data.get("budget")
        if not isinstance(budget, dict) or len(budget) != 1 or next(iter(budget)) not in BUDGETS:
            raise self.fail("budget", f"must be one of {', '.join(f'{{{b}: N}}' for b in BUDGETS)} (each trial's), "
                                      f"got {budget!r}")
        limit, amount = next(iter(budget.items()))
        if not _number(amount) or amount <= 0 or (limit != "time_limit" and not float(amount).is_integer()):
            raise self.fail("budget", f"{limit} must be a positive "
                                      f"{'number' if limit == 'time_limit' else 'whole number'}, got {amount!r}")
        if limit != "time_limit" and amount < reports:
            raise self.fail("reports", f"{reports} reports need a budget of at least {reports} {limit}, got {amount}")
        return limit, float(amount) if limit == "time_limit" else int(amount)

    def metric(self) -> str:
        metric = self.data.get("metric", "success")
        if metric not in METRICS:
            raise self.fail("metric", f"must be one of {', '.join(METRICS)} (of the validation set), got {metric!r}")
        return metric

    def asha(self, reports: int) -> dict | None:
        asha = self.data.get("asha", {})
        if asha is False or asha is None:
            return None
        if not isinstance(asha, dict):
            raise self.fail("asha", f"must be a mapping (grace_period, reduction_factor) or false, got {asha!r}")
        unknown = sorted(set(map(str, asha)) - {"grace_period", "reduction_factor"})
        if unknown:
            raise self.fail("asha", f"unknown key {unknown[0]!r} (allowed: grace_period, reduction_factor)")
        grace = asha.get("grace_period", 1)
        factor = asha.get("reduction_factor", 2)
        if not isinstance(grace, int) or isinstance(grace, bool) or not 1 <= grace <= reports:
            raise self.fail("asha", f"grace_period must be a whole number from 1 to reports ({reports}), got {grace!r}")
        if not _number(factor) or factor <= 1:
            raise self.fail("asha", f"reduction_factor must be a number above 1, got {factor!r}")
        return {"grace_period": grace, "reduction_factor": factor}

    def cpus(self) -> float:
        cpus = self.data.get("trial_cpus", 1)
        if not _number(cpus) or cpus <= 0:
            raise self.fail("trial_cpus", f"must be a positive number, got {cpus!r}")
        return float(cpus)


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
    data: Any = read_yaml_file(path, "sweep")
    if not isinstance(data, dict):
        raise UserError(f"{source}: a sweep file must be a mapping (world or curriculum, preset, grid, budget, "
                        f"metric ...), got {type(data).__name__}")
    read = _Reader(path, data)
    for key in data:
        if key not in KEYS:
            raise read.fail(str(key), f"unknown key{did_you_mean(str(key), KEYS)}; the keys are {', '.join(KEYS)}")
    kind, located = read.target()
    name = read.preset_name(kind)
    overrides = read.mapping("overrides")
    read.check("overrides", overrides, name)
    grid = read.grid(name)
    sample = read.sample(name, grid, overrides)
    for option in overrides:
        if option in grid:
            raise read.fail("grid", f"{option} is also in overrides")
    samples = read.whole("samples", 1)
    if samples > 1 and not sample:
        raise read.fail("samples", "more than 1 needs distributions to draw from (sample: ...)")
    reports = read.whole("reports", 4)
    max_concurrent = read.whole("max_concurrent", None, optional=True)
    sweep = Sweep(source, located if kind == "world" else None, located if kind == "curriculum" else None, name,
                  overrides, grid, sample, samples, read.seeds(), read.budget(reports), reports, read.metric(),
                  read.asha(reports), read.cpus(), max_concurrent)
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
