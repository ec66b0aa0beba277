"""Benchmark the core: rasterising the field, and physics control steps.

Prints, in one run, the raster build of a 50x50 world with 10 polygon obstacles at 10
samples per unit by apf_physics (vectorised numpy) beside a per-cell Python loop over the
same grid (the way PythonRobotics' potential_field_planning.py computes its map), their
ratio, and physics control steps per second for one robot among 10 obstacles.

    python tools/bench_core.py [--loop-fraction 0.05]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from apf_physics import world_from_dict
from apf_physics.sim.physics import Physics


def make_world(n_obstacles: int = 10, seed: int = 0):
    rng = np.random.default_rng(seed)
    obstacles = []
    for i in range(n_obstacles):
        cx, cy = 5 + (i % 5) * 9 + rng.uniform(-1, 1), 12 + (i // 5) * 24 + rng.uniform(-2, 2)
        angles = np.sort(rng.uniform(0, 2 * math.pi, 5))
        radii = rng.uniform(1.0, 3.0, 5)
        obstacles.append({"polygon": [[cx + r * math.cos(a), cy + r * math.sin(a)] for a, r in zip(angles, radii)]})
    return world_from_dict({"name": "bench50", "size": [50, 50], "field": "thesis-general", "obstacles": obstacles,
                            "targets": [[45, 45]], "starts": [[2, 2]]})


def python_loop_potential(world, xs, ys):
    """Per-cell loop, PythonRobotics style: for each cell, each target and each obstacle edge."""
    f = world.field
    out = np.empty((len(ys), len(xs)))
    polys = [o.vertices.tolist() for o in world.obstacles]
    targets = world.targets.tolist()
    for iy, y in enumerate(ys):
        for ix, x in enumerate(xs):
            u = 0.0
            for tx, ty in targets:
                d = math.hypot(x - tx, y - ty)
                u += 0.5 * f.katt * d * d
                if d <= f.ps:
                    u -= 0.5 * f.kstr * (f.ps - d) ** 2
            for poly in polys:
                inside = False
                dmin = math.inf
                n = len(poly)
                for k in range(n):
                    (x1, y1), (x2, y2) = poly[k], poly[(k + 1) % n]
                    if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
                        inside = not inside
                    dx, dy = x2 - x1, y2 - y1
                    t = max(0.0, min(1.0, ((x - x1) * dx + (y - y1) * dy) / (dx * dx + dy * dy)))
                    dmin = min(dmin, math.hypot(x - x1 - t * dx, y - y1 - t * dy))
                if inside or dmin <= 0:
                    u += f.u_max
                elif dmin <= f.p0:
                    u += min(0.5 * f.krep * (1 / dmin - 1 / f.p0) ** 2, f.u_max)
            out[iy, ix] = u
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loop-fraction", type=float, default=0.05,
                        help="share of the grid's rows the Python loop computes (its time is scaled up); 1 = all")
    parser.add_argument("--steps", type=int, default=3000)
    args = parser.parse_args()

    world = make_world()
    res = 10
    times = []
    for _ in range(5):
        world.forget()
        t = time.perf_counter()
        raster = world.raster(res)
        times.append(time.perf_counter() - t)
    ours = float(np.median(times))
    rows, cols = raster.grid.shape
    xs = np.arange(cols) / res
    ys = np.arange(rows) / res
    n_rows = max(1, int(rows * args.loop_fraction))
    pick = np.linspace(0, rows - 1, n_rows).astype(int)
    t = time.perf_counter()
    loop_values = python_loop_potential(world, xs, ys[pick])
    loop = (time.perf_counter() - t) * rows / n_rows
    assert np.allclose(loop_values, raster.values[pick], rtol=1e-9, atol=1e-9), "loop and raster disagree"

    physics = Physics([world])
    physics.place([0], [[2.0, 2.0]])
    rng = np.random.default_rng(0)
    commands = rng.uniform(-1, 1, (args.steps, 1, 2))
    t = time.perf_counter()
    for c in commands:
        physics.step(c)
    step_rate = args.steps / (time.perf_counter() - t)

    print(f"raster 50x50 world, 10 polygons, {res}/unit ({rows}x{cols} = {rows * cols} nodes)")
    print(f"  apf_physics (numpy)       {ours * 1e3:10.2f} ms   (median of 5)")
    print(f"  per-cell Python loop      {loop * 1e3:10.0f} ms   ({n_rows}/{rows} rows timed, scaled; values equal)")
    print(f"  ratio                     {loop / ours:10.0f} x")
    print(f"physics: one robot among 10 obstacles, {physics.substeps} substeps per control step")
    print(f"  control steps per second  {step_rate:10.0f}")


if __name__ == "__main__":
    main()
