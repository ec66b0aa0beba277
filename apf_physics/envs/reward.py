"""The step reward of SPEC §2 (eq. 15–16) as named terms, and the thesis's weight sets."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class RewardWeights:
    """Weights of ``R = W1 + W2 + W3 + W4``.

    Attributes:
        w1: On hitting an obstacle or the map's edge (negative).
        w2: On reaching the target (positive).
        w3: Every step (negative).
        beta: ``W4 = beta · (U(P_{n+1}) − U(P_n))``; negative, so going down the field pays.
    """

    w1: float
    w2: float
    w3: float
    beta: float

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


REWARD_PRESETS: dict[str, RewardWeights] = {
    "thesis-fixed": RewardWeights(w1=-1000.0, w2=1000.0, w3=-1.0, beta=-4.0),      # Table 3
    "thesis-general": RewardWeights(w1=-10.0, w2=10.0, w3=-0.2, beta=-20.0),       # Table 4
}

TERMS = ("collision", "target", "step", "potential")  # W1, W2, W3, W4


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
                 u_before: np.ndarray, u_after: np.ndarray) -> dict[str, np.ndarray]:
    """The four terms for a batch of steps; their sum is the reward."""
    if len(collided) == 1:  # one robot: plain floats, numpy's per-call cost would dominate
        c, r = bool(collided[0]), bool(reached[0])
        return {
            "collision": np.array([weights.w1 if c else 0.0]),
            "target": np.array([weights.w2 if r and not c else 0.0]),
            "step": np.array([weights.w3]),
            "potential": np.array([weights.beta * (float(u_after[0]) - float(u_before[0]))]),
        }
    return {
        "collision": np.where(collided, weights.w1, 0.0),
        "target": np.where(reached & ~collided, weights.w2, 0.0),
        "step": np.full(len(collided), weights.w3),
        "potential": weights.beta * (u_after - u_before),
    }
