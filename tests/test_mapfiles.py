"""Grid-map readers: ROS map_server maps, map images, MovingAI maps and scenarios, and the rectangle tiling."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

from apf_physics.common.geometry import occupancy_rectangles
from apf_physics.world.io import mapfiles
from apf_physics.errors import WorldError
from apf_physics.world.io.mapfiles import (OccupancyMap, Scenario, read_image, read_movingai_map,
                                  read_movingai_scen, read_ros_map, scenario_points, write_pgm)

grids = hnp.arrays(bool, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12))


def p2(pixels, maxval=255) -> bytes:
    """An ASCII PGM of ``pixels`` (image rows, top first)."""
    pixels = np.asarray(pixels)
    lines = [" ".join(str(v) for v in row) for row in pixels]
    return f"P2\n# a comment\n{pixels.shape[1]} {pixels.shape[0]}\n{maxval}\n".encode() + "\n".join(lines).encode() + b"\n"


def p5(pixels) -> bytes:
    pixels = np.asarray(pixels, dtype=np.uint8)
    return f"P5\n{pixels.shape[1]} {pixels.shape[0]}\n255\n".encode() + pixels.tobytes()


def png(pixels) -> bytes:
    ok, data = cv2.imencode(".png", np.asarray(pixels))
    assert ok
    return data.tobytes()


def write(path, data: bytes):
    path.write_bytes(data)
    return path


# Image rows top first: 0 black (occupied), 254 white (free), 205 grey (unknown), 100 dark grey.
PIXELS = np.array([[0, 254, 205],
                   [100, 254, 0]], dtype=np.uint8)


# -- images ------------------------------------------------------------------------------

@pytest.mark.parametrize("encode", [p2, p5, png], ids=["P2", "P5", "PNG"])
def test_image_thresholds_like_map_server(tmp_path, encode):
    path = write(tmp_path / "map.img", encode(PIXELS))
    # Bottom row first: the image's second line, then its first.
    assert read_image(path).tolist() == [[True, False, True], [True, False, True]]   # grey 205 is unknown: occupied
    # negate: white is occupied, black free; 205 and 100 (p 0.80 and 0.39) are not free.
    assert read_image(path, negate=1).tolist() == [[True, True, False], [False, True, True]]
    # A free_thresh above 205's p (0.196...) frees it; 100 (p 0.61) is free below 0.7.
    assert read_image(path, free_thresh=0.25).tolist() == [[True, False, True], [True, False, False]]
    assert read_image(path, free_thresh=0.7, occupied_thresh=0.9).tolist() == [[False, False, True],
                                                                                [True, False, False]]
    # mode "scale" reads as trinary here.
    assert read_image(path, mode="scale").tolist() == read_image(path).tolist()


def test_image_raw_mode(tmp_path):
    path = write(tmp_path / "raw.pgm", p5([[0, 49, 50, 100, 255]]))
    assert read_image(path, mode="raw").tolist() == [[False, False, True, True, True]]


def test_image_orientation(tmp_path):
    pixels = np.full((4, 5), 254, np.uint8)
    pixels[0, 0] = 0   # the image's top-left pixel
    for name, data in (("a.pgm", p5(pixels)), ("a.png", png(pixels))):
        occupied = read_image(write(tmp_path / name, data))
        assert occupied.shape == (4, 5)
        assert np.argwhere(occupied).tolist() == [[3, 0]]


@settings(max_examples=30)
@given(grid=grids)
def test_write_pgm_reads_back(tmp_path_factory, grid):
    path = tmp_path_factory.mktemp("pgm") / "map.pgm"
    write_pgm(path, grid)
    assert path.read_bytes().startswith(b"P5")
    back = read_image(path)
    assert back.dtype == bool and back.flags.c_contiguous
    np.testing.assert_array_equal(back, grid)


def test_colour_alpha_and_16_bit_images(tmp_path):
    bgr = np.zeros((1, 3, 3), np.uint8)
    bgr[0, 0] = (254, 254, 254)          # white: free
    bgr[0, 1] = (0, 0, 254)              # red: mean 84.7, p 0.67: occupied
    bgr[0, 2] = (254, 254, 200)          # mean 236: free
    assert read_image(write(tmp_path / "c.png", png(bgr))).tolist() == [[False, True, False]]
    bgra = np.dstack([bgr, np.array([[0, 255, 0]], np.uint8)])   # alpha ignored
    assert read_image(write(tmp_path / "ca.png", png(bgra))).tolist() == [[False, True, False]]
    deep = np.array([[0, 65535, 205 * 257]], np.uint16)
    assert read_image(write(tmp_path / "d.png", png(deep))).tolist() == [[True, False, True]]
    assert read_image(write(tmp_path / "d.pgm", p2([[0, 1000, 800]], maxval=1000))).tolist() == [[True, False, True]]
    big_endian = b"P5\n2 1\n1000\n" + struct.pack(">HH", 1000, 0)
    assert read_image(write(tmp_path / "e.pgm", big_endian)).tolist() == [[False, True]]
    small_maxval = b"P5\n2 1\n15\n" + bytes([15, 0])   # scaled: 15 is white
    assert read_image(write(tmp_path / "f.pgm", small_maxval)).tolist() == [[False, True]]


def test_bmp(tmp_path):
    ok, data = cv2.imencode(".bmp", PIXELS)
    assert ok
    assert read_image(write(tmp_path / "m.bmp", data.tobytes())).tolist() == [[True, False, True],
                                                                            [True, False, True]]


@pytest.mark.parametrize("data, message", [
    (b"this is not an image", "not an image (PGM, PNG or BMP)"),
    (b"GIF89a\x01\x00\x01\x00", "not an image (PGM, PNG or BMP)"),
    (b"P5\n3 2\n255\n\x00", "cut short"),
    (b"P2\n3 2\n255\n0 0 0\n0 0\n", "cut short"),
    (b"P2\n2 1\n255\n0 x\n", "not a whole number"),
    (b"P2\n2 1\n255\n0 300\n", "over its maxval"),
    (b"P5\nwide 1\n255\n", "width"),
    (b"P5\n0 4\n255\n", "empty"),
    (b"P5\n2 1\n70000\n", "maxval"),
    (png(PIXELS)[:40] + b"\x00" * 30, "OpenCV could not decode it"),
])
def test_bad_images(tmp_path, data, message):
    path = write(tmp_path / "bad.png", data)
    with pytest.raises(WorldError) as error:
        read_image(path)
    text = str(error.value)
    assert text.startswith(f"{path}: ") and message in text and "\n" not in text


def test_missing_image_and_directory(tmp_path):
    with pytest.raises(WorldError, match="no such map image file"):
        read_image(tmp_path / "nope.pgm")
    with pytest.raises(WorldError, match="a directory"):
        read_image(tmp_path)


def png_header_only(width: int, height: int) -> bytes:
    """A PNG signature and IHDR claiming a size, and no pixels."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))


