"""Model files from a careless or hostile hand: every one is refused with one short line.

Each file has a valid checksum (anyone can compute one), so only the checks of the metadata,
the payload and the weights stand between it and the planner.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import os

import pytest
import torch

from apf_physics.cli import main
from apf_physics.errors import ModelError
from apf_physics.models import SHIPPED
from apf_physics.models.files import MAGIC, load_model, read_file, write_file

META, TENSORS = read_file(SHIPPED["thesis-fixed"])


def refused(path) -> str:
    with pytest.raises(ModelError) as err:
        load_model(path)
    message = str(err.value)
    assert "\n" not in message and len(message) <= 500, message
    assert message.startswith(f"{path}: ")
    return message


def with_meta(tmp_path, change) -> str:
    meta = copy.deepcopy(META)
    change(meta)
    return str(write_file(tmp_path / "m.pt", meta, TENSORS))


def with_weights(tmp_path, change) -> str:
    tensors = copy.deepcopy(TENSORS)
    change(tensors["q_network"])
    return str(write_file(tmp_path / "m.pt", META, tensors))


def raw_file(tmp_path, meta_bytes: bytes, payload: bytes) -> str:
    """A file with a correct header and checksum around any bytes."""
    header = {"format_version": 1, "sha256": hashlib.sha256(meta_bytes + payload).hexdigest(),
              "meta_bytes": len(meta_bytes), "payload_bytes": len(payload)}
    path = tmp_path / "raw.pt"
    path.write_bytes(MAGIC + json.dumps(header).encode() + b"\n" + meta_bytes + payload)
    return str(path)


def test_the_shipped_models_pass_every_check():
    from apf_physics.models import MODELS
    shipped = sorted(MODELS.glob("*.pt"))
    assert {p.name for p in shipped} >= {"fixed20.pt", "general.pt", "moving.pt", "map.pt"}
    assert set(SHIPPED.values()) <= set(shipped)
    for path in shipped:
        assert load_model(path).network is not None


@pytest.mark.parametrize("change, words", [
    (lambda m: m.pop("field"), "metadata field: missing"),
    (lambda m: (m.pop("obs_shape"), m["arch"].pop("obs_shape")), "metadata arch.obs_shape: missing"),
    (lambda m: m["arch"].update(obs_shape=["1", "11", "11"]), 'arch.obs_shape[0]: expected a whole number from 1 to 29, got "1"'),
    (lambda m: m["field"].update(katt="2"), 'field.katt: expected a finite number, got "2"'),
    (lambda m: m["arch"].update(filters="10"), "arch.filters: expected a list of 1 to 8 whole numbers"),
    (lambda m: m.update(obs_shape=[2, 11, 11]), "obs_shape: [2, 11, 11] contradicts arch.obs_shape [1, 11, 11]"),
    (lambda m: m.update(observer={"size": 9, "resolution": 4, "channels": ["potential"]}),
     "observer builds (1, 9, 9) observations, but its network takes (1, 11, 11)"),
    (lambda m: m.update(observer={"size": 11, "resolution": 1000, "channels": ["potential"]}),
     "observer.resolution: expected a whole number from 1 to 8, got 1000"),
    (lambda m: m["arch"].update(hidden=[4096] * 4), "a network of 53,335,305 parameters"),
    (lambda m: m["arch"].update(filters=[4] * 8, pooled_convs=4), "a 11 x 11 window is too small for 8 convolutions"),
    (lambda m: m["arch"].update(obs_transform="rm -rf"), "arch.obs_transform: expected one of raw, relative-log"),
    (lambda m: m["arch"].update(n_actions=10**9), "arch.n_actions: expected a whole number from 9 to 9"),
    (lambda m: m.update(kind=None), "metadata kind: expected one of model, checkpoint, got null"),
    (lambda m: m["arch"].update(extra=1), "metadata arch.extra: unknown key"),
])
def test_metadata_is_checked_against_the_schema_before_anything_is_built(tmp_path, change, words):
    assert words in refused(with_meta(tmp_path, change))


def test_non_finite_weights_are_refused(tmp_path):
    path = with_weights(tmp_path, lambda q: q["hidden.0.weight"].__setitem__((0, 0), float("nan")))
    assert "1 of its 25,705 weights are not finite" in refused(path)


def test_weights_that_do_not_fit_the_network_are_one_line(tmp_path):
    path = with_weights(tmp_path, lambda q: q.__setitem__("hidden.0.weight", torch.zeros(3, 3)))
    assert "the weights do not fit the network the metadata describes" in refused(path)
    path = str(write_file(tmp_path / "m.pt", META, {"other": torch.zeros(1)}))
    assert "the payload has no 'q_network' weights" in refused(path)


class _Shell:
    def __reduce__(self):
        return (os.system, ("touch PWNED",))


def test_payloads_that_are_not_plain_tensors_are_refused_without_running_anything(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    pickled = io.BytesIO()
    torch.save({"q_network": _Shell()}, pickled)
    message = refused(raw_file(tmp_path, json.dumps(META).encode(), pickled.getvalue()))
    assert "nothing in it was run" in message and "posix.system" in message
    assert not (tmp_path / "PWNED").exists()
    assert "unreadable model file" in refused(raw_file(tmp_path, json.dumps(META).encode(), b"not a torch file" * 8))


@pytest.mark.parametrize("meta_bytes, words", [
    (b"[1, 2]", "not a JSON object"),
    (b"[" * 100_000 + b"]" * 100_000, "unreadable model metadata"),
    (b'{"arch": 1e999}', "metadata kind: missing"),
])
def test_metadata_that_is_not_an_object_is_one_line(tmp_path, meta_bytes, words):
    payload = io.BytesIO()
    torch.save(TENSORS, payload)
    assert words in refused(raw_file(tmp_path, meta_bytes, payload.getvalue()))


def test_header_sizes_are_checked_against_the_file_before_reading(tmp_path):
    path = tmp_path / "h.pt"
    path.write_bytes(MAGIC + b'{"format_version": 1, "sha256": "0", "meta_bytes": 99999999999, "payload_bytes": 1}\n')
    assert "expected 100000000000" in refused(path)
    path.write_bytes(MAGIC + b'{"format_version": 1, "sha256": "0", "meta_bytes": "9", "payload_bytes": 1}\n')
    assert "unreadable header" in refused(path)


def test_only_regular_files_are_read(tmp_path):
    fifo = tmp_path / "model.pt"
    os.mkfifo(fifo)
    assert "not a regular file" in refused(fifo)
    assert "not a regular file" in refused(tmp_path)


def test_the_command_line_prints_one_line(tmp_path, worlds_dir, capsys):
    path = with_meta(tmp_path, lambda m: m["arch"].update(obs_shape=["1", "11", "11"]))
    assert main(["eval", str(worlds_dir / "fixed20.yaml"), "--planner", "dqn", "--model", path]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("apf-physics: error: ") and "Traceback" not in err
