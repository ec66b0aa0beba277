import importlib.util
import os

import numpy as np
from pathlib import Path

import pytest
from hypothesis import settings

# the benchmark's warehouse maps, drawn the same way at a test's size (tools/bench_warehouse.py)
_WAREHOUSE_SPEC = importlib.util.spec_from_file_location(
    "apf_bench_warehouse_tool", Path(__file__).resolve().parent.parent / "tools" / "bench_warehouse.py")
_warehouse_tool = importlib.util.module_from_spec(_WAREHOUSE_SPEC)
_WAREHOUSE_SPEC.loader.exec_module(_warehouse_tool)

# Property tests draw the same examples on every run (a landing never depends on luck);
# HYPOTHESIS_PROFILE=explore draws new ones each run, to look for failures.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

WORLDS = Path(__file__).resolve().parent.parent / "worlds"


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs(tmp_path_factory):
    """Stable-Baselines3 makes a folder for its logger at every ``learn`` (``/tmp/SB3-<time>`` unless
    ``SB3_LOGDIR`` says where): the tests' go in pytest's temporary folder, not the machine's /tmp
    (subprocesses, such as the README's snippets, inherit it)."""
    if "SB3_LOGDIR" not in os.environ:
        os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3-logs"))
    yield


@pytest.fixture
def worlds_dir() -> Path:
    return WORLDS


def simple_world_dict(**overrides):
    data = {
        "name": "t",
        "size": [20, 20],
        "robot_radius": 0.25,
        "goal_tolerance": 0.5,
        "field": {"katt": 2, "krep": 20, "kstr": 8, "p0": 0.5, "ps": 8, "u_max": 100},
        "obstacles": [
            {"polygon": [[5, 5], [8, 5], [8, 9], [6, 9]]},
            {"circle": {"center": [12, 4], "radius": 0.5}},
        ],
        "targets": [[15, 15]],
        "starts": [[2, 2], [3, 17]],
    }
    data.update(overrides)
    return data



def write_warehouse_map(path, blocks=(5, 4), shelf=6, aisle=2, border=3) -> np.ndarray:
    """A small warehouse-like MovingAI map at ``path``: ``blocks`` (columns, rows) of shelves two
    cells deep and ``shelf`` long, ``aisle`` cells between them, a free ``border`` around (the
    layout of MovingAI's ``warehouse-*`` maps, made here: no third-party map is committed).

    Returns:
        (height, width) bool, the occupied cells, row 0 the map's top line (highest y).
    """
    columns, rows = blocks
    lines = _warehouse_tool.warehouse_lines(columns, rows, shelf, aisle, border)
    path.write_text("\n".join(lines) + "\n")
    return np.array([[cell == "@" for cell in line] for line in lines[4:]])


def warehouse_formations(occupied: np.ndarray, count: int, followers: int, seed: int = 0) -> list[dict]:
    """``count`` formations (a world file's ``formations:``) whose starts and targets are centres of
    free cells of :func:`write_warehouse_map`'s map, each with its 8 neighbours free, at least 4
    cells from one another, drawn from ``seed``."""
    height, width = occupied.shape
    padded = np.pad(occupied, 1, constant_values=True)
    open_cells = ~np.max([padded[1 + dr:1 + dr + height, 1 + dc:1 + dc + width]
                          for dr in (-1, 0, 1) for dc in (-1, 0, 1)], axis=0)
    rows, cols = np.nonzero(open_cells)
    centres = np.column_stack([cols + 0.5, height - rows - 0.5])
    rng = np.random.default_rng(seed)
    points: list[np.ndarray] = []
    for k in rng.permutation(len(centres)):
        if all(np.abs(centres[k] - p).max() >= 4 for p in points):
            points.append(centres[k])
        if len(points) == 2 * count:
            break
    return [{"start": points[2 * i].tolist(), "target": points[2 * i + 1].tolist(), "followers": followers}
            for i in range(count)]
