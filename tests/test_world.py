"""The world-file contract: valid files load; each kind of bad input gets one clear error."""

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from apf_physics import WorldError, load_world, world_from_dict
from apf_physics.errors import UserError
from apf_physics.world.obstacles import PolygonObstacle
from apf_physics.world.io.worldfile import dump_world_yaml, load_worlds, save_world
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
    """A world written and read back is the same world: its map, robot, field, obstacles, targets,
    starts and formation, and so the same potential everywhere."""
    data = simple_world_dict(formation={"followers": 2, "comm_range": 2.5, "spacing": 0.75, "shape": "wedge"},
                             obstacles=[{"polygon": [[5, 5], [8, 5], [8, 9], [6, 9]], "name": "wall"},
                                        {"circle": {"center": [12, 4], "radius": 0.5},
                                         "motion": {"path": [[0, 3]], "speed": 0.5, "phase": 1.0}}])
    world = world_from_dict(data)
    again = world_from_dict(yaml.safe_load(dump_world_yaml(world)))
    assert (again.name, again.size, again.robot_radius, again.goal_tolerance) == \
        (world.name, world.size, world.robot_radius, world.goal_tolerance)
    assert again.field == world.field and again.formation == world.formation
    np.testing.assert_array_equal(again.targets, world.targets)
    np.testing.assert_array_equal(again.starts, world.starts)
    (polygon, circle), (polygon2, circle2) = world.obstacles, again.obstacles
    np.testing.assert_array_equal(polygon2.vertices, polygon.vertices)
    assert polygon2.name == "wall" and circle2.radius == circle.radius
    np.testing.assert_array_equal(circle2.center, circle.center)
    np.testing.assert_array_equal(circle2.motion.path, circle.motion.path)
    assert (circle2.motion.speed, circle2.motion.loop, circle2.motion.phase) == \
        (circle.motion.speed, circle.motion.loop, circle.motion.phase)
    points = np.random.default_rng(0).uniform(0, 20, (200, 2))
    for t in (0.0, 3.0):
        np.testing.assert_array_equal(again.potential(points, t), world.potential(points, t))


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
    (lambda d: d.update(starts=[[6.5, 6]]), "starts[0]", "inside obstacles[0]"),
    (lambda d: d.update(starts=[[25, 2]]), "starts[0]", "outside the map"),
    (lambda d: d.update(starts=[[0.1, 2]]), "starts[0]", "robot radius"),
    (lambda d: d.update(targets=[[6.5, 6]]), "targets[0]", "inside obstacles[0]"),
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


# -- hostile input: every problem one short line, limits checked before the work they protect ------

def one_line_error(load) -> str:
    with pytest.raises(WorldError) as err:
        load()
    message = str(err.value)
    assert "\n" not in message and len(message) <= 500, message[:600]
    return message


def test_yaml_alias_bomb_is_refused_from_its_definition(tmp_path):
    # 537 bytes that expand to 9**10 values: nine levels of nine aliases each
    bomb = "size: &x0 [1,1,1,1,1,1,1,1,1]\n" + "".join(
        f"l{i}: &x{i} [" + ",".join([f"*x{i - 1}"] * 9) + "]\n" for i in range(1, 10))
    message = one_line_error(lambda: load_world(write(tmp_path, bomb)))
    assert "more than 500,000 values" in message and "line 6" in message


@pytest.mark.parametrize("text, words", [
    ("field: thesis-fixed\ntargets: [[5, 5]]\nsize: [1" + "0" * 400 + ", 20]",
     "size[0]: too large for a number: <an integer of about 401 digits>"),
    ("size: [1" + "0" * 5000 + ", 20]", "a value of 5,001 characters"),
    ("size: " + "[" * 40 + "]" * 40, "nested deeper than 32 levels"),
    ("size: &a [1, *a]", "alias *a is inside the collection it names"),
    ("size: [20, 20]\nsize: [30, 30]", "line 2: key 'size' appears twice in one mapping"),
    ("size: !!python/object/apply:os.system [echo]", "unsupported tag"),
    ("targets: 2024-13-45", "not valid YAML: 'month must be in 1..12'"),
    ("--- {}\n--- {}", "a second document"),
])
def test_yaml_beyond_the_limits_is_one_line(tmp_path, text, words):
    assert words in one_line_error(lambda: load_world(write(tmp_path, text + "\n")))


