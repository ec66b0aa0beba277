"""Errors that the command line reports as one message, without a traceback."""


class UserError(Exception):
    """Bad input from the user: a file, an option or a value. The message says what and where."""


class WorldError(UserError):
    """A world file (or dict) that breaks the world-file contract."""


class ModelError(UserError):
    """A model file that is missing, corrupt, or made for another observation or field."""
