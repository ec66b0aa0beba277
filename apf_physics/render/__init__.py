"""Rendering: state snapshots to RGB frames, frames to videos and images.

- :mod:`~apf_physics.render.drawing`: :class:`FieldImage` (the static picture of a world,
  built once) and the pure :func:`draw_frame` (snapshot → ``uint8 (H, W, 3)`` RGB).
- :mod:`~apf_physics.render.video`: trajectories to frames, frames to MP4/WebM/AVI and PNG.
- :mod:`~apf_physics.render.field_plot`: the level-line plot with paths (thesis Fig. 22–23).
"""

from apf_physics.render.drawing import FieldImage, Snapshot, draw_frame, field_image, formation_roles, robot_colours
from apf_physics.render.field_plot import draw_field_plot, plot_field
from apf_physics.render.video import (
    VideoWriter,
    render_trajectory,
    stack_paths,
    trajectory_snapshots,
    write_png,
    write_video,
)

__all__ = [
    "FieldImage",
    "Snapshot",
    "VideoWriter",
    "draw_field_plot",
    "draw_frame",
    "field_image",
    "formation_roles",
    "plot_field",
    "render_trajectory",
    "robot_colours",
    "stack_paths",
    "trajectory_snapshots",
    "write_png",
    "write_video",
]
