"""Evaluation campaigns on Ray: worlds × planners fanned out as Ray tasks, gathered as a local run's.

``apf-physics eval WORLD... --planner P,Q --ray [ADDRESS]`` runs :func:`evaluate_on_ray`
instead of one :func:`~apf_physics.evaluate.evaluate` per planner. Every planner's worlds
are dealt into batches (:func:`batches`), each one Ray task that builds its planner and runs
:func:`~apf_physics.evaluate.evaluate` on its worlds one by one; the episodes are put back
together in the worlds' order, so the result is the local run's, episode for episode
(every world's rollout starts from :meth:`~apf_physics.planners.base.Planner.reset` and its
starts are fixed before the fan-out: nothing depends on which worlds share a task).

The worlds are dealt into about :data:`TASKS_PER_CPU` tasks per CPU of the cluster, but at least
:data:`MIN_EPISODES_PER_TASK` episodes, so that a task lasts seconds rather than milliseconds
(start-up, shipping the worlds, and the worker building each world's field raster again are
paid per task).

Ray is found as Ray finds it (:func:`connect`): with no address, ``RAY_ADDRESS`` if it is set,
else a Ray started on this machine for the run (its cores); ``auto`` the Ray started here
with ``ray start --head``; ``HOST:PORT`` or ``ray://HOST:10001`` a cluster. Every node needs
the same ``apf-physics[ray]`` installed. Ray is imported only when it is used.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional, Sequence

import numpy as np

from apf_physics.errors import UserError
from apf_physics.evaluate import Evaluation, evaluate
from apf_physics.planners import LEARNED, make_planner
from apf_physics.rollout import Episode
from apf_physics.world import World

TASKS_PER_CPU = 4
"""Tasks per CPU of the cluster the worlds are cut into (over all planners): enough for the
CPUs to stay busy while the last tasks finish."""
MIN_EPISODES_PER_TASK = 50
"""Fewest episodes in a task (about a second of a planner's work), unless there are fewer in all."""
INSTALL_HINT = "pip install 'apf-physics[ray]'"


@dataclass(frozen=True)
class TaskTiming:
    """What one Ray task of :func:`evaluate_on_ray` did, for benchmarks and capacity planning.

    Attributes:
        planner: The planner's command-line name.
        worlds: Worlds in the task.
        episodes: Episodes it ran.
        seconds: Wall time of its evaluation on the worker (without queueing and shipping).
        cpu_seconds: CPU time of the worker process over the same span (what the task costs on
            a core of its own, whatever else the machine was doing).
        node: The Ray node it ran on.
        pid: The worker process.
    """

    planner: str
    worlds: int
    episodes: int
    seconds: float
    cpu_seconds: float
    node: str
    pid: int


def import_ray():
    """The ``ray`` module, or a clear error saying how to install it."""
    try:
        import ray
    except ImportError:
        raise UserError(f"Ray is not installed; install it with: {INSTALL_HINT}") from None
    return ray


def joins_cluster(address: Optional[str]) -> bool:
    """Whether :func:`connect` joins a running Ray (an address, or ``RAY_ADDRESS``) rather than starting one."""
    return bool(address) or bool(os.environ.get("RAY_ADDRESS"))


@contextlib.contextmanager
def connect(address: Optional[str] = None, num_cpus: Optional[int] = None) -> Iterator[object]:
    """Ray for the length of a ``with`` block: joined or started here, and shut down after if started here.

    A Ray already initialised in this process (a test's, a notebook's) is used as it is and
    left running. The workers' own output is not echoed here (their errors come back with
    their results).

    Args:
        address: None or ``""``: ``RAY_ADDRESS`` if set, else a new local Ray
            (``ray.init()``'s rule); ``"auto"``: the Ray started on this machine with
            ``ray start --head``; ``"HOST:PORT"`` / ``"ray://HOST:10001"``: that cluster.
        num_cpus: CPUs of a local Ray started here (default: all of this machine's).

    Yields:
        The ``ray`` module.

    Raises:
        UserError: Ray is not installed, or the cluster cannot be reached.
    """
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    options: dict = {"address": address or None, "logging_level": logging.WARNING, "log_to_driver": False}
    if not joins_cluster(address):   # only a Ray started here takes these
        options.update(include_dashboard=False, num_cpus=num_cpus)
    try:
        ray.init(**options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = address or os.environ.get("RAY_ADDRESS") or "a local Ray"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UserError(f"cannot start or reach Ray ({where}): {first}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def batches(count: int, tasks: int) -> list[list[int]]:
    """Deal ``count`` items into at most ``tasks`` batches, as cards are dealt: item ``i`` to batch ``i % tasks``.

    Dealt rather than cut: neighbouring worlds tend to be alike (a generated set is sorted by
    family, and one family can cost a planner ten times another), so each batch gets its share
    of every kind and the batches take about as long.

    Returns:
        Lists of item indices, each ascending, together covering every item once; none empty.
    """
    tasks = max(1, min(int(tasks), count))
    return [list(range(j, count, tasks)) for j in range(tasks)] if count else []


def episodes_per_world(worlds: Sequence[World], starts: Optional[dict[str, np.ndarray]], formation: bool) -> list[int]:
    """How many episodes each world will give (its starts, or its formations with ``formation``)."""
    out = []
    for w in worlds:
        if formation and w.formations:
            out.append(len(w.formations))
        else:
            out.append(len(w.starts if starts is None else starts[w.name]))
    return out


def tasks_per_planner(episodes: int, planners: int, cpus: int, worlds_per_task: Optional[int] = None,
                      worlds: int = 0) -> int:
    """How many tasks each planner's worlds are cut into (see the module's notes).

    Args:
        episodes: Episodes of one planner over all worlds.
        planners: Planners run.
        cpus: CPUs of the cluster.
        worlds_per_task: A batch size asked for (worlds per task) instead of the rule.
        worlds: Worlds in all (with ``worlds_per_task``).
    """
    if worlds_per_task is not None:
        return max(1, math.ceil(worlds / max(1, worlds_per_task)))
    spread = math.ceil(TASKS_PER_CPU * max(1, cpus) / max(1, planners))
    return max(1, min(spread, episodes // MIN_EPISODES_PER_TASK))


def _model_copy(data: bytes, name: str) -> Path:
    """A private copy of a shipped model file on this node (written once, atomically), named by its hash."""
    folder = Path(tempfile.gettempdir()) / "apf-physics-models" / hashlib.sha256(data).hexdigest()[:16]
    path = folder / name
    if not path.is_file() or path.stat().st_size != len(data):
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    return path


def evaluate_batch(planner: str, worlds: Sequence[World], starts: Optional[dict[str, np.ndarray]],
                   max_steps: Optional[int], formation: bool, model: Optional[str] = None,
                   model_bytes: Optional[bytes] = None) -> tuple[str, list[list[Episode]]]:
    """One task: :func:`~apf_physics.evaluate.evaluate` of a planner on some worlds (run on a Ray worker).

    Args:
        planner: The planner's command-line name.
        worlds: The task's worlds.
        starts: Their starts by world name (None: the worlds' own).
        max_steps: Step limit per episode.
        formation: Run the worlds' formations.
        model: The model file as the user named it, for a learned planner.
        model_bytes: Its contents, shipped to the worker (a cluster's nodes need not share files);
            None: ``model`` is opened where the task runs.

    Returns:
        The evaluation's planner label, and each world's episodes.
    """
    local = None
    if model_bytes is not None:
        local = _model_copy(model_bytes, Path(model).name)
    try:
        made = make_planner(planner, model=model if local is None else str(local))
        label, episodes = "", []
        for world in worlds:   # one planner through the worlds in turn, as evaluate() runs it
            ev = evaluate(made, [world], starts, max_steps=max_steps, formation=formation)
            label = ev.planner
            episodes.append(ev.episodes)
        return label, episodes
    except UserError as exc:   # name the user's file, not the worker's copy
        if local is None:
            raise
        raise type(exc)(str(exc).replace(str(local), str(model))) from None


def _timed_batch(*args) -> tuple[tuple[str, list[list[Episode]]], float, float, str, int]:
    """:func:`evaluate_batch` with its wall and CPU time, node and process (run on a Ray worker)."""
    import ray
    start, cpu = time.perf_counter(), time.process_time()
    result = evaluate_batch(*args)
    return (result, time.perf_counter() - start, time.process_time() - cpu,
            ray.get_runtime_context().get_node_id(), os.getpid())


def evaluate_on_ray(planners: Sequence[str], worlds: Sequence[World], starts: Optional[dict[str, np.ndarray]] = None,
                    model: Optional[str] = None, max_steps: Optional[int] = None, formation: bool = False,
                    address: Optional[str] = None, worlds_per_task: Optional[int] = None,
                    num_cpus: Optional[int] = None, timings: Optional[list[TaskTiming]] = None) -> list[Evaluation]:
    """Evaluate several planners over worlds as Ray tasks: the same evaluations as a local run.

    Args:
        planners: Planner command-line names (:data:`~apf_physics.planners.PLANNERS`).
        worlds: The worlds.
        starts: Starts per world name, instead of the worlds' own.
        model: Model file of the learned planners (default: the shipped model for the world's field).
        max_steps: Step limit per episode.
        formation: Run each world's formation.
        address: Where Ray is (:func:`connect`).
        worlds_per_task: Worlds per task (default: :func:`tasks_per_planner`'s rule).
        num_cpus: CPUs of a local Ray started for the run (default: all).
        timings: A list to append a :class:`TaskTiming` per task to, in submission order.

    Returns:
        One :class:`~apf_physics.evaluate.Evaluation` per planner, in order, as
        ``[evaluate(make_planner(p, model), worlds, starts, ...) for p in planners]`` gives.

    Raises:
        UserError: An unknown planner, an unusable model file, Ray missing or unreachable, or
            a task's own error (a world's, a model's), as the local run would raise it.
    """
    names = list(planners)
    for name in names:
        make_planner(name, model=model)   # an unknown name is refused before Ray starts
    model_bytes = None
    if model is not None and any(n in LEARNED for n in names):
        try:   # shipped to the workers; one that cannot be read is left to them, to refuse as a local run does
            model_bytes = Path(model).read_bytes()
        except OSError:
            pass
    if worlds_per_task is not None and worlds_per_task < 1:
        raise UserError(f"worlds per Ray task must be at least 1, got {worlds_per_task}")
    sizes = episodes_per_world(worlds, starts, formation)
    with connect(address, num_cpus=num_cpus) as ray:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        parts = batches(len(worlds), tasks_per_planner(sum(sizes), len(names), cpus, worlds_per_task, len(worlds)))
        task = ray.remote(num_cpus=1)(_timed_batch)
        shipped = ray.put(model_bytes) if model_bytes is not None else None
        shared = []   # each batch's worlds and starts go to the object store once, for every planner
        for part in parts:
            chosen = [worlds[i] for i in part]
            shared.append((ray.put(chosen), ray.put(None if starts is None else {w.name: starts[w.name] for w in chosen})))
        futures, submitted = [], []
        for name in names:
            for part, (chosen, mine) in zip(parts, shared):
                submitted.append((name, len(part), sum(sizes[i] for i in part)))
                futures.append(task.remote(name, chosen, mine, max_steps, formation,
                                           model if name in LEARNED else None,
                                           shipped if name in LEARNED else None))
        try:
            results = ray.get(futures)
        except ray.exceptions.RayTaskError as exc:
            cause = getattr(exc, "cause", None)
            if isinstance(cause, UserError):
                raise type(cause)(str(cause)) from None
            raise
    if timings is not None:
        timings.extend(TaskTiming(name, n, eps, *measured[1:])
                       for (name, n, eps), measured in zip(submitted, results))
    results = [r[0] for r in results]
    out = []
    for k, name in enumerate(names):
        per_world: list[list[Episode]] = [[] for _ in worlds]
        label = make_planner(name, model=model).name + ("+formation" if formation else "")
        for part, (label, episodes) in zip(parts, results[k * len(parts):(k + 1) * len(parts)]):
            for i, eps in zip(part, episodes):
                per_world[i] = eps
        out.append(Evaluation(label, [e for eps in per_world for e in eps]))
    return out
