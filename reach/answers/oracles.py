"""The oracles answers are refined by: each strategy's ``refine`` variant, built once from its tree's own spec.

A tree built with a body this version of reach builds otherwise (a human from before the ANSUR II bodies) is refined
with the body it was built with, and said so in ``notes``; any other mismatch is refused.
"""

from __future__ import annotations

import copy
import logging
from typing import Any

import numpy as np

from oracles.protocol import EffectorPositions, Limited, ModelHashed, Oracle, OracleSpec, Rebuilt, Stepping, Tunable
from reach.errors import ModelMismatch
from reach.maps.atlas import Atlas

log = logging.getLogger("reach.answers.select")  # the selector's: its notes were always said there


class Oracles:
    """The strategies' refinement oracles of one atlas, built as they are first asked for.

    Args:
        atlas: The loaded atlas.
        budget: [s] each oracle's refinement budget (its ``refine`` variant's).

    Attributes:
        notes: What changed in the bodies of trees from earlier versions (:class:`~oracles.protocol.Rebuilt`).
        built: The oracles built so far, by strategy.
    """

    def __init__(self, atlas: Atlas, budget: float) -> None:
        self.atlas = atlas
        self.budget = float(budget)
        self.notes: list[str] = []
        self.built: dict[str, Oracle] = {}

    def __call__(self, name: str) -> Oracle:
        """The strategy's oracle for refinement (its ``"refine"`` variant)."""
        if name not in self.built:
            meta = self.atlas.maps[name].meta
            oracle = OracleSpec.from_dict(meta["oracle"]).create()
            stored_hash = meta.get("model_hash")
            if stored_hash and isinstance(oracle, ModelHashed) and oracle.model_hash != stored_hash:
                oracle = self._legacy(name, oracle, stored_hash)
            self.built[name] = (oracle.variant("refine", budget=self.budget) if isinstance(oracle, Tunable)
                                else oracle)
        return self.built[name]

    def _legacy(self, name: str, oracle: Oracle, stored: str) -> Oracle:
        """The oracle of a tree built with a body this version builds otherwise: a human from before ANSUR II bodies
        refines with the stature-scaled body it was built with, noted in ``notes`` and the log; any other is
        refused."""
        built = oracle.as_built(stored) if isinstance(oracle, Rebuilt) else None
        if built is None:
            raise ModelMismatch(self.atlas.path, name, stored, oracle.model_hash if isinstance(oracle, ModelHashed)
                                else "?")
        note = f"{self.atlas.path}: strategy {name!r} was {built[1]}"
        log.warning("%s", note)
        self.notes.append(note)
        return built[0]

    def with_budget(self, budget: float) -> Oracles:
        """These oracles with another refinement budget [s]: each built one's ``"refine"`` variant with it (its
        solvers shared)."""
        twin = copy.copy(self)
        twin.budget = float(budget)
        twin.built = {n: o.variant("refine", budget=budget) if isinstance(o, Tunable) else o
                      for n, o in self.built.items()}
        return twin

    def effector_positions(self, name: str, postures: np.ndarray) -> np.ndarray:
        """Effector positions [m] of postures (n, nq); NaN when the oracle cannot tell (no posture is then used)."""
        oracle = self(name)
        if isinstance(oracle, EffectorPositions):
            return np.asarray(oracle.effector_positions(postures), dtype=float)
        return np.full((len(postures), self.atlas.maps[name].dim), np.nan)

    def limits(self, name: str, q: np.ndarray, margin: float) -> list[str]:
        """The joint limits a posture of a strategy comes within ``margin`` [rad] of (none when its oracle cannot
        tell)."""
        oracle = self(name)
        return list(oracle.limits_near(q, margin)) if isinstance(oracle, Limited) else []

    def landing(self, name: str, q: np.ndarray) -> dict[str, Any] | None:
        """Where a stepping strategy's posture sets its foot down (its oracle's :class:`Stepping`), else None."""
        oracle = self(name)
        return oracle.landing(q) if isinstance(oracle, Stepping) else None
