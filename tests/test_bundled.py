"""Bundled worlds: found by name wherever the package is installed; the wheel's package list."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from apf_physics.world.bundled import bundled_dir, list_bundled, resolve_world
from apf_physics.cli import main
from apf_physics.errors import WorldError

ROOT = Path(__file__).resolve().parent.parent


def test_bundled_dir_holds_the_projects_worlds(worlds_dir):
    # In a checkout (editable install) the bundled folder is the project's worlds/ itself.
    assert bundled_dir().resolve() == worlds_dir.resolve()
    assert (bundled_dir() / "fixed20.yaml").is_file()


def test_list_bundled_names_worlds_not_curricula():
    names = list_bundled()
    assert {"fixed20", "local_minimum", "thesis/test1", "thesis/test4"} <= set(names)
    assert not any(name.startswith("curricula") or name.startswith("__") for name in names)
    assert names == sorted(names)


@pytest.mark.parametrize("spec, relative", [
    ("fixed20", "fixed20.yaml"),
    ("fixed20.yaml", "fixed20.yaml"),
    ("thesis/test1", "thesis/test1.yaml"),
    ("thesis/test1.yaml", "thesis/test1.yaml"),
    ("thesis", "thesis"),
    ("curricula/thesis", "curricula/thesis.yaml"),
])
def test_resolve_world_by_bundled_name(spec, relative, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)   # no worlds/ folder here: the names must come from the package
    assert resolve_world(spec) == bundled_dir() / relative


def test_resolve_world_drops_a_leading_worlds_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_world("worlds/thesis/test2.yaml") == bundled_dir() / "thesis" / "test2.yaml"


def test_existing_paths_win_over_bundled_names(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "fixed20").write_text("a local file that happens to share the name")
    assert resolve_world("fixed20") == Path("fixed20")
    assert resolve_world(tmp_path / "fixed20") == tmp_path / "fixed20"


@pytest.mark.parametrize("spec", ["nonesuch", "thesis/test9", "../worlds/fixed20", "/nonexistent/fixed20.yaml"])
def test_unknown_names_list_some_bundled_ones(spec, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(WorldError, match=r"no such world file, and no bundled world of that name( \(did you mean "
                                         r"'[a-z_0-9/]+'\?\))? \(bundled: fixed20, "):
        resolve_world(spec)


@pytest.mark.parametrize("spec, nearest", [("fixd20", "fixed20"), ("worlds/romos.yaml", "rooms"),
                                           ("thesis/tset1", "thesis/test1")])
def test_a_mistyped_world_name_gets_the_nearest_bundled_one(spec, nearest, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(WorldError, match=f"no bundled world of that name \\(did you mean '{nearest}'\\?\\)"):
        resolve_world(spec)


def test_load_world_resolves_bundled_names(tmp_path, monkeypatch):
    # Needs the world loader's hook: path = resolve_world(path) (see apf_physics.world.bundled).
    from apf_physics import load_world, load_worlds

    monkeypatch.chdir(tmp_path)
    assert load_world("fixed20").name == "fixed20"
    assert [w.name for w in load_worlds(["thesis"])][-4:] == ["test1", "test2", "test3", "test4"]


def test_worlds_command_lists_every_bundled_world(capsys):
    assert main(["worlds"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:4] == ["world", "size", "obstacles", "starts"]
    rows = {line.split()[0]: line.split() for line in lines[1:]}
    assert set(rows) == set(list_bundled())
    assert rows["fixed20"][1:4] == ["20x20", "3", "40"]
    assert "Thesis §6.2's fixed world" in " ".join(rows["fixed20"])


def test_pyproject_lists_every_subpackage():
    # The package list is explicit (the worlds/ folder is mapped into the package), so a new
    # subpackage must be added to it or the wheel ships without it.
    tomllib = pytest.importorskip("tomllib" if sys.version_info >= (3, 11) else "tomli")
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    listed = set(config["packages"])
    on_disk = {".".join(p.relative_to(ROOT).parent.parts) for p in (ROOT / "apf_physics").rglob("*.py")}
    assert on_disk - listed == set()
    assert config["package-dir"] == {"apf_physics.worlds": "worlds"}
    data = config["package-data"]
    assert "py.typed" in data["apf_physics"] and "*.pt" in data["apf_physics.models"]
