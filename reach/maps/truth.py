"""A truth suite as stored: goals labelled by a thorough referee, each "reachable" label kept with the posture that
proves it; and a tree's verdicts against it.

A suite is one folder (the repository's: ``tests/data/truth``): per strategy a ``NAME.npz`` (``goals`` (N, 3) [m],
``reachable`` (N,), ``posture`` (N, nq) with NaN rows where no posture was found, ``residual`` (N,) [m], the
referee's best distance, ``kind`` (N,) the region each goal was drawn in, ``found_by`` (N,) which of the referee's
searches proved it) and one ``provenance.json`` (per strategy: the config, the seed, the referee's settings, the
body's hash, how many candidates were drawn and kept). ``bench/truth.py`` writes it; the tests check its postures
(``tests/truth_suite.py``) and ``reach audit --truth`` compares a tree with it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reach.errors import StoreError
from reach.maps.tree import Policy, VATree

SHOWN = 5  # goals named per disagreement in a comparison


@dataclass
class Suite:
    """One strategy's labelled goals (see the module docstring)."""

    strategy: str
    goals: np.ndarray
    reachable: np.ndarray
    posture: np.ndarray
    residual: np.ndarray
    kind: np.ndarray
    found_by: np.ndarray

    def neighbour_hints(self) -> np.ndarray:
        """Each goal's hint as a build gives it: the kept posture of the nearest other proven-reachable goal (a NaN
        row, no hint, where there is none)."""
        proven = np.nonzero(self.reachable)[0]
        hints = np.full_like(self.posture, np.nan)
        for i, g in enumerate(self.goals):
            others = proven[proven != i]
            if others.size:
                hints[i] = self.posture[others[np.argmin(np.linalg.norm(self.goals[others] - g, axis=1))]]
        return hints

    def save(self, folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{self.strategy}.npz"
        np.savez_compressed(path, goals=self.goals, reachable=self.reachable, posture=self.posture,
                            residual=self.residual, kind=self.kind.astype("U16"), found_by=self.found_by.astype("U16"))
        return path


def load_suite(strategy: str, folder: Path) -> Suite:
    """A strategy's suite from a suite folder."""
    path = Path(folder) / f"{strategy}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            suite = Suite(strategy, z["goals"], z["reachable"], z["posture"], z["residual"], z["kind"], z["found_by"])
    except (OSError, ValueError, KeyError) as exc:
        raise StoreError(path, f"not a truth suite's strategy file ({exc})") from exc
    n = len(suite.goals)
    if suite.goals.shape != (n, 3) or suite.reachable.shape != (n,) or len(suite.posture) != n:
        raise StoreError(path, f"goals {suite.goals.shape}, labels {suite.reachable.shape} and postures "
                               f"{suite.posture.shape} do not match (expected (N, 3), (N,), (N, nq))")
    return suite


def provenance(folder: Path) -> dict[str, Any]:
    """A suite folder's provenance.json."""
    path = Path(folder) / "provenance.json"
    try:
        out = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(path, f"not a truth suite's provenance ({exc})") from exc
    if not isinstance(out, dict) or not isinstance(out.get("strategies"), dict):
        raise StoreError(path, "expected an object with 'strategies'")
    return out


def compare(tree: VATree, suite: Suite, policy: Policy = "vertex") -> dict[str, Any]:
    """A tree's word on a suite's goals: proven-reachable goals it calls unreachable (the tree is wrong there), and
    goals it calls reachable that no search of the referee reached (unproven: the referee may have missed them), each
    counted with the first ``SHOWN`` goals [m]."""
    said = tree.contains(suite.goals, policy)
    missed = np.nonzero(suite.reachable & ~said)[0]
    unproven = np.nonzero(~suite.reachable & said)[0]
    return {"goals": len(suite.goals), "proven": int(suite.reachable.sum()), "policy": policy,
            "proven_called_unreachable": int(missed.size),
            "rate": round(missed.size / max(int(suite.reachable.sum()), 1), 4),
            "missed_goals": np.round(suite.goals[missed[:SHOWN]], 4).tolist(),
            "reachable_unproven": int(unproven.size),
            "unproven_goals": np.round(suite.goals[unproven[:SHOWN]], 4).tolist()}
