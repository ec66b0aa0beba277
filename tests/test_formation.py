"""Formations: followers never collide, links stay in range, failure is reported as failure."""

import gymnasium as gym
import numpy as np
import pytest

import apf_physics  # noqa: F401
from apf_physics import UserError, load_world, world_from_dict
from apf_physics.planners import make_planner
from apf_physics.common.geometry import swept_distance
from apf_physics.control.formation import formation_offsets, initial_followers
from apf_physics.experiments.rollout import rollout, rollout_formations
from apf_physics.planners.base import Planner
from apf_physics.world.core import FormationSpec
from conftest import simple_world_dict


# Known: gradient descent's leader from fixed20's start 3 ([14, 1]) turns back onto its followers,
# which start packed against the map's edge under the L; blocked by their own leader they fall
# behind, and a chain moves no faster than its leader, so it never catches up (links in range in
# 2 of 16 steps). It held before only by the rounding of positions deciding an exact tie of the
# safety margin (robots placed exactly the safe distance apart, moving alike), which the rule now
# decides as exact arithmetic would (formation.ROUNDING).
KNOWN_LEFT_BEHIND = {("fixed20", "gradient"): {3}}


@pytest.mark.parametrize("name, planner", [("fixed20", "astar"), ("fixed20", "gradient"), ("local_minimum", "escape"),
                                           ("three_targets", "gradient")])
def test_followers_never_collide_and_stay_in_range(worlds_dir, name, planner):
    world = load_world(worlds_dir / f"{name}.yaml")
    episodes = rollout(world, make_planner(planner), world.starts, formation=True)
    known = KNOWN_LEFT_BEHIND.get((name, planner), set())
    for i, e in enumerate(episodes):
        f = e.formation
        assert f.robot_robot_collisions == 0 and f.robot_obstacle_collisions == 0
        assert e.outcome != "collision"
        assert f.min_robot_distance >= 2 * world.robot_radius
        assert f.positions.shape == (e.steps + 1, 3, 2)
        np.testing.assert_array_equal(f.positions[:, 0], e.path)
        if i in known:   # still left behind: when this fails, the case is mended; drop it from the list
            assert min(f.link_in_range) < 0.8
        else:
            assert min(f.link_in_range) >= 0.8
    # with a leader that goes around obstacles (A*), every link stays in range all the time
    if planner == "astar":
        assert all(min(e.formation.link_in_range) == 1.0 for e in episodes)
        assert all(e.success for e in episodes)


def test_trapped_leader_is_a_failure(worlds_dir):
    world = load_world(worlds_dir / "local_minimum.yaml")
    (e,) = rollout(world, make_planner("gradient"), world.starts, formation=True)
    assert e.outcome == "trapped"
    assert not e.success
    d = e.to_dict()
    assert d["success"] is False and d["robots"][0]["success"] is False


def test_followers_start_behind_the_leader(worlds_dir):
    world = load_world(worlds_dir / "local_minimum.yaml")   # target to the right of the start
    spec = FormationSpec(followers=2, comm_range=3.0, spacing=1.0)
    followers = initial_followers(world, spec, world.starts[0])
    assert np.all(followers[:, 0] < world.starts[0][0])
    assert np.all(world.is_free(followers))
    assert np.hypot(*(followers[0] - world.starts[0])) <= 3.0
    assert np.hypot(*(followers[1] - followers[0])) <= 3.0


def test_no_room_for_followers_is_a_clear_error():
    # a map barely larger than one robot: nowhere to put a follower
    world = world_from_dict(simple_world_dict(size=[1.2, 1.2], obstacles=[], starts=[[0.6, 0.6]], targets=[[1.15, 1.15]]))
    with pytest.raises(UserError, match="no free position for follower 1"):
        initial_followers(world, FormationSpec(), world.starts[0])


