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
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from apf_physics.control.shield import ACTIONS
from apf_physics.world.kinematics import MOVE_KINDS
from apf_physics.errors import ModelError
from apf_physics.models.mapnet import MapNetwork
from apf_physics.models.network import OBS_TRANSFORMS, QNetwork
from apf_physics.sensing.observation import CHANNELS, SCALES, ObserverConfig
from apf_physics.common.safefile import open_regular_file, write_bytes
from apf_physics.world.io.worldfile import RASTER_MARGIN

MAGIC = b"APF-PHYSICS-DQN\n"
"""First line of every model or checkpoint file."""
FORMAT_VERSION = 1
"""Version of the file layout and metadata written by this code."""
FIELD_KEYS = ("katt", "krep", "kstr", "p0", "ps", "u_max")
"""Field parameters recorded with a model (Model §1)."""

# Limits on what a file may describe, checked before anything is built from it.
MAX_HEADER_BYTES = 4096
"""Longest header line."""
MAX_META_BYTES = 64 * 2**20
"""Largest metadata (JSON) [bytes]."""
MAX_PARAMETERS = 10_000_000
"""Most parameters of a network (the thesis's has 24,000): 40 MB of float32 weights."""
MAX_ACTIVATIONS = 1_000_000
"""Most values one observation produces through the network's layers (the thesis's: 3,000)."""
MAX_FILTERS, MAX_HIDDEN, MAX_LAYERS = 1024, 4096, 8
"""Widest convolution, widest fully connected layer, most layers of each kind."""
MAX_WINDOW = 2 * (int(RASTER_MARGIN) - 2) + 1
"""Widest observation window [points]: the world files' memory estimate covers rasters this far beyond the map."""
MAX_OBS_RESOLUTION = 8
"""Finest observation raster [nodes per unit] (the memory estimate covers it)."""


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
    """Write a model or checkpoint file atomically and durably (:func:`~apf_physics.common.safefile.write_bytes`).

    Args:
        path: Destination; its directory must exist.
        meta: JSON-serialisable metadata.
        tensors: Tensors (or nested dicts/lists of tensors and plain values) for the payload.

    Returns:
        The path written.

    Raises:
        UserError: naming the path, when its folder takes no new file or the file cannot be written.
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
    write_bytes(path, b"".join([MAGIC, json.dumps(header).encode() + b"\n", meta_bytes, payload]))
    return path


def _one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception's message as one short line (torch's run over many)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _read_exactly(fd: int, count: int) -> bytes:
    chunks, left = [], count
    while left:
        chunk = os.read(fd, min(left, 1 << 24))
        if not chunk:
            break
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def read_file(path: str | os.PathLike) -> tuple[dict, dict]:
    """Read and verify a file written by :func:`write_file`.

    Only a regular file is read, and only after its header's sizes agree with the file's
    (so a hostile header cannot make it allocate more than the file holds).

    Args:
        path: The file.

    Returns:
        ``(meta, tensors)``.

    Raises:
        ModelError: The file is missing, not a regular file, not a model file, of another
            format version, truncated, or fails its checksum; one line each.
    """
    path = Path(path)
    with open_regular_file(path, "model", ModelError) as (fd, info):
        head = _read_exactly(fd, min(info.st_size, len(MAGIC) + MAX_HEADER_BYTES))
        if not head.startswith(MAGIC):
            raise ModelError(f"{path}: not an apf-physics model file (it does not start with {MAGIC[:-1].decode()!r})")
        end = head.find(b"\n", len(MAGIC))
        try:
            header = json.loads(head[len(MAGIC):end]) if end >= 0 else None
            version = header["format_version"]
            digest, n_meta, n_payload = header["sha256"], header["meta_bytes"], header["payload_bytes"]
            if not (isinstance(digest, str) and all(isinstance(n, int) and not isinstance(n, bool) and n >= 0
                                                     for n in (n_meta, n_payload))):
                raise TypeError
        except (ValueError, TypeError, KeyError, RecursionError):
            raise ModelError(f"{path}: corrupt model file (unreadable header)") from None
        if version != FORMAT_VERSION:
            raise ModelError(
                f"{path}: model file format version {str(version)[:20]}, but this apf-physics reads version "
                f"{FORMAT_VERSION}; train the model again with this version"
            )
        body_bytes = info.st_size - (end + 1)
        if body_bytes != n_meta + n_payload:
            raise ModelError(
                f"{path}: truncated or corrupt model file ({body_bytes} bytes after the header, expected {n_meta + n_payload})"
            )
        if n_meta > MAX_META_BYTES:
            raise ModelError(f"{path}: corrupt model file (metadata of {n_meta:,} bytes, at most {MAX_META_BYTES:,})")
        os.lseek(fd, end + 1, os.SEEK_SET)
        body = _read_exactly(fd, body_bytes)
    if len(body) != n_meta + n_payload:
        raise ModelError(f"{path}: truncated model file (it changed while being read)")
    if hashlib.sha256(body).hexdigest() != digest:
        raise ModelError(f"{path}: corrupt model file (SHA-256 checksum mismatch)")
    try:
        meta = json.loads(body[:n_meta])
    except (ValueError, RecursionError) as exc:
        raise ModelError(f"{path}: unreadable model metadata ({_one_line(exc)})") from None
    if not isinstance(meta, dict):
        raise ModelError(f"{path}: unreadable model metadata (not a JSON object)")
    try:
        tensors = torch.load(io.BytesIO(body[n_meta:]), weights_only=True, map_location="cpu")
    except Exception as exc:  # the checksum matched, so this is a file written by something else
        text = str(exc)
        if text.startswith("Weights only load failed"):  # keep torch's reason, not its advice
            reason = [p for p in text.split("\n\n") if p.strip() and not p.startswith(("Weights only", "Check the doc"))]
            raise ModelError(f"{path}: unreadable model file: its payload is not plain tensors, and nothing in it "
                             f"was run ({_one_line(' '.join(reason) or text)})") from None
        raise ModelError(f"{path}: unreadable model file ({_one_line(exc)})") from None
    if not isinstance(tensors, dict):
        raise ModelError(f"{path}: unreadable model file (the payload is not a mapping of tensors)")
    return meta, tensors


@dataclass(frozen=True)
class SavedModel:
    """A Q-network read from a file, with what the file says about it.

    Attributes:
        path: The file it came from.
        network: The network, in eval mode, on CPU: a window :class:`QNetwork`, or a
            :class:`~apf_physics.models.mapnet.MapNetwork` (``arch.type`` ``"map"``).
        obs_shape: (C, k, k) observation shape it expects (``()`` for a map network, which
            sees a :class:`~apf_physics.sensing.mapview.MapView` of any size).
        field: Field parameters of the world it was trained on.
        observer: How its observations were built (:func:`observer_of`; None for a map network).
        meta: All metadata of the file (``kind``, ``arch``, ``config``, ``training``, ...).
    """

    path: Path
    network: QNetwork | MapNetwork
    obs_shape: tuple[int, ...]
    field: dict[str, float]
    observer: ObserverConfig | None
    meta: dict

    @property
    def is_map(self) -> bool:
        """Whether the network plans on a map view rather than reading a potential window."""
        return isinstance(self.network, MapNetwork)


def observer_of(meta: Mapping[str, Any]) -> ObserverConfig:
    """The observer configuration a model was trained with.

    Files written before the configuration was recorded (the project's first models) had
    windows of U at resolution 4, with the visit memory as a second channel if there was one.
    """
    if "observer" in meta:
        return ObserverConfig.from_dict(meta["observer"])
    channels, size, _ = (int(v) for v in meta["obs_shape"])
    return ObserverConfig(size=size, resolution=4, channels=("potential", "memory")[:channels])


def model_meta(network: QNetwork | MapNetwork, field: Any, config: Mapping[str, Any], training: Mapping[str, Any],
               observer: ObserverConfig | None) -> dict:
    """Metadata describing a network (the part shared by model and checkpoint files).

    Args:
        network: The Q-network.
        field: Field parameters of the world trained on (dataclass or mapping).
        config: Training configuration (plain values).
        training: Training metadata (steps, episodes, evaluation, world name, ...).
        observer: How the network's observations are built (None for a map network).

    Returns:
        JSON-serialisable metadata.
    """
    if isinstance(network, MapNetwork):
        return {"arch": network.arch, "field": field_dict(field), "config": dict(config), "training": dict(training)}
    return {
        "arch": network.arch,
        "obs_shape": network.arch["obs_shape"],
        "obs_transform": network.arch["obs_transform"],
        "observer": observer.to_dict(),
        "field": field_dict(field),
        "config": dict(config),
        "training": dict(training),
    }


def save_model(path: str | os.PathLike, network: QNetwork | MapNetwork, meta: Mapping[str, Any]) -> Path:
    """Write a model file (network weights and ``meta`` from :func:`model_meta`).

    Args:
        path: Destination file.
        network: The Q-network.
        meta: Metadata from :func:`model_meta`.

    Returns:
        The path written.
    """
    return write_file(path, {**meta, "kind": "model"}, {"q_network": network.state_dict()})


class _Schema:
    """Checks a model file's metadata before anything is built from it; the first problem is one ModelError line."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, problem: str) -> ModelError:
        return ModelError(f"{self.path}: not a usable model: metadata {key}: {problem}")

    @staticmethod
    def _show(value: Any) -> str:
        """A metadata value for a message: JSON, cut to 40 characters."""
        try:
            text = json.dumps(value)
        except (TypeError, ValueError, RecursionError):
            text = type(value).__name__
        return text if len(text) <= 40 else text[:37] + "..."

    def get(self, data: Mapping[str, Any], key: str, where: str) -> Any:
        if key not in data:
            raise self.fail(f"{where}{key}", "missing")
        return data[key]

    def whole(self, value: Any, key: str, low: int, high: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(key, f"expected a whole number from {low:,} to {high:,}, got {self._show(value)}")
        return value

    def number(self, value: Any, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {self._show(value)}")
        return float(value)

    def wholes(self, value: Any, key: str, count: tuple[int, int], low: int, high: int) -> list[int]:
        if not isinstance(value, list) or not count[0] <= len(value) <= count[1]:
            raise self.fail(key, f"expected a list of {count[0]} to {count[1]} whole numbers, got {self._show(value)}")
        return [self.whole(v, f"{key}[{i}]", low, high) for i, v in enumerate(value)]

    def choice(self, value: Any, key: str, choices: Sequence[str]) -> str:
        if not isinstance(value, str) or value not in choices:
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {self._show(value)}")
        return value

    def map_arch(self, arch: Mapping[str, Any]) -> dict[str, Any]:
        """A map network's architecture (``arch.type`` ``"map"``), checked."""
        known = ("type", "resolution", "channels", "hidden", "negative_slope", "moves", "dv_clip", "least_resolution")
        unknown = sorted(set(map(str, arch)) - set(known))
        if unknown:
            raise self.fail(f"arch.{unknown[0][:40]}", "unknown key")
        checked = {"resolution": self.whole(self.get(arch, "resolution", "arch."), "arch.resolution", 1, MAX_OBS_RESOLUTION),
                   "channels": self.whole(self.get(arch, "channels", "arch."), "arch.channels", 1, MAX_FILTERS),
                   "hidden": self.wholes(self.get(arch, "hidden", "arch."), "arch.hidden", (0, MAX_LAYERS), 1, MAX_HIDDEN),
                   "negative_slope": self.number(self.get(arch, "negative_slope", "arch."), "arch.negative_slope"),
                   "moves": self.choice(self.get(arch, "moves", "arch."), "arch.moves", MOVE_KINDS)}
        if "dv_clip" in arch:
            clip = self.number(arch["dv_clip"], "arch.dv_clip")
            if not 0 < clip <= 1e3:
                raise self.fail("arch.dv_clip", f"expected a number from 0 to 1,000, got {self._show(clip)}")
            checked["dv_clip"] = clip
        if "least_resolution" in arch:
            checked["least_resolution"] = self.whole(arch["least_resolution"], "arch.least_resolution", 1,
                                                     MAX_OBS_RESOLUTION)
        return checked

    def arch(self, meta: Mapping[str, Any]) -> dict[str, Any]:
        """The network's architecture, checked, with its size bounded before it is built."""
        arch = self.get(meta, "arch", "")
        if not isinstance(arch, dict):
            raise self.fail("arch", f"expected a mapping, got {self._show(arch)}")
        if "type" in arch:
            self.choice(arch["type"], "arch.type", ("map",))
            return {"type": "map", **self.map_arch(arch)}
        known = ("obs_shape", "filters", "hidden", "n_actions", "negative_slope", "pooled_convs", "obs_transform")
        unknown = sorted(set(map(str, arch)) - set(known))
        if unknown:
            raise self.fail(f"arch.{unknown[0][:40]}", "unknown key")
        shape = self.wholes(self.get(arch, "obs_shape", "arch."), "arch.obs_shape", (3, 3), 1, MAX_WINDOW)
        if shape[0] > len(CHANNELS) or shape[1] != shape[2] or shape[1] % 2 == 0:
            raise self.fail("arch.obs_shape", f"expected [C, k, k] with C at most {len(CHANNELS)} and k odd, got {shape}")
        filters = self.wholes(self.get(arch, "filters", "arch."), "arch.filters", (1, MAX_LAYERS), 1, MAX_FILTERS)
        hidden = self.wholes(self.get(arch, "hidden", "arch."), "arch.hidden", (0, MAX_LAYERS), 1, MAX_HIDDEN)
        n_actions = self.whole(self.get(arch, "n_actions", "arch."), "arch.n_actions", len(ACTIONS), len(ACTIONS))
        slope = self.number(self.get(arch, "negative_slope", "arch."), "arch.negative_slope")
        pooled = self.whole(self.get(arch, "pooled_convs", "arch."), "arch.pooled_convs", 0, len(filters))
        transform = self.choice(self.get(arch, "obs_transform", "arch."), "arch.obs_transform", OBS_TRANSFORMS)
        # What QNetwork will allocate, from the same arithmetic (2x2 convolutions, pools of stride 1).
        channels, side, parameters, activations = shape[0], shape[1], 0, 0
        for i, f in enumerate(filters):
            side -= 2 if i < pooled else 1
            if side < 1:
                raise self.fail("arch", f"a {shape[1]} x {shape[1]} window is too small for {len(filters)} convolutions")
            parameters += 4 * channels * f + f
            activations += 2 * f * (side + 1) ** 2
            channels = f
        sizes = [channels * side * side, *hidden, n_actions]
        parameters += sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))
        activations += sum(sizes)
        if parameters > MAX_PARAMETERS or activations > MAX_ACTIVATIONS:
            raise self.fail("arch", f"a network of {parameters:,} parameters and {activations:,} values per observation "
                                    f"(at most {MAX_PARAMETERS:,} and {MAX_ACTIVATIONS:,})")
        return {"obs_shape": shape, "filters": filters, "hidden": hidden, "n_actions": n_actions,
                "negative_slope": slope, "pooled_convs": pooled, "obs_transform": transform}

    def field(self, meta: Mapping[str, Any]) -> dict[str, float]:
        field = self.get(meta, "field", "")
        if not isinstance(field, dict):
            raise self.fail("field", f"expected a mapping, got {self._show(field)}")
        return {key: self.number(self.get(field, key, "field."), f"field.{key}") for key in FIELD_KEYS}

    def observer(self, meta: Mapping[str, Any], shape: tuple[int, int, int]) -> ObserverConfig:
        if "observer" not in meta:
            if shape[0] > 2:
                raise self.fail("obs_shape", f"{shape[0]} channels, but without an 'observer' entry a model has at most 2")
            return observer_of({"obs_shape": shape})
        data = meta["observer"]
        if not isinstance(data, dict):
            raise self.fail("observer", f"expected a mapping, got {self._show(data)}")
        size = self.whole(self.get(data, "size", "observer."), "observer.size", 1, MAX_WINDOW)
        resolution = self.whole(self.get(data, "resolution", "observer."), "observer.resolution", 1, MAX_OBS_RESOLUTION)
        channels = self.get(data, "channels", "observer.")
        if not isinstance(channels, list) or not all(isinstance(c, str) for c in channels):
            raise self.fail("observer.channels", f"expected a list of names, got {self._show(channels)}")
        cap = self.whole(data.get("memory_cap", 4), "observer.memory_cap", 1, 1_000_000)
        scale = self.choice(data.get("scale", "raw"), "observer.scale", SCALES)
        try:
            return ObserverConfig(size=size, resolution=resolution, channels=tuple(channels), memory_cap=cap, scale=scale)
        except ValueError as exc:
            raise self.fail("observer", _one_line(exc)) from None


def load_model(
    path: str | os.PathLike,
    expect_obs_shape: Sequence[int] | None = None,
    expect_field: Any = None,
) -> SavedModel:
    """Load a model (or the network of a training checkpoint) and check it fits.

    The metadata is checked against the schema first (types, ranges, the network's size,
    obs_shape against the architecture and the observer), then the network is built and
    its weights loaded and checked to be finite.

    Args:
        path: A ``best.pt``, ``last.pt`` or other file written by the trainer.
        expect_obs_shape: (C, k, k) the caller will feed; refused if different.
        expect_field: Field parameters (``FieldParams`` or mapping) of the world it will
            be used in; refused if any differs from those it was trained on.

    Returns:
        The loaded model.

    Raises:
        ModelError: Missing, corrupt or truncated file, another format version, metadata
            that breaks the schema, weights that do not fit the network or are not finite,
            or a mismatched observation shape or field; one line each.
    """
    path = Path(path)
    meta, tensors = read_file(path)
    schema = _Schema(path)
    schema.choice(schema.get(meta, "kind", ""), "kind", ("model", "checkpoint"))
    arch = schema.arch(meta)
    if arch.get("type") == "map":
        return _load_map_model(path, schema, meta, tensors, arch, expect_obs_shape, expect_field)
    obs_shape = tuple(arch["obs_shape"])
    if "obs_shape" in meta and meta["obs_shape"] != list(obs_shape):
        raise schema.fail("obs_shape", f"{schema._show(meta['obs_shape'])} contradicts arch.obs_shape {list(obs_shape)}")
    if "obs_transform" in meta and meta["obs_transform"] != arch["obs_transform"]:
        raise schema.fail("obs_transform", f"{schema._show(meta['obs_transform'])} contradicts arch.obs_transform "
                                           f"{arch['obs_transform']!r}")
    field = schema.field(meta)
    observer = schema.observer(meta, obs_shape)
    if observer.shape != obs_shape:
        raise ModelError(f"{path}: the model's observer builds {observer.shape} observations, "
                         f"but its network takes {obs_shape}")
    network = _with_weights(path, QNetwork(**arch), tensors)
    if expect_obs_shape is not None and tuple(int(v) for v in expect_obs_shape) != obs_shape:
        raise ModelError(
            f"{path}: the model expects observations of shape {obs_shape} (C, k, k), "
            f"but they are {tuple(expect_obs_shape)} here"
        )
    _check_field(path, field, expect_field)
    return SavedModel(path=path, network=network, obs_shape=obs_shape, field=field, observer=observer, meta=meta)


def _check_field(path: Path, field: dict[str, float], expect_field: Any) -> None:
    if expect_field is not None:
        expected = field_dict(expect_field)
        wrong = [k for k in FIELD_KEYS if not np.isclose(field[k], expected[k], rtol=1e-9, atol=1e-12)]
        if wrong:
            diffs = ", ".join(f"{k}={field[k]:g} (world: {expected[k]:g})" for k in wrong)
            raise ModelError(f"{path}: the model was trained in another field: {diffs}")


def _with_weights(path: Path, network: torch.nn.Module, tensors: dict) -> torch.nn.Module:
    """``network`` with the payload's ``q_network`` weights, checked to fit and be finite, in eval mode."""
    state = tensors.get("q_network")
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ModelError(f"{path}: not a usable model: the payload has no 'q_network' weights")
    try:
        network.load_state_dict(state)
    except (RuntimeError, ValueError, TypeError, KeyError) as exc:
        raise ModelError(f"{path}: the weights do not fit the network the metadata describes ({_one_line(exc)})") from None
    network.eval()
    _finite_weights(path, network)
    return network


def _finite_weights(path: Path, network: torch.nn.Module) -> None:
    bad = sum(int((~torch.isfinite(p)).sum()) for p in network.state_dict().values() if p.is_floating_point())
    if bad:
        total = sum(p.numel() for p in network.state_dict().values())
        raise ModelError(f"{path}: not a usable model: {bad:,} of its {total:,} weights are not finite (NaN or infinite)")


def _load_map_model(path: Path, schema: _Schema, meta: dict, tensors: dict, arch: dict,
                    expect_obs_shape: Sequence[int] | None, expect_field: Any) -> SavedModel:
    """The rest of :func:`load_model` for a map network."""
    if expect_obs_shape is not None:
        raise ModelError(f"{path}: a map-planning model (it sees the whole map, not a window of "
                         f"{tuple(expect_obs_shape)}): use it with the dqn planner, not in an environment")
    field = schema.field(meta)
    network = _with_weights(path, MapNetwork(**{k: v for k, v in arch.items() if k != "type"}), tensors)
    _check_field(path, field, expect_field)
    return SavedModel(path=path, network=network, obs_shape=(), field=field, observer=None, meta=meta)
