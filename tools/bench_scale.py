"""Robots large against their gaps: doors one step wide on a user's grid map, and dense clutter.

Two checks of the learned planner where the robot barely fits, each beside A* in one run:

- **Doors one step wide.** Maps drawn as a new user would (MovingAI grids: a 3 × 3 block of
  rooms, 20 cells a side, walls one cell thick, a door of ``--door`` cells between every two
  neighbouring rooms, at random along the wall), read at ``--cell 0.5``: a door of 2 cells is one
  robot step wide. Six starts in the other rooms, the target in the first room's centre.
- **Dense clutter.** The obstacle-count world of ``tools/bench_obstacles.py`` at K boxes (0.6
  wide on a jittered lattice over 100 × 100, gaps of a few tenths), its 8 starts.

Usage::

    python tools/bench_scale.py [--maps 4] [--door 2] [--boxes 3573] [--planners dqn,astar] [--model PATH] [--keep DIR]

``--model`` gives the learned planners a model file of your own (an earlier ``map.pt``, say).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench_obstacles import lattice_world  # noqa: E402

from apf_physics.experiments.evaluate import evaluate  # noqa: E402
from apf_physics.experiments.movingai import evaluate_trials, scenario_trials  # noqa: E402
from apf_physics.planners import make_planner  # noqa: E402

ROOMS = 3
ROOM = 20
STARTS = 6


def rooms_grid(seed: int, door: int) -> np.ndarray:
    """(n, n) bool, True where a wall is: ROOMS × ROOMS rooms of ROOM cells, a door of ``door`` cells
    at random along every wall between neighbouring rooms."""
    rng = np.random.default_rng(seed)
    n = ROOMS * ROOM + 1
    walls = np.zeros((n, n), bool)
    walls[0, :] = walls[-1, :] = walls[:, 0] = walls[:, -1] = True
    for k in range(1, ROOMS):
        walls[k * ROOM, :] = walls[:, k * ROOM] = True
    for i in range(ROOMS):
        for j in range(ROOMS):
            if j + 1 < ROOMS:
                r0 = i * ROOM + 1 + rng.integers(0, ROOM - 1 - door)
                walls[r0:r0 + door, (j + 1) * ROOM] = False
            if i + 1 < ROOMS:
                c0 = j * ROOM + 1 + rng.integers(0, ROOM - 1 - door)
                walls[(i + 1) * ROOM, c0:c0 + door] = False
    return walls


def write_rooms(folder: Path, seed: int, door: int) -> tuple[Path, Path]:
    """The map and its scenarios (MovingAI formats: cells from the top-left corner)."""
    walls = rooms_grid(seed, door)
    name = f"rooms{door}_{seed}.map"
    map_path, scen_path = folder / name, folder / f"{name}.scen"
    rows = "".join("".join("@" if w else "." for w in row) + "\n" for row in walls)
    map_path.write_text(f"type octile\nheight {walls.shape[0]}\nwidth {walls.shape[1]}\nmap\n{rows}")
    rng = np.random.default_rng(seed + 1000)
    goal = (ROOM // 2, ROOM // 2)
    others = [(i, j) for i in range(ROOMS) for j in range(ROOMS) if (i, j) != (0, 0)]
    lines = ["version 1"]
    for _ in range(STARTS):
        i, j = others[rng.integers(len(others))]
        x, y = j * ROOM + rng.integers(3, ROOM - 3), i * ROOM + rng.integers(3, ROOM - 3)
        lines.append(f"0\t{name}\t{walls.shape[1]}\t{walls.shape[0]}\t{x}\t{y}\t{goal[0]}\t{goal[1]}\t0")
    scen_path.write_text("\n".join(lines) + "\n")
    return map_path, scen_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--maps", type=int, default=4, help="rooms maps, seeds 0 to N-1")
    parser.add_argument("--door", type=int, default=2, help="door width in cells (2 at --cell 0.5: one step)")
    parser.add_argument("--boxes", type=int, default=3573, help="the clutter world's box count")
    parser.add_argument("--planners", default="dqn,astar")
    parser.add_argument("--model", help="a model file for the learned planners (default: the shipped one)")
    parser.add_argument("--keep", type=Path, help="write the maps here (default: a temporary folder)")
    args = parser.parse_args()
    names = args.planners.split(",")
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.keep or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        files = [write_rooms(folder, seed, args.door) for seed in range(args.maps)]
        print(f"doors of {args.door} cells at --cell 0.5 ({args.maps} maps x {STARTS} starts)", flush=True)
        for name in names:
            t = time.perf_counter()
            outcomes = []
            for map_path, scen_path in files:
                ev = evaluate_trials(make_planner(name, args.model), scenario_trials(map_path, scen_path, cell=0.5))
                outcomes += [e.outcome for e in ev.episodes]
            print(f"  {name:<16} {outcomes.count('reached')}/{len(outcomes)} reached, "
                  f"{outcomes.count('collision')} collisions  ({time.perf_counter() - t:.1f} s)", flush=True)
    world = lattice_world(args.boxes)
    print(f"dense clutter: {len(world.obstacles):,} boxes, {len(world.starts)} starts", flush=True)
    for name in names:
        t = time.perf_counter()
        outcomes = [e.outcome for e in evaluate(make_planner(name, args.model), [world]).episodes]
        print(f"  {name:<16} {outcomes.count('reached')}/{len(outcomes)} reached, "
              f"{outcomes.count('collision')} collisions, outcomes {outcomes}  ({time.perf_counter() - t:.1f} s)",
              flush=True)


if __name__ == "__main__":
    main()
