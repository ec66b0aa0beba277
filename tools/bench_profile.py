"""Where a step's time goes: the vector env (and one robot through ``gymnasium.make``), by part.

    python tools/bench_profile.py [--sizes 1 1024] [--steps 300]

For each N, ``NavigateVectorEnv`` on fixed20 (random starts and actions; N = 1 is
``apf_physics/Navigate-v0`` through ``gymnasium.make``, wrappers included) is stepped under
cProfile, and every function's own time is put in one part by where it lives:

- chipmunk: pymunk's ``Space.step`` (the solver, collision detection);
- pymunk's batched I/O and bookkeeping: the rest of pymunk;
- the rest of the physics: our free-move test, free moves, proxies, settling, contacts, placement;
- observation: windows of the potential (OpenCV's remap included), the memory, lidar;
- episode rules and reward: the stepper, the reward's terms;
- the environment and task: actions to commands, starts, info, autoreset;
- numpy and Python: what is left (array calls made by any of the above, builtins);
- the wrappers (N = 1): Gymnasium's.

Run it in two checkouts (``cd OTHER && python /path/to/tools/bench_profile.py``) for a before and
after: the parts are found by file name, so both layouts are read. The profiler adds its own cost
to each call: compare parts, not totals with unprofiled figures.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import gymnasium as gym
import numpy as np

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics.envs import NavigateVectorEnv

PARTS = [
    ("chipmunk (Space.step)", ("cpSpaceStep",)),
    ("pymunk: batched I/O, bookkeeping", ("pymunk", "_cffi_backend", "cpSpace")),
    ("observation", ("observation.py", "sensing/", "lidar.py", "remap", "field.py", "transforms.py")),
    ("episode rules, reward", ("engine.py", "reward.py")),
    ("physics (ours)", ("physics.py", "sim/", "sweep.py", "contacts.py", "tiles.py", "compiled.py")),
    ("environment, task, starts", ("envs/", "kinematics.py", "world.py", "world/", "actions.py")),
    ("wrappers (Gymnasium)", ("gymnasium",)),
]


def part_of(filename: str, function: str) -> str:
    where = f"{filename}:{function}"
    for name, needles in PARTS:
        if any(n in where for n in needles):
            return name
    return "numpy, Python"


def profile(n: int, steps: int) -> tuple[dict[str, float], float]:
    """Seconds per robot-step of each part (profiled) and the step's total, at N = ``n``."""
    rng = np.random.default_rng(0)
    if n == 1:
        env = gym.make("apf_physics/Navigate-v0", world="fixed20", starts="random")
        env.reset(seed=0)

        def run(k):
            for a in rng.integers(0, 9, k).tolist():
                _, _, te, tr, _ = env.step(a)
                if te or tr:
                    env.reset()
        steps *= 20
    else:
        vec = NavigateVectorEnv(world="fixed20", num_envs=n, starts="random")
        vec.reset(seed=0)

        def run(k):
            for _ in range(k):
                vec.step(rng.integers(0, 9, n))
    run(max(10, steps // 10))   # warm up: rasters, compiled loops
    profiler = cProfile.Profile()
    t = time.perf_counter()
    profiler.runcall(run, steps)
    total = time.perf_counter() - t
    parts: dict[str, float] = {}
    for (filename, _, function), (_, _, own, _, _) in pstats.Stats(profiler).stats.items():
        name = part_of(filename, function)
        parts[name] = parts.get(name, 0.0) + own
    return {k: v / (steps * n) for k, v in parts.items()}, total / (steps * n)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 1024])
    parser.add_argument("--steps", type=int, default=300, help="vector steps (N = 1: 20 times as many)")
    args = parser.parse_args()
    for n in args.sizes:
        parts, total = profile(n, args.steps)
        whole = sum(parts.values())
        print(f"N = {n}: {total * 1e6:.2f} us per robot-step under the profiler")
        for name, seconds in sorted(parts.items(), key=lambda kv: -kv[1]):
            print(f"  {name:36s} {seconds * 1e6:8.2f} us  {seconds / whole:6.1%}")


if __name__ == "__main__":
    main()
