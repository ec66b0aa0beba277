"""The range sensor (apf_physics.sensing.lidar): exact against a brute-force reference, one ray and one shape at a time."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apf_physics.common import geometry
from apf_physics.sensing import lidar
from apf_physics.world.field import FieldParams
from apf_physics.sensing.lidar import Lidar, LidarConfig, scan, teammates
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, Motion, PolygonObstacle
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import load_world

from conftest import WORLDS


# -- the brute-force reference -----------------------------------------------------------------

def ray_segment(p, c, a, b) -> float:
    """Distance along the ray ``p + t·c`` to segment ``a–b`` (inf if missed), by a 2×2 solve."""
    m = np.array([[c[0], a[0] - b[0]], [c[1], a[1] - b[1]]])
    if abs(np.linalg.det(m)) < 1e-300:
        return math.inf
    t, u = np.linalg.solve(m, a - p)
    return t if t >= 0 and 0 <= u <= 1 else math.inf


def ray_disc(p, c, centre, r) -> float:
    """Distance along the ray to a disc (0 from inside), inf if missed, by the quadratic's roots."""
    f = p - centre
    if f @ f <= r * r:
        return 0.0
    roots = np.roots([1.0, 2 * (f @ c), f @ f - r * r])
    real = [x.real for x in roots if abs(x.imag) < 1e-12 and x.real >= 0]
    return min(real, default=math.inf)


def outline(vertices):
    return [(vertices[i], vertices[(i + 1) % len(vertices)]) for i in range(len(vertices))]


