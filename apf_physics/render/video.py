"""Videos and still images: trajectories to frames, frames to MP4 / WebM / AVI and PNG files.

The writer wraps the pure drawing function the way Gymnasium's ``RecordVideo`` wraps
``render()``: :func:`render_trajectory` turns positions over time into frames with
:func:`~apf_physics.render.drawing.draw_frame`, :func:`write_video` streams any iterable
of frames to a file.

Codecs (see :data:`CODECS`); the file's extension picks the default:

- ``.mp4``: H.264 (``h264``), yuv420p, the index at the front (``+faststart``): every
  browser plays it. Written through PyAV, whose wheels carry FFmpeg's libx264.
- ``.webm``: VP9 (``vp9``, libvpx through PyAV); browsers play it too.
- ``.avi``: Motion-JPEG (``mjpg``, OpenCV).
- ``mp4v`` (MPEG-4 Part 2 in ``.mp4``, OpenCV) only on request or when PyAV is missing:
  desktop players such as VLC play it, web browsers do not.

Every file is written to a temporary file beside it and renamed over it at the end (see
:mod:`~apf_physics.common.safefile`). FFmpeg's log stays off (PyAV's default), so encoding
prints nothing.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Iterator, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from apf_physics.errors import UserError
from apf_physics.render.drawing import FieldImage, Snapshot, TrailLayer, draw_frame, field_image
from apf_physics.common.safefile import Replacement, check_writable, write_bytes

if TYPE_CHECKING:
    from apf_physics.world.core import World

try:
    import av
except ImportError:  # a stated fallback: .mp4 becomes mp4v (see choose_codec)
    av = None


@dataclass(frozen=True)
class Codec:
    """A way to write a video.

    Attributes:
        name: The name users pass (``--codec``).
        extension: The file extension it needs.
        label: How messages name it.
        encoder: FFmpeg encoder (PyAV) or OpenCV fourcc.
        pyav: Written through PyAV (else OpenCV).
        browsers: Web browsers play it.
    """

    name: str
    extension: str
    label: str
    encoder: str
    pyav: bool
    browsers: bool


CODECS = {
    "h264": Codec("h264", ".mp4", "H.264", "libx264", True, True),
    "vp9": Codec("vp9", ".webm", "VP9", "libvpx-vp9", True, True),
    "mp4v": Codec("mp4v", ".mp4", "mp4v", "mp4v", False, False),
    "mjpg": Codec("mjpg", ".avi", "MJPG", "MJPG", False, False),
}

#: File extension → default codec name.
DEFAULT_CODEC = {".mp4": "h264", ".webm": "vp9", ".avi": "mjpg"}
VIDEO_EXTENSIONS = tuple(DEFAULT_CODEC)

# Encoder settings: x264's "veryfast" preset at CRF 23 keeps draw + encode of 512x512 frames
# near 400-450 frames/s on these 2-core machines ("medium": ~170), VP9's realtime mode ~500
# (BENCHMARKS.md). Per codec: container format, encoder options, container options.
_PYAV_SETTINGS = {
    "h264": ("mp4", {"preset": "veryfast", "crf": "23"}, {"movflags": "+faststart"}),
    "vp9": ("webm", {"deadline": "realtime", "cpu-used": "8", "crf": "32", "b": "0", "row-mt": "1"}, {}),
}


def choose_codec(path: str | Path, codec: str | None = None) -> Codec:
    """The codec a video file will be written with.

    Args:
        path: The output file; its extension gives the default codec.
        codec: A name from :data:`CODECS`, or ``None`` for the extension's default. Without
            PyAV the default for ``.mp4`` falls back to ``mp4v`` (check ``Codec.browsers``).

    Raises:
        UserError: an unknown codec or extension, a codec that does not fit the extension,
            or a PyAV codec when PyAV is not installed.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in DEFAULT_CODEC:
        raise UserError(f"cannot write {path}: unsupported video extension {suffix or '(none)'!r} "
                        f"(use {', '.join(VIDEO_EXTENSIONS)})")
    if codec is not None and codec not in CODECS:
        raise UserError(f"cannot write {path}: unknown codec {codec!r} (known: {', '.join(CODECS)})")
    chosen = CODECS[codec or DEFAULT_CODEC[suffix]]
    if chosen.extension != suffix:
        raise UserError(f"cannot write {path}: {chosen.label} needs a {chosen.extension} file")
    if chosen.pyav and av is None:
        if codec is None and suffix == ".mp4":
            return CODECS["mp4v"]
        raise UserError(f"cannot write {path}: {chosen.label} needs PyAV (pip install av)")
    return chosen


