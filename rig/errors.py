"""The project's exception hierarchy: each also subclasses the built-in it resembles.

Messages name the rule and the value, e.g.
`actuator 3 velocity 0.91 m/s exceeds servovalve limit 0.74 m/s`.
CLIs catch `RigError` and print its message on one line with exit code 2.
"""

from __future__ import annotations


class RigError(Exception):
    """Base of every error the project reports to a user as one line."""


class ConfigError(RigError, ValueError):
    """A configuration or profile file that is malformed or out of range."""

    def __init__(self, source: str, field: str, problem: str) -> None:
        self.source = source
        self.field = field
        self.problem = problem
        where = f"{source}: {field}" if field else source
        super().__init__(f"{where}: {problem}")


class LimitError(RigError, ValueError):
    """A commanded motion beyond what the table can do; nothing has moved."""


class DataError(RigError, ValueError):
    """A data file (run file, CSV) that cannot be used, and why."""
