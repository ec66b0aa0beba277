"""BARN as a benchmark: the challenge's worlds in 2-D, run through the physics, scored as the challenge does.

BARN (Perille et al., "Benchmarking Metric Ground Navigation", SSRR 2020) has 300 worlds of
cylinders; the ICRA BARN challenge's copy is in the public repository
``Daffan/nav-competition-icra2022`` (MIT), which you fetch yourself (nothing here downloads it,
and none of it is committed). ``--barn DIR`` is its root (or its ``jackal_helper/worlds/BARN``
folder): ``world_N.world`` and ``path_files/path_N.npy``.

Each world becomes a world file in metres (``--write-worlds DIR`` keeps them):

- every cylinder (static ``unit_cylinder`` models of radius 0.075 m, read by
  :mod:`apf_physics.world.io.sdfworld`) a ``circle``; the rows of touching cylinders along three sides are
  the challenge's walls, open to the north;
- the robot a disc of radius ``--radius`` (0.21 m: the Jackal is 0.508 × 0.430 m) moving
  ``--step`` metres per control step (default 0.15 m);
- start (-2, 3), goal (-2, 13) (``run.py``'s ``INIT_POSITION`` and ``GOAL_POSITION``), reached
  within 1 m of the goal as ``run.py`` decides; Table 4's field (``thesis-general``, in steps);
- the map: the smallest rectangle holding the cylinders, the start and the goal, with 1 m to
  spare on every side (Gazebo's ground goes on; our map's edge is a wall, kept out of the way).

**Score** (``run.py``): ``success × OT / clip(AT, 4·OT, 8·OT)``, ``OT`` the reference path's length
(its lattice points mapped by ``path_coord_to_gazebo_coord``, the start put first and the goal
last, as ``run.py`` does) over 2 m/s, the Jackal's top speed. ``AT``, the run's time: **one
control step takes ``step / 2`` seconds**, the time the Jackal needs for one step's travel at its
top speed (a diagonal move, √2 steps long, takes the same time: the holonomic robot is that much
faster along diagonals). The challenge's 100 s timeout is ``200 / step`` control steps. The
highest score is 0.25 (any run within 4·OT).

**Worlds**: ``--worlds dev`` are those whose index is divisible by 3 (0, 3, ..., 297: 100 worlds),
the only ones for development and validation; ``heldout`` the other 200, for judging; ``all``;
or indices such as ``0,3,6`` or ``0-30``.

Usage::

    python tools/barn.py --barn DIR --worlds dev --step 0.15 --planner dqn,astar \\
        [--kinematics unicycle] [--model M] [--json out.json] [--write-worlds DIR]
    python tools/barn.py --barn DIR --worlds dev --step 0.15,0.07,0.42 --kinematics holonomic,unicycle   # the table
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.errors import UserError  # noqa: E402
from apf_physics.experiments.evaluate import evaluate  # noqa: E402
from apf_physics.planners import make_planner  # noqa: E402
from apf_physics.common.safefile import check_writable, read_regular_file, write_text  # noqa: E402
from apf_physics.world.io.sdfworld import read_sdf_obstacles  # noqa: E402
from apf_physics.world.io.worldfile import world_from_dict  # noqa: E402

WORLDS = 300
"""BARN's worlds: ``world_0`` to ``world_299``."""
START = (-2.0, 3.0)
"""``run.py``'s ``INIT_POSITION`` (heading north, π/2: our unicycles start facing the goal, the same)."""
GOAL = (-2.0, 13.0)
"""``INIT_POSITION + GOAL_POSITION``."""
GOAL_REACH = 1.0
"""``run.py`` ends a run as a success when the robot is within 1 m of the goal."""
TOP_SPEED = 2.0
"""The Jackal's top speed [m/s], ``run.py``'s divisor of OT."""
TIMEOUT = 100.0
"""``run.py``'s time limit [s]."""
CELL = 0.15
"""The BARN lattice (``path_coord_to_gazebo_coord``'s ``RADIUS * 2``)."""
MARGIN = 1.0
"""Room left around the cylinders, start and goal [m]."""
MAX_PATH_BYTES = 2**20
"""Largest reference path file read [bytes] (one is about 1 kB)."""