class VideoWriter:
    """Append RGB frames to a video file; a context manager.

    The file appears (or replaces an old one) only when the writer closes without error.

    Args:
        path: Output file; its extension picks the default codec (see :func:`choose_codec`).
        fps: Frames per second of the video.
        frame_size: ``(width, height)`` of every frame in pixels. yuv420p needs even sizes:
            H.264 and VP9 frames of odd size get one replicated column or row.
        codec: A name from :data:`CODECS`, or ``None`` for the extension's default.

    Attributes:
        codec: The :class:`Codec` in use.
        frames: Frames written so far.

    Raises:
        UserError: the extension or codec is not supported, or the file cannot be written
            (the message names the path).
    """

    def __init__(self, path: str | Path, fps: float, frame_size: tuple[int, int], codec: str | None = None):
        self.path = Path(path)
        self.frame_size = (int(frame_size[0]), int(frame_size[1]))
        self.frames = 0
        if fps <= 0:
            raise UserError(f"cannot write {self.path}: fps must be positive, got {fps:g}")
        self.codec = choose_codec(self.path, codec)
        check_writable(self.path)
        self._replacement = Replacement(self.path)
        try:
            if self.codec.pyav:
                self._encoder: _PyAVEncoder | _OpenCVEncoder | None = _PyAVEncoder(
                    self._replacement.temporary, self.codec, fps, self.frame_size)
            else:
                self._encoder = _OpenCVEncoder(self._replacement.temporary, self.codec, fps, self.frame_size)
        except BaseException:
            self._replacement.discard()
            raise

    def write(self, frame: np.ndarray) -> None:
        """Append one ``(H, W, 3)`` uint8 RGB frame of the writer's size."""
        if frame.shape != (self.frame_size[1], self.frame_size[0], 3) or frame.dtype != np.uint8:
            raise ValueError(f"expected a ({self.frame_size[1]}, {self.frame_size[0]}, 3) uint8 frame, "
                             f"got {frame.shape} {frame.dtype}")
        if self._encoder is None:
            raise ValueError(f"{self.path}: the writer is closed")
        self._encoder.write(frame)
        self.frames += 1

    def close(self) -> None:
        """Finish the file and move it into place. Safe to call twice.

        Raises:
            UserError: the encoder failed, or the finished file is empty.
            ValueError: no frame was written (nothing replaces the old file).
        """
        if self._encoder is None:
            return
        encoder, self._encoder = self._encoder, None
        try:
            encoder.close()
            if not self.frames:
                raise ValueError(f"{self.path}: no frames were written")
            if encoder.path.stat().st_size == 0:
                raise UserError(f"cannot write {self.path}: the video file is empty after writing")
        except BaseException:
            self._replacement.discard()
            raise
        self._replacement.commit()

    def abort(self) -> None:
        """Stop without writing: the temporary file goes, an old file at ``path`` stays."""
        if self._encoder is None:
            return
        encoder, self._encoder = self._encoder, None
        try:
            encoder.close()
        except Exception:
            pass  # the half-written file is thrown away; its encoder's complaints do not matter
        finally:
            self._replacement.discard()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class _PyAVEncoder:
    """H.264 or VP9 through PyAV: RGB frames to limited-range BT.601 yuv420p, tagged as such
    in the stream (with sRGB primaries and transfer, what was drawn), so that browsers and
    players show the colours that were drawn."""

    def __init__(self, path: Path, codec: Codec, fps: float, frame_size: tuple[int, int]):
        self.path = path
        container_format, codec_options, container_options = _PYAV_SETTINGS[codec.name]
        w, h = frame_size
        self.padded = (w + w % 2, h + h % 2)
        self.rate = Fraction(fps).limit_denominator(100_000)
        self.index = 0
        try:
            self.container = av.open(str(path), "w", format=container_format, options=container_options)
            self.stream = self.container.add_stream(codec.encoder, rate=self.rate)
        except (av.FFmpegError, ValueError) as exc:
            raise UserError(f"cannot write {path}: PyAV could not open a {codec.label} writer ({exc})") from None
        self.stream.width, self.stream.height = self.padded
        self.stream.pix_fmt = "yuv420p"
        # The tags that say how to turn the samples back into the drawn sRGB colours: the
        # matrix of OpenCV's RGB→I420 (BT.601, limited range), BT.709 (= sRGB) primaries, sRGB transfer.
        context = self.stream.codec_context
        context.colorspace = 6          # SMPTE 170M (BT.601)
        context.color_range = 1         # limited ("MPEG"): 16-235
        context.color_primaries = 1     # BT.709
        context.color_trc = 13          # IEC 61966-2-1 (sRGB)
        self.stream.options = codec_options

    def write(self, frame: np.ndarray) -> None:
        w, h = frame.shape[1], frame.shape[0]
        if (w, h) != self.padded:
            frame = cv2.copyMakeBorder(frame, 0, self.padded[1] - h, 0, self.padded[0] - w, cv2.BORDER_REPLICATE)
        # OpenCV's conversion costs a seventh of FFmpeg's swscale here (0.16 against 1.2 ms at 512x512).
        picture = av.VideoFrame.from_ndarray(cv2.cvtColor(frame, cv2.COLOR_RGB2YUV_I420), format="yuv420p")
        picture.pts = self.index
        picture.time_base = 1 / self.rate
        self.index += 1
        self._mux(picture)

    def _mux(self, picture) -> None:
        try:
            self.container.mux(self.stream.encode(picture))
        except av.FFmpegError as exc:
            raise UserError(f"cannot write {self.path}: the encoder failed ({exc})") from None

    def close(self) -> None:
        try:
            self._mux(None)  # flush the encoder's delayed frames
        finally:
            self.container.close()