@pytest.mark.parametrize("data", [b"P5\n100 100\n255\n", b"P2 100\n100 255\n", png_header_only(100, 100),
                                  b"BM" + b"\x00" * 12 + struct.pack("<Iii", 40, 100, -100)],
                         ids=["P5", "P2", "PNG", "BMP"])
def test_size_limit_from_the_header(tmp_path, monkeypatch, data):
    monkeypatch.setattr(mapfiles, "MAX_MAP_CELLS", 9_999)
    path = write(tmp_path / "huge", data)   # no pixels at all: refused before decoding
    with pytest.raises(WorldError, match=r"100 x 100 = 10,000 cells, over the limit of 9,999") as error:
        read_image(path)
    assert "\n" not in str(error.value)


def test_file_size_limit(tmp_path, monkeypatch):
    monkeypatch.setattr(mapfiles, "MAX_MAP_FILE_BYTES", 100)
    path = write(tmp_path / "big.pgm", p5(np.zeros((20, 20))))
    with pytest.raises(WorldError, match="over the limit of 100"):
        read_image(path)


# -- ROS map_server YAML -----------------------------------------------------------------

def test_ros_map_with_relative_image(tmp_path):
    (tmp_path / "maps" / "images").mkdir(parents=True)
    write(tmp_path / "maps" / "images" / "lab.pgm", p5(PIXELS))
    yaml_path = tmp_path / "maps" / "lab.yaml"
    yaml_path.write_text("image: images/lab.pgm\nresolution: 0.05\norigin: [-1.5, 2.0, 0.0]\n"
                         "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")
    grid = read_ros_map(yaml_path)
    assert isinstance(grid, OccupancyMap)
    assert grid.occupied.tolist() == [[True, False, True], [True, False, True]]
    assert grid.cell == 0.05 and grid.origin == (-1.5, 2.0) and grid.source == str(yaml_path)
    assert grid.size == pytest.approx((0.15, 0.1))


