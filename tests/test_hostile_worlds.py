"""World files from a careless or hostile hand: a fuzzer over texts and mappings.

Each example is mutated from a bundled world or a generated one with moving obstacles (its
YAML text, or its mapping) and loaded.
The contract: a :class:`WorldError` whose lines each name the file and stay short, or a world
that the layers above can use (finite field, bounded substeps and rasters). The examples are
bounded in number (``APF_FUZZ_EXAMPLES``, default 150 per test) and each one's work is bounded
by the loader's own limits; hypothesis's ``deadline`` (10 s, some thousand times a typical
example) only flags a hang.
"""

from __future__ import annotations

import math
import os
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from apf_physics import WorldError, load_world, world_from_dict
from apf_physics.world.bundled import bundled_dir, list_bundled
from apf_physics.world.generate import generate_world
from apf_physics.world.kinematics import MAX_SUBSTEPS, physics_substeps
from apf_physics.world.io.worldfile import MAX_PROBLEMS, MAX_SIDE, MIN_ROBOT_RADIUS, dump_world_yaml, memory_budget, raster_memory

EXAMPLES = int(os.environ.get("APF_FUZZ_EXAMPLES", 150))
"""Examples per fuzz test; CI runs the same ones every time unless ``APF_FUZZ_RANDOM`` is set."""
FUZZ = settings(max_examples=EXAMPLES, deadline=timedelta(seconds=10), derandomize=not os.environ.get("APF_FUZZ_RANDOM"),
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])

TEXTS = {name: (bundled_dir() / f"{name}.yaml").read_text(encoding="utf-8") for name in list_bundled()}
TEXTS["generated-moving"] = dump_world_yaml(generate_world("moving", np.random.default_rng(0), n_starts=3))
NAMES = sorted(TEXTS)

# Fragments a hostile or clumsy editor inserts: YAML syntax, anchors and aliases, tags,
# numbers at the edges of float, deep nesting, long values.
FRAGMENTS = [
    "[", "]", "{", "}", ":", ",", "- ", "&a ", "*a", "!!str ", "!!binary ", "!!set ", "!!python/object:os.system ",
    "<<: ", "? ", "|\n", ">\n", "#", "'", '"', "\t", "\n", "  ", "---\n", "...\n", "~", "null", "true", "yes",
    ".nan", ".inf", "-.inf", "1e400", "5e-324", "1e-9", "1e300", "-0", "0x7fffffffffffffffffff", "1_000", "190:20:30",
    "2024-13-45", "1" + "0" * 400, "9" * 5000, "[" * 300, "x" * 5000, "\u00e9", "\ufeff", "\x00", "\x85",
    "&x0 [1,1,1,1,1,1,1,1,1]", "[*x0,*x0,*x0,*x0,*x0,*x0,*x0,*x0,*x0]",
]


def check_outcome(load) -> str:
    """Run ``load()``; assert it gives a clean refusal or a usable world; return which."""
    try:
        world = load()
    except WorldError as exc:
        lines = str(exc).split("\n")
        assert 1 <= len(lines) <= MAX_PROBLEMS + 1
        assert all(0 < len(line) <= 500 for line in lines), max(lines, key=len)[:600]
        return "refused"
    w, h = world.size
    assert 1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE
    top = max(math.sqrt(2), world.unicycle.top_speed) if world.unicycle is not None else math.sqrt(2)
    meet = bool(world.formations) or (world.formation is not None and world.formation.followers > 0)
    obstacle_speed = max((world.obstacles[i].motion.speed for i in world.moving), default=0.0)
    assert world.robot_radius >= MIN_ROBOT_RADIUS
    assert physics_substeps(world.robot_radius, top, obstacle_speed, meet) <= MAX_SUBSTEPS
    assert raster_memory(world.size, len(world.targets)) <= memory_budget()
    assert world.goal_tolerance < math.hypot(w, h) / 2
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h], *world.targets.tolist(), *world.starts.tolist()], float)
    assert np.all(np.isfinite(world.potential(corners))) and np.all(np.isfinite(world.gradient(corners)))
    assert np.all(world.clearance(world.starts) >= world.robot_radius) if len(world.starts) else True
    return "accepted"


