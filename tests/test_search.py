"""A* oracle, the boundary-following escape planner, the thesis worlds, the generator and curricula."""

import json

import numpy as np
import pytest

from apf_physics import load_world, world_from_dict
from apf_physics.learning.curriculum import load_curriculum, rehearsal_worlds
from apf_physics.errors import UserError, WorldError
from apf_physics.world.generate import FAMILIES, generate_world
from apf_physics.experiments.worldsets import generate_set
from apf_physics.planners import GradientPlanner, make_planner
from apf_physics.planners.astar import AStarPlanner
from apf_physics.world.search import shortest_costs, shortest_paths
from apf_physics.world.search import reachable, shortest_path, shortest_path_length
from apf_physics.planners.escape import EscapePlanner
from apf_physics.experiments.rollout import rollout
from apf_physics.world.io.units import obstacle_to_file, world_to_file
from apf_physics.world.core import Frame

from conftest import simple_world_dict


def nearest_target_distance(world, point):
    return float(np.min(np.hypot(*(world.targets - point).T)))


# -- A* ------------------------------------------------------------------------------------

def test_astar_goes_around_the_local_minimum_rectangle(worlds_dir):
    world = load_world(worlds_dir / "local_minimum.yaml")
    start = world.starts[0]
    path = shortest_path(world, start)
    assert path is not None
    np.testing.assert_allclose(path[0], start)
    assert nearest_target_distance(world, path[-1]) <= world.goal_tolerance
    # The path leaves the rectangle's y-range [6, 14] to get past it.
    assert path[:, 1].min() < 6 or path[:, 1].max() > 14
    (episode,) = rollout(world, AStarPlanner(), world.starts)
    assert episode.outcome == "reached"
    assert np.all(world.clearance(episode.path) > world.robot_radius)


def test_astar_length_is_at_least_the_straight_distance(worlds_dir):
    world = load_world(worlds_dir / "fixed20.yaml")
    lengths = np.array([shortest_path_length(world, s) for s in world.starts])
    straight = np.array([nearest_target_distance(world, s) for s in world.starts])
    assert np.all(lengths >= straight - 1e-9)
    # Around the local minimum's rectangle the detour is real.
    lm = load_world(worlds_dir / "local_minimum.yaml")
    assert shortest_path_length(lm, lm.starts[0]) > nearest_target_distance(lm, lm.starts[0]) + 1.0


def test_astar_rollouts_reach_and_match_their_path_length(worlds_dir):
    world = load_world(worlds_dir / "fixed20.yaml")
    episodes = rollout(world, make_planner("astar"), world.starts)
    assert all(e.outcome == "reached" for e in episodes)
    for e in episodes:
        planned = shortest_path_length(world, e.start)
        # Executed within the goal tolerance of the planned path's end.
        assert e.path_length <= planned + 1e-6
        assert e.path_length >= planned - 2 * world.goal_tolerance


def _walled_in_world():
    # Four thin walls enclose the square [4, 8] x [4, 8]; the target is outside.
    walls = [[[3.5, 3.5], [8.5, 3.5], [8.5, 4], [3.5, 4]], [[8, 3.5], [8.5, 3.5], [8.5, 8.5], [8, 8.5]],
             [[3.5, 8], [8.5, 8], [8.5, 8.5], [3.5, 8.5]], [[3.5, 3.5], [4, 3.5], [4, 8.5], [3.5, 8.5]]]
    return world_from_dict(simple_world_dict(obstacles=[{"polygon": w} for w in walls],
                                             starts=[[6, 6], [2, 2]]))


def test_unreachable_start_is_reported():
    world = _walled_in_world()
    inside, outside = world.starts
    assert not reachable(world, inside)
    assert shortest_path_length(world, inside) is None
    assert reachable(world, outside)
    assert shortest_path_length(world, outside) is not None
    planner = AStarPlanner()
    planner.reset(world, world.starts)
    assert planner.stuck().tolist() == [True, False]
    inside_ep, outside_ep = rollout(world, AStarPlanner(), world.starts)
    assert inside_ep.outcome == "trapped" and inside_ep.steps == 0
    assert outside_ep.outcome == "reached"


def test_target_in_a_gap_too_narrow_for_the_robot_is_unreachable():
    # The target sits between two discs whose gap is narrower than the robot.
    data = simple_world_dict(obstacles=[{"circle": {"center": [15, 14.6], "radius": 0.4}},
                                        {"circle": {"center": [15, 15.4], "radius": 0.4}},
                                        {"circle": {"center": [14.6, 15], "radius": 0.4}},
                                        {"circle": {"center": [15.4, 15], "radius": 0.4}}],
                             targets=[[15, 15]], starts=[[2, 2]])
    world = world_from_dict(data)
    assert not reachable(world, world.starts[0])
    assert shortest_path_length(world, world.starts[0]) is None


# -- the escape planner --------------------------------------------------------------------

def test_escape_gets_out_of_the_local_minimum(worlds_dir):
    world = load_world(worlds_dir / "local_minimum.yaml")
    (episode,) = rollout(world, EscapePlanner(), world.starts)
    assert episode.outcome == "reached"
    assert np.all(world.clearance(episode.path) > world.robot_radius)


