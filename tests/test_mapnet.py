"""The map network: value iteration over the map view, its model files, and imitation training."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from apf_physics import world_from_dict
from apf_physics.errors import ModelError
from apf_physics.experiments.evaluate import evaluate
from apf_physics.models import SHIPPED, MapNetwork, MapPolicy, load_policy, model_meta, save_model
from apf_physics.models.mapnet import UNREACHED
from apf_physics.sensing.mapview import MapView
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.learning.config import preset
from apf_physics.learning import train
from apf_physics.learning.imitation import Teacher, batch, map_network, update
from apf_physics.learning.phases import phases_for_curriculum

from conftest import simple_world_dict

WALLED = simple_world_dict(
    # a wall across the map with one door at its right end, and a sealed box
    obstacles=[{"polygon": [[0, 9.5], [17, 9.5], [17, 10.5], [0, 10.5]]},
               *({"polygon": box} for box in ([[2, 2], [6, 2], [6, 2.5], [2, 2.5]], [[2, 5.5], [6, 5.5], [6, 6], [2, 6]],
                                               [[2, 2.5], [2.5, 2.5], [2.5, 5.5], [2, 5.5]],
                                               [[5.5, 2.5], [6, 2.5], [6, 5.5], [5.5, 5.5]]))],
    targets=[[4, 15]], starts=[[4, 8], [10, 3]], goal_tolerance=0.75)


def test_values_are_minus_a_cost_to_go_around_walls_and_none_where_sealed_off():
    world = world_from_dict(WALLED)
    view = MapView.of(world, 2)
    net = MapNetwork(resolution=2)
    with torch.no_grad():
        v = net.values(torch.from_numpy(view.features), torch.from_numpy(view.free), torch.from_numpy(view.goal)).numpy()
    def at(x, y):
        c, r = view.grid.to_index(np.array([[x, y]]))[0]
        return v[int(round(r)), int(round(c))]
    assert at(4, 15) == 0.0
    # below the wall the way round (through the door at x 17..20) is far longer than the straight line
    assert at(4, 8) < -(13 + 2 + 13) * 0.9
    assert at(4, 8) < at(18.5, 8) < at(18.5, 12) < 0
    assert at(4, 4) == UNREACHED          # inside the sealed box
    assert at(10, 10) == UNREACHED        # inside the wall
    assert np.all(v[~view.free] == UNREACHED)


def test_map_model_files_round_trip_and_refuse_what_does_not_fit(tmp_path):
    world = world_from_dict(WALLED)
    net = MapNetwork(resolution=2, channels=4, hidden=(8,))
    path = save_model(tmp_path / "map.pt", net, model_meta(net, world.field, {"preset": "map"}, {}, None))
    policy = load_policy(path, expect_field=world.field.as_dict())
    assert isinstance(policy, MapPolicy) and policy.moves.shape == (17, 2)
    positions = np.array([[4.0, 8.0], [10.0, 3.0]])
    room, du = np.zeros((2, 17)), np.zeros((2, 17))
    np.testing.assert_allclose(policy.q_values(world, positions, room, du), MapPolicy(net).q_values(world, positions, room, du),
                               rtol=1e-6)
    with pytest.raises(ModelError, match="map-planning model"):
        from apf_physics.models import load_model
        load_model(path, expect_obs_shape=(1, 11, 11))
    # an unknown architecture type is one line naming the key
    raw = path.read_bytes()
    meta_start = raw.index(b"\n", len(b"APF-PHYSICS-DQN\n")) + 1
    header = json.loads(raw[len(b"APF-PHYSICS-DQN\n"):meta_start])
    meta = json.loads(raw[meta_start:meta_start + header["meta_bytes"]])
    meta["arch"]["moves"] = "sideways"
    from apf_physics.models.files import read_file, write_file
    _, tensors = read_file(path)
    bad = write_file(tmp_path / "bad.pt", meta, tensors)
    with pytest.raises(ModelError) as err:
        load_policy(bad)
    assert "arch.moves" in str(err.value) and "\n" not in str(err.value)


def test_training_and_acting_see_the_same_per_move_inputs():
    """The teacher's batches carry exactly what the planner computes when it acts (policy.move_inputs)."""
    from apf_physics.control.shield import MOVE_SETS
    from apf_physics.models.policy import move_inputs
    world = world_from_dict(WALLED)
    config = preset("map", demo_positions=64, map_moves="fine")
    data = batch(Teacher.of(world, config.imitation.map_resolution), config.imitation, np.random.default_rng(3))
    positions, room, du, _ = data
    acting_room, acting_du = move_inputs(world, positions, MOVE_SETS[config.imitation.map_moves])
    assert len(positions) > 20 and np.array_equal(room, acting_room) and np.array_equal(du, acting_du)
    assert (room < 0).any() and (room >= 0).any()       # near the walls some moves are unsafe, elsewhere safe


