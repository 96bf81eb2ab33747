"""Oracles: whatever decides whether a point is inside a volume.

Analytic shapes live in :mod:`oracles.shapes`; the body models, symbolic
kinematics and inverse-kinematics oracles in their own modules.
"""

from oracles.protocol import Oracle, OracleSpec, Verdicts
from oracles.registry import available, create

__all__ = ["Oracle", "OracleSpec", "Verdicts", "available", "create"]
