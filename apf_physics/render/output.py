"""Output files: checked before any work, written to a temporary file and renamed over the target.

A render that is killed or fails half-way leaves the old file (or none) in place, never a
truncated one; the temporary file sits in the target's folder (a rename within one file
system is atomic) under a hidden name, and is removed on any error.
"""

from __future__ import annotations

import os
import secrets
import stat
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

from apf_physics.errors import UserError


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
    if not parent.is_dir():
        if parent.exists():
            raise UserError(f"cannot write {path}: {parent} is not a directory")
        if not create_parent:
            raise UserError(f"cannot write {path}: directory {parent} does not exist")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot write {path}: cannot create directory {parent} ({exc.strerror or exc})") from None
    # Create and remove a file where the output will go: the only test that a folder takes a
    # new file (root passes os.access on read-only mounts and on /proc).
    try:
        probe = _create_temporary(path)
    except OSError as exc:
        raise UserError(f"cannot write {path}: directory {parent} does not take new files "
                        f"({exc.strerror or exc})") from None
    probe.unlink()
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
    the container by it); ordinary permissions (``0o666`` less the umask)."""
    while True:
        candidate = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.partial{path.suffix}")
        try:
            os.close(os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        return candidate


class Replacement:
    """A new version of ``path`` being written to a temporary file beside it.

    :meth:`commit` renames the temporary file over ``path``; :meth:`discard` removes it and
    leaves ``path`` as it was. Exactly one of them ends the replacement.

    Attributes:
        path: The file to replace (or create).
        temporary: The file to write instead: hidden, in the same folder, same suffix.

    Raises:
        UserError: the temporary file cannot be created.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self.temporary = _create_temporary(self.path)
        except OSError as exc:
            raise UserError(f"cannot write {self.path}: {exc.strerror or exc}") from None

    def commit(self) -> None:
        """Move the temporary file into place.

        Raises:
            UserError: ``path`` has meanwhile become something other than a regular file, or
                the rename fails (the temporary file is removed either way).
        """
        try:
            kind = _not_a_regular_file(self.path)
            if kind:
                raise UserError(f"cannot write {self.path}: it is {kind}, not a regular file")
            try:
                os.replace(self.temporary, self.path)
            except OSError as exc:
                raise UserError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary file (if it is still there); ``path`` stays as it was."""
        self.temporary.unlink(missing_ok=True)


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Write ``path`` through a temporary file: yields the temporary file's path.

    When the block ends normally the temporary file is renamed over ``path``; when it
    raises (or is interrupted) the temporary file is removed and ``path`` is untouched.
    """
    replacement = Replacement(path)
    try:
        yield replacement.temporary
    except BaseException:
        replacement.discard()
        raise
    replacement.commit()


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file (see :func:`replacing`).

    Raises:
        UserError: naming the path, when it cannot be written.
    """
    with replacing(path) as temporary:
        try:
            temporary.write_bytes(data)
        except OSError as exc:
            raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None


def write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` through a temporary file (see :func:`replacing`)."""
    write_bytes(path, text.encode("utf-8"))
