"""The results page: one folder with ``index.html``, the field figures (PNG) and the videos (H.264 MP4).

The page holds the results table, and per world the field figures (potential, colour bar,
paths) and the videos of the runs. Links are relative and nothing is fetched from the
network, so the folder can be zipped, moved and opened offline in any browser.
:func:`write_media` renders one planner's episodes in one world; :func:`write_page` writes
the HTML; :func:`write_results` does both for a list of evaluations (``eval --html``).
"""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

from apf_physics.version import __version__
from apf_physics.errors import UserError
from apf_physics.render.drawing import FieldImage
from apf_physics.render.episodes import is_formation, write_episode_video
from apf_physics.render.field_plot import field_figure
from apf_physics.common.safefile import check_writable, write_text
from apf_physics.render.video import progress_bar, write_png

PAGE = "index.html"
VIDEO_FPS = 10.0


@dataclass(frozen=True)
class Figure:
    """A PNG image on the page.

    Attributes:
        path: The file, inside the page's folder.
        caption: One line under it.
    """

    path: Path
    caption: str


@dataclass(frozen=True)
class Video:
    """A video on the page.

    Attributes:
        path: The file (H.264 MP4), inside the page's folder.
        caption: One line under it.
        duration: Its length in seconds (frames / fps).
        poster: A PNG shown before it plays (its last frame), or ``None``.
    """

    path: Path
    caption: str
    duration: float
    poster: Path | None = None
    wide: bool = False
    """Shown as wide as the page (a fleet's: hundreds of robots need the pixels)."""


@dataclass(frozen=True)
class Section:
    """A heading (a world) with its figures and videos."""

    title: str
    figures: list[Figure] = field(default_factory=list)
    videos: list[Video] = field(default_factory=list)


def file_stem(*parts: str) -> str:
    """A file name stem from names such as a world's and a planner's (``test1_dqn-formation``)."""
    return "_".join(re.sub(r"[^A-Za-z0-9._-]+", "-", part).strip("-.") or "x" for part in parts)


def write_media(folder: Path, world, episodes: Sequence, stem: str, caption: str, *, video: bool = True,
                overlay: tuple[str, ...] = ()) -> tuple[Figure, Video | None]:
    """The field figure of ``episodes`` (``stem.png``) and, with ``video``, their video (``stem.mp4``,
    last frame ``stem_last.png`` as its poster).

    Args:
        folder: The page's folder.
        world: The world the episodes ran in.
        episodes: Rollout or formation episodes (formations: every episode a clip in turn).
        stem: File name stem (see :func:`file_stem`).
        caption: What the figure and video show, e.g. ``"dqn: 40/40 reached"``.
        video: Write the video too.
        overlay: Text lines on every video frame.
    """
    formation = is_formation(episodes)
    image = FieldImage.from_world(world, 512)
    reached = [bool(e.success) for e in episodes]
    counts = f"{sum(reached)}/{len(episodes)} reached"
    figure_path = folder / f"{stem}.png"
    write_png(field_figure(world, [e.path for e in episodes], reached=reached, title=[f"{world.name}: {caption}", counts],
                           image=image), figure_path)
    figure = Figure(figure_path, f"{caption}: {counts}" + (" (leader paths)" if formation else ""))
    if not video:
        return figure, None
    video_path, poster = folder / f"{stem}.mp4", folder / f"{stem}_last.png"
    frames = write_episode_video(world, episodes, video_path, png=poster, fps=VIDEO_FPS, size=512,
                                 overlay=overlay or (f"world {world.name}", caption), formation=formation,
                                 progress=False)
    return figure, Video(video_path, f"{caption}: {counts}", frames / VIDEO_FPS, poster)


