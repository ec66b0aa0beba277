"""Videos and field figures of rollout episodes: single robots and formations, written to files."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from apf_physics.render.drawing import FieldImage, formation_roles
from apf_physics.world.core import Frame
from apf_physics.world.io.units import points_to_file
from apf_physics.render.video import render_trajectory, stack_headings, stack_paths, write_png, write_video


def write_episode_video(world, episodes: Sequence, out: str | Path, png: str | Path | None = None, fps: float = 10.0,
                        size: int = 512, hold: float = 1.0, overlay: tuple[str, ...] = (), formation: bool = False,
                        start_index: int | None = None, codec: str | None = None, progress: bool = True,
                        caption: str = "below") -> int:
    """Render rollout episodes of one world to a video (and the last frame to a PNG).

    Single robots from several starts share one clip (all move at once); each formation
    episode is a clip of its own. ``codec`` is a name from
    :data:`~apf_physics.render.video.CODECS` (default: the extension's); ``progress`` shows
    a bar of frames on stderr when it is a terminal. Unicycles' episodes (with ``headings``)
    draw each robot's heading. The text goes where ``caption`` says
    (:data:`~apf_physics.render.drawing.CAPTIONS`: below the map by default, never over it unless
    asked), positions in it in the world file's units. Returns the number of frames written.
    """
    image = FieldImage.from_world(world, size, caption=caption)
    hold_frames = max(0, int(round(hold * fps)))
    clips = list(zip(episode_clips(episodes, overlay, formation, start_index, world.frame),
                     clip_members(episodes, formation)))
    # every frame of the video has the most lines any clip shows (one size for the whole video)
    rows = max(1 + len(lines) + len(collision_events(members)) + len(final) for (_, _, lines, final, _), members in clips)
    total = sum(len(clip[0]) + hold_frames for clip, _ in clips)
    last: list[np.ndarray] = []

    def frames() -> Iterator[np.ndarray]:
        frame = None
        for (trajectory, roles, lines, final, families), members in clips:
            for frame in render_trajectory(world, trajectory, roles, overlay=lines, final_overlay=final, families=families,
                                           hold=hold_frames, image=image,
                                           events=collision_events(members, world.frame), caption_lines=rows,
                                           headings=clip_headings(members, trajectory)):
                yield frame
        last.append(frame)

    written = write_video(frames(), out, fps, codec=codec, progress=progress, total=total)
    if png is not None:
        write_png(last[-1], png)
    return written


def episode_clips(episodes: Sequence, overlay: tuple[str, ...], formation: bool, start_index: int | None,
                  frame: Frame = Frame()) -> Iterator[tuple[np.ndarray, tuple[str, ...], tuple[str, ...],
                                                            tuple[str, ...], tuple[int, ...]]]:
    """``(trajectory (T, R, 2), roles, overlay, final overlay, families)`` per clip of the video.

    Single robots from several starts share one clip (all move at once); each formation
    episode is a clip of its own, one after another; the formations of a world with several
    share one clip, each in its colour family. Positions in the text are in the world file's
    units and coordinates (``frame``); the trajectories are the world's.
    """
    crowds = _crowds(episodes)
    if crowds:
        for name, members in crowds.items():
            positions = [robot_positions(e) for e in members]
            steps = max(len(p) for p in positions)
            trajectory = np.concatenate([np.concatenate([p, np.repeat(p[-1:], steps - len(p), axis=0)])
                                         for p in positions], axis=1)
            roles = tuple(role for p in positions for role in formation_roles(p.shape[1]))
            families = tuple(e.formation.index for e, p in zip(members, positions) for _ in range(p.shape[1]))
            arrived = sum(e.success for e in members)
            yield (trajectory, roles, (*overlay, f"{len(members)} formations"),
                   (f"{arrived}/{len(members)} formations arrived",), families)
        return
    paths = [robot_positions(episode) for episode in episodes]
    if not formation and all(p.ndim == 2 for p in paths):
        counts = Counter(episode.outcome for episode in episodes)
        if len(episodes) == 1:
            episode = episodes[0]
            where = f"start {start_index} " if start_index is not None else ""
            lines = (*overlay, f"{where}{_place(frame, episode.start)}")
            final = (f"outcome {episode.outcome} after {episode.steps} steps",)
        else:
            lines = (*overlay, f"{len(episodes)} starts")
            final = (", ".join(f"{k} {v}" for k, v in sorted(counts.items())),)
        yield stack_paths(paths), ("single",) * len(paths), lines, final, ()
        return
    for i, (episode, path) in enumerate(zip(episodes, paths)):
        trajectory = path if path.ndim == 3 else path[:, None, :]
        where = f"start {start_index} " if start_index is not None else ""
        lines = (*overlay, f"formation, {where}{_place(frame, episode.start)}")
        yield (trajectory, formation_roles(trajectory.shape[1]), lines,
               (f"outcome {episode.outcome} after {episode.steps} steps",), ())


def clip_members(episodes: Sequence, formation: bool) -> list[list]:
    """The episodes each clip of :func:`episode_clips` shows, in the same order."""
    crowds = _crowds(episodes)
    if crowds:
        return list(crowds.values())
    paths = [robot_positions(episode) for episode in episodes]
    if not formation and all(p.ndim == 2 for p in paths):
        return [list(episodes)]
    return [[episode] for episode in episodes]


def clip_headings(members: Sequence, trajectory: np.ndarray) -> np.ndarray | None:
    """(T, R) the headings of a clip's robots (the episodes of :func:`clip_members`), matching its
    trajectory; None for holonomic robots (no headings)."""
    if any(e.headings is None for e in members):
        return None
    formations = [e.formation for e in members if e.formation is not None]
    if formations:   # formations: each held at its last headings, as their positions
        steps = len(trajectory)
        headings = np.concatenate([np.concatenate([f.headings, np.repeat(f.headings[-1:], steps - len(f.headings), axis=0)])
                                   for f in formations], axis=1)
    else:
        headings = stack_headings([e.headings for e in members])
    return headings.reshape(len(trajectory), -1)


def _crowds(episodes: Sequence) -> dict[str, list]:
    """The episodes of each world run with several formations at once, by world (none: {})."""
    crowds: dict[str, list] = {}
    for episode in episodes:
        record = getattr(episode, "formation", None)
        if getattr(record, "crowd", None) is not None:
            crowds.setdefault(record.crowd, []).append(episode)
    return crowds


def _place(frame: Frame, point: np.ndarray, digits: int = 4) -> str:
    """``(6.5, -0.5)``: a point of the world in the file's coordinates, for a caption."""
    x, y = (round(float(v), digits) for v in points_to_file(frame, point))
    return f"({x:g}, {y:g})"


def collision_events(episodes: Sequence, frame: Frame = Frame()) -> list[tuple[int, str]]:
    """``(step, text)`` for each episode that ended in a collision: the frame of that step on says so
    (where, in the world file's coordinates: ``frame``)."""
    out = []
    for k, episode in enumerate(episodes):
        if episode.outcome == "collision":
            where = robot_positions(episode)[-1].reshape(-1, 2)[0]
            what = ", ".join(getattr(episode, "contacts", []) or ["something"])
            who = f"robot {k} " if len(episodes) > 1 else ""
            out.append((int(episode.steps), f"COLLISION at step {episode.steps}: {who}hit {what} at "
                                           f"{_place(frame, where, 2)}"))
    return sorted(out)


def robot_positions(episode) -> np.ndarray:
    """Where an episode's robots were: ``(T, R, 2)`` for a formation's episode (the leader
    first, from its :attr:`formation` record), ``(T, 2)`` for a single robot's (its path)."""
    record = getattr(episode, "formation", None)
    return np.asarray(episode.path if record is None else record.positions, dtype=float)


def is_formation(episodes: Sequence) -> bool:
    """Whether the episodes are a formation's (they carry every robot's positions)."""
    return any(getattr(episode, "formation", None) is not None for episode in episodes)
