"""The field plot of thesis Fig. 22–23: level lines of the potential with robot paths over them.

Paths are yellow, each start a blue robot disc, the targets red dots and the obstacles
white; a path that did not end at a target (trapped, collided) ends in a blue ring, so the
traps stand out. As a figure (:func:`field_figure`, what ``plot-field`` writes) the map gets
a title above it, axes along its left and bottom edges in the world file's units and
coordinates (the unit named: ``x [m]``), and, beside it, a colour bar with the potential's scale
and a legend, so that nothing covers the map.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import cv2
import numpy as np

from apf_physics.render.drawing import (
    BLUE,
    DARK_HALO,
    LEVEL_LINE,
    OBSTACLE_EDGE,
    OBSTACLE_FILL,
    RED,
    YELLOW,
    FieldImage,
    draw_level_lines,
    field_image,
    heatmap,
)
from apf_physics.render.video import write_png
from apf_physics.world.io.units import points_to_file, points_to_steps

if TYPE_CHECKING:
    from apf_physics.world.core import World

INK = (20, 20, 20)
PAPER = (255, 255, 255)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
COLOUR_BAR_TICKS = 6


def draw_field_plot(
    world: World,
    paths: Sequence[np.ndarray] = (),
    *,
    reached: Sequence[bool] | None = None,
    long_side: int = 512,
    image: FieldImage | None = None,
) -> np.ndarray:
    """The field image with ``paths`` drawn over it (the map alone; see :func:`field_figure`).

    Args:
        world: The world.
        paths: ``(n_i, 2)`` robot paths in world coordinates, e.g. the episodes of a
            gradient-descent rollout from ``world.starts``.
        reached: Per path, whether it ended at a target; the ends of the others are marked
            with a blue ring. Default: judged by ``world.goal_tolerance``.
        long_side: Image size in pixels along the world's longer side.
        image: A prebuilt :class:`FieldImage` (overrides ``long_side``).

    Returns:
        ``(H, W, 3)`` uint8 RGB image, pixel for pixel the :class:`FieldImage`'s frame.
    """
    image = image if image is not None else field_image(world, long_side)
    frame = image.background.copy()
    image.draw_moving(frame, 0.0)   # moving obstacles (if any) where they start
    paths = [np.asarray(p, dtype=float).reshape(-1, 2) for p in paths]
    paths = [p for p in paths if len(p)]
    if reached is None:
        reached = [_at_target(world, p[-1]) for p in paths]
    for path in paths:
        image.draw_path(frame, path, YELLOW)
    image.draw_targets(frame)
    for path, arrived in zip(paths, reached):
        image.draw_disc(frame, path[0], BLUE)
        if not arrived:
            image.draw_disc(frame, path[-1], BLUE, radius=0.7 * image.robot_radius, filled=False)
    return frame


def _at_target(world: World, point: np.ndarray) -> bool:
    return bool(world.reached(point)[0])


def field_figure(
    world: World,
    paths: Sequence[np.ndarray] = (),
    *,
    reached: Sequence[bool] | None = None,
    title: Sequence[str] = (),
    long_side: int = 512,
    image: FieldImage | None = None,
) -> np.ndarray:
    """The field plot as a figure: title lines above the map, axes in the world file's units along
    its left and bottom edges, colour bar and legend beside it.

    Arguments as :func:`draw_field_plot`, and ``title``: lines of text above the map.

    Returns:
        ``(H, W, 3)`` uint8 RGB image; the map sits at :func:`figure_map_origin`.
    """
    image = image if image is not None else field_image(world, long_side)
    plot = draw_field_plot(world, paths, reached=reached, image=image)
    unit = _unit(image)
    header = _header_height(len(title), unit)
    left, below = _axis_margins(unit)
    panel = _SidePanel(image, unit, top=header)
    rows = header + max(plot.shape[0] + below, panel.height)
    cols = left + plot.shape[1] + panel.width
    figure = np.full((rows, cols, 3), PAPER, np.uint8)
    figure[header: header + plot.shape[0], left: left + plot.shape[1]] = plot
    for i, line in enumerate(title):
        _text(figure, line, (round(6 * unit), round((22 * i + 18) * unit)), unit, scale=1.15 if i == 0 else 1.0)
    _draw_axes(figure, world, image, (header, left), unit)
    panel.draw(figure, left=left + plot.shape[1])
    return figure


def figure_map_origin(title_lines: int, image: FieldImage) -> tuple[int, int]:
    """``(row, col)`` of the map's top-left pixel in a :func:`field_figure` with that many title lines."""
    unit = _unit(image)
    return _header_height(title_lines, unit), _axis_margins(unit)[0]


