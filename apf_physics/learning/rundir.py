"""A training run's output folder: its lock, its log (``train.csv``, optional TensorBoard) and its files.

The folder is locked while a run writes to it: ``train.lock`` holds the writer's PID and host
and an exclusive ``fcntl.flock``, which the operating system releases when the process ends
however it ends (even ``kill -9``), so a lock is never stale. Model files are written
atomically through hidden temporary files (:func:`~apf_physics.models.files.write_file`,
:func:`~apf_physics.common.safefile.atomic_path`); those left by a killed process
(:func:`~apf_physics.common.safefile.stale_temporaries`) are removed when the next run takes the lock.
"""

from __future__ import annotations

import csv
import fcntl
import math
import os
import socket
from pathlib import Path
from typing import Optional, Sequence

from apf_physics.errors import UserError
from apf_physics.common.safefile import stale_temporaries

LOCK_NAME = "train.lock"


class RunDir:
    """The output folder of one training session, locked while it is open.

    Args:
        path: The folder (created if missing).
        columns: Columns of ``train.csv``.

    Raises:
        UserError: Another live process holds the folder's lock (the message names it), or the
            folder cannot be created.
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str]):
        self.path = Path(path)
        self.columns = tuple(columns)
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{self.path}: cannot create the output folder ({exc.strerror or exc})") from None
        self._lock_fd: Optional[int] = None
        self._lock()
        self.removed_temporaries = self._remove_temporaries()
        self._tensorboard = None
        self.written: list[Path] = []
        """Files written by this session, in the order first written."""

    @property
    def csv(self) -> Path:
        return self.path / "train.csv"

    @property
    def best(self) -> Path:
        return self.path / "best.pt"

    @property
    def last(self) -> Path:
        return self.path / "last.pt"

    @property
    def png(self) -> Path:
        return self.path / "train.png"

    def _lock(self) -> None:
        lock = self.path / LOCK_NAME
        while True:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 200).decode(errors="replace").strip() or "a process that has not said who it is"
                os.close(fd)
                raise UserError(f"{self.path} is in use by another training run ({holder}); wait for it to end, "
                                "or train into another --out") from None
            # The holder before us may have removed the file after we opened it: lock the file that is there.
            try:
                same = os.stat(lock).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()} on {socket.gethostname()}\n".encode())
        self._lock_fd = fd

    def _remove_temporaries(self) -> list[Path]:
        """Delete the temporary files of writes that a killed process left half done (we hold the lock)."""
        stale = stale_temporaries(self.path)
        for p in stale:
            p.unlink(missing_ok=True)
        return stale

    def close(self) -> None:
        """Flush the logs and release the lock."""
        if self._tensorboard is not None:
            self._tensorboard.close()
            self._tensorboard = None
        if self._lock_fd is not None:
            (self.path / LOCK_NAME).unlink(missing_ok=True)
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> "RunDir":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def wrote(self, path: Path) -> None:
        if path not in self.written:
            self.written.append(path)

    # -- the log ----------------------------------------------------------------------------
    def start_log(self, resume_step: Optional[int]) -> None:
        """Begin ``train.csv`` (a header), or on resume keep its rows up to ``resume_step``; open TensorBoard."""
        rows: list[dict] = []
        if resume_step is not None and self.csv.exists():
            with open(self.csv, newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["global_step"]) <= resume_step]
        with open(self.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, self.columns)
            writer.writeheader()
            writer.writerows(rows)
        self.wrote(self.csv)
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # the [tensorboard] extra is not installed
            return
        # purge_step drops events logged after the checkpoint by the interrupted session
        self._tensorboard = SummaryWriter(os.fspath(self.path / "tensorboard"), purge_step=resume_step)
        self.wrote(self.path / "tensorboard")

    def log(self, row: dict) -> None:
        """Append a row to ``train.csv`` (and its numbers to TensorBoard, at ``row["global_step"]``)."""
        with open(self.csv, "a", newline="") as f:
            csv.DictWriter(f, self.columns).writerow(row)
        if self._tensorboard is not None:
            step = int(row["global_step"])
            for name, value in row.items():
                if name != "global_step" and isinstance(value, (int, float)) and math.isfinite(value):
                    self._tensorboard.add_scalar(name, value, step)
            self._tensorboard.flush()
