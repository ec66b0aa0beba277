"""Planners drive unicycle robots: every planner's moves through :func:`tracking.track_safely`,
formations of unicycles, and ``eval`` / ``render --kinematics``.

- ``gradient``, ``escape``, ``astar`` and ``dqn`` (the map network, the default model of the
  general field) bring unicycles to the target of a small world without a collision; the
  episodes carry the headings, and every step a robot either turns on the spot or drives forward.
- :func:`track_safely` never drives an arc that comes nearer an obstacle than the straight move
  it tracks: next to a wall it turns on the spot first, then drives the straight move.
- A formation of unicycles arrives with every link in range and no two robots touching; several
  formations of unicycles in one world cross without touching.
- ``Formation-v0`` runs unicycle formations (the leader the agent's, the followers by the rule).
- ``--kinematics unicycle`` reaches ``eval`` (JSON with headings) and ``render`` (a video);
  ``--kinematics holonomic`` overrides a unicycle world file; a bad value is a clear error.
"""

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from apf_physics import world_from_dict
from apf_physics.cli import main
from apf_physics.world.kinematics import UnicycleLimits, arc_points
from apf_physics.planners import make_planner
from apf_physics.experiments.rollout import robot_limits, rollout, rollout_formations
from apf_physics.control.tracking import track_safely
from conftest import simple_world_dict

GENERAL_FIELD = {"katt": 1, "krep": 20, "kstr": 8, "p0": 3, "ps": 8, "u_max": 100}


def small_world(**overrides):
    """16 x 16, the general field (the map network's), one box between the starts and the target."""
    data = simple_world_dict(name="small", size=[16, 16], goal_tolerance=0.75, field=GENERAL_FIELD,
                             obstacles=[{"polygon": [[6, 7], [8, 7], [8, 9], [6, 9]]}],
                             targets=[[13, 13]], starts=[[2, 2], [2.5, 12], [12, 2.5]])
    data.update(overrides)
    return world_from_dict(data)


@pytest.mark.parametrize("name", ["gradient", "escape", "astar", "dqn"])
def test_every_planner_drives_unicycles_to_the_target(name):
    world = small_world()
    episodes = rollout(world, make_planner(name), world.starts, unicycle=True)
    assert [e.outcome for e in episodes] == ["reached"] * len(world.starts)
    for e in episodes:
        assert e.headings is not None and e.headings.shape == (e.steps + 1,)
        moves = np.diff(e.path, axis=0)
        length = np.hypot(*moves.T)
        assert length.max() <= UnicycleLimits().max_speed + 1e-9
        # forward only: each step's chord leaves within 90° of the heading the step started with
        ahead = np.cos(e.headings[:-1]) * moves[:, 0] + np.sin(e.headings[:-1]) * moves[:, 1]
        assert np.all(ahead[length > 1e-9] > 0)
        assert "final_heading" in e.to_dict()


def test_holonomic_episodes_carry_no_headings():
    world = small_world()
    episodes = rollout(world, make_planner("astar"), world.starts)
    assert all(e.headings is None and "final_heading" not in e.to_dict() for e in episodes)
    assert robot_limits(world) is None and robot_limits(world, True) == UnicycleLimits()


def test_an_arc_is_driven_only_when_as_clear_as_the_straight_move():
    # a wall 0.4 below the robot (its radius 0.25 + SAFETY 0.05 = 0.3 is the planners' bar); the move
    # goes straight right while the robot faces down-right: the arc through the move's end would dip
    # 0.15 toward the wall, below the bar, while the straight move keeps 0.4
    world = world_from_dict(simple_world_dict(obstacles=[{"polygon": [[0, 0], [20, 0], [20, 4.6], [0, 4.6]]}],
                                              starts=[[2, 5]]))
    moment = world.at(0)
    move = np.array([[1.0, 0.0]])
    state = np.array([[2.0, 5.0, -0.6, 0.0, 0.0]])
    v, omega = track_safely(state, move, moment)
    assert v[0] == 0.0 and omega[0] == pytest.approx(0.6)           # turns on the spot to face the move
    state[0, 2] += omega[0]
    v, omega = track_safely(state, move, moment)
    assert v[0] == pytest.approx(1.0) and abs(omega[0]) < 1e-9     # then drives it straight
    # in the open, the same bearing is driven as an arc at once, as clear as the bar
    open_state = np.array([[2.0, 12.0, -0.6, 0.0, 0.0]])
    v, omega = track_safely(open_state, move, world.at(0))
    assert v[0] > 0 and omega[0] != 0
    assert world.clearance(arc_points(open_state, v, omega, 16)[0]).min() >= world.robot_radius + 0.05


def test_a_formation_of_unicycles_arrives_with_its_links_in_range():
    world = small_world(starts=[[3, 3], [3, 11]])
    episodes = rollout(world, make_planner("astar"), world.starts, formation=True, unicycle=True)
    for e in episodes:
        f = e.formation
        assert e.outcome == "reached" and e.success
        assert all(f.final_links_in_range())
        assert f.robot_robot_collisions == 0 and f.robot_obstacle_collisions == 0
        assert f.headings.shape == f.positions.shape[:2]
        assert f.min_robot_distance >= 2 * world.robot_radius