def test_the_teacher_demonstrates_only_moves_the_exact_room_finds_safe():
    from apf_physics.control.shield import FINE_ACTIONS
    from apf_physics.models.policy import move_inputs
    from apf_physics.learning.imitation import teacher_room
    world = world_from_dict(WALLED)
    points = np.random.default_rng(0).uniform(0, 20, size=(300, 2))
    exact, _ = move_inputs(world, points, FINE_ACTIONS)
    teacher = teacher_room(world, points, FINE_ACTIONS)
    # within the room the network reads (up to 1) the teacher's bound is never above the exact room, and close to it
    exact, teacher = np.minimum(exact, 1.0), np.minimum(teacher, 1.0)
    assert np.all(teacher <= exact + 1e-9) and np.median(exact - teacher) < 0.2


def test_imitation_lowers_the_loss_and_the_planner_follows_the_values():
    world = world_from_dict(WALLED)
    config = preset("map", demo_positions=128, grad_iterations=8, map_moves="fine")
    losses, episodes = _short_imitation(world, config, Teacher.of(world, config.imitation.map_resolution), 40)
    assert np.mean(losses[-5:]) < 0.9 * np.mean(losses[:5])
    assert [e.outcome for e in episodes] == ["reached", "reached"]


def _short_imitation(world, config, teacher, updates: int):
    """``updates`` imitation updates of a fresh map network (seeded), then ``eval`` of its planner on
    ``world``'s starts: the losses and the episodes."""
    torch.manual_seed(0)
    net = map_network(config)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.network.learning_rate)
    rng = np.random.default_rng(0)
    losses = [update(net, optimizer, teacher, batch(teacher, config.imitation, rng), config) for _ in range(updates)]
    return losses, evaluate(DQNPlanner(policy=MapPolicy(net)), [world]).episodes


def test_node_moves_train_on_what_the_planner_reads_and_the_teacher_prefers_the_longest_shortest_move():
    """Moves onto nodes: the teacher's batch carries exactly the inputs the planner computes when it acts
    (robot_move_inputs of each robot's own moves), its labels favour, among the moves along a
    shortest way, the longest, and a short imitation makes the planner reach the targets."""
    from apf_physics.models.policy import robot_move_inputs
    from apf_physics.sim.nodegraph import node_moves
    from apf_physics.learning.imitation import NodeTeacher, node_batch
    world = world_from_dict({"size": [12, 12], "field": "thesis-general", "targets": [[10.0, 6.0]]})   # open
    config = preset("map", demo_positions=64, grad_iterations=8)
    teacher = NodeTeacher.of(world, config.imitation.map_resolution)
    positions, moves, usable, ends, room, du, target = node_batch(teacher, config.imitation, np.random.default_rng(3))
    acting_room, acting_du = robot_move_inputs(world, positions, moves)
    assert np.array_equal(room, acting_room) and np.array_equal(du, acting_du)
    assert np.array_equal(node_moves(teacher.graph, positions)[0], moves)
    # from (4, 6), 6 units short of the target on its axis: the unit move toward it is the one demonstrated
    here = np.array([[4.0, 6.0]])
    moves, usable, ends = node_moves(teacher.graph, here)
    room, _ = robot_move_inputs(world, here, moves)
    p, ok = teacher.labels(here, moves, usable, ends, room, config.imitation.label_temperature)
    assert ok[0] and np.allclose(moves[0, p[0].argmax()], [1.0, 0.0])
    half = np.flatnonzero(np.all(np.isclose(moves[0], [0.5, 0.0]), axis=1))[0]
    assert p[0, half] < 0.2 * p[0].max() and p[0, -1] < 1e-3          # a half move, and staying, much less
    # a short imitation on a walled world: the planner on nodes reaches both starts
    walled = world_from_dict(WALLED)
    # (more moves than the fine set: the cross-entropy starts higher and falls slower; measured 1.91 -> 1.51)
    losses, episodes = _short_imitation(walled, config, NodeTeacher.of(walled, config.imitation.map_resolution), 100)
    assert np.mean(losses[-10:]) < 0.9 * np.mean(losses[:10])
    assert [e.outcome for e in episodes] == ["reached", "reached"]


