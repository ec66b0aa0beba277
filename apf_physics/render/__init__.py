"""Rendering: state snapshots to RGB frames, frames to videos and images, results to a page.

- :mod:`~apf_physics.render.drawing`: :class:`FieldImage` (the static picture of a world,
  built once) and the pure :func:`draw_frame` (snapshot → ``uint8 (H, W, 3)`` RGB).
- :mod:`~apf_physics.render.video`: trajectories to frames, frames to H.264 MP4, VP9 WebM,
  MJPG AVI and PNG.
- :mod:`~apf_physics.render.field_plot`: the level-line plot with paths (thesis Fig. 22–23),
  as a figure with a colour bar and a legend.
- :mod:`~apf_physics.render.episodes`: videos of rollout episodes.
- :mod:`~apf_physics.render.page`: the results page (``index.html`` with table, figures, videos).
"""

from apf_physics.render.drawing import FieldImage, Snapshot, draw_frame, field_image, formation_roles, robot_colours
from apf_physics.render.field_plot import draw_field_plot, field_figure, plot_field
from apf_physics.render.video import (
    CODECS,
    VideoWriter,
    choose_codec,
    render_trajectory,
    stack_paths,
    trajectory_snapshots,
    write_png,
    write_video,
)

__all__ = [
    "CODECS",
    "FieldImage",
    "Snapshot",
    "VideoWriter",
    "choose_codec",
    "draw_field_plot",
    "draw_frame",
    "field_figure",
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
