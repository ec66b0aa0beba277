"""Ray: ``eval --ray`` gives the serial run's episodes and JSON; a sweep runs, is resumed, and picks the better trial.

The tests that need Ray share one local Ray of 2 CPUs (started once for the module) and are
skipped, with the reason, where Ray is not installed (``pip install 'apf-physics[ray]'``). The
sweep files' checks and the batching need no Ray and run everywhere.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from apf_physics.experiments.campaign import batches, evaluate_on_ray, task_count
from apf_physics.cli import main
from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import evaluate
from apf_physics.planners import make_planner
from apf_physics.learning.sweep import load_sweep
from apf_physics.world.io.worldfile import load_world

ROOT = Path(__file__).resolve().parent.parent
TINY_SWEEP = ROOT / "sweeps" / "tiny.yaml"
WORLDS = ["local_minimum", "three_targets", "fixed20", "thesis/test1"]


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray", reason="Ray is not installed here (pip install 'apf-physics[ray]')")
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="WARNING")
    yield ray
    ray.shutdown()


# ------------------------------------------------------------------------------ no Ray needed


def test_worlds_are_dealt_into_batches_covering_each_once():
    assert batches(0, 4) == []
    assert batches(3, 8) == [[0], [1], [2]]
    parts = batches(10, 3)
    assert parts == [[0, 3, 6, 9], [1, 4, 7], [2, 5, 8]]
    assert sorted(i for p in parts for i in p) == list(range(10))
    # about 4 tasks per CPU, but none under 50 episodes (over the planners)
    assert task_count(900, 2) == 8 and task_count(900, 8) == 18 and task_count(40, 8) == 1
    assert task_count(900, 2, worlds_per_task=7, worlds=60) == 9


def test_eval_ray_without_ray_installed_says_how_to_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)   # import ray fails
    assert main(["eval", "local_minimum", "--ray"]) == 2
    assert "Ray is not installed; install it with: pip install 'apf-physics[ray]'" in capsys.readouterr().err


def test_eval_ray_refuses_a_world_file_as_its_address(capsys):
    assert main(["eval", "--ray", str(ROOT / "worlds" / "local_minimum.yaml"), "fixed20"]) == 2
    assert "is a file, not a Ray address; put --ray after the worlds" in capsys.readouterr().err


def test_the_example_sweeps_are_read():
    tiny = load_sweep(TINY_SWEEP)
    assert tiny.world.endswith("local_minimum.yaml") and tiny.grid == {"learning_rate": [1e-3, 1e-9]}
    assert tiny.budget == ("total_steps", 3000) and tiny.reports == 3 and tiny.metric == "success"
    assert [tiny.leg_budget(k) for k in (1, 2, 3)] == [1000, 2000, 3000]
    config = tiny.config({"learning_rate": 1e-9, "seed": 4}, 2)
    assert config.network.learning_rate == 1e-9 and config.run.seed == 4 and config.schedule.total_steps == 2000
    assert config.schedule.time_limit is None and config.schedule.total_episodes is None and config.env.obs_size == 5
    recipes = load_sweep(ROOT / "sweeps" / "general-recipes.yaml")
    assert recipes.curriculum.endswith("thesis.yaml") and recipes.metric == "spl" and len(recipes.seeds) == 3
    assert recipes.config({"preset": "general", "seed": 1}, 6).preset == "general"


@pytest.mark.parametrize("text, message", [
    ("world: local_minimum\nbudget: {total_steps: 100}\ngrid: {learnin_rate: [0.1]}",
     r"bad\.yaml: grid: unknown training option 'learnin_rate' \(did you mean 'learning_rate'\?\)"),
    ("world: local_minimum\nbudget: {total_steps: 100}\noverrides: {batch_size: big}",
     r"bad\.yaml: overrides: training option batch_size must be int, got 'big'"),
    ("world: local_minimum\nbudgte: {total_steps: 100}", r"bad\.yaml: budgte: unknown key \(did you mean 'budget'\?\)"),
    ("world: local_minimum\nbudget: {steps: 100}", r"bad\.yaml: budget: must be one of \{total_steps: N\}"),
    ("world: local_minimum\nbudget: {total_steps: 100}\nmetric: collisions", r"bad\.yaml: metric: must be one of success, spl"),
    ("world: local_minimum\nbudget: {total_steps: 100}\npreset: fsat", r"bad\.yaml: preset: unknown preset 'fsat' \(did you mean 'fast'\?\)"),
    ("world: local_minimum\nbudget: {total_steps: 100}\noverrides: {seed: 3}", r"bad\.yaml: overrides: seed is set by the sweep's seeds"),
    ("world: local_minimum\nbudget: {total_steps: 100}\nsample: {tau: {loguniform: [0, 1]}}",
     r"bad\.yaml: sample: tau: loguniform needs \[low, high\], positive numbers"),
    ("world: nowhere\nbudget: {total_steps: 100}", r"bad\.yaml: world: nowhere: no such world file"),
    ("curriculum: curricula/thesis\nworld: fixed20\nbudget: {total_steps: 100}", r"bad\.yaml: name exactly one of world or curriculum"),
    ("world: local_minimum\nbudget: {total_steps: 100}\noverrides: {memory: true}",
     r"bad\.yaml: overrides: invalid training configuration: memory needs obs_transform"),
    ("world: local_minimum\nbudget: {total_steps: 100}\nasha: {grace_period: 9}", r"bad\.yaml: asha: grace_period must be"),
    ("world: [1]: x", r"bad\.yaml: not valid YAML at line 1"),
])
def test_a_malformed_sweep_file_is_one_line_naming_the_file_and_key(tmp_path, text, message):
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(UserError, match=message) as info:
        load_sweep(bad)
    assert "\n" not in str(info.value)


# ------------------------------------------------------------------------------ on a local Ray


def test_eval_ray_gives_the_serial_episodes_table_and_json(local_ray, tmp_path, capsys):
    common = ["eval", *WORLDS, "--planner", "gradient,escape,dqn", "--random-starts", "3", "--seed", "5"]
    assert main([*common, "--json", str(tmp_path / "serial.json")]) == 0
    serial_out = capsys.readouterr().out
    assert main([*common, "--json", str(tmp_path / "ray.json"), "--ray", "--ray-batch", "1"]) == 0
    ray_out = capsys.readouterr().out
    assert (tmp_path / "ray.json").read_bytes() == (tmp_path / "serial.json").read_bytes()
    assert ray_out.replace("ray.json", "serial.json") == serial_out
    data = json.loads((tmp_path / "ray.json").read_text())
    assert [d["planner"] for d in data] == ["gradient", "escape", "dqn"] and len(data[0]["episodes"]) == 12


def test_eval_on_ray_ships_a_model_file_and_batches_do_not_matter(local_ray):
    model = str(ROOT / "apf_physics" / "models" / "fixed20.pt")
    world = load_world("fixed20")
    serial = evaluate(make_planner("dqn", model=model), [world])
    for per_task in (None, 1):
        (on_ray,) = evaluate_on_ray(["dqn"], [world], model=model, worlds_per_task=per_task)
        assert on_ray.planner == serial.planner
        assert [e.to_dict() for e in on_ray.episodes] == [e.to_dict() for e in serial.episodes]
        np.testing.assert_array_equal(on_ray.episodes[3].path, serial.episodes[3].path)


def _interrupt_at_first_checkpoint(folder: Path) -> threading.Thread:
    """Send this process SIGUSR1, which Tune's fit() takes as Ctrl-C, once a trial has checkpointed."""
    def watch():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            # a trial has finished its first leg (its progress file is written just before it reports), or
            # Tune has stored its first checkpoint: whichever shows first, so a fast machine cannot outrun it
            if list(folder.glob("tune/*/*/run/sweep-progress.json")) or list(folder.glob("tune/*/checkpoint_000000")):
                os.kill(os.getpid(), signal.SIGUSR1)   # Tune's handler is installed by then (fit() is running)
                return
            time.sleep(0.05)
    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.mark.skipif(not hasattr(signal, "SIGUSR1"), reason="needs SIGUSR1 to interrupt Tune")
