"""Shared fixtures: small analytic trees, built once per session."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.protocol import OracleSpec, Verdicts
from reach.build import build_tree
from reach.tree import Box, VATree


class CountingOracle:
    """Wraps an oracle and records every point it is asked about."""

    def __init__(self, inner):  # noqa: ANN001
        self.inner = inner
        self.dim = inner.dim
        self.posture_names = tuple(inner.posture_names)
        self.asked: list[np.ndarray] = []
        self.hints: list[np.ndarray | None] = []

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None = None) -> Verdicts:
        self.asked.append(np.array(points))
        self.hints.append(None if hints is None else np.array(hints))
        return self.inner.evaluate(points, hints)

    @property
    def calls(self) -> int:
        return sum(len(a) for a in self.asked)


@pytest.fixture
def counting():
    return CountingOracle


@pytest.fixture(scope="session")
def unit_sphere_tree() -> VATree:
    return build_tree(OracleSpec("sphere", {"radius": 1.0}), Box([-1, -1, -1], [1, 1, 1]), 2, 6)
