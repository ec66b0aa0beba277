"""The DQN trainer: network, configuration, experience pool, evaluation, the loop, checkpoints and resume.

Training runs use the 8×8 world of ``rl_worlds`` (real physics, learned in seconds).
"""

from __future__ import annotations

import dataclasses

import csv
import io
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from apf_physics.errors import ModelError, UserError
from apf_physics.experiments.evaluate import evaluate
from apf_physics.models import DQNPolicy, QNetwork, load_model
from apf_physics.models.files import MAGIC, read_file, write_file
from apf_physics.models.network import max_pool_2x2_stride1, relative_log
from apf_physics.planners import make_planner
from apf_physics.learning import (
    PRESETS,
    ReplayBuffer,
    TrainConfig,
    epsilon_schedule,
    load_checkpoint_config,
    phases_for_world,
    preset,
    train,
)
from apf_physics.learning import validation
from apf_physics.learning.buffer import NStepReturns
from apf_physics.learning.config import replace
from apf_physics.learning.phases import reachable_mask, training_starts, validation_starts
from apf_physics.learning.rundir import RunDir
from apf_physics.learning.config import load_config
from apf_physics.learning.dqn import q_network
from apf_physics.learning.learner import Counters
from apf_physics.learning.progress import Progress
from apf_physics.learning.trainer import CSV_COLUMNS
from rl_worlds import TINY, TINY_OPTIONS, tiny_world, write_tiny_world
from apf_physics.world.io.worldfile import world_from_dict

TINY_FIELD = tiny_world().field


def tiny_config(**overrides) -> TrainConfig:
    return preset("fast", **{**TINY_OPTIONS, **overrides})


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# ---------------------------------------------------------------------------- network


@pytest.mark.parametrize("shape", [(64, 10, 10, 10), (3, 2, 7, 5)])
def test_max_pool_matches_f_max_pool2d_values_and_gradients(shape):
    x = torch.randn(shape, dtype=torch.float64, requires_grad=True)
    expected = F.max_pool2d(x, kernel_size=2, stride=1)
    got = max_pool_2x2_stride1(x)
    assert torch.equal(got, expected)
    grad_out = torch.randn_like(expected)
    (g_expected,) = torch.autograd.grad(expected, x, grad_out)
    (g_got,) = torch.autograd.grad(got, x, grad_out)
    torch.testing.assert_close(g_got, g_expected)


def test_max_pool_ties_send_the_gradient_where_max_pool2d_does():
    x = torch.randint(0, 2, (4, 3, 6, 6)).double().requires_grad_()
    grad_out = torch.randn(4, 3, 5, 5, dtype=torch.float64)
    (g_expected,) = torch.autograd.grad(F.max_pool2d(x, 2, 1), x, grad_out)
    (g_got,) = torch.autograd.grad(max_pool_2x2_stride1(x), x, grad_out)
    torch.testing.assert_close(g_got, g_expected)
    with torch.no_grad():
        assert torch.equal(max_pool_2x2_stride1(x), F.max_pool2d(x, 2, 1))


@pytest.mark.parametrize("name, k, params", [("thesis-fixed", 11, 25_705), ("thesis-general-world", 9, 4_673),
                                             ("thesis-general", 9, 4_673)])
def test_thesis_networks_have_the_tables_layers(name, k, params):
    config = preset(name)
    assert config.env.obs_size == k
    net = q_network(config)
    assert sum(p.numel() for p in net.parameters()) == params
    assert [c.out_channels for c in net.convs] == list(config.network.filters)
    assert [layer.out_features for layer in net.hidden] == [32, 32]
    assert net(torch.zeros(5, 1, k, k)).shape == (5, 9)


def test_relative_log_centres_and_keeps_walls_highest():
    obs = torch.full((1, 1, 5, 5), 40.0)
    obs[0, 0, 2, 2] = 30.0          # robot's cell
    obs[0, 0, 2, 3] = 20.0          # downhill
    obs[0, 0, 0, :] = 500.0         # a wall above
    out = relative_log(obs)
    assert out[0, 0, 2, 2] == 0
    assert out[0, 0, 2, 3] < 0 < out[0, 0, 1, 1]
    assert torch.isclose(out[0, 0, 2, 3], -torch.log1p(torch.tensor(10.0)))
    assert out[0, 0, 0].min() > out[0, 0, 1:].max()


def test_observation_transform_is_part_of_the_saved_network():
    raw = QNetwork(obs_shape=(1, 5, 5), filters=(4, 4), obs_transform="raw")
    logged = QNetwork(obs_shape=(1, 5, 5), filters=(4, 4), obs_transform="relative-log")
    logged.load_state_dict(raw.state_dict())
    obs = torch.rand(3, 1, 5, 5) * 100
    torch.testing.assert_close(logged(obs), raw(relative_log(obs)))


# ---------------------------------------------------------------------------- configuration


def test_thesis_presets_stay_as_written():
    fixed = preset("thesis-fixed")
    assert (fixed.dqn.loss, fixed.dqn.batch_size, fixed.dqn.target_update, fixed.network.obs_transform) == ("mse", 7, "none", "raw")
    assert (fixed.dqn.gamma, fixed.network.learning_rate, fixed.dqn.epsilon_initial, fixed.dqn.epsilon_final) == (0.95, 1e-3, 0.95, 0.05)
    assert fixed.dqn.exploration_episodes == fixed.schedule.total_episodes == 30_000 and fixed.env.max_episode_steps == 100
    assert fixed.network.filters == (10, 10, 20) and not fixed.dqn.double_dqn and fixed.dqn.reward_scale == 1.0
    assert fixed.env.reward == "thesis-fixed" and fixed.env.num_envs == 1 and fixed.env.train_starts == "world"
    for name in ("thesis-general-world", "thesis-general"):  # Table 4
        general = preset(name)
        assert (general.env.obs_size, general.network.filters, general.dqn.exploration_episodes) == (9, (4, 4), 150)
        assert (general.env.reward, general.dqn.batch_size, general.dqn.loss, general.dqn.target_update) == (
            "thesis-general", 7, "mse", "none")
    assert preset("thesis-general-world").schedule.total_episodes == 150
    curriculum = preset("thesis-general")
    assert curriculum.schedule.stage_episodes == 150 and curriculum.dqn.restart_exploration
    assert curriculum.schedule.total_episodes is None
    fast = preset("fast")
    assert (fast.env.num_envs, fast.dqn.batch_size, fast.dqn.loss, fast.dqn.double_dqn, fast.dqn.target_update, fast.dqn.tau) == (
        64, 128, "huber", True, "soft", 0.01)
    assert (fast.dqn.reward_scale, fast.network.obs_transform, fast.env.train_starts, fast.schedule.target_success) == (
        1e-3, "relative-log", "reachable", 0.99)
    assert (fast.dqn.gradient_steps, fast.dqn.n_step, fast.network.learning_rate, fast.dqn.eval_network) == (
        4, 5, 5e-4, "target")
    assert fast.env.failure_starts == 0.5 and fast.dqn.exploration_episodes == 1_500
    # validated on 1,000 seeded random free starts never trained on: they pick best.pt and stop the run, which
    # stops by steps (the same run on any machine), not by the clock
    assert fast.evaluation.eval_random_starts == 1000 and fast.evaluation.select == ("success", "world_starts_success")
    assert not fast.evaluation.eval_shield
    assert fast.schedule.total_steps == 300_000 and fast.schedule.time_limit is None