def test_ros_map_defaults_and_negate(tmp_path):
    write(tmp_path / "m.png", png(PIXELS))
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 1\norigin: [0, 0, 0]\nnegate: 1\n")
    assert read_ros_map(tmp_path / "m.yaml").occupied.tolist() == [[True, True, False], [False, True, True]]


def test_ros_map_reports_every_problem_at_once(tmp_path):
    yaml_path = tmp_path / "bad.yaml"
    yaml_path.write_text("image: missing.pgm\nresolution: -0.05\norigin: [0, 0, 1.57]\n"
                         "occupied_thres: 0.65\nfree_thresh: 0.7\n")
    with pytest.raises(WorldError) as error:
        read_ros_map(yaml_path)
    lines = str(error.value).splitlines()
    assert all(line.startswith(f"{yaml_path}: ") for line in lines)
    text = "\n".join(line[len(str(yaml_path)) + 2:] for line in lines)
    assert "keys: 1 unknown key (did you mean 'occupied_thresh'?)" in text   # (a file's keys are not shown)
    assert "origin[2]: a rotated map (yaw 1.57) is not supported; rotate the image instead" in text
    assert "resolution: expected a positive finite number" in text
    assert f"image: no such file {tmp_path / 'missing.pgm'}" in text
    assert "free_thresh: must be below occupied_thresh (0.65), got 0.7" in text
    assert len(lines) == 5


@pytest.mark.parametrize("text, message", [
    ("image: m.pgm\norigin: [0, 0, 0]\n", "resolution: missing"),
    ("image: m.pgm\nresolution: .nan\norigin: [0, 0, 0]\n", "resolution: expected a positive finite number"),
    ("image: m.pgm\nresolution: true\norigin: [0, 0, 0]\n", "resolution: expected a positive finite number"),
    ("image: m.pgm\nresolution: 1\norigin: [0, 0]\n", None),
    ("image: m.pgm\nresolution: 1\norigin: 5\n", "origin: expected [x, y, yaw], got an int"),
    ("image: m.pgm\nresolution: 1\norigin: [a, 0, 0]\n", "origin[0]: expected a finite number, got a str"),
    ("image: m.pgm\nresolution: 1\norigin: [0, 0, 0]\nnegate: 2\n", "negate: expected 0 or 1, got an int"),
    ("image: m.pgm\nresolution: 1\norigin: [0, 0, 0]\nfree_thresh: 1.5\n", "free_thresh: expected a number from 0 to 1"),
    ("image: m.pgm\nresolution: 1\norigin: [0, 0, 0]\nmode: trinay\n", "did you mean 'trinary'?"),
    ("image: [1]\nresolution: 1\norigin: [0, 0, 0]\n", "image: expected a file name, got list"),
    ("- a list\n", "expected a mapping"),
    ("image: [unclosed\n", "not valid YAML at line 2"),
    ("image: m.pgm\nresolution: 1.0e308\norigin: [0, 0, 0]\n", "resolution: 1e+308 makes the map infinitely large"),
])
def test_ros_map_problems(tmp_path, text, message):
    write(tmp_path / "m.pgm", p5(PIXELS))
    yaml_path = tmp_path / "m.yaml"
    yaml_path.write_text(text)
    if message is None:
        assert read_ros_map(yaml_path).origin == (0.0, 0.0)
        return
    with pytest.raises(WorldError) as error:
        read_ros_map(yaml_path)
    assert str(error.value).startswith(f"{yaml_path}: ") and message in str(error.value)


