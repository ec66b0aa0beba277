"""The ``apf-physics`` command: a thin layer over the package's functions.

Subcommands live in :mod:`apf_physics.cli`, one module each, found by name in
:data:`COMMANDS` (string entry points, as Gymnasium registers environments): only the
module of the subcommand being run is loaded, so ``apf-physics eval --planner gradient``
never loads torch and ``apf-physics --help`` loads nothing.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from apf_physics import __version__
from apf_physics.errors import UserError

COMMANDS = {
    "demo": "run the shipped models: fixed-world formation and general worlds, with videos and a results page",
    "eval": "run planners from every start of every world; print a table, write JSON",
    "train": "train a DQN planner on a world or a curriculum; write best.pt, last.pt, train.csv",
    "sweep": "compare training recipes on Ray Tune: grids, seeds, early stopping; the best model copied out",
    "generate": "generate random worlds where gradient descent tends to be trapped",
    "draw_scen": "draw a MovingAI scenario file as the MAPF benchmark's random ones (for fleets)",
    "render": "render a planner's run in a world to a video (and optionally a PNG of the last frame)",
    "plot_field": "plot a world's potential field: heatmap, level lines, descent paths",
    "plot_curve": "plot a training run's curve from its train.csv",
    "worlds": "list the worlds bundled with the package",
}
"""Subcommand module in :mod:`apf_physics.cli` → one-line help, in the order ``--help`` lists them."""


def _module_name(command: str) -> str:
    return command.replace("-", "_")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; ``command``'s own options are loaded (its module imported) only when it is given."""
    parser = argparse.ArgumentParser(
        prog="apf-physics",
        description="Artificial-potential-field path planning with pymunk physics: plan, train, evaluate, render.")
    parser.add_argument("--version", action="version", version=f"apf-physics {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, help_text in COMMANDS.items():
        if name == command:
            module = importlib.import_module(f"apf_physics.cli.{name}")
            module.add_parser(sub)
        else:
            sub.add_parser(name.replace("_", "-"), help=help_text, add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    command = _module_name(chosen) if chosen is not None and _module_name(chosen) in COMMANDS else None
    parser = build_parser(command)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as exc:   # one line per problem, each with the prefix
        for line in str(exc).splitlines() or [""]:
            print(f"apf-physics: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("apf-physics: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:   # the reader went away (``| head``): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141

