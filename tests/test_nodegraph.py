"""The robot's configuration space as a node graph, and moves onto its nodes: whatever the graph threads, the robot's moves thread."""

from __future__ import annotations

import numpy as np
import pytest

from apf_physics.control.shield import SAFETY, move_clearance
from apf_physics.world.generate import generate_world
from apf_physics.sim.nodegraph import NEIGHBOURS, NodeGraph, move_count, node_moves, resolution_for
from apf_physics.world.io.worldfile import world_from_dict


def pillars(radius: float, step: float, seed: int = 0):
    """Discs of radius 0.5 on a unit lattice with random holes, and a robot of ``radius`` moving ``step`` per step."""
    rng = np.random.default_rng(seed)
    centres = [[x, y] for x in range(2, 12) for y in range(2, 12) if rng.random() < 0.35]
    return world_from_dict({"size": [14, 14], "robot": {"radius": radius, "step": step}, "field": "thesis-general",
                            "goal_tolerance": 1.0, "obstacles": [{"circle": {"center": c, "radius": 0.5}} for c in centres],
                            "targets": [[13, 13]]})


@pytest.mark.parametrize("radius, step", [(0.6, 0.15), (0.6, 0.3), (0.55, 1.0), (1.2, 0.5), (0.3, 1.0)])
def test_the_shield_admits_every_link_of_the_graph(radius, step):
    world = pillars(radius, step)
    graph = NodeGraph.of(world, resolution_for(world, 2), SAFETY)
    rows, cols = graph.free.shape
    for k, (dr, dc) in enumerate(NEIGHBOURS):
        r, c = np.nonzero(graph.links[k])
        assert graph.free[r, c].all() and graph.free[r + dr, c + dc].all()
        start = graph.grid.to_world(np.column_stack([c, r]).astype(float))
        move = np.array([[dc, dr]], float) / graph.grid.resolution
        room = move_clearance(world, start, move)[:, 0]
        assert (room >= world.robot_radius + SAFETY - 1e-12).all()
    # and the graph is not empty: links exist in every direction
    assert all(graph.links[k].any() for k in range(8))


def test_links_are_left_out_where_the_straight_way_grazes_an_obstacle():
    # a disc between two free nodes that are one diagonal apart: their link passes too close
    world = world_from_dict({"size": [10, 10], "robot": {"radius": 0.3}, "field": "thesis-general",
                             "obstacles": [{"circle": {"center": [5.0, 5.0], "radius": 0.1}}], "targets": [[9, 9]]})
    graph = NodeGraph.of(world, 2, SAFETY)
    # nodes (4.5, 5.0) and (5.0, 5.5) are free (clearance 0.5 - 0.1 = 0.4 >= 0.3 + 0.05), but the
    # link between them passes 0.354 - 0.1 = 0.254 from the disc; (4.5, 5.5) -> (5.0, 5.5) keeps 0.4
    c, r = 9, 10                                                  # node (4.5, 5.0)
    assert graph.free[r, c] and graph.free[r + 1, c + 1]
    assert not graph.links[NEIGHBOURS.index((1, 1)), r, c]
    assert graph.links[NEIGHBOURS.index((0, 1)), r + 1, c]        # (4.5, 5.5) -> (5.0, 5.5): 0.5 from the centre


def test_moves_end_on_free_nodes_within_one_step_and_keep_the_robot_on_them():
    world = pillars(0.6, 0.3)
    graph = NodeGraph.of(world, 2, SAFETY)
    rng = np.random.default_rng(1)
    positions = world.random_free_positions(rng, 50)
    moves, usable, ends = node_moves(graph, positions)
    assert moves.shape == (50, move_count(2), 2) and (np.abs(moves) <= 1.0).all()
    assert usable[:, -1].all() and (moves[:, -1] == 0).all() and (ends[:, -1] == -1).all()
    rows, cols = graph.free.shape
    for i in range(50):
        for m in np.flatnonzero(usable[i, :-1]):
            end = positions[i] + moves[i, m]
            flat, on = graph.node_of(end[None])
            assert on[0] and flat[0] == ends[i, m] and graph.free.ravel()[flat[0]]
    # every free node within one step is a move
    index = graph.grid.to_index(positions[:1])[0]
    near = [(r, c) for r in range(rows) for c in range(cols) if graph.free[r, c]
            and np.all(np.abs(np.array([c, r]) - index) <= graph.grid.resolution + 1e-9)]
    assert len(near) == usable[0, :-1].sum()


def test_the_graph_is_finer_for_a_small_robot_and_within_a_budget():
    big = pillars(0.6, 0.3)            # 2 steps in radius
    small = pillars(0.3, 3.0)          # 0.1 step
    assert resolution_for(big, 2) == 2 and resolution_for(big, 2, 4) == 4
    assert resolution_for(small, 2) == 8 and resolution_for(small, 2, 4) == 8
    tiny = pillars(0.05, 3.0)          # 1/60 step: refined at most 4 times
    assert resolution_for(tiny, 2) == 8
    huge = world_from_dict({"size": [520, 520], "field": "thesis-general", "targets": [[1, 1]]})
    assert resolution_for(huge, 2, 4) == 2     # 4 nodes a step would be 4.3 million


@pytest.mark.parametrize("family", ["pillars", "doors", "rescaled"])
def test_scaled_families_draw_robots_of_every_size_with_reachable_starts(family):
    radii = []
    for seed in range(4):
        world = generate_world(family, np.random.default_rng(seed), size=100, n_starts=2)
        radii.append(world.robot_radius)
        assert len(world.starts) >= 1 and max(world.size) <= 100 + 1e-9
        assert 0.1 - 1e-9 <= world.robot_radius <= 3.0 + 1e-9
    assert max(radii) / min(radii) > 1.5