def test_a_tiny_imitation_run_writes_a_usable_model_and_resumes(tmp_path):
    from apf_physics.learning.curriculum import load_curriculum
    from conftest import WORLDS
    config = preset("map", total_steps=6, eval_every=6, validation_worlds=2, validation_starts=1, pool_size=2,
                    map_sizes=(30.0,), families=("point", "narrow_gap"), demo_positions=64, grad_iterations=4)
    phases = phases_for_curriculum(load_curriculum(WORLDS / "curricula" / "thesis.yaml"), config)
    result = train(config, phases, out_dir=tmp_path / "run")
    assert result.counters.global_step == 6 and (tmp_path / "run" / "best.pt").is_file()
    assert isinstance(load_policy(tmp_path / "run" / "best.pt"), MapPolicy)
    again = train(config, phases, out_dir=tmp_path / "run", resume=True)
    assert again.already_finished


@pytest.mark.parametrize("world_name", ["fixed20", "maze", "rooms"])
def test_fixed_point_equals_the_bellman_updates_to_the_bit(world_name):
    """The label-correcting search finds exactly what updating the whole grid to a fixed point does."""
    from apf_physics.models.mapnet import UNREACHED, _bellman_update, _neighbours, _shift, fixed_point
    from apf_physics.models import resolve_model
    from apf_physics.sensing.mapview import MapView
    from apf_physics import load_world
    world = load_world(world_name)
    policy = load_policy(resolve_model("map"))
    net = policy.network
    view = MapView.of(world, net.resolution)
    features, free, goal = (torch.from_numpy(view.features), torch.from_numpy(view.free), torch.from_numpy(view.goal))
    with torch.no_grad():
        kappa = net.cost(features)
        edges = [(dr, dc, w * 0.5 * (kappa + _shift(kappa, dr, dc, float("inf")))) for dr, dc, w in _neighbours(net.resolution)]
        v = torch.where(goal, 0.0, UNREACHED).to(kappa.dtype)
        while True:
            new = _bellman_update(v, edges, free, goal)
            if torch.equal(new, v):
                break
            v = new
        assert torch.equal(fixed_point(edges, free, goal), v)


# -- training through the public entry points --------------------------------------------------------------------

def _fit(config, phases, out_dir=None, resume=False):
    """The imitation trainer's public entry point: the one training loop, ``train``."""
    return train(config, phases, out_dir, resume=resume)


def _tiny_map_config(**overrides):
    options = dict(validation_worlds=4, validation_starts=2, pool_size=2, map_sizes=(30.0,),
                   families=("point", "narrow_gap"), demo_positions=64, grad_iterations=4, time_limit=None)
    return preset("map", **{**options, **overrides})


def _phases(config):
    from apf_physics.learning.curriculum import load_curriculum
    from conftest import WORLDS
    return phases_for_curriculum(load_curriculum(WORLDS / "curricula" / "thesis.yaml"), config)


def _validation_success(network, phase):
    from apf_physics.learning import validation
    planner = DQNPlanner(policy=MapPolicy(network), shield=False)     # as the preset evaluates: unshielded
    return validation.summarise(evaluate(planner, phase.validation.worlds).episodes, phase.validation)


@pytest.mark.parametrize("seed", range(6))
def test_replanning_a_patch_settles_where_the_bellman_updates_do_to_the_bit(seed):
    """The compiled Bellman updates of ``replan`` reach the fixed point of :func:`_bellman_update` (held nodes kept)."""
    from apf_physics.models.mapnet import _neighbours, _shift, _bellman_update, replan

    rng = np.random.default_rng(seed)
    net = MapNetwork(resolution=2, channels=4, hidden=(8,))
    rows, cols = rng.integers(4, 26, 2)
    features = torch.from_numpy(rng.uniform(-0.5, 1.0, (2, rows, cols)).astype(np.float32))
    free = torch.from_numpy(rng.random((rows, cols)) > 0.25)
    held = torch.zeros((rows, cols), dtype=torch.bool)
    held[[0, -1], :] = held[:, [0, -1]] = True
    held &= torch.from_numpy(rng.random((rows, cols)) > 0.3)
    values = torch.from_numpy(rng.uniform(-40.0, 0.0, (rows, cols)).astype(np.float32))
    extra = torch.from_numpy(np.where(rng.random((rows, cols)) > 0.7, 8.0, 0.0).astype(np.float32))
    fast = replan(net, features, free, held, values, extra)
    with torch.no_grad():
        kappa = net.cost(features) + extra
        edges = [(dr, dc, w * 0.5 * (kappa + _shift(kappa, dr, dc, float("inf")))) for dr, dc, w in _neighbours(2)]
        kept = torch.where(held & free, values, torch.full_like(kappa, UNREACHED))
        v = kept
        for _ in range(rows * cols):
            new = torch.where(held & free, kept, _bellman_update(v, edges, free, torch.zeros_like(free)))
            if torch.equal(new, v):
                break
            v = new
    assert torch.equal(fast, v)


