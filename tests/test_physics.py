"""Physics: contacts are logged, robots move as commanded, and nothing tunnels through walls."""

import math
import os

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import pymunk
import pymunk.batch
import pytest
from hypothesis import assume

from apf_physics import UserError, WorldError, load_world, world_from_dict
from apf_physics.sim.physics import Physics
from apf_physics.common.geometry import triangulate
from apf_physics.common.geometry import polygon_area
from conftest import simple_world_dict
from contacts_check import assert_contacts_hold


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
    except WorldError:
        world = None   # the random polygon was degenerate after clipping; not a world
    assume(world is not None and len(world.free_cells()) > 0)
    rng = np.random.default_rng(seed)
    start = world.random_free_positions(rng, 1)
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


# -- the fast path: robots in open space skip pymunk, and move exactly as pymunk would move them ---

def _all_through_pymunk(physics):
    physics.needs_physics = lambda moves, bend=None: np.ones(physics.num_robots, bool)
    return physics


@pytest.mark.parametrize("robots_per_slot", [1, 3])
def test_skipping_pymunk_changes_nothing(worlds_dir, robots_per_slot):
    world = load_world(worlds_dir / "fixed20.yaml")
    rng = np.random.default_rng(3)
    starts = world.random_free_positions(rng, 12 * robots_per_slot, margin=0.6)
    fast = Physics([world] * 12, robots_per_slot)
    slow = _all_through_pymunk(Physics([world] * 12, robots_per_slot))
    for physics in (fast, slow):
        physics.place(np.arange(len(starts)), starts)
    skipped = 0
    for _ in range(40):
        moves = rng.uniform(-1, 1, (len(starts), 2))
        skipped += int((~fast.needs_physics(moves * fast.control_dt)).sum())
        log_fast, log_slow = fast.step(moves), slow.step(moves)
        # a robot that touched something may end 1e-4 apart: chipmunk's solver takes its contacts in
        # an order that the other bodies in the space (the robots sent to pymunk) can change
        touched = log_fast.any | log_slow.any
        np.testing.assert_array_equal(fast.positions[~touched], slow.positions[~touched])   # to the bit
        np.testing.assert_allclose(fast.positions[touched], slow.positions[touched], atol=1e-3)
        np.testing.assert_array_equal(log_fast.pairs, log_slow.pairs)
        where = slow.positions[touched]
        for physics in (fast, slow):   # both go on from the same state
            physics.place(np.flatnonzero(touched), where)
    assert skipped > 100   # the fast path was taken, not only pymunk


def test_one_robot_steps_as_a_robot_of_a_batch(worlds_dir):
    """A lone robot and the same robot as one of a batch (its neighbour elsewhere in its own slot)
    take the same steps and contacts to the bit, through pymunk or not: one step path, whatever N."""
    world = load_world(worlds_dir / "fixed20.yaml")
    rng = np.random.default_rng(5)
    one, batch = Physics([world]), Physics([world, world])
    free = through = 0
    for episode in range(30):
        start = world.random_free_positions(rng, 2, margin=0.4)
        one.place([0], start[:1])
        batch.place([0, 1], start)
        for _ in range(25):
            v = rng.uniform(-1, 1, (2, 2)) * rng.choice([1.0, 1.5])   # some beyond the top speed
            log_one, log_batch = one.step(v[:1]), batch.step(v)
            free += not one.in_pymunk[0]
            through += bool(one.in_pymunk[0])
            np.testing.assert_array_equal(one.positions[0], batch.positions[0])
            np.testing.assert_array_equal(log_one.pairs, log_batch.pairs[log_batch.pairs[:, 0] == 0])
            if log_one.touched or log_batch.touched:
                break
    assert free > 150 and through > 10   # both ways were taken