def test_ros_map_reads_exponents_without_a_dot(tmp_path):
    # YAML 1.1 (PyYAML) reads 5e-2 as a string; map_server (yaml-cpp) as a number.
    write(tmp_path / "m.pgm", p5(PIXELS))
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 5e-2\norigin: [-1e1, 0, 0]\n")
    grid = read_ros_map(tmp_path / "m.yaml")
    assert grid.cell == 0.05 and grid.origin == (-10.0, 0.0)


def test_ros_map_names_a_broken_image(tmp_path):
    write(tmp_path / "m.pgm", b"not an image at all")
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 1\norigin: [0, 0, 0]\n")
    with pytest.raises(WorldError) as error:
        read_ros_map(tmp_path / "m.yaml")
    assert str(error.value).startswith(f"{tmp_path / 'm.yaml'}: image: {tmp_path / 'm.pgm'}: not an image")


def test_ros_map_image_size_limit(tmp_path, monkeypatch):
    monkeypatch.setattr(mapfiles, "MAX_MAP_CELLS", 5)
    write(tmp_path / "m.pgm", p5(PIXELS))
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 1\norigin: [0, 0, 0]\n")
    with pytest.raises(WorldError, match="3 x 2 = 6 cells, over the limit of 5"):
        read_ros_map(tmp_path / "m.yaml")


# -- MovingAI ----------------------------------------------------------------------------

MOVINGAI = "type octile\nheight 3\nwidth 4\nmap\n@..T\n.GSW\nO.@.\n"


def test_movingai_map(tmp_path):
    path = tmp_path / "m.map"
    path.write_text(MOVINGAI)
    grid = read_movingai_map(path, cell=0.5)
    # Bottom row first: the file's last row, then up.
    assert grid.occupied.tolist() == [[True, False, True, False],
                                      [False, False, False, True],
                                      [True, False, False, True]]
    assert grid.origin == (0.0, 0.0) and grid.cell == 0.5 and grid.size == (2.0, 1.5) and grid.source == str(path)


def test_movingai_orientation_and_line_ends(tmp_path):
    path = tmp_path / "m.map"
    path.write_bytes(b"type octile\r\nheight 2\r\nwidth 3\r\nmap\r\n@..\r\n...\r\n\r\n")
    assert np.argwhere(read_movingai_map(path).occupied).tolist() == [[1, 0]]


@settings(max_examples=30)
@given(grid=grids)
def test_movingai_reads_what_was_written(tmp_path_factory, grid):
    rows = ["".join("@" if cell else "." for cell in row) for row in grid[::-1]]
    path = tmp_path_factory.mktemp("mai") / "m.map"
    path.write_text(f"type octile\nheight {grid.shape[0]}\nwidth {grid.shape[1]}\nmap\n" + "\n".join(rows))
    np.testing.assert_array_equal(read_movingai_map(path).occupied, grid)


