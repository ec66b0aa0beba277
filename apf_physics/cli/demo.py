"""``apf-physics demo``: the shipped models at work, no training needed.

Runs the fixed 20×20 world's three-robot formation with the shipped fixed-world DQN as
leader, the thesis's general test worlds with the shipped general DQN, a world with moving
obstacles, a world of four formations crossing each other and a ROS occupancy map in metres,
beside gradient descent (and
escape and A* where they apply); prints the summary table and writes a results page
(``index.html``: the table, field figures and browser-playable videos) into a folder. The
worlds are the bundled ones, so the demo runs from any folder.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Callable

from apf_physics import load_world
from apf_physics.world.bundled import bundled_dir
from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import evaluate, format_table, write_json
from apf_physics.planners import make_planner
from apf_physics.common.safefile import check_writable, write_text
from apf_physics.render.page import PAGE, Section, write_media, write_page
from apf_physics.render.video import progress_bar

GENERAL_WORLDS = tuple(f"thesis/test{i}.yaml" for i in range(1, 5))
MOVING_WORLD = "moving_obstacles.yaml"
FORMATIONS_WORLD = "four_formations.yaml"
MAP_WORLD = "ros_arena.yaml"


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("demo", help="run the shipped models: fixed-world formation and general worlds; "
                                           "write a results page with figures and videos, print the table",
                              description="The shipped models at work, no training needed: the fixed 20×20 "
                                          "world's three-robot formation with the shipped fixed-world DQN as leader, "
                                          "the thesis's general test worlds with the shipped general DQN, a world "
                                          "with moving obstacles, four formations crossing each other and a ROS "
                                          "occupancy map in metres, beside gradient descent (and escape and A* where "
                                          "they apply). Prints the summary table and writes a results page "
                                          "(index.html: the table, field figures and browser-playable videos).")
    p.add_argument("--out", default="apf-demo",
                   help="folder for the results page, figures and videos (default: apf-demo)")
    p.add_argument("--worlds", default=None, metavar="DIR",
                   help=f"a worlds folder with fixed20.yaml, thesis/test1-4.yaml, {MOVING_WORLD}, "
                        f"{FORMATIONS_WORLD} and {MAP_WORLD} (default: the bundled worlds)")
    p.add_argument("--no-video", action="store_true", help="skip the videos (the page keeps the table and figures)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


class _Worlds:
    """The demo's worlds, loaded from the bundled folder (or ``--worlds``)."""

    def __init__(self, folder: str | None):
        root = Path(folder) if folder is not None else bundled_dir()
        paths = [root / "fixed20.yaml", *(root / name for name in GENERAL_WORLDS), root / MOVING_WORLD,
                 root / FORMATIONS_WORLD, root / MAP_WORLD]
        for path in paths:
            if not path.is_file():
                raise UserError(f"{path}: demo world missing (--worlds needs fixed20.yaml, thesis/test1-4.yaml, "
                                f"{MOVING_WORLD}, {FORMATIONS_WORLD} and {MAP_WORLD})")
        worlds = [load_world(p) for p in paths]
        self.fixed, *self.general = worlds[:1 + len(GENERAL_WORLDS)]
        self.moving, self.crowd, self.ros_map = worlds[1 + len(GENERAL_WORLDS):]

    def runs(self) -> list[tuple[str, Callable]]:
        """Every evaluation of the demo: a name and a function that runs it."""
        def run(planner: str, worlds, formation: bool = False) -> Callable:
            return lambda: evaluate(make_planner(planner), worlds, formation=formation)
        fixed, general = [self.fixed], self.general
        return [
            ("gradient", run("gradient", fixed)), ("dqn", run("dqn", fixed)),
            ("dqn formation", run("dqn", fixed, True)),
            ("gradient, general", run("gradient", general)), ("dqn, general", run("dqn", general)),
            # what a hand-made escape and the grid-search oracle do on the same worlds
            ("escape, general", run("escape", general)), ("astar, general", run("astar", general)),
            # moving obstacles: the field at each step; A* replans every step around them
            ("gradient, moving", run("gradient", [self.moving])), ("dqn, moving", run("dqn", [self.moving])),
            ("astar, moving", run("astar", [self.moving])),
            ("dqn, four formations", run("dqn", [self.crowd], True)),
            # a ROS map in metres, a robot that moves a quarter of a metre a step
            ("gradient, ROS map", run("gradient", [self.ros_map])), ("dqn, ROS map", run("dqn", [self.ros_map])),
        ]