def test_one_robot_is_placed_as_a_batch_places_it(worlds_dir):
    """A lone robot and a robot of a batch placed at the same point end at the same place, to the
    bit, edges and obstacles' sides included, and a centre inside an obstacle is refused by both."""
    world = load_world(worlds_dir / "fixed20.yaml")
    rng = np.random.default_rng(3)
    one, batch = Physics([world]), Physics([world, world])
    points = np.concatenate([world.random_free_positions(rng, 40, margin=0.0),
                             rng.uniform(0.0, 0.3, (10, 2)),                       # against the map's corner
                             world.random_free_positions(rng, 10, margin=0.4)])
    pushed = 0
    for p in points:
        try:
            batch.place([0], p[None])
        except UserError:
            with pytest.raises(UserError):
                one.place([0], p[None])
            continue
        one.place([0], p[None])
        np.testing.assert_array_equal(one.positions, batch.positions[:1])
        pushed += bool(np.any(one.positions[0] != p))
    assert pushed >= 5   # robots placed over an edge were moved off it, by both


def test_needs_physics_is_conservative(worlds_dir):
    # every robot the test lets skip pymunk keeps clear of everything along its whole move
    world = load_world(worlds_dir / "fixed20.yaml")
    rng = np.random.default_rng(0)
    physics = Physics([world] * 400)
    positions = world.random_free_positions(rng, 400)
    physics.place(np.arange(400), positions)
    moves = rng.uniform(-1, 1, (400, 2)) * 1.4
    free = ~physics.needs_physics(moves)
    t = np.linspace(0, 1, 101)
    path = positions[free, None, :] + t[None, :, None] * moves[free, None, :]
    clearance = world.clearance(path.reshape(-1, 2)).reshape(len(path), -1).min(axis=1)
    assert free.sum() > 100
    assert np.all(clearance > world.robot_radius)


def test_pymunk_batch_behaves_as_the_physics_assumes():
    """pymunk.batch is experimental: if its rows or fields change, fail here, loudly."""
    space = pymunk.Space()
    space.collision_persistence = 1
    wall = pymunk.Body(body_type=pymunk.Body.STATIC)
    space.add(wall, pymunk.Poly(wall, [(5, 0), (6, 0), (6, 10), (5, 10)]))
    bodies = []
    for k in range(6):
        body = pymunk.Body(1.0, math.inf)
        space.add(body, pymunk.Circle(body, 0.25))
        body.position = (1.0 + 0.5 * k, 1.0 + k)
        bodies.append(body)
    buffer = pymunk.batch.Buffer()
    pymunk.batch.get_space_bodies(space, pymunk.batch.BodyFields.BODY_ID | pymunk.batch.BodyFields.POSITION, buffer)
    ids = np.frombuffer(buffer.int_buf(), dtype=np.uintp)
    rows = np.frombuffer(buffer.float_buf()).reshape(-1, 2)
    assert set(ids.tolist()) == {b.id for b in bodies} | {wall.id}    # static bodies are rows too
    for body_id, row in zip(ids.tolist(), rows):
        body = next((b for b in bodies if b.id == body_id), None)
        if body is not None:
            assert tuple(row) == tuple(body.position)
    velocities = np.zeros((len(ids), 2))
    velocities[ids == bodies[-1].id] = (2.0, 0.0)
    write = pymunk.batch.Buffer()
    write.set_float_buf(velocities.reshape(-1))
    pymunk.batch.set_space_bodies(space, pymunk.batch.BodyFields.VELOCITY, write)
    assert tuple(bodies[-1].velocity) == (2.0, 0.0) and tuple(bodies[0].velocity) == (0.0, 0.0)
    # arbiters: the body ids of the pairs touching after a step, and only those
    bodies[0].position, bodies[0].velocity = (4.8, 5.0), (2.0, 0.0)
    space.step(0.1)
    arbiters = pymunk.batch.Buffer()
    pymunk.batch.get_space_arbiters(space, pymunk.batch.ArbiterFields.BODY_A_ID | pymunk.batch.ArbiterFields.BODY_B_ID,
                                    arbiters)
    pairs = np.frombuffer(arbiters.int_buf(), dtype=np.uintp).reshape(-1, 2)
    assert [set(p) for p in pairs.tolist()] == [{bodies[0].id, wall.id}]
    bodies[0].position, bodies[0].velocity = (2.0, 8.0), (0.0, 0.0)
    space.step(0.1)
    arbiters.clear()
    pymunk.batch.get_space_arbiters(space, pymunk.batch.ArbiterFields.BODY_A_ID | pymunk.batch.ArbiterFields.BODY_B_ID,
                                    arbiters)
    assert len(np.frombuffer(arbiters.int_buf(), dtype=np.uintp)) == 0