def test_yaml_merge_keys_and_shared_values_read_as_safe_load_reads_them(tmp_path, worlds_dir):
    from apf_physics.world.io.worldfile import read_yaml_file

    text = ("base: &field {katt: 1, krep: 20}\nfield:\n  <<: *field\n  krep: 5\n"
            "point: &p [1, 2]\npoints: [*p, *p]\nmany:\n  <<: [{a: 1}, {a: 2, b: 3}]\n")
    assert read_yaml_file(write(tmp_path, text), "world") == yaml.safe_load(text)
    for path in worlds_dir.rglob("*.yaml"):
        assert read_yaml_file(path, "world") == yaml.safe_load(path.read_text())


def test_json_style_exponents_are_numbers(tmp_path):
    # YAML 1.1 reads 1e-3 as a string; JSON and YAML 1.2 read it as a number
    world = load_world(write(tmp_path, json.dumps(simple_world_dict(robot_radius=2.5e-1, goal_tolerance=5e-1)), "w.json"))
    assert world.robot_radius == 0.25
    assert "must be at least 0.01" in one_line_error(lambda: load_world(write(tmp_path, "robot_radius: 1e-9\n" + yaml.safe_dump(
        {k: v for k, v in simple_world_dict().items() if k != "robot_radius"}))))


def test_field_preset_that_is_not_a_name(tmp_path):
    message = one_line_error(lambda: load_world(write(tmp_path, simple_world_dict(field={"preset": [1]}))))
    assert ": field.preset: unknown preset [1]" in message


