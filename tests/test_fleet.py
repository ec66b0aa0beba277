"""Fleets: many robots on one map, each to its own goal (control.fleet, experiments.fleet, eval --agents)."""

import json

import numpy as np
import pytest

from apf_physics import world_from_dict
from apf_physics.cli import main
from apf_physics.control.fleet import (STAY, GoalTables, Lattice, Priorities, fleet_moves, goal_columns,
                                       preferences)
from apf_physics.control.shield import ACTIONS, SAFETY, move_clearance
from apf_physics.errors import UserError
from apf_physics.control.fleet import place_fleet
from apf_physics.experiments.fleet import rollout_fleet
from apf_physics.experiments.movingai import draw_scenarios, scenario_fleet
from apf_physics.models.policy import potential_change
from apf_physics.planners import make_planner
from apf_physics.sim.engine import Stepper
from apf_physics.world.core import Fleet
from apf_physics.world.io.mapfiles import read_movingai_scen, scen_text
from conftest import write_warehouse_map


def open_world(size=12):
    return world_from_dict({"name": "open", "size": [size, size], "field": "thesis-general",
                            "targets": [[size - 0.5, size - 0.5]]})


def least_gap(before: np.ndarray, after: np.ndarray) -> float:
    """The least distance between two robots' centres over a step of straight, uniform moves."""
    p = before[:, None, :] - before[None, :, :]
    v = (after - before)[:, None, :] - (after - before)[None, :, :]
    a = np.sum(v * v, axis=-1)
    t = np.clip(np.where(a > 0, -np.sum(p * v, axis=-1) / np.where(a > 0, a, 1.0), 0.0), 0.0, 1.0)
    d = np.hypot(*(p + t[..., None] * v).transpose(2, 0, 1))
    d[np.eye(len(before), dtype=bool)] = np.inf
    return float(d.min())


# -- the rule ------------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(12))
def test_fleet_moves_never_bring_two_robots_within_contact(seed):
    # dense crowds on an open lattice, every robot wanting a random move: whatever they want, the
    # moves keep every pair at least 2r + SAFETY apart over the whole step
    world = open_world()
    lattice = Lattice.of(world, (0.5, 0.5))
    rng = np.random.default_rng(seed)
    free = np.flatnonzero(lattice.free)
    nodes = rng.choice(free, 60, replace=False)
    values = rng.normal(size=(60, 9))
    moves = fleet_moves(lattice, nodes, preferences(values, lattice.ok[nodes]), rng.permutation(60))
    before = lattice.points(nodes)
    after = before + ACTIONS[moves]
    assert least_gap(before, after) >= 2 * world.robot_radius + SAFETY - 1e-9
    assert np.all(lattice.ok[nodes, moves] | (moves == STAY))
    assert len(np.unique(lattice.nearest(after))) == 60


def test_a_robot_alone_takes_its_best_move():
    world = open_world()
    lattice = Lattice.of(world, (0.5, 0.5))
    node = lattice.nearest([[5.5, 5.5]])
    values = np.zeros((1, 9))
    values[0, 6] = 1.0   # right-up
    assert fleet_moves(lattice, node, preferences(values, lattice.ok[node]), np.array([0]))[0] == 6


def test_priority_inheritance_pushes_a_robot_out_of_the_way():
    # a corridor one cell wide with a side pocket: the robot with priority goes right; the one in its
    # way has nowhere to want to go, and is pushed on (never back into the pusher's node)
    world = world_from_dict({"name": "c", "size": [8, 3], "field": "thesis-general", "targets": [[7.5, 1.5]],
                             "obstacles": [{"polygon": [[0, 0], [8, 0], [8, 1], [0, 1]]},
                                           {"polygon": [[0, 2], [8, 2], [8, 3], [0, 3]]}]})
    lattice = Lattice.of(world, (0.5, 0.5))
    nodes = lattice.nearest([[2.5, 1.5], [3.5, 1.5]])
    values = np.full((2, 9), -1.0)
    values[0, 3], values[0, STAY] = 1.0, 0.0     # robot 0 wants to go right, else to wait
    values[1, STAY] = 1.0                        # robot 1 would rather stay
    moves = fleet_moves(lattice, nodes, preferences(values, lattice.ok[nodes]), np.array([0, 1]))
    assert list(moves) == [3, 3]
    # without priority over it, robot 0 waits
    moves = fleet_moves(lattice, nodes, preferences(values, lattice.ok[nodes]), np.array([1, 0]))
    assert list(moves) == [STAY, STAY]


