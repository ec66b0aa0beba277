"""``apf-physics plot-curve TRAIN_CSV --out curve.png``: the training curve of a run, as a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from apf_physics.errors import UserError
from apf_physics.common.safefile import check_writable
from apf_physics.render.video import write_png
from apf_physics.learning.plot import plot_training_curve


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("plot-curve", help="draw a training run's curve (train.csv) to a PNG",
                              description="Draw the training curve (episodes, epsilon, return, success, "
                                          "evaluations) of a run's train.csv to a PNG. `apf-physics train` "
                                          "writes one (train.png) as it goes; this redraws it from the log.")
    p.add_argument("csv", metavar="TRAIN_CSV", help="a run's train.csv")
    p.add_argument("--out", required=True, help="output .png; a missing folder is created")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    csv = Path(args.csv)
    if not csv.is_file():
        raise UserError(f"{csv}: no such training log")
    out = check_writable(args.out, (".png",), create_parent=True)
    try:
        curve = plot_training_curve(csv)
    except (KeyError, ValueError) as exc:
        raise UserError(f"{csv}: not a training log this tool can read ({exc})") from None
    write_png(curve[:, :, ::-1], out)  # the curve is drawn in BGR; write_png takes RGB
    print(f"wrote {out}")
    return 0
