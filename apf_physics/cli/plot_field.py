"""``apf-physics plot-field WORLD --out field.png``: level lines and gradient-descent paths (thesis Fig. 22–23)."""

from __future__ import annotations

import argparse
from collections import Counter

from apf_physics.errors import UserError
from apf_physics.planners.gradient import GradientPlanner
from apf_physics.render.drawing import FieldImage
from apf_physics.render.field_plot import plot_field
from apf_physics.common.safefile import check_writable
from apf_physics.experiments.rollout import rollout
from apf_physics.world.io.worldfile import load_world


def add_parser(subparsers) -> None:
    """Register the ``plot-field`` subcommand."""
    parser = subparsers.add_parser(
        "plot-field",
        help="draw a world's potential field with gradient-descent paths to a PNG",
        description="Draw the world's potential (log-scaled heatmap, level lines, a colour bar with U's "
                    "scale), its obstacles and targets, and the gradient-descent path from each of the "
                    "world's starts (thesis Fig. 22-23: yellow paths, blue starts, blue rings where a robot "
                    "got stuck), with a legend beside the map.",
    )
    add_arguments(parser)
    parser.set_defaults(func=run)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The subcommand's options, on any parser (the CLI's subparser or a standalone script's)."""
    parser.add_argument("world", help="world file (.yaml), or a bundled world's name (fixed20, thesis/test1)")
    parser.add_argument("--out", required=True, help="output image (.png); a missing folder is created")
    parser.add_argument("--size", type=int, default=512, help="pixels along the world's longer side (default 512)")
    parser.add_argument("--no-paths", action="store_true", help="draw the field only, without paths")
    parser.add_argument("--scaling", choices=("log", "rank"), default="log",
                        help="colour scale of the potential: log (default) or rank (histogram-equalised)")
    parser.add_argument("--max-steps", type=int, default=None,
                        help="step limit of each descent (default: the rollout's)")
    parser.add_argument("--t", type=float, default=None, metavar="T",
                        help="a world with moving obstacles: draw the field and the obstacles as they are at "
                             "control step T (default: the static field, the routes as faint lines, the moving "
                             "obstacles where they start)")


def run(args: argparse.Namespace) -> int:
    """Draw the plot; returns the exit status."""
    out = check_writable(args.out, (".png",), create_parent=True)
    if args.size < 16:
        raise UserError(f"--size must be at least 16 pixels, got {args.size}")
    world = load_world(args.world)
    if args.t is not None and args.t < 0:
        raise UserError(f"--t must not be negative, got {args.t:g}")
    image = FieldImage.from_world(world, args.size, scaling=args.scaling,
                                  t=args.t if args.t is not None or not world.moving else None)
    paths, reached, title = [], [], [f"{world.name}: potential field"]
    if args.t is not None:
        title = [f"{world.name}: potential field at step {args.t:g}"]
    if not args.no_paths and len(world.starts) and args.t is None:
        episodes = rollout(world, GradientPlanner(), world.starts, max_steps=args.max_steps)
        paths = [episode.path for episode in episodes]
        reached = [episode.success for episode in episodes]
        counts = Counter(episode.outcome for episode in episodes)
        summary = ", ".join(f"{outcome} {count}" for outcome, count in sorted(counts.items()))
        title = [f"{world.name}: gradient descent", f"{len(episodes)} starts: {summary}"]
    plot_field(world, paths, out, reached=reached, title=title, image=image)
    print(f"wrote {out}" + (f" ({title[1]})" if len(title) > 1 else ""))
    return 0
