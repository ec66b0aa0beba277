"""Files users give and files we write: regular files only, read within a limit, written whole.

Reading: world files, map images, MovingAI maps, configurations and model files are all read
through here, so that a FIFO, a directory or a huge file gets one clear refusal naming the
file, never a hang.

Writing: every file the package writes (model files, configurations, videos, figures, pages,
JSON, world sets) goes through :class:`Replacement` (:func:`atomic_path`, :func:`write_bytes`,
:func:`write_text`): it is written to a temporary file beside it, flushed to the disk and
renamed over it, and the folder is flushed, so that a write killed or failing half-way (or
a crash of the machine) leaves the old file (or none) in place, never a truncated one. The
temporary file sits in the target's folder (a rename within one file system is atomic) under
a hidden name that keeps the target's suffix (video encoders pick the container by it), with
the permissions of a plain ``open`` (``0o666`` less the umask), and is removed on any error.
:func:`check_writable` fails early, before any work, when a file could not be written;
:func:`stale_temporaries` finds what a killed process left behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import stat
from pathlib import Path
from typing import Iterator, Sequence

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


# -- files that files name ---------------------------------------------------------------------
CONFINE_VARIABLE = "APF_PHYSICS_CONFINE_PATHS"
"""Set to 1 (or true, yes, on), every file a world file names (a map YAML, an image, a MovingAI
map, and the image a map YAML names) must be inside the world file's folder, symbolic links
followed: what a service that evaluates users' world files wants."""
_ON, _OFF = ("1", "true", "yes", "on"), ("", "0", "false", "no", "off")


def paths_confined() -> bool:
    """Whether :data:`CONFINE_VARIABLE` confines the files that world files name to their folder.

    Raises:
        UserError: the variable holds something other than a yes or a no.
    """
    text = os.environ.get(CONFINE_VARIABLE, "").strip().lower()
    if text in _ON or text in _OFF:
        return text in _ON
    raise UserError(f"{CONFINE_VARIABLE}: expected 1 or 0 (true or false), got {text[:20]!r}")


class NamedFileError(UserError):
    """A file name in a file that names no readable file (the message says why, without the naming file)."""


def named_file(name: object, folder: str | Path, within: str | Path | None = None) -> Path:
    """The file that a file names: ``name`` relative to ``folder`` (an absolute name as it is).

    Every way a name can fail is one :class:`NamedFileError`, never an exception of the OS
    layer: not a string, empty, a NUL character, no such file, a symbolic link loop, a name too
    long, a folder that cannot be searched. With ``within``, the file (symbolic links followed)
    must be inside that folder.

    Returns:
        The path, not resolved (messages show it as the user wrote it, after the folder).
    """
    if not isinstance(name, str) or not name.strip():
        what = "nothing" if name is None else "an empty name" if isinstance(name, str) else type(name).__name__
        raise NamedFileError(f"expected a file name, got {what}")
    if "\0" in name:
        raise NamedFileError("the file name holds a NUL character")
    path = Path(folder) / name
    try:
        os.stat(path)
    except FileNotFoundError:
        raise NamedFileError(f"no such file {path}") from None
    except OSError as exc:
        reason = "a symbolic link loop" if exc.errno == errno.ELOOP else (exc.strerror or str(exc))
        raise NamedFileError(f"cannot read {path} ({reason})") from None
    except ValueError:   # a name the OS cannot take at all
        raise NamedFileError("not a file name the system can open") from None
    if within is not None:
        root = os.path.realpath(within)
        real = os.path.realpath(path)
        if os.path.commonpath([root, real]) != root:
            raise NamedFileError(f"{path} is outside the folder {root} ({CONFINE_VARIABLE} confines files to the "
                                 "world file's folder)")
    return path


# -- writing ---------------------------------------------------------------------------------
_TEMPORARY = re.compile(r"\..+\.[0-9a-f]{8}\.partial(\.[^.]*)?")
"""Names of the temporary files of :class:`Replacement`: ``.STEM.XXXXXXXX.partial.SUFFIX``."""
_OLD_TEMPORARY = re.compile(r"\..+\.tmp")
"""Names of the temporary files of earlier versions' model files: ``.NAME.XXXXXXXX.tmp``."""


