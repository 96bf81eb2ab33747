"""The paper's priority mechanism: which strategy reaches a goal.

For an effector and a goal, the strategies of that effector are tried in
priority order; the first whose tree holds the goal is chosen. The posture is
the one stored at the nearest reachable vertex of that tree.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from reach.errors import ReachError
from reach.store import Atlas
from reach.tree import POLICIES, Policy, VATree


@dataclass(frozen=True)
class Answer:
    """The selector's answer for one goal.

    Attributes:
        effector: The effector asked about.
        goal: The goal [m] in the atlas's world frame.
        strategy: The chosen strategy, or None when none reaches.
        reachable: Whether any strategy reaches the goal.
        alternatives: Other strategies that also reach it, in priority order.
        posture: Joint name -> value [rad or m] from the nearest stored
            reachable vertex, or None when the oracle stores no postures.
        residual: Residual [m] stored with that vertex.
        seconds: Time spent answering [s].
    """

    effector: str
    goal: tuple[float, ...]
    strategy: str | None
    reachable: bool
    alternatives: tuple[str, ...] = ()
    posture: dict[str, float] | None = None
    residual: float | None = None
    seconds: float = 0.0
    kinds: dict[str, str] = field(default_factory=dict)


class Selector:
    """Answers goals from an atlas; builds per-tree lookup structures once."""

    def __init__(self, atlas: Atlas, policy: Policy = "vertex") -> None:
        if policy not in POLICIES:
            raise ReachError(f"unknown policy {policy!r}; expected one of {', '.join(POLICIES)}")
        self.atlas = atlas
        self.policy = policy
        self.order = [(s["name"], s["effector"]) for s in sorted(atlas.strategies, key=lambda s: s["priority"])]
        self._kd: dict[str, tuple[cKDTree, np.ndarray] | None] = {}

    @property
    def effectors(self) -> list[str]:
        return sorted({e for _, e in self.order})

    def strategies_for(self, effector: str) -> list[str]:
        names = [n for n, e in self.order if e == effector]
        if not names:
            raise ReachError(f"unknown effector {effector!r}; this atlas has {', '.join(self.effectors)}")
        return names

    def _nearest(self, name: str, tree: VATree, goal: np.ndarray) -> tuple[dict[str, float] | None, float | None]:
        if name not in self._kd:
            v = tree.vertices
            ok = np.nonzero(v.reachable)[0]
            self._kd[name] = None
            if v.posture is not None and ok.size:
                pts = tree.lattice.points(tree.lattice.coords(v.keys[ok]))
                self._kd[name] = (cKDTree(pts), ok)
        found = self._kd[name]
        if found is None:
            return None, None
        kd, rows = found
        _, i = kd.query(goal)
        row = rows[int(i)]
        posture = tree.vertices.posture[row]  # type: ignore[index]
        return dict(zip(tree.vertices.posture_names, map(float, posture), strict=True)), float(tree.vertices.residual[row])

    def select(self, effector: str, goal: np.ndarray) -> Answer:
        """Choose a strategy for one goal [m]."""
        t0 = time.perf_counter()
        g = np.asarray(goal, dtype=float).reshape(1, -1)
        names = self.strategies_for(effector)
        hits = [n for n in names if bool(self.atlas.trees[n].contains(g, self.policy)[0])]
        posture = residual = None
        if hits:
            posture, residual = self._nearest(hits[0], self.atlas.trees[hits[0]], g[0])
        return Answer(
            effector, tuple(map(float, g[0])), hits[0] if hits else None, bool(hits), tuple(hits[1:]),
            posture, residual, time.perf_counter() - t0,
        )
