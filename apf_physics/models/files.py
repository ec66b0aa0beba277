"""Model and training-checkpoint files: self-describing, checksummed, written atomically.

A file has three parts::

    APF-PHYSICS-DQN\\n                                   magic line
    {"format_version": 1, "sha256": ..., "meta_bytes": M, "payload_bytes": P}\\n
    <M bytes of JSON metadata><P bytes of torch.save payload (tensors only)>

The metadata (JSON, readable with ``head -c``) says what the file is: its kind
(``"model"`` or ``"checkpoint"``), the network's architecture and observation transform,
the observation shape (C, k, k), the field parameters of the world it was trained on and
the training configuration and counters. The payload holds the tensors (state dicts) and
is read with ``torch.load(weights_only=True)``, so a file cannot run code when loaded. The
SHA-256 covers the metadata and the payload; a truncated or corrupted file is refused
before anything is unpickled.

Files are written to a temporary file in the same directory, flushed to disk and renamed
over the target, so a crash leaves either the old file or the new one, never half of one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from apf_physics.errors import ModelError
from apf_physics.models.network import QNetwork
from apf_physics.observation import ObserverConfig

MAGIC = b"APF-PHYSICS-DQN\n"
"""First line of every model or checkpoint file."""
FORMAT_VERSION = 1
"""Version of the file layout and metadata written by this code."""
FIELD_KEYS = ("katt", "krep", "kstr", "p0", "ps", "u_max")
"""Field parameters recorded with a model (SPEC §1)."""


def field_dict(field: Any) -> dict[str, float]:
    """The field parameters as a plain dict.

    Args:
        field: A ``FieldParams`` dataclass or a mapping with the keys of :data:`FIELD_KEYS`.

    Returns:
        ``{key: float}`` for each key of :data:`FIELD_KEYS`.
    """
    data = dataclasses.asdict(field) if dataclasses.is_dataclass(field) else dict(field)
    return {key: float(data[key]) for key in FIELD_KEYS}


def write_file(path: str | os.PathLike, meta: Mapping[str, Any], tensors: Mapping[str, Any]) -> Path:
    """Write a model or checkpoint file atomically.

    Args:
        path: Destination; its directory must exist.
        meta: JSON-serialisable metadata.
        tensors: Tensors (or nested dicts/lists of tensors and plain values) for the payload.

    Returns:
        The path written.
    """
    path = Path(path)
    buffer = io.BytesIO()
    torch.save(dict(tensors), buffer)
    payload = buffer.getvalue()
    meta_bytes = json.dumps(meta, sort_keys=True).encode()
    header = {
        "format_version": FORMAT_VERSION,
        "sha256": hashlib.sha256(meta_bytes + payload).hexdigest(),
        "meta_bytes": len(meta_bytes),
        "payload_bytes": len(payload),
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp's 0600 would make shared models unreadable
        with os.fdopen(fd, "wb") as f:
            f.write(MAGIC)
            f.write(json.dumps(header).encode() + b"\n")
            f.write(meta_bytes)
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    try:  # make the rename itself durable
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except OSError:
        pass
    return path


def read_file(path: str | os.PathLike) -> tuple[dict, dict]:
    """Read and verify a file written by :func:`write_file`.

    Args:
        path: The file.

    Returns:
        ``(meta, tensors)``.

    Raises:
        ModelError: The file is missing, not a model file, of another format version,
            truncated, or fails its checksum.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    data = path.read_bytes()
    if not data.startswith(MAGIC):
        raise ModelError(f"{path}: not an apf-physics model file (it does not start with {MAGIC[:-1].decode()!r})")
    end = data.find(b"\n", len(MAGIC))
    try:
        header = json.loads(data[len(MAGIC) : end]) if end >= 0 else None
        version = header["format_version"]
        digest, n_meta, n_payload = header["sha256"], int(header["meta_bytes"]), int(header["payload_bytes"])
    except (ValueError, TypeError, KeyError):
        raise ModelError(f"{path}: corrupt model file (unreadable header)") from None
    if version != FORMAT_VERSION:
        raise ModelError(
            f"{path}: model file format version {version}, but this apf-physics reads version {FORMAT_VERSION}; "
            "train the model again with this version"
        )
    body = data[end + 1 :]
    if len(body) != n_meta + n_payload:
        raise ModelError(
            f"{path}: truncated or corrupt model file ({len(body)} bytes after the header, expected {n_meta + n_payload})"
        )
    if hashlib.sha256(body).hexdigest() != digest:
        raise ModelError(f"{path}: corrupt model file (SHA-256 checksum mismatch)")
    try:
        meta = json.loads(body[:n_meta])
        tensors = torch.load(io.BytesIO(body[n_meta:]), weights_only=True, map_location="cpu")
    except Exception as exc:  # the checksum matched, so this is a file written by something else
        raise ModelError(f"{path}: unreadable model file ({exc})") from None
    return meta, tensors


