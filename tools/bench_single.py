"""Benchmark one robot: a ``Navigate-v0`` step beside a ``CartPole-v1`` step, in one process.

    python tools/bench_single.py [--steps 20000] [--blocks 10] [--profile]

Both through ``gymnasium.make`` (wrappers included), random actions, an episode reset when
one ends (resets included in the time). The two are timed in alternating blocks of
``steps / blocks`` steps, so that a change of the machine's load hits both alike; the
figure of each is the median over its blocks, and the ratio is theirs (aim ≤ 5).

Then where a Navigate step goes: the same steps again with the physics call
(``Physics.step``), the observation (``Observer.observe``) and the reward's terms timed
apart (per call, with ``time.perf_counter``), and the share of steps that went through
pymunk. ``--profile`` adds a cProfile of the Navigate steps (top 25 by own time).
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


def make(env_id: str):
    kwargs = {"world": "fixed20"} if env_id.startswith("apf_physics") else {}
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    return env


def run(env, actions: np.ndarray) -> float:
    """Seconds for ``len(actions)`` steps (resetting when an episode ends)."""
    t = time.perf_counter()
    for a in actions.tolist():
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - t


def side_by_side(steps: int, blocks: int) -> tuple[float, float]:
    """Median µs per step of CartPole-v1 and of Navigate-v0, timed in alternating blocks."""
    cart, nav = make("CartPole-v1"), make("apf_physics/Navigate-v0")
    rng = np.random.default_rng(0)
    per = max(1, steps // blocks)
    run(cart, rng.integers(0, 2, 500))   # warm up
    run(nav, rng.integers(0, 9, 500))
    c, n = [], []
    for _ in range(blocks):
        c.append(run(cart, rng.integers(0, 2, per)) / per * 1e6)
        n.append(run(nav, rng.integers(0, 9, per)) / per * 1e6)
    return statistics.median(c), statistics.median(n)


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
    task = env.unwrapped._task
    physics, observer = task.stepper.physics, task.observer
    import apf_physics.envs.task as task_module
    actions = np.random.default_rng(1).integers(0, 9, steps)
    run(env, actions[:500])
    phys, obs, rew = [], [], []
    simulated = [0]
    step = physics.step

    def counting(*args, **kwargs):
        out = step(*args, **kwargs)
        simulated[0] += physics._proxy_held
        return out
    physics.step = counting
    try:
        with timed(physics, "step", phys), timed(observer, "observe", obs), timed(task_module, "reward_terms", rew):
            total = run(env, actions)
    finally:
        del physics.step
    parts = {"Physics.step (free moves and pymunk)": sum(phys), "Observer.observe": sum(obs),
             "reward_terms": sum(rew)}
    print(f"where a Navigate step goes ({steps} steps, per-call timers add a little to each part):")
    print(f"  {'whole step':38s} {total / steps * 1e6:7.1f} us")
    for name, seconds in parts.items():
        print(f"  {name:38s} {seconds / steps * 1e6:7.1f} us  {seconds / total:5.1%}")
    rest = total - sum(parts.values())
    print(f"  {'the rest (env, task, stepper, wrappers)':38s} {rest / steps * 1e6:7.1f} us  {rest / total:5.1%}")
    print(f"  steps through pymunk: {simulated[0] / steps:.1%}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--blocks", type=int, default=10)
    parser.add_argument("--profile", action="store_true", help="also cProfile the Navigate steps")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    cart, nav = side_by_side(args.steps, args.blocks)
    print(f"single environment, random actions, through gymnasium.make (median of {args.blocks} alternating blocks)")
    print(f"  CartPole-v1               {cart:7.1f} us/step")
    print(f"  apf_physics/Navigate-v0   {nav:7.1f} us/step")
    print(f"  a Navigate step costs     {nav / cart:7.1f} x a CartPole step (aim <= 5)")
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
