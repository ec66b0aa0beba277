import os
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run (a landing never depends on luck);
# HYPOTHESIS_PROFILE=explore draws new ones each run, to look for failures.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

WORLDS = Path(__file__).resolve().parent.parent / "worlds"


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
