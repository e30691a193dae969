"""The one base class of errors that are the user's to fix (a bad file, an impossible
setting, a missing library): the CLI prints their one-line message and exits with status 2,
with no traceback. Everything else is a bug and keeps its traceback."""


class UserError(Exception):
    """An error in what the user gave or installed; its message is one self-contained line."""
