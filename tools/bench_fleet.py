"""Fleets on MovingAI maps: success, collisions, sum of costs and time, and the cost per robot-step by fleet size.

    python tools/bench_fleet.py draw MAPS_DIR --out SCEN_DIR [--seeds 101 102 103 104 105] [--count 400]
    python tools/bench_fleet.py run MAPS_DIR SCEN_DIR [--cases warehouse-20-40-10-2-2:100,200 ...]
        [--planners dqn,astar,gradient] [--seeds ...] [--json OUT]
    python tools/bench_fleet.py speed MAP SCEN [--sizes 10 100 200 400] [--planner dqn]
    python tools/bench_fleet.py lifelong MAP SCEN [--agents 200] [--horizon 500] [--planners dqn,astar]

``draw`` writes one scenario file per map and seed (``MAP-SEED.scen``, drawn as the MAPF benchmark's
random scenarios by ``apf-physics draw-scen``: distinct free starts and goals in the map's largest
connected region). ``run`` runs the first N lines of each as one fleet (``eval MAP --scen FILE
--agents N``) with each planner, in this process, and prints a row per run: robots arrived, makespan,
sum of costs (steps; each robot's last arrival) over the sum of the robots' own octile optima, path
lengths over the same, robot–robot and robot–obstacle collisions, wall time (the planner's per-goal
tables included) and milliseconds per robot-step (wall time over robots × steps). ``speed`` runs one
file's first 10, 100, 200, 400 lines and splits the time per robot-step into the planner's values
(its per-goal tables built included), the fleet's rule and the engine's step. ``lifelong`` gives the
throughput (goals per step) over a horizon, each robot's goals from a stream seeded by the run's seed.

Maps are read from where they are (MovingAI's, e.g. the repository ``Kei18/pibt2``, folder ``map/``);
nothing is copied into this repository. Run it under ``nice`` on a shared machine: the times are
wall times.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

import numpy as np  # noqa: E402

from apf_physics.common.safefile import write_text  # noqa: E402
from apf_physics.experiments.fleet import rollout_fleet  # noqa: E402
from apf_physics.experiments.movingai import draw_scenarios, scenario_fleet  # noqa: E402
from apf_physics.planners import make_planner  # noqa: E402
from apf_physics.world.io.mapfiles import scen_text  # noqa: E402

CASES = ["warehouse-20-40-10-2-2:100,200", "random-64-64-20:100", "den312d:100"]
"""The issue's maps and fleet sizes."""


def draw(args: argparse.Namespace) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for path in sorted(Path(args.maps).glob("*.map")):
        for seed in args.seeds:
            scen = out / f"{path.stem}-{seed}.scen"
            write_text(scen, scen_text(draw_scenarios(path, args.count, seed)))
            print(f"wrote {scen}")


def row(run, label: str) -> dict:
    s = run.summary()
    return {"case": label, "planner": run.planner, "robots": s["robots"], "arrived": s.get("arrived"),
            "makespan": s.get("makespan"), "sum_of_costs": s.get("sum_of_costs"),
            "soc_over_optimal": s.get("soc_over_optimal"), "path_over_optimal": s.get("path_over_optimal"),
            "robot_robot": s["robot_robot_collisions"], "robot_obstacle": s["robot_obstacle_collisions"],
            "seconds": s["seconds"], "ms_per_robot_step": s["ms_per_robot_step"], "steps": s["steps"],
            "parts": s["seconds_by_part"], "goal_tables_peak_mb": round(s["goal_tables_peak_bytes"] / 2**20, 1),
            "throughput": s.get("throughput"), "goals_reached": s.get("goals_reached")}


def show(r: dict) -> None:
    if r["throughput"] is not None:
        print(f"{r['case']:<34} {r['planner']:<9} {r['robots']:>4} goals {r['goals_reached']:>5} throughput "
              f"{r['throughput']:.3f}/step  r-r {r['robot_robot']} r-o {r['robot_obstacle']}  {r['seconds']:>7.1f} s "
              f"{r['ms_per_robot_step']:.3f} ms/robot-step {r['parts']}", flush=True)
        return
    ratio = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    print(f"{r['case']:<34} {r['planner']:<9} {r['arrived']:>4}/{r['robots']:<4} makespan {str(r['makespan']):>5} "
          f"SoC {r['sum_of_costs']:>6} SoC/opt {ratio(r['soc_over_optimal'])} path/opt {ratio(r['path_over_optimal'])} "
          f"r-r {r['robot_robot']} r-o {r['robot_obstacle']} {r['seconds']:>7.1f} s "
          f"{r['ms_per_robot_step']:.3f} ms/robot-step", flush=True)


