"""The world-file contract: valid files load; each kind of bad input gets one clear error."""

import json

import numpy as np
import pytest
import yaml

from apf_physics import WorldError, load_world, world_from_dict
from apf_physics.worldfile import dump_world_yaml, load_worlds
from conftest import simple_world_dict


def write(tmp_path, data, name="w.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


def test_seed_worlds_load(worlds_dir):
    worlds = load_worlds([worlds_dir])
    names = {w.name for w in worlds}
    assert {"fixed20", "local_minimum", "three_targets", "three_targets_no_blackhole"} <= names
    fixed = next(w for w in worlds if w.name == "fixed20")
    assert len(fixed.starts) == 40
    assert fixed.field.p0 == 0.5 and fixed.field.katt == 2


def test_json_is_accepted(tmp_path):
    path = tmp_path / "w.json"
    path.write_text(json.dumps(simple_world_dict()))
    world = load_world(path)
    assert world.size == (20.0, 20.0)
    assert len(world.obstacles) == 2


def test_round_trip(tmp_path):
    world = world_from_dict(simple_world_dict())
    again = world_from_dict(yaml.safe_load(dump_world_yaml(world)))
    assert again.to_dict() == world.to_dict()


def test_polygon_winding_is_normalised():
    clockwise = simple_world_dict(obstacles=[{"polygon": [[5, 5], [5, 8], [8, 8], [8, 5]]}])
    world = world_from_dict(clockwise)
    assert world.obstacle_distance(np.array([[6.5, 6.5]]))[0] < 0


def test_field_preset_by_name():
    world = world_from_dict(simple_world_dict(field="thesis-general"))
    assert world.field.p0 == 3 and world.field.katt == 1


@pytest.mark.parametrize("mutate, key, words", [
    (lambda d: d.pop("size"), "size", "missing"),
    (lambda d: d.update(colour="red"), "colour", "unknown key"),
    (lambda d: d.update(size=[20, "wide"]), "size[1]", "expected a number"),
    (lambda d: d.update(size=[20, -3]), "size[1]", "must be positive"),
    (lambda d: d.update(robot_radius=0), "robot_radius", "must be positive"),
    (lambda d: d.update(goal_tolerance=float("nan")), "goal_tolerance", "finite"),
    (lambda d: d["field"].update(katt=float("inf")), "field.katt", "finite"),
    (lambda d: d["field"].pop("p0"), "field.p0", "missing"),
    (lambda d: d["field"].update(speed=3), "field.speed", "unknown key"),
    (lambda d: d.update(obstacles=[{"polygon": [[1, 1], [2, 2]]}]), "obstacles[0].polygon", "at least 3"),
    (lambda d: d.update(obstacles=[{"polygon": [[1, 1], [4, 4], [4, 1], [1, 4]]}]), "obstacles[0].polygon", "crosses itself"),
    (lambda d: d.update(obstacles=[{"polygon": [[1, 1], [2, 2], [3, 3]]}]), "obstacles[0].polygon", "zero area"),
    (lambda d: d.update(obstacles=[{"polygon": [[18, 1], [22, 1], [20, 4]]}]), "obstacles[0].polygon", "outside the map"),
    (lambda d: d.update(obstacles=[{"circle": {"center": [1, 10], "radius": 2}}]), "obstacles[0].circle", "outside the map"),
    (lambda d: d.update(obstacles=[{"circle": {"center": [10, 10], "radius": -1}}]), "obstacles[0].circle.radius", "negative"),
    (lambda d: d.update(obstacles=[{"circle": {"center": [10, 10]}}]), "obstacles[0].circle.radius", "missing"),
    (lambda d: d.update(obstacles=[{"square": 3}]), "obstacles[0].square", "unknown key"),
    (lambda d: d.update(obstacles=[{"polygon": [[1, 1], [2, 1], [2, 2]], "circle": {"center": [5, 5], "radius": 1}}]),
     "obstacles[0]", "exactly one"),
    (lambda d: d.update(starts=[[6.5, 6]]), "starts[0]", "inside an obstacle"),
    (lambda d: d.update(starts=[[25, 2]]), "starts[0]", "outside the map"),
    (lambda d: d.update(starts=[[0.1, 2]]), "starts[0]", "robot radius"),
    (lambda d: d.update(targets=[[6.5, 6]]), "targets[0]", "inside an obstacle"),
    (lambda d: d.update(targets=[[-1, 6]]), "targets[0]", "outside the map"),
    (lambda d: d.update(targets=[]), "targets", "at least 1"),
    (lambda d: d.update(targets=[[1, 2, 3]]), "targets[0]", "expected a point"),
    (lambda d: d.update(formation={"followers": -1}), "formation.followers", "whole number"),
])
def test_bad_input_names_file_key_and_problem(tmp_path, mutate, key, words):
    data = simple_world_dict()
    mutate(data)
    path = write(tmp_path, data)
    with pytest.raises(WorldError) as err:
        load_world(path)
    message = str(err.value)
    assert str(path) in message
    assert f": {key}:" in message
    assert words in message


def test_not_yaml(tmp_path):
    path = write(tmp_path, "size: [20, 20\nfield: {")
    with pytest.raises(WorldError, match="not valid YAML"):
        load_world(path)


def test_not_a_mapping(tmp_path):
    with pytest.raises(WorldError, match="mapping"):
        load_world(write(tmp_path, "- 1\n- 2\n"))


def test_missing_file(tmp_path):
    with pytest.raises(WorldError, match="no such world file"):
        load_world(tmp_path / "nope.yaml")


def test_cli_reports_error_without_traceback(tmp_path, capsys):
    from apf_physics.cli import main

    data = simple_world_dict(starts=[[6.5, 6]])
    path = write(tmp_path, data)
    assert main(["eval", str(path)]) == 2
    err = capsys.readouterr().err
    assert "starts[0]" in err and str(path) in err and "Traceback" not in err