def test_the_map_policy_goes_round_a_robot_in_its_way():
    """Another robot straight between a robot and its target: with it in the world's crowd, the
    policy's best move no longer heads into it (the static values alone would)."""
    world = world_from_dict(simple_world_dict(obstacles=[], targets=[[17, 10]], starts=[[5, 10]],
                                              field="thesis-general", goal_tolerance=0.75))
    policy = load_policy(SHIPPED["thesis-general"])
    position = np.array([[5.0, 10.0]])
    crowd = world.among([[6.2, 10.0]])

    def best_move(where):
        candidates = moves, _, _ = policy.candidates(where, position)   # its own moves (onto nodes)
        zeros = np.zeros(moves.shape[:2])
        return moves[0, policy.q_values(where, position, zeros, zeros, candidates)[0].argmax()]
    alone, among = best_move(world), best_move(crowd)
    assert alone[0] > 0 and alone[1] == 0                            # straight at the target
    assert among[0] >= 0 and among[1] != 0                           # round the other robot


def test_a_short_imitation_run_beats_the_untrained_network_on_its_validation_set(tmp_path):
    import csv
    # the fixed moves, whose untrained networks this was measured against (moves onto nodes: their own test above)
    config = _tiny_map_config(total_steps=40, eval_every=40, log_every=5, checkpoint_every=40, seed=1, map_moves="fine")
    phases = _phases(config)
    # untrained networks of three initialisations, on the validation set the run is judged on (measured:
    # 6/8, 2/8 and 3/8 starts reached, 2 to 5 collisions)
    untrained = []
    for seed in (0, 1, 2):
        torch.manual_seed(seed)
        untrained.append(_validation_success(map_network(config), phases[0]))
    result = _fit(config, phases, out_dir=tmp_path)
    assert result.counters.global_step == 40 and result.best is not None
    trained = _validation_success(result.network, phases[0])
    assert trained == result.best                                      # the run's evaluation is this one
    # measured after 40 updates: 8/8, no collision
    assert trained["success"] > max(u["success"] for u in untrained), (trained, untrained)
    assert trained["collisions"] < min(u["collisions"] for u in untrained)
    with open(tmp_path / "train.csv", newline="") as f:
        losses = [float(r["loss"]) for r in csv.DictReader(f) if r["loss"]]
    # the cross-entropy to the teacher falls (measured 1.60 → 1.35 over the 8 logged means)
    assert len(losses) == 8 and losses[-1] < 0.92 * losses[0] and np.mean(losses[-3:]) < np.mean(losses[:3])


def test_an_imitation_run_resumed_from_a_checkpoint_ends_as_one_run_without_a_stop(tmp_path):
    import csv
    every = dict(eval_every=4, checkpoint_every=4, log_every=2, refresh_every=6, seed=2)   # a pool redraw after the stop
    whole = _fit(_tiny_map_config(total_steps=12, **every), _phases(_tiny_map_config(**every)), out_dir=tmp_path / "a")
    first = _fit(_tiny_map_config(total_steps=8, **every), _phases(_tiny_map_config(**every)), out_dir=tmp_path / "b")
    assert first.counters.global_step == 8
    resumed = _fit(_tiny_map_config(total_steps=12, **every), _phases(_tiny_map_config(**every)), out_dir=tmp_path / "b",
                   resume=True)
    assert not resumed.already_finished and resumed.stop_reason == whole.stop_reason == "total_steps 12 reached"
    a, b = whole.network.state_dict(), resumed.network.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert resumed.best == whole.best
    fields = ("global_step", "episodes", "phase", "phase_steps", "pool_draws", "best_step", "top_success", "last_eval_step")
    assert {f: getattr(resumed.counters, f) for f in fields} == {f: getattr(whole.counters, f) for f in fields}
    assert whole.counters.pool_draws == 2
    # the resumed session went on from update 8: the log has each row once, the same as the run's without a stop
    def rows(run):
        with open(tmp_path / run / "train.csv", newline="") as f:
            return [{k: v for k, v in r.items() if k != "wall_time"} for r in csv.DictReader(f)]
    assert [r["global_step"] for r in rows("b")] == [str(s) for s in range(2, 13, 2)]
    assert rows("b") == rows("a")
    # resuming a finished run trains nothing
    again = _fit(_tiny_map_config(total_steps=12, **every), _phases(_tiny_map_config(**every)), out_dir=tmp_path / "b",
                 resume=True)
    assert again.already_finished and again.counters.global_step == 12