def test_each_preset_is_its_base_changed_by_its_layer():
    """A chained preset equals the preset it builds on in every option but those its own layer sets
    (learning.config.LAYERS): what --show-config credits to a layer is what that layer changes."""
    from apf_physics.learning.config import LAYERS, TrainConfig

    for name, (base, changes, _) in LAYERS.items():
        if " " in name:
            continue
        mine = preset(name).options()
        if base is None:
            below = TrainConfig(preset=name).options()
        elif " " in base:   # a shared part: the defaults with that part's changes
            below = replace(TrainConfig(preset=name), **LAYERS[base][1]).options()
        else:
            below = preset(base).options()
        differ = {k for k in mine if k != "preset" and mine[k] != below[k]}
        assert differ <= set(changes), (name, differ - set(changes))
    revisit = preset("general-revisit")
    assert revisit.env.reward_weights.revisit < 0 and revisit.env.reward_weights.length < 0


def test_unknown_names_keys_and_bad_values_are_refused():
    with pytest.raises(UserError, match="unknown training preset 'fsat' \\(did you mean 'fast'\\?\\)"):
        preset("fsat")
    with pytest.raises(UserError, match="unknown training option 'batchsize' \\(did you mean 'batch_size'\\?\\)"):
        preset("fast", batchsize=3)
    with pytest.raises(UserError, match="unknown training option"):
        TrainConfig.from_dict({**preset("fast").to_dict(), "no_such_option": 1})
    with pytest.raises(UserError, match="loss"):
        preset("fast", loss="l1")
    with pytest.raises(UserError, match="total_steps must be int or null"):
        preset("fast", total_steps="many")
    with pytest.raises(UserError, match="double_dqn must be bool"):
        preset("fast", double_dqn="yes")
    with pytest.raises(UserError, match="memory needs obs_transform"):
        preset("fast", memory=True)
    with pytest.raises(UserError, match="held-out"):
        preset("general", validation_seed=100)
    with pytest.raises(UserError, match="select"):
        preset("fast", select=["succes"])


def test_values_from_yaml_take_the_fields_types_and_round_trip():
    config = preset("fast", filters=[4, 4], max_grad_norm=1, time_limit=60, total_steps=5e4, select="-collisions")
    assert config.network.filters == (4, 4) and config.network.max_grad_norm == 1.0 and isinstance(config.schedule.time_limit, float)
    assert config.schedule.total_steps == 50_000 and config.evaluation.select == ("-collisions",)
    for name in PRESETS:
        assert TrainConfig.from_dict(preset(name).to_dict()) == preset(name)
    custom = preset("fast", reward={"w1": -1, "w2": 1, "w3": 0, "beta": -1})
    assert TrainConfig.from_dict(custom.to_dict()) == custom and custom.env.reward_weights.w2 == 1


def test_options_are_named_by_name_or_path_and_checked_once_when_built():
    config = preset("fast", **{"network.learning_rate": 3e-4}, gamma=0.9, run={"seed": 7})
    assert (config.network.learning_rate, config.dqn.gamma, config.run.seed) == (3e-4, 0.9, 7)
    assert config.option("learning_rate") == config.option("network.learning_rate") == 3e-4
    with pytest.raises(UserError, match="option 'dqn.learning_rate' \\(did you mean 'network.learning_rate'\\?\\)"):
        preset("fast", **{"dqn.learning_rate": 1e-3})
    with pytest.raises(UserError, match="target_update must be one of none, hard, soft, got 'sfot' \\(did you mean 'soft'\\?\\)"):
        preset("fast", target_update="sfot")
    with pytest.raises(UserError, match="method must be one of dqn, imitation"):
        preset("fast", method="ppo")
    with pytest.raises(UserError, match="section run must be a mapping"):
        preset("fast", run=3)
    # a built configuration cannot be made invalid afterwards: every section is frozen
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.dqn.gamma = 2.0


def test_a_configuration_saves_to_yaml_and_loads_back(tmp_path):
    config = preset("map", hidden=(16, 16), total_steps=40)
    path = config.to_yaml(tmp_path / "config.yaml")
    text = path.read_text()
    assert "imitation:\n" in text and "  map_moves: nodes\n" in text and "network:\n" in text
    assert load_config(path) == config
    # a flat file (or an old model file's configuration) reads the same
    flat = tmp_path / "flat.yaml"
    flat.write_text("preset: map\nmethod: imitation\nhidden: [16, 16]\n")
    assert load_config(flat).network.hidden == (16, 16) and load_config(flat).method == "imitation"
    bad = tmp_path / "bad.yaml"
    bad.write_text("network:\n  learning_rat: 0.1\n")
    with pytest.raises(UserError, match="bad.yaml: unknown training option 'network.learning_rat' \\(did you mean "
                                        "'network.learning_rate'\\?\\)"):
        load_config(bad)


def test_epsilon_schedule_is_specs_eq_34():
    config = preset("thesis-fixed", exploration_episodes=100)
    assert epsilon_schedule(config, 0) == pytest.approx(0.95)
    assert epsilon_schedule(config, 50) == pytest.approx(0.475)
    assert epsilon_schedule(config, 99) == pytest.approx(0.05)
    assert epsilon_schedule(config, 10_000) == 0.05


