"""Videos of fleets: hundreds of robots on one map, each with its goal in its own colour.

Legible at hundreds of robots: the map is drawn without its field (obstacles on a dark floor:
:meth:`~apf_physics.render.drawing.FieldImage.from_world` with ``field=False``); every robot has a
colour of its own (hues spread by the golden ratio, so neighbours in the list differ), its goal is
a square outline in that colour, a thin line joins a robot to its goal while it is on its way (so
the eye can match them; in fleets of a few dozen: more would cross the whole map), and the trail is only the last few steps, fading (no trail buries the
map). A robot on its goal is drawn filled inside its square.
"""

from __future__ import annotations

import colorsys
from pathlib import Path
from typing import Callable, Iterator, Sequence

import cv2
import numpy as np

from apf_physics.render.drawing import DARK_HALO, FieldImage
from apf_physics.render.video import write_png, write_video
from apf_physics.world.core import World

TAIL = 6
"""Steps of trail drawn behind each robot."""
LINES_UP_TO = 40
"""Fleets of at most this many robots have a faint line from each robot to its goal."""
_SHIFT = 4
_ONE = 1 << _SHIFT


def fleet_colours(count: int) -> np.ndarray:
    """(count, 3) uint8 RGB: bright hues spread by the golden ratio, every third a little darker."""
    out = np.empty((count, 3), np.uint8)
    for i in range(count):
        hue = (i * 0.6180339887) % 1.0
        value = 1.0 if i % 3 else 0.8
        out[i] = np.round(np.array(colorsys.hsv_to_rgb(hue, 0.75, value)) * 255)
    return out


def fleet_image(world: World, long_side: int, caption: str = "below") -> FieldImage:
    """The map as a fleet's frames show it (no field, no targets)."""
    return FieldImage.from_world(world, long_side, caption=caption, field=False)


def fleet_frame(image: FieldImage, positions: np.ndarray, goals: np.ndarray, step: int, colours: np.ndarray,
                lines: Sequence[str] = (), tail: int = TAIL, lines_to_goals: bool | None = None) -> np.ndarray:
    """One frame of a fleet at ``step``: trails, goal squares, lines to goals, robots, text.

    Args:
        image: The map (:func:`fleet_image`).
        positions: ``(steps + 1, N, 2)`` every robot's positions.
        goals: ``(steps + 1, N, 2)`` every robot's goal at every step (NaN: none drawn, e.g. a
            formation's follower).
        step: The step shown.
        colours: (N, 3) each robot's colour (:func:`fleet_colours`).
        lines: Text for the caption.
        tail: Steps of trail.
        lines_to_goals: Join each robot on its way to its goal by a faint line (default: for at most
            :data:`LINES_UP_TO` robots; more would cross the whole map).
    """
    frame = image.background.copy()
    if lines_to_goals is None:
        lines_to_goals = positions.shape[1] <= LINES_UP_TO
    now, goal = positions[step], goals[step]
    px = lambda points: np.round((image.to_pixels(points) - 0.5) * _ONE).astype(np.int32)  # noqa: E731
    # robots drawn a little larger than their discs (0.42 of a step: they stand a step apart), goals as
    # squares a step wide, trails a third of a step: legible at a few pixels per step
    r = max(1.5, 0.45 * image.scale)
    width = max(1, int(round(0.3 * image.scale)))
    has_goal = ~np.isnan(goal[:, 0])
    home = has_goal & (np.hypot(*(now - np.where(has_goal[:, None], goal, now)).T) < 1e-6)
    for k in range(max(0, step - tail), step):   # the trail, older steps dimmer
        fade = 0.25 + 0.5 * (k - step + tail + 1) / (tail + 1)
        a, b = px(positions[k]), px(positions[k + 1])
        for i in np.flatnonzero(np.any(positions[k] != positions[k + 1], axis=1)).tolist():
            cv2.line(frame, tuple(a[i]), tuple(b[i]), tuple(int(c * fade) for c in colours[i]), width, cv2.LINE_AA,
                     _SHIFT)
    g, p = px(np.where(has_goal[:, None], goal, now)), px(now)
    side = int(round(0.5 * image.scale * _ONE))
    for i in np.flatnonzero(has_goal).tolist():
        colour = tuple(int(c) for c in colours[i])
        if lines_to_goals and not home[i]:   # a faint line from the robot to its goal
            cv2.line(frame, tuple(p[i]), tuple(g[i]), tuple(int(c * 0.3) for c in colours[i]), 1, cv2.LINE_AA, _SHIFT)
        cv2.rectangle(frame, (int(g[i][0] - side), int(g[i][1] - side)), (int(g[i][0] + side), int(g[i][1] + side)),
                      colour, 1, cv2.LINE_AA, _SHIFT)
    radius = int(round(r * _ONE))
    for i in range(len(now)):
        colour = tuple(int(c) for c in colours[i])
        cv2.circle(frame, tuple(p[i]), radius + _ONE // 2, DARK_HALO, -1, cv2.LINE_AA, _SHIFT)
        cv2.circle(frame, tuple(p[i]), radius, colour, -1, cv2.LINE_AA, _SHIFT)
    return image.draw_text(frame, lines)


def write_fleet_video(world: World, positions: np.ndarray, goals: np.ndarray, path: str | Path, *, fps: float = 10.0,
                      size: int = 2048, hold: float = 1.0, caption: Callable[[int], Sequence[str]] | None = None,
                      caption_place: str = "below", codec: str | None = None, progress: bool = False,
                      png: str | Path | None = None) -> int:
    """Write a fleet's run as a video (and its last frame as a PNG); returns the frames written.

    Args:
        world: The map.
        positions: ``(steps + 1, N, 2)`` every robot's positions.
        goals: ``(steps + 1, N, 2)`` every robot's goal at every step.
        path: ``.mp4``, ``.webm`` or ``.avi``.
        fps: Frames (steps) per second.
        size: Pixels along the map's longer side.
        hold: Seconds the last frame stays.
        caption: The caption's lines at a step (the same number of lines at every step).
        caption_place: :data:`~apf_physics.render.drawing.CAPTIONS`.
        codec: See :func:`~apf_physics.render.video.choose_codec`.
        progress: A progress bar on a terminal.
        png: Also write the last frame here.
    """
    image = fleet_image(world, size, caption_place)
    colours = fleet_colours(positions.shape[1])
    steps = len(positions) - 1
    lines = caption or (lambda step: ())

    def frames() -> Iterator[np.ndarray]:
        for step in range(steps + 1):
            frame = fleet_frame(image, positions, goals, step, colours, lines(step))
            yield from [frame] * (1 + (int(round(hold * fps)) if step == steps else 0))
            if step == steps and png is not None:
                write_png(frame, png)

    return write_video(frames(), path, fps, codec=codec, progress=progress,
                       total=steps + 1 + int(round(hold * fps)))
