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
import types
from typing import Callable, TypeVar

F = TypeVar("F", bound=Callable)


def kernel(fn: F) -> F:
    """``fn`` compiled by ``numba.njit(cache=True)`` when first called; ``fn.py_func`` is the
    Python original (for tests that compare both). A kernel may call other kernels: they are
    compiled with it."""
    compiled = None

    def compile_():
        nonlocal compiled
        if compiled is None:
            import numba  # lazy, as torch and cv2 are: half a second to import, needed only where a kernel runs
            # the kernels it calls, as numba's own compiled functions (numba cannot call our wrapper)
            names = dict(fn.__globals__)
            for name in fn.__code__.co_names:
                if hasattr(names.get(name), "compile_"):
                    names[name] = names[name].compile_()
            source = types.FunctionType(fn.__code__, names, fn.__name__, fn.__defaults__, fn.__closure__)
            source.__qualname__ = fn.__qualname__
            compiled = numba.njit(cache=True, nogil=True)(source)
        return compiled

    @functools.wraps(fn)
    def call(*args):
        return (compiled or compile_())(*args)

    call.py_func = fn  # type: ignore[attr-defined]
    call.compile_ = compile_  # type: ignore[attr-defined]
    return call  # type: ignore[return-value]
