"""Physics: contacts are logged, robots move as commanded, and nothing tunnels through walls."""

import math
import os

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics import world_from_dict
from apf_physics.physics import Physics
from apf_physics.geometry import triangulate
from apf_physics.geometry import polygon_area
from conftest import simple_world_dict


def test_free_motion_is_exact():
    world = world_from_dict(simple_world_dict())
    physics = Physics([world])
    physics.place([0], [[2.0, 2.0]])
    for _ in range(3):
        log = physics.step(np.array([[1.0, 0.5]]))
        assert not log.any[0]
    np.testing.assert_allclose(physics.positions[0], [5.0, 3.5], atol=1e-9)


def test_contacts_are_logged_by_kind():
    world = world_from_dict(simple_world_dict())
    physics = Physics([world], robots_per_slot=3)
    physics.place([0, 1, 2], [[4.0, 7.0], [0.6, 15.0], [15.0, 15.0]])
    hits = {"obstacle": False, "wall": False}
    for _ in range(3):
        log = physics.step(np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]]))
        hits["obstacle"] |= bool(log.obstacle[0])
        hits["wall"] |= bool(log.wall[1])
        assert not log.any[2]
        assert all(c.robot in (0, 1) for c in log.contacts)
    assert hits == {"obstacle": True, "wall": True}
    kinds = {(c.robot, c.kind, c.other) for c in log.contacts}
    assert (0, "obstacle", 0) in kinds and (1, "wall", 3) in kinds


def test_robot_robot_contact():
    world = world_from_dict(simple_world_dict())
    physics = Physics([world], robots_per_slot=2)
    physics.place([0, 1], [[10.0, 15.0], [11.2, 15.0]])
    log = physics.step(np.array([[1.0, 0.0], [-1.0, 0.0]]))
    assert log.robot.tolist() == [True, True]
    assert any(c.kind == "robot" for c in log.contacts)


def test_slots_are_independent():
    world = world_from_dict(simple_world_dict())
    physics = Physics([world] * 5)
    physics.place(range(5), [[2.0, 2.0]] * 5)
    log = physics.step(np.tile([[1.0, 0.5]], (5, 1)))
    assert not log.any.any()
    np.testing.assert_allclose(physics.positions, [[3.0, 2.5]] * 5, atol=1e-9)


def test_speed_is_clipped():
    world = world_from_dict(simple_world_dict(obstacles=[]))
    physics = Physics([world])
    physics.place([0], [[2.0, 10.0]])
    physics.step(np.array([[10.0, 0.0]]))
    assert physics.positions[0, 0] - 2.0 <= math.sqrt(2) + 1e-9


def test_concave_polygon_triangulation_covers_area():
    l_shape = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], float)
    pieces = triangulate(l_shape)
    assert sum(abs(polygon_area(p)) for p in pieces) == np.float64(polygon_area(l_shape))


def test_swapping_a_slots_world():
    a = world_from_dict(simple_world_dict())
    b = world_from_dict(simple_world_dict(obstacles=[{"polygon": [[2.5, 1], [3, 1], [3, 4], [2.5, 4]]}]))
    physics = Physics([a, a])
    physics.place([0, 1], [[2.0, 2.0], [2.0, 2.0]])
    physics.set_world(1, b)
    log = physics.step(np.array([[1.0, 0.0], [1.0, 0.0]]))
    assert log.obstacle.tolist() == [False, True]


# -- no tunnelling ---------------------------------------------------------------------------

thin_obstacle = st.one_of(
    # a thin rectangle (down to 0.01 thick) at any angle
    st.tuples(st.just("bar"), st.floats(2, 18), st.floats(2, 18), st.floats(0, math.pi), st.floats(1, 6), st.floats(0.01, 0.3)),
    # a point obstacle (radius 0) or a small disc
    st.tuples(st.just("circle"), st.floats(2, 18), st.floats(2, 18), st.floats(0, 0.3), st.just(0.0), st.just(0.0)),
    # a thin sliver triangle
    st.tuples(st.just("sliver"), st.floats(2, 18), st.floats(2, 18), st.floats(0, math.pi), st.floats(1, 6), st.floats(0.01, 0.2)),
)


def make_obstacle(spec):
    kind, x, y, angle, length, width = spec
    if kind == "circle":
        return {"circle": {"center": [x, y], "radius": angle}}
    u = np.array([math.cos(angle), math.sin(angle)])
    n = np.array([-u[1], u[0]])
    c = np.array([x, y])
    if kind == "bar":
        pts = [c - u * length / 2 - n * width / 2, c + u * length / 2 - n * width / 2,
               c + u * length / 2 + n * width / 2, c - u * length / 2 + n * width / 2]
    else:
        pts = [c - u * length / 2, c + u * length / 2, c + n * width]
    pts = np.clip(np.array(pts), 0.5, 19.5)
    return {"polygon": pts.tolist()}


@settings(max_examples=int(os.environ.get("APF_TUNNEL_EXAMPLES", 60)), deadline=None)
@given(st.lists(thin_obstacle, min_size=1, max_size=4), st.floats(0, 2 * math.pi), st.integers(0, 10_000),
       st.floats(0.05, 0.5))
def test_no_tunnelling_at_full_speed(obstacles, heading, seed, radius):
    data = simple_world_dict(obstacles=[make_obstacle(o) for o in obstacles], starts=[], targets=[[0.1, 0.1]],
                             robot_radius=radius)
    try:
        world = world_from_dict(data)
    except Exception:
        return  # the random polygon was degenerate after clipping; not a world
    rng = np.random.default_rng(seed)
    try:
        start = world.random_free_positions(rng, 1)
    except Exception:
        return
    physics = Physics([world])
    physics.place([0], start)
    velocity = np.array([[math.cos(heading), math.sin(heading)]]) * physics.max_speed
    # aim at the nearest obstacle half of the time, so that most runs actually hit something
    if seed % 2 == 0:
        o = world.obstacles[0]
        centre = o.center if hasattr(o, "center") else o.vertices.mean(axis=0)
        direction = centre - start[0]
        if np.hypot(*direction) > 0:
            velocity = direction[None] / np.hypot(*direction) * physics.max_speed
    for _ in range(30):
        physics.step(velocity)
        p = physics.positions
        assert world.obstacle_distance(p)[0] > 0, "robot centre inside an obstacle"
        assert world.edge_distance(p)[0] > 0, "robot centre outside the map"