def test_no_swaps_and_no_crossing_diagonals():
    world = open_world()
    lattice = Lattice.of(world, (0.5, 0.5))
    nodes = lattice.nearest([[5.5, 5.5], [6.5, 5.5], [5.5, 6.5]])
    values = np.full((3, 9), -1.0)
    values[0, 3] = values[1, 2] = 1.0        # 0 and 1 want to trade places
    values[2, 7] = 0.5                       # 2 wants to cross 0's diagonal... (right-down: onto 1's node)
    moves = fleet_moves(lattice, nodes, preferences(values, lattice.ok[nodes]), np.array([0, 1, 2]))
    before = lattice.points(nodes)
    assert least_gap(before, before + ACTIONS[moves]) >= 0.55 - 1e-9
    assert not (moves[0] == 3 and moves[1] == 2)


def test_pinned_robots_stay():
    world = open_world()
    lattice = Lattice.of(world, (0.5, 0.5))
    nodes = lattice.nearest([[5.5, 5.5], [6.5, 5.5]])
    values = np.zeros((2, 9))
    values[0, 3] = 1.0
    values[1, 3] = 1.0
    moves = fleet_moves(lattice, nodes, preferences(values, lattice.ok[nodes]), np.array([0, 1]),
                        pinned=np.array([False, True]))
    assert moves[1] == STAY and moves[0] != 3


def test_priorities_rise_until_the_goal():
    p = Priorities(3, seed=0)
    p.update(np.array([False, True, False]))
    p.update(np.array([False, False, False]))
    assert p.value[0] >= 2 and p.value[2] >= 2 and p.value[1] < 2
    assert p.order()[-1] == 1


def test_lattice_moves_cut_no_corner():
    # a diagonal between two free cells whose side cells are blocked is not admitted (MovingAI's octile rule)
    world = world_from_dict({"name": "k", "size": [4, 4], "field": "thesis-general", "targets": [[3.5, 3.5]],
                             "obstacles": [{"polygon": [[1, 0], [2, 0], [2, 1], [1, 1]]}]})
    lattice = Lattice.of(world, (0.5, 0.5))
    node = lattice.nearest([[0.5, 0.5]])[0]
    assert not lattice.ok[node, 6]      # right-up past the blocked cell's corner
    assert lattice.ok[node, 0]          # up


def test_lattice_distances_are_octile():
    world = open_world()
    lattice = Lattice.of(world, (0.5, 0.5))
    goal = lattice.nearest([[10.5, 2.5]])[0]
    d = lattice.distances(goal)
    start = lattice.nearest([[1.5, 5.5]])[0]
    assert d[start] == pytest.approx(9 - 3 + 3 * np.sqrt(2), rel=1e-6)


def test_goal_tables_stay_within_their_budget():
    lattice = Lattice.of(open_world(), (0.5, 0.5))
    size = lattice.count * 4
    tables = GoalTables(lattice, budget=3 * size)
    for goal in [1, 2, 3, 4, 1]:
        tables.get(goal, lambda: np.zeros(lattice.count, np.float32))
        assert tables.held <= tables.budget
    assert len(tables) == 3 and tables.built == 5 and tables.peak == 3 * size


def test_goal_columns_read_each_robots_own_table():
    lattice = Lattice.of(open_world(), (0.5, 0.5))
    tables = GoalTables(lattice, budget=2**30)
    nodes = lattice.nearest([[3.5, 3.5], [5.5, 5.5], [7.5, 7.5]])
    goals = np.array([10, 20, 10])
    out = goal_columns(tables, nodes, goals, lambda g: np.full(lattice.count, float(g), np.float32))
    assert np.all(out[[0, 2]] == 10) and np.all(out[1] == 20) and tables.built == 2


