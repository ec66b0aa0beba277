"""``apf-physics generate --family F --count N --seed S --out DIR``: random worlds and a manifest."""

from __future__ import annotations

import argparse

from apf_physics.errors import UserError
from apf_physics.generate import FAMILIES
from apf_physics.worldsets import generate_set


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "generate", help="generate random worlds where gradient descent tends to be trapped",
        description="Generate random worlds whose obstacles lie between the starts and the target, with "
                    "reachable starts, and write them with a manifest (DIR/manifest.json) that labels each "
                    "start with gradient descent's outcome and the A* path length.")
    p.add_argument("--family", required=True,
                   help=f"world family, or several separated by commas (cycled): {', '.join(FAMILIES)}")
    p.add_argument("--count", type=int, required=True, help="number of worlds")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    p.add_argument("--size", type=float, default=50, help="map width and height (default 50)")
    p.add_argument("--field", default="thesis-general", help="field preset (default thesis-general)")
    p.add_argument("--starts", type=int, default=4, help="starts per world (default 4)")
    p.add_argument("--no-label", action="store_true",
                   help="skip the gradient-descent rollouts (the manifest then has only A* lengths)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    families = [f.strip() for f in args.family.split(",") if f.strip()]
    for family in families:
        if family not in FAMILIES:
            raise UserError(f"--family: unknown family {family!r} (known: {', '.join(FAMILIES)})")
    if args.starts < 1:
        raise UserError(f"--starts: must be at least 1, got {args.starts}")
    if args.size < 10:
        raise UserError(f"--size: must be at least 10, got {args.size:g}")
    manifest = generate_set(families if len(families) > 1 else families[0], args.count, args.seed, args.out,
                            size=args.size, field=args.field, n_starts=args.starts, label=not args.no_label)
    summary = manifest["summary"]
    line = f"wrote {summary['worlds']} worlds, {summary['starts']} starts to {args.out}"
    if "gradient_trapped" in summary:
        line += f"; gradient descent fails from {summary['gradient_trapped']} ({summary['gradient_trapped_rate']:.0%})"
    print(line)
    return 0
