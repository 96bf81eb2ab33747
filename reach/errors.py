"""Errors raised by reach and oracles.

Every error a user can trigger derives from :class:`ReachError` and carries
the file, key or field it is about, so that a message names what was wrong
and what was expected.
"""

from __future__ import annotations

from pathlib import Path


class ReachError(Exception):
    """Root of every error reach raises on purpose."""


class ConfigError(ReachError):
    """A configuration file or mapping is invalid.

    Attributes:
        source: The file (or "<mapping>") the configuration came from.
        key: Dotted path of the offending key, e.g. ``depth.max``.
        reason: What was wrong and what was expected.
    """

    def __init__(self, source: str | Path, key: str, reason: str) -> None:
        self.source = str(source)
        self.key = key
        self.reason = reason
        where = f"{self.source}: {key}" if key else self.source
        super().__init__(f"{where}: {reason}")


class StoreError(ReachError):
    """A stored tree or atlas cannot be read or written.

    Attributes:
        path: The file concerned.
        reason: What is wrong with it.
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class OracleError(ReachError):
    """An oracle is unknown, misconfigured, or returned malformed verdicts."""


class ModelError(ReachError):
    """A body model (URDF, frame or joint name) is invalid or unknown."""


class TreeError(ReachError):
    """An operation on trees is impossible (e.g. booleans of mismatched lattices)."""
