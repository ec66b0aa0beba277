"""The DQN learner: network, experience pool, training loop, checkpoints and model files.

Training runs use the tiny grid world of ``rl_stub_env`` so the learner is tested alone
and fast.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from apf_physics.errors import ModelError, UserError
from apf_physics.rl import (
    DQNPolicy,
    QNetwork,
    ReplayBuffer,
    epsilon_schedule,
    load_model,
    max_pool_2x2_stride1,
    preset,
    relative_log,
    train,
)
from apf_physics.models.files import MAGIC, read_file, write_file
from apf_physics.rl.dqn import CSV_COLUMNS, DQNConfig, load_checkpoint_config
from rl_stub_env import StubVectorEnv, StubWorld, stub_env_factory

STUB_FIELD = StubWorld().field


def stub_config(**overrides) -> DQNConfig:
    """The ``fast`` recipe scaled to the 7×7 stub world."""
    options = dict(obs_size=5, filters=(8, 8), num_envs=16, batch_size=64, learning_starts=200,
                   exploration_episodes=300, total_steps=3_000, eval_every=1_000, log_every=500,
                   checkpoint_every=1_000, max_episode_steps=30, seed=0, train_starts="random")
    options.update(overrides)
    return preset("fast", **options)


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


@pytest.mark.parametrize("name, k, params", [("thesis-fixed", 11, 25_705), ("thesis-general", 9, 4_673)])
def test_thesis_networks_have_the_tables_layers(name, k, params):
    config = preset(name)
    assert config.obs_size == k
    net = config.network()
    assert sum(p.numel() for p in net.parameters()) == params
    assert [c.out_channels for c in net.convs] == list(config.filters)
    assert [layer.out_features for layer in net.hidden] == [32, 32]
    out = net(torch.zeros(5, 1, k, k))
    assert out.shape == (5, 9)


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


def test_observation_transform_is_part_of_the_saved_network(tmp_path):
    raw = QNetwork(obs_shape=(1, 5, 5), filters=(4, 4), obs_transform="raw")
    logged = QNetwork(obs_shape=(1, 5, 5), filters=(4, 4), obs_transform="relative-log")
    logged.load_state_dict(raw.state_dict())
    obs = torch.rand(3, 1, 5, 5) * 100
    torch.testing.assert_close(logged(obs), raw(relative_log(obs)))


# ---------------------------------------------------------------------------- config


def test_thesis_presets_stay_as_written():
    fixed = preset("thesis-fixed")
    assert (fixed.loss, fixed.batch_size, fixed.target_update, fixed.obs_transform) == ("mse", 7, "none", "raw")
    assert (fixed.gamma, fixed.learning_rate, fixed.epsilon_initial, fixed.epsilon_final) == (0.95, 1e-3, 0.95, 0.05)
    assert fixed.exploration_episodes == fixed.total_episodes == 30_000
    assert fixed.filters == (10, 10, 20) and not fixed.double_dqn and fixed.reward_scale == 1.0
    general = preset("thesis-general")
    assert (general.obs_size, general.filters, general.exploration_episodes) == (9, (4, 4), 150)
    fast = preset("fast")
    assert (fast.num_envs, fast.batch_size, fast.loss, fast.double_dqn, fast.target_update, fast.tau) == (
        64, 128, "huber", True, "soft", 0.01)
    assert (fast.reward_scale, fast.obs_transform, fast.train_starts) == (1e-3, "relative-log", "lattice")


def test_preset_rejects_unknown_names_keys_and_values():
    with pytest.raises(UserError, match="unknown training preset"):
        preset("nope")
    with pytest.raises(UserError, match="unknown training option.*batchsize"):
        preset("fast", batchsize=3)
    with pytest.raises(UserError, match="loss"):
        preset("fast", loss="l1")
    assert preset("fast", filters=[4, 4], max_grad_norm=1).filters == (4, 4)
    assert DQNConfig.from_dict(preset("fast").to_dict()) == preset("fast")


def test_epsilon_schedule_is_specs_eq_34():
    config = preset("thesis-fixed", exploration_episodes=100)
    assert epsilon_schedule(config, 0) == pytest.approx(0.95)
    assert epsilon_schedule(config, 50) == pytest.approx(0.475)
    assert epsilon_schedule(config, 99) == pytest.approx(0.05)
    assert epsilon_schedule(config, 10_000) == 0.05


# ---------------------------------------------------------------------------- buffer


def test_replay_buffer_wraps_samples_and_round_trips():
    buffer = ReplayBuffer(capacity=5, obs_shape=(1, 3, 3), batch_size=4)
    for start in (0, 3):
        ids = np.arange(start, start + 3)
        obs = np.broadcast_to(ids[:, None, None, None], (3, 1, 3, 3)).astype(np.float32)
        buffer.add(obs, obs + 100, ids, ids * 10.0, ids % 2 == 0)
    assert len(buffer) == 5 and buffer.pos == 1
    assert sorted(buffer.actions.tolist()) == [1, 2, 3, 4, 5]  # 0 was overwritten
    batch = buffer.sample(np.random.default_rng(0))
    assert batch.observations.shape == (4, 1, 3, 3) and batch.actions.shape == (4, 1)
    a = batch.actions[:, 0].numpy()
    np.testing.assert_array_equal(batch.observations[:, 0, 0, 0].numpy(), a)
    np.testing.assert_array_equal(batch.next_observations[:, 0, 1, 1].numpy(), a + 100)
    np.testing.assert_array_equal(batch.rewards.numpy(), a * 10.0)
    np.testing.assert_array_equal(batch.dones.numpy(), a % 2 == 0)
    copy = ReplayBuffer(capacity=5, obs_shape=(1, 3, 3), batch_size=4)
    copy.load_state_dict(buffer.state_dict())
    assert (copy.pos, copy.size) == (buffer.pos, buffer.size)
    np.testing.assert_array_equal(copy.next_observations, buffer.next_observations)


def test_stub_env_autoresets_next_step():
    env = StubVectorEnv(StubWorld(), num_envs=1, starts=np.array([[4, 5]]), obs_size=5)
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(np.array([3]))  # right: onto the target
    assert terminated[0] and info["success"][0] and reward[0] > 900
    obs, reward, terminated, truncated, _ = env.step(np.array([3]))
    assert reward[0] == 0 and not terminated[0] and not truncated[0]
    assert env.pos.tolist() == [[4, 5]] and obs[0, 0, 2, 3] < obs[0, 0, 2, 2]


# ---------------------------------------------------------------------------- training


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_training_writes_log_plot_and_checkpoints(tmp_path):
    result = train(stub_config(total_steps=1_500), StubWorld(), out_dir=tmp_path,
                   env_factory=stub_env_factory, progress=False)
    assert result.global_step >= 1_500 and result.updates > 0 and result.episodes > 0
    rows = read_csv(tmp_path / "train.csv")
    assert tuple(rows[0]) == CSV_COLUMNS
    steps = [int(r["global_step"]) for r in rows]
    assert steps == sorted(steps) and steps[-1] <= result.global_step
    assert any(r["eval_success"] != "" for r in rows)
    png = (tmp_path / "train.png").read_bytes()
    assert png.startswith(b"\x89PNG")
    for name in ("best.pt", "last.pt"):
        model = load_model(tmp_path / name, expect_obs_shape=(1, 5, 5), expect_field=STUB_FIELD)
        assert model.meta["config"]["preset"] == "fast" and model.obs_shape == (1, 5, 5)
        assert model.meta["obs_transform"] == "relative-log"
        assert model.field == {"katt": 2.0, "krep": 20.0, "kstr": 8.0, "p0": 0.5, "ps": 8.0, "u_max": 100.0}
    policy = DQNPolicy.load(tmp_path / "best.pt")
    obs = np.random.default_rng(0).random((7, 1, 5, 5), dtype=np.float32) * 50
    actions = policy.act(obs)
    assert actions.shape == (7,) and actions.dtype == np.int64 and ((0 <= actions) & (actions < 9)).all()
    np.testing.assert_array_equal(actions, policy.q_values(obs).argmax(1))
    assert load_checkpoint_config(tmp_path / "last.pt") == result.config


class InterruptingFactory:
    """Builds stub envs whose training env raises KeyboardInterrupt after ``after`` steps."""

    def __init__(self, after: int):
        self.after = after

    def __call__(self, world, *, num_envs, seed, starts, config):
        env = stub_env_factory(world, num_envs=num_envs, seed=seed, starts=starts, config=config)
        if isinstance(starts, str):
            step, calls = env.step, [0]

            def interrupting_step(actions):
                calls[0] += 1
                if calls[0] > self.after:
                    raise KeyboardInterrupt
                return step(actions)

            env.step = interrupting_step
        return env


def test_interrupted_training_resumes_where_it_stopped(tmp_path):
    config = stub_config(total_steps=2_400, checkpoint_every=100_000, save_buffer=True)
    with pytest.raises(KeyboardInterrupt):
        train(config, StubWorld(), out_dir=tmp_path, env_factory=InterruptingFactory(after=60), progress=False)
    counters = read_file(tmp_path / "last.pt")[0]["counters"]
    assert counters["vector_steps"] == 60 and counters["global_step"] > 0
    first_rows = read_csv(tmp_path / "train.csv")
    interrupted_step = counters["global_step"]
    resumed = train(config, StubWorld(), out_dir=tmp_path, resume=True, env_factory=stub_env_factory, progress=False)
    assert resumed.global_step >= 2_400
    # counters continued instead of starting again: fewer steps were collected in this session
    assert resumed.history[0]["global_step"] > interrupted_step
    assert resumed.history[0]["episodes"] > int(first_rows[-1]["episodes"])
    steps = [int(r["global_step"]) for r in read_csv(tmp_path / "train.csv")]
    assert steps == sorted(steps) and len(set(steps)) == len(steps)
    with pytest.raises(UserError, match="different options.*batch_size"):
        train(stub_config(total_steps=2_400, batch_size=32), StubWorld(), out_dir=tmp_path, resume=True,
              env_factory=stub_env_factory, progress=False)


def test_training_learns_the_stub_world():
    """Can fail: the greedy policy must reach the target from every evaluation start."""
    result = train(stub_config(total_steps=20_000, target_success=1.0), StubWorld(),
                   env_factory=stub_env_factory, progress=False)
    assert result.best_eval_success == 1.0 and result.stopped_early
    assert result.time_to_target is not None and result.global_step < 20_000


# ---------------------------------------------------------------------------- model files


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("model")
    train(stub_config(total_steps=1_000, eval_every=500), StubWorld(), out_dir=out,
          env_factory=stub_env_factory, progress=False)
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
    data = model_file.read_bytes()
    newer = tmp_path / "newer.pt"
    newer.write_bytes(data.replace(b'"format_version": 1', b'"format_version": 99', 1))
    with pytest.raises(ModelError, match="newer.pt: model file format version 99"):
        load_model(newer)


def test_load_model_refuses_a_mismatched_observation_or_field(model_file):
    assert load_model(model_file, expect_obs_shape=(1, 5, 5), expect_field=STUB_FIELD).obs_shape == (1, 5, 5)
    with pytest.raises(ModelError, match=r"best.pt: the model expects observations of shape \(1, 5, 5\)"):
        load_model(model_file, expect_obs_shape=(1, 11, 11))
    other = {**STUB_FIELD.__dict__, "p0": 3.0}
    with pytest.raises(ModelError, match=r"best.pt: the model was trained in another field: p0=0.5 \(world: 3\)"):
        load_model(model_file, expect_field=other)
    with pytest.raises(ModelError, match="best.pt: the model expects"):
        DQNPolicy.load(model_file, expect_obs_shape=(1, 9, 9))


def test_write_file_replaces_atomically_and_leaves_no_temporaries(tmp_path):
    path = tmp_path / "m.pt"
    net = QNetwork(obs_shape=(1, 5, 5), filters=(4, 4))
    meta = {"arch": net.arch, "obs_shape": [1, 5, 5], "field": STUB_FIELD.__dict__, "kind": "model"}
    write_file(path, meta, {"q_network": net.state_dict()})
    write_file(path, meta, {"q_network": net.state_dict()})
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]
    loaded = load_model(path)
    torch.testing.assert_close(loaded.network.state_dict(), net.state_dict())


# ---------------------------------------------------------------------------- command line


def test_cli_overrides_are_read_as_yaml():
    from apf_physics.commands.train import parse_overrides

    assert parse_overrides(["total_steps=5000", "double_dqn=false", "filters=[4, 4]", "max_grad_norm=null",
                            "learning_rate=1e-4"]) == {
        "total_steps": 5000, "double_dqn": False, "filters": [4, 4], "max_grad_norm": None, "learning_rate": 1e-4}
    with pytest.raises(UserError, match="KEY=VALUE"):
        parse_overrides(["total_steps"])


# ---------------------------------------------------------------------------- starts


def test_reachable_mask_is_integer_moves_within_the_tolerance(worlds_dir):
    from apf_physics import load_world
    from apf_physics.rl.dqn import reachable_mask

    from types import SimpleNamespace

    points = np.array([[1.0, 1.0], [12.5, 15.5], [3.3, 7.2], [3.4, 7.4], [16.6, 16.0]])
    half = SimpleNamespace(targets=np.array([[16.0, 16.0]]), goal_tolerance=0.5)
    assert reachable_mask(half, points).tolist() == [True, False, True, False, True]
    wide = SimpleNamespace(targets=half.targets, goal_tolerance=0.75)  # > √2/2: every start can succeed
    assert reachable_mask(wide, points).all()
    world = load_world(worlds_dir / "fixed20.yaml")
    assert reachable_mask(world, world.starts).all()


def test_lattice_reachable_and_validation_starts(worlds_dir):
    from apf_physics import load_world
    from apf_physics.rl.dqn import reachable_mask, training_starts, validation_starts

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