def test_curriculum_presets_are_refused_on_one_world():
    world = tiny_world()
    with pytest.raises(UserError, match="trains a curriculum"):
        phases_for_world(world, preset("thesis-general"))
    (phase,) = phases_for_world(world, preset("thesis-general-world"))
    assert phase.worlds == (world,) and phase.starts == "world" and phase.validation.starts == 6


# ---------------------------------------------------------------------------- buffer


def test_replay_buffer_wraps_samples_and_round_trips():
    buffer = ReplayBuffer(capacity=5, obs_shape=(1, 3, 3), batch_size=4)
    for start in (0, 3):
        ids = np.arange(start, start + 3)
        obs = np.broadcast_to(ids[:, None, None, None], (3, 1, 3, 3)).astype(np.float32)
        buffer.add(obs, obs + 100, ids, ids * 10.0, np.where(ids % 2 == 0, 0.0, 0.9))
    assert len(buffer) == 5 and buffer.pos == 1
    assert sorted(buffer.actions.tolist()) == [1, 2, 3, 4, 5]  # 0 was overwritten
    batch = buffer.sample(np.random.default_rng(0))
    assert batch.observations.shape == (4, 1, 3, 3) and batch.actions.shape == (4, 1)
    a = batch.actions[:, 0].numpy()
    np.testing.assert_array_equal(batch.observations[:, 0, 0, 0].numpy(), a)
    np.testing.assert_array_equal(batch.next_observations[:, 0, 1, 1].numpy(), a + 100)
    np.testing.assert_array_equal(batch.rewards.numpy(), a * 10.0)
    np.testing.assert_allclose(batch.discounts.numpy(), np.where(a % 2 == 0, 0.0, 0.9))
    copy = ReplayBuffer(capacity=5, obs_shape=(1, 3, 3), batch_size=4)
    copy.load_state_dict(buffer.state_dict())
    assert (copy.pos, copy.size) == (buffer.pos, buffer.size)
    np.testing.assert_array_equal(copy.next_observations, buffer.next_observations)


def _n_step_reference(episodes: list[list[tuple]], n: int, gamma: float) -> list[tuple]:
    """The n-step transitions of whole episodes, one by one: ``(obs, action, return, next obs, discount)``."""
    out = []
    for steps, open_ended in episodes:
        for i, (obs, action, *_) in enumerate(steps):
            seen = steps[i:i + n]
            ret = sum(gamma ** k * r for k, (_, _, r, _, _) in enumerate(seen))
            *_, last_next, last_terminal = seen[-1]
            ends_there = i + len(seen) == len(steps) and not open_ended
            out.append((obs, action, last_next, ret, 0.0 if ends_there and last_terminal else gamma ** len(seen)))
    return sorted(out)


@pytest.mark.parametrize("n", [1, 3])
def test_n_step_returns_sum_the_rewards_to_the_episodes_end_or_n_steps(n):
    """Random episodes of three environments stepped together (ends by termination and by the step limit,
    NEXT_STEP autoreset steps, a flush mid-episode), against the returns written out episode by episode."""
    rng, gamma, envs = np.random.default_rng(n), 0.9, 3
    returns = NStepReturns(n, gamma, envs, (1, 1, 1))
    obs = np.arange(envs, dtype=np.float32).reshape(envs, 1, 1, 1)
    restarting = np.zeros(envs, bool)
    episodes, current, made, label = [], [[] for _ in range(envs)], [], envs
    for _ in range(60):
        actions, rewards = rng.integers(0, 9, envs), rng.normal(size=envs)
        terminated = rng.random(envs) < 0.1
        ended = (terminated | (rng.random(envs) < 0.05)) & ~restarting
        next_obs = np.arange(label, label + envs, dtype=np.float32).reshape(envs, 1, 1, 1)
        label += envs
        made.append(returns.add(obs, actions, rewards, next_obs, terminated, ended, ~restarting))
        for e in np.flatnonzero(~restarting):
            current[e].append((obs[e].item(), int(actions[e]), rewards[e], next_obs[e].item(), bool(terminated[e])))
            if ended[e]:
                episodes.append((current[e], False))
                current[e] = []
        restarting, obs = ended, next_obs
    made.append(returns.flush())
    episodes += [(steps, True) for steps in current if steps]
    got = sorted((float(o), int(a), float(x), float(r), float(d))
                 for m in made for o, x, a, r, d in zip(m.observations.ravel(), m.next_observations.ravel(),
                                                           m.actions, m.rewards, m.discounts))
    expected = _n_step_reference(episodes, n, gamma)
    assert [g[:3] for g in got] == [e[:3] for e in expected] and len(got) > 100   # each observation once
    np.testing.assert_allclose([g[3:] for g in got], [e[3:] for e in expected], rtol=1e-5, atol=1e-6)


def test_failure_starts_are_drawn_where_searches_failed():
    """Searches that failed from one cell make the share drawn by failure come from that cell; the rest
    stay uniform over the pool, and the counts fade at each draw."""
    from apf_physics.learning.dqn import DRAWN_STARTS, FAILURE_MEMORY, FailureStarts

    world = tiny_world()
    pool = training_starts(world, "reachable", seed=0, count=5_000)
    starts = FailureStarts(pool, world, share=0.5)
    cell = np.floor(pool[0])
    in_cell = (np.floor(pool) == cell).all(axis=1)
    assert 0 < in_cell.mean() < 0.1
    ok = pool[~in_cell]   # every other cell: many searches, all reached
    starts.record(np.vstack([pool[in_cell][:20], ok]), np.r_[np.zeros(20, bool), np.ones(len(ok), bool)])
    drawn = starts.draw(np.random.default_rng(0))
    share = (np.floor(drawn) == cell).all(axis=1).mean()
    assert len(drawn) == DRAWN_STARTS and 0.45 < share < 0.5 + 0.1   # about half from the failing cell
    assert starts.failures.sum() == pytest.approx(20 * FAILURE_MEMORY)
    assert starts.searches.sum() == pytest.approx((20 + len(ok)) * FAILURE_MEMORY)
    again = FailureStarts(pool, world, share=0.5)
    again.load(starts.state())
    np.testing.assert_array_equal(again.draw(np.random.default_rng(1)), starts.draw(np.random.default_rng(1)))
    # with random starts, drawn from a pool of random free positions away from the target
    from apf_physics.learning.dqn import start_pool
    random = start_pool("random", world, seed=0, count=500)
    assert random.shape == (500, 2) and world.is_free(random).all()
    assert np.array_equal(start_pool("world", world, seed=0), world.starts)
    from apf_physics.learning import phases_for_curriculum
    from apf_physics.learning.curriculum import load_curriculum
    with pytest.raises(UserError, match="failure_starts draws the starts of one world"):
        phases_for_curriculum(load_curriculum(Path(__file__).parent.parent / "worlds" / "curricula" / "thesis.yaml"),
                              preset("general", failure_starts=0.5))


