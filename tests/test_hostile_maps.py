"""Hostile maps, scenarios and robots: the probe's reproducers, generated small, and fuzzers of
the families it used (images, map YAML, scenario files, robot limits).

The contract for every input: one clear message naming the file (exit status 2 from the
command line), never a traceback, a numpy warning, a C library's own line on standard error,
or the bytes of a file the world names; or an accepted world whose cost is bounded (the
physics' substeps, the distances' work). Timing is never asserted: the costs are bounded by
construction and measured in ``tools/`` (BENCHMARKS.md, "Hostile inputs").
"""

from __future__ import annotations

import math
import os
import re
import warnings
from datetime import timedelta

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from apf_physics import WorldError, load_world, world_from_dict
from apf_physics.cli import main
from apf_physics.common.safefile import CONFINE_VARIABLE
from apf_physics.experiments.movingai import parse_buckets, scenario_trials
from apf_physics.errors import UserError
from apf_physics.world import obstacles as obstacles_module
from apf_physics.world.io import mapfiles
from apf_physics.world.io.mapfiles import (MAX_PROBLEMS, read_image, read_ros_map, read_scenarios,
                                           write_pgm)
from apf_physics.world.kinematics import LIMIT_BOUNDS, MAX_SUBSTEPS, UnicycleLimits, arc_points, physics_substeps
from apf_physics.world.obstacles import GridObstacle

FUZZ = settings(max_examples=int(os.environ.get("APF_FUZZ_EXAMPLES", 150)), deadline=timedelta(seconds=10),
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large])
SECRET = "s3cr3t-t0ken"
"""What a file the world names holds and a message must never show."""

ROBOT = "robot: {radius: 0.2, step: 0.25%s}\nfield: thesis-general\ntargets: [[1.5, 1.5]]\nstarts: [[0.6, 0.6]]\n"


def world_text(grid: str, robot: str = "") -> str:
    """A world file of the issue's shape: ``grid: GRID``, a 0.2 m robot in 0.25 m steps, a target and a start."""
    return f"grid: {grid}\n" + ROBOT % robot


def free_map(folder, name="m", cells=40, resolution=0.05, extra=""):
    """A free ROS map (PGM and YAML) in ``folder``; returns the YAML's path."""
    write_pgm(folder / f"{name}.pgm", np.zeros((cells, cells), bool))
    path = folder / f"{name}.yaml"
    path.write_text(f"image: {name}.pgm\nresolution: {resolution}\norigin: [0, 0, 0]\n{extra}")
    return path