def test_escape_reaches_most_fixed20_starts_where_descent_is_trapped(worlds_dir):
    world = load_world(worlds_dir / "fixed20.yaml")
    descent = rollout(world, GradientPlanner(), world.starts)
    escape = rollout(world, EscapePlanner(), world.starts)
    trapped = [i for i, e in enumerate(descent) if e.outcome != "reached"]
    assert len(trapped) >= 5
    rescued = sum(escape[i].outcome == "reached" for i in trapped)
    assert rescued >= 0.8 * len(trapped)
    assert not any(e.outcome == "collision" for e in escape)
    # Where descent works, the escape planner is descent: it reaches too.
    assert all(escape[i].outcome == "reached" for i, e in enumerate(descent) if e.outcome == "reached")


# -- the thesis worlds ---------------------------------------------------------------------

THESIS = ["basic1", "basic2", "basic3", "basic4", "curriculum1_line", "curriculum2_two_points",
          "curriculum3_concave", "curriculum4_two_lines_bent", "test1", "test2", "test3", "test4"]


@pytest.mark.parametrize("name", THESIS)
def test_thesis_worlds_are_valid_and_reachable(worlds_dir, name):
    world = load_world(worlds_dir / "thesis" / f"{name}.yaml")
    assert world.size == (50.0, 50.0)
    assert (world.field.katt, world.field.krep, world.field.kstr, world.field.p0, world.field.ps) == (1, 20, 8, 3, 8)
    assert len(world.starts) >= 4 and len(world.targets) == 1
    assert all(reachable(world, s) for s in world.starts)
    if name.startswith("basic"):
        assert len(world.obstacles) == 1 and obstacle_to_file(Frame(), world.obstacles[0])["circle"]["radius"] == 0


def test_thesis_test_worlds_trap_gradient_descent(worlds_dir):
    for k in range(1, 5):
        world = load_world(worlds_dir / "thesis" / f"test{k}.yaml")
        episodes = rollout(world, GradientPlanner(), world.starts)
        assert sum(e.outcome != "reached" for e in episodes) > len(episodes) / 2


# -- the generator -------------------------------------------------------------------------

def test_generate_world_is_deterministic_and_reachable():
    for family in FAMILIES:
        a = generate_world(family, np.random.default_rng(3), n_starts=3)
        b = generate_world(family, np.random.default_rng(3), n_starts=3)
        assert world_to_file(a) == world_to_file(b)
        assert len(a.starts) == 3
        assert all(reachable(a, s) for s in a.starts)
        # Starts are not already at the target.
        assert all(nearest_target_distance(a, s) > a.goal_tolerance for s in a.starts)
    c = generate_world("line", np.random.default_rng(4), n_starts=3)
    assert world_to_file(c) != world_to_file(generate_world("line", np.random.default_rng(3), n_starts=3))


def test_generate_world_rejects_unknown_names():
    with pytest.raises(UserError, match="family"):
        generate_world("spiral", np.random.default_rng(0))
    with pytest.raises(UserError, match="field"):
        generate_world("point", np.random.default_rng(0), field="nope")


def test_generate_set_writes_valid_worlds_and_a_truthful_manifest(tmp_path):
    manifest = generate_set(list(FAMILIES), count=len(FAMILIES), seed=11, out=tmp_path / "a", n_starts=2)
    again = generate_set(list(FAMILIES), count=len(FAMILIES), seed=11, out=tmp_path / "b", n_starts=2)
    assert manifest == again
    on_disk = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert on_disk["seed"] == 11 and len(on_disk["worlds"]) == len(FAMILIES)
    assert {w["family"] for w in on_disk["worlds"]} == set(FAMILIES)
    for record in on_disk["worlds"]:
        text_a = (tmp_path / "a" / record["file"]).read_text()
        assert text_a == (tmp_path / "b" / record["file"]).read_text()
        world = load_world(tmp_path / "a" / record["file"])
        np.testing.assert_allclose(world.starts, [s["start"] for s in record["starts"]])
        fresh = rollout(world, GradientPlanner(), world.starts)
        for label, episode in zip(record["starts"], fresh):
            assert label["gradient_outcome"] == episode.outcome
            assert label["gradient_trapped"] == (episode.outcome != "reached")
            assert label["astar_length"] >= label["straight_distance"] - 1e-6
            assert reachable(world, np.array(label["start"]))