class _OpenCVEncoder:
    """mp4v or MJPG through OpenCV's video writer (BGR frames)."""

    def __init__(self, path: Path, codec: Codec, fps: float, frame_size: tuple[int, int]):
        self.path = path
        self.writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec.encoder), float(fps), frame_size)
        if not self.writer.isOpened():
            raise UserError(f"cannot write {path}: OpenCV could not open a {codec.label} video writer for it")

    def write(self, frame: np.ndarray) -> None:
        self.writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))

    def close(self) -> None:
        self.writer.release()


def progress_bar(total: int | None, description: str, unit: str, enabled: bool = True):
    """A tqdm bar on stderr, shown only when ``enabled`` and stderr is a terminal.

    A disabled bar is still a tqdm object (``update``, ``set_postfix_str`` and ``close`` do
    nothing), so callers need no branches.
    """
    shown = enabled and sys.stderr.isatty()
    return tqdm(total=total, desc=description, unit=unit, file=sys.stderr, leave=False, dynamic_ncols=True,
                disable=not shown)


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
        path: ``.mp4`` (H.264), ``.webm`` (VP9) or ``.avi`` (MJPG); see :func:`choose_codec`.
        fps: Frames per second.
        codec: A name from :data:`CODECS`, or ``None`` for the extension's default.
        progress: Show a tqdm progress bar on stderr (when it is a terminal).
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
    with progress_bar(total, Path(path).name, "frame", progress) as bar:
        with VideoWriter(path, fps, (first.shape[1], first.shape[0]), codec) as writer:
            for frame in _chain(first, iterator):
                writer.write(frame)
                bar.update(1)
    return writer.frames


