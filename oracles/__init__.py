"""Oracles: whatever decides whether a point is inside a volume.

Analytic shapes live in :mod:`oracles.shapes`; the body models, symbolic
kinematics and inverse-kinematics oracles in their own modules. Names are
resolved lazily (PEP 562): :mod:`oracles.errors` is imported by clients
(the ROS bridge among them) that have neither numpy nor Pinocchio.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Oracle": "oracles.protocol",
    "OracleSpec": "oracles.protocol",
    "Verdicts": "oracles.protocol",
    "available": "oracles.registry",
    "create": "oracles.registry",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'oracles' has no attribute {name!r}")
