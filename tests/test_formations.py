"""Several formations at once: world files, the crowd's right of way, rollouts, figures, PettingZoo."""

from __future__ import annotations

import numpy as np
import pytest

from apf_physics import WorldError, load_world, world_from_dict
from apf_physics.experiments.evaluate import evaluate
from apf_physics.control.formation import Formations, right_of_way
from apf_physics.world.generate import generate_world
from apf_physics.planners import make_planner
from apf_physics.experiments.rollout import rollout_formations

THREE = [{"start": [3, 3], "target": [45, 45], "followers": 2, "shape": "line", "spacing": 1.0, "comm_range": 3.0},
         {"start": [45, 3], "target": [3, 45], "followers": 2, "shape": "wedge"},
         {"start": [45, 45], "target": [5, 5], "followers": 3, "shape": "offsets", "offsets": [[1, 0], [1, 1], [2, 0]]}]


def three_formations(**extra):
    return world_from_dict({"size": [50, 50], "field": "thesis-general", "formations": THREE, **extra})


def test_world_file_formations():
    world = three_formations()
    assert [t.spec.followers for t in world.formations] == [2, 2, 3]
    np.testing.assert_array_equal(world.targets, [[45, 45], [3, 45], [5, 5]])
    assert world.formation_world(2).targets.tolist() == [[5, 5]]


@pytest.mark.parametrize("change, problem", [
    ({"formation": {"followers": 2}}, "'formation' and 'formations' together"),
    ({"formations": [{"start": [3, 3], "target": [3, 3.5]}]}, r"formations\[0\].start: already within goal_tolerance"),
    ({"formations": [{"start": [3, 3], "target": [30, 30]}, {"start": [3.2, 3], "target": [20, 30]}]},
     r"formations\[1\].start: overlaps the leader of formations\[0\]"),
    ({"formations": [{"start": [3, 3], "target": [30, 30], "sape": "line"}]}, "did you mean"),
])
def test_formations_problems_are_one_line_each(change, problem):
    with pytest.raises(WorldError, match=problem):
        world_from_dict({"size": [50, 50], "field": "thesis-general", "formations": THREE, **change})


def test_right_of_way_never_lets_robots_touch():
    # eight robots on a ring all told to run through its centre: none may touch another
    world = world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19, 19]]})
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    positions = 10 + 1.2 * np.column_stack([np.cos(angles), np.sin(angles)])
    moved = 0.0
    for _ in range(6):
        proposed = -np.column_stack([np.cos(angles), np.sin(angles)])
        moves = right_of_way(world, positions, proposed, np.arange(8))
        t = np.linspace(0, 1, 21)
        path = positions[None] + t[:, None, None] * moves[None]
        gaps = np.hypot(*(path[:, :, None] - path[:, None]).transpose(3, 0, 1, 2)) + 9 * np.eye(8)
        assert gaps.min() >= 2 * world.robot_radius
        positions = positions + moves
        moved += np.abs(moves).sum()
    assert moved > 0   # robots did move, in turn


def test_crowd_rollout_all_arrive_without_touching():
    world = load_world("four_formations")
    episodes = rollout_formations(world, make_planner("astar"))
    assert [e.success for e in episodes] == [True] * 4
    assert all(e.formation.robot_robot_collisions == 0 and e.formation.crowd == world.name for e in episodes)
    summary = evaluate(make_planner("astar"), [world], formation=True).summary()
    assert summary["worlds_all_arrived"] == 1 and summary["between_collisions"] == 0
    assert summary["links_in_range"] >= 0.98
    data = episodes[2].to_dict()
    assert len(data["trajectory"][0]) == 4 and data["formation"] == 2


def test_crossing_family_and_a_crowd_of_learned_leaders():
    rng = np.random.default_rng(11)
    for _ in range(3):
        world = generate_world("crossing", rng)
        assert 2 <= len(world.formations) <= 4
        episodes = rollout_formations(world, make_planner("dqn"))
        assert sum(e.formation.robot_robot_collisions for e in episodes) == 0
        assert sum(e.success for e in episodes) >= len(episodes) - 1


def test_formation_leaders_default_to_the_window_network_on_table_4s_field():
    from apf_physics.models import SHIPPED, SHIPPED_FORMATION, shipped_model_for

    world = load_world("four_formations")
    assert world.field.equals_preset("thesis-general")
    assert shipped_model_for(world) == SHIPPED["thesis-general"]            # a robot alone: the map network
    leader_world = world.formation_world(0)
    assert shipped_model_for(leader_world) == SHIPPED_FORMATION["thesis-general"] != SHIPPED["thesis-general"]
    planner = make_planner("dqn")
    planner.reset(leader_world, leader_world.starts[:1])
    assert planner.observer is not None    # the window network's observer (a map network has none)


def test_followers_are_placed_clear_of_other_formations():
    world = three_formations()
    crowd = Formations(world)
    robots = np.concatenate([p[:size] for p, size in zip(crowd.starts(), crowd.sizes)])
    gaps = np.hypot(*(robots[:, None] - robots[None]).transpose(2, 0, 1)) + 9 * np.eye(len(robots))
    assert gaps.min() >= 2 * world.robot_radius and np.all(world.clearance(robots) >= world.robot_radius)


# -- PettingZoo ----------------------------------------------------------------------------------

@pytest.mark.parametrize("agents", ["leaders", "all"])
def test_parallel_env_passes_pettingzoo_api_test(agents):
    pytest.importorskip("pettingzoo", reason="the [pettingzoo] extra is not installed")
    from pettingzoo.test import parallel_api_test

    from apf_physics.envs.parallel import FormationsParallelEnv

    parallel_api_test(FormationsParallelEnv("four_formations", agents=agents), num_cycles=50)


def test_parallel_env_is_deterministic_and_leaders_never_touch():
    pytest.importorskip("pettingzoo", reason="the [pettingzoo] extra is not installed")
    from apf_physics.envs.parallel import FormationsParallelEnv

    runs = []
    for _ in range(2):
        env = FormationsParallelEnv("four_formations", render_mode="rgb_array")
        observations, _ = env.reset(seed=3)
        rng = np.random.default_rng(3)
        trace = []
        for _ in range(40):
            if not env.agents:
                break
            actions = {a: int(rng.integers(9)) for a in env.agents}
            observations, rewards, terminations, truncations, infos = env.step(actions)
            assert not any(info["robot_robot_contact"] for info in infos.values())
            trace.append((sorted(rewards.items()), [o.tobytes() for o in observations.values()]))
        frame = env.render()
        runs.append(trace)
    assert runs[0] == runs[1]
    assert frame.shape == (512, 512, 3)


def test_spatial_hash_finds_exactly_the_near_points():
    from apf_physics.common.geometry import near_any

    rng = np.random.default_rng(0)
    for _ in range(100):
        points = rng.uniform(-5, 50, (int(rng.integers(0, 60)), 2))
        centres = rng.uniform(-5, 50, (int(rng.integers(1, 8)), 2))
        reach = rng.uniform(0.5, 15)
        exact = np.hypot(points[:, None, 0] - centres[None, :, 0], points[:, None, 1] - centres[None, :, 1])
        np.testing.assert_array_equal(near_any(points, centres, reach), (exact <= reach).any(axis=1))


def test_the_parallel_env_is_importable_where_the_readme_says():
    import apf_physics.envs as envs
    from apf_physics.envs.parallel import FormationsParallelEnv
    assert envs.FormationsParallelEnv is FormationsParallelEnv and "FormationsParallelEnv" in envs.__all__