def refused(path, *args, capsys) -> list[str]:
    """The command line's error lines for ``eval PATH ARGS`` (asserting exit status 2 and no traceback)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # a numpy warning leaking out is a failure
        status = main(["eval", str(path), "--planner", "gradient", "--max-steps", "3", "--no-progress", *args])
    err = capsys.readouterr().err
    assert status == 2 and "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert lines and all(line.startswith("apf-physics: error: ") for line in lines), err
    return [line.removeprefix("apf-physics: error: ") for line in lines]


# -- images: a plain PGM decoded without a string per value --------------------------------------

def test_a_plain_pgm_with_a_huge_value_is_refused_in_one_line(tmp_path):
    # the P2 of one 10,000-character value among a million: refused from the value alone
    path = tmp_path / "m.pgm"
    path.write_bytes(b"P2 100 100 255\n" + b"0" * 9999 + b"1\n" + b"254 " * 9999)
    with pytest.raises(WorldError, match=r"m\.pgm: not a valid PGM: a pixel value of more than 18 digits$"):
        read_image(path)


@given(pixels=st.lists(st.integers(0, 65535), min_size=1, max_size=60), width=st.integers(1, 8),
       maxval=st.sampled_from([255, 1000, 65535]), chunk=st.sampled_from([1, 40, 64, 1 << 20]),
       spaces=st.lists(st.sampled_from([" ", "\n", "\t", "\r\n", "  ", " # a comment\n", "\v", "\f"]), min_size=1),
       zeros=st.integers(0, 12), data=st.data())
def test_plain_pgm_values_decode_as_python_reads_them(pixels, width, maxval, chunk, spaces, zeros, data):
    """Any whitespace, comments, leading zeros and chunk boundaries: the values Python's ``int`` reads."""
    pixels = [min(p, maxval) for p in pixels][: (len(pixels) // width) * width] or [0] * width
    height = len(pixels) // width
    text = "".join(("0" * data.draw(st.integers(0, zeros)) + str(p)) + data.draw(st.sampled_from(spaces))
                   for p in pixels)
    blob = f"P2 {width} {height} {maxval}\n".encode() + text.encode()
    original = mapfiles.PLAIN_CHUNK
    mapfiles.PLAIN_CHUNK = chunk
    try:
        width_, height_, maxval_, offset = mapfiles._pgm_header(blob, "m.pgm")
        values = mapfiles._plain_pgm_values(blob, offset - 1, width * height, "m.pgm", "")
    finally:
        mapfiles.PLAIN_CHUNK = original
    assert values.tolist() == pixels


def test_a_p5_header_ended_by_cr_lf_is_not_read_one_pixel_off(tmp_path):
    pixels = np.array([[10, 254, 0, 254]], np.uint8)   # 10 is the LF's byte value: the shift would read it
    crlf = write_to(tmp_path / "crlf.pgm", b"P5\r\n4 1\r\n255\r\n" + pixels.tobytes())
    lf = write_to(tmp_path / "lf.pgm", b"P5\n4 1\n255\n" + pixels.tobytes())
    assert read_image(crlf).tolist() == read_image(lf).tolist() == [[True, False, True, False]]


def write_to(path, data: bytes):
    path.write_bytes(data)
    return path


def broken_images() -> dict[str, bytes]:
    ok, data = cv2.imencode(".png", np.full((8, 8), 200, np.uint8))
    png = bytearray(data.tobytes())
    crc, idat = bytearray(png), bytearray(png)
    crc[29] ^= 0xFF                    # the IHDR chunk's checksum
    idat[-20] ^= 0xFF                  # the compressed pixels
    ok, bmp = cv2.imencode(".bmp", np.full((8, 8), 200, np.uint8))
    return {"truncated png": bytes(png[:40]), "ihdr crc": bytes(crc), "idat": bytes(idat),
            "truncated bmp": bmp.tobytes()[:60]}


@pytest.mark.parametrize("name", list(broken_images()))
def test_broken_images_print_nothing_of_libpng_or_opencv(tmp_path, capfd, name):
    path = write_to(tmp_path / "m.png", broken_images()[name])
    with pytest.raises(WorldError) as error:
        read_image(path)
    out, err = capfd.readouterr()
    assert (out, err) == ("", ""), err              # libpng's and OpenCV's own lines are not printed
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


IMAGE_SEEDS = {"P2": b"P2\n3 2\n255\n0 254 205\n100 254 0\n", "P5": b"P5\n3 2\n255\n\x00\xfe\xcd\x64\xfe\x00",
               "PNG": cv2.imencode(".png", np.array([[0, 254, 205], [100, 254, 0]], np.uint8))[1].tobytes(),
               "BMP": cv2.imencode(".bmp", np.array([[0, 254, 205], [100, 254, 0]], np.uint8))[1].tobytes()}


@st.composite
def mutated_images(draw) -> bytes:
    """An image's bytes with a few edits: bytes flipped, spans cut or repeated, a secret spliced in."""
    data = bytearray(IMAGE_SEEDS[draw(st.sampled_from(sorted(IMAGE_SEEDS)))])
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["flip", "cut", "repeat", "insert", "number"]))
        if kind == "flip" and at < len(data):
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "cut":
            del data[at:at + draw(st.integers(1, 20))]
        elif kind == "repeat":
            data[at:at] = data[at:at + draw(st.integers(1, 40))] * draw(st.integers(1, 30))
        elif kind == "insert":
            data[at:at] = draw(st.sampled_from([SECRET.encode(), b"\r\n", b"#", b" 99999999999999999999 ", b"-1",
                                                b"\xc2\xb2", b"9" * 300, b"0" * 5000, b"\x00" * 9]))
        else:
            data[at:at] = str(draw(st.sampled_from([0, 1, 65535, 65536, 10**9, 2**31]))).encode()
    return bytes(data)


