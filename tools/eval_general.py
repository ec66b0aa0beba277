"""Compare planners on general-field worlds, overall and on the starts where gradient descent is trapped.

For each planner (and each DQN model given): success over all starts, success over the
trap starts (gradient descent does not reach the target from them), collisions, the mean
path length on the successes divided by A*'s mean over the same starts, SPL (success weighted
by path length: the mean over all starts of A* length / max(path, A* length) on a success, 0
otherwise; Anderson et al. 2018), and success over the
starts from which unit moves can end within the goal tolerance at all (the DQN planner's
moves are integer vectors: with a tolerance below √2/2 some starts can never succeed). Episodes run
through the physics exactly as ``apf-physics eval`` runs them.

Trap labels and A* lengths come from the directory's ``manifest.json`` (written by
``apf-physics generate``); for world files without one they are computed here
(:func:`apf_physics.experiments.worldsets.label_starts`).

Usage::

    PYTHONPATH=. python tools/eval_general.py /tmp/heldout \\
        --planners gradient,escape,astar,dqn \\
        --model general=apf_physics/models/general.pt --model thesis=runs/thesis/best.pt \\
        [--json OUT] [--per-world] [--kinematics unicycle]
    PYTHONPATH=. python tools/eval_general.py worlds/thesis/test1.yaml ... --planners dqn --per-world

``--model`` applies to the learned planners (``dqn``, ``dqn-unshielded``, ``dqn-known``; one row per
model each).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.experiments.evaluate import evaluate, figures  # noqa: E402
from apf_physics.experiments.worldsets import label_starts  # noqa: E402
from apf_physics.planners import LEARNED, make_planner  # noqa: E402
from apf_physics.world.kinematics import KINEMATICS  # noqa: E402
from apf_physics.common.safefile import write_text  # noqa: E402
from apf_physics.world.io.worldfile import load_world  # noqa: E402


def lattice_reachable(world, start) -> bool:
    """Whether unit moves (axis or diagonal) from ``start`` can end within the goal tolerance of a target."""
    d = np.asarray(world.targets) - np.asarray(start)
    return bool(np.min(np.hypot(*(d - np.round(d)).T)) <= world.goal_tolerance)


def load_labelled(paths: list[str]):
    """Worlds and per-start labels ``(trapped, astar_length)``, from manifests where there are any."""
    worlds, labels = [], {}
    for p in map(Path, paths):
        if p.is_dir():
            manifest = json.loads((p / "manifest.json").read_text())
            for record in manifest["worlds"]:
                world = load_world(p / record["file"])
                worlds.append(world)
                labels[world.name] = [(s["gradient_trapped"], s["astar_length"], lattice_reachable(world, s["start"]))
                                      for s in record["starts"]]
        else:
            world = load_world(p)
            worlds.append(world)
            labels[world.name] = [(s["gradient_trapped"], s["astar_length"], lattice_reachable(world, s["start"]))
                                  for s in label_starts(world)]
    return worlds, labels


def family_of(world_name: str) -> str:
    """``rooms_03`` → ``rooms``, ``maze100_07`` → ``maze100`` (generated names)."""
    return re.sub(r"_\d+$", "", world_name)


def summarise(episodes, labels) -> dict:
    """Overall and trap-start figures for one planner's episodes (:func:`apf_physics.experiments.evaluate.figures`)."""
    rows = []
    index: dict[str, int] = {}
    for e in episodes:
        k = index.get(e.world, 0)
        index[e.world] = k + 1
        rows.append(labels[e.world][k])                    # (trapped, astar, lattice)
    trapped = np.array([r[0] for r in rows], bool)
    astar = [r[1] for r in rows]
    lattice = np.array([r[2] for r in rows], bool)
    scored = figures(episodes, optimal=astar, trapped=trapped)
    success = np.array([e.success for e in episodes], bool)
    ok = [(e.path_length, a) for e, a in zip(episodes, astar) if e.success and a]
    nan = float("nan")
    return {
        "starts": scored.episodes,
        "successes": scored.successes,
        "success_rate": scored.success_rate,
        "trap_starts": int(trapped.sum()),
        "trap_successes": int(success[trapped].sum()),
        "trap_success_rate": nan if scored.trap_success is None else scored.trap_success,
        "collisions": scored.collisions,
        "lattice_starts": int(lattice.sum()),
        "lattice_successes": int(success[lattice].sum()),
        "length_ratio_vs_astar": nan if scored.length_ratio is None else scored.length_ratio,
        "mean_path_length": float(np.mean([p for p, _ in ok])) if ok else nan,
        "mean_astar_length": float(np.mean([a for _, a in ok])) if ok else nan,
        "spl": scored.spl,
    }

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("worlds", nargs="+", help="a generated set's directory (with manifest.json) or world files")
    parser.add_argument("--planners", default="gradient,escape,astar,dqn")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                        help="a DQN model to evaluate as planner dqn:NAME (default: the shipped model)")
    parser.add_argument("--max-steps", type=int, default=None, help="as apf-physics eval (default 4 x (w + h))")
    parser.add_argument("--kinematics", choices=KINEMATICS, default=None,
                        help="as apf-physics eval: the robots are holonomic or unicycles (default: each world file's)")
    parser.add_argument("--per-world", action="store_true", help="also print successes per world")
    parser.add_argument("--per-family", action="store_true",
                        help="also print the figures per family (a world's name without its number; "
                             "generated 100x100 worlds are their own family, e.g. rooms100)")
    parser.add_argument("--json", help="write the figures as JSON")
    args = parser.parse_args(argv)

    worlds, labels = load_labelled(args.worlds)
    runs = []
    for name in [n.strip() for n in args.planners.split(",") if n.strip()]:
        if name in LEARNED and args.model:
            for spec in args.model:
                label, _, path = spec.partition("=")
                runs.append((f"{name}:{label}", make_planner(name, model=path)))
        else:
            runs.append((name, make_planner(name)))

    n_starts = sum(len(v) for v in labels.values())
    n_trap = sum(t for v in labels.values() for t, _, _ in v)
    n_lattice = sum(q for v in labels.values() for _, _, q in v)
    print(f"{len(worlds)} worlds, {n_starts} starts, {n_trap} trap starts ({n_trap / n_starts:.0%}); "
          f"{n_lattice} starts ({n_lattice / n_starts:.0%}) can end within the goal tolerance with unit moves")
    header = (f"{'planner':<26} {'success':>13} {'trap-start success':>19} {'collisions':>10} {'length/A*':>10}"
              f" {'SPL':>6} {'unit-move-reachable':>20}")
    print(header)
    print("-" * len(header))
    results = {}
    for label, planner in runs:
        ev = evaluate(planner, worlds, max_steps=args.max_steps, kinematics=args.kinematics)
        s = summarise(ev.episodes, labels)
        results[label] = s
        print(f"{label:<26} {s['successes']:>4}/{s['starts']:<4}{s['success_rate']:>5.1%} "
              f"{s['trap_successes']:>6}/{s['trap_starts']:<4}{s['trap_success_rate']:>7.1%} "
              f"{s['collisions']:>10} {s['length_ratio_vs_astar']:>10.3f} {s['spl']:>6.3f}"
              f" {s['lattice_successes']:>14}/{s['lattice_starts']:<4}")
        if args.per_family:
            families: dict[str, list] = {}
            for e in ev.episodes:
                families.setdefault(family_of(e.world), []).append(e)
            s["per_family"] = {}
            for fam, episodes in families.items():
                f = summarise(episodes, labels)
                s["per_family"][fam] = f
                print(f"  {fam:<24} {f['successes']:>4}/{f['starts']:<4}{f['success_rate']:>5.1%} "
                      f"{f['trap_successes']:>6}/{f['trap_starts']:<4}{f['trap_success_rate']:>7.1%} "
                      f"{f['collisions']:>10} {f['length_ratio_vs_astar']:>10.3f} {f['spl']:>6.3f}")
        if args.per_world:
            per = {}
            for e in ev.episodes:
                per.setdefault(e.world, []).append(e.success)
            worlds_ok = sum(any(v) for v in per.values())
            detail = ", ".join(f"{w} {sum(v)}/{len(v)}" for w, v in per.items())
            print(f"{'':<26} worlds with a success: {worlds_ok}/{len(per)} ({detail})")
            s["per_world"] = {w: [bool(x) for x in v] for w, v in per.items()}
    if args.json:
        write_text(args.json, json.dumps(results, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
