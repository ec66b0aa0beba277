"""The field plot of thesis Fig. 22–23: level lines of the potential with robot paths over them.

Paths are yellow, each start a blue robot disc, the targets red dots and the obstacles
white; a path that did not end at a target (trapped, collided) ends in a blue ring, so the
traps stand out.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from apf_physics.render.drawing import BLUE, YELLOW, FieldImage, field_image
from apf_physics.render.video import write_png

if TYPE_CHECKING:
    from apf_physics.world import World


def draw_field_plot(
    world: World,
    paths: Sequence[np.ndarray] = (),
    *,
    reached: Sequence[bool] | None = None,
    title: Sequence[str] = (),
    long_side: int = 512,
    image: FieldImage | None = None,
) -> np.ndarray:
    """The field image with ``paths`` drawn over it.

    Args:
        world: The world.
        paths: ``(n_i, 2)`` robot paths in world coordinates, e.g. the episodes of a
            gradient-descent rollout from ``world.starts``.
        reached: Per path, whether it ended at a target; the ends of the others are marked
            with a blue ring. Default: judged by ``world.goal_tolerance``.
        title: Text lines in the top-left corner.
        long_side: Image size in pixels along the world's longer side.
        image: A prebuilt :class:`FieldImage` (overrides ``long_side``).

    Returns:
        ``(H, W, 3)`` uint8 RGB image.
    """
    image = image if image is not None else field_image(world, long_side)
    frame = image.background.copy()
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
    image.draw_text(frame, list(title))
    return frame


def _at_target(world: World, point: np.ndarray) -> bool:
    return bool(np.min(np.linalg.norm(world.targets - point, axis=1)) <= world.goal_tolerance)


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
    """Draw the field plot (see :func:`draw_field_plot`) and write it as a PNG file.

    Returns:
        The image that was written.

    Raises:
        UserError: the file cannot be written (the message names the path).
    """
    frame = draw_field_plot(world, paths, reached=reached, title=title, long_side=long_side, image=image)
    write_png(frame, out_path)
    return frame
