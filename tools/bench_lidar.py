"""Benchmark the range sensor (``apf_physics.lidar``) beside the window observation, per robot-step.

    python tools/bench_lidar.py [--robots 256] [--beams 64] [--repeats 20] [--blocks 7] [--worlds fixed20 moving8 ros_arena]

For each world, ``--robots`` robots at random free poses (at varied steps, as the slots of a
vector env are) and, timed in alternating blocks in the same run:

- ``lidar``: one :func:`~apf_physics.lidar.scan` of ``--beams`` beams over 360° (range 8) for
  all robots;
- ``window``: one ``Observer.observe`` of the default 11 × 11 potential window for all of them
  (the environments' observation today).

Each figure is the median over blocks of µs per robot-step (one call for all robots divided by
their number), by the wall clock and by CPU time; the ratio is lidar over window (wall clock). Worlds: ``fixed20``; ``moving8``, fixed20 with 8 discs of radius 0.5 moving back
and forth across it (as ``tools/bench_moving.py``); ``ros_arena``, an occupancy-grid map (many
segments: each robot casts only against those within range). ``segments`` counts the static
segments (the map's edge is cast in closed form, apart). The machine's load is printed:
a core taken by another job slows both columns alike.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import numpy as np

import apf_physics
from apf_physics.lidar import LidarConfig, scan, static_geometry
from apf_physics.obstacles import CircleObstacle, Motion
from apf_physics.observation import Observer, ObserverConfig


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


def block(fn, repeats: int, robots: int) -> tuple[float, float]:
    """(wall, CPU) µs per robot-step of ``repeats`` calls for ``robots`` robots."""
    t, c = time.perf_counter(), time.process_time()
    for k in range(repeats):
        fn(k)
    scale = 1e6 / (repeats * robots)
    return (time.perf_counter() - t) * scale, (time.process_time() - c) * scale


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=256)
    parser.add_argument("--beams", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=20, help="calls per block")
    parser.add_argument("--blocks", type=int, default=7)
    parser.add_argument("--worlds", nargs="+", default=["fixed20", "moving8", "ros_arena"])
    args = parser.parse_args()
    one, five, _ = os.getloadavg()
    print(f"N = {args.robots} robots, K = {args.beams} beams over 360°, range 8; median of {args.blocks} blocks "
          f"of {args.repeats} calls; load {one:.2f} (5 min {five:.2f}) on {os.cpu_count()} cores")
    print("µs per robot-step, wall clock (CPU time)")
    print(f"{'world':<12}{'segments':>9}{'moving':>8}{'lidar':>16}{'window':>16}{'ratio':>8}")
    config = LidarConfig(beams=args.beams)
    for name in args.worlds:
        world = world_named(name)
        rng = np.random.default_rng(1)
        n = args.robots
        poses = np.column_stack([world.random_free_positions(rng, n), rng.uniform(-np.pi, np.pi, n)])
        steps = rng.integers(0, 100, n).astype(float)
        observer = Observer(ObserverConfig(), n, [world])
        observer.reset(np.arange(n), poses[:, :2], [world] * n)
        scan(world, poses, config, t=steps)                       # warm up: segments built, rasters built
        observer.observe(poses[:, :2], t=steps)
        lidar_times, window_times = [], []
        for _ in range(args.blocks):
            lidar_times.append(block(lambda k: scan(world, poses, config, t=steps + k), args.repeats, n))
            window_times.append(block(lambda k: observer.observe(poses[:, :2], t=steps + k), args.repeats, n))
        lid = [statistics.median(column) for column in zip(*lidar_times)]
        win = [statistics.median(column) for column in zip(*window_times)]
        print(f"{name:<12}{len(static_geometry(world).a):>9}{len(world.moving):>8}"
              f"{f'{lid[0]:.1f} ({lid[1]:.1f})':>16}{f'{win[0]:.1f} ({win[1]:.1f})':>16}{lid[0] / win[0]:>8.2f}")


if __name__ == "__main__":
    main()
