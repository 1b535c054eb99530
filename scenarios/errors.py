"""Errors a user can act on: printed by the CLI as one line, never as a traceback."""


class UserError(Exception):
    """Bad input that the user can fix: the message names the file, record or parameter."""
