"""The step reward of Model §2 (eq. 15–16) as named terms, and the thesis's weight sets."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from apf_physics.common.compiled import kernel


@dataclass(frozen=True)
class RewardWeights:
    """Weights of ``R = W1 + W2 + W3 + W4`` (Model eq. 15–16), and of two terms of ours, ``W5``, ``W6``.

    Attributes:
        w1: On hitting an obstacle or the map's edge (negative).
        w2: On reaching the target (positive).
        w3: Every step (negative).
        beta: ``W4 = beta · (U(P_{n+1}) − U(P_n))``; negative, so going down the field pays.
        revisit: Not in the thesis. ``W5 = revisit · n``, where ``n`` is how often the robot
            had already been in the 1×1 cell it enters (at most the visit memory's cap, 4);
            zero or negative. W4 alone makes circling in a well nearly free (each step down
            is paid back by the step up), while climbing out costs at once; W5 makes the
            circling cost. The robot's visit counts are the memory channel's
            (:class:`~apf_physics.sensing.observation.VisitMemory`), so with ``memory=True`` the
            term is a function of what the network sees.
        length: Not in the thesis. ``W6 = length · |P_{n+1} − P_n|``, per unit of distance
            moved; zero or negative. W3 charges a diagonal move no more than an axis move, so a
            path zigzagging on diagonals (√2 per unit of progress) costs as many steps as a
            straight one; W6 prefers the shorter.
        potential_discount: Not in the thesis. ``W4 = beta · (potential_discount · U(P_{n+1}) − U(P_n))``;
            1 in the thesis. Set to the learner's γ, W4 is a potential-based shaping term
            (Ng, Harada & Russell 1999): it no longer pays ``−beta·(1 − γ)·U`` each step for
            standing low in the field, which rewards lingering in a well and keeping far
            from obstacles, and the best policy is the one without W4.
    """

    w1: float
    w2: float
    w3: float
    beta: float
    revisit: float = 0.0
    length: float = 0.0
    potential_discount: float = 1.0

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


REWARD_PRESETS: dict[str, RewardWeights] = {
    "thesis-fixed": RewardWeights(w1=-1000.0, w2=1000.0, w3=-1.0, beta=-4.0),      # Table 3
    "thesis-general": RewardWeights(w1=-10.0, w2=10.0, w3=-0.2, beta=-20.0),       # Table 4
    # Table 3 plus W5 (a revisit costs about a median step's W4 in a 50×50 general field) and W6
    "general": RewardWeights(w1=-1000.0, w2=1000.0, w3=-1.0, beta=-4.0, revisit=-50.0, length=-40.0),
}

TERMS = ("collision", "target", "step", "potential", "revisit", "length")  # W1 ... W6


def reward_weights(spec: str | RewardWeights | dict) -> RewardWeights:
    """A preset name, a :class:`RewardWeights`, or a dict of its fields."""
    if isinstance(spec, RewardWeights):
        return spec
    if isinstance(spec, str):
        if spec not in REWARD_PRESETS:
            raise ValueError(f"unknown reward preset {spec!r} (known: {', '.join(REWARD_PRESETS)})")
        return REWARD_PRESETS[spec]
    return RewardWeights(**spec)


def reward_terms(weights: RewardWeights, collided: np.ndarray, reached: np.ndarray,
                 u_before: np.ndarray, u_after: np.ndarray, revisits: np.ndarray | None = None,
                 moved: np.ndarray | None = None, running: np.ndarray | None = None) -> np.ndarray:
    """The terms (:data:`TERMS`, one row each) for a batch of steps, ``(6, N)``; their column sums are the rewards.

    ``revisits``: earlier visits of the cell each robot entered (None: no W5); ``moved``:
    distance each robot moved (None: no W6); ``running``: (N,) the robots that stepped (the
    others' terms are 0; None: all).
    """
    return rewards(weights, collided, reached, u_before, u_after, revisits, moved, running)[1]


def rewards(weights: RewardWeights, collided: np.ndarray, reached: np.ndarray, u_before: np.ndarray,
            u_after: np.ndarray, revisits: np.ndarray | None = None, moved: np.ndarray | None = None,
            running: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(rewards (N,), terms (6, N))``: :func:`reward_terms` and their column sums, in one pass."""
    n = len(collided)
    terms = np.empty((len(TERMS), n))
    total = np.empty(n)
    _terms(weights.w1, weights.w2, weights.w3, weights.beta, weights.potential_discount, weights.revisit,
           weights.length, collided, reached, u_before, u_after,
           _NONE if revisits is None else np.asarray(revisits, float),
           _NONE if moved is None else np.asarray(moved, float),
           _ALL if running is None else running, running is None, terms, total)
    return total, terms


_NONE = np.zeros(0)
_ALL = np.ones(1, bool)


@kernel
def _terms(w1, w2, w3, beta, discount, w_revisit, w_length, collided, reached, u_before, u_after, revisits,
           walked, running, everyone, out, total):
    """:func:`reward_terms`' arithmetic, column by column (a robot's terms, as eq. 15–16 and the
    project's revisit and length terms read). The one place the reward is computed."""
    for i in range(out.shape[1]):
        out[0, i] = w1 if collided[i] else 0.0
        out[1, i] = w2 if reached[i] and not collided[i] else 0.0
        out[2, i] = w3
        out[3, i] = beta * (discount * u_after[i] - u_before[i])
        out[4, i] = w_revisit * revisits[i] if revisits.shape[0] else 0.0
        out[5, i] = w_length * walked[i] if walked.shape[0] else 0.0
        if not everyone:   # a robot that did not step scores nothing (its terms times 0, as numpy multiplies)
            for k in range(out.shape[0]):
                out[k, i] = out[k, i] * (1.0 if running[i] else 0.0)
        sum_ = out[0, i]   # the reward: the terms added in order, as numpy sums a column
        for k in range(1, out.shape[0]):
            sum_ = sum_ + out[k, i]
        total[i] = sum_
