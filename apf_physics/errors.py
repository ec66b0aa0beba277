"""Errors that the command line reports as one message, without a traceback."""

import difflib


class UserError(Exception):
    """Bad input from the user: a file, an option or a value. The message says what and where."""


class WorldError(UserError):
    """A world file (or dict) that breaks the world-file contract."""


class ModelError(UserError):
    """A model file that is missing, corrupt, or made for another observation or field."""


def did_you_mean(word: object, choices) -> str:
    """``" (did you mean 'x'?)"`` naming the choice nearest to ``word``, or ``""`` when none is near."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""