@st.composite
def mutated_text(draw) -> str:
    """A bundled world's text with a few edits: fragments inserted, spans deleted or doubled."""
    text = TEXTS[draw(st.sampled_from(NAMES))]
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(text)))
        kind = draw(st.sampled_from(["insert", "delete", "double", "replace-number"]))
        if kind == "insert":
            text = text[:at] + draw(st.sampled_from(FRAGMENTS) | st.text(max_size=8)) + text[at:]
        elif kind == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 40)):]
        elif kind == "double":
            end = at + draw(st.integers(1, 200))
            text = text[:end] + text[at:end] * draw(st.integers(1, 50)) + text[end:]
        else:
            numbers = [i for i, c in enumerate(text) if c.isdigit()]
            if numbers:
                i = numbers[draw(st.integers(0, len(numbers) - 1))]
                text = text[:i] + draw(st.sampled_from(FRAGMENTS[28:])) + text[i + 1:]
    return text


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@FUZZ
@given(text=mutated_text())
def test_mutated_world_texts_load_or_are_refused_cleanly(folder, text):
    path = folder / "world.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    event(check_outcome(lambda: load_world(path)))


NASTY = st.recursive(
    st.none() | st.booleans() | st.integers() | st.sampled_from([63, 400, 5000]).map(lambda e: -(10**e))
    | st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([5e-324, 1e-9, 1e300, 1e308, -0.0])
    | st.text(max_size=30) | st.integers(4_000, 12_000).map(lambda n: "x" * n),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=12), inner, max_size=4),
    max_leaves=20,
)


def paths(value, prefix=()):
    """Every (key path) inside a world mapping down to 8 levels, the root's keys first."""
    if len(prefix) >= 8:
        return
    if isinstance(value, dict):
        for key, item in value.items():
            yield prefix + (key,)
            yield from paths(item, prefix + (key,))
    elif isinstance(value, list):
        for i, item in enumerate(value[:6]):
            yield prefix + (i,)
            yield from paths(item, prefix + (i,))


def deep(levels: int):
    value: list = []
    for _ in range(levels):
        value = [value]
    return value


@st.composite
def mutated_mapping(draw) -> dict:
    """A bundled world's mapping with values replaced, keys dropped or added, numbers scaled."""
    data = yaml.safe_load(TEXTS[draw(st.sampled_from(NAMES))])
    for _ in range(draw(st.integers(1, 3))):
        where = list(paths(data))
        path = where[draw(st.integers(0, len(where) - 1))]
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        kind = draw(st.sampled_from(["replace", "drop", "add", "scale", "nest"]))
        if kind == "replace":
            parent[path[-1]] = draw(NASTY)
        elif kind == "drop" and isinstance(parent, dict):
            parent.pop(path[-1])
        elif kind == "add" and isinstance(parent, dict):
            parent[draw(st.text(max_size=15))] = draw(NASTY)
        elif kind == "scale" and type(parent[path[-1]]) in (int, float) and abs(parent[path[-1]]) < 1e300:
            parent[path[-1]] = parent[path[-1]] * draw(st.sampled_from([0, -1, 1e-12, 1e-6, 1e3, 1e6, 1e12, 1e300]))
        elif kind == "nest":
            parent[path[-1]] = deep(draw(st.integers(1, 2000)))
    return data


@FUZZ
@given(data=mutated_mapping())
def test_mutated_world_mappings_build_or_are_refused_cleanly(data):
    event(check_outcome(lambda: world_from_dict(data, "fuzzed.yaml")))


def test_the_fuzzer_sees_both_outcomes():
    """The mutations are neither all fatal nor all harmless (else the fuzzer would test little)."""
    outcomes = {check_outcome(lambda: world_from_dict(yaml.safe_load(TEXTS[name]), name)) for name in NAMES}
    outcomes.add(check_outcome(lambda: world_from_dict({"size": [20, "wide"]}, "bad.yaml")))
    assert outcomes == {"accepted", "refused"}


def test_huge_coordinates_give_the_one_line_error_and_no_numpy_warning(tmp_path):
    import subprocess
    import sys
    path = tmp_path / "big.yaml"
    path.write_text("name: big\nsize: [20, 20]\nfield: {katt: 1, krep: 1, kstr: 1, p0: 1, ps: 2, u_max: 10}\n"
                    "obstacles:\n  - polygon: [[1e308, 1e308], [-1e308, 1e308], [0, -1e308]]\n"
                    "targets: [[10, 10]]\nstarts: [[2, 2]]\n")
    done = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "apf_physics.cli", "eval", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Warning" not in done.stderr and "Traceback" not in done.stderr
    assert "obstacles[0].polygon: polygon reaches outside the map" in done.stderr
