"""Several formations at scale: the time of a control step with 1, 4 and 16 formations in one world.

    python tools/bench_formations.py [--planner dqn] [--counts 1 4 16]

A 100×100 world with a few obstacles; formations of 3 robots (a leader and 2 followers in a
line) start on a circle of radius 40 around the middle and cross it to the opposite side.
Prints, for each number of formations, the steps run, the milliseconds per control step,
per robot-step, whether every formation arrived, and robot–robot collisions; the ratio of
the cost per robot-step to that of one formation shows whether it stays flat.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from apf_physics import world_from_dict
from apf_physics.planners import make_planner
from apf_physics.experiments.rollout import rollout_formations


def crossing_world(count: int, size: float = 100.0):
    centre = size / 2
    formations = []
    for k in range(count):
        angle = 2 * math.pi * k / max(count, 1) + 0.1
        u = np.array([math.cos(angle), math.sin(angle)])
        formations.append({"start": (centre + 40 * u).round(3).tolist(), "target": (centre - 38 * u).round(3).tolist(),
                           "followers": 2, "shape": "line"})
    obstacles = [{"circle": {"center": [30, 62], "radius": 2.5}}, {"polygon": [[62, 28], [68, 28], [68, 34], [62, 34]]},
                 {"circle": {"center": [70, 66], "radius": 1.5}}]
    return world_from_dict({"name": f"crossing{count}", "size": [size, size], "field": "thesis-general",
                            "obstacles": obstacles, "formations": formations})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--planner", default="dqn", help="the leaders' planner (default dqn)")
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 4, 16], help="numbers of formations")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    print(f"{'formations':>10} {'robots':>7} {'steps':>6} {'ms/step':>9} {'us/robot-step':>14} {'x one':>6} "
          f"{'all arrived':>12} {'collisions':>11} {'deadlocks':>10}")
    base = None
    for count in args.counts:
        world = crossing_world(count)
        planner = make_planner(args.planner)
        t = time.perf_counter()
        episodes = rollout_formations(world, planner)
        elapsed = time.perf_counter() - t
        steps = max(e.steps for e in episodes)
        robots = 3 * count
        per_robot = elapsed / max(steps, 1) / robots * 1e6
        base = per_robot if base is None else base
        collisions = sum(e.formation.robot_robot_collisions for e in episodes)
        deadlocks = sum(e.formation.deadlocks for e in episodes)
        arrived = sum(e.success for e in episodes)
        print(f"{count:>10} {robots:>7} {steps:>6} {elapsed / max(steps, 1) * 1e3:>9.2f} {per_robot:>14.0f} "
              f"{per_robot / base:>6.2f} {arrived:>7}/{count:<4} {collisions:>11} {deadlocks:>10}")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
