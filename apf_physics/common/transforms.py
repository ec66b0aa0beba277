"""The signed log, ``sign(x)·log(1 + |x|)``: how the observations, the Q-network and the map
network compress differences of U (Model §2), which span many orders of magnitude near obstacles.

One definition for NumPy arrays and torch tensors alike, so that what a network is trained on
and what it is given when it acts cannot drift apart.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

T = TypeVar("T")


def signed_log(x: T) -> T:
    """``sign(x)·log(1 + |x|)`` elementwise: odd, 0 at 0, ≈ x near 0, ≈ sign(x)·log|x| far from it.

    Args:
        x: A NumPy array (or scalar), or a torch tensor.

    Returns:
        The same kind as ``x`` (a tensor stays on its device, in its dtype, in the autograd graph).
    """
    if isinstance(x, np.ndarray) or np.isscalar(x):
        return np.sign(x) * np.log1p(np.abs(x))
    return x.sign() * x.abs().log1p()   # a torch tensor (not imported here: NumPy users need no torch)
