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
    "OptionError",
    "TableError",
    "OutputError",
]


class L3Error(Exception):
    """Base class of all errors l3 reports to the user as one line."""


class InputError(L3Error):
    """An input file is missing, unreadable, truncated or of the wrong kind."""


class ConfigError(L3Error):
    """A camera TOML or option value is invalid (names file, key and allowed values)."""


class OptionError(ConfigError):
    """A library option's value is not allowed: the message names the *parameter*.

    ``message`` may hold ``{name}`` where the name goes (else it follows the
    name); a command line says its flag instead (:meth:`named`).
    """

    def __init__(self, parameter: str, message: str) -> None:
        self.parameter = parameter
        self.template = message if "{name}" in message else "{name} " + message
        super().__init__(self.named(parameter))

    def named(self, name: str) -> str:
        """The message with ``name`` (e.g. a flag, ``--levels``) for the parameter."""
        return self.template.replace("{name}", name)

    def __reduce__(self):  # pickled with its parts (a task's error on a dask worker)
        return type(self), (self.parameter, self.template)


class TableError(L3Error):
    """A transform table is not an l3 table, is damaged, or does not fit the raw."""


class OutputError(L3Error):
    """An output cannot be written (folder missing or not writable)."""
