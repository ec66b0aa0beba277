"""Every Python snippet of the README and of docs/ runs alone (a fresh namespace, from the project
folder); the README's print what their comments say they print."""

from __future__ import annotations

import ast
import contextlib
import importlib.util
import io
import re
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def snippets(path: Path) -> list[str]:
    """The ```python blocks of a Markdown file."""
    return re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), re.S)


def run_alone(block: str, name: str) -> tuple[list[str], dict]:
    """Run one snippet in a namespace of its own; its printed lines and the names it leaves."""
    names: dict = {"__name__": "__snippet__"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(block, name, "exec"), names)
    return out.getvalue().splitlines(), names


CASES = [(path, k) for path in DOCUMENTS for k in range(len(snippets(path)))]


@pytest.mark.parametrize("path, index", CASES, ids=[f"{p.name}#{k}" for p, k in CASES])
def test_every_snippet_runs_alone(path, index, monkeypatch):
    monkeypatch.chdir(ROOT)
    block = snippets(path)[index]
    run_alone(block, f"{path.name}#{index}")   # raises if it does not run as written, alone


def _snippet(needle: str) -> tuple[str, list[str], dict]:
    (block,) = [b for b in snippets(ROOT / "README.md") if needle in b]
    lines, names = run_alone(block, "README.md")
    return block, lines, names


def test_readme_snippets_print_what_they_say(monkeypatch):
    from apf_physics import load_world

    monkeypatch.chdir(ROOT)
    # -- the environment: a step's reward terms, then world, position, distance, success, collision
    source, lines, names = _snippet('gym.make("apf_physics/Navigate-v0", world="fixed20", obs_size=11')
    assert len(lines) == 2, lines
    terms = ast.literal_eval(lines[0])
    documented = re.search(r"print\(info\[\"reward_terms\"\]\)\s+# \{(.*?)\}", source).group(1)
    assert set(terms) == {k.strip(" '") for k in documented.split(",")}
    world = load_world("fixed20")
    assert terms["step"] == -1.0 and terms["collision"] == 0.0 and terms["target"] == 0.0
    name, *rest = lines[1].split(" ")
    match = re.fullmatch(r"\[\s*(\S+)\s+(\S+)\s*\] (\S+) (False|True) (False|True)", " ".join(rest))
    assert name == "fixed20" and match, lines[1]
    position = np.array([float(match.group(1)), float(match.group(2))])
    distance = float(match.group(3))
    assert match.group(4, 5) == ("False", "False")          # one step from a start: neither there nor crashed
    assert distance == pytest.approx(np.hypot(*(world.targets[0] - position)))
    # the step was "right-up" (action 6): the potential term is Table 3's β = −4 times the change of U over it
    before, after = world.potential(np.array([position - (1.0, 1.0), position]))
    assert terms["potential"] == pytest.approx(-4.0 * (after - before)) and terms["potential"] > 0

    # -- the vector env
    source, lines, names = _snippet("gym.make_vec(")
    assert lines == ["(64, 1, 11, 11)"] and names["obs"].shape == (64, 1, 11, 11)

    # -- Stable-Baselines3: DQN (the window network), PPO and SAC train on the vector env as the README shows
    for algorithm, steps, shape in (("DQN", 2048, (1, 11, 11)), ("PPO", 1024, (1, 11, 11)), ("SAC", 400, (69,))):
        source, lines, names = _snippet(f"from stable_baselines3 import {algorithm}\n")
        assert lines == [str(steps)] and f"# {steps}" in source, algorithm
        assert names["model"].observation_space.shape == shape and names["model"].num_timesteps == steps
    assert names["model"].observation_space.low.min() == -1.0 and names["model"].observation_space.high.max() == 1.0

    # -- a unicycle with continuous commands and the range sensor: the spaces the README names
    source, lines, names = _snippet('kinematics="unicycle", observation="lidar"')
    assert lines == ["Box(-1.0, 1.0, (2,), float32) (69,) heading 0.63 rad"] and f"# {lines[0]}" in source

    # -- the field
    source, lines, names = _snippet("world.potential(points)")
    assert lines == ["(2,) (2, 2)", "(2,)"]
    np.testing.assert_allclose(names["raster"].sample(names["points"]), names["world"].potential(names["points"]),
                               rtol=0.05)

    # -- the ROS map: its size in steps and the step in metres, the target back in metres, five starts reached
    source, lines, names = _snippet('load_world("ros_arena")')
    assert lines == ["(21.6, 21.6) 0.25", "[[1.65 0.55]]", str(["reached"] * 5)]
    assert "# (21.6, 21.6) in steps; 0.25 m per step" in source and "# [[1.65 0.55]]" in source
    assert "# 5 x 'reached'" in source


def test_sb3_check_env_warnings_are_quoted_as_they_are():
    """SB3's ``check_env`` on ``Navigate-v0``: the README says how many warnings it gives and quotes the first
    sentence of each; docs/environments.md quotes each whole (whitespace aside)."""
    import warnings

    import gymnasium as gym
    from stable_baselines3.common.env_checker import check_env

    import apf_physics  # noqa: F401  (registers the ids)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gym.make("apf_physics/Navigate-v0", world="fixed20"))
    said = [re.sub(r"\s+", " ", str(w.message)).strip() for w in caught]
    readme, docs = (re.sub(r"\s+", " ", path.read_text(encoding="utf-8"))
                    for path in (ROOT / "README.md", ROOT / "docs" / "environments.md"))
    counts = {1: "once", 2: "twice", 3: "three times", 4: "four times"}
    assert f"SB3's `check_env` warns {counts[len(said)]}" in readme
    for message in said:
        assert message.split(". ")[0] in readme and message in docs, message


def _figures_tool():
    spec = importlib.util.spec_from_file_location("apf_figures_tool", ROOT / "tools" / "figures.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_readme_figures_are_the_results_files_figures():
    """The table of figures is written from tools/results/ by its commands (tools/figures.py): an edit by
    hand, or a results file re-measured without rewriting the README, fails here."""
    figures = _figures_tool()
    text = (ROOT / "README.md").read_text()
    assert figures.readme_block(text) == figures.table()
    for row in figures.ROWS:   # each row names the command that makes its figures
        assert row.path.is_file(), row.path
        assert f"`python tools/figures.py run {row.key}`" in figures.readme_block(text)


def test_the_figures_check_catches_a_stale_figure(monkeypatch):
    figures = _figures_tool()
    stale = figures.load(figures.BY_KEY["fixed20"])
    stale["evaluations"][1]["summary"]["successes"] -= 1    # one episode re-measured
    original = figures.load
    monkeypatch.setattr(figures, "load", lambda row: stale if row.key == "fixed20" else original(row))
    assert figures.readme_block((ROOT / "README.md").read_text()) != figures.table()
