"""Errors that the command line reports as one clear line, without a traceback."""


class BodymetryError(Exception):
    """A problem with the user's input or environment that the user can fix.

    The message names the file or option, what was expected and what was found.
    """


class InputError(BodymetryError, ValueError):
    """A public input (file, field, option) is malformed or out of range."""
