"""Where a step's time goes: the vector env (and one robot through ``gymnasium.make``), by part.

    python tools/bench_profile.py [--sizes 1 1024 single] [--steps 1000] [--top 8]
    python tools/bench_profile.py --trees BEFORE_CHECKOUT AFTER_CHECKOUT [--rounds 3]

For each size, ``NavigateVectorEnv`` on fixed20 with ``num_envs`` = N (random starts and
actions; the environment of BENCHMARKS' Environments table), or with ``single``
``apf_physics/Navigate-v0`` through ``gymnasium.make`` (wrappers included), is stepped first
without and then under cProfile (N = 1 and ``single``: 20 times as many steps; each after a
warm-up), and every function's own time (tottime) is put in one part by where it lives:

- pymunk: chipmunk's ``Space.step`` (the solver, collision detection);
- pymunk: batched reads and writes, bookkeeping (the rest of pymunk, cffi);
- the free-move pass: which robots' moves cannot touch anything, and their moves without pymunk
  (the swept-segment test against the static shapes, the robots that meet, the moves);
- the rest of the physics: proxies lent and released, settling, the contact log, placement;
- field and observation: windows of the potential (OpenCV's remap included), memory, lidar;
- episode rules and reward: the stepper, the reward's terms;
- environment, task, starts: actions to commands, episode starts and their placement, info,
  autoreset;
- numpy calls, Python builtins and standard library: made by any of the above (the glue's cost
  that is not in our own lines);
- Gymnasium's wrappers (``single``).

A compiled kernel (``common.compiled.kernel``) is reported by cProfile under its Python
function's name (numba calls the profiler's hooks), so it falls in its part; the kernels' share
of the step is printed apart, beside the share of the step spent in our own interpreted lines.
The way into a kernel (its Python wrapper, numba's own Python) is counted in its caller's part.
Also printed: how many times pymunk's ``Space.step`` ran per step (its substeps, in the steps
that needed pymunk), and with ``--top`` each part's costliest functions.

``--trees`` runs this script in each checkout in turn (``PYTHONPATH`` set to it; ``--rounds``
times, alternating, so that the machine's load hits both alike), takes each figure's median
and prints one Markdown table per size: a before and after. The script imports only what both
layouts have, and the parts are found by file and function names of either layout. The
profiler adds its own cost to every Python call: compare parts and shares; the step's time
without the profiler is printed beside.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import statistics
import subprocess
import sys
import time

import numpy as np

PYMUNK_STEP = "chipmunk: Space.step (solver, collisions)"
PYMUNK_IO = "pymunk: batched reads and writes, bookkeeping"
FREE_MOVE = "free-move pass (test and moves)"
PHYSICS = "rest of the physics (proxies, settling, contact log, placement)"
OBSERVATION = "field and observation"
RULES = "episode rules, reward"
ENV = "environment, task, starts"
GLUE = "numpy calls, Python builtins and standard library"
WRAPPERS = "Gymnasium wrappers"
OTHER = "other"
PARTS = [PYMUNK_STEP, PYMUNK_IO, FREE_MOVE, PHYSICS, OBSERVATION, RULES, ENV, GLUE, WRAPPERS, OTHER]

PHYSICS_FILES = ("/sim/", "/physics.py", "/sweep.py", "/contacts.py", "/tiles.py", "/spatial.py")
"""The physics' modules in either layout (``sim/`` now; ``physics.py``, ``sweep.py``... at the top before)."""

FREE_MOVE_FUNCTIONS = {
    "needs_physics", "_near_movers", "_move_free", "_free_moves", "_closest_approach",
    "_segment_point_distance", "_may_touch", "_close_under_touch", "may_touch", "close_under_touch",
}
"""The free-move pass's functions in ``physics.py`` before it had a module of its own (``sim/freemove.py``)."""

OBSERVATION_FILES = ("/observation.py", "/sensing/", "/lidar.py", "/field.py", "/transforms.py", "/mapview.py")
RULES_FILES = ("/engine.py", "/reward.py")
ENV_FILES = ("/envs/", "/world.py", "/world/", "/kinematics.py", "/actions.py", "/common/geometry.py",
             "/geometry.py")