# ---------------------------------------------------------------------------- evaluation


def _episode(success: bool, length: float, outcome: str | None = None):
    return SimpleNamespace(success=success, path_length=length, outcome=outcome or ("reached" if success else "trapped"),
                           steps=int(length))


def test_summary_figures_spl_and_length_ratio():
    evalset = validation.EvalSet((), np.array([True, True, False, False]), np.array([4.0, 5.0, 2.0, np.nan]))
    episodes = [_episode(True, 8.0), _episode(False, 3.0, "collision"), _episode(True, 2.0), _episode(True, 7.0)]
    s = validation.summarise(episodes, evalset)
    assert s["success"] == 0.75 and s["trap_success"] == 0.5 and s["collisions"] == 1
    assert s["length_ratio"] == pytest.approx((8 + 2) / (4 + 2))     # successes with an A* length
    assert s["spl"] == pytest.approx((4 / 8 + 0 + 1 + 1) / 4)          # no A* length: counts as 1
    none = validation.summarise([_episode(False, 1.0)], validation.EvalSet((), np.array([False]), np.array([3.0])))
    assert none["trap_success"] is None and none["length_ratio"] is None and none["spl"] == 0


def test_score_orders_by_the_selected_figures():
    a = {"success": 0.9, "collisions": 0, "spl": 0.7}
    b = {"success": 1.0, "collisions": 2, "spl": 0.8}
    assert validation.score(b, ("success",)) > validation.score(a, ("success",))
    assert validation.score(a, ("-collisions", "spl")) > validation.score(b, ("-collisions", "spl"))
    assert validation.score(a, ("success", "world_starts_success")) == (0.9, -np.inf)  # a missing figure ranks lowest


# ---------------------------------------------------------------------------- training


def test_training_learns_the_tiny_world():
    """Can fail: the greedy policy must reach the target from every start, trap starts included."""
    config = tiny_config(total_steps=20_000)
    result = train(config, phases_for_world(tiny_world(), config))
    evaluations = [row["validation_success"] for row in result.history if row["validation_success"] != ""]
    assert evaluations[0] < 1.0                                   # not solved before learning
    assert result.best["success"] == 1.0 and result.best["trap_success"] == 1.0 and result.stopped_early
    assert result.counters.time_to_target is not None and result.global_step < 20_000


def test_the_target_network_is_evaluated_and_kept_when_asked(tmp_path):
    """``eval_network: target``: the network evaluated and written to best.pt is the target network (the average
    of the online weights), not the online one; the checkpoint holds both."""
    config = tiny_config(total_steps=1_000, eval_every=1_000, target_success=None, eval_network="target")
    train(config, phases_for_world(tiny_world(), config), out_dir=tmp_path)   # one evaluation: at the end
    _, tensors = read_file(tmp_path / "last.pt")
    best = load_model(tmp_path / "best.pt").network.state_dict()
    for name, value in best.items():
        assert torch.equal(value, tensors["target_network"][name]), name
    assert not all(torch.equal(value, tensors["q_network"][name]) for name, value in best.items())
    with pytest.raises(UserError, match="eval_network 'target' needs a target network"):
        tiny_config(eval_network="target", target_update="none")


def test_training_writes_log_plot_and_models_evaluated_as_eval_runs_them(tmp_path):
    world = tiny_world()
    config = tiny_config(total_steps=2_000, target_success=None)
    result = train(config, phases_for_world(world, config), out_dir=tmp_path)
    rows = read_csv(tmp_path / "train.csv")
    assert tuple(rows[0]) == CSV_COLUMNS
    steps = [int(r["global_step"]) for r in rows]
    assert steps == sorted(steps) and steps[-1] == result.global_step >= 2_000
    assert (tmp_path / "train.png").read_bytes().startswith(b"\x89PNG")
    assert {p.name for p in result.written} >= {"train.csv", "best.pt", "last.pt", "train.png"}
    assert not (tmp_path / "train.lock").exists() and not list(tmp_path.glob(".*.tmp"))
    for name in ("best.pt", "last.pt"):
        model = load_model(tmp_path / name, expect_obs_shape=(1, 5, 5), expect_field=TINY_FIELD)
        assert model.observer == config.observer and model.meta["obs_transform"] == "relative-log"
        assert load_checkpoint_config(tmp_path / name) == config
    best = load_model(tmp_path / "best.pt").meta["training"]
    assert best["evaluation"] == result.best and best["evaluation_step"] == result.counters.best_step
    # the trainer's figures are those of `apf-physics eval --planner dqn-unshielded --model best.pt`
    episodes = evaluate(make_planner("dqn-unshielded", str(tmp_path / "best.pt")), [world]).episodes
    assert np.mean([e.success for e in episodes]) == result.best["success"]
    assert sum(e.outcome == "collision" for e in episodes) == result.best["collisions"]
    policy = DQNPolicy.load(tmp_path / "best.pt")
    obs = np.random.default_rng(0).random((7, 1, 5, 5), dtype=np.float32) * 50
    np.testing.assert_array_equal(policy.act(obs), policy.q_values(obs).argmax(1))


def test_the_same_seed_gives_the_same_run(tmp_path):
    """Runs stop by steps and evaluations, not the clock: two runs of one configuration and seed write the same
    train.csv (but for wall_time) and the same best.pt; another seed does not."""
    config = tiny_config(total_steps=1_500, eval_every=500, target_success=None, train_starts="reachable",
                         failure_starts=0.5, n_step=3, eval_network="target")
    phases = phases_for_world(tiny_world(), config)
    other = replace(config, seed=1)
    for c, name in ((config, "a"), (config, "b"), (other, "c")):
        train(c, phases if c is config else phases_for_world(tiny_world(), other), out_dir=tmp_path / name)
    a, b, c = ([{k: v for k, v in row.items() if k != "wall_time"} for row in read_csv(tmp_path / name / "train.csv")]
               for name in "abc")
    assert a == b and a != c
    best = [load_model(tmp_path / name / "best.pt").network.state_dict() for name in "ab"]
    assert all(torch.equal(best[0][k], best[1][k]) for k in best[0])