def reference(world: World, poses, config: LidarConfig, t, others) -> np.ndarray:
    """Ranges, one ray and one shape at a time: every obstacle where :meth:`World.at` puts it (the
    crowd's discs included), grids as their rectangles, the map's edge, the other robots."""
    w, h = world.size
    segments = outline(np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]))
    discs = []
    for obstacle in world.at(t).obstacles:
        if isinstance(obstacle, PolygonObstacle):
            segments += outline(obstacle.vertices)
        elif isinstance(obstacle, CircleObstacle):
            discs.append((obstacle.center, obstacle.radius))
        else:
            for x0, y0, x1, y1 in obstacle.rectangles():
                segments += outline(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
    out = np.empty((len(poses), config.beams))
    for n, (x, y, theta) in enumerate(poses):
        p = np.array([x, y])
        mine = discs + [(q, world.robot_radius) for q in others[n] if not np.isnan(q[0])]
        for k, angle in enumerate(theta + config.angles()):
            c = np.array([math.cos(angle), math.sin(angle)])
            best = min([ray_segment(p, c, a, b) for a, b in segments] + [ray_disc(p, c, q, r) for q, r in mine])
            out[n, k] = min(best, config.max_range)
    return out


# -- worlds ------------------------------------------------------------------------------------

def grid_world() -> World:
    rng = np.random.default_rng(3)
    occupied = rng.random((24, 30)) < 0.12
    occupied[:3, :3] = False
    grid = GridObstacle(occupied, 0.5, (1.0, 2.0))
    return World(name="grid", size=(17.0, 15.0), robot_radius=0.25, goal_tolerance=0.5,
                 field=FieldParams(2, 20, 8, 0.5, 8, 100), obstacles=(grid,), targets=np.array([[15.5, 13.5]]),
                 starts=np.zeros((0, 2)))


@functools.lru_cache(maxsize=None)
def worlds() -> dict[str, World]:
    fixed = load_world(WORLDS / "fixed20.yaml")
    discs = dataclasses.replace(fixed, obstacles=fixed.obstacles + (
        CircleObstacle(np.array([3.0, 12.0]), 0.8), CircleObstacle(np.array([18.0, 12.0]), 0.0),
        CircleObstacle(np.array([10.0, 16.0]), 0.5, Motion(np.array([[4.0, 0.0]]), 0.5)),
        PolygonObstacle(np.array([[2.0, 4.0], [4.0, 4.0], [4.0, 4.4], [2.0, 4.4]]),
                        Motion(np.array([[0.0, 2.0], [3.0, 2.0]]), 0.3, loop=True))))
    crowd = discs.among(np.array([[11.0, 7.0], [6.0, 16.5]]))
    return {"fixed20": fixed, "moving": load_world(WORLDS / "moving_obstacles.yaml"), "discs": discs,
            "crowd": crowd, "grid": grid_world()}


def free_poses(world: World, rng: np.random.Generator, n: int) -> np.ndarray:
    where = world.random_free_positions(rng, n)
    return np.column_stack([where, rng.uniform(-math.pi, math.pi, n)])


# -- exactness ---------------------------------------------------------------------------------

@settings(max_examples=12, deadline=None)
@given(name=st.sampled_from(["fixed20", "moving", "discs", "crowd", "grid"]), seed=st.integers(0, 2**16),
       robots=st.integers(1, 4), beams=st.integers(1, 12), fov=st.sampled_from([360.0, 270.0, 90.0, 7.5]),
       max_range=st.floats(0.5, 30.0), t=st.sampled_from([0.0, 3.0, 17.5, 40.0]), teams=st.integers(1, 3))
def test_ranges_match_brute_force(name, seed, robots, beams, fov, max_range, t, teams):
    world = worlds()[name]
    rng = np.random.default_rng(seed)
    poses = free_poses(world, rng, robots)
    team = rng.integers(teams, size=robots)
    others = teammates(poses[:, :2], team)
    config = LidarConfig(beams=beams, fov=fov, max_range=max_range)
    got = scan(world.at(t), poses, config, others=others)
    assert got.shape == (robots, beams)
    np.testing.assert_allclose(got, reference(world, poses, config, t, others), rtol=0, atol=1e-9)


def test_grid_world_matches():
    """An occupancy grid: its boundary runs (many segments, each robot casting only against those
    within range) against its rectangles, one by one."""
    world = worlds()["grid"]
    assert len(lidar.static_geometry(world).a) > 100
    poses = free_poses(world, np.random.default_rng(0), 4)
    config = LidarConfig(beams=16, max_range=3.0)
    none = np.full((4, 0, 2), np.nan)
    np.testing.assert_allclose(scan(world, poses, config), reference(world, poses, config, 0.0, none), atol=1e-9)


def test_robots_cast_in_parts_read_the_same(monkeypatch):
    world = worlds()["discs"]
    poses = free_poses(world, np.random.default_rng(1), 40)
    config = LidarConfig(beams=32, max_range=6.0)
    others = teammates(poses[:, :2], np.arange(40) % 3)
    whole = scan(world.at(5.0), poses, config, others=others)
    monkeypatch.setattr(lidar, "ROBOTS_PER_CAST", 7)
    np.testing.assert_array_equal(scan(world.at(5.0), poses, config, others=others), whole)


def test_beams_through_corners():
    """Beams exactly through a corner are met by one of its two edges (the angular intervals are widened)."""
    world = World(name="square", size=(4.0, 4.0), robot_radius=0.25, goal_tolerance=0.5,
                  field=FieldParams(2, 20, 8, 0.5, 8, 100), targets=np.array([[3.0, 3.0]]), starts=np.zeros((0, 2)),
                  obstacles=(PolygonObstacle(np.array([[3.0, 1.0], [3.5, 1.0], [3.5, 1.5], [3.0, 1.5]])),))
    ranges = scan(world, np.array([[2.0, 2.0, 0.0]]), LidarConfig(beams=8, max_range=10.0))
    d = 2 * math.sqrt(2)
    np.testing.assert_allclose(ranges, [[2.0, d, 2.0, math.sqrt(2), 2.0, d, 2.0, d]], atol=1e-12)


def test_an_empty_square_reads_its_edges():
    world = World(name="empty", size=(10.0, 6.0), robot_radius=0.25, goal_tolerance=0.5,
                  field=FieldParams(2, 20, 8, 0.5, 8, 100), obstacles=(), targets=np.array([[9.0, 5.0]]),
                  starts=np.zeros((0, 2)))
    ranges = scan(world, np.array([[4.0, 2.0, 0.0]]), LidarConfig(beams=4, max_range=100.0))
    np.testing.assert_allclose(ranges, [[4.0, 2.0, 6.0, 4.0]])     # behind, right, ahead, left
    assert scan(world, np.array([[4.0, 2.0, 0.0]]), LidarConfig(beams=4, max_range=3.0)).max() == 3.0


def test_beam_layout():
    np.testing.assert_allclose(LidarConfig(beams=4).angles(), [-math.pi, -math.pi / 2, 0.0, math.pi / 2])
    np.testing.assert_allclose(LidarConfig(beams=3, fov=90).angles(), [-math.pi / 4, 0.0, math.pi / 4])
    np.testing.assert_allclose(LidarConfig(beams=1, fov=90).angles(), [0.0])
    for bad in ({"beams": 0}, {"fov": 0}, {"fov": 361}, {"max_range": 0}, {"noise": -1}):
        with pytest.raises(ValueError):
            LidarConfig(**bad)


def test_per_robot_steps_match_one_step_at_a_time():
    world = worlds()["moving"]
    poses = free_poses(world, np.random.default_rng(2), 6)
    steps = np.array([0.0, 1.0, 7.0, 7.0, 30.0, 55.5])
    together = scan(world, poses, t=steps)
    apart = np.vstack([scan(world.at(s), poses[i:i + 1]) for i, s in enumerate(steps)])
    np.testing.assert_array_equal(together, apart)


def test_teammates_see_each_other_not_themselves():
    positions = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    mates = teammates(positions, np.array([7, 3, 7, 7]))
    assert mates.shape == (4, 2, 2)
    assert {tuple(q) for q in mates[0]} == {(2.0, 0.0), (3.0, 0.0)}
    assert np.isnan(mates[1]).all()
    assert teammates(positions, np.arange(4)).shape == (4, 0, 2)
    # a robot right in front of another: the beam ahead stops at its rim
    world = worlds()["fixed20"]
    poses = np.array([[10.0, 1.0, 0.0], [11.0, 1.0, math.pi]])
    ranges = scan(world, poses, LidarConfig(beams=2), others=teammates(poses[:, :2], np.zeros(2)))
    np.testing.assert_allclose(ranges[:, 1], [1.0 - world.robot_radius] * 2)


def test_noise_is_seeded_and_clipped():
    world = worlds()["fixed20"]
    poses = free_poses(world, np.random.default_rng(4), 8)
    config = LidarConfig(beams=16, max_range=5.0, noise=0.3)
    a, b = Lidar(config, seed=11).scan(world, poses), Lidar(config, seed=11).scan(world, poses)
    np.testing.assert_array_equal(a, b)
    assert (a >= 0).all() and (a <= 5.0).all()
    clean = scan(world, poses, dataclasses.replace(config, noise=0.0))
    assert not np.array_equal(a, clean) and np.abs(a - clean).max() < 3.0
    with pytest.raises(ValueError):
        scan(world, poses, config)      # noise without a generator


def test_one_cast_per_world():
    sensor = Lidar(LidarConfig(beams=8))
    both = [worlds()["fixed20"], worlds()["grid"]]
    rng = np.random.default_rng(5)
    poses = np.vstack([free_poses(both[0], rng, 3), free_poses(both[1], rng, 2)])
    world_of = np.array([0, 0, 0, 1, 1])
    out = sensor.scan_worlds(both, world_of[[0, 3, 1, 4, 2]], poses[[0, 3, 1, 4, 2]])
    np.testing.assert_array_equal(out[[0, 2, 4]], sensor.scan(both[0], poses[:3]))
    np.testing.assert_array_equal(out[[1, 3]], sensor.scan(both[1], poses[3:]))


# -- the cast's tables and approximations --------------------------------------------------------

def random_world(seed: int) -> World:
    """A world of random convex polygons, discs (one a point), a small occupancy grid, moving
    polygons and discs and a crowd: every kind of shape the sensor casts against."""
    rng = np.random.default_rng(seed)
    size = (float(rng.uniform(12, 20)), float(rng.uniform(10, 16)))
    obstacles = []
    for _ in range(int(rng.integers(1, 5))):
        centre = rng.uniform([2, 2], [size[0] - 2, size[1] - 2])
        angles = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 7))))
        obstacles.append(PolygonObstacle(centre + rng.uniform(0.3, 1.5) * np.column_stack([np.cos(angles), np.sin(angles)])))
    for radius in (float(rng.uniform(0.2, 1.0)), 0.0):
        obstacles.append(CircleObstacle(rng.uniform([1, 1], [size[0] - 1, size[1] - 1]), radius))
    occupied = rng.random((int(rng.integers(4, 12)), int(rng.integers(4, 12)))) < 0.3
    obstacles.append(GridObstacle(occupied, float(rng.uniform(0.3, 0.7)), tuple(rng.uniform(0, 4, 2))))
    obstacles.append(CircleObstacle(rng.uniform([1, 1], [size[0] - 1, size[1] - 1]), 0.4,
                                    Motion(rng.uniform(-3, 3, (2, 2)), 0.4, loop=True)))
    obstacles.append(PolygonObstacle(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.0, 0.5]]) + rng.uniform(2, 8, 2),
                                     Motion(rng.uniform(-3, 3, (1, 2)), 0.3)))
    world = World(name="random", size=size, robot_radius=0.25, goal_tolerance=0.5,
                  field=FieldParams(2, 20, 8, 0.5, 8, 100), obstacles=tuple(obstacles),
                  targets=np.array([[size[0] - 1, size[1] - 1]]), starts=np.zeros((0, 2)))
    return world.among(rng.uniform([0, 0], size, (2, 2)))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("by_cells", [False, True])