def part_of(filename: str, function: str) -> str:
    """The part of a step that a function (cProfile's file name and function name) belongs to."""
    filename = filename.replace("\\", "/")
    builtin = filename == "~"   # a C function: cProfile names it by its module and name only
    if builtin and "cpSpaceStep" in function:
        return PYMUNK_STEP
    if "/pymunk/" in filename or (builtin and ("pymunk" in function or "_cffi_backend" in function)):
        return PYMUNK_IO
    if builtin and "remap" in function:
        return OBSERVATION
    if "/apf_physics/" in filename:
        if any(f in filename for f in RULES_FILES):
            return RULES
        if any(f in filename for f in PHYSICS_FILES):
            if "settle" in function or "settle" in filename:
                return PHYSICS
            if filename.endswith(("/freemove.py", "/swept.py", "/sweep.py")) or function in FREE_MOVE_FUNCTIONS:
                return FREE_MOVE
            return PHYSICS
        if any(f in filename for f in OBSERVATION_FILES):
            return OBSERVATION
        if any(f in filename for f in ENV_FILES):
            return ENV
        return OTHER
    if "/gymnasium/" in filename:
        return WRAPPERS
    return GLUE


def callers_calls(callers: dict) -> int:
    """How many times a function was called (the sum over its callers)."""
    return sum(edge[0] for edge in callers.values())


def calls_kernel(filename: str, function: str) -> bool:
    """Whether a function is the way into a compiled kernel: its Python wrapper
    (``compiled.kernel``'s ``call``) or numba's own Python on the way in."""
    filename = filename.replace("\\", "/")
    return (filename.endswith("/compiled.py") and function == "call") or "/numba/" in filename


def kernel_codes() -> set[tuple[str, int, str]]:
    """cProfile's keys of the compiled kernels in the loaded ``apf_physics`` modules (either layout)."""
    codes = set()
    for name, module in list(sys.modules.items()):
        if not name.startswith("apf_physics") or module is None:
            continue
        for value in vars(module).values():
            if callable(value) and hasattr(value, "compile_") and hasattr(value, "py_func"):
                code = value.py_func.__code__
                codes.add((code.co_filename, code.co_firstlineno, code.co_name))
    return codes


def stepper(size: str, steps: int):
    """``run(k)``, which takes ``k`` random steps, and the robots a step moves."""
    import gymnasium as gym

    import apf_physics  # noqa: F401  (registers the ids)
    from apf_physics.envs import NavigateVectorEnv

    rng = np.random.default_rng(0)
    if size == "single":
        env = gym.make("apf_physics/Navigate-v0", world="fixed20", starts="random")
        env.reset(seed=0)

        def run(k):
            for a in rng.integers(0, 9, k).tolist():
                _, _, terminated, truncated, _ = env.step(a)
                if terminated or truncated:
                    env.reset()
        return run, 1
    n = int(size)
    vec = NavigateVectorEnv(world="fixed20", num_envs=n, starts="random")
    vec.reset(seed=0)

    def run(k):
        for _ in range(k):
            vec.step(rng.integers(0, 9, n))
    return run, n


