"""Many formations in a warehouse: success, time and memory of formation leaders on a MovingAI map.

    python tools/bench_warehouse.py MAP.map [--formations 10 30] [--followers 1] [--seed 0]
        [--models general,map] [--out DIR]
    python tools/bench_warehouse.py --generate 12x6 --out DIR ...   # a warehouse-like map made here

For each number of formations, draws that many formations (a leader and ``--followers``
followers each) whose starts and targets are free cells of the map (with their eight neighbours
free, at least 4 cells apart), writes the world file to DIR (beside the map, which is read from
where it is: nothing is copied into the repository), and runs ``apf-physics eval WORLD --planner dqn
--model M --formation`` for each model in a fresh process, so that each run's peak memory is its
own. Prints per run: formations arrived, trapped, robot–robot collisions, mean path of those that
arrived (in steps), seconds, the process's peak resident memory, the bytes the formations' worlds
keep (their rasters and values, summed over the formations) and the loader's estimate
(``worldfile.raster_memory``).

``--generate CxR`` writes a warehouse-like map instead (C × R blocks of shelves two cells deep and
10 long, aisles 2 wide, a border of 5; the layout of MovingAI's ``warehouse-*`` maps), for
validation on maps other than the benchmark's.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml


def warehouse_lines(columns: int, rows: int, shelf: int = 10, aisle: int = 2, border: int = 5) -> list[str]:
    """A MovingAI map's lines: ``columns`` × ``rows`` blocks of shelves (2 × ``shelf`` cells)."""
    width = 2 * border + columns * (shelf + aisle) - aisle
    height = 2 * border + rows * (2 + aisle) - aisle
    occupied = np.zeros((height, width), bool)
    for i in range(columns):
        for j in range(rows):
            x, y = border + i * (shelf + aisle), border + j * (2 + aisle)
            occupied[y:y + 2, x:x + shelf] = True
    return ["type octile", f"height {height}", f"width {width}", "map"] + [
        "".join("@" if cell else "." for cell in row) for row in occupied]


def draw_formations(world, count: int, followers: int, seed: int) -> list[dict]:
    """``count`` formations on free cell centres of ``world``'s grid, each cell's neighbours free, 4 cells apart."""
    grid = next(o for o in world.obstacles if o.__class__.__name__ == "GridObstacle")
    cell = grid.cell
    cols, rows = int(round(world.size[0] / cell)), int(round(world.size[1] / cell))
    xs, ys = np.meshgrid((np.arange(cols) + 0.5) * cell, (np.arange(rows) + 0.5) * cell)
    centres = np.column_stack([xs.ravel(), ys.ravel()])
    centres = centres[world.clearance(centres) >= 1.5 * cell]     # the eight neighbours free
    rng = np.random.default_rng(seed)
    points: list[np.ndarray] = []
    for k in rng.permutation(len(centres)):
        if all(np.abs(centres[k] - p).max() >= 4 * cell for p in points):
            points.append(centres[k])
        if len(points) == 2 * count:
            break
    if len(points) < 2 * count:
        raise SystemExit(f"only {len(points) // 2} formations fit on the map")
    to_file = world.frame.to_file
    return [{"start": to_file(points[2 * i]).tolist(), "target": to_file(points[2 * i + 1]).tolist(),
             "followers": followers} for i in range(count)]


def run_one(world_file: str, model: str) -> dict:
    """One evaluation in this process (the child of :func:`main`): its figures as a dict."""
    from apf_physics import load_world
    from apf_physics.experiments.rollout import rollout_formations
    from apf_physics.planners import make_planner
    from apf_physics.world.io.worldfile import raster_memory

    import torch
    torch.set_num_threads(1)
    world = load_world(world_file)
    start = time.perf_counter()
    episodes = rollout_formations(world, make_planner("dqn", model=model))
    seconds = time.perf_counter() - start
    kept = sum(_nbytes(world.formation_world(i).kept(), set()) for i in range(len(world.formations)))
    arrived = [e for e in episodes if e.success]
    return {"formations": len(episodes), "arrived": len(arrived),
            "trapped": sum(e.outcome == "trapped" for e in episodes),
            "collisions": sum(e.formation.robot_robot_collisions + e.formation.robot_obstacle_collisions
                              for e in episodes),
            "path": float(np.mean([e.path_length for e in arrived])) if arrived else None,
            "seconds": seconds, "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "kept_mib": kept / 2**20,
            "estimate_mib": raster_memory(world.size, 1, len(world.formations)) / 2**20}


