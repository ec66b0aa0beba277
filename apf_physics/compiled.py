"""Compiled kernels: plain Python loops over arrays, compiled by numba on first use.

Where numpy's fixed cost per call dominates (a few robots, a few window points per robot, a
handful of segments near a move), one loop compiled once does what twenty small array calls
did. A kernel is written as ordinary Python over arrays and floats, so that it reads as the
rule it computes; :func:`kernel` compiles it with ``numba.njit`` the first time it is called
(numba's import and a kernel's compilation take about a second; the machine code is cached on
disk, beside the module or in numba's user cache, for the next process). No fast-math: the
compiled code does the same IEEE operations in the same order as the Python source.
"""

from __future__ import annotations

import functools
from typing import Callable, TypeVar

F = TypeVar("F", bound=Callable)


def kernel(fn: F) -> F:
    """``fn`` compiled by ``numba.njit(cache=True)`` when first called; ``fn.py_func`` is the
    Python original (for tests that compare both)."""
    compiled = None

    @functools.wraps(fn)
    def call(*args):
        nonlocal compiled
        if compiled is None:
            import numba  # lazy, as torch and cv2 are: half a second to import, needed only where a kernel runs
            compiled = numba.njit(cache=True, nogil=True)(fn)
        return compiled(*args)

    call.py_func = fn  # type: ignore[attr-defined]
    return call  # type: ignore[return-value]
