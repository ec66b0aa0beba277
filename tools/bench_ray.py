"""Benchmark: ``apf-physics eval --ray`` on a local Ray against a serial run, side by side, in one run.

Four parts, all on the same worlds and planners:

1. **serial**: :func:`~apf_physics.experiments.evaluate.evaluate` of each planner in this process, timing
   every world (wall and CPU time);
2. **Ray start-up**: ``ray.init`` of a local Ray with ``--cpus`` CPUs, then the workers'
   first task (importing the package and torch);
3. **Ray, warm**: :func:`~apf_physics.experiments.campaign.evaluate_on_ray` on that Ray, with each task's
   wall and CPU time; its episodes must equal the serial run's;
4. **command line** (unless ``--no-cli``): ``apf-physics eval ... --json`` and the same with
   ``--ray`` as a user runs them (Ray started and stopped inside); their JSON files must be
   byte for byte the same.

Then, on paper, what ``--nodes`` nodes of ``--node-cpus`` CPUs would take: the tasks that
:func:`~apf_physics.experiments.campaign.evaluate_on_ray` makes for that many CPUs, each costing the serial
CPU time of its worlds times the measured Ray overhead (worker CPU over serial CPU, per
planner), run first come first served on dedicated cores, plus the measured dispatch and
gather time. The machine's load average is printed beside every figure: a core taken by
another job slows every Ray worker sharing it.

Usage::

    python tools/bench_ray.py /tmp/heldout --planners gradient,escape,dqn --cpus 2 [--nodes 4 --node-cpus 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.experiments.campaign import TaskTiming, batches, episodes_per_world, evaluate_on_ray, task_count  # noqa: E402
from apf_physics.experiments.evaluate import evaluate  # noqa: E402
from apf_physics.planners import make_planner  # noqa: E402
from apf_physics.world.io.worldfile import load_worlds  # noqa: E402


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load {one:.2f} (5 min {five:.2f}) on {os.cpu_count()} cores"


def serial(names, paths):
    """Each planner over fresh worlds in this process: (evaluations, wall, {planner: [(wall, cpu) per world]})."""
    worlds = load_worlds(paths)
    per_world: dict[str, list[tuple[float, float]]] = {}
    evaluations = []
    start = time.perf_counter()
    for name in names:
        marks = [(time.perf_counter(), time.process_time())]
        times = []

        def progress(_world, marks=marks, times=times):
            now = (time.perf_counter(), time.process_time())
            times.append((now[0] - marks[-1][0], now[1] - marks[-1][1]))
            marks.append(now)

        evaluations.append(evaluate(make_planner(name), worlds, progress=progress))
        per_world[name] = times
    return evaluations, time.perf_counter() - start, per_world


def warm_workers() -> None:
    """Run in each worker of a fresh Ray: what a first task imports (the package, torch, the DQN planner)."""
    import apf_physics.planners.dqn  # noqa: F401
    import torch  # noqa: F401
    time.sleep(0.5)   # hold the worker, so that the next warm-up task goes to another one


def schedule(durations: list[float], slots: int) -> float:
    """Makespan of tasks run first come first served on ``slots`` cores."""
    free = [0.0] * slots
    for d in durations:
        i = min(range(slots), key=free.__getitem__)
        free[i] += d
    return max(free) if free else 0.0


def paper(names, worlds, per_world, timings: list[TaskTiming], dispatch: float, cpus: int) -> tuple[float, int, dict]:
    """Predicted wall time of the warm evaluation on ``cpus`` dedicated CPUs, its tasks, and Ray's CPU overhead per planner.

    A task costs the serial CPU time of its worlds under each planner times that planner's
    measured overhead (its CPU time in the Ray tasks over its serial CPU time).
    """
    sizes = episodes_per_world(worlds, None, False)
    serial_cpu = {n: sum(c for _, c in per_world[n]) for n in names}
    ray_cpu = defaultdict(float)
    for t in timings:
        for n, c in t.planner_cpu.items():
            ray_cpu[n] += c
    factor = {n: ray_cpu[n] / serial_cpu[n] if serial_cpu[n] else 1.0 for n in names}
    parts = batches(len(worlds), task_count(sum(sizes) * len(names), cpus))
    durations = [sum(factor[n] * per_world[n][i][1] for n in names for i in part) for part in parts]
    return schedule(durations, cpus) + dispatch, len(parts), factor


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("worlds", nargs="+", help="world files or folders (e.g. /tmp/heldout)")
    ap.add_argument("--planners", default="gradient,escape,dqn")
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the local Ray (default 2)")
    ap.add_argument("--ray-batch", type=int, help="worlds per Ray task (default: the rule of apf_physics.experiments.campaign)")
    ap.add_argument("--nodes", type=int, default=4, help="nodes of the cluster worked out on paper (default 4)")
    ap.add_argument("--node-cpus", type=int, default=2, help="CPUs per node on paper (default 2)")
    ap.add_argument("--no-cli", action="store_true", help="skip the command-line comparison")
    args = ap.parse_args()
    names = [n.strip() for n in args.planners.split(",") if n.strip()]
    import ray
    import torch  # noqa: F401  (imported before the serial clock starts, as the Ray workers are warmed below)
    import apf_physics.planners.dqn  # noqa: F401

    worlds = load_worlds(args.worlds)
    episodes = sum(episodes_per_world(worlds, None, False))
    print(f"{len(worlds)} worlds, {episodes} starts, planners {', '.join(names)}; {load()}", flush=True)

    evaluations, serial_wall, per_world = serial(names, args.worlds)
    serial_cpu = sum(c for n in names for _, c in per_world[n])
    print(f"serial:            {serial_wall:6.2f} s  (CPU {serial_cpu:.2f} s; "
          + ", ".join(f"{n} {sum(w for w, _ in per_world[n]):.2f} s" for n in names) + f")  [{load()}]", flush=True)

    t = time.perf_counter()
    ray.init(num_cpus=args.cpus, include_dashboard=False, log_to_driver=False, logging_level="WARNING")
    init = time.perf_counter() - t
    t = time.perf_counter()
    warm = ray.remote(num_cpus=1)(warm_workers)
    ray.get([warm.remote() for _ in range(args.cpus)])
    warmup = time.perf_counter() - t - 0.5
    print(f"ray start-up:      {init:6.2f} s ray.init + {warmup:.2f} s first task per worker (imports)  [{load()}]",
          flush=True)

    timings: list[TaskTiming] = []
    t = time.perf_counter()
    on_ray = evaluate_on_ray(names, load_worlds(args.worlds), worlds_per_task=args.ray_batch, timings=timings)
    ray_wall = time.perf_counter() - t
    same = all(a.planner == b.planner and [e.to_dict() for e in a.episodes] == [e.to_dict() for e in b.episodes]
               for a, b in zip(evaluations, on_ray))
    busy = defaultdict(float)
    for task in timings:
        busy[task.pid] += task.seconds
    dispatch = ray_wall - max(busy.values())
    task_cpu = sum(task.cpu_seconds for task in timings)
    print(f"ray ({args.cpus} CPUs), warm: {ray_wall:6.2f} s  ({len(timings)} tasks of "
          f"{min(t.seconds for t in timings):.2f}-{max(t.seconds for t in timings):.2f} s; worker CPU {task_cpu:.2f} s; "
          f"dispatch and gather {dispatch:.2f} s)  [{load()}]", flush=True)
    t = time.perf_counter()
    ray.shutdown()
    shutdown = time.perf_counter() - t
    print(f"  same episodes as serial: {same}; ray.shutdown {shutdown:.2f} s")
    print(f"  speed-up warm: {serial_wall / ray_wall:.2f}x; with start-up and shutdown "
          f"({init + warmup + ray_wall + shutdown:.2f} s): {serial_wall / (init + warmup + ray_wall + shutdown):.2f}x")
    for task in timings:
        print(f"    task of {len(task.worlds):3d} worlds, {task.episodes:4d} episodes: {task.seconds:6.2f} s wall, "
              f"{task.cpu_seconds:6.2f} s CPU (" + ", ".join(f"{n} {c:.2f}" for n, c in task.planner_cpu.items())
              + f")  pid {task.pid}")

    if not args.no_cli:
        with tempfile.TemporaryDirectory() as tmp:
            base = ["apf-physics", "eval", *args.worlds, "--planner", ",".join(names)]
            runs = {}
            for label, extra in (("serial", []), ("ray", ["--ray"])):
                out = Path(tmp) / f"{label}.json"
                t = time.perf_counter()
                subprocess.run([*base, "--json", str(out), *extra], check=True, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
                runs[label] = (time.perf_counter() - t, out.read_bytes())
                print(f"command line {label:<6} {runs[label][0]:6.2f} s  [{load()}]", flush=True)
            print(f"  ratio serial / ray: {runs['serial'][0] / runs['ray'][0]:.2f}x; "
                  f"same JSON: {runs['serial'][1] == runs['ray'][1]}")

    cpus = args.nodes * args.node_cpus
    predicted, tasks, factor = paper(names, worlds, per_world, timings, dispatch, cpus)
    local, _, _ = paper(names, worlds, per_world, timings, dispatch, args.cpus)
    print("on paper (dedicated cores; Ray CPU / serial CPU per planner: "
          + ", ".join(f"{n} {f:.2f}" for n, f in factor.items()) + ")")
    print(f"  serial on a core of its own: {serial_cpu:.2f} s (its CPU time)")
    print(f"  {args.cpus} CPUs: {local:.2f} s warm ({serial_cpu / local:.2f}x)")
    print(f"  {args.nodes} nodes x {args.node_cpus} CPUs: {tasks} tasks, {predicted:.2f} s warm "
          f"({serial_cpu / predicted:.2f}x); plus joining the cluster and the workers' first imports "
          f"(~{warmup:.1f} s, in parallel on the nodes)")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
