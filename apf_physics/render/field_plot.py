"""The field plot of thesis Fig. 22–23: level lines of the potential with robot paths over them.

Paths are yellow, each start a blue robot disc, the targets red dots and the obstacles
white; a path that did not end at a target (trapped, collided) ends in a blue ring, so the
traps stand out. As a figure (:func:`field_figure`, what ``plot-field`` writes) the map gets
a title above it and, beside it, a colour bar with the potential's scale and a legend, so
that nothing covers the map.
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
    """The field plot as a figure: title lines above the map, colour bar and legend beside it.

    Arguments as :func:`draw_field_plot`, and ``title``: lines of text above the map.

    Returns:
        ``(H, W, 3)`` uint8 RGB image; the map sits at :func:`figure_map_origin`.
    """
    image = image if image is not None else field_image(world, long_side)
    plot = draw_field_plot(world, paths, reached=reached, image=image)
    unit = _unit(image)
    header = _header_height(len(title), unit)
    panel = _SidePanel(image, unit, top=header)
    rows = header + max(plot.shape[0], panel.height)
    cols = plot.shape[1] + panel.width
    figure = np.full((rows, cols, 3), PAPER, np.uint8)
    figure[header: header + plot.shape[0], : plot.shape[1]] = plot
    for i, line in enumerate(title):
        _text(figure, line, (round(6 * unit), round((22 * i + 18) * unit)), unit, scale=1.15 if i == 0 else 1.0)
    panel.draw(figure, left=plot.shape[1])
    return figure


def figure_map_origin(title_lines: int, image: FieldImage) -> tuple[int, int]:
    """``(row, col)`` of the map's top-left pixel in a :func:`field_figure` with that many title lines."""
    return _header_height(title_lines, _unit(image)), 0


def _unit(image: FieldImage) -> float:
    """Text and symbol scale: 1 for a 512-pixel map, at least 0.8 so small maps stay legible."""
    return max(0.8, image.font_scale / 0.45)


def _header_height(lines: int, unit: float) -> int:
    return round((22 * lines + 8) * unit) if lines else 0


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