AXIS_TICKS = 6
"""About how many labelled ticks each axis of a field figure has."""


def axis_label(world: World, axis: str) -> str:
    """``x [m]``: an axis of a field figure in the world file's units; ``x [steps]`` for a file that names
    no unit and moves a unit a step, else ``x [file units]``."""
    frame = world.frame
    unit = frame.name or ("steps" if frame.unit == 1.0 else "file units")
    return f"{axis} [{unit}]"


def nice_ticks(lo: float, hi: float, count: int = AXIS_TICKS) -> np.ndarray:
    """Round tick values (1, 2, 2.5 or 5 times a power of ten apart) within ``[lo, hi]``, about ``count`` of them."""
    span = max(hi - lo, 1e-12)
    raw = span / max(count - 1, 1)
    power = 10.0 ** np.floor(np.log10(raw))
    step = min((m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw), default=10 * power)
    first = np.ceil(lo / step - 1e-9) * step
    ticks = np.arange(first, hi + step * 1e-9, step)
    return np.round(ticks, 10)


def _tick_text(value: float) -> str:
    return f"{value:.6g}" if abs(value) >= 1e-9 else "0"


def _axis_margins(unit: float) -> tuple[int, int]:
    """``(left, below)`` pixels the axes' tick labels and names take beside and below the map."""
    return round(62 * unit), round(40 * unit)