def test_sweep_is_interrupted_resumed_and_picks_the_better_trial(local_ray, tmp_path):
    from apf_physics.models import load_model
    from apf_physics.learning.sweep import run_sweep

    sweep = load_sweep(TINY_SWEEP)
    out = tmp_path / "sweep"
    watcher = _interrupt_at_first_checkpoint(out)
    first = run_sweep(sweep, out, verbose=0)
    watcher.join(timeout=5)
    assert first.interrupted and not (out / "best.pt").exists()
    assert any(r.status == "interrupted" for r in first.rows)
    with pytest.raises(UserError, match="already holds a sweep; continue it with --resume"):
        run_sweep(sweep, out, verbose=0)

    result = run_sweep(sweep, out, resume=True, verbose=0)
    assert not result.interrupted and len(result.rows) == 2
    better, worse = result.rows
    assert result.best is better and better.values == {"learning_rate": 1e-3, "seed": 0}
    assert better.metrics["success"] > worse.metrics["success"] and better.status == "finished"
    assert better.metrics["global_step"] >= 3000 and better.metrics["legs"] == 3
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["learning_rate"] for r in rows] == ["0.001", "1e-09"] and rows[0]["status"] == "finished"
    best = json.loads((out / "best.json").read_text())
    assert best["values"] == better.values and best["config"]["network"]["learning_rate"] == 1e-3
    with better.checkpoint.as_directory() as folder:   # best.pt is the trial's, from the trainer's own files
        assert (out / "best.pt").read_bytes() == (Path(folder) / "best.pt").read_bytes()
    model = load_model(out / "best.pt")
    assert model.meta["training"]["evaluation"]["success"] == better.metrics["success"]


