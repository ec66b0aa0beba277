"""Subcommands of ``apf-physics``: each module has ``add_parser(subparsers)`` and ``run(args) -> int``."""
