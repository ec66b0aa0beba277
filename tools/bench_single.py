"""Benchmark one robot: a ``Navigate-v0`` step beside a ``CartPole-v1`` step, in one process.

    python tools/bench_single.py [--steps 20000] [--blocks 10] [--profile]

All through ``gymnasium.make`` (wrappers included), random actions, an episode reset when one
ends (resets included in the time). They are timed in alternating blocks of ``steps /
blocks`` steps, so that a change of the machine's load hits all alike; the figure of each is
the median over its blocks, and the ratio the median of each block's ratio to the CartPole
block beside it (aim ≤ 5); the fastest block of each is printed too (on a loaded machine it is
the one the scheduler took least from). Each figure is given by the wall clock and by the
thread's CPU time. A third steps it with ``Physics.step`` and ``Observer.observe`` stubbed
(nobody moves, nothing touches): the step's own part, the env, task, stepper and wrappers.

Then where a Navigate step goes: the same steps again with the physics call
(``Physics.step``, its free-move test apart (``FreeMoveTest.step``), and steps with and without pymunk apart), the
observation of the steps (``Observer.observe``) and the resets (``env.reset`` through the
wrappers, their observation included; ``NavigationTask.start`` apart) timed apart (per call,
with ``time.perf_counter``). ``--profile`` adds a cProfile of the Navigate steps (top 25 by own time).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import statistics
import time
from contextlib import contextmanager

import gymnasium as gym
import numpy as np

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics.sim.contacts import ContactLog


def make(env_id: str):
    kwargs = {"world": "fixed20"} if env_id.startswith("apf_physics") else {}
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    return env


def run(env, actions: np.ndarray) -> tuple[float, float]:
    """Seconds for ``len(actions)`` steps (resetting when an episode ends): by the wall clock, and
    by this thread's CPU time (what a loaded machine's scheduler takes away is not in it)."""
    t, c = time.perf_counter(), time.thread_time()
    for a in actions.tolist():
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - t, time.thread_time() - c


def stubbed(env):
    """``env`` with ``Physics.step`` and ``Observer.observe`` replaced by stubs (nothing touched,
    nobody moves; the window of the start): what is left of a step is the env's, the task's, the
    stepper's and the wrappers' own part (episodes run to the step limit, 100 steps)."""
    task = env.unwrapped.task
    nothing = ContactLog.nothing(task.stepper.physics.num_robots)
    window = task.observer.observe(task.stepper.positions[:, 0], None, task.stepper.steps)
    task.stepper.physics.step = lambda velocities, active=None: nothing
    task.observer.observe = lambda positions, robots=None, t=0.0, discs=None: window.copy()
    return env


def side_by_side(steps: int, blocks: int) -> dict[str, tuple[float, float]]:
    """Median µs per step (wall clock, CPU time) of CartPole-v1, of Navigate-v0, and of Navigate-v0
    with the physics and the observation stubbed, timed in alternating blocks; the Navigate-v0
    take the same actions."""
    envs = {"CartPole-v1": make("CartPole-v1"), "Navigate-v0": make("apf_physics/Navigate-v0"),
            "own part": stubbed(make("apf_physics/Navigate-v0"))}
    rng = np.random.default_rng(0)
    per = max(1, steps // blocks)
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in envs}
    for block in range(blocks + 1):   # block 0 warms up
        moves = rng.integers(0, 9, per)
        for name, env in envs.items():
            wall, cpu = run(env, rng.integers(0, 2, per) if name == "CartPole-v1" else moves)
            if block:
                times[name].append((wall / per * 1e6, cpu / per * 1e6))
    out = {}
    cart = times["CartPole-v1"]
    for name, values in times.items():
        wall, cpu = [w for w, _ in values], [c for _, c in values]
        ratio = [w / c for (w, _), (c, _) in zip(values, cart)]   # per block: what the load did to both
        ratio_cpu = [w / c for (_, w), (_, c) in zip(values, cart)]
        out[name] = (statistics.median(wall), statistics.median(cpu),
                     statistics.median(ratio), statistics.median(ratio_cpu))
        print(f"  blocks of {name}: median {out[name][0]:.1f} (CPU {out[name][1]:.1f}), fastest {min(wall):.1f} "
              f"(CPU {min(cpu):.1f}) us/step" + ("" if name == "CartPole-v1" else
                                                  f"; x CartPole's block: median {out[name][2]:.1f}, "
                                                  f"{min(ratio):.1f} to {max(ratio):.1f}"))
    return out


@contextmanager
def timed(obj, name: str, into: list):
    """Time every call of ``obj.name`` into ``into`` (seconds), for the duration of the block."""
    original = getattr(obj, name)
    own = name in vars(obj)   # an attribute of the object itself (not of its class)

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        out = original(*args, **kwargs)
        into.append(time.perf_counter() - t)
        return out
    setattr(obj, name, wrapper)
    try:
        yield
    finally:
        if own:
            setattr(obj, name, original)
        else:
            delattr(obj, name)


def breakdown(steps: int) -> None:
    env = make("apf_physics/Navigate-v0")
    task = env.unwrapped.task
    physics, observer = task.stepper.physics, task.observer
    actions = np.random.default_rng(1).integers(0, 9, steps)
    run(env, actions[:500])   # warm up
    free, simulated, test, obs, starts, resets, reset_obs = [], [], [], [], [], [], []
    step = physics.step

    def sorting(*args, **kwargs):   # physics steps with and without pymunk, apart
        t = time.perf_counter()
        out = step(*args, **kwargs)
        (simulated if physics.in_pymunk[0] else free).append(time.perf_counter() - t)
        return out
    reset = env.reset

    def resetting(*args, **kwargs):   # whole resets, and the observations made in them apart
        seen = len(obs)
        t = time.perf_counter()
        out = reset(*args, **kwargs)
        resets.append(time.perf_counter() - t)
        reset_obs.extend(obs[seen:])
        return out
    physics.step, env.reset = sorting, resetting
    try:
        with timed(physics.free, "step", test), \
                timed(observer, "observe", obs), timed(task, "start", starts):
            total, _ = run(env, actions)
    finally:
        del physics.step, env.reset
    phys = sum(free) + sum(simulated)
    parts = {"Physics.step, all": phys,
             "  of which the free-move test": sum(test),
             "Observer.observe (in steps)": sum(obs) - sum(reset_obs),
             "resets (env.reset, wrappers included)": sum(resets),
             "  of which NavigationTask.start": sum(starts)}
    print(f"where a Navigate step goes ({steps} steps, per-call timers add a little to each part):")
    print(f"  {'whole step (resets included)':40s} {total / steps * 1e6:7.1f} us")
    for name, seconds in parts.items():
        print(f"  {name:40s} {seconds / steps * 1e6:7.1f} us  {seconds / total:5.1%}")
    rest = total - phys - (sum(obs) - sum(reset_obs)) - sum(resets)
    print(f"  {'the rest (env, task, stepper, wrappers)':40s} {rest / steps * 1e6:7.1f} us  {rest / total:5.1%}")
    print(f"  episodes: {len(resets)}, {steps / max(len(resets), 1):.1f} steps each; a reset "
          f"{np.median(resets) * 1e6:.1f} us (median)")
    print(f"  physics steps without pymunk: {len(free) / steps:.1%} of steps, median {np.median(free) * 1e6:.1f} us")
    print(f"  physics steps through pymunk: {len(simulated) / steps:.1%} of steps, median "
          f"{np.median(simulated) * 1e6:.1f} us")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--blocks", type=int, default=10)
    parser.add_argument("--profile", action="store_true", help="also cProfile the Navigate steps")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    times = side_by_side(args.steps, args.blocks)
    (cart, cart_cpu, _, _), nav, own = times.values()
    print(f"single environment, random actions, through gymnasium.make (median of {args.blocks} alternating blocks; "
          f"wall clock, and CPU time; x CartPole: the median of the blocks' ratios to the CartPole block beside them)")
    print(f"  CartPole-v1                             {cart:7.1f} us/step (CPU {cart_cpu:6.1f})")
    for label, (wall, cpu, ratio, ratio_cpu) in (("apf_physics/Navigate-v0", nav),
                                                 ("own part: physics, observation stubbed", own)):
        aim = "; aim <= 5" if label.startswith("apf") else ""
        print(f"  {label:39s} {wall:7.1f} us/step (CPU {cpu:6.1f})   {ratio:5.1f} x CartPole (CPU {ratio_cpu:4.1f} x{aim})")
    breakdown(args.steps)
    if args.profile:
        env = make("apf_physics/Navigate-v0")
        actions = np.random.default_rng(2).integers(0, 9, args.steps)
        profiler = cProfile.Profile()
        profiler.runcall(run, env, actions)
        pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