def test_a_map_preset_sweep_trains_the_map_network(local_ray, tmp_path):
    """``preset: map`` trains the map network by imitation, through the same loop as DQN (not a Q-network)."""
    from apf_physics.models import MapPolicy, load_policy
    from apf_physics.learning.sweep import run_sweep

    curriculum = ROOT / "worlds" / "curricula" / "thesis.yaml"
    path = tmp_path / "map.yaml"
    path.write_text(
        f"curriculum: {curriculum}\npreset: map\n"
        "overrides: {validation_worlds: 2, validation_starts: 1, pool_size: 2, map_sizes: [30.0], demo_positions: 64,\n"
        "            grad_iterations: 4, families: [point, narrow_gap], eval_every: 4, log_every: 2}\n"
        "grid: {learning_rate: [0.003]}\nseeds: [0]\nbudget: {total_steps: 8}\nreports: 2\nasha: false\n")
    sweep = load_sweep(path)
    result = run_sweep(sweep, tmp_path / "sweep", verbose=0)
    (row,) = result.rows
    assert row.status == "finished" and row.metrics["global_step"] == 8 and row.metrics["legs"] == 2
    best = json.loads((tmp_path / "sweep" / "best.json").read_text())
    assert best["config"]["method"] == "imitation" and best["config"]["preset"] == "map"
    assert isinstance(load_policy(tmp_path / "sweep" / "best.pt"), MapPolicy)


def test_eval_on_ray_drives_unicycles_as_the_local_run_does(local_ray):
    worlds = [load_world("local_minimum"), load_world("three_targets")]
    (on_ray,) = evaluate_on_ray(["gradient"], worlds, kinematics="unicycle", worlds_per_task=1)
    local = evaluate(make_planner("gradient"), worlds, kinematics="unicycle")
    assert [e.to_dict() for e in on_ray.episodes] == [e.to_dict() for e in local.episodes]
    assert all(e.headings is not None for e in on_ray.episodes)
