"""The ``apf-physics`` command: a thin layer over the package's functions."""

from __future__ import annotations

import argparse
import importlib
import sys

from apf_physics import __version__
from apf_physics.errors import UserError

# Subcommand modules in apf_physics.commands, in the order ``--help`` lists them.
COMMANDS = ("demo", "eval", "train", "generate", "render", "plot_field", "plot_curve", "worlds")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="apf-physics",
        description="Artificial-potential-field path planning with pymunk physics: plan, train, evaluate, render.")
    parser.add_argument("--version", action="version", version=f"apf-physics {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"apf_physics.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"apf_physics.commands.{name}":
                continue  # not part of this build
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"apf-physics: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("apf-physics: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