def _nbytes(value, seen: set) -> int:
    """Bytes of the NumPy arrays and torch tensors reachable from ``value`` (each counted once)."""
    import torch
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, torch.Tensor):
        return value.element_size() * value.nelement()
    if isinstance(value, dict):
        return sum(_nbytes(v, seen) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_nbytes(v, seen) for v in value)
    if hasattr(value, "kept"):                           # the map policy's values (MapValues)
        return sum(_nbytes(v, seen) for v in value.kept())
    if hasattr(value, "__dataclass_fields__"):
        return sum(_nbytes(getattr(value, f), seen) for f in value.__dataclass_fields__)
    if hasattr(value, "__dict__"):
        return sum(_nbytes(v, seen) for v in vars(value).values())
    return 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("map", nargs="?", help="a MovingAI .map (read where it is)")
    parser.add_argument("--generate", metavar="CxR", help="write a warehouse-like map of C x R shelf blocks instead")
    parser.add_argument("--formations", type=int, nargs="+", default=[10, 30], help="numbers of formations")
    parser.add_argument("--followers", type=int, default=1, help="followers per formation (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the starts and targets (default 0)")
    parser.add_argument("--models", default="general,map", help="leader models, comma-separated (default general,map)")
    parser.add_argument("--out", default=None, help="folder for the world files (default: beside the map)")
    parser.add_argument("--one", nargs=2, metavar=("WORLD", "MODEL"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(*args.one)))
        return

    from apf_physics import world_from_dict
    from apf_physics.world.io.worldfile import MEMORY_BUDGET_VARIABLE

    if args.generate:
        columns, rows = (int(v) for v in args.generate.lower().split("x"))
        out = Path(args.out or ".")
        out.mkdir(parents=True, exist_ok=True)
        map_path = out / f"warehouse-like-{columns}x{rows}.map"
        map_path.write_text("\n".join(warehouse_lines(columns, rows)) + "\n")
    elif args.map:
        map_path = Path(args.map).resolve()
    else:
        parser.error("give a MovingAI map, or --generate CxR")
    out = Path(args.out).resolve() if args.out else map_path.parent
    out.mkdir(parents=True, exist_ok=True)
    base = {"grid": {"movingai": str(map_path.resolve())}, "field": "thesis-general"}
    probe = world_from_dict({**base, "targets": [[1.5, 1.5]]}, str(out / "probe.yaml"))
    print(f"map {map_path.name}: {probe.size[0]:g} x {probe.size[1]:g} cells; followers {args.followers}, "
          f"seed {args.seed}; load average {os.getloadavg()[0]:.2f}")
    print(f"{'formations':>10} {'model':>8} {'arrived':>9} {'trapped':>7} {'collide':>7} {'path':>7} {'s':>6} "
          f"{'peak MiB':>9} {'kept MiB':>9} {'estimate MiB':>12}")
    env = {**os.environ, "OMP_NUM_THREADS": "1", MEMORY_BUDGET_VARIABLE: os.environ.get(MEMORY_BUDGET_VARIABLE, "64G")}
    for count in args.formations:
        world_file = out / f"{map_path.stem}-{count}f{args.followers}-s{args.seed}.yaml"
        data = {"name": world_file.stem, **base,
                "formations": draw_formations(probe, count, args.followers, args.seed)}
        world_file.write_text(yaml.safe_dump(data, default_flow_style=None, sort_keys=False))
        for model in args.models.split(","):
            done = subprocess.run([sys.executable, __file__, "--one", str(world_file), model], env=env,
                                  capture_output=True, text=True)
            if done.returncode:
                print(done.stderr[-2000:], file=sys.stderr)
                raise SystemExit(done.returncode)
            r = json.loads(done.stdout.strip().splitlines()[-1])
            path = "-" if r["path"] is None else f"{r['path']:.1f}"
            print(f"{count:>10} {model:>8} {r['arrived']:>4}/{r['formations']:<4} {r['trapped']:>7} {r['collisions']:>7} "
                  f"{path:>7} {r['seconds']:>6.0f} {r['peak_mib']:>9.0f} {r['kept_mib']:>9.1f} "
                  f"{r['estimate_mib']:>12.0f}", flush=True)


if __name__ == "__main__":
    main()