@FUZZ
@given(data=mutated_images())
def test_mutated_images_read_or_are_refused_in_one_line_without_their_bytes(tmp_path, capfd, data):
    path = write_to(tmp_path / "m.img", data)
    capfd.readouterr()
    try:
        grid = read_image(path)
    except WorldError as exc:
        text = str(exc)
        assert text.startswith(f"{path}: ") and "\n" not in text and len(text) < 400
        assert SECRET not in text and "b'" not in text
        event("refused")
    else:
        assert grid.dtype == bool and grid.ndim == 2 and grid.size
        event("read")
    assert capfd.readouterr() == ("", "")


# -- map YAML ------------------------------------------------------------------------------------

def test_a_map_yaml_with_a_key_twice_is_refused_as_world_files_are(tmp_path):
    free_map(tmp_path, extra="resolution: 0.1\n")
    with pytest.raises(WorldError, match=r"m\.yaml: line 4: a key appears twice in one mapping$"):
        read_ros_map(tmp_path / "m.yaml")


MAP_YAML = "image: m.pgm\nresolution: 0.05\norigin: [-1.0, -2.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"


@st.composite
def mutated_map_yaml(draw) -> str:
    text = MAP_YAML
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(text)))
        kind = draw(st.sampled_from(["insert", "delete", "double"]))
        if kind == "insert":
            text = text[:at] + draw(st.sampled_from([
                f"{SECRET}: 1\n", f"image: {SECRET}\n", f"mode: {SECRET}\n", f"origin: [{SECRET}, 0, 0]\n", "[", "{",
                ":", "- ", "&a ", "*a", "!!binary ", "\t", "\n", "1e308", "-1", ".nan", "resolution: 1e300\n",
                "origin: [1e308, 0, 0]\n", "\x00", "\\0", "image: /dev/zero\n", "image: ../../../etc/passwd\n",
                "image: m\\0.pgm\n", "resolution: 0.05\n"])) + text[at:]
        elif kind == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 30)):]
        else:
            end = at + draw(st.integers(1, 60))
            text = text[:end] + text[at:end] * draw(st.integers(1, 20)) + text[end:]
    return text


@FUZZ
@given(text=mutated_map_yaml())
def test_mutated_map_yaml_reads_or_is_refused_without_its_contents(tmp_path, text):
    write_pgm(tmp_path / "m.pgm", np.zeros((20, 20), bool))
    path = tmp_path / "m.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        grid = read_ros_map(path)
    except WorldError as exc:
        lines = str(exc).splitlines()
        assert all(line.startswith(f"{path}: ") and len(line) < 500 for line in lines)
        assert SECRET not in str(exc)
        event("refused")
    else:
        assert grid.occupied.shape == (20, 20) and all(math.isfinite(v) for v in (*grid.origin, *grid.size))
        event("read")


# -- files that a world names --------------------------------------------------------------------

@pytest.fixture
def secret_file(tmp_path):
    """A file outside the world's folder whose text must never appear in a message."""
    path = tmp_path / "outside" / "secret.txt"
    path.parent.mkdir()
    path.write_text(f"root:*:{SECRET}:0:\nmore {SECRET}\n")
    return path


@pytest.mark.parametrize("grid", ["{map: %s}", "{movingai: %s}", "{image: %s, resolution: 0.05, origin: [0, 0, 0]}"])
def test_a_world_naming_a_file_that_is_no_map_never_shows_its_bytes(tmp_path, secret_file, capsys, grid):
    world = tmp_path / "w" / "world.yaml"
    world.parent.mkdir()
    world.write_text(world_text(grid % secret_file))
    lines = refused(world, capsys=capsys)
    assert len(lines) == 1 and str(secret_file) in lines[0] and SECRET not in lines[0] and "root:*" not in lines[0]


