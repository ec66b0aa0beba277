"""``apf-physics worlds``: the bundled worlds, usable by name anywhere (``eval fixed20 thesis/test1``)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from apf_physics import load_world
from apf_physics.world.bundled import bundled_dir, list_bundled, resolve_world
from apf_physics.world.io.units import length_to_file, unit_suffix


def add_parser(subparsers) -> None:
    """Register the ``worlds`` subcommand."""
    parser = subparsers.add_parser(
        "worlds", help="list the bundled worlds (name, size, obstacles, starts, what each shows)",
        description="List the worlds that ship with the package. Every command and world= argument takes "
                    "these names (fixed20, thesis/test1, or thesis for the whole folder) as well as paths.")
    parser.add_argument("--path", action="store_true", help="also print the folder they are installed in")
    parser.set_defaults(func=run)


def describe(path: Path, width: int = 110) -> str:
    """The first sentence of the file's leading comment (what the world shows), at most ``width`` characters."""
    lines = []
    for line in path.read_text(encoding="utf-8").splitlines():
        stripped = line.strip()
        if not stripped.startswith("#"):
            break
        lines.append(stripped.lstrip("#").strip())
    # A sentence ends at a full stop before a capital letter ("Fig. 1" does not end one).
    sentence = re.split(r"(?<=[a-z0-9)'])\.\s+(?=[A-Z])", " ".join(lines), maxsplit=1)[0].strip()
    if len(sentence) > width:
        sentence = sentence[: width - 3].rsplit(" ", 1)[0] + "..."
    return sentence


def run(args: argparse.Namespace) -> int:
    """Print one line per bundled world; returns the exit status."""

    rows = []
    for name in list_bundled():
        path = resolve_world(name)
        world = load_world(path)
        width, height = (length_to_file(world.frame, side) for side in world.size)
        size = f"{width:g}x{height:g}{unit_suffix(world.frame)}"   # in the file's units, as it is written
        rows.append((name, size, str(len(world.obstacles)), str(len(world.starts)), describe(path)))
    header = ("world", "size", "obstacles", "starts", "what it shows")
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(4)]
    for row in [header, *rows]:
        print(f"{row[0]:<{widths[0]}}  {row[1]:>{widths[1]}}  {row[2]:>{widths[2]}}  {row[3]:>{widths[3]}}  {row[4]}")
    if args.path:
        print(f"installed in {bundled_dir()}")
    return 0