def path_coord_to_gazebo_coord(points: np.ndarray) -> np.ndarray:
    """``run.py``'s mapping of reference path lattice points to Gazebo coordinates [m]."""
    radius = CELL / 2
    shift = np.array([-radius - 30 * radius * 2, radius + 5])
    return np.asarray(points, float) * (radius * 2) + shift


def optimal_time(path: np.ndarray) -> float:
    """``OT`` [s]: the reference path with the start first and the goal last, over 2 m/s (``run.py``)."""
    full = np.vstack([START, path_coord_to_gazebo_coord(path), GOAL])
    return float(np.sum(np.hypot(*np.diff(full, axis=0).T)) / TOP_SPEED)


def score(success: bool, actual: float, optimal: float) -> float:
    """``run.py``'s navigation metric: ``success × OT / clip(AT, 4·OT, 8·OT)``."""
    return float(success) * optimal / float(np.clip(actual, 4 * optimal, 8 * optimal))


def barn_folder(root: Path) -> Path:
    """The folder holding ``world_N.world`` and ``path_files/``: ``root`` or ``root/jackal_helper/worlds/BARN``."""
    for folder in (root, root / "jackal_helper" / "worlds" / "BARN"):
        if (folder / "world_0.world").is_file():
            return folder
    raise UserError(f"--barn: {root}: no world_0.world in it nor in jackal_helper/worlds/BARN (give the root of "
                    "nav-competition-icra2022, or its BARN folder)")


def read_path(file: Path) -> np.ndarray:
    """A reference path (K, 2) of lattice points, read as plain numbers (no pickles)."""
    data = read_regular_file(file, "BARN path", UserError, MAX_PATH_BYTES)
    try:
        path = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise UserError(f"{file}: not a .npy array of path points ({exc})") from None
    if path.ndim != 2 or path.shape[1] != 2 or len(path) < 1 or not np.issubdtype(path.dtype, np.number):
        raise UserError(f"{file}: expected (K, 2) numbers, got {path.dtype} {path.shape}")
    if not np.isfinite(path.astype(float)).all():
        raise UserError(f"{file}: path points must be finite")
    return path.astype(float)


def world_dict(world_file: Path, index: int, radius: float, step: float) -> dict:
    """The world file (a mapping, in metres) of BARN world ``index`` (module docstring)."""
    shapes = read_sdf_obstacles(world_file)
    if not shapes or any(s.radius is None for s in shapes):
        raise UserError(f"{world_file}: expected static cylinders only, as BARN's worlds hold")
    centres = np.array([s.center for s in shapes])
    radii = np.array([s.radius for s in shapes])
    lower = np.minimum((centres - radii[:, None]).min(axis=0), np.minimum(START, GOAL)) - MARGIN
    upper = np.maximum((centres + radii[:, None]).max(axis=0), np.maximum(START, GOAL)) + MARGIN
    lower, upper = np.floor(lower * 20) / 20, np.ceil(upper * 20) / 20     # to 5 cm
    return {
        "name": f"barn_{index}",
        "origin": [round(float(v), 6) for v in lower],
        "size": [round(float(v), 6) for v in upper - lower],
        "robot": {"radius": radius, "step": step},
        "goal_tolerance": GOAL_REACH,
        "field": "thesis-general",
        "obstacles": [{"circle": {"center": [float(x), float(y)], "radius": float(r)}}
                      for (x, y), r in zip(centres, radii)],
        "targets": [list(GOAL)],
        "starts": [list(START)],
    }