@pytest.mark.parametrize("key", ["map", "movingai", "image"])
def test_a_name_that_loops_or_holds_a_nul_is_one_message(tmp_path, capsys, key):
    (tmp_path / "loop").symlink_to("loop")
    rest = ", resolution: 0.05, origin: [0, 0, 0]" if key == "image" else ""
    for name, what in (("loop", "a symbolic link loop"), ('"m\\0.yaml"', "the file name holds a NUL character")):
        world = tmp_path / "world.yaml"
        world.write_text(world_text(f"{{{key}: {name}{rest}}}"))
        (line,) = refused(world, capsys=capsys)
        assert what in line and (f"grid.{key}:" in line or "image:" in line), line


def test_a_world_file_that_loops_is_not_called_missing(tmp_path, capsys):
    (tmp_path / "loop.yaml").symlink_to("loop.yaml")
    (line,) = refused(tmp_path / "loop.yaml", capsys=capsys)
    assert "cannot read the world file" in line and "no such" not in line


def test_paths_may_leave_the_folder_unless_confined(tmp_path, capsys, monkeypatch):
    outside = tmp_path / "maps"
    outside.mkdir()
    free_map(outside)
    folder = tmp_path / "world"
    (folder / "sub").mkdir(parents=True)
    free_map(folder / "sub")
    (folder / "link.yaml").symlink_to(outside / "m.yaml")
    escaping = folder / "sub" / "escape.yaml"                 # a map YAML inside whose image is outside
    escaping.write_text("image: ../../maps/m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    names = {"relative": "../maps/m.yaml", "absolute": str(outside / "m.yaml"), "link": "link.yaml",
             "image outside": "sub/escape.yaml"}
    world = folder / "world.yaml"
    for name in names.values():                               # by default: as written, wherever it is
        world.write_text(world_text(f"{{map: '{name}'}}"))
        assert load_world(world).size == (8.0, 8.0)
    monkeypatch.setenv(CONFINE_VARIABLE, "1")
    world.write_text(world_text("{map: sub/m.yaml}"))
    assert load_world(world).size == (8.0, 8.0)                # inside: still read
    for label, name in names.items():
        world.write_text(world_text(f"{{map: '{name}'}}"))
        (line,) = refused(world, capsys=capsys)
        assert f"is outside the folder {os.path.realpath(folder)}" in line and CONFINE_VARIABLE in line, (label, line)
    assert load_world(world, confine=False).size == (8.0, 8.0)   # the programmatic switch wins
    monkeypatch.setenv(CONFINE_VARIABLE, "perhaps")
    (line,) = refused(world, capsys=capsys)
    assert line.startswith(f"{CONFINE_VARIABLE}: expected 1 or 0")


# -- sizes that overflow ---------------------------------------------------------------------------

def test_a_resolution_or_cell_of_1e300_is_refused_by_the_size_it_makes(tmp_path, capsys):
    free_map(tmp_path, resolution="1.0e+300")
    (tmp_path / "world.yaml").write_text(world_text("{map: m.yaml}"))
    (line,) = refused(tmp_path / "world.yaml", capsys=capsys)
    assert "grid: the map is 1.6e+302 x 1.6e+302 steps of 0.25" in line and "between 1 and 10,000 steps" in line
    (tmp_path / "g.map").write_text("type octile\nheight 4\nwidth 4\nmap\n" + "....\n" * 4)
    (tmp_path / "g.scen").write_text("version 1\n0\tg.map\t4\t4\t0\t0\t3\t3\t4.24\n")
    (line,) = refused(tmp_path / "g.map", "--scen", str(tmp_path / "g.scen"), "--cell", "1e300", capsys=capsys)
    assert "the map is 4e+300 x 4e+300 steps" in line


def test_an_origin_far_from_zero_is_refused_without_a_numpy_warning(tmp_path, capsys):
    write_pgm(tmp_path / "m.pgm", np.zeros((40, 40), bool))
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [1.0e+308, 0, 0]\n")
    (tmp_path / "world.yaml").write_text(world_text("{map: m.yaml}"))
    (line,) = refused(tmp_path / "world.yaml", capsys=capsys)
    assert "origin[0]: at most 1e+09 from 0" in line
    (tmp_path / "far.yaml").write_text("size: [20, 20]\nrobot: {step: 0.25}\nfield: thesis-general\n"
                                       "targets: [[1.0e+308, 1.5]]\nstarts: [[-1.0e+308, 1.0e+308]]\n")
    lines = refused(tmp_path / "far.yaml", capsys=capsys)
    assert all("is far outside the map" in line for line in lines) and len(lines) == 2


