"""Videos and still images: trajectories to frames, frames to MP4 / WebM / AVI and PNG files.

The writer wraps the pure drawing function the way Gymnasium's ``RecordVideo`` wraps
``render()``: :func:`render_trajectory` turns positions over time into frames with
:func:`~apf_physics.render.drawing.draw_frame`, :func:`write_video` streams any iterable
of frames to a file.

Containers and codecs, chosen by the file's extension (what OpenCV's headless wheel can
write here, see MEASURED.md): ``.mp4`` MPEG-4 Part 2 (``mp4v``: desktop players such as
VLC play it, web browsers do not), ``.webm`` VP8 (browsers play it, but it encodes about
ten times slower), ``.avi`` Motion-JPEG. ``codec="h264"`` writes browser-playable H.264
MP4 through the ffmpeg binary that the optional ``imageio-ffmpeg`` wheel ships.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Iterator, Sequence

import cv2
import numpy as np

from apf_physics.errors import UserError
from apf_physics.render.drawing import FieldImage, Snapshot, TrailLayer, draw_frame, field_image

if TYPE_CHECKING:
    from apf_physics.world import World

#: File extension → OpenCV fourcc.
FOURCC_BY_EXTENSION = {".mp4": "mp4v", ".webm": "VP80", ".avi": "MJPG"}


def check_writable(path: str | Path, extensions: Sequence[str] | None = None) -> Path:
    """Fail early, before any work, if an output file cannot be written.

    Args:
        path: The output file.
        extensions: Allowed suffixes (lower case, with the dot); ``None`` for any.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        UserError: naming the path, when the suffix is not allowed, the path is a directory,
            or its directory is missing or read-only.
    """
    path = Path(path)
    if extensions is not None and path.suffix.lower() not in extensions:
        raise UserError(f"cannot write {path}: unsupported extension {path.suffix or '(none)'!r} "
                        f"(use {', '.join(extensions)})")
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise UserError(f"cannot write {path}: it is a directory")
    if not parent.is_dir():
        raise UserError(f"cannot write {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"cannot write {path}: directory {parent} is not writable")
    return path


class VideoWriter:
    """Append RGB frames to a video file; a context manager.

    Args:
        path: Output file; its extension picks the codec (see :data:`FOURCC_BY_EXTENSION`).
        fps: Frames per second of the video.
        frame_size: ``(width, height)`` of every frame in pixels.
        codec: ``None`` (by extension) or ``"h264"`` (``.mp4`` only, needs ``imageio-ffmpeg``).

    Raises:
        UserError: the extension is not supported, or the file cannot be opened for writing
            (the message names the path).
    """

    def __init__(self, path: str | Path, fps: float, frame_size: tuple[int, int], codec: str | None = None):
        self.path = Path(path)
        self.frame_size = (int(frame_size[0]), int(frame_size[1]))
        self.frames = 0
        suffix = self.path.suffix.lower()
        if fps <= 0:
            raise UserError(f"cannot write {self.path}: fps must be positive, got {fps:g}")
        if codec not in (None, "h264"):
            raise UserError(f"cannot write {self.path}: unknown codec {codec!r} (expected h264 or none)")
        if suffix not in FOURCC_BY_EXTENSION:
            raise UserError(f"cannot write {self.path}: unsupported video extension {suffix or '(none)'!r} "
                            f"(use {', '.join(FOURCC_BY_EXTENSION)})")
        if codec == "h264" and suffix != ".mp4":
            raise UserError(f"cannot write {self.path}: H.264 needs an .mp4 file")
        check_writable(self.path)
        self._cv: cv2.VideoWriter | None = None
        self._ffmpeg = None
        if codec == "h264":
            self._open_ffmpeg(fps)
        else:
            fourcc = cv2.VideoWriter_fourcc(*FOURCC_BY_EXTENSION[suffix])
            self._cv = cv2.VideoWriter(str(self.path), fourcc, float(fps), self.frame_size)
            if not self._cv.isOpened():
                raise UserError(f"cannot write {self.path}: OpenCV could not open a "
                                f"{FOURCC_BY_EXTENSION[suffix]} video writer for it")

    def _open_ffmpeg(self, fps: float) -> None:
        try:
            import imageio_ffmpeg
        except ImportError:
            raise UserError(f"cannot write {self.path} as H.264: install imageio-ffmpeg "
                            "(pip install imageio-ffmpeg), or drop the H.264 option to write mp4v") from None
        # yuv420p needs even sizes; frames are padded by at most one pixel (see write()).
        w, h = self.frame_size
        self._padded = (w + w % 2, h + h % 2)
        self._ffmpeg = imageio_ffmpeg.write_frames(
            str(self.path), self._padded, fps=float(fps), codec="libx264", pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p", macro_block_size=1, quality=7, ffmpeg_log_level="error")
        try:
            self._ffmpeg.send(None)  # starts ffmpeg
        except (OSError, RuntimeError) as exc:
            raise UserError(f"cannot write {self.path}: ffmpeg failed to start ({exc})") from None

    def write(self, frame: np.ndarray) -> None:
        """Append one ``(H, W, 3)`` uint8 RGB frame of the writer's size."""
        if frame.shape != (self.frame_size[1], self.frame_size[0], 3) or frame.dtype != np.uint8:
            raise ValueError(f"expected a ({self.frame_size[1]}, {self.frame_size[0]}, 3) uint8 frame, "
                             f"got {frame.shape} {frame.dtype}")
        if self._cv is not None:
            self._cv.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        elif self._ffmpeg is not None:
            w, h = self.frame_size
            if (w, h) != self._padded:
                frame = cv2.copyMakeBorder(frame, 0, self._padded[1] - h, 0, self._padded[0] - w,
                                           cv2.BORDER_REPLICATE)
            try:
                self._ffmpeg.send(np.ascontiguousarray(frame))
            except (OSError, RuntimeError) as exc:
                raise UserError(f"cannot write {self.path}: ffmpeg stopped ({exc})") from None
        else:
            raise ValueError(f"{self.path}: the writer is closed")
        self.frames += 1

    def close(self) -> None:
        """Finish the file. Safe to call twice.

        Raises:
            UserError: the finished file is missing or empty.
        """
        if self._cv is not None:
            self._cv.release()
            self._cv = None
        elif self._ffmpeg is not None:
            try:
                self._ffmpeg.close()
            except (OSError, RuntimeError) as exc:
                raise UserError(f"cannot write {self.path}: ffmpeg failed ({exc})") from None
            finally:
                self._ffmpeg = None
        else:
            return
        if self.frames and (not self.path.is_file() or self.path.stat().st_size == 0):
            raise UserError(f"cannot write {self.path}: the video file is empty after writing")

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def write_video(
    frames: Iterable[np.ndarray],
    path: str | Path,
    fps: float = 10.0,
    *,
    codec: str | None = None,
    progress: bool = False,
    total: int | None = None,
) -> int:
    """Write RGB frames to a video file; the first frame fixes the size.

    Args:
        frames: ``(H, W, 3)`` uint8 RGB frames, e.g. from :func:`render_trajectory`; a
            generator is consumed lazily, so long videos never sit in memory.
        path: ``.mp4`` (mp4v), ``.webm`` (VP8) or ``.avi`` (MJPG).
        fps: Frames per second.
        codec: ``None`` or ``"h264"`` (see :class:`VideoWriter`).
        progress: Show a tqdm progress bar on stderr.
        total: Number of frames, for the progress bar (taken from ``len(frames)`` if it has one).

    Returns:
        Number of frames written.

    Raises:
        UserError: the file cannot be written (the message names the path).
        ValueError: no frames, or frames of different sizes.
    """
    iterator = iter(frames)
    try:
        first = next(iterator)
    except StopIteration:
        raise ValueError(f"{path}: no frames to write") from None
    if total is None and hasattr(frames, "__len__"):
        total = len(frames)  # type: ignore[arg-type]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=total, unit="frame", desc=Path(path).name, leave=False)
    with VideoWriter(path, fps, (first.shape[1], first.shape[0]), codec) as writer:
        for frame in _chain(first, iterator):
            writer.write(frame)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return writer.frames


