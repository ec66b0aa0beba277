"""The map policy's values per world: kept while both the world and the policy live, a few per world.

Before, each :class:`MapPolicy` stored its values in the world's cache under a key of its own
and nothing ever removed them: 40 policies asked for their values on one world left 40
entries (and their rasters) in it for the world's lifetime.
"""

from __future__ import annotations

import gc
import pickle
import tracemalloc

import numpy as np

from apf_physics import world_from_dict
from apf_physics.models import MapNetwork, MapPolicy
from apf_physics.models.policy import MAP_VALUES_PER_WORLD, MapValues
from apf_physics.planners import make_planner

from conftest import simple_world_dict

NET = MapNetwork(resolution=2, channels=4, hidden=(8,))


def make_world():
    return world_from_dict(simple_world_dict(size=[40, 40], targets=[[35, 35]], starts=[[2, 2], [3, 30]]))


def ask(policy: MapPolicy, world) -> np.ndarray:
    """What a planner asks each step: action values at the world's starts (values built on the first call)."""
    n, m = len(world.starts), len(policy.moves)
    return policy.q_values(world, world.starts, np.zeros((n, m)), np.zeros((n, m)))


def entry_bytes(world) -> int:
    """NumPy bytes of one policy's values on ``world`` (its map view; the tensor is torch's, untraced)."""
    view, _ = MapPolicy(NET).values(world)
    return sum(a.nbytes for a in (view.features, view.free, view.goal))


def kept(world) -> int:
    return len(world.peek("map_values"))


def grown(step, rounds: int, settle: int = 10) -> int:
    """Bytes traced memory grew from round ``settle`` to round ``rounds`` of ``step(i)``."""
    tracemalloc.start()
    try:
        for i in range(rounds):
            step(i)
            if i + 1 == settle:
                gc.collect()
                base = tracemalloc.get_traced_memory()[0]
        gc.collect()
        return tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()


def test_forty_policies_on_one_world_leave_at_most_a_few_values_in_it():
    world = make_world()
    one = entry_bytes(world)
    ask(MapPolicy(NET), world)                               # the world's own rasters, built once
    entries = world.cache_size

    # policies made and dropped, as a training run's evaluations make them: nothing stays
    growth = grown(lambda i: ask(MapPolicy(NET), world), 40)
    assert world.cache_size == entries and kept(world) == 0
    assert growth < one, f"{growth:,} bytes for 30 policies (one's values: {one:,})"

    # policies that stay alive: the world keeps the latest few
    alive = [MapPolicy(NET) for _ in range(40)]
    for policy in alive:
        ask(policy, world)
        assert world.cache_size == entries and kept(world) <= MAP_VALUES_PER_WORLD
    assert kept(world) == MAP_VALUES_PER_WORLD
    np.testing.assert_array_equal(ask(alive[0], world), ask(alive[-1], world))   # rebuilt alike after eviction


def test_forty_worlds_on_one_policy_leave_nothing_in_the_policy():
    policy = MapPolicy(NET)
    one = entry_bytes(make_world())
    growth = grown(lambda i: ask(policy, make_world()), 40)
    assert growth < one, f"{growth:,} bytes for 30 worlds (one's values: {one:,})"
    assert vars(policy).keys() == {"network", "model", "on_nodes", "moves", "lengths"}   # no cache of its own


def test_views_share_the_values_and_copies_start_without():
    world = make_world()
    policy = MapPolicy(NET)
    view, values = policy.values(world)
    crowded = world.among(np.array([[10.0, 10.0]]))          # another formation's robot: same map, same target
    assert policy.values(crowded)[1] is values and kept(world) == 1
    assert len(pickle.loads(pickle.dumps(world.peek("map_values")))) == 0
    assert isinstance(world.peek("map_values"), MapValues)


def test_a_world_shows_what_it_keeps_and_the_map_values_their_entries():
    """``World.kept`` lists what :meth:`World.cached` built for the world itself (not what is shared
    with its other targets), and ``MapValues.kept`` one entry per policy: what a memory benchmark reads."""
    world = world_from_dict(simple_world_dict(field="thesis-general"))
    before = len(world.kept())
    raster = world.cached("a raster of its own", lambda: np.zeros(4))
    world.cached("shared with other targets", lambda: np.ones(3), static=True)
    assert len(world.kept()) == before + 1 and any(value is raster for value in world.kept())
    planner = make_planner("dqn")
    planner.reset(world, world.starts)
    planner.act(world.starts, np.ones(len(world.starts), bool))
    values = world.peek("map_values")
    assert len(values.kept()) == len(values) == 1
