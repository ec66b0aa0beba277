"""``apf-physics render WORLD --planner P --out run.mp4``: a video of a planner's run(s) in a world."""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from apf_physics.errors import UserError
from apf_physics.planners import make_planner
from apf_physics.render.drawing import CAPTIONS
from apf_physics.render.episodes import write_episode_video
from apf_physics.common.safefile import check_writable
from apf_physics.render.video import VIDEO_EXTENSIONS, choose_codec
from apf_physics.world.kinematics import KINEMATICS
from apf_physics.experiments.fleet import rollout_fleet
from apf_physics.experiments.movingai import scenario_fleet
from apf_physics.experiments.rollout import kinematics_option, rollout, rollout_formations
from apf_physics.render.fleet import write_fleet_video
from apf_physics.world.io.worldfile import load_world


def add_parser(subparsers) -> None:
    """Register the ``render`` subcommand."""
    parser = subparsers.add_parser(
        "render",
        help="render a planner's run in a world to a video (and optionally a PNG of the last frame)",
        description="Run a planner from one start (--start K) or from all of the world's starts at once "
                    "(--all-starts) and write the run as a video: .mp4 (H.264, plays in browsers), .webm "
                    "(VP9, plays in browsers) or .avi (MJPG); --codec mp4v writes the older MPEG-4 Part 2 "
                    "in .mp4 (desktop players only).",
    )
    add_arguments(parser)
    parser.set_defaults(func=run)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The subcommand's options, on any parser (the CLI's subparser or ``tools/render_video.py``)."""
    parser.add_argument("world", help="world file (.yaml), or a bundled world's name (fixed20, thesis/test1); with "
                                      "--scen, a MovingAI .map")
    parser.add_argument("--scen", metavar="FILE.scen", help="with --agents: a fleet of the first N lines of FILE on "
                                                            "the .map (a world file with 'robots:' is a fleet already)")
    parser.add_argument("--agents", type=int, metavar="N", help="with --scen: robots in the fleet")
    parser.add_argument("--lifelong", type=int, metavar="STEPS",
                        help="fleets: run STEPS steps, each robot given its next goal as soon as it arrives")
    parser.add_argument("--seed", type=int, default=0, help="fleets: the lifelong goal streams' seed (default 0)")
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
    parser.add_argument("--out", required=True, help="output video (.mp4, .webm or .avi); a missing folder is created")
    parser.add_argument("--png", default=None, help="also write the last frame to this .png file")
    parser.add_argument("--fps", type=float, default=10.0, help="frames (control steps) per second (default 10)")
    parser.add_argument("--size", type=int, default=None,
                        help="pixels along the world's longer side (default 512; a fleet's 2048)")
    parser.add_argument("--hold", type=float, default=1.0, help="seconds the last frame stays on screen (default 1)")
    parser.add_argument("--max-steps", type=int, default=None, help="step limit per episode (default: the rollout's)")
    parser.add_argument("--kinematics", default=None, metavar="KIND",
                        help=f"robot kind: {' or '.join(KINEMATICS)} (default: the world file's robot.kinematics); "
                             "unicycles drive the planner's moves and are drawn with their heading")
    parser.add_argument("--codec", default=None, metavar="CODEC",
                        help="h264 (.mp4, the default there), vp9 (.webm, the default there), mjpg (.avi), or "
                             "mp4v (.mp4 through OpenCV: browsers do not play it; the fallback without PyAV)")
    # Before 0.2 H.264 needed --h264 (and imageio-ffmpeg); it is now the .mp4 default.
    parser.add_argument("--h264", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--caption", choices=CAPTIONS, default="below",
                        help="where the text (step, world, planner, start, outcome) goes: below the map in a band "
                             "of its own (default; it never hides the map), over the map's top-left corner, or off")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar (it shows only on a terminal)")


def run(args: argparse.Namespace) -> int:
    """Run the planner, render and write the video; returns the exit status."""
    unicycle = kinematics_option(args.kinematics)
    out = check_writable(args.out, VIDEO_EXTENSIONS, create_parent=True)
    codec = choose_codec(out, args.codec or ("h264" if args.h264 else None))
    png = check_writable(args.png, (".png",), create_parent=True) if args.png else None
    if args.fps <= 0:
        raise UserError(f"--fps must be positive, got {args.fps:g}")
    if args.size is not None and args.size < 16:
        raise UserError(f"--size must be at least 16 pixels, got {args.size}")
    if (args.scen is None) != (args.agents is None):
        raise UserError("--scen and --agents: give both (a fleet of the first N lines of a scenario file)")
    if args.scen is not None:
        world, fleet = scenario_fleet(args.world, args.scen, args.agents)
        return render_fleet(args, world, fleet, out, codec, png)
    world = load_world(args.world)
    if world.robots is not None:
        return render_fleet(args, world, world.robots, out, codec, png)
    if args.lifelong is not None:
        raise UserError("--lifelong: only for fleets (--scen and --agents, or a world file with 'robots:')")
    args.size = 512 if args.size is None else args.size
    if not len(world.starts):
        raise UserError(f"{world.source or world.name}: the world has no starts to run from")
    if args.all_starts:
        starts = world.starts
    elif not 0 <= args.start < len(world.starts):
        raise UserError(f"--start {args.start}: {world.source or world.name} has starts 0..{len(world.starts) - 1}")
    else:
        starts = world.starts[args.start: args.start + 1]

    planner = make_planner(args.planner, model=args.model)
    if args.formation and world.formations:   # every formation at once, each to its own target
        episodes = rollout_formations(world, planner, max_steps=args.max_steps, unicycle=unicycle)
    else:
        episodes = rollout(world, planner, starts, max_steps=args.max_steps, formation=bool(args.formation),
                           unicycle=unicycle)

    written = write_episode_video(world, episodes, out, png=png, fps=args.fps, size=args.size, hold=args.hold,
                                  overlay=(f"world {world.name}", f"planner {args.planner}"),
                                  formation=bool(args.formation),
                                  start_index=None if args.all_starts else args.start,
                                  codec=codec.name, progress=not args.no_progress, caption=args.caption)
    counts = Counter(episode.outcome for episode in episodes)
    playable = "" if codec.browsers else ", which browsers do not play" + (
        "" if args.codec else " (write .mp4 for H.264 or .webm for VP9)" if out.suffix.lower() != ".mp4"
        else " (PyAV is not installed: pip install av for H.264)")
    print(f"wrote {out} ({codec.label}{playable}; {written} frames at {args.fps:g} fps; "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + ")"
          + (f" and {png}" if png is not None else ""))
    return 0


def render_fleet(args: argparse.Namespace, world, fleet, out, codec, png) -> int:
    """A fleet's run (:func:`~apf_physics.experiments.fleet.rollout_fleet`) as a video: every robot in a
    colour of its own, its goal a square of that colour (:mod:`apf_physics.render.fleet`)."""
    if args.formation or args.all_starts or args.kinematics is not None:
        raise UserError("--formation, --all-starts, --kinematics: not with fleets")
    planner = make_planner(args.planner, model=args.model)
    run = rollout_fleet(world, planner, fleet, max_steps=args.max_steps, lifelong=args.lifelong, seed=args.seed)
    summary = run.summary()
    positions, goals = run.drawn()
    home = np.hypot(*(run.positions - goals[:, :len(fleet)]).transpose(2, 0, 1)) < 1e-6
    reached = np.concatenate([[0], np.cumsum(np.sum(home[1:] & ((run.goals[1:] != run.goals[:-1]) | ~home[:-1]), axis=1))])

    def caption(step: int) -> list[str]:
        tally = (f"goals reached {reached[step]}" if run.lifelong is not None
                 else f"on their goal {int(home[step].sum())}/{len(fleet)}")
        return [f"{world.name}  planner {planner.name}  step {step}/{run.steps}",
                f"{len(fleet)} robots: {tally}; robot-robot collisions {summary['robot_robot_collisions']}, "
                f"robot-obstacle {summary['robot_obstacle_collisions']}"]

    written = write_fleet_video(world, positions, goals, out, fps=args.fps, size=args.size or 2048, hold=args.hold,
                                caption=caption, caption_place=args.caption, codec=codec.name,
                                progress=not args.no_progress, png=png)
    tally = (f"{summary['goals_reached']} goals, {summary['throughput']:.3f} per step" if run.lifelong is not None
             else f"{summary['arrived']}/{len(fleet)} on their goal")
    print(f"wrote {out} ({codec.label}; {written} frames at {args.fps:g} fps; {tally}, collisions robot-robot "
          f"{summary['robot_robot_collisions']}, robot-obstacle {summary['robot_obstacle_collisions']})"
          + (f" and {png}" if png is not None else ""))
    return 0