def _draw_axes(figure: np.ndarray, world: World, image: FieldImage, origin: tuple[int, int], unit: float) -> None:
    """Ticks and labels in the world file's coordinates along the map's left and bottom edges."""
    top, left = origin
    height, width = image.shape[:2]
    frame = world.frame
    lo, hi = points_to_file(frame, [0.0, 0.0]), points_to_file(frame, world.size)
    tick = max(3, round(5 * unit))
    cv2.line(figure, (left - 1, top), (left - 1, top + height), INK, 1)
    cv2.line(figure, (left - 1, top + height), (left + width, top + height), INK, 1)
    for value in nice_ticks(lo[0], hi[0]):
        x = left + int(round(image.to_pixels(points_to_steps(frame, [value, lo[1]]))[0, 0]))
        cv2.line(figure, (x, top + height), (x, top + height + tick), INK, 1)
        text = _tick_text(value)
        w = cv2.getTextSize(text, _FONT, 0.45 * unit, max(1, round(unit)))[0][0]
        _text(figure, text, (x - w // 2, top + height + tick + round(13 * unit)), unit)
    for value in nice_ticks(lo[1], hi[1]):
        y = top + int(round(image.to_pixels(points_to_steps(frame, [lo[0], value]))[0, 1]))
        cv2.line(figure, (left - 1 - tick, y), (left - 1, y), INK, 1)
        text = _tick_text(value)
        w = cv2.getTextSize(text, _FONT, 0.45 * unit, max(1, round(unit)))[0][0]
        _text(figure, text, (left - tick - 4 - w, y + round(5 * unit)), unit)
    name = axis_label(world, "x")
    w = cv2.getTextSize(name, _FONT, 0.45 * unit, max(1, round(unit)))[0][0]
    _text(figure, name, (left + (width - w) // 2, top + height + tick + round(31 * unit)), unit)
    _text(figure, axis_label(world, "y"), (round(4 * unit), top - round(6 * unit)), unit)


def _unit(image: FieldImage) -> float:
    """Text and symbol scale: 1 for a 512-pixel map, at least 0.8 so small maps stay legible."""
    return max(0.8, image.font_scale / 0.45)


def _header_height(lines: int, unit: float) -> int:
    """Rows above the map: the title's lines, then room for the y axis's name."""
    return round((22 * lines + 8) * unit) + round(16 * unit)


def _text(figure: np.ndarray, text: str, origin: tuple[int, int], unit: float, scale: float = 1.0,
          colour=INK) -> None:
    cv2.putText(figure, text, origin, _FONT, 0.45 * unit * scale, colour, max(1, round(unit)), cv2.LINE_AA)


class _SidePanel:
    """The colour bar of the potential (with the level lines' bands) and the legend, beside the map."""

    LEGEND = ("path", "start", "ended short of a target", "target", "obstacle", "level line of U")

    def __init__(self, image: FieldImage, unit: float, top: int):
        self.image, self.unit, self.top = image, unit, top
        self.bar_top = top + round(34 * unit)
        self.bar_height = max(round(220 * unit), round(0.5 * image.shape[0]))
        self.legend_top = self.bar_top + self.bar_height + round(30 * unit)
        self.row = round(20 * unit)
        self.width = round(230 * unit)
        self.height = self.legend_top - top + self.row * len(self.LEGEND) + round(6 * unit)

    def draw(self, figure: np.ndarray, left: int) -> None:
        self._colour_bar(figure, left + round(14 * self.unit))
        self._legend(figure, left + round(14 * self.unit))

    def _colour_bar(self, figure: np.ndarray, x: int) -> None:
        unit, image = self.unit, self.image
        width = round(18 * unit)
        _text(figure, f"potential U ({image.scaling} scale)", (x - round(6 * unit), self.bar_top - round(12 * unit)),
              unit)
        # Shade 1 at the top, 0 at the bottom: the map's colours and band edges, as a column.
        shade = np.linspace(1.0, 0.0, self.bar_height, dtype=np.float32)[:, None].repeat(width, axis=1)
        strip = np.ascontiguousarray(heatmap(shade))
        draw_level_lines(strip, shade, image.levels, thickness=1)
        figure[self.bar_top: self.bar_top + self.bar_height, x: x + width] = strip
        cv2.rectangle(figure, (x - 1, self.bar_top - 1), (x + width, self.bar_top + self.bar_height), INK, 1)
        samples = len(image.shade_potential) - 1
        for k in range(COLOUR_BAR_TICKS):
            fraction = k / (COLOUR_BAR_TICKS - 1)
            value = float(image.shade_potential[round(fraction * samples)])
            y = self.bar_top + round((1.0 - fraction) * (self.bar_height - 1))
            cv2.line(figure, (x + width, y), (x + width + round(5 * unit), y), INK, 1)
            # The top of the scale saturates: everything above it has the top colour.
            label = f">= {value:.3g}" if k == COLOUR_BAR_TICKS - 1 else f"{value:.3g}"
            _text(figure, label, (x + width + round(9 * unit), y + round(5 * unit)), unit)

    def _legend(self, figure: np.ndarray, x: int) -> None:
        unit = self.unit
        radius = max(3, round(5 * unit))
        for i, label in enumerate(self.LEGEND):
            y = self.legend_top + i * self.row
            centre = (x + round(9 * unit), y)
            if label == "path":
                cv2.line(figure, (x, y), (x + round(18 * unit), y), DARK_HALO, max(2, round(4 * unit)), cv2.LINE_AA)
                cv2.line(figure, (x, y), (x + round(18 * unit), y), YELLOW, max(1, round(2 * unit)), cv2.LINE_AA)
            elif label == "start":
                cv2.circle(figure, centre, radius + 1, DARK_HALO, -1, cv2.LINE_AA)
                cv2.circle(figure, centre, radius, BLUE, -1, cv2.LINE_AA)
            elif label.startswith("ended"):
                cv2.circle(figure, centre, radius, BLUE, max(2, round(2 * unit)), cv2.LINE_AA)
            elif label == "target":
                cv2.circle(figure, centre, radius + 1, DARK_HALO, -1, cv2.LINE_AA)
                cv2.circle(figure, centre, radius, RED, -1, cv2.LINE_AA)
            elif label == "obstacle":
                corner = (x + round(2 * unit), y - radius), (x + round(16 * unit), y + radius)
                cv2.rectangle(figure, *corner, OBSTACLE_FILL, -1)
                cv2.rectangle(figure, *corner, OBSTACLE_EDGE, 1)
            else:
                cv2.line(figure, (x, y), (x + round(18 * unit), y), LEVEL_LINE, max(1, round(unit)), cv2.LINE_AA)
            _text(figure, label, (x + round(26 * unit), y + round(5 * unit)), unit)


def plot_field(
    world: World,
    paths: Sequence[np.ndarray],
    out_path: str | Path,
    *,
    reached: Sequence[bool] | None = None,
    title: Sequence[str] = (),
    long_side: int = 512,
    image: FieldImage | None = None,
) -> np.ndarray:
    """Draw the field figure (see :func:`field_figure`) and write it as a PNG file.

    Returns:
        The image that was written.

    Raises:
        UserError: the file cannot be written (the message names the path).
    """
    figure = field_figure(world, paths, reached=reached, title=title, long_side=long_side, image=image)
    write_png(figure, out_path)
    return figure
