"""Rules with one definition each, called by every report, env, trainer and command that needs them.

The did-you-mean hint (errors), the atomic write (safefile), the signed log (transforms), an
evaluation's figures (evaluate.figures) and a formation's links and success (formation).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest
import torch

from apf_physics.experiments.movingai import bucket_summary
from apf_physics.errors import UserError, closest_match, did_you_mean
from apf_physics.experiments.evaluate import Evaluation, figures
from apf_physics.control.formation import Formations, FormationTeam, formation_success, link_lengths, links_in_range
from apf_physics.models.network import relative_log
from apf_physics.experiments.rollout import Episode, FormationRecord
from apf_physics.common.safefile import Replacement, atomic_path, check_writable, stale_temporaries, write_text
from apf_physics.common.transforms import signed_log
from apf_physics.world.core import FormationSpec


# -- did you mean ------------------------------------------------------------------------------
def test_did_you_mean_names_the_nearest_choice_or_nothing():
    assert did_you_mean("fsat", ("fast", "thesis-fixed")) == " (did you mean 'fast'?)"
    assert did_you_mean("zzz", ("fast", "thesis-fixed")) == ""
    assert closest_match("trinay", ["raw", "trinary", "scale"]) == "trinary"
    assert did_you_mean("tru", (1, True, "true")) == " (did you mean 'true'?)"    # a Literal's other choices
    for odd in (None, 3, ["fast"], "f" * 101):          # what a file holds is not always a name
        assert did_you_mean(odd, ("fast",)) == "" and closest_match(odd, ("fast",)) is None


# -- atomic writes -----------------------------------------------------------------------------
def test_atomic_path_replaces_whole_with_ordinary_permissions_and_leaves_nothing(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with atomic_path(target) as temporary:
        assert temporary.parent == tmp_path and temporary.name.startswith(".out.") and temporary.suffix == ".json"
        temporary.write_text("new")
        assert target.read_text() == "old"                   # not yet
    assert target.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["out.json"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as temporary:
            temporary.write_text("half")
            raise KeyboardInterrupt
    replacement = Replacement(target)
    replacement.temporary.write_text("half")
    replacement.discard()
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_a_folder_that_takes_no_file_is_one_user_error_naming_it(tmp_path):
    missing = tmp_path / "missing" / "out.json"
    for write in (lambda: write_text(missing, "x"), lambda: atomic_path(missing).__enter__(),
                  lambda: check_writable(missing)):
        with pytest.raises(UserError, match=f"cannot write {missing}: directory {missing.parent} does not exist"):
            write()
    (tmp_path / "file").write_text("mine")
    with pytest.raises(UserError, match="file is not a directory"):
        write_text(tmp_path / "file" / "out.json", "x")
    if Path("/proc/self").is_dir():
        with pytest.raises(UserError, match="cannot write /proc/out.json: directory /proc does not take new files"):
            write_text("/proc/out.json", "x")


def test_stale_temporaries_are_those_of_unfinished_writes(tmp_path):
    replacement = Replacement(tmp_path / "last.pt")             # a write killed half-way
    old = tmp_path / ".last.pt.abc123.tmp"                      # one of an earlier version's model files
    old.write_bytes(b"half")
    for name in ("notes.tmp", ".hidden", "last.pt", ".x.partial"):
        (tmp_path / name).write_text("not ours")
    (tmp_path / ".dir.tmp").mkdir()
    assert stale_temporaries(tmp_path) == sorted([replacement.temporary, old])


# -- the signed log ----------------------------------------------------------------------------
def test_signed_log_is_one_function_for_numpy_and_torch():
    x = np.array([-1e6, -3.0, -1e-9, 0.0, 1e-9, 2.5, 1e6])
    expected = np.sign(x) * np.log1p(np.abs(x))
    np.testing.assert_array_equal(signed_log(x), expected)
    np.testing.assert_array_equal(signed_log(-x), -expected)
    tensor = signed_log(torch.from_numpy(x))
    assert isinstance(tensor, torch.Tensor) and tensor.dtype == torch.float64
    np.testing.assert_array_equal(tensor.numpy(), expected)
    windows = torch.randn(3, 2, 5, 5, dtype=torch.float64) * 100
    np.testing.assert_array_equal(relative_log(windows).numpy(),
                                  signed_log(windows - windows[..., 2:3, 2:3]).numpy())


# -- an evaluation's figures -------------------------------------------------------------------
def episode(outcome: str, length: float, steps: int = 10, world: str = "w") -> Episode:
    path = np.array([[0.0, 0.0], [length, 0.0]])
    return Episode(world, path[0], outcome, steps, path)


EPISODES = [episode("reached", 10.0, 12), episode("reached", 7.0, 8), episode("collision", 3.0),
            episode("trapped", 1.0), episode("reached", 5.0, 6), episode("timeout", 20.0)]
OPTIMAL = [8.0, None, 4.0, 9.0, 5.0, 10.0]
TRAPPED = [True, False, True, False, False, True]


def test_figures_follow_their_definitions():
    f = figures(EPISODES, optimal=OPTIMAL, trapped=TRAPPED)
    assert (f.episodes, f.successes, f.collisions, f.trapped) == (6, 3, 1, 1)
    assert (f.success_rate, f.collision_rate, f.trapped_rate) == (3 / 6, 1 / 6, 1 / 6)
    assert f.mean_steps == pytest.approx(26 / 3) and f.mean_path_length == pytest.approx(22 / 3)
    assert f.length_ratio == pytest.approx((10 + 5) / (8 + 5))            # successes with an optimal length
    assert f.path_over_optimal == pytest.approx((10 / 8 + 5 / 5) / 2)
    assert f.spl == pytest.approx((8 / 10 + 1 + 0 + 0 + 1 + 0) / 6)       # no optimal length: a success counts 1
    assert f.trap_success == pytest.approx(1 / 3)
    empty = figures([])
    assert (empty.success_rate, empty.mean_steps, empty.spl, empty.trap_success) == (0.0, None, None, None)
    assert figures(EPISODES[:1], trapped=[False]).trap_success is None


def test_every_report_takes_its_figures_from_figures():
    f = figures(EPISODES, optimal=OPTIMAL, trapped=TRAPPED)
    summary = Evaluation("p", EPISODES).summary()
    assert summary == {"episodes": 6, "successes": 3, "success_rate": round(f.success_rate, 4),
                       "collision_rate": round(f.collision_rate, 4), "trapped_rate": round(f.trapped_rate, 4),
                       "mean_steps": round(f.mean_steps, 2), "mean_path_length": round(f.mean_path_length, 3)}

    class Scenario:
        def __init__(self, optimal):
            self.optimal, self.bucket = optimal, 0

    class Trial:
        def __init__(self, optimal):
            self.scenario = Scenario(optimal)

    scenarios = [Trial(0.0 if v is None else v) for v in OPTIMAL]
    every = bucket_summary(Evaluation("p", EPISODES), scenarios)[-1]
    assert every == {"bucket": "all", "episodes": 6, "successes": 3, "collisions": 1,
                     "path_over_optimal": round(f.path_over_optimal, 4)}


# -- a formation's links and success -----------------------------------------------------------
def test_link_lengths_and_success_are_the_model_rule():
    spec = FormationSpec(followers=3, comm_range=3.0, shape="wedge")            # every follower follows the leader
    line = FormationSpec(followers=2, comm_range=3.0)                           # each follows the one before
    robots = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0], [-1.0, -1.0]])
    np.testing.assert_allclose(link_lengths(robots, spec.followed), [3.0, 4.0, np.sqrt(2)])
    np.testing.assert_allclose(link_lengths(robots[:3], line.followed), [3.0, 5.0])
    assert links_in_range(robots, spec.followed, 3.0).tolist() == [True, False, True]
    assert not formation_success(True, robots, spec.followed, 3.0)
    assert formation_success(True, robots[[0, 1, 3]], [0, 0], 3.0)
    assert not formation_success(False, robots[[0, 1, 3]], [0, 0], 3.0)
    assert formation_success(True, robots[:1], [], 3.0)                         # no followers: the leader's
    # batched as the team and the crowd ask for them
    batch = np.stack([robots, robots[::-1]])
    np.testing.assert_array_equal(FormationTeam(spec, 2).links(batch),
                                  np.stack([link_lengths(robots, spec.followed), link_lengths(robots[::-1], spec.followed)]))

    class Crowd:
        count, sizes, followed = 2, [4, 3], [spec.followed, line.followed]

    crowd_links = Formations.links(Crowd(), batch)
    np.testing.assert_array_equal(crowd_links[1], link_lengths(robots[::-1][:3], line.followed))


def test_an_episode_succeeds_by_the_formation_rule():
    robots = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], [[5.0, 5.0], [6.0, 5.0], [9.5, 5.0]]])   # (T, m, 2)
    record = FormationRecord(robots, 3.0, [0, 1], 0, 0, [1.0, 0.5])
    assert record.final_links_in_range() == [True, False]
    assert not Episode("w", robots[0, 0], "reached", 1, robots[:, 0], formation=record).success
    record.positions = robots[:, [0, 1, 1]]
    assert Episode("w", robots[0, 0], "reached", 1, robots[:, 0], formation=record).success
    assert not Episode("w", robots[0, 0], "timeout", 1, robots[:, 0], formation=record).success