@pytest.mark.parametrize("text, message", [
    ("type octile\nwidth 4\nmap\n....\n", "line 3: the header has no height line"),
    ("type octile\nheight 1\nmap\n....\n", "line 3: the header has no width line"),
    ("type octile\nheight three\nwidth 4\nmap\n", "line 2: height: expected a positive whole number"),
    ("type octile\nheight 1\nwidth -4\nmap\n", "line 3: width: expected a positive whole number"),
    ("type octile\nheight 1\nwidth 4\n....\n", "line 4: expected 'type octile'"),
    ("type octile\nheight 1\nwidth 4\n", "no 'map' line"),
    ("type octile\nheight 1\nheight 1\nwidth 4\nmap\n", "line 3: a second 'height' line"),
    ("type octile\nheight 2\nwidth 4\nmap\n....\n...\n", "line 6: a row of 3 characters, expected width 4"),
    ("type octile\nheight 3\nwidth 4\nmap\n....\n....\n", "the map ends after 2 rows, expected height 3"),
    ("type octile\nheight 3\nwidth 4\nmap\n....\n....\n\n\n", "line 7: the map ends after 2 rows, expected height 3"),
    ("type octile\nheight 1\nwidth 4\nmap\n....\n....\n", "line 6: more rows than the height 1"),
])
def test_movingai_map_problems(tmp_path, text, message):
    path = tmp_path / "m.map"
    path.write_text(text)
    with pytest.raises(WorldError) as error:
        read_movingai_map(path)
    assert str(error.value).startswith(f"{path}: ") and message in str(error.value)
    assert "\n" not in str(error.value)


def test_movingai_size_limit_from_the_header(tmp_path, monkeypatch):
    monkeypatch.setattr(mapfiles, "MAX_MAP_CELLS", 1_000)
    path = tmp_path / "m.map"
    path.write_text("type octile\nheight 100\nwidth 20\nmap\n")   # no rows: refused from the header
    with pytest.raises(WorldError, match="20 x 100 = 2,000 cells, over the limit of 1,000"):
        read_movingai_map(path)


def test_movingai_cell_must_be_positive(tmp_path):
    path = tmp_path / "m.map"
    path.write_text(MOVINGAI)
    with pytest.raises(WorldError, match="cell size"):
        read_movingai_map(path, cell=0)


SCEN = ("version 1\n"
        "0\tm.map\t4\t3\t1\t0\t3\t2\t3.41421356\n"
        "\n"
        "1\tm.map\t4\t3\t0\t1\t1\t2\t1.41421356\n")


def test_movingai_scen_and_points(tmp_path):
    (tmp_path / "m.map").write_text(MOVINGAI)
    scen_path = tmp_path / "m.map.scen"
    scen_path.write_text(SCEN)
    scenarios = read_movingai_scen(scen_path)
    assert scenarios == [Scenario(0, "m.map", 4, 3, (1, 0), (3, 2), 3.41421356),
                         Scenario(1, "m.map", 4, 3, (0, 1), (1, 2), 1.41421356)]
    assert [s.line for s in scenarios] == [2, 4] and scenarios[0].source == str(scen_path)
    grid = read_movingai_map(tmp_path / "m.map", cell=2.0)
    start, goal = scenario_points(scenarios[0], grid)
    # (1, 0): second column of the top row -> x = 1.5 cells, y = 2.5 cells; (3, 2): bottom-right cell.
    np.testing.assert_allclose(start, [3.0, 5.0])
    np.testing.assert_allclose(goal, [7.0, 1.0])
    # Both ends are free cells of the map (as a benchmark's always are).
    for point in (start, goal):
        col, row = (point / grid.cell).astype(int)
        assert not grid.occupied[row, col]


def test_scenario_points_use_the_origin(tmp_path):
    grid = OccupancyMap(np.zeros((3, 4), bool), cell=0.5, origin=(10.0, -2.0), source="g")
    start, goal = scenario_points(Scenario(0, "g", 4, 3, (0, 0), (3, 2), 0.0), grid)
    np.testing.assert_allclose(start, [10.25, -0.75])
    np.testing.assert_allclose(goal, [11.75, -1.75])


def test_scenario_for_another_map_is_refused(tmp_path):
    scen_path = tmp_path / "m.scen"
    scen_path.write_text("version 1.0\n\n0 other.map 5 5 0 0 1 1 1.4\n")
    (scen,) = read_movingai_scen(scen_path)
    grid = OccupancyMap(np.zeros((3, 4), bool), cell=1.0, origin=(0.0, 0.0), source="m.map")
    with pytest.raises(WorldError, match=rf"^{scen_path}: line 3: the scenario is for a 5 x 5 map, but m.map is 4 x 3$"):
        scenario_points(scen, grid)


