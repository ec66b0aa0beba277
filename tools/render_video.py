#!/usr/bin/env python
"""Render a planner's run in a world to a video: the same as ``apf-physics render``.

Example::

    python tools/render_video.py worlds/fixed20.yaml --planner gradient --all-starts \
        --out fixed20.mp4 --png fixed20.png
"""

from __future__ import annotations

import argparse
import sys

from apf_physics.cli import render
from apf_physics.errors import UserError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="render_video.py", description=__doc__.splitlines()[0])
    render.add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return render.run(args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