# -- a grid's distances bounded by what is near --------------------------------------------------------

def noise(shape, density, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).random(shape) < density


@given(seed=st.integers(0, 10_000), density=st.sampled_from([0.01, 0.2, 0.5, 0.9]),
       reach=st.sampled_from([0.3, 1.0, 2.5]))
@settings(max_examples=30, deadline=None)
def test_a_grid_searched_row_by_row_measures_what_its_index_measures(seed, density, reach):
    occupied = noise((30, 40), density, seed)
    indexed = GridObstacle(occupied, 0.1, (1.0, -2.0))
    searched = GridObstacle(occupied, 0.1, (1.0, -2.0))
    searched._tables.update({("indexed", reach / 0.1): False})   # as a grid over the budget is
    points = np.random.default_rng(seed).uniform([0.5, -2.5], [5.5, 1.5], (300, 2))
    d_index, _ = indexed.signed_distance(points, reach)
    d_rows, near = searched.signed_distance(points, reach)
    np.testing.assert_allclose(d_rows, d_index, atol=1e-9)
    close = np.abs(d_rows) < reach
    np.testing.assert_allclose(np.hypot(*(near[close] - points[close]).T), np.abs(d_rows[close]), atol=1e-9)


def test_a_noise_map_over_the_index_budget_loads_from_what_is_near_its_points(tmp_path, monkeypatch):
    # the 4000 x 4000 map at 2.5 mm, half its pixels occupied, made small: a 400 x 400 one
    # whose boundary would take more registrations than the budget allows (lowered to match)
    occupied = noise((400, 400), 0.5)
    occupied[180:220, 180:220] = False                        # a clearing for the start and the target
    write_pgm(tmp_path / "m.pgm", occupied)
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.0025\norigin: [0, 0, 0]\n")
    (tmp_path / "world.yaml").write_text("grid: {map: m.yaml}\nrobot: {radius: 0.02, step: 0.025}\n"
                                         "goal_tolerance: 0.01\nfield: thesis-general\n"
                                         "targets: [[0.5, 0.52]]\nstarts: [[0.48, 0.5], [0.1, 0.1]]\n")
    monkeypatch.setattr(obstacles_module, "INDEX_BUDGET", 10_000)
    with pytest.raises(WorldError) as error:
        load_world(tmp_path / "world.yaml")
    (line,) = str(error.value).splitlines()                   # the start in the noise, and only it
    assert "starts[1]: [0.1, 0.1] is" in line
    grid = next(o for o in world_from_dict({**yaml.safe_load((tmp_path / "world.yaml").read_text()), "starts": []},
                                           str(tmp_path / "world.yaml")).obstacles if isinstance(o, GridObstacle))
    assert not grid._indexed(3.0 / grid.cell)                 # the row search, not an index of the boundary


# -- scenario files ------------------------------------------------------------------------------

def movingai(folder, name="g", width=8, height=8) -> None:
    (folder / f"{name}.map").write_text(f"type octile\nheight {height}\nwidth {width}\nmap\n"
                                        + ("." * width + "\n") * height)


SCEN_LINE = "{b}\tg.map\t8\t8\t{sx}\t{sy}\t6\t6\t{opt}"


@pytest.mark.parametrize("field", ["1\u00b2", "\u2460", "\u0661", "٣"])
def test_scenario_fields_are_ascii_digits(tmp_path, field):
    path = tmp_path / "g.scen"
    path.write_text("version 1\n" + SCEN_LINE.format(b=0, sx=field, sy=1, opt=7.07) + "\n")
    with pytest.raises(WorldError, match=r"line 2: start_x: expected a whole number of at most 9 digits \(0-9\)$"):
        read_scenarios(path)


