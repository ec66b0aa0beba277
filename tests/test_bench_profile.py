"""tools/bench_profile.py puts every function of a step in one part, in this layout and the one before it."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("apf_bench_profile_tool", ROOT / "tools" / "bench_profile.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("before", "after", "function", "part"), [
    ("sweep.py", "sim/swept.py", "_near_static", "FREE_MOVE"),
    ("physics.py", "sim/physics.py", "_move_free", "FREE_MOVE"),
    ("physics.py", "sim/freemove.py", "needs_physics", "FREE_MOVE"),
    ("sweep.py", "sim/swept.py", "_settle", "PHYSICS"),
    ("physics.py", "sim/settle.py", "_settle_alone", "PHYSICS"),
    ("contacts.py", "sim/contacts.py", "_contact_rows", "PHYSICS"),
    ("physics.py", "sim/physics.py", "_simulate", "PHYSICS"),
    ("engine.py", "sim/engine.py", "step", "RULES"),
    ("envs/reward.py", "envs/reward.py", "rewards", "RULES"),
    ("field.py", "world/field.py", "sample", "OBSERVATION"),
    ("observation.py", "sensing/observation.py", "potential_windows", "OBSERVATION"),
    ("envs/task.py", "envs/task.py", "start", "ENV"),
    ("world.py", "world/core.py", "random_free", "ENV"),
])
def test_a_function_falls_in_the_same_part_in_both_layouts(tool, before, after, function, part):
    for path in (before, after):
        assert tool.part_of(f"/src/apf_physics/{path}", function) == getattr(tool, part), path


def test_pymunk_numpy_and_wrappers_have_parts_of_their_own(tool):
    assert tool.part_of("~", "<built-in method pymunk._chipmunk.cpSpaceStep>") == tool.PYMUNK_STEP
    assert tool.part_of("/venv/site-packages/pymunk/batch.py", "get_space_arbiters") == tool.PYMUNK_IO
    assert tool.part_of("~", "<built-in method pymunk._chipmunk.cpSpaceEachBody>") == tool.PYMUNK_IO
    assert tool.part_of("~", "<remap>") == tool.OBSERVATION
    assert tool.part_of("/venv/site-packages/numpy/_core/numeric.py", "flatnonzero") == tool.GLUE
    assert tool.part_of("~", "<method 'reduce' of 'numpy.ufunc' objects>") == tool.GLUE
    assert tool.part_of("/venv/site-packages/gymnasium/wrappers/common.py", "step") == tool.WRAPPERS
    assert tool.calls_kernel("/src/apf_physics/common/compiled.py", "call")
    assert tool.calls_kernel("/venv/site-packages/numba/core/serialize.py", "_numba_unpickle")
    assert not tool.calls_kernel("/src/apf_physics/sim/freemove.py", "step")


def test_a_profiled_step_is_all_in_named_parts(tool):
    """A few vector steps of 64 robots: every function of ours lands in a named part, the compiled
    kernels are found and counted, and the parts add up to no more than the time profiled."""
    result = tool.profile("64", steps=5)
    parts = result["parts"]
    assert parts[tool.OTHER] == 0.0
    for part in (tool.PYMUNK_STEP, tool.FREE_MOVE, tool.PHYSICS, tool.OBSERVATION, tool.RULES, tool.ENV, tool.GLUE):
        assert parts[part] > 0.0, part
    assert 0.0 < result["compiled"] < sum(parts.values()) <= result["profiled"]
    assert result["space_steps"] > 0
    assert tool.kernel_codes()
