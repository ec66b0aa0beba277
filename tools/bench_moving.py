"""Benchmark observations among moving obstacles: 8 moving discs beside the same discs frozen.

    python tools/bench_moving.py [--repeats 200] [--blocks 7] [--robots 1 64 256] [--previous]

fixed20 with 8 discs of radius 0.5 that move back and forth across it, and the same world
with the discs standing where they start (so they are in the observation's static raster).
For each number of robots, µs per robot of one ``Observer.observe`` call for all of them (at
varied steps), frozen beside moving, and their ratio (aim ≤ 2). ``Observer.observe`` is the
one implementation of both the environments' observations and ``eval``'s (the DQN planner's).
Frozen and moving are timed in alternating blocks; each figure is the median of its blocks.
A third column times moving discs through the numpy implementation that the compiled loops of
``Observer._add_moving`` and ``Observer._add_near`` replaced (kept in
``tests/test_moving_observation.py``, which checks that both add the same terms): before and
after in one run.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import statistics
import time
from pathlib import Path

import numpy as np

from apf_physics.sensing.observation import Observer, ObserverConfig
from bench_env import moving_world   # the same worlds as bench_env's moving-obstacle rows (this folder)


def numpy_add_moving():
    """The numpy implementation of ``Observer._add_moving`` and ``_add_near`` of 2026-11-25 (from
    the test that keeps it)."""
    path = Path(__file__).resolve().parent.parent / "tests" / "test_moving_observation.py"
    spec = importlib.util.spec_from_file_location("test_moving_observation", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return functools.partial(module.reference_add_moving, add_near=module.numpy_add_near)


class Case:
    """An observer of ``robots`` robots at random free positions of ``world``, at varied steps."""

    def __init__(self, world, robots: int, config: ObserverConfig, add_moving=None):
        self.observer = Observer(config, robots, [world])
        if add_moving is not None:
            self.observer._add_moving = functools.partial(add_moving, self.observer)
        rng = np.random.default_rng(1)
        self.positions = world.random_free_positions(rng, robots)
        self.observer.reset(np.arange(robots), self.positions, [world] * robots)
        self.steps = rng.integers(0, 100, robots).astype(float)
        self.robots = robots
        self.observer.observe(self.positions, t=self.steps)   # warm up (rasters built)

    def time(self, repeats: int) -> float:
        """µs per robot of one observe call for all robots."""
        t = time.perf_counter()
        for k in range(repeats):
            self.observer.observe(self.positions, t=self.steps + k)
        return (time.perf_counter() - t) / (repeats * self.robots) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200, help="calls per block")
    parser.add_argument("--blocks", type=int, default=7)
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 64, 256])
    parser.add_argument("--previous", action="store_true",
                        help="with the 'previous' channel (the field a step earlier)")
    args = parser.parse_args()
    config = ObserverConfig(channels=("potential", "previous") if args.previous else ("potential",))
    frozen_world, moving_world_ = moving_world(True), moving_world(False)
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    print(f"observations in fixed20 with 8 discs, channels {config.channels} "
          f"(median of {args.blocks} alternating blocks)")
    before_add_moving = numpy_add_moving()
    print(f"  {'robots':>6} {'frozen us/robot':>16} {'moving us/robot':>16} {'moving / frozen':>16} "
          f"{'before: moving':>15} {'before / frozen':>16}")
    for n in args.robots:
        frozen, moving = Case(frozen_world, n, config), Case(moving_world_, n, config)
        before = Case(moving_world_, n, config, before_add_moving)
        repeats = max(20, args.repeats * 64 // max(n, 64))
        f, m, b = [], [], []
        for _ in range(args.blocks):
            f.append(frozen.time(repeats))
            m.append(moving.time(repeats))
            b.append(before.time(repeats))
        f, m, b = statistics.median(f), statistics.median(m), statistics.median(b)
        print(f"  {n:>6} {f:>16.2f} {m:>16.2f} {m / f:>15.2f}x {b:>15.2f} {b / f:>15.2f}x   (aim <= 2)")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
