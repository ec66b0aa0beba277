"""Outputs: checked before the work, never replacing what is not a regular file, never losing a user's file."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from apf_physics.cli import main
from apf_physics.cli import eval as eval_command

WORLD = "fixed20"


def no_work(monkeypatch):
    """Fail the test if an evaluation starts (patched where the command calls it: its module is
    imported once, so patching ``apf_physics.experiments.evaluate`` would leak into later tests)."""
    monkeypatch.setattr(eval_command, "evaluate", lambda *a, **k: pytest.fail("the evaluation ran"))


def refused(capsys, argv) -> str:
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert "wrote" not in out and err.count("\n") == 1 and "Traceback" not in err
    return err


@pytest.mark.parametrize("make, kind", [
    (lambda p: p.symlink_to(p.parent / "elsewhere.json"), "a symbolic link"),
    (lambda p: os.mkfifo(p), "a FIFO"),
    (lambda p: p.mkdir(), "a directory"),
])
def test_json_to_what_is_not_a_regular_file_is_refused_before_the_evaluation(tmp_path, capsys, monkeypatch, make, kind):
    no_work(monkeypatch)
    target = tmp_path / "out.json"
    make(target)
    assert f"it is {kind}, not a regular file" in refused(capsys, ["eval", WORLD, "--json", str(target)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]   # no temporary file left
    assert not (tmp_path / "elsewhere.json").exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="making a device node needs root")
def test_json_to_a_device_is_refused_and_the_device_stays(tmp_path, capsys, monkeypatch):
    no_work(monkeypatch)
    device = tmp_path / "full"
    os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 7))   # a /dev/full of our own
    assert "it is a device" in refused(capsys, ["eval", WORLD, "--json", str(device)])
    assert stat.S_ISCHR(os.lstat(device).st_mode)


def test_json_under_a_file_is_refused_before_the_worlds_are_read(tmp_path, capsys, monkeypatch):
    no_work(monkeypatch)
    (tmp_path / "file").write_text("mine")
    err = refused(capsys, ["eval", str(tmp_path / "missing.yaml"), "--json", str(tmp_path / "file" / "out.json")])
    assert "file is not a directory" in err or "Not a directory" in err
    assert (tmp_path / "file").read_text() == "mine"


def test_json_is_written_whole(tmp_path, capsys):
    target = tmp_path / "new" / "out.json"
    assert main(["eval", WORLD, "--json", str(target), "--max-steps", "2"]) == 0
    assert target.read_text().startswith("[") and [p.name for p in target.parent.iterdir()] == ["out.json"]


def test_a_world_without_starts_is_named(tmp_path, capsys, monkeypatch):
    no_work(monkeypatch)
    world = tmp_path / "nostarts.yaml"
    world.write_text("size: [20, 20]\nfield: thesis-fixed\ntargets: [[15, 15]]\n")
    err = refused(capsys, ["eval", WORLD, str(world)])
    assert f"{world}: no starts to run from" in err and "--random-starts" in err
    assert "must be from 1 to 10,000" in refused(capsys, ["eval", str(world), "--random-starts", "0"])


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc")
def test_plot_curve_into_proc_is_refused(tmp_path, capsys):
    log = tmp_path / "train.csv"
    log.write_text("global_step,episodes\n")
    assert "cannot write /proc/c.png" in refused(capsys, ["plot-curve", str(log), "--out", "/proc/c.png"])


def generate(out, *extra) -> list[str]:
    return ["generate", "--family", "point", "--out", str(out), "--no-label", "--size", "20", *extra]


def test_generate_refuses_a_folder_that_is_not_empty_and_force_leaves_no_stale_world(tmp_path, capsys):
    out = tmp_path / "set"
    assert main(generate(out, "--count", "5")) == 0
    capsys.readouterr()
    err = refused(capsys, generate(out, "--count", "2"))
    assert "is not empty" in err and "--force" in err
    assert len(list(out.glob("*.yaml"))) == 5
    assert main(generate(out, "--count", "2", "--force")) == 0
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "point20_0.yaml", "point20_1.yaml"]


def test_generate_force_never_removes_a_world_it_did_not_write(tmp_path, capsys):
    out = tmp_path / "set"
    out.mkdir()
    mine = out / "mine.yaml"
    mine.write_text("size: [20, 20]\n")
    (out / "notes.txt").write_text("keep")
    err = refused(capsys, generate(out, "--count", "1", "--force"))
    assert "did not write (mine.yaml)" in err
    assert mine.read_text() == "size: [20, 20]\n" and (out / "notes.txt").read_text() == "keep"
    assert sorted(p.name for p in out.iterdir()) == ["mine.yaml", "notes.txt"]


def test_generate_refuses_a_map_beyond_the_memory_budget_before_drawing(tmp_path, capsys):
    err = refused(capsys, ["generate", "--family", "point", "--count", "1", "--out", str(tmp_path / "s"), "--size", "5000"])
    assert "GiB of rasters" in err and not (tmp_path / "s").exists()