def test_a_released_proxy_carries_nothing_to_its_next_robot(worlds_dir):
    # a robot pressed into a wall hands its proxy back; the next robot to get it must move as if new
    world = load_world(worlds_dir / "fixed20.yaml")
    physics = Physics([world, world])
    physics.place([0, 1], [[0.3, 10.0], [10.0, 19.6]])
    for _ in range(3):
        physics.step(np.array([[-1.0, 0.0], [0.0, 0.0]]))     # robot 0 pushes into the left wall
    physics.place([0], [[10.0, 10.0]])                         # gone: its proxy is parked
    fresh = Physics([world, world])
    fresh.place([0, 1], [[10.0, 10.0], [10.0, 19.6]])
    for _ in range(4):                                          # robot 1 now needs pymunk (the top wall)
        moves = np.array([[0.0, 0.0], [0.3, 0.5]])
        physics.step(moves)
        fresh.step(moves)
        np.testing.assert_allclose(physics.positions, fresh.positions, atol=1e-12)


def test_a_step_after_a_reset_in_the_open_leaves_pymunk_alone(worlds_dir, monkeypatch):
    # a robot ends an episode against a wall and starts the next in open space: its proxy was taken
    # back at the start, so its next step is a free move, computed without stepping pymunk
    world = load_world(worlds_dir / "fixed20.yaml")
    physics = Physics([world])
    physics.place([0], [[0.3, 10.0]])
    log = physics.step(np.array([[-1.0, 0.0]]))
    assert log.wall[0] and physics.proxies.lent == 1
    physics.place([0], [[10.0, 10.0]])
    assert physics.proxies.lent == 0
    steps = []
    step = pymunk.Space.step
    monkeypatch.setattr(pymunk.Space, "step", lambda space, dt: (steps.append(dt), step(space, dt)))
    log = physics.step(np.array([[0.5, 0.25]]))
    assert not steps and not log.any[0]
    fresh = Physics([world])
    fresh.place([0], [[10.0, 10.0]])
    fresh.step(np.array([[0.5, 0.25]]))
    np.testing.assert_array_equal(physics.positions, fresh.positions)


def test_the_pool_counts_the_proxies_lent(worlds_dir):
    world = load_world(worlds_dir / "fixed20.yaml")
    rng = np.random.default_rng(5)
    physics = Physics([world] * 16)
    physics.place(np.arange(16), world.random_free_positions(rng, 16, margin=0.6))
    for _ in range(60):
        log = physics.step(rng.uniform(-1.4, 1.4, (16, 2)))
        assert physics.proxies.lent == np.count_nonzero(physics.in_pymunk)
        touched = np.flatnonzero(log.any)
        physics.place(touched, world.random_free_positions(rng, len(touched), margin=0.6))
        assert physics.proxies.lent == np.count_nonzero(physics.in_pymunk)


# -- crowds and spawns: nothing pushes a robot through a wall -----------------------------------

def _thin_wall_world(thickness=0.001):
    return world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19.5, 19.5]],
                            "obstacles": [{"polygon": [[0, 10], [20, 10], [20, 10 + thickness], [0, 10 + thickness]]}]})


@pytest.mark.parametrize("robots", [2, 3, 6, 12])
def test_robots_placed_on_one_point_are_separated_without_crossing(robots):
    world = _thin_wall_world()
    for angle in np.linspace(0, np.pi, 5):
        physics = Physics([world], robots_per_slot=robots)
        point = [10 + 0.01 * np.cos(angle), 10.001 + 0.26]
        physics.place(np.arange(robots), np.tile(point, (robots, 1)))
        p = physics.positions
        gaps = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1)) + np.eye(robots)
        assert gaps.min() >= 2 * world.robot_radius
        assert np.all(world.clearance(p) >= world.robot_radius)
        for _ in range(20):
            physics.step(np.zeros((robots, 2)))
        assert np.all(physics.positions[:, 1] > 10.001), "a robot ended on the far side of the wall"


