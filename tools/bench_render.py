#!/usr/bin/env python
"""Benchmark rendering: frames per second drawing 512×512 frames, and drawing + writing videos.

Prints one table: the background build once per world, then frames per second for drawing
only, and per codec side by side (H.264 and VP9 through PyAV, mp4v and MJPG through OpenCV)
writing pre-drawn frames only and drawing + writing. The scene is the bundled 20×20 world
``fixed20`` with a three-robot formation whose trails grow over 200-step episodes, and
overlay text (the rollout's default step limit there is 160), and a 50×50 world for the
background build. Medians over ``--repeats`` runs.

Example::

    python tools/bench_render.py --frames 600 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from apf_physics import load_world, world_from_dict
from apf_physics.world.bundled import bundled_dir
from apf_physics.render import (CODECS, FieldImage, draw_frame, formation_roles, render_trajectory,
                                trajectory_snapshots, write_video)

WORLD_50 = {
    "name": "bench50", "size": [50, 50], "robot_radius": 0.25, "field": "thesis-general",
    "obstacles": [{"polygon": [[10, 20], [30, 20], [30, 22], [10, 22]]},
                  {"polygon": [[35, 30], [40, 30], [40, 45], [35, 45]]},
                  {"polygon": [[5, 35], [12, 30], [14, 40]]},
                  {"circle": {"center": [20, 35], "radius": 0}}],
    "targets": [[25, 40]],
}

WORLD_20 = {
    "name": "bench20", "size": [20, 20], "robot_radius": 0.25, "field": "thesis-fixed",
    "obstacles": [{"polygon": [[4, 8], [9, 8], [9, 10], [4, 10]]},
                  {"polygon": [[12, 3], [14, 3], [14, 9], [12, 9]]},
                  {"circle": {"center": [6, 15], "radius": 1}}],
    "targets": [[16, 16]],
}


def formation_trajectory(steps: int = 200) -> np.ndarray:
    """A three-robot line wandering across a 20×20 map, ``(steps, 3, 2)``."""
    t = np.linspace(0.0, 1.0, steps)
    leader = np.column_stack([2 + 14 * t, 2 + 14 * t + 2 * np.sin(6 * np.pi * t)])
    offsets = np.array([[0.0, 0.0], [-0.7, -0.7], [-1.4, -1.4]])
    return np.clip(leader[:, None, :] + offsets[None], 0.5, 19.5)


def frames(world, image: FieldImage, trajectory: np.ndarray, count: int, pure: bool = False):
    """``count`` frames, cycling through the trajectory's episode (trails restart each cycle).

    ``pure``: :func:`draw_frame` per snapshot, every trail redrawn each frame (the env's
    ``rgb_array``); otherwise :func:`render_trajectory`, which grows a trail layer (videos).
    """
    roles = formation_roles(trajectory.shape[1])
    overlay = ("planner bench", f"world {world.name}")
    produced = 0
    while produced < count:
        if pure:
            episode = (draw_frame(image, s) for s in trajectory_snapshots(trajectory, roles, overlay=overlay))
        else:
            episode = render_trajectory(world, trajectory, roles, overlay=overlay, image=image)
        for frame in episode:
            yield frame
            produced += 1
            if produced >= count:
                return


def timed(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` over ``repeats`` runs [s]."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=600, help="frames per measurement (default 600)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement; the median is shown")
    parser.add_argument("--size", type=int, default=512, help="pixels along the longer side (default 512)")
    args = parser.parse_args(argv)

    seed = bundled_dir() / "fixed20.yaml"
    world20 = load_world(seed) if seed.is_file() else world_from_dict(WORLD_20)
    world50 = world_from_dict(WORLD_50)
    trajectory = formation_trajectory()
    n = args.frames
    rows: list[tuple[str, str]] = []

    for world in (world20, world50):
        def build(world=world):
            world.forget()  # include the raster, as the first frame of a new world pays it
            return FieldImage.from_world(world, args.size)
        rows.append((f"background build, {world.name} {world.size[0]:g}x{world.size[1]:g} (raster + heatmap)",
                     f"{timed(build, args.repeats) * 1e3:8.1f} ms"))

    image = FieldImage.from_world(world20, args.size)
    h, w = image.shape[:2]
    for pure, label in ((True, "draw_frame per snapshot (env rgb_array)"), (False, "render_trajectory (trail layer)")):
        draw_s = timed(lambda: sum(1 for _ in frames(world20, image, trajectory, n, pure)), args.repeats)
        rows.append((f"draw only, {label}, {w}x{h}",
                     f"{n / draw_s:8.0f} fps  ({draw_s / n * 1e3:.2f} ms/frame)"))
    predrawn = list(frames(world20, image, trajectory, n))

    with tempfile.TemporaryDirectory() as tmp:
        for name in ("h264", "vp9", "mp4v", "mjpg"):
            codec = CODECS[name]
            out = Path(tmp) / f"bench{codec.extension}"
            write_s = timed(lambda: write_video(predrawn, out, 10, codec=name), args.repeats)
            both_s = timed(lambda: write_video(frames(world20, image, trajectory, n), out, 10, codec=name),
                           args.repeats)
            kib = out.stat().st_size / 1024
            via = "PyAV" if codec.pyav else "OpenCV"
            rows.append((f"{codec.label} {codec.extension} ({via}): write only / draw + write",
                         f"{n / write_s:8.0f} / {n / both_s:4.0f} fps  ({kib / n:.1f} KiB/frame)"))

    width = max(len(label) for label, _ in rows)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"bench_render: {n} frames per measurement, median of {args.repeats}; "
          f"{os.cpu_count()} CPUs, load average {load:.1f} at the end")
    for label, value in rows:
        print(f"  {label:<{width}}  {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
