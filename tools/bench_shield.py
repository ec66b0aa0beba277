"""Time the shield over time against the shield of one step, per robot and step.

Robots are put at random free positions of moving-obstacle worlds, many of them near a moving
obstacle (where the shield over time does its work), and each shield is called for all of them
at a run of steps, in alternating blocks (the machine's load changes while it runs).

Usage::

    python tools/bench_shield.py /tmp/apf-figures/mv_heldout --worlds 10 --robots 64 --steps 20 --blocks 3
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.control.shield import ACTIONS, SAFETY, assess_moves, move_clearance, shield_over_time, shielded_argmax  # noqa: E402
from apf_physics.world.io.worldfile import load_world  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory")
    parser.add_argument("--worlds", type=int, default=10)
    parser.add_argument("--robots", type=int, default=64)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--blocks", type=int, default=3)
    parser.add_argument("--near", action="store_true",
                        help="put the robots 1.5-4 units from the moving obstacles' centres at step 0 (most of them watched)")
    args = parser.parse_args(argv)
    files = sorted(Path(args.directory).glob("*.yaml"))[: args.worlds]
    worlds = [load_world(f) for f in files]
    rng = np.random.default_rng(0)
    cases = []
    for w in worlds:
        p = w.random_free_positions(rng, args.robots, margin=0.4)
        if args.near:
            centres = np.array([np.mean(np.asarray(o.bounds), axis=0) for o in w.obstacles_at(0)])[list(w.moving)]
            pick = centres[rng.integers(len(centres), size=4 * args.robots)]
            angle = rng.uniform(0, 2 * np.pi, len(pick))
            cand = pick + rng.uniform(1.5, 4.0, len(pick))[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
            cand = cand[(w.at(0).clearance(cand) > 0.4)]
            p = cand[: args.robots]
        q = rng.normal(size=(len(p), len(ACTIONS)))
        cases.append((w, p, q))
    shields = {
        "one step (move_clearance at the step)": lambda w, t, p, q: shielded_argmax(
            q, move_clearance(w.at(t), p) - (w.robot_radius + SAFETY)),
        "over time, velocity": lambda w, t, p, q: shield_over_time(w.at(t), p, ACTIONS, q, "velocity"),
        "over time, known": lambda w, t, p, q: shield_over_time(w.at(t), p, ACTIONS, q, "known"),
    }
    watched = np.mean([assess_moves(w.at(t), p, ACTIONS).watched.mean() for w, p, _ in cases for t in range(args.steps)])
    totals = {k: [] for k in shields}
    for _ in range(args.blocks):
        for name, fn in shields.items():
            began = time.perf_counter()
            for w, p, q in cases:
                for t in range(args.steps):
                    fn(w, t, p, q)
            totals[name].append((time.perf_counter() - began) / (len(cases) * args.steps * args.robots))
    print(f"{len(cases)} worlds x {args.robots} robots x {args.steps} steps; {watched:.0%} of robot-steps near a moving obstacle")
    for name, v in totals.items():
        print(f"{name:<40} {1e6 * min(v):8.1f} µs per robot-step (best of {args.blocks} blocks; all: "
              f"{', '.join(f'{1e6 * x:.1f}' for x in v)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
