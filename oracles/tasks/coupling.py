"""Coupled joint limits: ``{type: coupling, rules: [{joint, by, limit, slope}, ...]}``.

A joint's upper limit that depends on another joint: ``q[joint] <= limit +
slope * q[by]`` (radians); ``joint`` may also be a list, whose joints' sum
is limited. A rule's first ``joint`` and ``by`` may hold one ``*``, matched
per side (``*_hip_flexion`` with ``*_knee_flexion``: right with right, left
with left; a ``*`` in the list's other joints takes the same side).
``add`` lists rules applied besides the defaults (``rules`` replaces them).
Without ``rules`` the task applies the couplings of the generated human:

* **Hamstrings.** With the knee straight, hip flexion stops at about 80 deg,
  the straight-leg raise of adults (Magee, D.J. (2014), *Orthopedic Physical
  Assessment*, 6th ed., ch. 9: 80-90 deg is normal; we take the lower end,
  the average adult being short of the athletic norm); with the knee flexed
  90 deg or more it reaches the full 120 deg of the AAOS range (Norkin &
  White 2016). Between, the limit grows linearly: 80 deg + (40/90) x knee
  flexion; above 90 deg of knee flexion the hip's own 120 deg bound applies.
  The same rule with the roles of hip and knee exchanged (the knee cannot
  straighten fully with the hip flexed past 80 deg) is the same inequality.
* **Lumbo-pelvic flexion with straight knees.** Each joint's own range
  (hip 80 deg by the rule above, lumbar 60, thoracic 20) let the model's
  straight-legged stoop lay a fist on the floor, which only flexible people
  do: in the standing fingertip-to-floor test the average adult's fingertips
  just touch the floor, knuckles on the floor is above average and palms
  flat excellent (Perret, C. et al. (2001), Arch Phys Med Rehabil 82:1566-70,
  the test; the grades as yogabody.com/forward-fold-test gives them), and
  the median man's fingertips reach his toes in the seated sit-and-reach,
  the same hamstring and low-back flexibility (ACSM norms). Forward bending
  is hip and lumbar flexion together (the lumbopelvic rhythm, reviewed by
  Vazirian, Van Dillen & Bazrgari 2016, Int Musculoskelet Med 38:51-58), so
  their sum is limited: hip + lumbar flexion <= 100 deg with the knee
  straight, the value at which the 50th-percentile man's lowest grip centre,
  in a straight-legged stoop in front of his right foot (0.35, -0.15 m), is
  0.14 m above the floor, his fingertips about at it (the grip lies 0.13 m
  from the middle fingertip: ANSUR II's hand length less its grip offset)
  (calibrated on the model with the twist rule below, not measured on
  people; thoracic flexion adds its own 20 deg). An earlier limit
  was 90 deg, calibrated on a stoop that side-bent and twisted the spine to
  their limits (the twist rule had not been made). The knees slacken the
  hamstrings: 1 deg more per degree of knee flexion, so that at 90 deg the
  joints' own ranges (120 + 60) apply again. A crouch therefore reaches
  lower than the straight-legged whole body, as people do.
* **No twist or side-bend to a limit in a full stoop.** Hip + lumbar
  flexion + |lumbar side-bend| + |thoracic rotation| <= 110 deg with the
  knee straight (four rules, one per sign; the knee slackens it as above):
  at the full stoop 10 deg of side-bend and twist together remain, upright
  their own ranges. Without it the lowest straight-legged reach took the
  lumbar side-bend to its 35 deg limit and the thoracic rotation to its
  45 deg, the pelvis 21 cm aside and the legs tilted to their ankle and hip
  limits (a sideways "Z"): turning and bending sideways lowers the
  shoulder when forward flexion is spent, which people do not do with
  straight knees; they bend the knees (the crouch). Side-bend range is not
  smaller in end-range lumbar flexion than in neutral (*Lumbar spine side
  bending is reduced in end range extension compared to neutral and end
  range flexion postures*, Manual Therapy 19(2):114-118, 2014,
  doi:10.1016/j.math.2013.08.004, 20 people; read in its abstract only): the
  rule is not a range of motion but a choice of what a straight-legged stoop
  uses, and the 10 deg is a modelling choice, not a measured value.

* **Shoulder: no abduction past the frontal plane with the arm extended.**
  The shoulder is three revolute joints (flexion, abduction, rotation; an
  Euler sequence), which reach most humerus directions twice: flexion
  ``f`` and abduction ``a`` point the arm as ``f - 180 deg`` and
  ``180 deg - a`` do, the humerus turned half a turn about its own axis.
  Where the ranges allow both (flexion 120-180 deg), the second is an
  extended arm swung up past the side (say flexion -57 deg, abduction
  140 deg for an arm hanging forward), which no person takes: the clinical
  ranges are measured with abduction in the frontal plane and extension
  with the arm at the side (AAOS 1965, via Norkin & White 2016, the
  model's ranges: ``oracles/bodies/anthropometry.py``), the humerus's axial
  rotation is about 160 deg in all (-90 to 70 deg here) and is itself
  limited by the arm's direction (Wang, X. et al. (1998), *Three-dimensional
  modelling of the motion range of axial rotation of the upper arm*,
  J Biomech 31(10), 899-908). Without the rule builds and answers took that
  second posture, and two goals 1 cm apart flipped the shoulder by 165 deg.
  The rule: abduction <= 180 deg + 2 x flexion, which leaves every flexed
  arm its full range and an extended one abduction up to 180 deg + 2 x
  flexion (90 deg at 45 deg of extension, 60 deg at the full 60); near the
  overhead pole, where both postures are real (the arm raised to vertical
  by flexion or by abduction: Codman's paradox), a little extension with
  high abduction remains. The slope is a modelling choice, not a measured
  value.

No other coupling changed a reach volume noticeably enough to model here.

**The squat's knee** (not a default: ``configs/human.yaml``'s squat adds it with ``add``). A squat with the heels up
flexes the knee 157 +- 6 deg (Hemmerich, A. et al. (2006), *Hip, knee, and ankle kinematics of high range of motion
activities of daily living*, J Orthop Res 24(4):770-781, abstract: 30 subjects), past the 135 deg the knee's own
muscles reach (AAOS, the body's range): the thigh is pressed onto the calf by the body's weight, and the squat
strategy takes 157 deg as its own range (``strategies[i].ranges``). The rectus femoris crosses both the hip and the
knee, so the deep flexion needs the hip flexed: knee flexion <= 135 deg + (22 / 90) x hip flexion, the full 157 deg
from 90 deg of hip flexion (the squats' hip flexion, 95 +- 27 deg with the heels flat, same abstract). The line
between the two figures is a modelling choice, not a measured coupling (:data:`RECTUS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from oracles.errors import TaskError
from oracles.tasks.base import BUFFER, INSIDE, Constraint, HardTask, Numeric, Row, Scope, Symbolic, matching, number

LIMIT_TOL = 1e-6  # [rad] overshoot the verdict accepts
HAMSTRINGS = {"joint": "*_hip_flexion", "by": "*_knee_flexion", "limit": math.radians(80.0), "slope": 40.0 / 90.0}
# Calibrated on the 50th-percentile man (see the module docstring).
LUMBOPELVIC = {"joint": ["*_hip_flexion", "lumbar_flexion"], "by": "*_knee_flexion", "limit": math.radians(100.0),
               "slope": 1.0}
# A modelling choice (see the module docstring): side-bend and twist spent by a full straight-legged stoop.
TWIST = [{"joint": ["*_hip_flexion", "lumbar_flexion", lateral, rotation], "by": "*_knee_flexion",
          "limit": math.radians(110.0), "slope": 1.0}
         for lateral in ("lumbar_lateral", "-lumbar_lateral")
         for rotation in ("thoracic_rotation", "-thoracic_rotation")]
# A modelling choice against the Euler sequence's second cover (see the module docstring).
SHOULDER = {"joint": "*_shoulder_abduction", "by": "*_shoulder_flexion", "limit": math.pi, "slope": 2.0}
DEFAULT_RULES = [HAMSTRINGS, LUMBOPELVIC, *TWIST, SHOULDER]
# The squat's: knee flexion past the muscles' 135 deg only with the hip flexed (see the module docstring).
RECTUS = {"joint": "*_knee_flexion", "by": "*_hip_flexion", "limit": math.radians(135.0), "slope": 22.0 / 90.0}


@dataclass(frozen=True)
class Rule:
    """sum(sign * q[joints]) <= limit + slope * q[by] (configuration indices; a joint after the first may be written
    ``-name``: subtracted)."""

    joints: tuple[str, ...]
    by: str
    limit: float
    slope: float
    iq: tuple[int, ...] = ()
    iby: int = -1
    signs: tuple[float, ...] = ()  # one per joint (+1 or -1); empty: every joint added

    def __post_init__(self) -> None:
        if not self.signs:
            object.__setattr__(self, "signs", (1.0,) * len(self.joints))

    def total(self, q: Any) -> Any:
        return sum(s * q[i] for s, i in zip(self.signs, self.iq, strict=True))

    @property
    def joint(self) -> str:
        """The first (sided) joint of the rule, which names it."""
        return self.joints[0]


def _rule(joint: str, summed: list[str], by: str, limit: float, slope: float, here: str, written: bool,
          scope: Scope) -> Rule | None:
    """A rule for one joint its first name matches, or None: a default rule about joints the body lacks, or one whose
    joints do not move (the reference posture decides it, once and for all)."""
    model = scope.body.model
    # A leading '*' is a side: the same side's joints are summed and coupled.
    side = joint[: len(joint) - len(summed[0]) + 1] if summed[0].startswith("*") else ""
    signs = (1.0, *(-1.0 if n.startswith("-") else 1.0 for n in summed[1:]))
    group = [joint, *(n.lstrip("-").replace("*", side, 1) for n in summed[1:])]
    by = by.replace("*", side, 1) if "*" in by else by
    names = scope.body.joint_names
    missing = [(n, field) for n, field in [*((n, "joint") for n in group[1:]), (by, "by")] if n not in names]
    if missing and not written:
        return None
    if missing:
        raise TaskError(f"{here}.{missing[0][1]}", f"{scope.body.source}: no joint {missing[0][0]!r} pairs with "
                                                   f"{joint!r}")
    if not any(n in scope.active for n in (*group, by)):
        return None
    iq = tuple(int(model.joints[model.getJointId(n)].idx_q) for n in group)
    iby = int(model.joints[model.getJointId(by)].idx_q)
    return Rule(tuple(group), by, limit, slope, iq, iby, signs)


def _fields(here: str, r: Any) -> tuple[list[str], float, float]:
    """A written rule's joints summed (a name or a list of them), its limit [rad] and slope, checked."""
    ok = isinstance(r, dict) and set(r) == {"joint", "by", "limit", "slope"} and isinstance(r["by"], str)
    summed = r.get("joint") if ok else None
    if isinstance(summed, str):
        summed = [summed]
    if not ok or not isinstance(summed, list) or not summed or not all(isinstance(n, str) for n in summed):
        raise TaskError(here, "expected {joint: name or [names, summed], by: name, limit: rad, slope: number}, got "
                              f"{r!r}")
    limit = number(r["limit"], f"{here}.limit", -4 * math.pi, 4 * math.pi)
    slope = number(r["slope"], f"{here}.slope", -10.0, 10.0)
    return summed, limit, slope


