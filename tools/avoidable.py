"""Starts from which no sequence of moves escapes the moving obstacles: a check of a world set.

For every start of every world (a generated set's directory, or world files), a breadth-first
search of the time-expanded graph of the nine unit moves (:func:`apf_physics.world.search.escape_moves`,
the obstacles where the physics has them at each moment) asks whether any sequence of
``--steps`` moves from the start at step 0 touches nothing. A start from which none does is a
robot cornered from the start (for instance by an obstacle faster than itself): no planner can
be blamed for its collision, and a generator should not produce it unawares.

Usage::

    python tools/avoidable.py /tmp/apf-figures/mv_heldout [--steps 12]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.world.search import escape_moves  # noqa: E402
from apf_physics.world.io.worldfile import load_world  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("worlds", nargs="+", help="directories of world files, or world files")
    parser.add_argument("--steps", type=int, default=12, help="moves each sequence must survive")
    args = parser.parse_args(argv)
    files = [f for p in map(Path, args.worlds) for f in (sorted(p.glob("*.yaml")) if p.is_dir() else [p])]
    starts = cornered = undecided = 0
    for f in files:
        world = load_world(f)
        for k, start in enumerate(world.starts):
            starts += 1
            if escape_moves(world, start, 0, args.steps, strict=True) is not None:
                continue
            if escape_moves(world, start, 0, args.steps, strict=False) is None:
                cornered += 1
                print(f"{world.name} start {k} {start.tolist()}: every sequence of {args.steps} moves collides")
            else:
                undecided += 1
                print(f"{world.name} start {k} {start.tolist()}: undecided (only within the bounds' slack)")
    print(f"{len(files)} worlds, {starts} starts: {cornered} cornered, {undecided} undecided, "
          f"{starts - cornered - undecided} with a way out for {args.steps} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
