"""Grid maps as worlds: ROS maps in metres, MovingAI maps and scenarios, any step length."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from apf_physics.errors import WorldError
from apf_physics.experiments.evaluate import evaluate
from apf_physics.world.io.mapfiles import write_pgm
from apf_physics.world.obstacles import GridObstacle
from apf_physics.sim.physics import Physics
from apf_physics.planners import make_planner
from apf_physics.world.io.worldfile import load_world, world_from_dict
from apf_physics.world.io.units import world_to_file

MAZE = """type octile
height 7
width 9
map
@@@@@@@@@
@...@...@
@.@.@.@.@
@.@...@.@
@.@@@@@.@
@.......@
@@@@@@@@@
"""


def scaled(data: dict, k: float) -> dict:
    """A world-file mapping with every length multiplied by ``k`` (and the robot's step with it)."""
    def pts(v):
        return (np.asarray(v, float) * k).tolist()
    out = dict(data)
    out["size"] = pts(data["size"])
    out["robot"] = {"radius": data["robot"]["radius"] * k, "step": data["robot"]["step"] * k}
    out["goal_tolerance"] = data["goal_tolerance"] * k
    out["targets"], out["starts"] = pts(data["targets"]), pts(data["starts"])
    out["obstacles"] = [{"polygon": pts(o["polygon"])} if "polygon" in o else
                        {"circle": {"center": pts(o["circle"]["center"]), "radius": o["circle"]["radius"] * k}}
                        for o in data["obstacles"]]
    f = data["field"]
    if isinstance(f, str):   # a preset by name: its values are in steps, whatever the file's unit
        return out
    out["field"] = dict(f, katt=f["katt"] / k**2, krep=f["krep"] * k**2, kstr=f["kstr"] / k**2, p0=f["p0"] * k,
                        ps=f["ps"] * k)
    return out


@pytest.mark.parametrize("k", [0.25, 0.05])
def test_one_world_at_two_scales_gives_the_same_episodes(k):
    unit = load_world("fixed20")
    small = world_from_dict(scaled(world_to_file(unit), k), "<scaled>")
    assert small.frame.unit == pytest.approx(k)
    np.testing.assert_allclose(small.starts, unit.starts, atol=1e-9)
    for name in ("gradient", "dqn"):
        a = evaluate(make_planner(name), [unit]).episodes
        b = evaluate(make_planner(name), [small]).episodes
        assert [e.outcome for e in a] == [e.outcome for e in b]
        assert [e.steps for e in a] == [e.steps for e in b]
        np.testing.assert_allclose([e.path_length for e in a], [e.path_length for e in b], rtol=1e-9)


def test_ros_map_in_metres_loads_with_its_origin_and_step(tmp_path):
    occupied = np.zeros((40, 60), bool)          # 3 m x 2 m at 5 cm
    occupied[:, 28:32] = True                     # a wall across the middle...
    occupied[30:, 28:32] = False                  # ...with a gap at the top
    write_pgm(tmp_path / "m.pgm", occupied)
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [-1.0, -0.5, 0]\n")
    (tmp_path / "w.yaml").write_text(
        "grid: {map: m.yaml}\nrobot: {radius: 0.1, step: 0.1}\nfield: thesis-general\n"
        "targets: [[1.5, 0.0]]\nstarts: [[-0.5, 0.0]]\ngoal_tolerance: 0.1\n")
    world = load_world(tmp_path / "w.yaml")
    assert world.size == pytest.approx((30.0, 20.0))            # in steps of 0.1 m
    np.testing.assert_allclose(world.targets, [[25.0, 5.0]])
    grid = world.obstacles[-1]
    assert isinstance(grid, GridObstacle) and grid.cell == pytest.approx(0.5)
    # the wall's face is at x = 1.4 m -> 14 steps from the map's left edge at -1 m... (cells 28..31 -> 14..16 steps)
    assert world.static_clearance(np.array([[12.0, 5.0]]))[0] == pytest.approx(2.0)
    episodes = evaluate(make_planner("astar"), [world]).episodes
    assert episodes[0].outcome == "reached"
    # the world file round-trips, in metres
    again = world_from_dict(world_to_file(world), str(tmp_path / "w.yaml"))
    np.testing.assert_allclose(again.targets, world.targets)
    assert again.frame == world.frame


def test_a_start_inside_a_grid_wall_is_reported_in_file_coordinates(tmp_path):
    occupied = np.zeros((20, 20), bool)
    occupied[5:15, 5:15] = True
    write_pgm(tmp_path / "m.pgm", occupied)
    (tmp_path / "w.yaml").write_text(
        "grid: {image: m.pgm, resolution: 0.1, origin: [10, 20, 0]}\nrobot: {radius: 0.05, step: 0.1}\n"
        "field: thesis-general\ntargets: [[10.15, 20.15]]\nstarts: [[11.0, 21.0], [13, 20.5]]\n")
    with pytest.raises(WorldError) as info:
        load_world(tmp_path / "w.yaml")
    lines = str(info.value).splitlines()
    assert any("starts[0]: [11.0, 21.0] is inside the grid map's occupied cells" in line for line in lines)
    assert any("starts[1]: [13.0, 20.5] is outside the map [10, 12] x [20, 22]" in line for line in lines)


def test_movingai_map_as_a_world_and_its_physics(tmp_path):
    (tmp_path / "maze.map").write_text(MAZE)
    (tmp_path / "w.yaml").write_text(
        "grid: {movingai: maze.map}\nfield: thesis-general\ntargets: [[7.5, 5.5]]\nstarts: [[1.5, 5.5]]\n")
    world = load_world(tmp_path / "w.yaml")
    assert world.size == (9.0, 7.0)
    # one-cell corridors: a robot of radius 0.25 fits; the wall between (1.5, 5.5) and (3.5, 5.5) is cell (2, 5)
    assert world.static_clearance(np.array([[1.5, 5.5]]))[0] == pytest.approx(0.5)
    physics = Physics([world])
    physics.place([0], np.array([[1.5, 4.5]]))
    for _ in range(5):                          # pushed right, into the wall cell at x in [2, 3]
        physics.step(np.array([[1.0, 0.0]]))
    assert physics.positions[0, 0] <= 2.0 - world.robot_radius + 0.01
    episodes = evaluate(make_planner("astar"), [world]).episodes
    assert episodes[0].outcome == "reached"


def test_a_map_file_alone_is_not_a_world(tmp_path):
    (tmp_path / "maze.map").write_text(MAZE)
    with pytest.raises(WorldError, match="--scen"):
        load_world(tmp_path / "maze.map")


SCEN = """version 1
0\tmaze.map\t9\t7\t1\t1\t3\t1\t2.00000000
1\tmaze.map\t9\t7\t1\t1\t7\t1\t10.00000000
1\tmaze.map\t9\t7\t1\t5\t7\t5\t6.00000000
"""


def test_eval_runs_movingai_scenarios_per_bucket(tmp_path, capsys):
    from apf_physics.cli import main
    import json
    (tmp_path / "maze.map").write_text(MAZE)
    (tmp_path / "maze.map.scen").write_text(SCEN)
    out = tmp_path / "r.json"
    assert main(["eval", str(tmp_path / "maze.map"), "--scen", str(tmp_path / "maze.map.scen"),
                 "--planner", "astar,gradient", "--json", str(out)]) == 0
    table = capsys.readouterr().out
    assert "3 scenarios" in table and "path/optimal" in table
    data = json.loads(out.read_text())
    astar = data[0]
    assert astar["planner"] == "astar" and [e["bucket"] for e in astar["episodes"]] == [0, 1, 1]
    assert all(e["success"] for e in astar["episodes"])
    # in corridors one cell wide no path is shorter than the octile one
    assert astar["episodes"][0]["path_over_optimal"] >= 0.99
    assert [b["bucket"] for b in astar["buckets"]] == [0, 1, "all"]
    # only bucket 1, and at most one scenario
    assert main(["eval", str(tmp_path / "maze.map"), "--scen", str(tmp_path / "maze.map.scen"),
                 "--planner", "astar", "--buckets", "1-1", "--limit", "1"]) == 0
    assert "1 scenarios" in capsys.readouterr().out


def test_scenarios_for_another_map_are_refused(tmp_path):
    from apf_physics.experiments.movingai import scenario_trials
    (tmp_path / "maze.map").write_text(MAZE)
    (tmp_path / "x.scen").write_text("version 1\n0\tmaze.map\t10\t7\t1\t1\t3\t1\t4\n")
    with pytest.raises(WorldError, match="x.scen"):
        scenario_trials(tmp_path / "maze.map", tmp_path / "x.scen")


def test_a_building_floor_at_5cm_loads_within_the_default_budget(tmp_path, monkeypatch):
    """A SLAM map of one floor: 2000 x 2000 pixels at 5 cm, a robot of 0.2 m moving 0.25 m a step."""
    from apf_physics.world.io.worldfile import MEMORY_BUDGET_VARIABLE, memory_budget, raster_memory
    monkeypatch.delenv(MEMORY_BUDGET_VARIABLE, raising=False)
    occupied = np.zeros((2000, 2000), bool)
    occupied[:, :4] = occupied[:, -4:] = occupied[:4] = occupied[-4:] = True
    occupied[1000:1004, :1800] = True                      # a corridor wall, with a door at the end
    write_pgm(tmp_path / "floor.pgm", occupied)
    (tmp_path / "floor.yaml").write_text("image: floor.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    (tmp_path / "w.yaml").write_text("grid: {map: floor.yaml}\nrobot: {radius: 0.2, step: 0.25}\n"
                                     "field: thesis-general\ntargets: [[10, 90]]\nstarts: [[10, 10]]\n")
    world = load_world(tmp_path / "w.yaml")
    assert world.size == pytest.approx((400.0, 400.0))
    assert raster_memory(world.size, 1) <= memory_budget()
    assert world.static_clearance(np.array([[40.0, 40.0]]))[0] > 1.0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), density=st.floats(0.05, 0.45), cell=st.sampled_from([1.0, 0.5, 0.25]),
       heading=st.floats(0, 2 * np.pi), radius=st.floats(0.05, 0.45))
