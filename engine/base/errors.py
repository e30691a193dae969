"""The one base class of errors that are the user's to fix (a bad file, an impossible
setting, a missing library): the CLI prints their one-line message and exits with status 2,
with no traceback. Everything else is a bug and keeps its traceback."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class UserError(Exception):
    """An error in what the user gave or installed; its message is one self-contained line."""


def did_you_mean(word: object, choices: Iterable[str]) -> str:
    """``"; did you mean 'X'?"`` for the choice closest to ``word`` (difflib's ratio of at least
    0.6), or "" when none is that close: the tail of a one-line error about a misspelt name."""
    close = difflib.get_close_matches(str(word), list(choices), n=1)
    return f"; did you mean '{close[0]}'?" if close else ""