class _Page:
    """The results page's sections, each a world's field figures and videos, made as the bar advances."""

    def __init__(self, out: Path, bar, video: bool):
        self.out, self.bar, self.video = out, bar, video

    def media(self, world, evaluation, stem: str, caption: str, video: bool, episodes=None):
        self.bar.set_postfix_str(stem)
        episodes = [e for e in evaluation.episodes if e.world == world.name] if episodes is None else episodes
        figure, clip = write_media(self.out, world, episodes, stem, caption, video=video,
                                   overlay=(f"world {world.name}", caption))
        self.bar.update(1)
        return figure, clip

    def beside(self, title: str, world, gradient_run, dqn_run) -> Section:
        """A section: gradient descent's figure, then the shipped DQN's figure and video."""
        section = Section(title)
        section.figures.append(self.media(world, gradient_run, f"{world.name}_gradient", "gradient descent", False)[0])
        self.add(section, *self.media(world, dqn_run, f"{world.name}_dqn", "dqn (shipped)", self.video))
        return section

    @staticmethod
    def add(section: Section, figure, clip) -> None:
        section.figures.append(figure)
        if clip is not None:
            section.videos.append(clip)

    def sections(self, worlds: _Worlds, evaluations: list) -> list[Section]:
        (gradient, dqn, formation, gradient_general, dqn_general, _, _, gradient_moving, dqn_moving, astar_moving,
         formations, gradient_map, dqn_map) = evaluations
        fixed, moving, crowd = worlds.fixed, worlds.moving, worlds.crowd
        section = self.beside("fixed20: thesis §6.2's fixed world, 40 starts", fixed, gradient, dqn)
        if self.video:   # the formation from four starts where gradient descent is trapped (the interesting ones)
            trapped = [e.start for e in gradient.episodes if e.outcome == "trapped"][:4]
            chosen = [e for e in formation.episodes if any((e.start == s).all() for s in trapped)]
            self.add(section, *self.media(fixed, formation, "fixed20_formation", "leader dqn (shipped), 2 followers",
                                          True, chosen))
        sections = [section]
        for world in worlds.general:
            sections.append(self.beside(f"{world.name}: a thesis general test world", world, gradient_general,
                                        dqn_general))
        section = self.beside(f"{moving.name}: a cup before the target, five obstacles moving across the way", moving,
                              gradient_moving, dqn_moving)
        section.figures.append(self.media(moving, astar_moving, f"{moving.name}_astar", "A*, replanning every step",
                                          False)[0])
        sections.append(section)
        section = Section(f"{crowd.name}: four formations, each to its own target across the others' way")
        self.add(section, *self.media(crowd, formations, f"{crowd.name}_dqn", "leaders dqn (shipped), 2 followers each",
                                      self.video))
        sections.append(section)
        sections.append(self.beside(f"{worlds.ros_map.name}: a ROS map (PGM + YAML) in metres, a 0.2 m robot "
                                    "moving 0.25 m a step", worlds.ros_map, gradient_map, dqn_map))
        return sections


NOTES = ["Gradient descent beside the shipped DQN planners, on the fixed 20×20 world (single robot and "
         "three-robot formation), the thesis's four general test worlds, a world with moving obstacles (drawn "
         "where they are in each frame, their routes as faint lines), four formations crossing each other and a "
         "ROS occupancy map in metres (drawn in steps of 0.25 m); yellow paths, blue starts, blue rings where a "
         "robot stopped short."]


def run(args: argparse.Namespace) -> int:
    began = time.perf_counter()
    worlds = _Worlds(args.worlds)
    out = Path(args.out)
    check_writable(out / PAGE, create_parent=True)
    runs = worlds.runs()
    media = 2 * (1 + len(worlds.general)) + (0 if args.no_video else 1) + 2 + 1 + 2
    with progress_bar(len(runs) + media, "demo", "step", not args.no_progress) as bar:
        evaluations = []
        for name, run_planner in runs:
            bar.set_postfix_str(name)
            evaluations.append(run_planner())
            bar.update(1)
        table = format_table(evaluations)
        write_text(out / "summary.txt", table + "\n")
        write_json(evaluations, out / "summary.json")
        sections = _Page(out, bar, not args.no_video).sections(worlds, evaluations)
        page = write_page(out, "apf-physics demo: the shipped models", evaluations, sections, notes=NOTES,
                          files=["summary.txt", "summary.json"])
    print(table)
    videos = sum(len(s.videos) for s in sections)
    figures = sum(len(s.figures) for s in sections)
    print(f"wrote {page} (open it in a browser): the table, {figures} field figures, {videos} videos; "
          f"and summary.txt, summary.json in {time.perf_counter() - began:.1f} s")
    return 0
