"""Errors a user can act on.

Anything raised as `UserError` reaches the user as one line on stderr and exit
status 1, never as a traceback (see `laneprint.app.cli`).
"""


class UserError(Exception):
    """A problem with the user's input or workspace, explained in one line."""
