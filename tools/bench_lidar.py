"""Benchmark the range sensor (``apf_physics.sensing.lidar``) beside the window observation, per robot-step.

    python tools/bench_lidar.py [--robots 256 [1024 ...]] [--beams 64] [--repeats 20] [--blocks 7]
                                [--worlds fixed20 moving8 ros_arena] [--baseline REV]

For each number of robots and each world, that many robots at random free poses (at varied
steps, as the slots of a vector env are) and, timed in alternating blocks in the same run:

- ``lidar``: one :func:`~apf_physics.sensing.lidar.scan` of ``--beams`` beams over 360° (range 8) for
  all robots;
- ``window``: one ``Observer.observe`` of the default 11 × 11 potential window for all of them
  (the environments' observation today);
- with ``--baseline REV``: the same scan by ``apf_physics/sensing/lidar.py`` as it was at git revision
  ``REV`` (loaded beside today's; its ranges are checked equal), and the speed-up, baseline
  over today's lidar (wall clock).

Each figure is the median over blocks of µs per robot-step (one call for all robots divided by
their number), by the wall clock and by CPU time; the ratio is lidar over window (wall clock).
Worlds: ``fixed20``; ``moving8``, fixed20 with 8 discs of radius 0.5 moving back and forth
across it (as ``tools/bench_moving.py``); ``ros_arena``, an occupancy-grid map (many segments:
each robot casts only against those within range and facing it). ``segments`` counts the static
segments (the map's edge is cast in closed form, apart). The machine's load is printed: a core
taken by another job slows all columns alike, so compare the ratios.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import apf_physics
from apf_physics.sensing.lidar import LidarConfig, scan, static_geometry
from apf_physics.world.obstacles import CircleObstacle, Motion
from apf_physics.sensing.observation import Observer, ObserverConfig


def moving8():
    """fixed20 with 8 discs moving back and forth across it."""
    base = apf_physics.load_world("fixed20")
    rng = np.random.default_rng(0)
    discs = []
    for k in range(8):
        centre = np.array([2.0 + 2.0 * k, rng.uniform(3, 6)])
        discs.append(CircleObstacle(centre, 0.5, Motion(np.array([[0.0, 10.0]]), float(rng.uniform(0.15, 0.6)),
                                                        phase=float(rng.uniform(0, 10)))))
    return dataclasses.replace(base, name="moving8", obstacles=base.obstacles + tuple(discs))


def world_named(name: str):
    return moving8() if name == "moving8" else apf_physics.load_world(name)


def baseline_scan(rev: str):
    """``scan`` of ``apf_physics/sensing/lidar.py`` at git revision ``rev``, loaded as a module of its own."""
    root = Path(__file__).resolve().parents[1]
    source = subprocess.run(["git", "show", f"{rev}:apf_physics/sensing/lidar.py"], cwd=root, check=True,
                            capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "lidar_baseline.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("lidar_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module                   # (its dataclasses look their module up)
    spec.loader.exec_module(module)
    return module.scan


def block(fn, repeats: int, robots: int) -> tuple[float, float]:
    """(wall, CPU) µs per robot-step of ``repeats`` calls for ``robots`` robots."""
    t, c = time.perf_counter(), time.process_time()
    for k in range(repeats):
        fn(k)
    scale = 1e6 / (repeats * robots)
    return (time.perf_counter() - t) * scale, (time.process_time() - c) * scale


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[256])
    parser.add_argument("--beams", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=20, help="calls per block")
    parser.add_argument("--blocks", type=int, default=7)
    parser.add_argument("--worlds", nargs="+", default=["fixed20", "moving8", "ros_arena"])
    parser.add_argument("--baseline", help="git revision whose lidar.py to time beside today's")
    args = parser.parse_args()
    before = baseline_scan(args.baseline) if args.baseline else None
    config = LidarConfig(beams=args.beams)
    for n in args.robots:
        one, five, _ = os.getloadavg()
        print(f"N = {n} robots, K = {args.beams} beams over 360°, range 8; median of {args.blocks} blocks "
              f"of {args.repeats} calls; load {one:.2f} (5 min {five:.2f}) on {os.cpu_count()} cores")
        print("µs per robot-step, wall clock (CPU time)")
        print(f"{'world':<12}{'segments':>9}{'moving':>8}{'lidar':>16}{'window':>16}{'ratio':>8}"
              + (f"{'baseline':>16}{'speed-up':>10}" if before else ""))
        for name in args.worlds:
            world = world_named(name)
            rng = np.random.default_rng(1)
            poses = np.column_stack([world.random_free_positions(rng, n), rng.uniform(-np.pi, np.pi, n)])
            steps = rng.integers(0, 100, n).astype(float)
            observer = Observer(ObserverConfig(), n, [world])
            observer.reset(np.arange(n), poses[:, :2], [world] * n)
            ranges = scan(world, poses, config, t=steps)              # warm up: segments built, rasters built
            observer.observe(poses[:, :2], t=steps)
            timed = {"lidar": lambda k: scan(world, poses, config, t=steps + k),
                     "window": lambda k: observer.observe(poses[:, :2], t=steps + k)}
            if before:
                assert np.abs(before(world, poses, config, t=steps) - ranges).max() <= 1e-9
                timed["baseline"] = lambda k: before(world, poses, config, t=steps + k)
            times = {key: [] for key in timed}
            for _ in range(args.blocks):
                for key, fn in timed.items():
                    times[key].append(block(fn, args.repeats, n))
            med = {key: [statistics.median(column) for column in zip(*rows)] for key, rows in times.items()}
            cell = {key: f"{wall:.1f} ({cpu:.1f})" for key, (wall, cpu) in med.items()}
            line = (f"{name:<12}{len(static_geometry(world).a):>9}{len(world.moving):>8}{cell['lidar']:>16}"
                    f"{cell['window']:>16}{med['lidar'][0] / med['window'][0]:>8.2f}")
            if before:
                line += f"{cell['baseline']:>16}{med['baseline'][0] / med['lidar'][0]:>10.2f}"
            print(line)
        print()


if __name__ == "__main__":
    main()