def test_generate_command(tmp_path, capsys):
    from apf_physics.cli import main

    out = tmp_path / "set"
    assert main(["generate", "--family", "concave", "--count", "2", "--seed", "1", "--out", str(out),
                 "--starts", "2"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["concave_0.yaml", "concave_1.yaml", "manifest.json"]
    assert "wrote 2 worlds" in capsys.readouterr().out
    assert main(["generate", "--family", "spiral", "--count", "1", "--out", str(out)]) == 2
    assert "spiral" in capsys.readouterr().err


# -- curricula -----------------------------------------------------------------------------

def test_thesis_curriculum_loads_with_rehearsal(worlds_dir):
    stages = load_curriculum(worlds_dir / "curricula" / "thesis.yaml")
    assert [s.name for s in stages] == ["basic", "line", "two_points", "concave", "two_lines_bent"]
    assert [w.name for w in stages[0].worlds] == ["basic1", "basic2", "basic3", "basic4"]
    assert [len(s.training_worlds) for s in stages] == [4, 5, 6, 7, 8]
    # Stage i trains its own worlds with every earlier stage's.
    for i, stage in enumerate(stages):
        assert list(stage.training_worlds) == rehearsal_worlds(stages, i)
        assert set(stage.worlds) <= set(stage.training_worlds)
        for earlier in stages[:i]:
            assert set(earlier.worlds) <= set(stage.training_worlds)


def _write(tmp_path, text, name="c.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, key", [
    ("{}", "stages"),
    ("stages: []", "stages"),
    ("stages: [{name: a, worlds: [w.yaml]}]\nextra: 1", "extra"),
    ("stages: [{worlds: [w.yaml]}]", "stages[0].name"),
    ("stages: [{name: a}]", "stages[0].worlds"),
    ("stages: [{name: a, worlds: [w.yaml], speed: 2}]", "stages[0].speed"),
    ("stages: [{name: a, worlds: [missing.yaml]}]", "stages[0].worlds[0]"),
    ("stages: [{name: a, worlds: [w.yaml]}, {name: a, worlds: [w.yaml]}]", "stages[1].name"),
    ("stages: [{name: a, worlds: [3]}]", "stages[0].worlds[0]"),
])
def test_curriculum_errors_name_file_and_key(tmp_path, text, key):
    (tmp_path / "w.yaml").write_text(json.dumps(simple_world_dict()))
    path = _write(tmp_path, text)
    with pytest.raises(UserError) as info:
        load_curriculum(path)
    assert str(path) in str(info.value) and key in str(info.value)


def test_curriculum_reports_a_bad_world_file_by_name(tmp_path):
    (tmp_path / "bad.yaml").write_text(json.dumps(simple_world_dict(size=[-1, 20])))
    with pytest.raises(WorldError, match="bad.yaml: size"):
        load_curriculum(_write(tmp_path, "stages: [{name: a, worlds: [bad.yaml]}]"))
    with pytest.raises(UserError, match="no such curriculum file"):
        load_curriculum(tmp_path / "none.yaml")
    with pytest.raises(UserError, match="not valid YAML"):
        load_curriculum(_write(tmp_path, "stages: [", name="broken.yaml"))


def _dijkstra(free, sources, steps):
    """Reference: a heap Dijkstra over the free nodes (the next node: the first settled that gives the least cost)."""
    import heapq
    rows, cols = free.shape
    cost = np.full(rows * cols, np.inf)
    nxt = np.full(rows * cols, -1)
    heap = [(0.0, int(s)) for s in sources]
    for _, s in heap:
        cost[s] = 0.0
    heapq.heapify(heap)
    while heap:
        d, u = heapq.heappop(heap)
        if d > cost[u]:
            continue
        r, c = divmod(u, cols)
        for dr, dc, w in steps:
            rr, cc = r - dr, c - dc
            if 0 <= rr < rows and 0 <= cc < cols and free[rr, cc]:
                v = rr * cols + cc
                if d + w < cost[v]:
                    cost[v], nxt[v] = d + w, u
                    heapq.heappush(heap, (d + w, v))
    return cost, nxt


@pytest.mark.parametrize("seed", range(6))
def test_vectorised_shortest_paths_are_dijkstras(seed):
    from apf_physics.world.search import _NEIGHBOURS, shortest_paths
    rng = np.random.default_rng(seed)
    free = rng.random((23, 31)) > 0.3
    sources = rng.choice(np.flatnonzero(free.ravel()), size=2, replace=False)
    steps = [(dr, dc, w / 4) for dr, dc, w in _NEIGHBOURS]
    cost, nxt = shortest_paths(free, sources, steps)
    want_cost, want_next = _dijkstra(free, sources, steps)
    np.testing.assert_array_equal(cost, want_cost)
    np.testing.assert_array_equal(nxt, want_next)


@pytest.mark.parametrize("seed", range(8))
def test_the_compiled_search_gives_the_label_correcting_costs_to_the_bit(seed):
    rng = np.random.default_rng(seed)
    rows, cols = rng.integers(3, 50, 2)
    free = rng.random((rows, cols)) > rng.uniform(0, 0.5)
    sources = rng.choice(rows * cols, rng.integers(1, 4), replace=False)
    steps = [(dr, dc, (rng.random((rows, cols)).astype(np.float32) * 3 + 0.1) if seed % 2 else np.float32(np.hypot(dr, dc)))
             for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]
    expected, _ = shortest_paths(free, sources, steps, np.float32)
    got = shortest_costs(free, sources, steps, np.float32)
    assert got.dtype == expected.dtype and np.array_equal(got, expected)