def _chain(first: np.ndarray, rest: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
    yield first
    yield from rest


def write_png(frame: np.ndarray, path: str | Path) -> None:
    """Write one RGB frame as a PNG file (through a temporary file and a rename).

    Raises:
        UserError: the file cannot be written (the message names the path).
    """
    path = check_writable(path, (".png",))
    ok, encoded = cv2.imencode(".png", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    if not ok:
        raise UserError(f"cannot write {path}: OpenCV could not encode the PNG image")
    write_bytes(path, encoded.tobytes())


def trajectory_snapshots(
    trajectory: np.ndarray,
    roles: Sequence[str] | None = None,
    *,
    overlay: Sequence[str] = (),
    final_overlay: Sequence[str] = (),
    trails: bool = True,
    hold: int = 0,
    families: Sequence[int] = (),
    events: Sequence[tuple[int, str]] = (),
    headings: np.ndarray | None = None,
    caption_lines: int = 0,
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
        families: One formation number per robot (several formations), or empty.
        events: ``(step, text)``: a line shown from that step's frame on (e.g. a collision, marked
            at the step it happened).
        headings: ``(T, R)`` each robot's heading [rad] at each step (``(T,)`` for one robot;
            unicycles: drawn as a line from the centre to the rim), or None (holonomic robots).
        caption_lines: Every snapshot has at least this many lines of text (padded with empty
            ones), and at least as many as the longest of this trajectory's: the frames of a
            video, their text in a band below the map, share one size.
    """
    trajectory = np.asarray(trajectory, dtype=float)
    if trajectory.ndim == 2:
        trajectory = trajectory[:, None, :]
    if trajectory.ndim != 3 or trajectory.shape[2] != 2 or len(trajectory) == 0:
        raise ValueError(f"trajectory must be (T, R, 2) with T >= 1, got shape {trajectory.shape}")
    steps, robots = trajectory.shape[:2]
    roles = tuple(roles) if roles is not None else ("single",) * robots
    if headings is not None:
        headings = np.asarray(headings, dtype=float).reshape(steps, robots)
    per_robot = np.ascontiguousarray(trajectory.transpose(1, 0, 2))  # (R, T, 2): trails are slices
    rows = max(caption_lines, 1 + len(overlay) + len(events) + len(final_overlay))
    for t in range(steps):
        lines = (f"step {t}/{steps - 1}", *overlay, *(text for step, text in events if t >= step))
        if t == steps - 1:
            lines = (*lines, *final_overlay)
        lines = (*lines, *("",) * (rows - len(lines)))
        snapshot = Snapshot(trajectory[t], roles, tuple(per_robot[:, : t + 1]) if trails else (), lines, t,
                            tuple(families), None if headings is None else headings[t])
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
    families: Sequence[int] = (),
    events: Sequence[tuple[int, str]] = (),
    headings: np.ndarray | None = None,
    caption_lines: int = 0,
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
        families: One formation number per robot (several formations), or empty.
        events: ``(step, text)`` lines shown from that step on (see :func:`trajectory_snapshots`).
        headings: ``(T, R)`` robots' headings [rad] (unicycles), or None (see :func:`trajectory_snapshots`).
        caption_lines: The least lines of text of every frame (see :func:`trajectory_snapshots`).

    Yields:
        ``(H, W, 3)`` uint8 RGB frames: the map, and below it the band of text (the image's
        :attr:`~apf_physics.render.drawing.FieldImage.caption`).
    """
    image = image if image is not None else field_image(world, long_side)
    layer: TrailLayer | None = None
    # Trails grow by one segment a step on a persistent layer: constant cost per frame.
    for snapshot in trajectory_snapshots(trajectory, roles, overlay=overlay, final_overlay=final_overlay,
                                         trails=False, hold=hold, families=families, events=events,
                                         headings=headings, caption_lines=caption_lines):
        if not trails:
            frame = draw_frame(image, snapshot)
        else:
            if layer is None:
                layer = TrailLayer(image, snapshot.roles, snapshot.families)
            layer.extend(snapshot.positions)
            frame = layer.frame(snapshot)
        yield frame


def stack_headings(headings: Sequence[np.ndarray]) -> np.ndarray:
    """Stack robots' headings ``(n_i,)`` of different lengths into ``(T, R)``, as :func:`stack_paths`
    stacks their paths (each held at its last value)."""
    if not headings:
        raise ValueError("no headings to stack")
    headings = [np.asarray(h, dtype=float).reshape(-1) for h in headings]
    steps = max(len(h) for h in headings)
    return np.stack([np.concatenate([h, np.repeat(h[-1:], steps - len(h))]) for h in headings], axis=1)


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