@pytest.mark.parametrize("starts", [{}, {"train_starts": "reachable", "failure_starts": 0.5, "n_step": 3}])
def test_resumed_run_continues_exactly_as_an_uninterrupted_one(tmp_path, starts):
    config = tiny_config(total_steps=3_000, checkpoint_every=1_500, eval_every=500, target_success=None,
                         save_buffer=True, **starts)
    phases = phases_for_world(tiny_world(), config)
    straight = train(config, phases, out_dir=tmp_path / "straight")
    # stopped where the uninterrupted run writes its first checkpoint, then resumed
    first = train(replace(config, total_steps=1_500), phases, out_dir=tmp_path / "resumed")
    assert first.global_step >= 1_500 and first.stop_reason == "total_steps 1500 reached"
    resumed = train(config, phases, out_dir=tmp_path / "resumed", resume=True)
    assert resumed.history[0]["global_step"] > first.global_step          # it went on from the checkpoint
    assert resumed.global_step == straight.global_step and resumed.episodes == straight.episodes
    assert resumed.updates == straight.updates and resumed.best == straight.best
    for name, value in straight.network.state_dict().items():
        assert torch.equal(resumed.network.state_dict()[name], value), name
    a, b = (read_csv(tmp_path / d / "train.csv") for d in ("straight", "resumed"))
    assert [{k: v for k, v in r.items() if k != "wall_time"} for r in a] == \
        [{k: v for k, v in r.items() if k != "wall_time"} for r in b]


def test_resume_refuses_other_options_and_a_finished_run_trains_no_more(tmp_path):
    config = tiny_config(total_steps=1_000, target_success=None)
    phases = phases_for_world(tiny_world(), config)
    train(config, phases, out_dir=tmp_path)
    with pytest.raises(UserError, match="already holds a training run"):
        train(config, phases, out_dir=tmp_path)
    with pytest.raises(UserError, match="different options \\(batch_size\\)"):
        train(tiny_config(total_steps=1_000, target_success=None, batch_size=32), phases, out_dir=tmp_path, resume=True)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    again = train(config, phases, out_dir=tmp_path, resume=True)
    assert again.already_finished and again.stop_reason == "total_steps 1000 reached" and again.written == []
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    longer = train(tiny_config(total_steps=1_500, target_success=None), phases, out_dir=tmp_path, resume=True)
    assert not longer.already_finished and longer.global_step >= 1_500


def test_output_folder_is_locked_and_names_the_holder(tmp_path):
    with RunDir(tmp_path, CSV_COLUMNS):
        with pytest.raises(UserError, match=f"in use by another training run \\(pid {os.getpid()} on "):
            RunDir(tmp_path, CSV_COLUMNS)
        config = tiny_config(total_steps=500)
        with pytest.raises(UserError, match="in use by another training run"):
            train(config, phases_for_world(tiny_world(), config), out_dir=tmp_path)
    with RunDir(tmp_path, CSV_COLUMNS):  # released
        pass


def test_stale_temporaries_are_removed_when_a_run_takes_the_folder(tmp_path):
    stale = tmp_path / ".last.pt.abc123.tmp"
    stale.write_bytes(b"half a file")
    keep = tmp_path / "notes.tmp"
    keep.write_text("not ours")
    with RunDir(tmp_path, CSV_COLUMNS) as run:
        assert run.removed_temporaries == [stale]
    assert not stale.exists() and keep.exists()


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_measures_the_stop_rule_and_shows_the_latest_evaluation(monkeypatch):
    world = tiny_world()
    texts = []
    for options in ({"total_steps": 20_000}, {"total_steps": None, "time_limit": 2.0, "target_success": None}):
        terminal = _Terminal()
        monkeypatch.setattr(sys, "stderr", terminal)
        config = tiny_config(**options)
        train(config, phases_for_world(world, config), progress=True)
        texts.append(terminal.getvalue())
    target, timed = texts
    # a target_success run shows its step budget and says it stops at the target; it ends on 100 %
    assert "/20000 [" in target and "until 100% of the validation starts" in target
    assert "validation starts -" in target and "validation starts 100.0%" in target.split("\r")[-1]
    # a time-limited run counts seconds up to its limit, and says nothing of a target
    assert re.search(r"2\.0/2\.0 \[.*s/s", timed) and "until" not in timed
    assert re.search(r"validation starts [\d.]+%", timed) and "world starts" not in timed  # they are the same
    logged = io.StringIO()  # not a terminal (nohup, CI, a notebook): no bar, a plain line per row of train.csv
    monkeypatch.setattr(sys, "stderr", logged)
    result = train(config, phases_for_world(world, config), progress=True)
    lines = logged.getvalue().splitlines()
    assert "\r" not in logged.getvalue() and len(lines) == len(result.history) >= 2
    assert all(re.fullmatch(r"train: step [\d,]+, phase tiny, episodes [\d,]+, .*\d+ s", line) for line in lines)
    assert re.search(r", validation starts [\d.]+%, ", lines[-1]) and "loss" in lines[-1]
    # with random validation starts, the world's own starts are shown beside them, by the same names as train.csv
    config = tiny_config(eval_random_starts=20)
    shown = Progress(config, phases_for_world(world, config), Counters(), stream=io.StringIO())
    assert shown.figures({"success": 0.95, "world_starts_success": 5 / 6}, 0) == "validation starts 95.0%, world starts 5/6"
    assert shown.figures(None, 0) == "validation starts -"
    terminal = _Terminal()  # the bar says both targets: the fast preset's world-starts target applies here
    Progress(config, phases_for_world(world, config), Counters(), stream=terminal).close()
    assert "until 100% of the validation starts and 100% of the world starts" in terminal.getvalue()