@dataclass(frozen=True)
class SavedModel:
    """A Q-network read from a file, with what the file says about it.

    Attributes:
        path: The file it came from.
        network: The network, in eval mode, on CPU.
        obs_shape: (C, k, k) observation shape it expects.
        field: Field parameters of the world it was trained on.
        observer: How its observations were built (:func:`observer_of`).
        meta: All metadata of the file (``kind``, ``arch``, ``config``, ``training``, ...).
    """

    path: Path
    network: QNetwork
    obs_shape: tuple[int, int, int]
    field: dict[str, float]
    observer: ObserverConfig
    meta: dict


def observer_of(meta: Mapping[str, Any]) -> ObserverConfig:
    """The observer configuration a model was trained with.

    Files written before the configuration was recorded (the project's first models) had
    windows of U at resolution 4, with the visit memory as a second channel if there was one.
    """
    if "observer" in meta:
        return ObserverConfig.from_dict(meta["observer"])
    channels, size, _ = (int(v) for v in meta["obs_shape"])
    return ObserverConfig(size=size, resolution=4, channels=("potential", "memory")[:channels])


def model_meta(network: QNetwork, field: Any, config: Mapping[str, Any], training: Mapping[str, Any],
               observer: ObserverConfig) -> dict:
    """Metadata describing a network (the part shared by model and checkpoint files).

    Args:
        network: The Q-network.
        field: Field parameters of the world trained on (dataclass or mapping).
        config: Training configuration (plain values).
        training: Training metadata (steps, episodes, evaluation, world name, ...).
        observer: How the network's observations are built.

    Returns:
        JSON-serialisable metadata.
    """
    return {
        "arch": network.arch,
        "obs_shape": network.arch["obs_shape"],
        "obs_transform": network.arch["obs_transform"],
        "observer": observer.to_dict(),
        "field": field_dict(field),
        "config": dict(config),
        "training": dict(training),
    }


def save_model(path: str | os.PathLike, network: QNetwork, meta: Mapping[str, Any]) -> Path:
    """Write a model file (network weights and ``meta`` from :func:`model_meta`).

    Args:
        path: Destination file.
        network: The Q-network.
        meta: Metadata from :func:`model_meta`.

    Returns:
        The path written.
    """
    return write_file(path, {**meta, "kind": "model"}, {"q_network": network.state_dict()})


def load_model(
    path: str | os.PathLike,
    expect_obs_shape: Sequence[int] | None = None,
    expect_field: Any = None,
) -> SavedModel:
    """Load a model (or the network of a training checkpoint) and check it fits.

    Args:
        path: A ``best.pt``, ``last.pt`` or other file written by the trainer.
        expect_obs_shape: (C, k, k) the caller will feed; refused if different.
        expect_field: Field parameters (``FieldParams`` or mapping) of the world it will
            be used in; refused if any differs from those it was trained on.

    Returns:
        The loaded model.

    Raises:
        ModelError: Missing, corrupt or truncated file, another format version, or a
            mismatched observation shape or field.
    """
    path = Path(path)
    meta, tensors = read_file(path)
    try:
        arch = meta["arch"]
        network = QNetwork(**arch)
        network.load_state_dict(tensors["q_network"])
    except Exception as exc:
        raise ModelError(f"{path}: model file does not describe a usable network ({exc})") from None
    network.eval()
    obs_shape = tuple(int(v) for v in meta["obs_shape"])
    if expect_obs_shape is not None and tuple(int(v) for v in expect_obs_shape) != obs_shape:
        raise ModelError(
            f"{path}: the model expects observations of shape {obs_shape} (C, k, k), "
            f"but they are {tuple(expect_obs_shape)} here"
        )
    field = field_dict(meta["field"])
    if expect_field is not None:
        expected = field_dict(expect_field)
        wrong = [k for k in FIELD_KEYS if not np.isclose(field[k], expected[k], rtol=1e-9, atol=1e-12)]
        if wrong:
            diffs = ", ".join(f"{k}={field[k]:g} (world: {expected[k]:g})" for k in wrong)
            raise ModelError(f"{path}: the model was trained in another field: {diffs}")
    observer = observer_of(meta)
    if observer.shape != obs_shape:
        raise ModelError(f"{path}: the model's observer builds {observer.shape} observations, "
                         f"but its network takes {obs_shape}")
    return SavedModel(path=path, network=network, obs_shape=obs_shape, field=field, observer=observer, meta=meta)