def write_results(folder: str | Path, evaluations: Sequence, worlds: Sequence, *, title: str = "apf-physics results",
                  video: bool = True, progress: bool = True, notes: Sequence[str] = ()) -> Path:
    """The page for evaluations (``eval --html``): the table, and per world and planner a field
    figure and a video of the episodes.

    Args:
        folder: Output folder (created if missing).
        evaluations: :class:`~apf_physics.experiments.evaluate.Evaluation` objects (``planner``, ``episodes``).
        worlds: The worlds they ran in (episodes name their world).
        title: The page's title.
        video: Write the videos (else figures only).
        progress: Show a progress bar on stderr (when it is a terminal).
        notes: Lines of text under the title.

    Returns:
        The path of ``index.html``.
    """
    folder = Path(folder)
    check_writable(folder / PAGE, create_parent=True)
    jobs = [(world, ev) for world in worlds for ev in evaluations
            if any(e.world == world.name for e in ev.episodes)]
    sections: dict[str, Section] = {}
    with progress_bar(len(jobs), "results page", "world", progress) as bar:
        for world, ev in jobs:
            bar.set_postfix_str(f"{world.name} {ev.planner}")
            episodes = [e for e in ev.episodes if e.world == world.name]
            figure, clip = write_media(folder, world, episodes, file_stem(world.name, ev.planner), ev.planner,
                                       video=video)
            section = sections.setdefault(world.name, Section(world.name))
            section.figures.append(figure)
            if clip is not None:
                section.videos.append(clip)
            bar.update(1)
    return write_page(folder, title, evaluations, list(sections.values()), notes=notes)


def write_page(folder: str | Path, title: str, evaluations: Sequence, sections: Sequence[Section], *,
               notes: Sequence[str] = (), files: Sequence[str] = (), tables: Sequence[str] = ()) -> Path:
    """Write ``folder/index.html`` (``folder`` is created if missing): title, notes, the results
    table (and ``tables``, HTML such as :func:`fleet_table`'s), the sections, links to ``files``.

    Every figure, video and file must lie inside ``folder``; links are relative to it.

    Raises:
        UserError: a linked file is missing or outside the folder, or the page cannot be written.
    """
    folder = Path(folder)
    check_writable(folder / PAGE, create_parent=True)
    parts = [_HEAD.format(title=html.escape(title)), f"<h1>{html.escape(title)}</h1>"]
    parts += [f"<p>{html.escape(line)}</p>" for line in notes]
    if evaluations or tables:
        parts += ["<h2>Results</h2>"] + ([results_table(evaluations)] if evaluations else []) + list(tables)
    for section in sections:
        parts.append(f'<section><h2>{html.escape(section.title)}</h2><div class="row">')
        for figure in section.figures:
            parts.append(f'<figure><img src="{_link(folder, figure.path)}" alt="{html.escape(figure.caption)}">'
                         f"<figcaption>{html.escape(figure.caption)}</figcaption></figure>")
        for video in section.videos:
            poster = f' poster="{_link(folder, video.poster)}"' if video.poster is not None else ""
            wide = ' class="wide"' if video.wide else ""
            parts.append(f'<figure{wide}><video controls muted playsinline preload="auto"{poster} '
                         f'data-duration="{video.duration:.3f}" src="{_link(folder, video.path)}"></video>'
                         f"<figcaption>{html.escape(video.caption)} ({video.duration:.1f} s)</figcaption></figure>")
        parts.append("</div></section>")
    links = [f'<a href="{_link(folder, folder / name)}">{html.escape(name)}</a>' for name in files]
    footer = f"apf-physics {html.escape(__version__)}" + (f" · files: {', '.join(links)}" if links else "")
    parts += [f"<footer>{footer}</footer>", "</body>\n</html>\n"]
    page = folder / PAGE
    write_text(page, "\n".join(parts))
    return page