def write_world(tmp_path, **robot):
    world = {"name": "small", "size": [16, 16], "goal_tolerance": 0.75, "field": GENERAL_FIELD,
             "obstacles": [{"polygon": [[6, 7], [8, 7], [8, 9], [6, 9]]}], "targets": [[13, 13]],
             "starts": [[2, 2], [12, 2.5]], "robot": {"radius": 0.25, **robot}}
    path = tmp_path / "small.yaml"
    path.write_text(json.dumps(world))   # JSON is YAML
    return path


def test_eval_runs_unicycles_with_the_kinematics_option(tmp_path, capsys):
    path = write_world(tmp_path)
    out = tmp_path / "eval.json"
    assert main(["eval", str(path), "--planner", "astar", "--kinematics", "unicycle", "--json", str(out),
                 "--no-progress"]) == 0
    episodes = json.loads(out.read_text())[0]["episodes"]
    assert all(e["success"] and "final_heading" in e for e in episodes)
    # a unicycle world file, forced holonomic
    path = write_world(tmp_path, kinematics="unicycle")
    assert main(["eval", str(path), "--planner", "astar", "--kinematics", "holonomic", "--json", str(out),
                 "--no-progress"]) == 0
    assert all("final_heading" not in e for e in json.loads(out.read_text())[0]["episodes"])
    assert main(["eval", str(path), "--planner", "astar", "--json", str(out), "--no-progress"]) == 0
    assert all("final_heading" in e for e in json.loads(out.read_text())[0]["episodes"])


def test_render_draws_unicycles(tmp_path, capsys):
    path = write_world(tmp_path)
    video, png = tmp_path / "run.avi", tmp_path / "run.png"
    assert main(["render", str(path), "--planner", "astar", "--kinematics", "unicycle", "--all-starts",
                 "--out", str(video), "--png", str(png), "--size", "96", "--no-progress"]) == 0
    assert video.stat().st_size > 0 and png.stat().st_size > 0
    assert "reached 2" in capsys.readouterr().out


@pytest.mark.parametrize("command", ["eval", "render"])
def test_a_bad_kinematics_value_is_named(tmp_path, capsys, command):
    path = write_world(tmp_path)
    extra = ["--out", str(tmp_path / "x.avi")] if command == "render" else []
    assert main([command, str(path), "--kinematics", "wheels", *extra]) == 2
    err = capsys.readouterr().err
    assert "--kinematics" in err and "'wheels'" in err and "holonomic, unicycle" in err


@pytest.mark.parametrize("action", ["discrete", "continuous"])
def test_a_formation_of_unicycles_in_the_environment(action):
    """``Formation-v0`` with unicycles passes Gymnasium's checker, and driven at random its robots
    never touch one another (the followers' unicycle rule checks the leader's arc too)."""
    env = gym.make("apf_physics/Formation-v0", world="fixed20", action=action, kinematics="unicycle")
    check_env(env.unwrapped)
    env.reset(seed=3)
    env.action_space.seed(3)
    for _ in range(40):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        positions = env.unwrapped.positions
        gaps = np.hypot(*(positions[:, None] - positions[None]).transpose(2, 0, 1))
        assert gaps[~np.eye(len(positions), dtype=bool)].min() >= 2 * env.unwrapped.world.robot_radius - 1e-9
        if terminated or truncated:
            env.reset()


def test_several_formations_of_unicycles_cross_without_touching():
    """``rollout_formations`` with unicycles: two formations crossing each other's way arrive, no
    two robots ever touch (they give way on their arcs), and the episodes carry the headings;
    ``escape`` among other formations (whose discs near it come and go) runs too."""
    world = world_from_dict({"name": "cross", "size": [16, 16], "field": "thesis-general",
                             "obstacles": [{"circle": {"center": [8, 8], "radius": 1}}],
                             "formations": [{"start": [2, 2], "target": [13, 13], "followers": 1, "shape": "line"},
                                            {"start": [13, 2], "target": [2, 13], "followers": 1, "shape": "line"}]})
    for name in ("astar", "escape"):
        episodes = rollout_formations(world, make_planner(name), unicycle=True)
        for e in episodes:
            assert e.success and e.formation.robot_robot_collisions == 0
            assert e.formation.headings.shape == e.formation.positions.shape[:2]
        together = np.concatenate([e.formation.positions[-1] for e in episodes])
        assert np.hypot(*(together[:, None] - together[None]).transpose(2, 0, 1))[~np.eye(4, dtype=bool)].min() \
            >= 2 * world.robot_radius


def test_render_draws_several_formations_of_unicycles(tmp_path, capsys):
    world = {"name": "cross", "size": [16, 16], "field": "thesis-general",
             "obstacles": [{"circle": {"center": [8, 8], "radius": 1}}],
             "formations": [{"start": [2, 2], "target": [13, 13], "followers": 1, "shape": "line"},
                            {"start": [13, 2], "target": [2, 13], "followers": 1, "shape": "line"}]}
    path = tmp_path / "cross.yaml"
    path.write_text(json.dumps(world))
    video = tmp_path / "cross.avi"
    assert main(["render", str(path), "--formation", "--planner", "astar", "--kinematics", "unicycle",
                 "--out", str(video), "--size", "96", "--hold", "0", "--no-progress"]) == 0
    assert video.stat().st_size > 0 and "reached 2" in capsys.readouterr().out