def profile(size: str, steps: int) -> dict:
    """Seconds per robot-step of each part (under the profiler), of the compiled kernels and of our
    own lines, and of the whole step with and without the profiler."""
    if size in ("single", "1"):
        steps *= 20
    run, n = stepper(size, steps)
    run(max(200, steps // 5))   # warm up: rasters, compiled kernels (from numba's cache or compiled now)
    t, cpu = time.perf_counter(), time.process_time()
    run(steps)
    plain, plain_cpu = time.perf_counter() - t, time.process_time() - cpu
    profiler = cProfile.Profile()
    t = time.perf_counter()
    profiler.runcall(run, steps)
    profiled = time.perf_counter() - t
    kernels = kernel_codes()
    parts = dict.fromkeys(PARTS, 0.0)
    functions: dict[str, float] = {}   # "part | file:function" -> its own seconds
    compiled = ours = space_steps = 0.0
    loop = (run.__code__.co_filename, run.__code__.co_firstlineno, run.__code__.co_name)
    for key, (_, _, own, _, callers) in pstats.Stats(profiler).stats.items():
        filename, _, function = key
        if key == loop:
            continue
        if calls_kernel(filename, function):   # its caller's cost of calling a kernel
            for (caller_file, _, caller_function), edge in callers.items():
                part = part_of(caller_file, caller_function)
                parts[part] += edge[2]
                where = f"{part} | calling kernels from {short(caller_file)}:{caller_function}"
                functions[where] = functions.get(where, 0.0) + edge[2]
            continue
        own -= callers[loop][2] if loop in callers else 0.0   # this script's loop: drawing the random actions
        part = part_of(filename, function)
        parts[part] += own
        if part == PYMUNK_STEP:
            space_steps += callers_calls(callers)
        where = f"{part} | {short(filename)}:{function}"
        functions[where] = functions.get(where, 0.0) + own
        if key in kernels:
            compiled += own
        elif "/apf_physics/" in filename.replace("\\", "/"):
            ours += own
    robot_steps = steps * n
    return {
        "parts": {k: v / robot_steps for k, v in parts.items()},
        "functions": {k: v / robot_steps for k, v in functions.items()},
        "compiled": compiled / robot_steps,
        "ours": ours / robot_steps,
        "profiled": profiled / robot_steps,
        "plain": plain / robot_steps,
        "plain_cpu": plain_cpu / robot_steps,
        "space_steps": space_steps / steps,
        "steps": steps,
        "robots": n,
    }


def short(filename: str) -> str:
    """A file name from the package (or the site-packages) down."""
    filename = filename.replace("\\", "/")
    for root in ("/apf_physics/", "/site-packages/"):
        if root in filename:
            return filename.split(root, 1)[1] if root == "/site-packages/" else "apf_physics/" + filename.split(root, 1)[1]
    return filename


def print_one(size: str, result: dict, top: int) -> None:
    parts = result["parts"]
    whole = sum(parts.values())
    label = "one robot through gymnasium.make" if size == "single" else f"N = {size}"
    print(f"{label}: {result['plain'] * 1e6:.2f} us per robot-step ({result['plain_cpu'] * 1e6:.2f} of CPU time), "
          f"{result['profiled'] * 1e6:.2f} under the profiler ({result['steps']} steps; "
          f"pymunk's Space.step called {result['space_steps']:.2f} times a step)")
    for name, seconds in sorted(parts.items(), key=lambda kv: -kv[1]):
        if seconds:
            print(f"  {name:66s} {seconds * 1e6:8.3f} us  {seconds / whole:6.1%}")
            mine = sorted(((k.split(" | ", 1)[1], v) for k, v in result["functions"].items()
                           if k.startswith(name + " | ")), key=lambda kv: -kv[1])
            for where, own in mine[:top]:
                print(f"      {where:62s} {own * 1e6:8.3f} us  {own / whole:6.1%}")
    print(f"  {'of the whole: in compiled kernels':66s} {result['compiled'] * 1e6:8.3f} us  "
          f"{result['compiled'] / whole:6.1%}")
    print(f"  {'of the whole: in our own interpreted lines':66s} {result['ours'] * 1e6:8.3f} us  "
          f"{result['ours'] / whole:6.1%}")


def run_tree(tree: str, sizes: list[str], steps: int) -> dict:
    """This script's results in the checkout ``tree`` (a child process, ``PYTHONPATH`` = ``tree``)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (tree, os.environ.get("PYTHONPATH")) if p))
    child = subprocess.run([sys.executable, os.path.abspath(__file__), "--json", "--steps", str(steps),
                            "--sizes", *sizes], env=env, cwd=tree, check=False, capture_output=True, text=True)
    if child.returncode:
        sys.exit(f"{tree}: this script failed there (exit status {child.returncode}):\n{child.stderr[-2000:]}")
    result = json.loads(child.stdout)
    if not os.path.realpath(result["package"]).startswith(os.path.realpath(tree) + os.sep):
        sys.exit(f"{tree}: imported apf_physics from {result['package']}, not from this checkout")
    return result


def median(results: list[dict], size: str) -> dict:
    runs = [r["sizes"][size] for r in results]
    keys = ("compiled", "ours", "profiled", "plain", "plain_cpu", "space_steps")
    out = {k: statistics.median(r[k] for r in runs) for k in keys}
    out["parts"] = {p: statistics.median(r["parts"][p] for r in runs) for p in PARTS}
    out["fastest"] = min(r["plain"] for r in runs)
    return out


def print_comparison(trees: list[str], labels: list[str], results: dict[str, list[dict]], size: str) -> None:
    before, after = (median(results[t], size) for t in trees)
    whole = [sum(r["parts"].values()) for r in (before, after)]
    title = "one robot through `gymnasium.make`" if size == "single" else f"N = {size}"
    print(f"\n{title} (medians of {len(results[trees[0]])} runs each)\n")
    print(f"| part | {labels[0]} % | {labels[1]} % | {labels[0]} µs/robot-step | {labels[1]} µs/robot-step |")
    print("|---|---|---|---|---|")
    rows = sorted((p for p in PARTS if before["parts"][p] / whole[0] >= 5e-4 or after["parts"][p] / whole[1] >= 5e-4),
                  key=lambda p: -(before["parts"][p] / whole[0] + after["parts"][p] / whole[1]))
    for p in rows:
        b, a = before["parts"][p], after["parts"][p]
        print(f"| {p} | {b / whole[0]:.1%} | {a / whole[1]:.1%} | {b * 1e6:.3g} | {a * 1e6:.3g} |")
    print(f"| the whole step, under the profiler | 100 % | 100 % | {whole[0] * 1e6:.3g} | {whole[1] * 1e6:.3g} |")
    print(f"| the whole step, without the profiler (median; fastest run) | | | {before['plain'] * 1e6:.3g}; "
          f"{before['fastest'] * 1e6:.3g} | {after['plain'] * 1e6:.3g}; {after['fastest'] * 1e6:.3g} |")
    print(f"| the whole step, without the profiler, CPU time | | | {before['plain_cpu'] * 1e6:.3g} | "
          f"{after['plain_cpu'] * 1e6:.3g} |")
    for key, what in (("compiled", "of the whole: in compiled kernels"), ("ours", "of the whole: our own interpreted lines")):
        b, a = before[key], after[key]
        print(f"| {what} | {b / whole[0]:.1%} | {a / whole[1]:.1%} | {b * 1e6:.3g} | {a * 1e6:.3g} |")
    print(f"\npymunk's Space.step calls per step (substeps of the steps that need pymunk): "
          f"{labels[0]} {before['space_steps']:.2f}, {labels[1]} {after['space_steps']:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["1", "1024", "single"],
                        help="robots per vector step, or 'single' (Navigate-v0 through gymnasium.make)")
    parser.add_argument("--steps", type=int, default=1000, help="vector steps (N = 1 and single: 20 times as many)")
    parser.add_argument("--trees", nargs=2, metavar=("BEFORE", "AFTER"),
                        help="run in these two checkouts in turn and print them side by side")
    parser.add_argument("--rounds", type=int, default=3, help="with --trees: runs in each checkout, alternating")
    parser.add_argument("--top", type=int, default=0, help="also list each part's TOP functions by own time")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    for size in args.sizes:
        if size != "single" and not (size.isdigit() and int(size) > 0):
            parser.error(f"--sizes: {size!r} is neither a positive number of robots nor 'single'")
    if args.trees:
        trees = [os.path.abspath(t) for t in args.trees]
        labels = ["before", "after"]
        for tree, label in zip(trees, labels):
            head = subprocess.run(["git", "-C", tree, "rev-parse", "--short", "HEAD"], check=False,
                                  capture_output=True, text=True)
            print(f"{label}: {tree} ({head.stdout.strip() or 'not a git checkout'})")
        results: dict[str, list[dict]] = {t: [] for t in trees}
        for r in range(args.rounds):
            for tree in trees if r % 2 == 0 else trees[::-1]:
                results[tree].append(run_tree(tree, args.sizes, args.steps))
        for size in args.sizes:
            print_comparison(trees, labels, results, size)
        return
    import apf_physics

    out = {"package": apf_physics.__file__, "sizes": {size: profile(size, args.steps) for size in args.sizes}}
    if args.json:
        print(json.dumps(out))
        return
    print(f"apf_physics from {os.path.dirname(out['package'])}")
    for size, result in out["sizes"].items():
        print_one(size, result, args.top)


if __name__ == "__main__":
    main()