def results_table(evaluations: Sequence) -> str:
    """The results as an HTML table: a row per planner and world, and a total row per planner (mean
    steps in control steps, mean lengths in the world files' units)."""
    header = ("planner", "world", "episodes", "reached", "collisions", "trapped", "mean steps", "mean length")
    rows = []
    notes = []
    for ev in evaluations:
        names = list(dict.fromkeys(e.world for e in ev.episodes))
        groups = [(name, [e for e in ev.episodes if e.world == name]) for name in names]
        if len(names) > 1:
            groups.append(("(all)", list(ev.episodes)))
        for name, episodes in groups:
            summary = ev.summary(episodes)
            cells = (ev.planner, name, summary["episodes"], f"{summary['successes']}/{summary['episodes']}",
                     f"{summary['collision_rate']:.1%}", f"{summary['trapped_rate']:.1%}",
                     "-" if summary["mean_steps"] is None else f"{summary['mean_steps']:.1f}",
                     "-" if summary["mean_path_length"] is None else f"{summary['mean_path_length']:.2f}"
                     + (f" {summary['units']}" if summary["units"] not in (None, "mixed") else ""))
            total = ' class="total"' if name == "(all)" else ""
            rows.append(f"<tr{total}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
        summary = ev.summary()
        if "link_in_range" in summary:
            shares = ", ".join(f"{v:.1%}" for v in summary["link_in_range"])
            notes.append(f"{ev.planner}: steps each link in range {shares}; episodes with every link ≥ 99 %: "
                         f"{summary['episodes_all_links_99']}/{summary['episodes']}; robot–robot collisions "
                         f"{summary['robot_robot_collisions']}")
    head = "".join(f"<th>{h}</th>" for h in header)
    table = f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    return table + "".join(f"<p>{html.escape(note)}</p>" for note in notes)


FLEET_COLUMNS = (("planner", "planner"), ("world", "world"), ("robots", "robots"), ("arrived", "arrived"),
                 ("makespan", "makespan"), ("sum of costs", "sum_of_costs"), ("over the optima", "soc_over_optimal"),
                 ("goals reached", "goals_reached"), ("throughput", "throughput"),
                 ("robot–robot", "robot_robot_collisions"), ("robot–obstacle", "robot_obstacle_collisions"),
                 ("ms per robot-step", "ms_per_robot_step"))


def fleet_table(rows: Sequence[dict]) -> str:
    """Fleets' runs as an HTML table: a row per run (its summary, with ``planner`` and ``world``); a
    column only where some run has a value."""
    columns = [(name, key) for name, key in FLEET_COLUMNS if any(row.get(key) is not None for row in rows)]
    head = "".join(f"<th>{html.escape(name)}</th>" for name, _ in columns)
    body = "".join("<tr>" + "".join(f"<td>{html.escape('-' if row.get(key) is None else str(row[key]))}</td>"
                                    for _, key in columns) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _link(folder: Path, path: Path) -> str:
    """``path`` relative to ``folder``, URL-quoted; it must exist inside the folder."""
    try:
        relative = Path(path).resolve().relative_to(folder.resolve())
    except ValueError:
        raise UserError(f"{path}: not inside the results folder {folder}") from None
    if not Path(path).is_file():
        raise UserError(f"{path}: missing, cannot link it from {folder / PAGE}")
    return html.escape(quote(relative.as_posix()))


_HEAD = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0; font-variant-numeric: tabular-nums; }}
th, td {{ padding: 0.2em 0.7em; border-bottom: 1px solid #ddd; text-align: right; }}
th:nth-child(-n+2), td:nth-child(-n+2) {{ text-align: left; }}
tr.total td {{ font-weight: 600; border-bottom: 2px solid #bbb; }}
.row {{ display: flex; flex-wrap: wrap; gap: 1em; align-items: flex-start; }}
figure {{ margin: 0; max-width: 640px; }}
figure.wide {{ max-width: 100%; }}
img, video {{ max-width: 100%; height: auto; display: block; background: #eee; }}
figcaption {{ font-size: 0.9em; color: #555; margin-top: 0.3em; }}
footer {{ margin-top: 2em; font-size: 0.85em; color: #777; }}
</style>
</head>
<body>"""