def _chain(first: np.ndarray, rest: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
    yield first
    yield from rest


def write_png(frame: np.ndarray, path: str | Path) -> None:
    """Write one RGB frame as a PNG file.

    Raises:
        UserError: the file cannot be written (the message names the path).
    """
    path = check_writable(path, (".png",))
    if not cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)):
        raise UserError(f"cannot write {path}: OpenCV could not write the PNG file")


def trajectory_snapshots(
    trajectory: np.ndarray,
    roles: Sequence[str] | None = None,
    *,
    overlay: Sequence[str] = (),
    final_overlay: Sequence[str] = (),
    trails: bool = True,
    hold: int = 0,
) -> Iterator[Snapshot]:
    """One :class:`Snapshot` per time step of a trajectory.

    Args:
        trajectory: ``(T, R, 2)`` robot positions over time (``(T, 2)`` for one robot). A
            robot whose episode ended earlier should repeat its last position.
        roles: One role per robot; default ``"single"`` for every robot.
        overlay: Text lines on every frame, after an automatic ``"step t/T"`` line.
        final_overlay: Extra text lines on the last frame only (e.g. the outcome).
        trails: Draw each robot's path so far.
        hold: Repeat the last frame this many extra times (a pause at the end of a video).
    """
    trajectory = np.asarray(trajectory, dtype=float)
    if trajectory.ndim == 2:
        trajectory = trajectory[:, None, :]
    if trajectory.ndim != 3 or trajectory.shape[2] != 2 or len(trajectory) == 0:
        raise ValueError(f"trajectory must be (T, R, 2) with T >= 1, got shape {trajectory.shape}")
    steps, robots = trajectory.shape[:2]
    roles = tuple(roles) if roles is not None else ("single",) * robots
    per_robot = np.ascontiguousarray(trajectory.transpose(1, 0, 2))  # (R, T, 2): trails are slices
    for t in range(steps):
        lines = (f"step {t}/{steps - 1}", *overlay)
        if t == steps - 1:
            lines = (*lines, *final_overlay)
        snapshot = Snapshot(trajectory[t], roles, tuple(per_robot[:, : t + 1]) if trails else (), lines)
        yield snapshot
        if t == steps - 1:
            for _ in range(hold):
                yield snapshot