# -- the learned planner's values ---------------------------------------------------------------------

def test_fleet_values_are_the_map_networks_action_values_for_a_robot_alone():
    world = world_from_dict({"name": "v", "size": [16, 12], "field": "thesis-general", "targets": [[14.5, 9.5]],
                             "obstacles": [{"polygon": [[5, 2], [7, 2], [7, 9], [5, 9]]}]})
    lattice = Lattice.of(world, (0.5, 0.5))
    planner = make_planner("dqn")
    positions = np.array([[2.5, 5.5], [8.5, 3.5], [12.5, 9.5]])
    planner.reset(world, positions)
    goal = lattice.nearest(world.targets)
    nodes = lattice.nearest(positions)
    fleet = planner.fleet_values(lattice, nodes, np.repeat(goal, 3))
    policy = planner.policy
    alone = world.with_task(lattice.points(goal), np.zeros((0, 2)))
    # the same nine moves scored by the policy itself, V read at the nodes they end on
    view, _ = policy.values(alone)
    rows, cols = view.grid.shape
    ends_at = view.grid.to_index((positions[:, None, :] + ACTIONS[None]).reshape(-1, 2))
    ends = (np.rint(ends_at[:, 1]) * cols + np.rint(ends_at[:, 0])).astype(np.intp).reshape(3, len(ACTIONS))
    ends[:, STAY] = -1                                                   # staying: V where the robot is
    moves = np.broadcast_to(ACTIONS, (3, *ACTIONS.shape))
    room = move_clearance(alone, positions, ACTIONS) - (world.robot_radius + SAFETY)
    candidates = (moves, np.ones(ends.shape, bool), ends)
    direct = policy.q_values(alone, positions, room, potential_change(alone, positions, ACTIONS), candidates)
    np.testing.assert_allclose(fleet, direct, rtol=1e-4, atol=1e-4)


# -- the engine --------------------------------------------------------------------------------------

def test_a_stepper_that_continues_at_targets_keeps_robots_in_play():
    world = open_world()
    stepper = Stepper([world], 2, 1, crowds=[0, 0], arrival="continue")
    stepper.start(np.arange(2), np.array([[[2.5, 2.5]], [[5.5, 5.5]]]))
    stepper.set_targets(np.arange(2), np.array([[3.5, 2.5], [9.5, 9.5]]))
    report = stepper.step(np.array([[[1.0, 0.0]], [[1.0, 0.0]]]))
    assert list(report.reached) == [True, False] and stepper.running.all()
    report = stepper.step(np.array([[[1.0, 0.0]], [[0.0, 0.0]]]))
    assert list(report.reached) == [False, False] and stepper.running.all()


# -- whole fleets -------------------------------------------------------------------------------------

@pytest.fixture
def warehouse(tmp_path):
    path = tmp_path / "wh.map"
    write_warehouse_map(path, blocks=(5, 4), shelf=6, aisle=2, border=3)
    return path


def test_draw_scenarios_as_the_mapf_benchmark(warehouse, tmp_path):
    scenarios = draw_scenarios(warehouse, 60, seed=3)
    out = tmp_path / "wh.scen"
    out.write_text(scen_text(scenarios))
    again = read_movingai_scen(out)
    assert [(s.start, s.goal, s.optimal) for s in again] == [(s.start, s.goal, s.optimal) for s in scenarios]
    assert len({s.start for s in scenarios}) == 60 and len({s.goal for s in scenarios}) == 60
    assert all(s.start != s.goal for s in scenarios)
    world, fleet = scenario_fleet(warehouse, out, 60)
    placed = place_fleet(world, fleet)
    regions = placed.lattice.regions()
    assert len(set(regions[placed.starts]) | set(regions[placed.goals])) == 1
    assert fleet.optimal[0] == pytest.approx(placed.lattice.distances(placed.goals[0])[placed.starts[0]], rel=1e-6)
    assert draw_scenarios(warehouse, 60, seed=3) == scenarios


