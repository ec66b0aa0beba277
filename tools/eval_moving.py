"""Planners among moving obstacles: success, collisions, and which collisions could have been avoided.

Runs each planner on a generated set (or world files) exactly as ``tools/eval_general.py`` does
(the same episodes, through the physics) and then, for every episode that ends in a collision at
step ``c``, asks whether it was avoidable: from where the robot was ``--before`` steps earlier
(step ``c − before``, or the start), does any sequence of the robot's moves
(:func:`apf_physics.world.search.escape_moves`: breadth-first over the time-expanded graph of the nine
unit moves, the obstacles where the physics has them at each moment) touch nothing up to step
``c + --after``? Each collision is labelled

- ``avoidable``: such a sequence exists, with clearance proved by a lower bound;
- ``unavoidable``: every sequence touches something at one of its samples (16 per step);
- ``undecided``: neither (a sequence grazes within the bounds' slack; none was seen).

Usage::

    python tools/eval_moving.py /tmp/apf-figures/mv_heldout --planners dqn,dqn-known,astar,sipp \\
        --model moving=moving [--json OUT] [--before 5] [--after 3]

``--model`` applies to the learned planners (``dqn``, ``dqn-known``, ``dqn-unshielded``, and
``dqn-one-step``: the shield as it was before the shield over time, for comparison).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_general import load_labelled, summarise  # noqa: E402

from apf_physics.experiments.evaluate import evaluate  # noqa: E402
from apf_physics.planners import LEARNED, make_planner  # noqa: E402
from apf_physics.planners.dqn import DQNPlanner  # noqa: E402
from apf_physics.common.safefile import write_text  # noqa: E402
from apf_physics.world.search import escape_moves  # noqa: E402


def planner_named(name: str, model: str | None):
    """A planner by its command-line name, or ``dqn-one-step`` (the shield of one step, no look-ahead)."""
    if name == "dqn-one-step":
        return DQNPlanner(model=model, horizon=0)
    return make_planner(name, model=model if name in LEARNED else None)


def avoidability(world, episode, before: int = 5, after: int = 3) -> dict:
    """The label of one collision episode (see the module's docstring) and where it was searched from."""
    c = int(episode.steps)
    t0 = max(0, c - before)
    start = episode.path[t0]
    steps = c - t0 + after
    if escape_moves(world, start, t0, steps, strict=True) is not None:
        label = "avoidable"
    elif escape_moves(world, start, t0, steps, strict=False) is None:
        label = "unavoidable"
    else:
        label = "undecided"
    return {"world": episode.world, "start": [round(float(v), 4) for v in episode.start], "step": c,
            "with": list(episode.contacts), "from_step": t0, "label": label}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("worlds", nargs="+", help="a generated set's directory (with manifest.json) or world files")
    parser.add_argument("--planners", default="dqn,dqn-known,astar,sipp")
    parser.add_argument("--model", default=None, metavar="NAME=PATH",
                        help="the model of the learned planners (a file, or a shipped model's name)")
    parser.add_argument("--before", type=int, default=5, help="search from this many steps before a collision")
    parser.add_argument("--after", type=int, default=3, help="and ask for no contact up to this many steps after it")
    parser.add_argument("--max-steps", type=int, default=None)
    parser.add_argument("--json", help="write the figures and every collision's label as JSON")
    args = parser.parse_args(argv)

    worlds, labels = load_labelled(args.worlds)
    by_name = {w.name: w for w in worlds}
    model = args.model.partition("=")[2] or args.model if args.model else None
    n = sum(len(v) for v in labels.values())
    print(f"{len(worlds)} worlds, {n} starts")
    header = (f"{'planner':<16} {'success':>14} {'trap-start':>14} {'collisions':>11} {'avoidable':>10}"
              f" {'unavoidable':>12} {'undecided':>10} {'SPL':>6} {'time':>7}")
    print(header)
    print("-" * len(header))
    results = {}
    for name in [p.strip() for p in args.planners.split(",") if p.strip()]:
        planner = planner_named(name, model)
        began = time.perf_counter()
        ev = evaluate(planner, worlds, max_steps=args.max_steps)
        took = time.perf_counter() - began
        s = summarise(ev.episodes, labels)
        s["collision_labels"] = [avoidability(by_name[e.world], e, args.before, args.after)
                                 for e in ev.episodes if e.outcome == "collision"]
        count = {k: sum(c["label"] == k for c in s["collision_labels"]) for k in ("avoidable", "unavoidable", "undecided")}
        s.update({k: v for k, v in count.items()})
        s["seconds"] = took
        s["outcomes"] = {k: sum(e.outcome == k for e in ev.episodes) for k in ("reached", "collision", "trapped", "timeout")}
        s["not_reached"] = [{"world": e.world, "start": [round(float(v), 4) for v in e.start], "outcome": e.outcome,
                             "steps": int(e.steps)} for e in ev.episodes if e.outcome not in ("reached", "collision")]
        results[name] = s
        print(f"{name:<16} {s['successes']:>4}/{s['starts']:<4}{s['success_rate']:>6.1%} "
              f"{s['trap_successes']:>4}/{s['trap_starts']:<4}{s['trap_success_rate']:>6.1%} "
              f"{s['collisions']:>11} {count['avoidable']:>10} {count['unavoidable']:>12} {count['undecided']:>10}"
              f" {s['spl']:>6.3f} {took:>6.0f}s", flush=True)
        for c in s["not_reached"]:
            print(f"    {c['world']} start {c['start']}: {c['outcome']} after {c['steps']} steps", flush=True)
        for c in s["collision_labels"]:
            print(f"    {c['world']} start {c['start']}: collision at step {c['step']} with {','.join(c['with'])}: "
                  f"{c['label']} (searched from step {c['from_step']})", flush=True)
    if args.json:
        write_text(args.json, json.dumps(results, indent=1, default=float))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
