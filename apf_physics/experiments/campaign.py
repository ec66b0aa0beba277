"""Evaluation campaigns on Ray: worlds × planners fanned out as Ray tasks, gathered as a local run's.

``apf-physics eval WORLD... --planner P,Q --ray [ADDRESS]`` runs :func:`evaluate_on_ray`
instead of one :func:`~apf_physics.experiments.evaluate.evaluate` per planner. The worlds are dealt into
batches (:func:`batches`), each one Ray task that runs every planner on its worlds, world by
world, as :func:`~apf_physics.experiments.evaluate.evaluate` does; the episodes are put back together per
planner in the worlds' order, so the result is the local run's, episode for episode (every
world's rollout starts from :meth:`~apf_physics.planners.base.Planner.reset`, and random
starts are drawn before the fan-out: nothing depends on which worlds share a task).

A task runs all the planners so that a world's field raster and clearance tables, built on
the worker from the world file's data, serve every planner as they do in a local run. There
are about :data:`TASKS_PER_CPU` tasks per CPU of the cluster, but none under
:data:`MIN_EPISODES_PER_TASK` episodes (over its planners), so that a task lasts a second or
more rather than milliseconds (scheduling, shipping the worlds and building their tables are
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
from apf_physics.experiments.evaluate import Evaluation, evaluate
from apf_physics.planners import LEARNED, make_planner
from apf_physics.experiments.rollout import Episode
from apf_physics.common.safefile import write_bytes
from apf_physics.world.core import World

TASKS_PER_CPU = 4
"""Tasks per CPU of the cluster the worlds are dealt into: enough for the CPUs to stay busy
while the last tasks finish."""
MIN_EPISODES_PER_TASK = 50
"""Fewest episodes in a task, over its planners (about a second of work), unless there are fewer in all."""
INSTALL_HINT = "pip install 'apf-physics[ray]'"


@dataclass(frozen=True)
class TaskTiming:
    """What one Ray task of :func:`evaluate_on_ray` did, for benchmarks and capacity planning.

    Attributes:
        worlds: Indices of its worlds.
        episodes: Episodes it ran (over all planners).
        seconds: Wall time of its evaluations on the worker (without queueing and shipping).
        cpu_seconds: CPU time of the worker process over the same span (what the task costs on
            a core of its own, whatever else the machine was doing).
        planner_cpu: CPU seconds per planner.
        node: The Ray node it ran on.
        pid: The worker process.
    """

    worlds: tuple[int, ...]
    episodes: int
    seconds: float
    cpu_seconds: float
    planner_cpu: dict
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


def task_count(episodes: int, cpus: int, worlds_per_task: Optional[int] = None, worlds: int = 0) -> int:
    """How many tasks the worlds are dealt into (see the module's notes).

    Args:
        episodes: Episodes of all planners over all worlds.
        cpus: CPUs of the cluster.
        worlds_per_task: A batch size asked for (worlds per task) instead of the rule.
        worlds: Worlds in all (with ``worlds_per_task``).
    """
    if worlds_per_task is not None:
        return max(1, math.ceil(worlds / max(1, worlds_per_task)))
    return max(1, min(TASKS_PER_CPU * max(1, cpus), episodes // MIN_EPISODES_PER_TASK))


def _model_copy(data: bytes, name: str) -> Path:
    """A private copy of a shipped model file on this node (written once, atomically), named by its hash."""
    folder = Path(tempfile.gettempdir()) / "apf-physics-models" / hashlib.sha256(data).hexdigest()[:16]
    path = folder / name
    if not path.is_file() or path.stat().st_size != len(data):
        folder.mkdir(parents=True, exist_ok=True)
        write_bytes(path, data)
    return path


def evaluate_batch(planners: Sequence[str], worlds: Sequence[World], starts: Optional[dict[str, np.ndarray]],
                   max_steps: Optional[int], formation: bool, model: Optional[str] = None,
                   model_bytes: Optional[bytes] = None,
                   kinematics: Optional[str] = None) -> dict[str, tuple[str, list[list[Episode]], float]]:
    """One task: every planner on some worlds, as :func:`~apf_physics.experiments.evaluate.evaluate` runs it (on a Ray worker).

    Args:
        planners: The planners' command-line names.
        worlds: The task's worlds.
        starts: Their starts by world name (None: the worlds' own).
        max_steps: Step limit per episode.
        formation: Run the worlds' formations.
        model: The model file of the learned planners, as the user named it.
        model_bytes: Its contents, shipped to the worker (a cluster's nodes need not share files);
            None: ``model`` is opened where the task runs.
        kinematics: The robot kind (None: each world file's).

    Returns:
        Per planner: the evaluation's label, each world's episodes, and the CPU seconds taken.
    """
    local = None
    if model_bytes is not None:
        local = _model_copy(model_bytes, Path(model).name)
    out = {}
    try:
        for name in planners:
            cpu = time.process_time()
            made = make_planner(name, model=model if local is None else str(local))
            label, episodes = made.name + ("+formation" if formation else ""), []
            for world in worlds:   # one planner through the worlds in turn, as evaluate() runs it
                ev = evaluate(made, [world], starts, max_steps=max_steps, formation=formation, kinematics=kinematics)
                label = ev.planner
                episodes.append(ev.episodes)
            out[name] = (label, episodes, time.process_time() - cpu)
    except UserError as exc:   # name the user's file, not the worker's copy
        if local is None:
            raise
        raise type(exc)(str(exc).replace(str(local), str(model))) from None
    return out


def _timed_batch(*args) -> tuple[dict, float, float, str, int]:
    """:func:`evaluate_batch` with its wall and CPU time, node and process (run on a Ray worker)."""
    import ray
    start, cpu = time.perf_counter(), time.process_time()
    result = evaluate_batch(*args)
    return (result, time.perf_counter() - start, time.process_time() - cpu,
            ray.get_runtime_context().get_node_id(), os.getpid())


def evaluate_on_ray(planners: Sequence[str], worlds: Sequence[World], starts: Optional[dict[str, np.ndarray]] = None,
                    model: Optional[str] = None, max_steps: Optional[int] = None, formation: bool = False,
                    address: Optional[str] = None, worlds_per_task: Optional[int] = None,
                    num_cpus: Optional[int] = None, timings: Optional[list[TaskTiming]] = None,
                    kinematics: Optional[str] = None) -> list[Evaluation]:
    """Evaluate several planners over worlds as Ray tasks: the same evaluations as a local run.

    Args:
        planners: Planner command-line names (:data:`~apf_physics.planners.PLANNERS`).
        worlds: The worlds.
        starts: Starts per world name, instead of the worlds' own.
        model: Model file of the learned planners (default: the shipped model for the world's field).
        max_steps: Step limit per episode.
        formation: Run each world's formation.
        address: Where Ray is (:func:`connect`).
        worlds_per_task: Worlds per task (default: :func:`task_count`'s rule).
        num_cpus: CPUs of a local Ray started for the run (default: all).
        timings: A list to append a :class:`TaskTiming` per task to.
        kinematics: The robot kind (None: each world file's).

    Returns:
        One :class:`~apf_physics.experiments.evaluate.Evaluation` per planner, in order, as
        ``[evaluate(make_planner(p, model), worlds, starts, ...) for p in planners]`` gives.

    Raises:
        UserError: An unknown planner, Ray missing or unreachable, or a task's own error (a
            world's, a model file's), as the local run would raise it.
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
        parts = batches(len(worlds), task_count(sum(sizes) * len(names), cpus, worlds_per_task, len(worlds)))
        task = ray.remote(num_cpus=1)(_timed_batch)
        shipped = ray.put(model_bytes) if model_bytes is not None else None
        futures = []
        for part in parts:
            chosen = [worlds[i] for i in part]
            mine = None if starts is None else {w.name: starts[w.name] for w in chosen}
            futures.append(task.remote(names, chosen, mine, max_steps, formation, model, shipped, kinematics))
        try:
            results = ray.get(futures)
        except ray.exceptions.RayTaskError as exc:
            cause = getattr(exc, "cause", None)
            if isinstance(cause, UserError):
                raise type(cause)(str(cause)) from None
            raise
    if timings is not None:
        timings.extend(TaskTiming(tuple(part), sum(sizes[i] for i in part) * len(names), seconds, cpu,
                                  {n: r[n][2] for n in names}, node, pid)
                       for part, (r, seconds, cpu, node, pid) in zip(parts, results))
    out = []
    for name in dict.fromkeys(names):
        per_world: list[list[Episode]] = [[] for _ in worlds]
        label = make_planner(name, model=model).name + ("+formation" if formation else "")
        for part, (r, *_) in zip(parts, results):
            label, episodes, _ = r[name]
            for i, eps in zip(part, episodes):
                per_world[i] = eps
        out.append(Evaluation(label, [e for eps in per_world for e in eps]))
    return [out[list(dict.fromkeys(names)).index(n)] for n in names]