def test_every_bad_scenario_line_is_reported_the_first_20_then_a_count(tmp_path):
    path = tmp_path / "g.scen"
    good = SCEN_LINE.format(b=0, sx=1, sy=1, opt=7.07)
    bad = [SCEN_LINE.format(b=0, sx=9, sy=1, opt=7.07), SCEN_LINE.format(b=0, sx=1, sy="x", opt=7.07),
           "0\tg.map\t8\t8\t1\t1\t6\t6", SCEN_LINE.format(b=0, sx=1, sy=1, opt="1e300")]
    lines = ["version 1", good] + bad * 10 + [good]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(WorldError) as error:
        read_scenarios(path)
    report = str(error.value).splitlines()
    assert len(report) == MAX_PROBLEMS + 1 and all(line.startswith(f"{path}: ") for line in report)
    assert report[0].endswith("line 3: start_x: 9 is outside the 8 x 8 map")
    assert report[1].endswith("line 4: start_y: expected a whole number of at most 9 digits (0-9)")
    assert report[2].endswith("line 5: expected 9 fields (bucket map width height start_x start_y goal_x goal_y "
                              "optimal_length), got 8")
    assert report[3].endswith("line 6: optimal_length: 1e+300 is longer than any path on a 8 x 8 map (at most 89.0955)")
    assert report[-1].endswith("and 20 more bad lines (40 in all; the first 20 are listed)")


def test_limit_and_buckets_apply_while_reading(tmp_path):
    path = tmp_path / "g.scen"
    path.write_text("version 1\n" + "".join(SCEN_LINE.format(b=k % 5, sx=1, sy=1, opt=7.07) + "\n" for k in range(5000)))
    read = read_scenarios(path, limit=3)
    assert [s.line for s in read.scenarios] == [2, 2502, 5001] and (read.lines, read.selected) == (5000, 5000)
    read = read_scenarios(path, buckets=(2, 3), limit=4)
    assert read.selected == 2000 and len(read.scenarios) == 4 and {s.bucket for s in read.scenarios} == {2, 3}
    original = mapfiles.MAX_SCENARIOS
    mapfiles.MAX_SCENARIOS = 100
    try:
        with pytest.raises(WorldError, match=r"g\.scen: 5,000 scenarios, over the 100 run at once: take some"):
            read_scenarios(path)
        assert len(read_scenarios(path, limit=100).scenarios) == 100
    finally:
        mapfiles.MAX_SCENARIOS = original


def test_a_scenario_naming_another_map_is_warned_about_in_one_line(tmp_path):
    movingai(tmp_path)
    (tmp_path / "g.scen").write_text("version 1\n" + SCEN_LINE.format(b=0, sx=1, sy=1, opt=7.07) + "\n"
                                     + SCEN_LINE.replace("g.map", "maps/other.map").format(b=0, sx=2, sy=2, opt=5.66)
                                     + "\n" + SCEN_LINE.replace("g.map", "dao\\g.map").format(b=1, sx=2, sy=1, opt=6.2))
    said: list[str] = []
    trials = scenario_trials(tmp_path / "g.map", tmp_path / "g.scen", warn=said.append)
    assert len(trials) == 3 and said == [f"{tmp_path / 'g.scen'}: 1 of 3 scenario lines name a map other than g.map "
                                         f"(the first at line 3); they are run on {tmp_path / 'g.map'}"]


def test_the_ratio_compares_steps_with_steps_at_any_cell(tmp_path):
    movingai(tmp_path, width=16, height=4)
    (tmp_path / "g.scen").write_text("version 1\n0\tg.map\t16\t4\t1\t1\t14\t1\t13\n")
    ratios = []
    for cell in (1.0, 2.0):
        (trial,) = scenario_trials(tmp_path / "g.map", tmp_path / "g.scen", cell=cell)
        assert trial.optimal == 13 * cell and trial.max_steps == math.ceil(39 * cell) + 50
        start, goal = trial.world.starts[0], trial.world.targets[0]
        ratios.append(float(np.hypot(*(goal - start))) / trial.optimal)
    assert ratios[0] == pytest.approx(ratios[1]) == pytest.approx(1.0)