@pytest.mark.parametrize("planner", ["astar", "dqn"])
def test_a_fleet_on_a_warehouse_arrives_without_collisions(warehouse, tmp_path, planner):
    out = tmp_path / "wh.scen"
    out.write_text(scen_text(draw_scenarios(warehouse, 80, seed=1)))
    world, fleet = scenario_fleet(warehouse, out, 80)
    run = rollout_fleet(world, make_planner(planner), fleet)
    s = run.summary()
    assert s["all_arrived"] and s["robot_robot_collisions"] == 0 and s["robot_obstacle_collisions"] == 0
    assert s["makespan"] == int(run.cost.max()) and s["sum_of_costs"] == int(run.cost.sum())
    assert s["soc_over_optimal"] < 1.5
    for t in range(run.steps):   # every step: the robots' discs kept apart all along their moves
        assert least_gap(run.positions[t], run.positions[t + 1]) >= 2 * world.robot_radius + SAFETY - 1e-6
    assert np.all(run.positions[-1] == run.lattice.points(run.goals[-1]))


def test_lifelong_goals_come_from_each_robots_own_stream(warehouse, tmp_path):
    out = tmp_path / "wh.scen"
    out.write_text(scen_text(draw_scenarios(warehouse, 30, seed=2)))
    world, fleet = scenario_fleet(warehouse, out, 30)
    a = rollout_fleet(world, make_planner("astar"), fleet, lifelong=60, seed=5)
    b = rollout_fleet(world, make_planner("gradient"), fleet, lifelong=60, seed=5)
    s = a.summary()
    assert s["goals_reached"] > 30 and s["throughput"] == pytest.approx(s["goals_reached"] / 60, abs=1e-4)
    assert s["robot_robot_collisions"] == 0 and a.steps == 60
    for i in range(30):   # the same goals, in the same order, whoever plans
        seq_a = [g for k, g in enumerate(a.goals[:, i]) if k == 0 or g != a.goals[k - 1, i]]
        seq_b = [g for k, g in enumerate(b.goals[:, i]) if k == 0 or g != b.goals[k - 1, i]]
        n = min(len(seq_a), len(seq_b))
        assert seq_a[:n] == seq_b[:n]


def test_a_world_file_of_robots_runs_as_a_fleet(tmp_path, capsys):
    path = tmp_path / "f.yaml"
    path.write_text("name: f\nsize: [10, 6]\nfield: thesis-general\nrobots:\n"
                    "  - {start: [0.5, 0.5], target: [9.5, 5.5]}\n  - {start: [9.5, 5.5], target: [0.5, 0.5]}\n"
                    "  - {start: [0.5, 5.5], target: [9.5, 0.5]}\n")
    out = tmp_path / "f.json"
    assert main(["eval", str(path), "--planner", "dqn,astar", "--json", str(out), "--no-progress"]) == 0
    runs = json.loads(out.read_text())
    assert [r["planner"] for r in runs] == ["dqn", "astar"]
    robot = runs[0]["robots"][0]
    assert {"success", "collision", "steps", "path_length", "target", "label"} <= set(robot)
    summary = runs[0]["summary"]
    assert summary["all_arrived"] and summary["robot_robot_collisions"] == 0
    assert {"arrived_share", "makespan", "sum_of_costs", "robot_obstacle_collisions"} <= set(summary)
    assert "3/3" in capsys.readouterr().out


# -- bad input --------------------------------------------------------------------------------------

def scen_file(path, lines, width=8, height=6):
    rows = [f"0\tm.map\t{width}\t{height}\t{sx}\t{sy}\t{gx}\t{gy}\t5.0" for sx, sy, gx, gy in lines]
    path.write_text("version 1\n" + "\n".join(rows) + "\n")
    return path