def test_tensorboard_logs_beside_train_csv(tmp_path):
    pytest.importorskip("tensorboard", reason="the [tensorboard] extra is not installed")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config = tiny_config(total_steps=1_000, target_success=None)
    result = train(config, phases_for_world(tiny_world(), config), out_dir=tmp_path)
    events = EventAccumulator(str(tmp_path / "tensorboard"))
    events.Reload()
    rows = [r for r in read_csv(tmp_path / "train.csv") if r["validation_success"] != ""]
    assert [(e.step, round(e.value, 4)) for e in events.Scalars("validation_success")] == \
        [(int(r["global_step"]), float(r["validation_success"])) for r in rows]
    assert tmp_path / "tensorboard" in result.written


# ---------------------------------------------------------------------------- the command line


def _cli(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "apf_physics.cli", "train", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


def _wait_for(condition, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "training did not get there in time"
        time.sleep(0.05)


def test_kill_9_leaves_loadable_models_and_resume_carries_on(tmp_path):
    world = write_tiny_world(tmp_path)
    out = tmp_path / "run"
    options = [f"--set={k}={v}" for k, v in {**TINY_OPTIONS, "filters": "[8, 8]", "select": "[success, world_starts_success]", "total_steps": 10**7,
                                             "target_success": "null", "checkpoint_every": 500}.items()]
    proc = _cli("--world", str(world), "--out", str(out), "--no-progress", *options)
    _wait_for(lambda: (out / "best.pt").exists() and (out / "last.pt").exists(), proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    step = read_file(out / "last.pt")[0]["trainer"]["counters"]["global_step"]
    assert load_model(out / "best.pt").network is not None and step >= 500
    (out / ".last.pt.killed.tmp").write_bytes(b"half")        # what a kill during a write leaves
    done = _cli("--world", str(world), "--out", str(out), "--resume", "--no-progress",
                f"--set=total_steps={step + 700}")
    stdout, stderr = done.communicate(timeout=300)
    assert done.returncode == 0, stderr
    assert "trained" in stdout and not (out / ".last.pt.killed.tmp").exists()
    assert read_file(out / "last.pt")[0]["trainer"]["counters"]["global_step"] >= step + 700
    again = _cli("--world", str(world), "--out", str(out), "--resume")
    stdout, _ = again.communicate(timeout=300)
    assert again.returncode == 0 and "already finished" in stdout


def test_interrupt_saves_and_prints_the_resume_command_and_a_second_run_is_refused(tmp_path):
    world = write_tiny_world(tmp_path)
    out = tmp_path / "run"
    options = [f"--set={k}={v}" for k, v in {**TINY_OPTIONS, "filters": "[8, 8]", "select": "[success, world_starts_success]", "total_steps": 10**7,
                                             "target_success": "null", "eval_every": 10**6}.items()]
    proc = _cli("--world", str(world), "--out", str(out), *options)
    _wait_for(lambda: len(read_csv(out / "train.csv")) >= 2 if (out / "train.csv").exists() else False, proc)
    second = _cli("--world", str(world), "--out", str(out), "--resume")
    _, err = second.communicate(timeout=300)
    assert second.returncode == 2 and f"is in use by another training run (pid {proc.pid} on " in err
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert f"apf-physics train --world {world} --out {out} --resume" in stderr
    assert not (out / "best.pt").exists() and "wrote" not in stdout       # no evaluation ran
    assert read_file(out / "last.pt")[0]["trainer"]["counters"]["global_step"] > 0


@pytest.mark.parametrize("options", [["--set", "batch_sise=64"], ["--set", "batch_size=-1"], ["--preset", "general"],
                                     ["--config", "missing.yaml"], ["--resume"]])
def test_a_refused_train_command_leaves_nothing_behind(tmp_path, capsys, options):
    """A mistyped option, a bad value, a preset for curricula, a missing file, nothing to resume: refused in
    one line (status 2) before the output folder is made."""
    from apf_physics.cli import main

    world = write_tiny_world(tmp_path)
    out = tmp_path / "runs" / "new"
    assert main(["train", "--world", str(world), "--out", str(out), *options]) == 2
    assert capsys.readouterr().err.count("apf-physics: error:") == 1
    assert not (tmp_path / "runs").exists()
    out.mkdir(parents=True)   # an existing folder is left as it was
    assert main(["train", "--world", str(world), "--out", str(out), *options]) == 2
    assert list(out.iterdir()) == []


def test_cli_overrides_are_read_as_yaml():
    from apf_physics.cli.train import parse_overrides

    assert parse_overrides(["total_steps=5000", "double_dqn=false", "filters=[4, 4]", "max_grad_norm=null",
                            "learning_rate=1e-4"]) == {
        "total_steps": 5000, "double_dqn": False, "filters": [4, 4], "max_grad_norm": None, "learning_rate": 1e-4}
    with pytest.raises(UserError, match="KEY=VALUE"):
        parse_overrides(["total_steps"])


# ---------------------------------------------------------------------------- model files


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("model")
    config = tiny_config(total_steps=500, eval_every=250)
    train(config, phases_for_world(tiny_world(), config), out_dir=out)
    return out / "best.pt"


def test_load_model_refuses_a_missing_file(tmp_path):
    with pytest.raises(ModelError, match=f"{tmp_path / 'none.pt'}: no such model file"):
        load_model(tmp_path / "none.pt")


def test_load_model_refuses_truncated_and_corrupt_files(model_file, tmp_path):
    data = model_file.read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(data[: len(data) - 100])
    with pytest.raises(ModelError, match="truncated.pt: truncated or corrupt"):
        load_model(truncated)
    flipped = bytearray(data)
    flipped[-50] ^= 0xFF
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(bytes(flipped))
    with pytest.raises(ModelError, match="corrupt.pt: corrupt model file \\(SHA-256"):
        load_model(corrupt)
    header_gone = tmp_path / "header.pt"
    header_gone.write_bytes(MAGIC + b"{not json\n" + data[200:])
    with pytest.raises(ModelError, match="header.pt: corrupt model file"):
        load_model(header_gone)
    foreign = tmp_path / "foreign.pt"
    torch.save({"q_network": {}}, foreign)
    with pytest.raises(ModelError, match="foreign.pt: not an apf-physics model file"):
        load_model(foreign)


def test_load_model_refuses_another_format_version(model_file, tmp_path):
    newer = tmp_path / "newer.pt"
    newer.write_bytes(model_file.read_bytes().replace(b'"format_version": 1', b'"format_version": 99', 1))
    with pytest.raises(ModelError, match="newer.pt: model file format version 99"):
        load_model(newer)


def test_load_model_refuses_a_mismatched_observation_or_field(model_file):
    assert load_model(model_file, expect_obs_shape=(1, 5, 5), expect_field=TINY_FIELD).obs_shape == (1, 5, 5)
    with pytest.raises(ModelError, match=r"best.pt: the model expects observations of shape \(1, 5, 5\)"):
        load_model(model_file, expect_obs_shape=(1, 11, 11))
    other = {**TINY_FIELD.as_dict(), "p0": 3.0}
    with pytest.raises(ModelError, match=r"best.pt: the model was trained in another field: p0=0.5 \(world: 3\)"):
        load_model(model_file, expect_field=other)
    with pytest.raises(ModelError, match="best.pt: the model expects"):
        DQNPolicy.load(model_file, expect_obs_shape=(1, 9, 9))


def test_write_file_replaces_atomically_and_leaves_no_temporaries(tmp_path):
    path = tmp_path / "m.pt"
    net = QNetwork(obs_shape=(1, 5, 5), filters=(4, 4))
    meta = {"arch": net.arch, "obs_shape": [1, 5, 5], "field": TINY_FIELD.as_dict(), "kind": "model"}
    write_file(path, meta, {"q_network": net.state_dict()})
    write_file(path, meta, {"q_network": net.state_dict()})
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]
    torch.testing.assert_close(load_model(path).network.state_dict(), net.state_dict())


# ---------------------------------------------------------------------------- starts


def test_reachable_mask_is_integer_moves_within_the_tolerance(worlds_dir):
    from apf_physics.world.io.worldfile import load_world

    points = np.array([[1.0, 1.0], [12.5, 15.5], [3.3, 7.2], [3.4, 7.4], [16.6, 16.0]])
    half = SimpleNamespace(targets=np.array([[16.0, 16.0]]), goal_tolerance=0.5)
    assert reachable_mask(half, points).tolist() == [True, False, True, False, True]
    wide = SimpleNamespace(targets=half.targets, goal_tolerance=0.75)  # > √2/2: every start can succeed
    assert reachable_mask(wide, points).all()
    world = load_world(worlds_dir / "fixed20.yaml")
    assert reachable_mask(world, world.starts).all()


def test_lattice_reachable_and_validation_starts(worlds_dir):
    from apf_physics.world.io.worldfile import load_world

    world = load_world(worlds_dir / "fixed20.yaml")
    lattice = training_starts(world, "lattice", seed=0)
    assert np.array_equal(lattice, np.round(lattice)) and world.is_free(lattice).all()
    assert {tuple(p) for p in world.starts} <= {tuple(p) for p in lattice}
    assert not any(np.hypot(*(p - world.targets[0])) <= world.goal_tolerance for p in lattice)
    reachable = training_starts(world, "reachable", seed=0, count=2_000)
    assert 0 < len(reachable) <= 2_000 and reachable_mask(world, reachable).all() and world.is_free(reachable).all()
    assert training_starts(world, "random", seed=0) == "random"
    val = validation_starts(world, 50, seed=0)
    assert val.shape == (50, 2) and reachable_mask(world, val).all()
    assert np.array_equal(val, validation_starts(world, 50, seed=0))
    assert not np.isin(val, reachable).any()  # a stream of its own
    (phase,) = phases_for_world(world, preset("fast", eval_random_starts=20))
    assert phase.validation.starts == 20 and phase.world_starts.starts == 40
    assert phase.validation.trapped is None     # random validation starts are not labelled: success and collisions
    (own,) = phases_for_world(world, preset("fast", eval_random_starts=0))
    assert own.validation is own.world_starts and own.validation.starts == 40


def test_a_list_of_whole_numbers_sets_a_tuple_of_floats():
    from apf_physics.learning.config import preset, replace
    config = replace(preset("map"), map_sizes=[50, 100, 250])
    assert config.schedule.map_sizes == (50.0, 100.0, 250.0)
    with pytest.raises(UserError, match="map_sizes must be a list of float"):
        replace(preset("map"), map_sizes=["big"])


def test_a_diverging_run_stops_and_says_what_to_change(tmp_path):
    # a learning rate far too large for the thesis's MSE on raw rewards: the loss explodes
    config = tiny_config(loss="mse", reward_scale=1.0, max_grad_norm=None, learning_rate=50.0, loss_limit=1e6,
                         target_success=None, total_steps=3_000, log_every=100)
    result = train(config, phases_for_world(tiny_world(), config), out_dir=tmp_path / "run")
    assert result.diverged and result.global_step < 3_000
    assert result.stop_reason.startswith("diverged: the mean loss reached") and "learning_rate" in result.stop_reason
    last = read_csv(tmp_path / "run" / "train.csv")[-1]
    assert last["loss"] in ("nan", "inf") or float(last["loss"]) > 1e6
    # the checkpoint keeps it: resuming does not train on
    again = train(config, phases_for_world(tiny_world(), config), out_dir=tmp_path / "run", resume=True)
    assert again.already_finished and again.diverged


def test_train_prints_progress_lines_and_a_finished_run_names_the_limit_to_lift(tmp_path):
    world = write_tiny_world(tmp_path)
    out = tmp_path / "run"
    options = [f"--set={k}={v}" for k, v in {**TINY_OPTIONS, "total_steps": 600, "eval_every": 300,
                                              "log_every": 300}.items() if not isinstance(v, tuple)]
    done = subprocess.run([sys.executable, "-m", "apf_physics.cli", "train", "--world", str(world), "--out", str(out),
                           "--set", "filters=[8, 8]", *options], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.startswith("train: step")]
    assert len(lines) >= 2 and "\r" not in done.stderr            # stderr is a pipe: lines, no bar
    assert (out / "config.yaml").is_file() and load_config(out / "config.yaml").schedule.total_steps == 600
    again = subprocess.run([sys.executable, "-m", "apf_physics.cli", "train", "--world", str(world), "--out",
                            str(out), "--resume"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "has already finished" in again.stdout
    reason = "target_success=null" if "target_success" in again.stdout.split("nothing more")[0] else "total_steps="
    assert f"--resume --set {reason}" in again.stdout


def test_the_target_is_measured_on_the_validation_starts_not_the_world_starts():
    from apf_physics.learning.trainer import Evaluations, stop_reason
    config = tiny_config(target_success=0.9, target_world_starts=None, eval_random_starts=20)
    phases = phases_for_world(tiny_world(), config)
    c, evals = Counters(), Evaluations()
    net = torch.nn.Linear(1, 1)
    evals.record({"success": 0.5, "world_starts_success": 1.0}, c, net, config)   # every world start, few others
    assert c.top_success == 0.5 and stop_reason(config, phases, c, 0.0) is None
    evals.record({"success": 0.95, "world_starts_success": 0.8}, c, net, config)
    assert stop_reason(config, phases, c, 0.0) == "target_success 0.9 of the validation starts reached"


def test_with_a_world_starts_target_one_evaluation_must_meet_both_targets_and_is_preferred_as_best():
    """``target_world_starts``: the run stops only at an evaluation that meets it and ``target_success``
    together, and ``best.pt`` prefers such an evaluation to a better-scoring one that misses either."""
    from apf_physics.learning.trainer import Evaluations, stop_reason
    config = tiny_config(target_success=0.9, target_world_starts=1.0, eval_random_starts=20)
    phases = phases_for_world(tiny_world(), config)
    c, evals = Counters(), Evaluations()
    net = torch.nn.Linear(1, 1)
    assert evals.record({"success": 0.5, "world_starts_success": 1.0}, c, net, config)
    assert evals.record({"success": 0.97, "world_starts_success": 0.8}, c, net, config)   # validation target only
    assert stop_reason(config, phases, c, 0.0) is None and c.time_to_target is None
    assert evals.record({"success": 0.92, "world_starts_success": 1.0}, c, net, config)   # both: best, though lower
    assert evals.best["success"] == 0.92 and c.time_to_target is not None
    assert stop_reason(config, phases, c, 0.0) == ("target_success 0.9 of the validation starts reached "
                                                   "with target_world_starts 1 of the world starts")
    assert not evals.record({"success": 0.99, "world_starts_success": 5 / 6}, c, net, config)  # misses one
    assert evals.record({"success": 0.95, "world_starts_success": 1.0}, c, net, config)   # both, then select
    assert evals.best["success"] == 0.95
    # where the world starts are the validation starts, only target_success counts
    same = tiny_config(target_success=0.9, target_world_starts=1.0, eval_random_starts=0)
    c, evals = Counters(), Evaluations()
    evals.record({"success": 0.95, "world_starts_success": 0.95}, c, net, same)
    assert stop_reason(same, phases_for_world(tiny_world(), same), c, 0.0) == \
        "target_success 0.9 of the validation starts reached"
    with pytest.raises(UserError, match="target_world_starts must be in"):
        tiny_config(target_world_starts=1.5)
    assert preset("fast").schedule.target_world_starts == 1.0


def test_a_run_that_meets_the_validation_target_but_not_the_world_starts_target_goes_on():
    """A world start that can never be reached (walled into a corner): the run meets ``target_success`` on
    the random validation starts early, yet with ``target_world_starts`` it trains to its step budget;
    without it, it stops at that evaluation."""
    world = world_from_dict({**TINY, "name": "tiny-pocket",
                             "obstacles": TINY["obstacles"] + [{"polygon": [[0, 6.8], [1.3, 6.8], [1.3, 7.0], [0, 7.0]]},
                                                               {"polygon": [[1.1, 7.0], [1.3, 7.0], [1.3, 8], [1.1, 8]]}],
                             "starts": TINY["starts"] + [[0.5, 7.5]]})
    options = dict(eval_random_starts=20, target_success=0.5, total_steps=5_000, eval_every=500)
    held = tiny_config(**options, target_world_starts=1.0)
    result = train(held, phases_for_world(world, held))
    evaluations = [row for row in result.history if row["validation_success"] != ""]
    assert any(row["validation_success"] >= 0.5 for row in evaluations)
    assert all(row["world_starts_success"] < 1.0 for row in evaluations)
    assert result.stop_reason == "total_steps 5000 reached" and not result.stopped_early
    assert result.global_step >= 5_000 and result.counters.time_to_target is None
    alone = tiny_config(**options, target_world_starts=None)
    early = train(alone, phases_for_world(world, alone))
    assert early.stopped_early and early.global_step < 5_000
    first = next(row for row in early.history if row["validation_success"] != "" and row["validation_success"] >= 0.5)
    assert early.global_step == first["global_step"]


def test_show_config_names_the_layer_each_value_comes_from():
    """Every option of a preset is shown with its value as the preset has it, and the layer that set
    it: a chained preset's option is credited to the preset that changed it, a --set to --set."""
    from apf_physics.learning.config import LAYERS, PRESETS, explain

    for name in PRESETS:
        rows = {option.rpartition(".")[2]: (value, source) for option, value, source in explain(name)}
        assert {k: v for k, (v, _) in rows.items()} == preset(name).options()
        assert rows["preset"] == (name, "the preset chosen")
        for option, (value, source) in rows.items():
            if source == "default":
                assert option not in PRESETS[name]
    moving = {option: source for option, _, source in explain("moving", {"learning_rate": 3e-4})}
    assert moving["env.memory"] == "preset general-memory" and moving["env.previous"] == "preset moving"
    assert moving["dqn.loss"].startswith("fast learner") and moving["network.learning_rate"] == "--set"
    assert moving["dqn.gamma"] == "default" and "fast learner" in LAYERS
    # an option is shown as section.option; the two outside any section by their names alone
    names = [option for option, _, _ in explain("map")]
    assert names[:2] == ["preset", "method"] and all(name.count(".") == 1 for name in names[2:])
    assert {name.split(".")[0] for name in names[2:]} == {"env", "dqn", "network", "schedule", "evaluation", "run",
                                                          "imitation"}


def test_train_show_config_trains_nothing_and_needs_no_out(tmp_path, capsys):
    from apf_physics.cli import main

    assert main(["train", "--world", "worlds/fixed20.yaml", "--show-config", "--set", "batch_size=256"]) == 0
    out = capsys.readouterr().out
    assert any(line.split()[:2] == ["dqn.batch_size", "256"] and line.split()[-1] == "--set" for line in out.splitlines())
    assert main(["train", "--world", "worlds/fixed20.yaml"]) == 2   # training needs --out
    assert not list(tmp_path.iterdir())