@pytest.mark.parametrize("text, message", [
    ("0\tm.map\t4\t3\t1\t0\t3\t2\t3.4\n", "line 1: expected 'version 1'"),
    ("version 2\n", "line 1: expected 'version 1'"),
    ("", "line 1: empty"),
    ("version 1\n0\tm.map\t4\t3\t1\t0\t3\t2\n", "line 2: expected 9 fields"),
    ("version 1\n\n0\tm.map\t4\tx\t1\t0\t3\t2\t3.4\n", "line 3: height: expected a whole number of at most 9 digits"),
    ("version 1\n0\tm.map\t4\t3\t1\t0\t3\t2\tfar\n", "line 2: optimal_length: expected a non-negative decimal number"),
    ("version 1\n0\tm.map\t4\t3\t4\t0\t3\t2\t3.4\n", "line 2: start_x: 4 is outside the 4 x 3 map"),
    ("version 1\n0\tm.map\t4\t3\t1\t0\t3\t3\t3.4\n", "line 2: goal_y: 3 is outside the 4 x 3 map"),
])
def test_scen_problems(tmp_path, text, message):
    path = tmp_path / "m.scen"
    path.write_text(text)
    with pytest.raises(WorldError) as error:
        read_movingai_scen(path)
    assert str(error.value).startswith(f"{path}: ") and message in str(error.value)


def test_scen_map_names_with_spaces_in_tab_separated_files(tmp_path):
    path = tmp_path / "m.scen"
    path.write_text("version 1\n0\tmy maps/a b.map\t4\t3\t1\t0\t3\t2\t3.4\n")
    assert read_movingai_scen(path)[0].map_name == "my maps/a b.map"


# -- rectangles --------------------------------------------------------------------------

def paint(boxes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """How many rectangles cover each cell."""
    count = np.zeros(shape, int)
    for col0, row0, col1, row1 in boxes:
        assert 0 <= col0 < col1 <= shape[1] and 0 <= row0 < row1 <= shape[0]
        count[row0:row1, col0:col1] += 1
    return count


@settings(max_examples=200)
@given(grid=grids)
def test_rectangles_tile_the_occupied_cells_exactly(grid):
    boxes = occupancy_rectangles(grid)
    assert boxes.dtype.kind == "i" and boxes.shape == (len(boxes), 4)
    np.testing.assert_array_equal(paint(boxes, grid.shape), grid.astype(int))   # covered once, nothing else


@given(rows=st.integers(1, 8), cols=st.integers(1, 8), top=st.integers(0, 5), left=st.integers(0, 5))
def test_a_solid_block_is_one_rectangle(rows, cols, top, left):
    grid = np.zeros((top + rows + 2, left + cols + 3), bool)
    grid[top:top + rows, left:left + cols] = True
    assert occupancy_rectangles(grid).tolist() == [[left, top, left + cols, top + rows]]


def test_rectangles_merge_identical_runs_only():
    grid = np.array([[1, 1, 0, 1],
                     [1, 1, 0, 1],
                     [1, 1, 1, 0]], bool)
    assert occupancy_rectangles(grid).tolist() == [[0, 0, 2, 2], [3, 0, 4, 2], [0, 2, 3, 3]]
    assert occupancy_rectangles(np.zeros((3, 3), bool)).shape == (0, 4)
    assert occupancy_rectangles(np.zeros((0, 0), bool)).shape == (0, 4)


def test_rectangles_of_a_large_grid(tmp_path):
    grid = np.random.default_rng(1).random((2000, 2000)) < 0.3
    grid[99:901, 49:701] = False
    grid[100:900, 50:700] = True
    boxes = occupancy_rectangles(grid)
    area = ((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).sum()
    assert area == grid.sum()
    assert [50, 100, 700, 900] in boxes.tolist()