def check_writable(path: str | Path, extensions: Sequence[str] | None = None, *, create_parent: bool = False) -> Path:
    """Fail early, before any work, if an output file cannot be written.

    Args:
        path: The output file.
        extensions: Allowed suffixes (lower case, with the dot); ``None`` for any.
        create_parent: Create a missing parent folder (and its parents).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        UserError: naming the path, when the suffix is not allowed, the path exists and is
            not a regular file (a directory, a symbolic link, a device, a FIFO), or its folder
            is missing (and not to be created) or cannot take a new file.
    """
    path = Path(path)
    if extensions is not None and path.suffix.lower() not in extensions:
        raise UserError(f"cannot write {path}: unsupported extension {path.suffix or '(none)'!r} "
                        f"(use {', '.join(extensions)})")
    kind = _not_a_regular_file(path)
    if kind:
        raise UserError(f"cannot write {path}: it is {kind}, not a regular file")
    parent = path.parent
    if not parent.is_dir() and not parent.exists() and create_parent:
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot write {path}: cannot create directory {parent} ({exc.strerror or exc})") from None
    # Create and remove a file where the output will go: the only test that a folder takes a
    # new file (root passes os.access on read-only mounts and on /proc).
    _create_temporary(path).unlink()
    return path


def _not_a_regular_file(path: Path) -> str | None:
    """What ``path`` is if it exists and is not a regular file (``"a directory"``, ...), else ``None``."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "a special file"


def _create_temporary(path: Path) -> Path:
    """A new empty file beside ``path`` with a hidden name and the same suffix (encoders pick
    the container by it); ordinary permissions (``0o666`` less the umask).

    Raises:
        UserError: naming ``path``, when its folder is missing, is not a folder, or takes no new file.
    """
    while True:
        candidate = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.partial{path.suffix}")
        try:
            os.close(os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        except OSError as exc:
            parent = path.parent
            if not parent.is_dir():
                if parent.exists() or parent.is_symlink():
                    raise UserError(f"cannot write {path}: {parent} is not a directory") from None
                raise UserError(f"cannot write {path}: directory {parent} does not exist") from None
            raise UserError(f"cannot write {path}: directory {parent} does not take new files "
                            f"({exc.strerror or exc})") from None
        return candidate


def stale_temporaries(folder: str | Path) -> list[Path]:
    """The temporary files in ``folder`` (sorted) of writes that never finished.

    Those of :class:`Replacement`, and those of earlier versions' model files
    (``.NAME.XXXXXXXX.tmp``). Only a process that alone writes to the folder (a training run
    holding its lock) may remove them: another's may be in progress.
    """
    return sorted(p for p in Path(folder).iterdir()
                  if (_TEMPORARY.fullmatch(p.name) or _OLD_TEMPORARY.fullmatch(p.name)) and not p.is_dir())


def _fsync(path: Path) -> None:
    """Flush ``path`` (a file or a folder) to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class Replacement:
    """A new version of ``path`` being written to a temporary file beside it.

    :meth:`commit` flushes the temporary file and renames it over ``path``; :meth:`discard`
    removes it and leaves ``path`` as it was. Exactly one of them ends the replacement. For a
    file written in one block, :func:`atomic_path`.

    Attributes:
        path: The file to replace (or create).
        temporary: The file to write instead: hidden, in the same folder, same suffix.

    Raises:
        UserError: the temporary file cannot be created (the message names ``path`` and why:
            its folder is missing, is not a folder, or takes no new file).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.temporary = _create_temporary(self.path)

    def commit(self) -> None:
        """Flush the temporary file to the disk and move it into place (then flush the folder).

        Raises:
            UserError: ``path`` has meanwhile become something other than a regular file, or
                the rename fails (the temporary file is removed either way).
        """
        try:
            kind = _not_a_regular_file(self.path)
            if kind:
                raise UserError(f"cannot write {self.path}: it is {kind}, not a regular file")
            try:
                _fsync(self.temporary)
                os.replace(self.temporary, self.path)
            except OSError as exc:
                raise UserError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        finally:
            self.discard()
        with contextlib.suppress(OSError):   # the rename itself; not every file system can
            _fsync(self.path.parent)

    def discard(self) -> None:
        """Remove the temporary file (if it is still there); ``path`` stays as it was."""
        self.temporary.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write; renamed over ``path`` when the block ends without error.

    Readers never see a half-written file (see :class:`Replacement`). On any error, or an
    interrupt, the temporary file is removed and ``path`` is untouched.

    Raises:
        UserError: naming ``path``, when its folder does not exist or takes no new file, or
            the file cannot be moved into place.
    """
    replacement = Replacement(path)
    try:
        yield replacement.temporary
    except BaseException:
        replacement.discard()
        raise
    replacement.commit()


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file (see :func:`atomic_path`).

    Raises:
        UserError: naming the path, when it cannot be written.
    """
    with atomic_path(path) as temporary:
        try:
            temporary.write_bytes(data)
        except OSError as exc:
            raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None


def write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` through a temporary file (see :func:`atomic_path`)."""
    write_bytes(path, text.encode("utf-8"))
