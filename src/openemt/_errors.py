"""Exception types shared by the library and the CLI."""

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input from a user or a file: the message is one line naming what was expected and
    what arrived. The CLI prints it as ``error: <message>`` and exits with status 2."""
