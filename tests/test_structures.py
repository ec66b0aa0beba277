"""The structure families (rooms, maze, nested_cups, narrow_gap, dense_clutter, mixed),
and the older families' worlds, which must stay what they were for a seed (held-out and
validation sets are defined by seeds)."""

import hashlib
import json

import numpy as np
import pytest
import yaml

from apf_physics import world_from_dict
from apf_physics.cli import main
from apf_physics.world.generate import (GAP_WIDTH, PATH_SHARE, START_CLEARANCE, STRUCTURE_FAMILIES, STRUCTURE_ROBOT_RADIUS,
                                  TARGET_CLEARANCE, generate_world, step_limit)
from apf_physics.experiments.rollout import default_max_steps
from apf_physics.world.search import reachable, shortest_path_length
from apf_physics.world.io.worldfile import dump_world_yaml
from apf_physics.experiments.worldsets import generate_set
from apf_physics.world.io.units import obstacle_to_file
from apf_physics.world.core import Frame


def fingerprint(world) -> str:
    """A short hash of everything a generated world is made of (independent of the YAML layout)."""
    data = {"size": list(map(float, world.size)), "robot_radius": world.robot_radius,
            "obstacles": [obstacle_to_file(Frame(), o) for o in world.obstacles], "targets": world.targets.tolist(),
            "starts": world.starts.tolist(),
            "formations": [[t.start.tolist(), t.target.tolist()] for t in world.formations]}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=float).encode()).hexdigest()[:16]


# Computed from the generator as it was before the structure families were added (commit 0c147c3)
# (rng = default_rng(2024), one world on a 50 x 50 map, then one on a 100 x 100 map, 3 starts).
BEFORE = {
    "point": ["e800907efdfc83cc", "ba72f4a69da33b2c"], "line": ["afd4004bd9d4542d", "fa4f2076ad12c364"],
    "two_points": ["b84b25222f552603", "6533f13c8acbc16c"], "concave": ["a8bd77a2a8b7c961", "faf7faf2d20856c7"],
    "bent_line": ["2a025f322c1d9d9c", "7467edc74d4c9df9"], "clutter": ["270698e0001852a7", "a88363990cfd08ba"],
    "moving": ["3c3b86ff9ef5fbbf", "a1ce1b077dc3bb99"], "crossing": ["dde742433d8a414e", "0058ddd26fc9ddfe"],
}


@pytest.mark.parametrize("family", sorted(BEFORE))
def test_older_families_draw_the_same_worlds_as_before(family):
    rng = np.random.default_rng(2024)
    assert [fingerprint(generate_world(family, rng, size=s, n_starts=3)) for s in (50, 100)] == BEFORE[family]


@pytest.fixture(scope="module")
def worlds50():
    return {family: [generate_world(family, np.random.default_rng(seed), n_starts=3) for seed in (0, 1)]
            for family in STRUCTURE_FAMILIES}


def check_world(world, size: float, n_starts: int = 3) -> None:
    """What every structure world promises: valid, every start hidden from the target, solvable, short enough."""
    assert tuple(world.size) == (size, size)
    assert world.robot_radius == STRUCTURE_ROBOT_RADIUS
    assert len(world.starts) == n_starts and len(world.targets) == 1
    target = world.targets[0]
    assert world.clearance(target[None])[0] >= TARGET_CLEARANCE
    assert np.all(world.clearance(world.starts) >= START_CLEARANCE)
    limit = PATH_SHARE * default_max_steps(world)
    for start in world.starts:
        assert reachable(world, start)
        assert shortest_path_length(world, start) < limit
        # behind a structure as seen from the target: the straight way is blocked for the robot
        assert world.path_clearance(start[None], target[None], 0.05)[0] < world.robot_radius
    again = world_from_dict(yaml.safe_load(dump_world_yaml(world)))
    assert fingerprint(again) == fingerprint(world)


@pytest.mark.parametrize("family", STRUCTURE_FAMILIES)
def test_structure_worlds_are_valid_and_every_start_is_solvable(family, worlds50):
    for world in worlds50[family]:
        assert world.name == family
        check_world(world, 50)


@pytest.mark.parametrize("family", STRUCTURE_FAMILIES)
def test_structure_worlds_are_deterministic_for_a_seed_and_vary_between_seeds(family, worlds50):
    first, second = worlds50[family]
    assert dump_world_yaml(generate_world(family, np.random.default_rng(0), n_starts=3)) == dump_world_yaml(first)
    assert fingerprint(first) != fingerprint(second)


def test_structures_are_what_the_families_promise(worlds50):
    for world in worlds50["narrow_gap"]:
        left, right = (o.vertices for o in world.obstacles)
        gap = np.min(np.hypot(*(left[:, None] - right[None]).transpose(2, 0, 1)))
        assert GAP_WIDTH[0] - 0.01 <= gap <= GAP_WIDTH[1] + 0.01
        # the wall runs from edge to edge: the gap is the only way through
        ends = np.vstack([left, right])
        assert np.sum(np.any((ends <= 1e-6) | (ends >= 50 - 1e-6), axis=1)) >= 2
    for world in worlds50["dense_clutter"]:
        assert 18 <= len(world.obstacles) <= 32
    for world in worlds50["nested_cups"]:
        assert len(world.obstacles) in (2, 3)
    for family in ("rooms", "maze", "mixed"):
        assert all(len(world.obstacles) >= 4 for world in worlds50[family])


def test_a_100_by_100_world_mixing_structures():
    world = generate_world("mixed", np.random.default_rng(3), size=100, n_starts=3)
    check_world(world, 100)
    assert step_limit(100) == default_max_steps(world) == 800


def test_step_limit_is_the_rollouts_default(worlds50):
    assert step_limit(50) == default_max_steps(worlds50["maze"][0]) == 400


def test_generated_set_labels_traps_and_most_starts_trap_gradient_descent(tmp_path):
    manifest = generate_set(list(STRUCTURE_FAMILIES), count=6, seed=3, out=tmp_path, n_starts=3)
    starts = [s for w in manifest["worlds"] for s in w["starts"]]
    assert len(starts) == 18 and {w["family"] for w in manifest["worlds"]} == set(STRUCTURE_FAMILIES)
    assert all(isinstance(s["gradient_trapped"], bool) and s["astar_length"] < 0.6 * 400 for s in starts)
    assert manifest["summary"]["gradient_trapped_rate"] >= 0.6   # measured: about 0.9


def test_generate_command_makes_structures_on_a_100_by_100_map(tmp_path, capsys):
    out = tmp_path / "set"
    assert main(["generate", "--family", "narrow_gap,nested_cups", "--count", "2", "--size", "100",
                 "--starts", "2", "--no-label", "--out", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["size"] == 100 and [w["family"] for w in manifest["worlds"]] == ["narrow_gap", "nested_cups"]
    assert all(s["astar_length"] < 0.6 * 800 for w in manifest["worlds"] for s in w["starts"])
    assert "wrote 2 worlds, 4 starts" in capsys.readouterr().out
