"""The truth suite: goals labelled by a thorough referee, each "reachable" label kept with the posture that proves it.

A suite is one folder (``tests/data/truth``): per strategy a ``NAME.npz`` (``goals`` (N, 3) [m], ``reachable`` (N,),
``posture`` (N, nq) with NaN rows where no posture was found, ``residual`` (N,) [m], the referee's best distance,
``kind`` (N,) the region each goal was drawn in, ``found_by`` (N,) which of the referee's searches proved it) and one
``provenance.json`` (the config, strategy, seed, the referee's settings, the body's hash, how many candidates were
drawn and kept). ``bench/truth.py`` writes it; ``tests/test_truth.py`` and ``bench/truth.py --score`` read it.

A "reachable" label is proven: its posture passes :func:`independent_check`. An "unreachable" label is only what
no search of the referee found; an engine that reaches such a goal with a posture that passes the check is right,
and the suite is regenerated.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import coal
import numpy as np
import pinocchio as pin

SUITE = Path(__file__).resolve().parent / "data" / "truth"
LIMIT_TOL = 1e-6  # [rad or m] a joint this far past its range still holds (the interior-point programs' tolerance)
GAP_TOL = 1e-6  # [m] coal's distance this far below a pair's floor still holds


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


def load_suite(strategy: str, folder: Path = SUITE) -> Suite:
    with np.load(folder / f"{strategy}.npz", allow_pickle=False) as z:
        return Suite(strategy, z["goals"], z["reachable"], z["posture"], z["residual"], z["kind"], z["found_by"])


def provenance(folder: Path = SUITE) -> dict[str, Any]:
    return json.loads((folder / "provenance.json").read_text())


def _capsule(a: np.ndarray, b: np.ndarray, r: float) -> tuple[Any, Any]:
    """coal's capsule between world points a and b (a sphere when they meet), and its placement."""
    axis = b - a
    n = float(np.linalg.norm(axis))
    if n < 1e-12:
        return coal.Sphere(r), coal.Transform3s(np.eye(3), a)
    z = axis / n
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    return coal.Capsule(r, n), coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), 0.5 * (a + b))


def independent_check(oracle: Any, q: np.ndarray, goal: np.ndarray) -> list[str]:
    """What a posture breaks, by this module's own computations where it can: the effector's distance to the goal
    by Pinocchio's forward kinematics, the joints' ranges, every self-collision pair by coal on capsules placed by
    those kinematics, every capsule above the floor; the other hard tasks (feet, balance, couplings, hang, ...) by
    their own verdicts. An empty list: the posture proves the goal reachable."""
    model = oracle.body.model
    data = model.createData()
    q = np.asarray(q, float)
    pin.framesForwardKinematics(model, data, q)
    faults = []
    hand = data.oMf[model.getFrameId(oracle.effector)].translation
    if np.linalg.norm(hand - goal) > oracle.strategy.tolerance + 1e-9:
        faults.append(f"reach ({np.linalg.norm(hand - goal) * 1e3:.1f} mm)")
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    bounded = np.isfinite(lo) & np.isfinite(hi) & (hi - lo < 1e6)
    bounded[:7] = False  # the floating root's coordinates
    if np.any((q < lo - LIMIT_TOL)[bounded] | (q > hi + LIMIT_TOL)[bounded]):
        faults.append("limits")
    collision = oracle.body.collision
    ends = ([collision.world(data, i) for i in range(len(collision.placed))] if collision is not None else [])
    for task in oracle.strategy.hard:
        if task.type == "self_collision":
            for pair in task.pairs:
                (a, b), (c, d) = ends[pair.first], ends[pair.second]
                ga, ta = _capsule(a, b, collision.placed[pair.first].radius)
                gb, tb = _capsule(c, d, collision.placed[pair.second].radius)
                gap = coal.distance(ga, ta, gb, tb, coal.DistanceRequest(), coal.DistanceResult())
                if gap < pair.floor - GAP_TOL:
                    faults.append(f"self_collision ({collision.placed[pair.first].name}-"
                                  f"{collision.placed[pair.second].name} {gap * 1e3:+.1f} mm)")
                    break
        elif task.type == "floor":
            low = min(min(a[2], b[2]) - collision.placed[i].radius for i, (a, b) in enumerate(ends)
                      if i in task.capsules)
            if low < -1e-4:  # the floor task's contact tolerance (oracles/tasks/floor.py)
                faults.append(f"floor ({low * 1e3:+.1f} mm)")
        else:
            faults += [f for f in oracle.faults(q[None])[0] if f == task.type]
    return sorted(set(faults))


@dataclass
class Score:
    """An engine's verdicts on a suite: goals proven reachable it calls unreachable (``false_unreachable``), its
    "reachable" answers whose posture fails the independent check (``false_reachable``), and goals labelled
    unreachable that it proves reachable (``new``: the suite is stale there)."""

    strategy: str
    goals: int
    proven: int
    false_unreachable: list[int]
    false_reachable: list[int]
    new: list[int]

    @property
    def false_unreachable_rate(self) -> float:
        return len(self.false_unreachable) / max(self.proven, 1)

    @property
    def false_reachable_rate(self) -> float:
        return len(self.false_reachable) / max(self.goals, 1)

    def line(self) -> dict[str, Any]:
        return {"strategy": self.strategy, "goals": self.goals, "proven_reachable": self.proven,
                "false_unreachable": len(self.false_unreachable),
                "false_unreachable_rate": round(self.false_unreachable_rate, 4),
                "false_reachable": len(self.false_reachable),
                "false_reachable_rate": round(self.false_reachable_rate, 4), "reached_beyond_suite": len(self.new)}


def score(oracle: Any, suite: Suite, verdicts: Any) -> Score:
    """Score an engine's verdicts (``reachable``, ``posture``) on a suite against its labels and the check."""
    said = np.asarray(verdicts.reachable, bool)
    bad = [int(i) for i in np.nonzero(said)[0] if independent_check(oracle, verdicts.posture[i], suite.goals[i])]
    fu = [int(i) for i in np.nonzero(suite.reachable & ~said)[0]]
    new = [int(i) for i in np.nonzero(~suite.reachable & said)[0] if i not in bad]
    return Score(suite.strategy, len(suite.goals), int(suite.reachable.sum()), fu, bad, new)