def test_wedge_shape_and_example_world(worlds_dir):
    world = load_world(worlds_dir / "formation_wedge.yaml")
    assert world.formation.shape == "wedge" and world.formation.followers == 4
    offsets = formation_offsets(world.formation)
    np.testing.assert_allclose(offsets, [[1, 1], [1, -1], [2, 2], [2, -2]])
    episodes = rollout(world, make_planner("escape"), world.starts, formation=True)
    assert all(e.formation.robot_robot_collisions == 0 and e.formation.robot_obstacle_collisions == 0
               for e in episodes)
    assert all(e.formation.positions.shape[1] == 5 for e in episodes)
    assert sum(e.success for e in episodes) >= 4


def test_offsets_shape_from_world_file():
    data = simple_world_dict(formation={"followers": 2, "shape": "offsets", "offsets": [[1, 0.5], [1, -0.5]],
                                        "comm_range": 3})
    world = world_from_dict(data)
    np.testing.assert_allclose(formation_offsets(world.formation), [[1, 0.5], [1, -0.5]])
    with pytest.raises(UserError, match="formation.offsets"):
        world_from_dict(simple_world_dict(formation={"followers": 3, "shape": "offsets", "offsets": [[1, 0]]}))


def test_swept_distance():
    # two robots swapping places head-on meet in the middle
    assert swept_distance(np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([1.0, 0.0]), np.array([-1.0, 0.0])) == 0
    assert swept_distance(np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([1.0, 0.0])) == 1


def test_formation_env(worlds_dir):
    from gymnasium.utils.env_checker import check_env

    env = gym.make("apf_physics/Formation-v0", world=str(worlds_dir / "fixed20.yaml"))
    check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert obs.shape == (1, 11, 11) and info["positions"].shape == (3, 2)
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(6)
        assert set(info) >= {"positions", "links", "links_in_range", "link_in_range_share", "reward_terms"}
        if terminated:
            break
    assert not info["robot_robot_contact"]


def test_eval_formation_json(worlds_dir, tmp_path):
    import json

    from apf_physics.cli import main

    out = tmp_path / "f.json"
    assert main(["eval", str(worlds_dir / "local_minimum.yaml"), "--planner", "astar", "--formation", "--json", str(out)]) == 0
    ((episode,),) = [ev["episodes"] for ev in json.loads(out.read_text())]
    assert {"robots", "min_robot_distance", "robot_robot_collisions", "robot_obstacle_collisions",
            "link_in_range"} <= set(episode)
    assert [r["role"] for r in episode["robots"]] == ["leader", "follower1", "follower2"]


class _Standing(Planner):
    """Leaders that stay where they are (the followers then stay behind them)."""

    name = "standing"

    def act(self, positions, active, moment=None):
        return np.zeros_like(positions)


def _hit_by_a_moving_obstacle(formations: bool) -> dict:
    """A formation standing at (4, 10), its followers behind it towards -x, and a disc that comes down
    the line x = 3 (onto follower 1) from the top of the map; the formation's record."""
    moving = {"circle": {"center": [3.0, 17.0], "radius": 0.5}, "motion": {"path": [[0, -14]], "speed": 1.0}}
    spec = {"followers": 2, "comm_range": 3.0, "spacing": 1.0}
    data = simple_world_dict(obstacles=[moving], targets=[[18.0, 10.0]], starts=[[4.0, 10.0]])
    if formations:
        data.pop("starts")
        data["formations"] = [{"start": [4.0, 10.0], "target": [18.0, 10.0], **spec}]
        episodes = rollout_formations(world_from_dict(data), _Standing(), max_steps=30)
    else:
        data["formation"] = spec
        episodes = rollout(world_from_dict(data), _Standing(), [[4.0, 10.0]], max_steps=30, formation=True)
    assert episodes[0].outcome == "collision"
    return episodes[0].to_dict()


@pytest.mark.parametrize("formations", [False, True])
def test_a_moving_obstacle_hitting_a_follower_counts_as_an_obstacle_collision(formations):
    """One formation and several formations count a robot touched by a moving obstacle alike (as a
    robot-obstacle collision): the two rollouts once counted it differently."""
    record = _hit_by_a_moving_obstacle(formations)
    assert record["robot_obstacle_collisions"] >= 1 and record["robot_robot_collisions"] == 0