def test_a_centre_placed_inside_an_obstacle_is_refused():
    world = _thin_wall_world(thickness=1.0)
    physics = Physics([world], robots_per_slot=2)
    with pytest.raises(UserError, match="inside an obstacle"):
        physics.place([0, 1], [[5.0, 10.5], [8.0, 14.0]])


@settings(max_examples=int(os.environ.get("APF_CROWD_EXAMPLES", 6)), deadline=None)
@given(st.integers(0, 10_000), st.floats(0.002, 0.05))
def test_a_crowd_pressed_onto_a_thin_wall_never_pushes_through(seed, thickness):
    world = _thin_wall_world(thickness)
    n = 48
    rng = np.random.default_rng(seed)
    physics = Physics([world], robots_per_slot=n)
    physics.place(np.arange(n), np.column_stack([rng.uniform(1, 19, n), rng.uniform(10.4, 14, n)]))
    for _ in range(40):
        before = physics.positions
        physics.step(np.column_stack([rng.uniform(-0.3, 0.3, n), np.full(n, -1.4)]))
        assert np.all(physics.positions[:, 1] > 10 + thickness), "a robot pushed through the wall"
        assert_contacts_hold(physics, before)   # and none ends a step in the wall or another robot


def test_skipping_arbiter_reads_on_untouched_substeps_changes_nothing():
    """With a few robots in pymunk, the physics reads pymunk's arbiters only after substeps in which
    shapes touch (counted by begin/separate callbacks); reading them after every substep (as it
    does with many) gives the same contacts."""
    from apf_physics import load_world
    from apf_physics.control.shield import ACTIONS
    from apf_physics.sim.engine import Stepper

    world = load_world("fixed20")

    def run(always_read: bool):
        rng = np.random.default_rng(0)
        stepper = Stepper([world], 32, max_steps=40)
        if always_read:   # never count: read after every substep
            stepper.physics.count_at_most = -1
        stepper.start(np.arange(32), world.random_free_positions(rng, 32)[:, None, :])
        log = []
        for _ in range(120):
            report = stepper.step(ACTIONS[rng.integers(9, size=32)][:, None, :])
            log.append((report.positions.copy(), stepper.outcome.copy(), report.contacts.any.copy()))
            done = np.flatnonzero(stepper.outcome != 0)
            if len(done):
                stepper.start(done, world.random_free_positions(rng, len(done))[:, None, :])
        return log

    fast, slow = run(False), run(True)
    assert sum(int(c.sum()) for _, _, c in slow) > 50          # contacts did happen
    for (p, o, c), (q, u, d) in zip(fast, slow):
        np.testing.assert_array_equal(p, q)
        np.testing.assert_array_equal(o, u)
        np.testing.assert_array_equal(c, d)