@dataclass
class CouplingTask(HardTask):
    """Joint limits that depend on another joint (see the module docstring)."""

    type: ClassVar[str] = "coupling"
    keys: ClassVar[frozenset[str]] = frozenset({"rules", "add"})
    summary: ClassVar[str] = ("coupled joint limits, sum(q[joints]) <= limit + slope q[by]; by default the hamstrings' "
                               "(hip flexion 80 deg, hip + lumbar flexion 100 deg, and with side-bend and twist "
                               "110 deg, with the knee straight) and the "
                               "shoulder's (abduction <= 180 deg + 2 flexion: no extended arm swung up past the side); "
                               "`add`: rules besides the defaults")

    rules: tuple[Rule, ...] = ()

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> CouplingTask:
        given = raw.get("rules", DEFAULT_RULES)
        added = raw.get("add", [])
        for key, value in (("rules", given), ("add", added)):
            if not isinstance(value, list):
                raise TaskError(f"{where}.{key}", f"expected a list of {{joint, by, limit, slope}}, got {value!r}")
        names = scope.body.joint_names
        rules = []
        # a rule the config writes must match the body; a default one about joints the body lacks is skipped
        entries = [(f"{where}.rules[{k}]", r, "rules" in raw) for k, r in enumerate(given)]
        entries += [(f"{where}.add[{k}]", r, True) for k, r in enumerate(added)]
        for here, r, written in entries:
            summed, limit, slope = _fields(here, r)
            hits = matching(names, summed[0])
            if not hits and written:
                raise TaskError(f"{here}.joint", f"no joint matches {summed[0]!r}")
            for joint in hits:
                rule = _rule(joint, summed, r["by"], limit, slope, here, written, scope)
                if rule is not None:
                    rules.append(rule)
        return cls(tuple(rules))

    parametric: ClassVar[bool] = True  # the body enters only through the kinematics

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        q = sym.kin.q
        return [Constraint(r.total(q) - r.slope * q[r.iby], -np.inf, r.limit) for r in self.rules]

    def rows(self, num: Numeric) -> list[Row]:
        assert num.joint_q is not None and num.joint_columns is not None and num.columns is not None
        out = []
        column = {int(iq): int(c) for iq, c in zip(num.joint_q, num.joint_columns, strict=True)}
        for r in self.rules:
            slack = r.limit + r.slope * num.q[r.iby] - r.total(num.q)
            if slack < BUFFER:
                jac = np.zeros((1, num.columns.size))
                for sign, i in zip(r.signs, r.iq, strict=True):
                    if i in column:
                        jac[0, column[i]] -= sign
                if r.iby in column:
                    jac[0, column[r.iby]] += r.slope
                out.append(Row(jac, np.array([max(0.0, INSIDE - slack)])))
        return out

    def limit_slacks(self, q: np.ndarray) -> dict[str, float]:
        return {" + ".join(r.joints): float(r.limit + r.slope * q[r.iby] - r.total(q)) for r in self.rules}

    def holds(self, num: Numeric) -> bool:
        matrix, limits = self._linear
        return bool(np.all(matrix @ num.q[: matrix.shape[1]] <= limits + LIMIT_TOL))

    @cached_property
    def _linear(self) -> tuple[np.ndarray, np.ndarray]:
        """The rules as one matrix over the configuration and their limits: A q <= limit. Rule by rule in Python, a
        motion's frame spent 20 us here."""
        width = 1 + max((i for r in self.rules for i in (*r.iq, r.iby)), default=-1)
        matrix = np.zeros((len(self.rules), width))
        for k, r in enumerate(self.rules):
            for sign, i in zip(r.signs, r.iq, strict=True):
                matrix[k, i] += sign
            matrix[k, r.iby] -= r.slope
        return matrix, np.array([r.limit for r in self.rules])

    def describe(self) -> dict[str, Any]:
        rules = "; ".join(f"{_terms(r)} <= {r.limit:.4f} {'-' if r.slope < 0 else '+'} {abs(r.slope):.4f} "
                          f"x {r.by}" for r in self.rules)
        return {**super().describe(),
                "rules": [{"joints": [n if sign > 0 else f"-{n}" for n, sign in zip(r.joints, r.signs, strict=True)],
                           "by": r.by, "limit": r.limit, "slope": r.slope}
                          for r in self.rules],
                **({"text": f"coupled limits [rad]: {rules}"} if self.rules else {})}


def _terms(rule: Rule) -> str:
    out = rule.joints[0]
    for name, sign in zip(rule.joints[1:], rule.signs[1:], strict=True):
        out += f" {'-' if sign < 0 else '+'} {name}"
    return out