@pytest.mark.parametrize("text, bounds", [("3", (3, 3)), ("2-7", (2, 7)), (" 4-4 ", (4, 4))])
def test_buckets_parse(text, bounds):
    assert parse_buckets(text) == bounds


@pytest.mark.parametrize("text", ["1-", "-3", "a-b", "5-2", "1-2-3", "", "²"])
def test_buckets_that_are_not_a_range_are_refused(text):
    with pytest.raises(UserError, match="--buckets: expected"):
        parse_buckets(text)


@st.composite
def mutated_scen(draw) -> str:
    """A scenario file with a few lines mutated: fields replaced, tabs and spaces swapped, CR LF ends."""
    count = draw(st.integers(1, 12))
    lines = ["version 1"] + [SCEN_LINE.format(b=draw(st.integers(0, 3)), sx=draw(st.integers(0, 7)),
                                              sy=draw(st.integers(0, 7)), opt=f"{draw(st.floats(0, 80)):.4f}")
                             for _ in range(count)]
    for _ in range(draw(st.integers(0, 5))):
        k = draw(st.integers(1, count))
        fields_ = lines[k].split("\t")
        kind = draw(st.sampled_from(["field", "spaces", "drop", "blank", "cr", "map"]))
        if len(fields_) != 9 and kind in ("field", "map"):
            continue
        if kind == "field":
            fields_[draw(st.integers(0, 8))] = draw(st.sampled_from(
                ["", "x", "-1", "+3", "1e3", "1.5", "00000000001", "9999999999", " 7", "7 ", "1\u00b2", "\u2460",
                 "nan", "inf", "1e400", ".5", "5.", "1.2.3", "1_0", "0", SECRET, "8", "80.1", "89.09"]))
            lines[k] = "\t".join(fields_)
        elif kind == "spaces":
            lines[k] = " ".join(fields_)
        elif kind == "drop":
            lines[k] = "\t".join(fields_[:-1])
        elif kind == "blank":
            lines[k] = draw(st.sampled_from(["", "  ", "\t"]))
        elif kind == "cr":
            lines[k] += "\r"
        else:
            fields_[1] = draw(st.sampled_from(["other.map", "a/g.map", "a\\g.map", "g.ma", "g.map ", "my g.map"]))
            lines[k] = "\t".join(fields_)
    return "\n".join(lines) + draw(st.sampled_from(["\n", "", "\n\n", "\r\n"]))


def one_by_one(self, starts, ends, first):
    """:meth:`_ScenLines.block` as the reference: every line on its own, in order."""
    for k in range(len(starts)):
        end = int(ends[k]) - (1 if ends[k] > starts[k] and self.raw[ends[k] - 1] == 13 else 0)
        self.one(int(starts[k]), end, first + k)


@FUZZ
@given(text=mutated_scen(), buckets=st.sampled_from([None, (1, 2)]), limit=st.sampled_from([None, 1, 5]))
def test_mutated_scenario_files_read_as_line_by_line_and_never_show_their_text(tmp_path, monkeypatch, text, buckets,
                                                                               limit):
    """The column-by-column check of well-formed lines agrees with checking every line on its own."""
    path = tmp_path / "g.scen"
    path.write_text(text)

    def outcome():
        try:
            read = read_scenarios(path, buckets, limit, map_name="g.map", map_size=(8, 8))
        except WorldError as exc:
            assert all(line.startswith(f"{path}: ") for line in str(exc).splitlines()) and SECRET not in str(exc)
            return str(exc)
        return (read.lines, read.selected, read.other_maps, read.first_other,
                [(s, s.line) for s in read.scenarios])

    columns = outcome()
    with monkeypatch.context() as patch:
        patch.setattr(mapfiles._ScenLines, "block", one_by_one)
        lines = outcome()
    assert columns == lines
    event("refused" if isinstance(columns, str) else "read")


# -- robots: limits that bound the physics ---------------------------------------------------------

@pytest.mark.parametrize("key, value", [("max_speed", "1.0e+9"), ("max_reverse", "1.0e+9"), ("max_speed", "1.0e+300"),
                                        ("max_speed", "1.0e+6"), ("max_speed", "50"), ("max_turn_rate", "1e9"),
                                        ("max_accel", "1e12"), ("max_turn_accel", "100")])