def test_only_regular_files_are_read(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    assert "it is a FIFO, not a regular file" in one_line_error(lambda: load_world(fifo))
    assert "it is a directory" in one_line_error(lambda: load_world(tmp_path))
    if Path("/dev/zero").exists():
        assert "character device" in one_line_error(lambda: load_world("/dev/zero"))


def test_a_file_over_the_size_limit_is_refused_before_it_is_read(tmp_path):
    from apf_physics.world.io.worldfile import MAX_FILE_BYTES

    path = tmp_path / "big.yaml"
    with open(path, "wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)   # sparse: nothing to read, only its size says no
    assert f"over the limit of {MAX_FILE_BYTES:,}" in one_line_error(lambda: load_world(path))


@pytest.mark.parametrize("overrides, key, words", [
    ({"robot_radius": 1e-9}, "robot_radius", "at least 0.01 (smaller robots need more than 256 physics substeps"),
    ({"robot_radius": 5e-324, "size": [1e308, 1e308]}, "size[0]", "between 1 and 10,000 units"),
    ({"robot_radius": 12}, "robot_radius", "does not fit in the 20 x 20 map"),
    ({"goal_tolerance": 1e300}, "goal_tolerance", "not less than half the map's diagonal (14.14)"),
    ({"goal_tolerance": 0.1}, "goal_tolerance", "at least 0.25"),
    ({"field": {"preset": "thesis-fixed", "ps": 1e300}}, "field", "|U| would reach infinity"),
    ({"field": {"preset": "thesis-fixed", "kstr": 1e300}}, "field", "|U| would reach about 3.2e+301"),
    ({"field": {"preset": "thesis-fixed", "p0": 5e-324}}, "field", "the slope of U would reach infinity"),
    ({"size": [1e5, 1e5]}, "size[0]", "between 1 and 10,000 units, got 100000"),
    ({"size": [2000, 2000]}, "size", "GiB of rasters (the planners' at 4 nodes per unit), "
                                     "over the budget of 2.0 GiB"),
    ({"starts": [[15.2, 15.2]]}, "starts[0]", "already within goal_tolerance 0.5 of a target"),
    ({"name": "x" * 300}, "name", "at most 200 characters"),
    ({"name": "two\nlines"}, "name", "printable on one line"),
])
def test_values_that_would_break_the_layers_above_are_refused(tmp_path, overrides, key, words):
    path = write(tmp_path, json.dumps(simple_world_dict(**overrides)), "w.json")
    with pytest.raises(WorldError) as err:
        load_world(path)
    lines = str(err.value).split("\n")
    assert all(len(line) <= 500 for line in lines)
    assert any(line.startswith(f"{path}: {key}: ") and words in line for line in lines), lines


def test_the_smallest_allowed_robot_keeps_the_physics_within_256_substeps():
    from apf_physics.sim.physics import substeps_for
    from apf_physics.world.io.worldfile import MIN_ROBOT_RADIUS

    world = world_from_dict(simple_world_dict(robot_radius=MIN_ROBOT_RADIUS))
    assert substeps_for(world.robot_radius) == 256


def test_the_memory_budget_can_be_raised_for_big_machines(monkeypatch):
    data = simple_world_dict(size=[2000, 2000])
    with pytest.raises(WorldError, match="APF_PHYSICS_MEMORY_BUDGET"):
        world_from_dict(data)
    monkeypatch.setenv("APF_PHYSICS_MEMORY_BUDGET", "32G")
    assert world_from_dict(data).size == (2000.0, 2000.0)
    monkeypatch.setenv("APF_PHYSICS_MEMORY_BUDGET", "lots")
    with pytest.raises(UserError, match="expected a size such as 8G"):
        world_from_dict(data)


RASTER_PEAK = """
import sys
import numpy as np
from apf_physics.world.io.mapfiles import write_pgm
from apf_physics.sensing.mapview import MapView
from apf_physics.sensing.observation import observation_raster
from apf_physics.world.search import SearchGrid
from apf_physics.sim.swept import SweptDistances
from apf_physics.world.io.worldfile import raster_memory, world_from_dict
if sys.argv[1] == "grid":   # a random occupancy grid of 150 x 150 cells, one unit each
    occupied = np.random.default_rng(0).random((150, 150)) < 0.2
    occupied[70:80, 70:80] = occupied[15:25, 135:145] = False
    write_pgm(sys.argv[2] + "/m.pgm", occupied)
    where = {"grid": {"image": sys.argv[2] + "/m.pgm", "resolution": 1.0, "origin": [0, 0, 0]}}
else:
    where = {"size": [150, 150], "obstacles": [{"circle": {"center": [30, 30], "radius": 2}}]}
world = world_from_dict({**where, "field": "thesis-general", "targets": [[75, 75], [140, 20]], "starts": []})
def status(key):   # kB figures of /proc/self/status
    return next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith(key + ":"))
try:   # reset the peak, so that what imports used does not count
    open("/proc/self/clear_refs", "w").write("5")
except OSError:
    pass
before = status("VmRSS")
SweptDistances().add(world)                                            # the physics' index of static shapes
observation_raster(world, 7, 4)                                # the DQN planner's (and u_wall's potential raster)
world.start_cells()                                            # --random-starts
SearchGrid.of(world).cost_to_go                                # the A* planner's
MapView.of(world, 2)                                           # the map network's
peak = status("VmHWM")
print(peak - before, raster_memory(world.size, len(world.targets)))
"""


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="reads the resident set from /proc")
@pytest.mark.parametrize("kind", ["polygons", "grid"])
def test_the_raster_memory_estimate_covers_what_an_evaluation_builds(kind, tmp_path):
    """The peak resident memory the rasters of an evaluation of a 150 x 150 map add (every
    planner's, and random starts'), in a fresh process, stays within the loader's estimate,
    for a map of polygons and for an occupancy grid."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", RASTER_PEAK, kind, str(tmp_path)], capture_output=True, text=True,
                         check=True).stdout
    used, estimate = (int(float(v)) for v in out.split())
    assert 0 < used <= estimate


def test_a_polygon_of_20k_vertices_is_refused_before_its_simplicity_is_checked(tmp_path, monkeypatch):
    from apf_physics.common import geometry

    angles = np.linspace(0, 2 * np.pi, 20_000, endpoint=False)
    ring = np.column_stack([10 + 5 * np.cos(angles), 10 + 5 * np.sin(angles)]).round(6).tolist()
    monkeypatch.setattr(geometry, "polygon_is_simple", lambda v: pytest.fail("checked a refused polygon"))
    message = one_line_error(lambda: world_from_dict(simple_world_dict(obstacles=[{"polygon": ring}]), "w.yaml"))
    assert "obstacles[0].polygon: at most 1,000 vertices, got 20,000" in message


def test_too_many_obstacles_or_vertices_are_refused_before_any_is_parsed(tmp_path, monkeypatch):
    from apf_physics.world.io import schema

    monkeypatch.setattr(schema, "_parse_obstacle", lambda *a: pytest.fail("parsed an obstacle of a refused list"))
    points = [{"circle": {"center": [10, 10], "radius": 0}}] * 10_001
    assert "obstacles: at most 10,000 obstacles, got 10,001" in one_line_error(
        lambda: world_from_dict(simple_world_dict(obstacles=points), "w.yaml"))
    triangle = [[1, 1], [2, 1], [1, 2]] * 340
    assert "at most 100,000 polygon vertices in all, got 102,000" in one_line_error(
        lambda: world_from_dict(simple_world_dict(obstacles=[{"polygon": triangle}] * 100), "w.yaml"))


def test_a_file_of_100k_obstacles_is_refused_by_the_reader(tmp_path):
    circles = [{"circle": {"center": [10, 10], "radius": 0}}] * 100_000
    message = one_line_error(lambda: load_world(write(tmp_path, json.dumps(simple_world_dict(obstacles=circles)), "w.json")))
    assert "more than 500,000 values" in message


def test_every_problem_is_reported_one_line_each_with_did_you_mean(tmp_path):
    path = write(tmp_path, {"size": [20, "wide"], "robot_radus": 0.3, "field": {"katt": "a", "krep": None},
                            "targets": [[1, 2, 3]], "starts": [[1, None]]})
    with pytest.raises(WorldError) as err:
        load_world(path)
    lines = str(err.value).split("\n")
    assert [line.split(": ")[1] for line in lines] == [
        "robot_radus", "size[1]", "field.katt", "field.krep", "field.kstr", "field.p0", "field.ps", "field.u_max",
        "targets[0]", "starts[0][1]"]
    assert all(line.startswith(f"{path}: ") for line in lines)
    assert "did you mean 'robot_radius'?" in lines[0]


def test_problems_are_listed_to_a_cap_then_counted(tmp_path):
    from apf_physics.world.io.schema import MAX_COUNTED, MAX_PROBLEMS

    with pytest.raises(WorldError) as err:
        world_from_dict(simple_world_dict(starts=[["x", "y"]] * 100), "w.yaml")
    lines = str(err.value).split("\n")
    assert len(lines) == MAX_PROBLEMS + 1
    assert lines[-1] == f"w.yaml: and 180 more problems (200 in all; the first {MAX_PROBLEMS} are listed)"
    with pytest.raises(WorldError) as err:   # a file of endless mistakes is not read to its end
        world_from_dict(simple_world_dict(starts=[["x", "y"]] * 1000), "w.yaml")
    lines = str(err.value).split("\n")
    assert lines[-1] == f"w.yaml: and {MAX_COUNTED - MAX_PROBLEMS:,} more problems (the check stopped after {MAX_COUNTED:,})"


def test_values_are_shortened_in_messages():
    message = one_line_error(lambda: world_from_dict(simple_world_dict(size=[20, "x" * 4000]), "w.yaml"))
    assert message.startswith("w.yaml: size[1]: expected a number, got str 'xxxx") and len(message) < 120
    message = one_line_error(lambda: world_from_dict(simple_world_dict(size=[20, 10**5000]), "w.yaml"))
    assert "<an integer of about 5001 digits>" in message
    deep: list = []
    for _ in range(5000):
        deep = [deep]
    assert "got list [[[[...]]]]" in one_line_error(lambda: world_from_dict(simple_world_dict(targets=[deep]), "w.yaml"))


def test_a_bounded_number_of_generated_worlds_stay_within_the_limits():
    from apf_physics.world.generate import FAMILIES, generate_world

    rng = np.random.default_rng(3)
    for family in FAMILIES:
        for size in (20, 100):
            world = generate_world(family, rng, size=size, n_starts=2)
            assert world_from_dict(world.to_dict()).size == (size, size)


def test_moving_obstacles_round_trip_and_their_routes_stay_inside_the_map():
    moving = {"circle": {"center": [10, 4], "radius": 0.5}, "motion": {"path": [[0, 8]], "speed": 0.5, "phase": 2}}
    world = world_from_dict(simple_world_dict(obstacles=[moving]))
    assert world.moving == (0,)
    assert world_from_dict(yaml.safe_load(dump_world_yaml(world))).to_dict() == world.to_dict()
    far = {**moving, "motion": {"path": [[0, 30]], "speed": 0.5}}
    assert "obstacles[0].circle: circle reaches outside the map [0, 20] x [0, 20] on its route" in one_line_error(
        lambda: world_from_dict(simple_world_dict(obstacles=[far]), "w.yaml"))
    fast = {**moving, "motion": {"path": [[0, 8]], "speed": 3, "loop": "yes"}}
    with pytest.raises(WorldError) as err:
        world_from_dict(simple_world_dict(obstacles=[fast]), "w.yaml")
    assert str(err.value).split("\n") == [
        "w.yaml: obstacles[0].motion.speed: at most 1 unit per control step, got 3",
        "w.yaml: obstacles[0].motion.loop: expected true or false, got str 'yes'"]


def test_a_file_with_five_mistakes_gets_one_report_naming_all_five(tmp_path):
    """Schema problems and placement problems together: the entries that parsed are still placed."""
    data = simple_world_dict()
    data["obstacles"] = [{"polygon": [[1, 1], [3, 1], [3, 3], [1, 3]], "name": "wall_b"},
                         {"circle": {"center": [10, 10], "radius": 2}},
                         {"cirle": {"center": [15, 15], "radius": 1}}]                     # 1: a typo
    data["starts"] = [[2, 2],                                                               # 2: inside obstacles[0]
                      ["a", 3],                                                             # 3: not a number
                      [12.2, 10],                                                           # 4: too near obstacles[1]
                      [30, 3]]                                                              # 5: outside the map
    path = write(tmp_path, data)
    with pytest.raises(WorldError) as err:
        load_world(path)
    lines = str(err.value).splitlines()
    expected = ["obstacles[2].cirle: unknown key (did you mean 'circle'?",
                "starts[0]: [2.0, 2.0] is inside obstacles[0] 'wall_b'",
                "starts[1][0]: expected a number",
                "starts[2]: [12.2, 10.0] is closer than the robot radius",
                "starts[3]: [30.0, 3.0] is outside the map"]
    assert len(lines) == 5 and all(str(path) in line for line in lines)
    for words in expected:
        assert sum(words in line for line in lines) == 1, words


def test_obstacle_names_are_checked_and_kept(tmp_path):
    data = simple_world_dict()
    data["obstacles"][0]["name"] = "pillar"
    data["obstacles"][1]["name"] = "pillar"
    with pytest.raises(WorldError) as err:
        world_from_dict(data, "w.yaml")
    assert str(err.value) == "w.yaml: obstacles[1].name: 'pillar' is already the name of obstacles[0]"
    data["obstacles"][1]["name"] = 7
    with pytest.raises(WorldError, match=r"obstacles\[1\]\.name: expected a non-empty string, got int"):
        world_from_dict(data, "w.yaml")
    data["obstacles"][1]["name"] = "post"
    world = world_from_dict(data, "w.yaml")
    assert [o.name for o in world.obstacles] == ["pillar", "post"]
    path = tmp_path / "named.yaml"
    save_world(world, path)
    assert [o.name for o in load_world(path).obstacles] == ["pillar", "post"]


def test_a_world_made_by_replace_builds_its_own_caches():
    """dataclasses.replace with other obstacles must not read the rasters and indexes of the world it
    came from (only among(), with_task() and formation_world() share them, on purpose)."""
    base = world_from_dict(simple_world_dict())
    far = np.array([[15.0, 4.0]])
    base.potential(far)                       # fill the caches
    assert len(base.static_obstacles) == 2
    wall = PolygonObstacle(np.array([[13.0, 2.0], [17.0, 2.0], [17.0, 6.0], [13.0, 6.0]]))
    walled = dataclasses.replace(base, obstacles=base.obstacles + (wall,))
    assert len(walled.static_obstacles) == 3
    assert walled.obstacle_distance(far)[0] < 0 < base.obstacle_distance(far)[0]
    assert walled.potential(far)[0] > base.potential(far)[0]
    view = base.with_task(np.array([[2.0, 15.0]]), np.array([[15.0, 15.0]]))
    assert view.static_obstacles is base.static_obstacles   # a view of the same map shares them