def world_indices(text: str) -> list[int]:
    """``dev`` (index divisible by 3), ``heldout`` (the others), ``all``, or ``0,3,6`` / ``0-30``."""
    if text == "dev":
        return list(range(0, WORLDS, 3))
    if text == "heldout":
        return [i for i in range(WORLDS) if i % 3]
    if text == "all":
        return list(range(WORLDS))
    out: list[int] = []
    for part in text.split(","):
        try:
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                out.extend(range(a, b + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise UserError(f"--worlds: expected dev, heldout, all or indices such as 0,3,6 or 0-30; got {part!r}") from None
    bad = [i for i in out if not 0 <= i < WORLDS]
    if bad:
        raise UserError(f"--worlds: BARN's worlds are 0 to {WORLDS - 1}, got {bad[0]}")
    return sorted(set(out))


def parse_steps(text: str) -> list[float]:
    """``--step``: one step length or several, separated by commas [m]."""
    out = []
    for part in text.split(","):
        try:
            value = float(part)
        except ValueError:
            value = math.nan
        if not (value > 0 and math.isfinite(value)):
            raise UserError(f"--step: expected positive lengths in metres separated by commas, got {part!r}")
        out.append(value)
    return out


def parse_kinds(text: str) -> list[str]:
    """``--kinematics``: ``holonomic``, ``unicycle``, or both separated by a comma."""
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    bad = [k for k in kinds if k not in ("holonomic", "unicycle")]
    if bad or not kinds:
        raise UserError(f"--kinematics: expected holonomic, unicycle or both (holonomic,unicycle), got {text!r}")
    return kinds


def run_one(worlds: list, optimal: dict, names: list[str], model: str | None, step: float, kind: str) -> list[dict]:
    """Every planner on ``worlds`` at one step length and robot kind: one result per planner."""
    seconds_per_step = step / TOP_SPEED
    max_steps = math.ceil(TIMEOUT / seconds_per_step)
    results, lengths = [], {}
    for name in names:
        planner = make_planner(name, model=model)
        start = time.perf_counter()
        ev = evaluate(planner, worlds, max_steps=max_steps, kinematics=kind)
        elapsed = time.perf_counter() - start
        lengths[name] = {e.world: (e.success, e.path_length) for e in ev.episodes}
        rows = []
        for world, e in zip(worlds, ev.episodes):
            at = e.steps * seconds_per_step
            rows.append({
                "world": int(world.name.split("_")[1]), "outcome": e.outcome, "success": e.success,
                "collision_with": list(e.contacts), "steps": int(e.steps), "time_s": round(at, 3),
                "optimal_time_s": round(optimal[world.name], 4),
                "score": round(score(e.success, at, optimal[world.name]), 5),
                "path_length_m": round(e.path_length * step, 4),
                "final_position_m": [round(float(v), 3) for v in world.frame.to_file(e.path[-1])]})
        results.append({"planner": name, "step_m": step, "kinematics": kind, "seconds_per_step": seconds_per_step,
                        "max_steps": max_steps, "seconds": round(elapsed, 1), "episodes": rows})
    reference = lengths.get("astar")
    for result in results:
        rows = result["episodes"]
        count = {k: sum(r["outcome"] == k for r in rows) for k in ("reached", "collision", "trapped", "timeout")}
        ratios = []
        if reference is not None:
            for world, r in zip(worlds, rows):
                ok, length = reference[world.name]
                if r["success"] and ok and length > 0:
                    ratios.append(lengths[result["planner"]][world.name][1] / length)
        result["summary"] = {"worlds": len(rows), "successes": count["reached"], "collisions": count["collision"],
                             "trapped": count["trapped"], "timeouts": count["timeout"],
                             "mean_score": round(float(np.mean([r["score"] for r in rows])), 4),
                             "path_over_astar": round(float(np.mean(ratios)), 4) if ratios else None,
                             "path_over_astar_worlds": len(ratios)}
    return results


def run(args: argparse.Namespace) -> int:
    steps = parse_steps(args.step)
    kinds = parse_kinds(args.kinematics)
    if not (args.radius > 0 and math.isfinite(args.radius)):
        raise UserError(f"--radius: must be a positive number of metres, got {args.radius:g}")
    if args.json:
        check_writable(args.json, create_parent=True)
    indices = world_indices(args.worlds)
    folder = barn_folder(Path(args.barn))
    names = [n.strip() for n in args.planner.split(",") if n.strip()]
    for name in names:
        make_planner(name, model=args.model)          # an unknown planner or model: said before any work
    header = (f"{'step':>6} {'r/step':>6} {'kind':<9} {'planner':<16} {'worlds':>6} {'success':>9} {'collide':>8} "
              f"{'trapped':>8} {'timeout':>8} {'score':>7} {'path/A*':>8} {'s':>7}")
    lines = [f"BARN {args.worlds}: {len(indices)} worlds, robot radius {args.radius:g} m; a control step takes "
             "step / 2 s (the Jackal's 2 m/s); timeout 100 s", header, "-" * len(header)]
    failures, runs = [], []
    for step in steps:
        worlds, optimal = [], {}
        for i in indices:
            data = world_dict(folder / f"world_{i}.world", i, args.radius, step)
            world = world_from_dict(data, str(folder / f"world_{i}.world"))
            if args.write_worlds:
                write_text(check_writable(Path(args.write_worlds) / f"barn_{i}_{step:g}.yaml", create_parent=True),
                           yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120))
            worlds.append(world)
            optimal[world.name] = optimal_time(read_path(folder / "path_files" / f"path_{i}.npy"))
        for kind in kinds:
            for result in run_one(worlds, optimal, names, args.model, step, kind):
                runs.append(result)
                summary, n = result["summary"], result["summary"]["worlds"]
                ratio = "-" if summary["path_over_astar"] is None else f"{summary['path_over_astar']:.3f}"
                lines.append(f"{step:>6g} {args.radius / step:>6.2f} {kind:<9} {result['planner']:<16} {n:>6} "
                             f"{summary['successes']:>4}/{n:<4} {summary['collisions']:>8} {summary['trapped']:>8} "
                             f"{summary['timeouts']:>8} {summary['mean_score']:>7.4f} {ratio:>8} {result['seconds']:>7.1f}")
                failures += [f"  {step:g} m {kind} {result['planner']}: world {r['world']}: {r['outcome']}"
                             + (f" ({', '.join(r['collision_with'])})" if r["collision_with"] else "")
                             + f" at {r['final_position_m']} after {r['steps']} steps"
                             for r in result["episodes"] if not r["success"]]
    print("\n".join(lines + (["failures:"] + failures if failures else [])))
    if args.json:
        meta = {"worlds": args.worlds, "indices": indices, "robot_radius_m": args.radius, "model": args.model,
                "steps_m": steps, "kinematics": kinds, "goal": list(GOAL), "start": list(START),
                "goal_reach_m": GOAL_REACH, "top_speed_m_s": TOP_SPEED, "timeout_s": TIMEOUT}
        write_text(args.json, json.dumps({"barn": meta, "runs": runs}, indent=1))
        print(f"wrote {args.json}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--barn", required=True, metavar="DIR",
                        help="nav-competition-icra2022's root, or its jackal_helper/worlds/BARN folder")
    parser.add_argument("--worlds", default="dev", help="dev (index divisible by 3), heldout, all, or 0,3,6 / 0-30")
    parser.add_argument("--step", default="0.15",
                        help="robot travel per control step [m], or several separated by commas (default 0.15)")
    parser.add_argument("--radius", type=float, default=0.21, help="robot radius [m] (default 0.21, a Jackal)")
    parser.add_argument("--planner", default="dqn,astar", help="planners, separated by commas (default dqn,astar)")
    parser.add_argument("--model", help="model file for the learned planners (default: the shipped one)")
    parser.add_argument("--kinematics", default="holonomic",
                        help="holonomic (default), unicycle, or holonomic,unicycle; unicycles take the package's "
                             "default limits, per step")
    parser.add_argument("--json", metavar="OUT", help="write every episode (in metres and seconds) and the summaries")
    parser.add_argument("--write-worlds", metavar="DIR", help="also write the world files (barn_N_STEP.yaml) here")
    args = parser.parse_args(argv)
    try:
        return run(args)
    except UserError as exc:     # WorldError is one: a clear message, no traceback
        print(f"barn.py: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