def render_trajectory(
    world: World,
    trajectory: np.ndarray,
    roles: Sequence[str] | None = None,
    *,
    overlay: Sequence[str] = (),
    final_overlay: Sequence[str] = (),
    trails: bool = True,
    hold: int = 0,
    long_side: int = 512,
    image: FieldImage | None = None,
) -> Iterator[np.ndarray]:
    """Frames of robots moving through ``world``, one per time step (see :func:`trajectory_snapshots`).

    Args:
        world: The world; its :class:`FieldImage` is built once (cached per world and size).
        trajectory: ``(T, R, 2)`` positions over time, or ``(T, 2)`` for one robot.
        roles: One role per robot (default ``"single"``); see
            :func:`~apf_physics.render.drawing.formation_roles`.
        overlay: Text lines on every frame.
        final_overlay: Extra text lines on the last frame.
        trails: Draw each robot's path so far.
        hold: Repeat the last frame this many extra times.
        long_side: Image size in pixels along the world's longer side.
        image: A prebuilt :class:`FieldImage` to draw on (overrides ``long_side``).

    Yields:
        ``(H, W, 3)`` uint8 RGB frames.
    """
    image = image if image is not None else field_image(world, long_side)
    layer: TrailLayer | None = None
    # Trails grow by one segment a step on a persistent layer: constant cost per frame.
    for snapshot in trajectory_snapshots(trajectory, roles, overlay=overlay, final_overlay=final_overlay,
                                         trails=False, hold=hold):
        if not trails:
            yield draw_frame(image, snapshot)
            continue
        if layer is None:
            layer = TrailLayer(image, snapshot.roles)
        layer.extend(snapshot.positions)
        yield layer.frame(snapshot)


def stack_paths(paths: Sequence[np.ndarray]) -> np.ndarray:
    """Stack robot paths of different lengths into one ``(T, R, 2)`` trajectory.

    Each path ``(n_i, 2)`` is held at its last position until the longest one ends, so
    robots whose episode ended early stay where they stopped.
    """
    if not paths:
        raise ValueError("no paths to stack")
    paths = [np.asarray(p, dtype=float).reshape(-1, 2) for p in paths]
    steps = max(len(p) for p in paths)
    out = np.empty((steps, len(paths), 2))
    for i, p in enumerate(paths):
        out[: len(p), i] = p
        out[len(p):, i] = p[-1]
    return out
