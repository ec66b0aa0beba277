"""``apf-physics generate --family F --count N --seed S --out DIR``: random worlds and a manifest."""

from __future__ import annotations

import argparse

from apf_physics.errors import UserError
from apf_physics.world.generate import ALL_FAMILIES
from apf_physics.world.io.worldfile import MAX_SIDE, raster_memory_problem
from apf_physics.experiments.worldsets import generate_set


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "generate", help="generate random worlds where gradient descent tends to be trapped",
        description="Generate random worlds whose obstacles lie between the starts and the target, with "
                    "reachable starts, and write them with a manifest (DIR/manifest.json) that labels each "
                    "start with gradient descent's outcome and the A* path length.")
    p.add_argument("--family", required=True,
                   help=f"world family, or several separated by commas (cycled): {', '.join(ALL_FAMILIES)}")
    p.add_argument("--count", type=int, required=True, help="number of worlds")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory: new or empty (created), or see --force")
    p.add_argument("--force", action="store_true",
                   help="replace the worlds an earlier `generate` wrote in DIR (none of them is left behind); "
                        "world files it did not write are never removed: their presence is an error")
    p.add_argument("--size", type=float, default=50, help="map width and height (default 50)")
    p.add_argument("--field", default="thesis-general", help="field preset (default thesis-general)")
    p.add_argument("--starts", type=int, default=4, help="starts per world (default 4)")
    p.add_argument("--no-label", action="store_true",
                   help="skip the gradient-descent rollouts (the manifest then has only A* lengths)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    families = [f.strip() for f in args.family.split(",") if f.strip()]
    for family in families:
        if family not in ALL_FAMILIES:
            raise UserError(f"--family: unknown family {family!r} (known: {', '.join(ALL_FAMILIES)})")
    if args.starts < 1:
        raise UserError(f"--starts: must be at least 1, got {args.starts}")
    if not 10 <= args.size <= MAX_SIDE:
        raise UserError(f"--size: must be between 10 and {MAX_SIDE:,.0f}, got {args.size:g}")
    problem = raster_memory_problem((args.size, args.size), 1)
    if problem:
        raise UserError(f"--size: {problem}")
    manifest = generate_set(families if len(families) > 1 else families[0], args.count, args.seed, args.out,
                            size=args.size, field=args.field, n_starts=args.starts, label=not args.no_label,
                            force=args.force, progress=not args.no_progress)
    summary = manifest["summary"]
    line = f"wrote {summary['worlds']} worlds, {summary['starts']} starts to {args.out}"
    if "gradient_trapped" in summary:
        line += f"; gradient descent fails from {summary['gradient_trapped']} ({summary['gradient_trapped_rate']:.0%})"
    print(line)
    return 0