def test_random_worlds_match_brute_force(seed, by_cells, monkeypatch):
    """Random poses in random worlds, wide and narrow fields of view, robots at different steps and
    in teams: the candidate beams picked from approximate angles (and segments cut to range,
    grids cut into one-sided runs, the segments a robot tests looked up by its cell) lose no hit."""
    if by_cells:
        monkeypatch.setattr(lidar, "CELLS_ABOVE", 0)
    world = random_world(seed)
    rng = np.random.default_rng(100 + seed)
    poses = free_poses(world, rng, 6)
    others = teammates(poses[:, :2], rng.integers(2, size=6))
    for config in (LidarConfig(beams=48, max_range=float(rng.uniform(2, 12))),
                   LidarConfig(beams=17, fov=200.0, max_range=30.0)):
        for t in (0.0, float(rng.uniform(0, 40))):
            got = scan(world.at(t), poses, config, others=others)
            np.testing.assert_allclose(got, reference(world, poses, config, t, others), rtol=0, atol=1e-9)


def reference_runs(world: World, poses, config: LidarConfig) -> np.ndarray:
    """Ranges against the map's edge and a grid's boundary runs (:func:`geometry.grid_boundary`, seen
    from either side), one ray and one run at a time: what a robot in a wall reads."""
    w, h = world.size
    segments = outline(np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]))
    geo = lidar.static_geometry(world)
    segments += [(a, a + e) for a, e in zip(geo.a, geo.e)]
    out = np.empty((len(poses), config.beams))
    for n, (x, y, theta) in enumerate(poses):
        for k, angle in enumerate(theta + config.angles()):
            c = np.array([math.cos(angle), math.sin(angle)])
            out[n, k] = min([ray_segment(np.array([x, y]), c, a, b) for a, b in segments] + [config.max_range])
    return out


