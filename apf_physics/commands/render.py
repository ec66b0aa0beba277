"""``apf-physics render WORLD --planner P --out run.mp4``: a video of a planner's run(s) in a world."""

from __future__ import annotations

import argparse
from collections import Counter
from typing import Iterator, Sequence

import numpy as np
PROGRESS_MIN_FRAMES = 300  # shorter renders take well under a second: no progress bar


def add_parser(subparsers) -> None:
    """Register the ``render`` subcommand."""
    parser = subparsers.add_parser(
        "render",
        help="render a planner's run in a world to a video (and optionally a PNG of the last frame)",
        description="Run a planner from one start (--start K) or from all of the world's starts at once "
                    "(--all-starts) and write the run as a video: .mp4 (mp4v; VLC plays it, browsers do "
                    "not, see --h264), .webm (VP8) or .avi (MJPG).",
    )
    add_arguments(parser)
    parser.set_defaults(func=run)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The subcommand's options, on any parser (the CLI's subparser or ``tools/render_video.py``)."""
    parser.add_argument("world", help="world file (.yaml)")
    parser.add_argument("--planner", default="gradient", help="planner name (default: gradient)")
    parser.add_argument("--model", default=None, help="model file for learned planners")
    parser.add_argument("--formation", action="store_true",
                        help="run the world's formation: the planner steers the leader, followers follow")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--start", type=int, default=0, metavar="K",
                       help="index of the world's start to run (default 0)")
    which.add_argument("--all-starts", action="store_true",
                       help="run every start of the world: single robots all at once in one video, "
                            "formations one after another")
    parser.add_argument("--out", required=True, help="output video (.mp4, .webm or .avi)")
    parser.add_argument("--png", default=None, help="also write the last frame to this .png file")
    parser.add_argument("--fps", type=float, default=10.0, help="frames (control steps) per second (default 10)")
    parser.add_argument("--size", type=int, default=512, help="pixels along the world's longer side (default 512)")
    parser.add_argument("--hold", type=float, default=1.0, help="seconds the last frame stays on screen (default 1)")
    parser.add_argument("--max-steps", type=int, default=None, help="step limit per episode (default: the rollout's)")
    parser.add_argument("--h264", action="store_true",
                        help="write browser-playable H.264 (.mp4 only; needs the imageio-ffmpeg package)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar (shown for long renders only)")


def run(args: argparse.Namespace) -> int:
    """Run the planner, render and write the video; returns the exit status."""
    from apf_physics import load_world
    from apf_physics.errors import UserError
    from apf_physics.planners import make_planner
    from apf_physics.render.drawing import FieldImage
    from apf_physics.render.video import FOURCC_BY_EXTENSION, check_writable, render_trajectory, write_png, write_video
    from apf_physics.rollout import rollout

    out = check_writable(args.out, tuple(FOURCC_BY_EXTENSION))
    if args.h264 and out.suffix.lower() != ".mp4":
        raise UserError(f"cannot write {out}: --h264 needs an .mp4 file")
    png = check_writable(args.png, (".png",)) if args.png else None
    if args.fps <= 0:
        raise UserError(f"--fps must be positive, got {args.fps:g}")
    if args.size < 16:
        raise UserError(f"--size must be at least 16 pixels, got {args.size}")
    world = load_world(args.world)
    if not len(world.starts):
        raise UserError(f"{world.source or world.name}: the world has no starts to run from")
    if args.all_starts:
        starts = world.starts
    elif not 0 <= args.start < len(world.starts):
        raise UserError(f"--start {args.start}: {world.source or world.name} has starts 0..{len(world.starts) - 1}")
    else:
        starts = world.starts[args.start: args.start + 1]

    planner = make_planner(args.planner, model=args.model)
    if args.formation:
        try:
            from apf_physics.formation import rollout_formation
        except ImportError:
            raise UserError("--formation: formation runs are not part of this build") from None
        # Contract: one episode per start, its positions (steps + 1, robots, 2), leader first.
        episodes = rollout_formation(world, planner, starts, max_steps=args.max_steps)
    else:
        episodes = rollout(world, planner, starts, max_steps=args.max_steps)

    image = FieldImage.from_world(world, args.size)
    hold = max(0, int(round(args.hold * args.fps)))
    overlay = (f"world {world.name}", f"planner {args.planner}")
    start_index = None if args.all_starts else args.start
    clips = list(_clips(episodes, overlay, bool(args.formation), start_index))
    total = sum(len(trajectory) + hold for trajectory, *_ in clips)

    last: list[np.ndarray] = []

    def frames() -> Iterator[np.ndarray]:
        for trajectory, roles, lines, final in clips:
            for frame in render_trajectory(world, trajectory, roles, overlay=lines, final_overlay=final,
                                           hold=hold, image=image):
                yield frame
        last.append(frame)

    written = write_video(frames(), out, args.fps, codec="h264" if args.h264 else None,
                          progress=not args.no_progress and total >= PROGRESS_MIN_FRAMES, total=total)
    if png is not None:
        write_png(last[-1], png)
    counts = Counter(episode.outcome for episode in episodes)
    print(f"wrote {out} ({written} frames at {args.fps:g} fps; "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + ")"
          + (f" and {png}" if png is not None else ""))
    return 0


def _clips(episodes: Sequence, overlay: tuple[str, ...], formation: bool,
           start_index: int | None) -> Iterator[tuple[np.ndarray, tuple[str, ...], tuple[str, ...], tuple[str, ...]]]:
    """``(trajectory (T, R, 2), roles, overlay, final overlay)`` per clip of the video.

    Single robots from several starts share one clip (all move at once); each formation
    episode is a clip of its own, one after another.
    """
    from apf_physics.render.drawing import formation_roles
    from apf_physics.render.video import stack_paths

    paths = [np.asarray(getattr(episode, "positions", episode.path), dtype=float) for episode in episodes]
    if not formation and all(p.ndim == 2 for p in paths):
        counts = Counter(episode.outcome for episode in episodes)
        if len(episodes) == 1:
            episode = episodes[0]
            where = f"start {start_index} " if start_index is not None else ""
            lines = (*overlay, f"{where}({episode.start[0]:g}, {episode.start[1]:g})")
            final = (f"outcome {episode.outcome} after {episode.steps} steps",)
        else:
            lines = (*overlay, f"{len(episodes)} starts")
            final = (", ".join(f"{k} {v}" for k, v in sorted(counts.items())),)
        yield stack_paths(paths), ("single",) * len(paths), lines, final
        return
    for i, (episode, path) in enumerate(zip(episodes, paths)):
        trajectory = path if path.ndim == 3 else path[:, None, :]
        index = start_index if start_index is not None else i
        lines = (*overlay, f"formation, start {index}")
        yield (trajectory, formation_roles(trajectory.shape[1]), lines,
               (f"outcome {episode.outcome} after {episode.steps} steps",))
