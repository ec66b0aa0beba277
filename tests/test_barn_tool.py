"""``tools/barn.py``: BARN's worlds as world files, the challenge's score, its world sets, its refusals.

A tiny BARN-like folder is made here (BARN itself is fetched by users, never committed)."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from apf_physics import load_world

TOOL = Path(__file__).resolve().parent.parent / "tools" / "barn.py"


@pytest.fixture(scope="module")
def barn():
    spec = importlib.util.spec_from_file_location("apf_barn_tool", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cylinder(i: int, x: float, y: float) -> str:
    return (f"<model name='unit_cylinder_{i}'><static>1</static><pose frame=''>{x} {y} 0 0 0 0</pose>"
            "<link name='link'><collision name='collision'><geometry><cylinder><radius>0.075</radius>"
            "<length>1</length></cylinder></geometry></collision></link></model>")


def make_barn(folder: Path, index: int = 0) -> Path:
    """A BARN-like world: walls of touching cylinders on three sides, a post beside the way north."""
    lattice = [(-4.425 + 0.15 * k, 0.075) for k in range(30)]
    lattice += [(x, 0.075 + 0.15 * k) for x in (-4.425, -0.075) for k in range(1, 64)]
    lattice += [(-3.0, 7.0)]
    models = "".join(cylinder(i, x, y) for i, (x, y) in enumerate(lattice))
    (folder / "path_files").mkdir(parents=True, exist_ok=True)
    (folder / f"world_{index}.world").write_text(f"<sdf version='1.6'><world name='default'>{models}</world></sdf>")
    np.save(folder / "path_files" / f"path_{index}.npy", np.array([[16, 0], [16, 29]]))
    return folder


def test_the_score_is_run_py_s(barn):
    assert barn.score(True, 1.0, 2.0) == pytest.approx(0.25)          # faster than 4 OT: clipped to 4 OT
    assert barn.score(True, 12.0, 2.0) == pytest.approx(2 / 12)
    assert barn.score(True, 100.0, 2.0) == pytest.approx(0.125)       # slower than 8 OT: clipped to 8 OT
    assert barn.score(False, 1.0, 2.0) == 0.0


def test_optimal_time_adds_the_start_and_the_goal(barn):
    path = np.array([[16, 0], [16, 29]])                               # x = 16 · 0.15 − 4.575 = −2.175
    points = barn.path_coord_to_gazebo_coord(path)
    assert points[0] == pytest.approx([-2.175, 5.075]) and points[1] == pytest.approx([-2.175, 9.425])
    expected = (math.hypot(0.175, 2.075) + 4.35 + math.hypot(0.175, 3.575)) / 2.0
    assert barn.optimal_time(path) == pytest.approx(expected)


def test_dev_and_heldout_split_the_300_worlds(barn):
    dev, held = barn.world_indices("dev"), barn.world_indices("heldout")
    assert len(dev) == 100 and all(i % 3 == 0 for i in dev) and len(held) == 200
    assert sorted(dev + held) == list(range(300))
    assert barn.world_indices("0-6,9") == [0, 1, 2, 3, 4, 5, 6, 9]


def test_a_barn_world_becomes_a_world_file_in_metres(barn, tmp_path):
    make_barn(tmp_path)
    data = barn.world_dict(tmp_path / "world_0.world", 0, 0.21, 0.15)
    assert data["origin"] == [-5.5, -1.0] and data["size"] == [6.5, 15.0]
    assert data["starts"] == [[-2.0, 3.0]] and data["targets"] == [[-2.0, 13.0]] and data["goal_tolerance"] == 1.0
    assert len(data["obstacles"]) == 30 + 126 + 1


def test_the_tool_runs_and_writes_metres_and_seconds(barn, tmp_path, capsys):
    make_barn(tmp_path / "barn")
    out = tmp_path / "out.json"
    assert barn.main(["--barn", str(tmp_path / "barn"), "--worlds", "0", "--planner", "astar", "--step", "0.42",
                      "--json", str(out), "--write-worlds", str(tmp_path / "worlds")]) == 0
    text = capsys.readouterr().out
    assert "astar" in text and "1/1" in text
    result = json.loads(out.read_text())
    (episode,) = result["runs"][0]["episodes"]
    assert episode["outcome"] == "reached" and episode["time_s"] == pytest.approx(episode["steps"] * 0.21)
    assert episode["score"] == pytest.approx(0.25)
    assert math.hypot(episode["final_position_m"][0] + 2, episode["final_position_m"][1] - 13) <= 1.0
    assert load_world(tmp_path / "worlds" / "barn_0_0.42.yaml").frame.unit == 0.42


@pytest.mark.parametrize("argv, words", [
    (["--worlds", "0"], ["no world_0.world"]),
    (["--worlds", "dev", "--step", "-1"], ["--step"]),
    (["--worlds", "dev", "--kinematics", "diff"], ["--kinematics"]),
    (["--worlds", "300"], ["0 to 299"]),
    (["--worlds", "a-b"], ["--worlds"]),
])
def test_bad_input_is_one_message_and_exit_2(barn, tmp_path, capsys, argv, words):
    assert barn.main(["--barn", str(tmp_path)] + argv) == 2
    err = capsys.readouterr().err
    assert all(w in err for w in words) and "Traceback" not in err


def test_a_broken_path_file_is_named(barn, tmp_path, capsys):
    make_barn(tmp_path)
    (tmp_path / "path_files" / "path_0.npy").write_bytes(b"not numpy")
    assert barn.main(["--barn", str(tmp_path), "--worlds", "0", "--planner", "astar"]) == 2
    assert "path_0.npy: not a .npy array" in capsys.readouterr().err