def test_robots_anywhere_on_a_grid_read_its_boundary_from_either_side():
    """A robot in a wall (collided) reads where its beams leave the wall (the one-sided runs are
    turned round for it: it tests all of them, not its cell's); one beyond the grid reads the
    grid's outer boundary."""
    world = worlds()["grid"]
    assert len(lidar._outlines(world).a) > lidar.CELLS_ABOVE
    rng = np.random.default_rng(7)
    grid = world.obstacles[0]
    walls = np.argwhere(grid.occupied)[:8]
    in_walls = (walls[:, ::-1] + rng.uniform(0.1, 0.9, (8, 2))) * grid.cell + np.asarray(grid.origin)
    anywhere = rng.uniform([0.0, 0.0], world.size, (8, 2))
    positions = np.vstack([in_walls, anywhere])
    poses = np.column_stack([positions, rng.uniform(-math.pi, math.pi, len(positions))])
    config = LidarConfig(beams=24, max_range=6.0)
    np.testing.assert_allclose(scan(world, poses, config), reference_runs(world, poses, config), rtol=0, atol=1e-9)


def test_oriented_runs_bound_the_occupied_cells_on_their_left():
    rng = np.random.default_rng(8)
    for _ in range(20):
        occupied = rng.random((int(rng.integers(1, 9)), int(rng.integers(1, 9)))) < rng.uniform(0.1, 0.9)
        a, b = lidar._oriented_runs(occupied)
        pieces = set()
        for start, end in zip(a, b):
            step = (end - start) / np.abs(end - start).sum()        # a unit step along the run
            left = np.array([-step[1], step[0]])
            for j in range(int(np.abs(end - start).sum())):
                middle = start + (j + 0.5) * step
                pieces.add(tuple(np.round(np.sort(np.stack([middle - step / 2, middle + step / 2]), axis=0), 6).ravel()))
                inner = np.floor(middle + left / 2).astype(int)[::-1]      # (row, col) of the cell on the left
                outer = np.floor(middle - left / 2).astype(int)[::-1]
                inside = lambda cell: bool(0 <= cell[0] < occupied.shape[0] and 0 <= cell[1] < occupied.shape[1]
                                           and occupied[cell[0], cell[1]])
                assert inside(inner) and not inside(outer)
        # the same unit sides as the runs grid_boundary cuts
        expected = set()
        for start, end in zip(*geometry.grid_boundary(occupied)):
            step = (end - start) / max(np.abs(end - start).sum(), 1)
            for j in range(int(np.abs(end - start).sum())):
                expected.add(tuple(np.round(np.sort(np.stack([start + j * step, start + (j + 1) * step]), axis=0), 6).ravel()))
        assert pieces == expected