@pytest.fixture
def small_map(tmp_path):
    path = tmp_path / "m.map"
    path.write_text("type octile\nheight 6\nwidth 8\nmap\n........\n..@@....\n........\n....@...\n........\n........\n")
    return path


@pytest.mark.parametrize("lines, agents, message", [
    ([(0, 0, 7, 5), (0, 0, 6, 5)], 2, "two robots on one cell"),
    ([(0, 0, 7, 5), (1, 0, 7, 5)], 2, "two robots on one cell"),
    ([(2, 1, 7, 5)], 1, "is inside an obstacle"),
    ([(0, 0, 7, 5)], 2, "the file has only 1 scenarios"),
])
def test_bad_fleets_are_refused_in_one_line(small_map, tmp_path, capsys, lines, agents, message):
    scen = scen_file(tmp_path / "s.scen", lines)
    assert main(["eval", str(small_map), "--scen", str(scen), "--agents", str(agents), "--planner", "astar",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_a_planner_that_cannot_drive_a_fleet_is_named(small_map, tmp_path, capsys):
    scen = scen_file(tmp_path / "s.scen", [(0, 0, 7, 5)])
    assert main(["eval", str(small_map), "--scen", str(scen), "--agents", "1", "--planner", "escape"]) == 2
    assert "cannot drive a fleet" in capsys.readouterr().err


@pytest.mark.parametrize("robots, message", [
    ([{"start": [1.5, 1.5], "target": [8.5, 4.5]}, {"start": [1.6, 1.5], "target": [7.5, 4.5]}], "is on robots[0]'s start"),
    ([{"start": [1.5, 1.5], "target": [8.5, 4.5]}, {"start": [3.5, 1.5], "target": [8.5, 4.5]}], "robots[0]'s target too"),
    ([{"start": [4.5, 3.5], "target": [8.5, 4.5]}], "robots[0].start"),
    ([{"start": [1.5, 1.5]}], "robots[0]"),
])
def test_bad_robots_in_a_world_file_are_refused(robots, message):
    with pytest.raises(UserError, match=message.replace("[", r"\[").replace("]", r"\]")):
        world_from_dict({"name": "f", "size": [10, 6], "field": "thesis-general", "robots": robots,
                         "obstacles": [{"polygon": [[4, 3], [5, 3], [5, 4], [4, 4]]}]})


def test_a_start_off_the_lattice_is_refused():
    world = world_from_dict({"name": "f", "size": [10, 6], "field": "thesis-general",
                             "robots": [{"start": [1.5, 1.5], "target": [8.5, 4.5]},
                                        {"start": [3.2, 1.5], "target": [7.5, 4.5]}]})
    with pytest.raises(UserError, match="off the fleet's lattice"):
        place_fleet(world, world.robots)


def test_a_world_of_robots_round_trips(tmp_path):
    from apf_physics.world.io.worldfile import dump_world_yaml, load_world
    world = world_from_dict({"name": "f", "size": [10, 6], "field": "thesis-general",
                             "robots": [{"start": [1.5, 1.5], "target": [8.5, 4.5]}]})
    path = tmp_path / "f.yaml"
    path.write_text(dump_world_yaml(world))
    again = load_world(path)
    assert np.array_equal(again.robots.starts, world.robots.starts)
    assert np.array_equal(again.robots.targets, world.robots.targets)


def test_map_world_and_fleet_first():
    fleet = Fleet([[0.5, 0.5], [1.5, 0.5]], [[3.5, 3.5], [2.5, 3.5]], optimal=np.array([3.0, 4.0]))
    assert len(fleet.first(1)) == 1 and fleet.first(1).optimal.tolist() == [3.0]
    assert fleet.labels == ("robots[0]", "robots[1]")


# -- the multi-agent environment ----------------------------------------------------------------------

def fleet_world(count=12, size=10):
    rng = np.random.default_rng(0)
    cells = rng.choice(size * size, 2 * count, replace=False)
    points = np.column_stack([cells % size + 0.5, cells // size + 0.5])
    return world_from_dict({"name": "env", "size": [size, size], "field": "thesis-general",
                            "robots": [{"start": points[i].tolist(), "target": points[count + i].tolist()}
                                       for i in range(count)]})


@pytest.mark.parametrize("on_target", ["finish", "restart"])
def test_the_fleet_env_passes_pettingzoos_parallel_api_test(on_target):
    from pettingzoo.test import parallel_api_test
    from apf_physics.envs import FleetParallelEnv
    parallel_api_test(FleetParallelEnv(fleet_world(), on_target=on_target, max_episode_steps=40), num_cycles=60)


def test_the_fleet_env_never_lets_robots_touch_and_rewards_arrivals():
    from apf_physics.envs import FleetParallelEnv
    env = FleetParallelEnv(fleet_world(20), max_episode_steps=200)
    obs, infos = env.reset(seed=3)
    assert obs["robot_0"].shape == (3, 11, 11) and obs["robot_0"][2].sum() == 1
    total, refused = 0.0, 0
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        before = env.task.lattice.points(env.task.nodes)
        obs, rewards, terminated, truncated, infos = env.step(actions)
        after = env.task.lattice.points(env.task.nodes)
        assert least_gap(before, after) >= 2 * env.world.robot_radius + SAFETY - 1e-9
        assert not any(info["collision"] for info in infos.values())
        refused += sum(info["refused"] for info in infos.values())
        total += sum(rewards.values())
    assert refused > 0 and total == sum(1 for i in range(20) if env.task.done[i])


def test_the_fleet_envs_random_starts_follow_the_seed():
    from apf_physics.envs import FleetParallelEnv
    a, b = FleetParallelEnv(fleet_world(), starts="random"), FleetParallelEnv(fleet_world(), starts="random")
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)
    assert np.array_equal(a.task.nodes, b.task.nodes) and not np.array_equal(
        a.task.nodes, a.task.lattice.nearest(a.world.robots.starts))


# -- formations among a fleet -------------------------------------------------------------------------

def mixed_world(robots=40, seed=4):
    rng = np.random.default_rng(seed)
    width, height = 30, 20

    def blocked(p):
        return ((10 <= p[0] <= 12 and 4 <= p[1] <= 8) or (18 <= p[0] <= 20 and 12 <= p[1] <= 16)
                or np.hypot(*(p - [2.5, 10.5])) < 3 or np.hypot(*(p - [27.5, 10.5])) < 3)

    cells = rng.permutation(width * height)
    points = np.array([p for p in np.column_stack([cells % width + 0.5, cells // width + 0.5]) if not blocked(p)])
    return world_from_dict({
        "name": "mix", "size": [width, height], "field": "thesis-general",
        "obstacles": [{"polygon": [[10, 4], [12, 4], [12, 8], [10, 8]]}, {"polygon": [[18, 12], [20, 12], [20, 16], [18, 16]]}],
        "robots": [{"start": points[i].tolist(), "target": points[robots + i].tolist()} for i in range(robots)],
        "formations": [{"start": [2.5, 10.5], "target": [27.5, 10.2], "followers": 2},
                       {"start": [27.5, 10.5], "target": [2.5, 10.2], "followers": 2}]})


@pytest.mark.parametrize("planner", ["astar", "dqn"])
def test_formations_cross_a_fleet_and_everyone_arrives_untouched(planner):
    world = mixed_world()
    run = rollout_fleet(world, make_planner(planner))
    s = run.summary()
    assert s["all_arrived"] and s["formations_arrived"] == 2
    assert s["robot_robot_collisions"] == 0 and s["robot_obstacle_collisions"] == 0
    steps = run.steps
    everyone = [run.positions]
    for episode in run.formations:   # formations stop at their targets: held there to the end
        p = episode.formation.positions
        everyone.append(np.concatenate([p, np.repeat(p[-1:], steps + 1 - len(p), axis=0)]))
    positions = np.concatenate(everyone, axis=1)
    for t in range(steps):
        assert least_gap(positions[t], positions[t + 1]) >= 2 * world.robot_radius + SAFETY - 1e-6
    assert "formations" in run.to_dict()
