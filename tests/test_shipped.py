"""The shipped DQN model for fixed20 (apf_physics/models/fixed20.pt; see apf_physics/models/README.md)."""

from __future__ import annotations

import pytest

from apf_physics import load_world
from apf_physics.models import SHIPPED

pytestmark = pytest.mark.skipif(not SHIPPED["thesis-fixed"].exists(), reason="no shipped fixed20 model")


def test_shipped_fixed20_model_loads_and_fits_the_world(worlds_dir):
    from apf_physics.models import load_model

    world = load_world(worlds_dir / "fixed20.yaml")
    model = load_model(SHIPPED["thesis-fixed"], expect_obs_shape=(1, 11, 11), expect_field=world.field.as_dict())
    assert model.meta["kind"] == "model"
    assert model.network.arch["obs_transform"] == "relative-log"


def test_shipped_fixed20_model_reaches_the_target_from_every_start(worlds_dir):
    from apf_physics.experiments.evaluate import evaluate
    from apf_physics.planners import make_planner

    world = load_world(worlds_dir / "fixed20.yaml")
    episodes = evaluate(make_planner("dqn"), [world]).episodes
    assert len(episodes) == 40
    assert [e.outcome for e in episodes].count("reached") == 40
    assert not any(e.outcome == "collision" for e in episodes)