@pytest.mark.parametrize("robots_per_slot", [1, 3])
def test_the_contact_log_names_what_each_robot_touched(worlds_dir, robots_per_slot):
    """Every row of a step's contact log is true of where the step left the robots: an obstacle
    named (its index in the world) is within a step's travel of the robot's disc, a wall likewise
    (0 bottom, 1 right, 2 top, 3 left), and two robots said to touch within two steps' travel."""
    world = load_world(worlds_dir / "fixed20.yaml")
    rng = np.random.default_rng(5)
    physics = Physics([world] * 16, robots_per_slot)
    physics.place(np.arange(16 * robots_per_slot), world.random_free_positions(rng, 16 * robots_per_slot, margin=0.6))
    # a robot touches something at some substep and may move on, up to its step's travel, before the step ends
    r, reach = world.robot_radius, physics.max_speed
    w, h = world.size
    kinds = set()
    for _ in range(60):
        log = physics.step(rng.uniform(-1.4, 1.4, (physics.num_robots, 2)))
        p = physics.positions
        for robot, kind, other in log.pairs.tolist():
            kinds.add(kind)
            x, y = p[robot]
            if kind == 0:     # an obstacle, by its index
                d, _ = world.obstacles[other].signed_distance(p[robot][None])
                assert d[0] <= r + reach, (robot, other, d)
            elif kind == 1:   # a wall
                assert [y, w - x, h - y, x][other] <= r + reach, (robot, other, x, y)
            elif kind == 2:   # a robot of its slot
                assert other // robots_per_slot == robot // robots_per_slot
                assert np.hypot(*(p[other] - p[robot])) <= 2 * r + 2 * reach
    assert {0, 1} <= kinds and (robots_per_slot == 1 or 2 in kinds)   # obstacles, walls (and robots) were touched


@pytest.mark.parametrize("seed", range(6))
def test_a_crowds_free_move_test_by_cells_decides_as_the_dense_one(seed):
    from apf_physics.sim.freemove import close_under_touch, crowd_needs, may_touch
    rng = np.random.default_rng(seed)
    n = 200
    p = rng.uniform(0, 12 + 4 * seed, (n, 2))
    dp = rng.choice([-1.0, 0.0, 1.0], (n, 2)) * rng.uniform(0.5, 1.0, (n, 1))
    radius = np.full(n, 0.25)
    needs = rng.random(n) < 0.05
    bend = rng.uniform(0, 0.1, n) if seed % 2 else None
    both, near = may_touch(p[None], dp[None], radius[None, :, None], np.ones((1, n), bool), 2.8,
                           None if bend is None else bend[None])
    dense = close_under_touch(needs[None], both, near)[0]
    assert np.array_equal(crowd_needs(p, dp, radius, needs, 2.8, bend), dense)


def test_the_spatial_hash_is_sized_by_the_worlds_not_the_robots():
    small = world_from_dict(simple_world_dict())
    boxes = [{"polygon": [[x + 0.55, y + 0.55], [x + 0.95, y + 0.55], [x + 0.95, y + 0.95], [x + 0.55, y + 0.95]]}
             for x in np.arange(1, 19, 1.5).tolist() for y in np.arange(1, 19, 1.5).tolist()]
    cluttered = world_from_dict(simple_world_dict(obstacles=boxes, starts=[[1.0, 1.0]], targets=[[18.8, 18.8]]))
    assert Physics([small]).hash_cells == Physics([small] * 64).hash_cells == 256   # the fewest
    assert Physics([cluttered]).hash_cells == Physics([cluttered] * 64).hash_cells == 2 * (len(boxes) + 4)
    grown = Physics([small])
    grown.set_world(0, cluttered)   # a tile made later: the table grows with it
    assert grown.hash_cells == 2 * (len(boxes) + 2 + 8)


def test_a_robot_in_a_corner_moves_alone_as_in_a_batch():
    """Pressed into the corner of two obstacles (two contacts at once, whose order the solver
    follows), a lone robot and 64 robots alone in their slots, driven the same, end bit for bit
    where the lone one does."""
    world = world_from_dict(simple_world_dict(obstacles=[{"polygon": [[5, 5], [8, 5], [8, 9], [5, 9]]},
                                                         {"circle": {"center": [4.4, 8.3], "radius": 0.5}}]))
    lone, batch = Physics([world]), Physics([world] * 64)
    lone.place([0], [[4.0, 6.0]])
    batch.place(np.arange(64), np.tile([[4.0, 6.0]], (64, 1)))
    touched = 0
    for k in range(40):
        v = np.array([[0.7, 0.9]]) if k % 7 else np.array([[-0.3, 0.2]])
        log = lone.step(v)
        batch.step(np.tile(v, (64, 1)))
        touched += bool(log.any[0])
        np.testing.assert_array_equal(batch.positions, np.tile(lone.positions, (64, 1)))
    assert touched > 10
