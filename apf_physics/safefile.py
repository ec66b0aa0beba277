"""Reading files users give: regular files only, opened without blocking, within a size limit.

World files, map images, MovingAI maps and model files are all read through here, so that a
FIFO, a directory or a huge file gets one clear refusal naming the file, never a hang.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path
from typing import Iterator

from apf_physics.errors import UserError

MAX_FILE_BYTES = 10 * 2**20
"""Largest text file read [bytes] (a world of 10,000 boxes is about 0.7 MB)."""


def _file_kind(mode: int) -> str:
    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


@contextlib.contextmanager
def open_regular_file(path: str | Path, kind: str, error: type[UserError]) -> Iterator[tuple[int, os.stat_result]]:
    """``(fd, stat)`` of ``path`` opened for reading, if it is a regular file; closed afterwards.

    Opened without blocking (a FIFO would wait for a writer forever) and checked with
    ``fstat`` on the open file, so what is read is what was checked. Every failure to open,
    check or read is one ``error`` naming the file and its ``kind`` (``"world"``, ``"model"``).
    """
    source = str(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{source}: no such {kind} file") from None
    except OSError as exc:
        raise error(f"{source}: cannot read the {kind} file ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{source}: cannot read the {kind} file: it is {_file_kind(info.st_mode)}, not a regular file")
        yield fd, info
    except OSError as exc:
        raise error(f"{source}: cannot read the {kind} file ({exc.strerror or exc})") from None
    finally:
        os.close(fd)


def read_regular_file(path: str | Path, kind: str, error: type[UserError], limit: int = MAX_FILE_BYTES) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes (default :data:`MAX_FILE_BYTES`)."""
    with open_regular_file(path, kind, error) as (fd, info):
        if info.st_size > limit:
            raise error(f"{path}: the {kind} file is {info.st_size:,} bytes, over the limit of {limit:,}")
        chunks, total = [], 0
        while total <= limit:
            chunk = os.read(fd, limit + 1 - total)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > limit:
            raise error(f"{path}: the {kind} file grew over the limit of {limit:,} bytes while being read")
        return b"".join(chunks)


def read_text_file(path: str | Path, kind: str, error: type[UserError] = UserError, limit: int = MAX_FILE_BYTES) -> str:
    """The text (UTF-8) of a regular file of at most ``limit`` bytes; one clear error otherwise."""
    data = read_regular_file(path, kind, error, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: the {kind} file is not UTF-8 text (byte {e.start})") from None


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write; renamed over ``path`` when the block ends without error.

    Readers never see a half-written file: the temporary (mode 0666 less the umask, like a plain
    ``open``) is flushed to disk, then renamed in one step, and the folder is synced so the rename
    survives a crash. On any error, or an interrupt, the temporary is removed and ``path`` is untouched.

    Raises:
        UserError: The folder does not exist or cannot be written.
    """
    path = Path(path)
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise UserError(f"{path}: cannot write there ({e.strerror})") from None
    tmp = Path(name)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp's 0600 would make shared files unreadable
        os.close(fd)
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    with contextlib.suppress(OSError):  # make the rename itself durable
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