def test_unicycle_limits_beyond_their_bounds_are_one_message(tmp_path, capsys, key, value):
    free_map(tmp_path)
    (tmp_path / "world.yaml").write_text(world_text("{map: m.yaml}", f", kinematics: unicycle, {key}: {value}"))
    (line,) = refused(tmp_path / "world.yaml", capsys=capsys)
    assert f"robot.{key}: at most " in line and f"got {float(value):g}" in line


def test_the_fastest_unicycle_a_file_accepts_keeps_the_physics_within_its_substeps(tmp_path):
    free_map(tmp_path)
    (tmp_path / "world.yaml").write_text(world_text("{map: m.yaml}", ", kinematics: unicycle, max_speed: 1, "
                                                                     "max_reverse: 1"))
    world = load_world(tmp_path / "world.yaml")
    assert world.unicycle.top_speed == LIMIT_BOUNDS["max_speed"]          # 4 steps of 0.25
    # a small robot that fast would need more substeps than allowed: refused, naming the radius
    (tmp_path / "small.yaml").write_text(world_text("{map: m.yaml}", ", kinematics: unicycle, max_speed: 1")
                                         .replace("radius: 0.2", "radius: 0.004"))
    with pytest.raises(WorldError, match=r"small\.yaml: robot: a robot of radius 0\.004 moving at up to 1 per "
                                         r"control step needs 512 physics substeps per step, over the limit of 256"):
        load_world(tmp_path / "small.yaml")


NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(0.05, 3.0), st.sampled_from([1e-300, 1e-9, 4.0, 4.000001,
                                                                                        2 * math.pi, 1e9, 1e300]),
                    st.integers(-10, 10**6))


@FUZZ
@given(limits=st.dictionaries(st.sampled_from(list(LIMIT_BOUNDS)), NUMBERS, max_size=5),
       radius=st.sampled_from([0.003, 0.01, 0.1, 0.25, 1.0]), step=st.sampled_from([0.05, 0.25, 1.0, 3.0]),
       followers=st.sampled_from([None, 0, 3]))
def test_fuzzed_robot_limits_build_a_bounded_robot_or_are_refused(limits, radius, step, followers):
    data = {"size": [40, 40], "field": "thesis-general", "targets": [[20, 20]],
            "robot": {"radius": radius * step, "step": step, "kinematics": "unicycle", **limits}}
    if followers is not None:
        data["formation"] = {"followers": followers, "comm_range": 5 * step, "spacing": 1 * step}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            world = world_from_dict(data, "robot.yaml")
        except WorldError as exc:
            assert all(line.startswith("robot.yaml: ") for line in str(exc).splitlines())
            event("refused")
            return
    event("accepted")
    u = world.unicycle
    assert all(getattr(u, k) <= bound + 1e-12 for k, bound in LIMIT_BOUNDS.items())
    meet = followers is not None and followers > 0
    assert physics_substeps(world.robot_radius, max(math.sqrt(2), u.top_speed), 0.0, meet) <= MAX_SUBSTEPS
    state = np.zeros((1, 5))
    assert arc_points(state, [u.top_speed], [u.max_turn_rate], MAX_SUBSTEPS).shape == (1, MAX_SUBSTEPS + 1, 2)


def test_limits_in_the_api_are_finite(tmp_path):
    for bad in (math.inf, math.nan, -1.0):
        with pytest.raises(ValueError, match="max_speed must be positive and finite"):
            UnicycleLimits(max_speed=bad)


@pytest.mark.parametrize("limits, message", [({"max_turn_rate": 1e9}, "max_turn_rate at most 6.28319 [rad per control step]"),
                                             ({"max_speed": 1e9}, "max_speed at most 4 [steps per control step]")])
def test_the_environments_take_the_same_bounds(limits, message):
    import gymnasium as gym
    import apf_physics.envs  # noqa: F401  (registers the ids)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(UserError, match=rf"^limits: {re.escape(message)}, got 1e\+09$"):
            gym.make("apf_physics/Navigate-v0", world="fixed20", kinematics="unicycle", limits=limits)
