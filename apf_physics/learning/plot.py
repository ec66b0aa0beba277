"""The training curve as a PNG, drawn with OpenCV (no matplotlib)."""

from __future__ import annotations

import csv
import os
from typing import Sequence

import cv2
import numpy as np

from apf_physics.errors import UserError
from apf_physics.common.safefile import write_bytes

_BLUE, _RED, _GREEN, _GREY, _BLACK = (200, 110, 30), (40, 40, 220), (60, 160, 60), (200, 200, 200), (0, 0, 0)
_ORANGE = (0, 140, 255)


def _read_columns(csv_path: str | os.PathLike) -> dict[str, np.ndarray]:
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    names = rows[0].keys() if rows else []
    columns = {}
    for name in names:
        try:
            columns[name] = np.array([float(r[name]) if r[name] not in ("", None) else np.nan for r in rows])
        except ValueError:
            continue  # a text column (e.g. the curriculum stage): not plotted
    return columns


def _panel(image: np.ndarray, top: int, height: int, x: np.ndarray, series: Sequence, title: str,
           y_range: tuple[float, float] | None = None) -> None:
    """Draw one panel: axes box, title, y range labels and each (values, colour, label, markers) series
    (markers: False a line, True dots, ``"rings"`` circles)."""
    left, right = 70, image.shape[1] - 20
    cv2.rectangle(image, (left, top), (right, top + height), _GREY, 1)
    ys = np.concatenate([s[0][np.isfinite(s[0])] for s in series] + [np.zeros(0)])
    lo, hi = y_range or ((float(ys.min()), float(ys.max())) if ys.size else (0.0, 1.0))
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    x_hi = max(float(x.max()), 1.0) if x.size else 1.0
    cv2.putText(image, title, (left, top - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, _BLACK, 1, cv2.LINE_AA)
    for value, y in ((hi, top + 12), (lo, top + height)):
        cv2.putText(image, f"{value:.3g}", (4, y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, _BLACK, 1, cv2.LINE_AA)
    _legend(image, series, right, top - 8)
    for values, colour, label, markers in series:
        keep = np.isfinite(values)
        px = left + x[keep] / x_hi * (right - left)
        py = top + height - (values[keep] - lo) / (hi - lo) * height
        points = np.round(np.stack([px, py], axis=1)).astype(np.int32)
        if markers:  # True: dots; "rings": circles, visible over dots at the same steps
            for p in points:
                cv2.circle(image, tuple(int(v) for v in p), 4 if markers == "rings" else 3, colour,
                           2 if markers == "rings" else -1, cv2.LINE_AA)
        elif len(points) > 1:
            cv2.polylines(image, [points], False, colour, 2, cv2.LINE_AA)


def _legend(image: np.ndarray, series: Sequence, right: int, baseline: int) -> None:
    """The series' names on the panel's title line, flush right: above the axes box, never on a curve."""
    entries = []
    for _, colour, label, markers in series:
        (width, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        entries.append((colour, label, markers, width))
    x = right - sum(22 + width + 14 for *_, width in entries) + 14
    for colour, label, markers, width in entries:
        y = baseline - 4
        if markers:
            cv2.circle(image, (x + 9, y), 4 if markers == "rings" else 3, colour, 2 if markers == "rings" else -1,
                       cv2.LINE_AA)
        else:
            cv2.line(image, (x, y), (x + 18, y), colour, 2, cv2.LINE_AA)
        cv2.putText(image, label, (x + 22, baseline), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
        x += 22 + width + 14


def success_columns(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The success rates of a training log by what they measure: ``training`` (the recent ε-greedy
    episodes), ``validation`` (the greedy evaluations on the validation starts, which choose
    ``best.pt``) and ``world starts`` (on a world's own starts); also read from the column names of
    logs written before they had these names."""
    empty = np.zeros(0)
    if "validation_success" in columns:
        return {"training": columns.get("training_success", empty), "validation": columns["validation_success"],
                "world starts": columns.get("world_starts_success", empty)}
    held_out = columns.get("eval_random_success", empty)
    evaluated = columns.get("eval_success", columns.get("val_success", empty))
    separate = bool(np.isfinite(held_out).any())   # a world's run: random starts chose best.pt, its own beside
    return {"training": columns.get("success_rate", empty), "validation": held_out if separate else evaluated,
            "world starts": evaluated if separate else empty}


def plot_training_curve(csv_path: str | os.PathLike, png_path: str | os.PathLike | None = None) -> np.ndarray:
    """Draw the training log: success rates above (training episodes, validation starts, world starts),
    mean episode return below.

    Args:
        csv_path: Training log written by :func:`apf_physics.learning.train`.
        png_path: Where to write the PNG (not written if None).

    Returns:
        The (H, W, 3) uint8 BGR image.
    """
    columns = _read_columns(csv_path)
    empty = np.zeros(0)
    x = columns.get("global_step", empty)
    image = np.full((480, 720, 3), 255, np.uint8)
    success = success_columns(columns)
    series = [(success["training"], _BLUE, "training episodes", False),
              (success["validation"], _RED, "validation starts", True)]
    if np.isfinite(success["world starts"]).any():
        series.append((success["world starts"], _ORANGE, "world starts", "rings"))
    _panel(image, 30, 190, x, series, "success rate", y_range=(0.0, 1.0))
    _panel(image, 260, 190, x, [(columns.get("mean_return", empty), _GREEN, "mean return", False)], "mean episode return")
    x_hi = int(x.max()) if x.size else 0
    cv2.putText(image, f"env steps (0 .. {x_hi})", (300, 472), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _BLACK, 1, cv2.LINE_AA)
    if png_path is not None:
        ok, encoded = cv2.imencode(".png", image)
        if not ok:
            raise UserError(f"cannot write {png_path}: OpenCV could not encode the PNG image")
        write_bytes(png_path, encoded.tobytes())
    return image
