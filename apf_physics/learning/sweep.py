"""Training sweeps on Ray Tune: one trainer run per trial, ASHA, the best model copied out.

The sweep file is read by :mod:`apf_physics.learning.sweepfile`.

A trial is :func:`~apf_physics.learning.trainer.train` run in ``reports`` legs, each to a further
share of the budget, the next resuming the last from its ``last.pt`` (the budget fields are
:data:`~apf_physics.learning.config.RESUMABLE`). Each leg ends with an evaluation; the trial
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
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from apf_physics.experiments.campaign import connect, import_ray
from apf_physics.errors import UserError
from apf_physics.learning.config import TrainConfig, replace
from apf_physics.learning.phases import phases_for_curriculum, phases_for_world
from apf_physics.learning.sweepfile import BUDGETS, METRICS, Sweep, load_sweep
from apf_physics.learning.trainer import train
from apf_physics.common.safefile import atomic_path, write_text

__all__ = ["BUDGETS", "METRICS", "Sweep", "SweepResult", "TrialRow", "format_results", "load_sweep", "run_sweep"]

FIGURES = ("success", "spl", "trap_success", "collisions", "length_ratio", "world_starts_success")
"""Figures of an evaluation reported per leg (those present): on the validation starts, and a world's own."""
ENDED = "ended.json"
"""In the output folder: the trials Tune saw end (finished, stopped by ASHA, failed), over every session.
An interrupted trial never ends; Tune marks it terminated all the same, so this is how it is told apart."""
PROGRESS = "sweep-progress.json"
"""In a trial's folder: the legs done, so a restored trial knows where it stands."""
SAMPLE_SEED = 0
"""Seed of Tune's draws from the distributions: the same file gives the same trials."""


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
        small = dataclasses.replace(target, starts=target.starts[:1])
    first = {k: args[0] for k, (_, args) in sweep.sample.items()}
    for combo in itertools.islice(itertools.product(*sweep.grid.values()), most):
        params = {**dict(zip(sweep.grid, combo)), **first}
        config = replace(sweep.config(params, 1), validation_worlds=1, validation_starts=1, eval_random_starts=0)
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
        write_text(out / PROGRESS, json.dumps({"legs": leg, "finished": finished}))
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
            write_text(path, json.dumps(sorted(read_ended(path) | {trial.trial_id})))

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
        address: Where Ray is (:func:`~apf_physics.experiments.campaign.connect`).
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
            write_text(recipe, json.dumps(current, indent=1))
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
                with atomic_path(out / "best.pt") as tmp:
                    shutil.copyfile(Path(folder) / "best.pt", tmp)
                written.append(out / "best.pt")
        config = sweep.config(best.values, sweep.reports)
        write_text(out / "best.json", json.dumps(
            {"trial": best.trial, "values": best.values, "figures": {k: best.metrics.get(k) for k in FIGURES},
             "metric": sweep.metric, "global_step": best.metrics.get("global_step"),
             "config": config.to_dict()}, indent=1, default=str))
        written.append(out / "best.json")
    return SweepResult(rows, best, out, interrupted, written)


def write_results(rows: Sequence[TrialRow], sweep: Sweep, path: Path) -> Path:
    """``results.csv``: a row per trial (its values, status, steps and figures)."""
    columns = ["trial", *sweep.varied(), "status", "legs", "global_step", "train_seconds", *FIGURES, "error"]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        for r in rows:
            writer.writerow({"trial": r.trial, **r.values, "status": r.status, "error": r.error,
                             **{k: r.metrics.get(k, "") for k in ("legs", "global_step", *FIGURES)},
                             "train_seconds": round(r.metrics["train_seconds"], 1) if "train_seconds" in r.metrics
                             else ""})
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
