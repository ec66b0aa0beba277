"""Gradient descent and the seed worlds behave as the thesis's figures say."""

import json
from pathlib import Path

import numpy as np

from apf_physics import load_world
from apf_physics.planners import GradientPlanner
from apf_physics.experiments.rollout import rollout


def run(worlds_dir, name):
    world = load_world(worlds_dir / f"{name}.yaml")
    return world, rollout(world, GradientPlanner(), world.starts)


def test_local_minimum_traps_descent(worlds_dir):
    world, (episode,) = run(worlds_dir, "local_minimum")
    assert episode.outcome == "trapped"
    # trapped in front of the rectangle, on the start's side, without touching it
    assert episode.path[-1][0] < 9.0
    assert world.obstacle_distance(episode.path[-1:])[0] > world.robot_radius


def test_three_targets_with_black_holes_reach_nearest(worlds_dir):
    world, episodes = run(worlds_dir, "three_targets")
    for e in episodes:
        assert e.outcome == "reached"
        nearest = np.argmin(np.hypot(*(world.targets - e.start).T))
        reached = np.argmin(np.hypot(*(world.targets - e.path[-1]).T))
        assert nearest == reached


def test_three_targets_without_black_holes_end_between(worlds_dir):
    world, episodes = run(worlds_dir, "three_targets_no_blackhole")
    centroid = world.targets.mean(axis=0)
    for e in episodes:
        assert e.outcome == "trapped"
        assert np.hypot(*(e.path[-1] - centroid)) < 1.0


def test_fixed20_traps_descent_from_the_starts_the_figures_say(worlds_dir):
    """Gradient descent on the thesis's fixed world: reached and trapped exactly as often as the
    README's figures say (tools/results/fixed20.json, written by ``tools/figures.py run fixed20``),
    never colliding."""
    world, episodes = run(worlds_dir, "fixed20")
    outcomes = [e.outcome for e in episodes]
    results = json.loads((Path(__file__).resolve().parent.parent / "tools/results/fixed20.json").read_text())
    (gradient,) = [e["summary"] for e in results if e["planner"] == "gradient"]
    assert len(outcomes) == gradient["episodes"] == 40
    assert outcomes.count("reached") == gradient["successes"]
    assert outcomes.count("trapped") == round(gradient["trapped_rate"] * 40) == 40 - gradient["successes"]
    assert outcomes.count("collision") == 0


def test_episode_bookkeeping(worlds_dir):
    world, episodes = run(worlds_dir, "fixed20")
    for e in episodes:
        assert len(e.path) == e.steps + 1
        np.testing.assert_allclose(e.path[0], e.start)
        d = e.to_dict()
        assert set(d) >= {"world", "start", "success", "collision", "trapped", "steps", "path_length", "final_position"}
        if e.success:
            assert np.min(np.hypot(*(world.targets - e.path[-1]).T)) <= world.goal_tolerance


def test_eval_command_writes_json(worlds_dir, tmp_path, capsys):
    import json

    from apf_physics.cli import main

    out = tmp_path / "sub" / "eval.json"
    assert main(["eval", str(worlds_dir / "fixed20.yaml"), "--planner", "gradient", "--json", str(out)]) == 0
    (data,) = json.loads(out.read_text())      # one object per planner, always in a list
    assert data["planner"] == "gradient"
    assert data["summary"]["episodes"] == 40
    assert len(data["episodes"]) == 40
    assert 0 < data["summary"]["success_rate"] < 1
    assert "fixed20" in capsys.readouterr().out


def test_eval_unwritable_json(worlds_dir, tmp_path, capsys):
    from apf_physics.cli import main

    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["eval", str(worlds_dir / "local_minimum.yaml"), "--json", str(blocker / "out.json")]) == 2
    assert "cannot write" in capsys.readouterr().err
