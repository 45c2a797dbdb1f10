"""One exception family for l3.

Every error that a user can cause (a bad file, a bad value, a damaged table)
is an :class:`L3Error`. The command line turns it into a one-line message and
exit status 1; anything else is a bug and shows a traceback under ``--debug``.
"""

from __future__ import annotations

__all__ = [
    "L3Error",
    "InputError",
    "ConfigError",
    "TableError",
    "OutputError",
]


class L3Error(Exception):
    """Base class of all errors l3 reports to the user as one line."""


class InputError(L3Error):
    """An input file is missing, unreadable, truncated or of the wrong kind."""


class ConfigError(L3Error):
    """A camera TOML or option value is invalid (names file, key and allowed values)."""


class TableError(L3Error):
    """A transform table is not an l3 table, is damaged, or does not fit the raw."""


class OutputError(L3Error):
    """An output cannot be written (folder missing or not writable)."""