def test_approximate_angles_within_their_bound():
    rng = np.random.default_rng(9)
    x, y = rng.normal(size=(2, 20000)) * np.exp(rng.uniform(-20, 20, (2, 20000)))
    axes = np.array([1.0, -1.0, 0.0, -0.0, 1.0, 1.0, -1.0, 3.0])
    x, y = np.concatenate([x, axes]), np.concatenate([y, np.array([0.0, 0.0, 1.0, -1.0, 1.0, -1.0, -1.0, -0.0])])
    error = np.abs((lidar._angle(x, y) - np.arctan2(y, x) + math.pi) % (2 * math.pi) - math.pi)
    assert error.max() <= lidar.ANGLE_ERROR


def test_inside_a_disc_reads_zero_on_every_beam_of_a_narrow_field():
    """Every beam, however the field of view is laid (the interval of a disc around the robot is the whole turn)."""
    world = worlds()["discs"]
    poses = np.array([[3.2, 12.1, 2.5], [3.0, 11.5, -1.0]])               # in the disc at (3, 12), radius 0.8
    for fov in (360.0, 270.0, 90.0, 7.5):
        assert (scan(world, poses, LidarConfig(beams=9, fov=fov)) == 0).all()


def test_cells_hold_every_segment_a_robot_in_them_can_see():
    """The table of :func:`lidar._cells` against the test of every segment, for robots all over a grid map."""
    world = worlds()["grid"]
    rng = np.random.default_rng(11)
    pos = free_poses(world, rng, 200)[:, :2]
    lines = lidar._outlines(world)
    for reach in (1.5, 6.0):
        every = lidar._seen(pos, lines.a, lines.e, reach, lines.grid, lines.grids)
        by_cell = lidar._seen_static(pos, world, reach)
        assert len(lidar._cells(world, reach).segment) < len(lines.a) * np.prod(lidar._cells(world, reach).shape)
        assert set(zip(*[v.tolist() for v in every[:2]])) == set(zip(*[v.tolist() for v in by_cell[:2]]))