def run_cases(args: argparse.Namespace) -> None:
    rows = []
    for case in args.cases:
        name, sizes = case.split(":")
        for seed in args.seeds:
            for size in [int(v) for v in sizes.split(",")]:
                for planner in args.planners.split(","):
                    world, fleet = scenario_fleet(Path(args.maps) / f"{name}.map", Path(args.scen) / f"{name}-{seed}.scen",
                                                  size)
                    run = rollout_fleet(world, make_planner(planner), fleet)
                    rows.append(row(run, f"{name} seed {seed}"))
                    show(rows[-1])
    if args.json:
        write_text(args.json, json.dumps(rows, indent=1))


def crowd_test_us(run, robots: int) -> tuple[float, float]:
    """Microseconds per robot of a crowd's free-move test over the run's recorded steps: by cells
    (:func:`~apf_physics.sim.freemove.crowd_needs`, what the engine runs) and dense (every pair,
    ``may_touch`` and ``close_under_touch``: the engine's before), side by side in this process."""
    from apf_physics.sim.freemove import close_under_touch, crowd_needs, may_touch
    radius = np.full(robots, run.world.robot_radius)
    steps = range(0, run.steps, max(1, run.steps // 40))
    times = []
    for dense in (False, True):
        clock = time.perf_counter()
        for t in steps:
            p, dp = run.positions[t], run.positions[t + 1] - run.positions[t]
            needs = np.zeros(robots, bool)
            if dense:
                both, near = may_touch(p[None], dp[None], radius[None, :, None], np.ones((1, robots), bool), 2.83)
                close_under_touch(needs[None], both, near)
            else:
                crowd_needs(p, dp, radius, needs, 2.83)
        times.append(1e6 * (time.perf_counter() - clock) / (len(steps) * robots))
    return times[0], times[1]


def speed(args: argparse.Namespace) -> None:
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    for size in args.sizes:
        world, fleet = scenario_fleet(args.map, args.scen, size)
        clock = time.perf_counter()
        run = rollout_fleet(world, make_planner(args.planner), fleet)
        total = time.perf_counter() - clock
        robot_steps = size * run.steps
        parts = {k: 1000 * v / robot_steps for k, v in run.parts.items()}
        print(f"{size:>5} robots, {run.steps:>4} steps, {int(run.arrived.sum())}/{size} arrived, collisions "
              f"{run.robot_robot}+{run.robot_obstacle}: {1000 * total / robot_steps:.3f} ms per robot-step "
              f"(values {parts['values']:.3f}, rule {parts['rule']:.4f}, engine {parts['physics']:.4f}); "
              f"{run.tables[0]} value tables built, peak {run.tables[1] / 2**20:.1f} MiB", flush=True)
        cells, dense = crowd_test_us(run, size)
        print(f"        the crowd's free-move test: {cells:.2f} µs per robot by cells, {dense:.2f} dense "
              f"(every pair), ratio {dense / cells:.1f}", flush=True)


def lifelong(args: argparse.Namespace) -> None:
    for planner in args.planners.split(","):
        world, fleet = scenario_fleet(args.map, args.scen, args.agents)
        run = rollout_fleet(world, make_planner(planner), fleet, lifelong=args.horizon, seed=args.seed)
        show(row(run, f"{world.name} lifelong seed {args.seed}"))


def main() -> None:
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("draw")
    p.add_argument("maps")
    p.add_argument("--out", required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105])
    p.add_argument("--count", type=int, default=400)
    p.set_defaults(func=draw)
    p = sub.add_parser("run")
    p.add_argument("maps")
    p.add_argument("scen")
    p.add_argument("--cases", nargs="+", default=CASES)
    p.add_argument("--planners", default="dqn,astar,gradient")
    p.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105])
    p.add_argument("--json")
    p.set_defaults(func=run_cases)
    p = sub.add_parser("speed")
    p.add_argument("map")
    p.add_argument("scen")
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 200, 400])
    p.add_argument("--planner", default="dqn")
    p.set_defaults(func=speed)
    p = sub.add_parser("lifelong")
    p.add_argument("map")
    p.add_argument("scen")
    p.add_argument("--agents", type=int, default=200)
    p.add_argument("--horizon", type=int, default=500)
    p.add_argument("--planners", default="dqn,astar")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=lifelong)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
