"""A world in metres speaks metres back: every position and length a user reads or gives is in the
world file's units and coordinates (eval's table and JSON, captions, the environments' ``info`` and
``reset(options=...)``, messages, the ``worlds`` listing); steps stay inside."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import apf_physics  # noqa: F401 (registers the environments)
from apf_physics.cli import main
from apf_physics.errors import UserError, WorldError
from apf_physics.experiments.evaluate import evaluate, format_table
from apf_physics.planners import make_planner
from apf_physics.render.episodes import collision_events, episode_clips
from apf_physics.world.io.mapfiles import write_pgm
from apf_physics.world.io.units import (length_to_file, length_to_steps, points_to_file, points_to_steps, show_length,
                                      show_point)
from apf_physics.world.io.worldfile import load_world, world_from_dict
from apf_physics.world.core import Frame
from apf_physics.world.io.units import world_to_file

START, TARGET = [6.5, -0.5], [1.0, 1.0]


def metric_world(tmp_path, **extra):
    """A ROS map of 10 m x 4 m at 5 cm whose corner is at [-1, -2] m, a block in the middle, a robot
    of 0.2 m moving 0.25 m a step (the map's origin is not the world's: it is 4 steps by 8 away)."""
    occupied = np.zeros((80, 200), bool)
    occupied[30:50, 90:110] = True                      # x 3.5..4.5 m, y -0.5..0.5 m
    write_pgm(tmp_path / "floor.pgm", occupied)
    (tmp_path / "floor.yaml").write_text("image: floor.pgm\nresolution: 0.05\norigin: [-1.0, -2.0, 0.0]\n")
    data = {"name": "floor", "grid": {"map": "floor.yaml"}, "robot": {"radius": 0.2, "step": 0.25},
            "goal_tolerance": 0.2, "field": "thesis-general", "targets": [TARGET], "starts": [START], **extra}
    path = tmp_path / "floor_world.yaml"
    path.write_text(json.dumps(data))
    return path


def test_units_convert_both_ways():
    frame = Frame((-1.0, -2.0), 0.25, "m")
    np.testing.assert_allclose(points_to_steps(frame, START), [30.0, 6.0])
    np.testing.assert_allclose(points_to_file(frame, points_to_steps(frame, [[6.5, -0.5], [1, 1]])), [START, TARGET])
    assert length_to_steps(frame, 0.2) == pytest.approx(0.8) and length_to_file(frame, 0.8) == pytest.approx(0.2)
    assert show_length(frame, 0.8) == "0.2 m" and show_length(Frame(), 2.5) == "2.5"


def test_eval_reports_the_files_units(tmp_path, capsys):
    path = metric_world(tmp_path)
    out = tmp_path / "eval.json"
    assert main(["eval", str(path), "--planner", "astar", "--json", str(out), "--no-progress"]) == 0
    table = capsys.readouterr().out
    (evaluation,) = json.loads(out.read_text())
    episode, summary = evaluation["episodes"][0], evaluation["summary"]
    assert episode["start"] == START and episode["units"] == summary["units"] == "m"
    assert episode["success"] and np.hypot(*np.subtract(episode["final_position"], TARGET)) <= 0.2
    # the path of 6 m or so, in metres (in steps it would be four times that)
    assert 5.5 <= episode["path_length"] <= 7.5 and summary["mean_path_length"] == pytest.approx(episode["path_length"],
                                                                                                  abs=1e-3)
    assert f"{summary['mean_path_length']:.2f} m" in table


def test_mixed_units_have_no_mean_length(tmp_path):
    metric, plain = load_world(metric_world(tmp_path)), load_world("fixed20")
    ev = evaluate(make_planner("astar"), [metric, plain.with_task(plain.targets, plain.starts[:1])])
    summary = ev.summary()
    assert summary["units"] == "mixed" and summary["mean_path_length"] is None
    assert ev.summary([e for e in ev.episodes if e.world == "floor"])["units"] == "m"
    assert "(all)" in format_table([ev])


def test_captions_give_positions_in_the_files_coordinates(tmp_path):
    world = load_world(metric_world(tmp_path))
    (episode,) = evaluate(make_planner("astar"), [world]).episodes
    (_, _, lines, _, _), = episode_clips([episode], ("world floor",), False, 0, world.frame)
    assert lines[-1] == "start 0 (6.5, -0.5)"
    episode.outcome, episode.contacts = "collision", ["obstacle"]
    x, y = (round(float(v), 2) for v in points_to_file(world.frame, episode.path[-1]))
    assert collision_events([episode], world.frame)[0][1].endswith(f"hit obstacle at ({x:g}, {y:g})")
    assert abs(x - TARGET[0]) < 0.3 and abs(y - TARGET[1]) < 0.3       # metres, near the target (not steps)


def test_the_environments_take_and_give_the_files_units(tmp_path):
    path = metric_world(tmp_path)
    env = gym.make("apf_physics/Navigate-v0", world=str(path))
    _, info = env.reset(seed=0, options={"start": START})
    np.testing.assert_allclose(info["position"], START)
    assert info["units"] == "m" and info["distance"] == pytest.approx(np.hypot(5.5, 1.5))
    np.testing.assert_allclose(env.unwrapped.position, [30.0, 6.0])      # the world's steps, inside
    _, _, _, _, info = env.step(2)                                       # left: one step, 0.25 m
    np.testing.assert_allclose(info["position"], [6.25, -0.5], atol=1e-6)
    with pytest.raises(UserError, match=r"options\['start'\] = \[4.0, 0.0\]: a robot of radius 0.2 m does not fit"):
        env.reset(options={"start": [4.0, 0.0]})                         # inside the block
    vec = gym.make_vec("apf_physics/Navigate-v0", num_envs=2, vectorization_mode="vector_entry_point",
                       world=str(path), starts=np.array([START, [0.0, 1.5]]))
    _, info = vec.reset(seed=0)
    assert all(any(np.allclose(p, s) for s in (START, [0.0, 1.5])) for p in info["position"])
    assert list(info["units"]) == ["m", "m"]


def test_messages_name_the_files_lengths(tmp_path):
    with pytest.raises(WorldError) as err:
        load_world(metric_world(tmp_path, robot={"radius": 0.001, "step": 0.25}))
    assert "robot.radius: must be at least 0.0025 m, 0.01 of a step of 0.25 m" in str(err.value)
    assert "got 0.001 m" in str(err.value)
    with pytest.raises(WorldError, match=r"starts\[0\]: \[4.0, 0.0\] is inside the grid map's occupied cells"):
        load_world(metric_world(tmp_path, starts=[[4.0, 0.0]]))
    with pytest.raises(WorldError, match=r"starts\[0\]: \[3.35, 0.0\] is closer than the robot radius 0.2 m"):
        load_world(metric_world(tmp_path, starts=[[3.35, 0.0]]))


def test_units_may_be_named_and_are_kept(tmp_path):
    world = world_from_dict({"units": "ft", "size": [40, 20], "robot": {"radius": 0.5, "step": 2}, "field": "thesis-general",
                             "targets": [[30, 10]], "starts": [[4, 4]]})
    assert world.frame.name == "ft" and world_to_file(world)["units"] == "ft"
    with pytest.raises(WorldError, match="units: expected the name of a unit"):
        world_from_dict({"units": 3, "size": [40, 20], "field": "thesis-general", "targets": [[30, 10]]})


def test_the_worlds_listing_gives_sizes_in_the_files_units(capsys):
    assert main(["worlds"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("ros_arena"))
    assert "5.4x5.4 m" in row


def file_in_steps_of(step):
    """A world file whose lengths are given in a unit of which the robot moves ``step`` a step: the
    same world in steps whatever ``step`` is (everything below is that world's value times ``step``)."""
    def s(*values):
        return [v * step for v in values]
    limits = {"max_speed": 1.0 * step, "max_reverse": 0.5 * step, "max_turn_rate": 0.5, "max_accel": 0.25 * step,
              "max_turn_accel": 0.25}
    return {"name": "scaled", "units": "m", "size": s(40, 20),
            "robot": {"radius": 0.5 * step, "step": step, "kinematics": "unicycle", **limits},
            "goal_tolerance": 1.0 * step, "field": "thesis-general",
            "obstacles": [{"circle": {"center": s(12, 4), "radius": 1.0 * step}, "name": "pillar",
                           "motion": {"path": [s(0, 8)], "speed": 0.5 * step, "phase": 2.0 * step}},
                          {"polygon": [s(20, 12), s(24, 12), s(24, 16)], "name": "cart",
                           "motion": {"path": [s(4, -4)], "speed": 0.25 * step, "loop": True}}],
            "targets": [s(36, 16)], "starts": [s(4, 4)],
            "formation": {"followers": 2, "comm_range": 4.0 * step, "spacing": 2.0 * step, "shape": "offsets",
                          "offsets": [s(-2, 1), s(-4, -1)]}}


@pytest.mark.parametrize("step", [0.5, 2.0])
def test_a_world_file_in_other_units_is_read_in_steps_and_written_back_as_given(step):
    data = file_in_steps_of(step)
    world = world_from_dict(data)
    # in steps: the same world whatever the file's unit
    assert world.size == (40.0, 20.0) and world.robot_radius == 0.5 and world.goal_tolerance == 1.0
    assert (world.unicycle.max_speed, world.unicycle.max_reverse, world.unicycle.max_accel) == (1.0, 0.5, 0.25)
    assert (world.unicycle.max_turn_rate, world.unicycle.max_turn_accel) == (0.5, 0.25)    # rates: no length in them
    circle, polygon = world.obstacles
    np.testing.assert_allclose(circle.center, [12, 4])
    assert circle.radius == 1.0 and circle.name == "pillar"
    np.testing.assert_allclose(circle.motion.path, [[0, 8]])
    assert (circle.motion.speed, circle.motion.phase) == (0.5, 2.0)
    np.testing.assert_allclose(polygon.vertices, [[20, 12], [24, 12], [24, 16]])
    assert polygon.name == "cart" and polygon.motion.loop and polygon.motion.speed == 0.25
    np.testing.assert_allclose(polygon.motion.path, [[4, -4]])
    np.testing.assert_allclose(world.targets, [[36, 16]])
    np.testing.assert_allclose(world.starts, [[4, 4]])
    assert (world.formation.comm_range, world.formation.spacing) == (4.0, 2.0)
    assert world.formation.offsets == ((-2.0, 1.0), (-4.0, -1.0))
    # written back: the file's own values, the field's parameters in its units too
    written = world_to_file(world)
    assert {k: v for k, v in written.items() if k != "field"} == {k: v for k, v in data.items() if k != "field"}
    again = world_from_dict(written)
    assert again.field == world.field and world_to_file(again) == written


@pytest.mark.parametrize("step", [0.5, 2.0])
def test_several_formations_are_read_in_steps_and_written_back_as_given(step):
    data = {k: v for k, v in file_in_steps_of(step).items() if k not in ("formation", "starts")}
    data["formations"] = [{"followers": 1, "comm_range": 4.0 * step, "spacing": 2.0 * step, "shape": "line",
                           "start": [4.0 * step, 4.0 * step], "target": [36.0 * step, 16.0 * step]}]
    world = world_from_dict(data)
    (task,) = world.formations
    np.testing.assert_allclose([task.start, task.target], [[4, 4], [36, 16]])
    assert (task.spec.comm_range, task.spec.spacing) == (4.0, 2.0)
    assert world_to_file(world)["formations"] == data["formations"]


def test_a_grid_maps_origin_moves_the_obstacles_drawn_on_it(tmp_path):
    """A ROS map whose corner is at [-1, -2] m: a circle and a polygon given in the map's coordinates
    are that far from the world's corner, in steps of 0.25 m; and a map in steps of 1 m too."""
    extra = {"obstacles": [{"circle": {"center": [1.0, -1.0], "radius": 0.25}},
                           {"polygon": [[7.0, 1.0], [8.0, 1.0], [8.0, 1.5]]}]}
    world = load_world(metric_world(tmp_path, **extra))
    circle, polygon = world.obstacles[:2]
    np.testing.assert_allclose(circle.center, [8.0, 4.0])
    assert circle.radius == 1.0
    np.testing.assert_allclose(polygon.vertices, [[32, 12], [36, 12], [36, 14]])
    written = world_to_file(world)
    assert written["grid"] == {"map": str(tmp_path / "floor.yaml")}
    assert written["obstacles"] == [{"circle": {"center": [1.0, -1.0], "radius": 0.25}},
                                    {"polygon": [[7.0, 1.0], [8.0, 1.0], [8.0, 1.5]]}]
    assert "size" not in written            # the map gives the size
    metres = load_world(metric_world(tmp_path, robot={"radius": 0.2, "step": 1.0}, goal_tolerance=1.0, **extra))
    np.testing.assert_allclose(metres.obstacles[0].center, [2.0, 1.0])
    np.testing.assert_allclose(metres.obstacles[1].vertices, [[8, 3], [9, 3], [9, 3.5]])


def test_lengths_convert_one_or_many():
    frame = Frame((-1.0, -2.0), 0.25, "m")
    one = length_to_steps(frame, 0.2)
    assert isinstance(one, float) and json.dumps(one) and one == pytest.approx(0.8)
    np.testing.assert_allclose(length_to_steps(frame, [0.2, 0.5]), [0.8, 2.0])
    np.testing.assert_allclose(length_to_file(frame, [0.8, 2.0]), [0.2, 0.5])
    assert isinstance(length_to_file(frame, 0.8), float)
    assert show_point(frame, [29.0, 7.0]) == "[6.25, -0.25]"
    assert show_point(Frame(), [1 / 3, 2 / 3]) == "[0.3333, 0.6667]"       # four digits unless told
    assert show_length(Frame(), 1 / 3) == "0.3333" and show_length(frame, 4 / 3, 2) == "0.33 m"
