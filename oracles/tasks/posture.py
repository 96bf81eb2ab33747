"""A natural posture: ``{type: posture, weights: {pattern: w}, energy: 5, limits: 1, start: 10, priority: 3}``.

Among the postures that reach (and look at) the goal, prefer the one a
person would take. The objective follows the optimisation-based posture
prediction of Marler, Yang, Abdel-Malek and co-workers (the Santos digital
human: Yang, J., Marler, R.T., Kim, H., Arora, J., Abdel-Malek, K. (2004),
*Multi-objective optimization for upper body posture prediction*, AIAA
2004-4506; Marler, R.T., Arora, J.S., Yang, J., Kim, H.J., Abdel-Malek, K.
(2009), *Use of multi-objective optimization for digital human posture
prediction*, Engineering Optimization 41(10), 925-943), whose terms are
summed here:

* **joint displacement** from the neutral (reference) posture, each joint's
  displacement normalised by its range, times a per-joint weight
  (``weights``: joint name or glob pattern -> weight; defaults in
  ``WEIGHTS``): the spine and the shoulder girdle weigh more than the arm,
  as in Yang et al., who weight the spine's joints above the arm's;
* **potential energy** of lifting (``energy``): each segment's rise of its
  centre of mass, relative to the root joint of its limb (the shoulder
  girdle for an arm, the hip for a leg, the neck for the head), above its
  height there at the reference posture, squared and weighted by its mass
  share (segments lowered cost nothing): lifting an elbow costs, and an
  idle arm hangs under gravity however the trunk leans rather than keeping
  its angles to the trunk;
* **discomfort near joint limits** (``limits``): the eighth power of each
  joint's normalised distance from mid-range, negligible in mid-range and
  steep in the last 10 % of the range, as Marler et al.'s discomfort term;
* **continuity** (``start``): with the character's current posture given
  (a query's ``from``), the range-normalised displacement from it, so that
  the answer stays near where the character is.

The weights are modelling choices in that family's spirit, not values from a
table; Zhang, Kuo and Chaffin (1998, J. Biomech. 31(11)) report under 5 deg
RMS error for seated reaches with weighted joint effort, which is the
accuracy such objectives reach when tuned to data. ``bench/posture.py``
measures what these weights give (elbow height, joints near limits,
continuity).
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.errors import TaskError
from oracles.tasks.base import Numeric, Reference, Row, Scope, SoftTask, Symbolic, number

# Per-joint weights of the displacement term, first matching pattern wins
# (modelling choices; see the module docstring). The hand's roll (forearm
# pronation, the wrist) weighs more than the shoulder: a goal for the grip
# centre barely constrains it, so with light weights (0.3, 0.5) the roll of
# two goals 1 cm apart flipped by up to 110 deg; with these, 1-cm neighbours
# asked independently changed a joint by over 10 deg in 4 pairs of 300
# instead of 9 (demo atlas), and a hand reaching for a point keeps its
# forearm near neutral.
WEIGHTS: dict[str, float] = {
    "lumbar_*": 4.0, "thoracic_*": 4.0, "neck_*": 1.0, "*_clavicle_*": 3.0,
    "*_shoulder_*": 1.0, "*_elbow_*": 0.5, "*_forearm_*": 2.0, "*_wrist_*": 1.5,
    "*_hip_*": 2.0, "*_knee_*": 1.0, "*_ankle_*": 2.0,
    "root_roll": 3.0, "root_pitch": 3.0, "root_yaw": 1.0, "root_x": 0.0, "root_y": 0.0, "root_z": 0.0,
}
ENERGY_SCALE = 0.1  # [m] a segment's rise that costs as much as its mass share
# default weight of the energy term: an idle arm left at 60 deg from hanging costs ten times its shoulder's displacement
ENERGY = 5.0
# Default weight of the displacement from the character's current posture: a
# 10 deg change of one joint then costs about as much as a 3 cm rise of the
# forearm, so that 1-cm goal steps move the joints by degrees, not tens of them
# (the least pull that kept 1-cm neighbours under 10 deg: docs/decisions/0007).
START = 10.0
LIMIT_POWER = 8
DLS_GAIN = 0.1


@dataclass
class PostureTask(SoftTask):
    """Prefer a natural posture (see the module docstring)."""

    type: ClassVar[str] = "posture"
    keys: ClassVar[frozenset[str]] = frozenset({"weights", "energy", "limits", "start"})
    summary: ClassVar[str] = ("a natural posture: weighted joint displacement, the energy of lifting segments, "
                              "discomfort near joint limits, and nearness to the character's current posture "
                              "(`weights`, `energy`, `limits`, `start`)")
    default_priority: ClassVar[int] = 3
    slack: ClassVar[float] = 1e-6

    weights: dict[str, float] = field(default_factory=dict)
    energy: float = ENERGY
    limits: float = 1.0
    start: float = START
    priority: float = 3.0
    _segments: list[tuple[int, np.ndarray, float, int, float]] = field(default_factory=list, init=False, repr=False,
        compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> PostureTask:
        given = raw.get("weights", {})
        if not isinstance(given, dict) or not all(isinstance(k, str) for k in given):
            raise TaskError(f"{where}.weights", f"expected a mapping of joint name or pattern to weight, got {given!r}")
        weights = {k: number(v, f"{where}.weights.{k}", 0.0, 1e3) for k, v in given.items()}
        return cls(
            {**weights, **{k: v for k, v in WEIGHTS.items() if k not in weights}},
            number(raw.get("energy", ENERGY), f"{where}.energy", 0.0, 1e3),
            number(raw.get("limits", 1.0), f"{where}.limits", 0.0, 1e3),
            number(raw.get("start", START), f"{where}.start", 0.0, 1e3),
            cls.priority_of(raw, where),
        )

    def weight(self, name: str) -> float:
        return next((w for p, w in self.weights.items() if fnmatch.fnmatchcase(name, p)), 1.0)

    def bind(self, reference: Reference) -> None:
        """Each massive link: joint, centre of mass in the joint frame, mass share, limb root joint, reference rise."""
        model, data = reference.body.model, reference.data
        total = sum(float(model.inertias[j].mass) for j in range(1, model.njoints))
        children: dict[int, int] = {}
        for j in range(1, model.njoints):
            children[int(model.parents[j])] = children.get(int(model.parents[j]), 0) + 1
        self._segments = []
        for j in range(1, model.njoints):
            inertia = model.inertias[j]
            if inertia.mass > 0:
                # The limb's root: the nearest ancestor joint (or itself) whose parent branches (the trunk).
                root = j
                while root > 1 and children.get(int(model.parents[root]), 0) < 2:
                    root = int(model.parents[root])
                lever = np.asarray(inertia.lever, float)
                rise0 = float(data.oMi[j].act(lever)[2] - data.oMi[root].translation[2])
                self._segments.append((j, lever, float(inertia.mass) / total, root, rise0))

    parametric: ClassVar[bool] = True

    def numbers(self) -> dict[str, np.ndarray]:
        return {f"{key}{i}": np.atleast_1d(v) for i, (_, lever, share, _, rise0) in enumerate(self._segments)
                for key, v in (("lever", lever), ("share", share), ("rise", rise0))}

    def objective(self, sym: Symbolic) -> ca.SX:
        w = np.array([self.weight(n) for n in sym.names]) if sym.names else np.ones(sym.x.numel())
        norm = (sym.x - sym.x_ref) / sym.span
        f = ca.dot(ca.SX(w), norm**2)
        if self.energy > 0:
            rises = []
            for i, (j, lever, share_, root, rise0) in enumerate(self._segments):
                rot, pos = sym.kin.placements[j]
                z = (rot @ sym.number(self, f"lever{i}", lever) + pos)[2] - sym.kin.placements[root][1][2]
                rise = (z - sym.number(self, f"rise{i}", rise0)) / ENERGY_SCALE
                share = sym.number(self, f"share{i}", share_)
                # A smooth max(rise, 0): only lifting costs.
                rises.append(share * (0.5 * (rise + ca.sqrt(rise**2 + 1e-4))) ** 2)
            f += self.energy * ca.sum1(ca.vertcat(*rises))
        if self.limits > 0 and sym.lower is not None:
            joint = (np.array([not n.startswith("root_") for n in sym.names]) if sym.names
                     else np.ones(sym.x.numel(), bool))
            mid = sym.lower + 0.5 * sym.span
            dist = (sym.x - mid) / (0.5 * sym.span)
            f += self.limits * ca.dot(ca.SX(joint.astype(float)), dist**LIMIT_POWER) / max(int(joint.sum()), 1)
        if self.start > 0 and sym.start is not None and sym.start_weight is not None:
            f += self.start * sym.start_weight * ca.sumsqr((sym.x - sym.start) / sym.span)
        return f

    def level(self, num: Numeric) -> Row:
        # dls approximates the task by its displacement terms: a pull towards the
        # neutral posture (and the start, when given), weighted per joint.
        assert (num.columns is not None and num.joint_columns is not None and num.joint_q is not None
                and num.x_ref is not None)
        target = num.x_ref[num.joint_columns]
        if num.start is not None and num.start_weight > 0:
            a = self.start * num.start_weight
            target = (target + a * num.start[num.joint_columns]) / (1 + a)
        select = np.zeros((num.joint_columns.size, num.columns.size))
        select[np.arange(num.joint_columns.size), num.joint_columns] = 1.0
        return Row(DLS_GAIN * select, DLS_GAIN * (target - num.q[num.joint_q]))
