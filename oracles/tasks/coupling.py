"""Coupled joint limits: ``{type: coupling, rules: [{joint, by, limit, slope}, ...]}``.

A joint's upper limit that depends on another joint: ``q[joint] <= limit +
slope * q[by]`` (radians). A rule's ``joint`` and ``by`` may hold one ``*``,
matched per side (``*_hip_flexion`` with ``*_knee_flexion``: right with
right, left with left). Without ``rules`` the task applies the couplings of
the generated human:

* **Hamstrings.** With the knee straight, hip flexion stops at about 80 deg,
  the straight-leg raise of adults (Magee, D.J. (2014), *Orthopedic Physical
  Assessment*, 6th ed., ch. 9: 80-90 deg is normal; we take the lower end,
  the average adult being short of the athletic norm); with the knee flexed
  90 deg or more it reaches the full 120 deg of the AAOS range (Norkin &
  White 2016). Between, the limit grows linearly: 80 deg + (40/90) x knee
  flexion; above 90 deg of knee flexion the hip's own 120 deg bound applies.
  The same rule with the roles of hip and knee exchanged (the knee cannot
  straighten fully with the hip flexed past 80 deg) is the same inequality.

No other coupling changed a reach volume noticeably enough to model here
(shoulder abduction with rotation mostly changes how the hand is turned,
not where it is).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from oracles.tasks.base import BUFFER, INSIDE, Constraint, HardTask, Numeric, Row, Scope, Symbolic, matching, number
from reach.errors import TaskError

LIMIT_TOL = 1e-6  # [rad] overshoot the verdict accepts
HAMSTRINGS = {"joint": "*_hip_flexion", "by": "*_knee_flexion", "limit": math.radians(80.0), "slope": 40.0 / 90.0}


@dataclass(frozen=True)
class Rule:
    """q[joint] <= limit + slope * q[by] (configuration indices)."""

    joint: str
    by: str
    limit: float
    slope: float
    iq: int = -1
    iby: int = -1


@dataclass
class CouplingTask(HardTask):
    """Joint limits that depend on another joint (see the module docstring)."""

    type: ClassVar[str] = "coupling"
    keys: ClassVar[frozenset[str]] = frozenset({"rules"})
    summary: ClassVar[str] = "coupled joint limits, q[joint] <= limit + slope q[by]; by default the hamstrings' (hip flexion 80 deg with the knee straight)"

    rules: tuple[Rule, ...] = ()

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> CouplingTask:
        given = raw.get("rules", [HAMSTRINGS])
        if not isinstance(given, list):
            raise TaskError(f"{where}.rules", f"expected a list of {{joint, by, limit, slope}}, got {given!r}")
        names = scope.body.joint_names
        model = scope.body.model
        rules = []
        for k, r in enumerate(given):
            here = f"{where}.rules[{k}]"
            if not isinstance(r, dict) or set(r) != {"joint", "by", "limit", "slope"} or not all(isinstance(r[n], str) for n in ("joint", "by")):
                raise TaskError(here, f"expected {{joint: name, by: name, limit: rad, slope: number}}, got {r!r}")
            limit = number(r["limit"], f"{here}.limit", -2 * math.pi, 2 * math.pi)
            slope = number(r["slope"], f"{here}.slope", -10.0, 10.0)
            hits = matching(names, r["joint"])
            if not hits and "rules" in raw:
                raise TaskError(f"{here}.joint", f"no joint matches {r['joint']!r}")
            for joint in hits:
                side = joint[: len(joint) - len(r["joint"]) + 1] if r["joint"].startswith("*") else ""
                by = r["by"].replace("*", side, 1) if "*" in r["by"] else r["by"]
                if by not in names:
                    raise TaskError(f"{here}.by", f"{scope.body.source}: no joint {by!r} pairs with {joint!r}")
                if joint not in scope.active and by not in scope.active:
                    continue  # neither moves: the reference posture decides, once and for all
                iq, iby = (int(model.joints[model.getJointId(n)].idx_q) for n in (joint, by))
                rules.append(Rule(joint, by, limit, slope, iq, iby))
        return cls(tuple(rules))

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        q = sym.kin.q
        return [Constraint(q[r.iq] - r.slope * q[r.iby], -np.inf, r.limit) for r in self.rules]

    def rows(self, num: Numeric) -> list[Row]:
        assert num.joint_q is not None and num.joint_columns is not None and num.columns is not None
        out = []
        column = {int(iq): int(c) for iq, c in zip(num.joint_q, num.joint_columns, strict=True)}
        for r in self.rules:
            slack = r.limit + r.slope * num.q[r.iby] - num.q[r.iq]
            if slack < BUFFER:
                jac = np.zeros((1, num.columns.size))
                if r.iq in column:
                    jac[0, column[r.iq]] = -1.0
                if r.iby in column:
                    jac[0, column[r.iby]] += r.slope
                out.append(Row(jac, np.array([max(0.0, INSIDE - slack)])))
        return out

    def holds(self, num: Numeric) -> bool:
        return all(num.q[r.iq] - r.slope * num.q[r.iby] <= r.limit + LIMIT_TOL for r in self.rules)
