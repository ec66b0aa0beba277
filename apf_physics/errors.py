"""Errors that the command line reports as one message, without a traceback; and the hint they share."""

from __future__ import annotations

import difflib
from typing import Any, Iterable

MAX_HINT_WORD = 100
"""Longest word a hint is looked for (difflib's matching is quadratic in its length)."""


class UserError(Exception):
    """Bad input from the user: a file, an option or a value. The message says what and where."""


class WorldError(UserError):
    """A world file (or dict) that breaks the world-file contract."""


class ModelError(UserError):
    """A model file that is missing, corrupt, or made for another observation or field."""


def closest_match(word: Any, choices: Iterable[str]) -> str | None:
    """The choice most like ``word`` (:func:`difflib.get_close_matches`, cutoff 0.6), or None.

    None, too, for a ``word`` that is not a string or is longer than :data:`MAX_HINT_WORD`
    characters (what a file holds is not always a name); choices that are not strings are
    passed over.
    """
    if not isinstance(word, str) or len(word) > MAX_HINT_WORD:
        return None
    close = difflib.get_close_matches(word, [c for c in choices if isinstance(c, str)], n=1, cutoff=0.6)
    return close[0] if close else None


def did_you_mean(word: Any, choices: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the choice most like ``word`` (:func:`closest_match`), else ``""``.

    Written straight after the unknown word: ``f"unknown preset {name!r}{did_you_mean(name, PRESETS)}"``.
    """
    close = closest_match(word, choices)
    return f" (did you mean {close!r}?)" if close is not None else ""