def test_no_tunnelling_through_grid_cells_at_full_speed(tmp_path_factory, seed, density, cell, heading, radius):
    """Robots driven at full speed into a random occupancy grid never put their centre in an occupied cell,
    with the grid's boxes built piece by piece as they come (the same property as for polygons)."""
    rng = np.random.default_rng(seed)
    occupied = rng.random((16, 16)) < density
    folder = tmp_path_factory.mktemp("grid")
    write_pgm(folder / "m.pgm", occupied)
    (folder / "w.yaml").write_text(f"grid: {{image: m.pgm, resolution: {cell}, origin: [0, 0, 0]}}\n"
                                   f"robot: {{radius: {radius * cell}, step: {cell}}}\n"
                                   f"field: thesis-general\ntargets: [[{0.01 * cell}, {0.01 * cell}]]\n")
    try:
        world = load_world(folder / "w.yaml")
    except WorldError:
        world = None   # the target fell in a wall: not a world
    assume(world is not None and len(world.free_cells()) > 0)
    starts = world.random_free_positions(rng, 8)
    physics = Physics([world] * 8)
    physics.place(np.arange(8), starts)
    velocity = np.column_stack([np.cos(heading + np.arange(8)), np.sin(heading + np.arange(8))]) * physics.max_speed
    grid = world.obstacles[-1]
    for _ in range(25):
        physics.step(velocity)
        p = physics.positions
        assert np.all(grid.signed_distance(p)[0] > 0), "robot centre inside an occupied cell"
        assert np.all(world.edge_distance(p) > 0), "robot centre outside the map"
