"""The step reward (Model eq. 15–16, and the revisit and length terms): each term of a batch of
steps, the rewards as their sums, robots that did not step, and the weights' presets."""

from __future__ import annotations

import numpy as np
import pytest

from apf_physics.envs.reward import REWARD_PRESETS, TERMS, RewardWeights, reward_terms, reward_weights, rewards

WEIGHTS = RewardWeights(w1=-1000.0, w2=1000.0, w3=-1.0, beta=-4.0, revisit=-50.0, length=-40.0, potential_discount=0.5)
# four robots: one collides, one reaches its target, one does both, one stands still
COLLIDED = np.array([True, False, True, False])
REACHED = np.array([False, True, True, False])
U_BEFORE = np.array([10.0, 8.0, 4.0, 2.0])
U_AFTER = np.array([12.0, 6.0, 4.0, 2.0])
REVISITS = np.array([0.0, 1.0, 2.0, 4.0])
MOVED = np.array([1.0, 1.5, 0.5, 0.0])
#                    W1       W2     W3    W4 = beta·(0.5·U' − U)   W5      W6
EXPECTED = np.array([[-1000.0, 0.0, -1.0, 16.0, 0.0, -40.0],
                     [0.0, 1000.0, -1.0, 20.0, -50.0, -60.0],
                     [-1000.0, 0.0, -1.0, 8.0, -100.0, -20.0],     # a collision earns no W2
                     [0.0, 0.0, -1.0, 4.0, -200.0, 0.0]]).T


def test_each_term_and_the_rewards_as_their_sums():
    total, terms = rewards(WEIGHTS, COLLIDED, REACHED, U_BEFORE, U_AFTER, REVISITS, MOVED)
    np.testing.assert_array_equal(terms, EXPECTED)
    np.testing.assert_array_equal(total, [-1025.0, 909.0, -1113.0, -197.0])
    np.testing.assert_array_equal(reward_terms(WEIGHTS, COLLIDED, REACHED, U_BEFORE, U_AFTER, REVISITS, MOVED), EXPECTED)
    assert len(TERMS) == len(EXPECTED) and TERMS[:2] == ("collision", "target")


def test_without_visit_counts_or_distances_those_terms_are_zero():
    total, terms = rewards(WEIGHTS, COLLIDED, REACHED, U_BEFORE, U_AFTER)
    np.testing.assert_array_equal(terms[:4], EXPECTED[:4])
    np.testing.assert_array_equal(terms[4:], 0.0)
    np.testing.assert_array_equal(total, EXPECTED[:4].sum(axis=0))
    np.testing.assert_array_equal(reward_terms(WEIGHTS, COLLIDED, REACHED, U_BEFORE, U_AFTER, moved=MOVED)[5], EXPECTED[5])


def test_a_robot_that_did_not_step_scores_nothing():
    running = np.array([True, False, True, False])
    total, terms = rewards(WEIGHTS, COLLIDED, REACHED, U_BEFORE, U_AFTER, REVISITS, MOVED, running)
    np.testing.assert_array_equal(terms[:, running], EXPECTED[:, running])
    np.testing.assert_array_equal(terms[:, ~running], 0.0)
    np.testing.assert_array_equal(total, [-1025.0, 0.0, -1113.0, 0.0])
    np.testing.assert_array_equal(
        reward_terms(WEIGHTS, COLLIDED, REACHED, U_BEFORE, U_AFTER, REVISITS, MOVED, running), terms)


def test_weights_by_preset_name_by_fields_or_as_they_are():
    assert reward_weights("thesis-fixed") == RewardWeights(w1=-1000.0, w2=1000.0, w3=-1.0, beta=-4.0)   # Table 3
    assert reward_weights(WEIGHTS) is WEIGHTS
    assert WEIGHTS.as_dict() == {"w1": -1000.0, "w2": 1000.0, "w3": -1.0, "beta": -4.0, "revisit": -50.0,
                                 "length": -40.0, "potential_discount": 0.5}
    assert reward_weights(WEIGHTS.as_dict()) == WEIGHTS
    with pytest.raises(ValueError, match=r"^unknown reward preset 'nope' \(known: " + ", ".join(REWARD_PRESETS) + r"\)$"):
        reward_weights("nope")
