"""An idle arm hangs: ``{type: hang, frames: [shoulder, elbow, wrist], cone: 45}``.

``frames`` is one chain, or a list of chains (``[[right_knee_flexion, right_hip_flexion], [left_knee_flexion,
left_hip_flexion]]``: with a 90 deg cone, each hip at or below its knee, a squat).

Each frame of a chain lies below the one before it, within ``cone`` deg
(as gaze's cone) of straight down: ``z[k-1] - z[k] >= cos(cone) * |p[k] - p[k-1]|``. Without
``frames``, the generated human's arms that do not carry the effector and
whose own joints move (``*_shoulder``, ``*_elbow_flexion``,
``*_wrist_flexion``) are chains, so one task list serves both hands; a body
without such arms (a URDF robot) must name its chain, top first.

Why: a strategy frees the idle arm's shoulder and elbow so that it hangs
under gravity when the trunk leans (the posture task's potential energy).
The reach stage, above the posture task, also uses it: at the lower edge of
the straight-legged whole body's volume the idle arm was thrown back to both
shoulder limits as a counterweight (hand behind the back at shoulder
height), while a goal 1 cm higher was reached with it hanging: 1-cm
neighbours changed a joint by up to 207 deg (``bench/posture.py``, low in
front). Within a cone below the shoulder the counterweight grows
continuously from the hanging arm, and stays one a person would use.

The 45 deg default is a modelling choice, calibrated on nothing: no
measurement of how far people swing the free arm back when reaching low was
found. It keeps a modest counterweight (the arm's centre of mass moves
about 0.25 m) and rules out the arm raised behind the back. ``cone`` changes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.errors import TaskError
from oracles.tasks.base import (
    BUFFER,
    INSIDE,
    Constraint,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    frames,
    number,
    relative_motion,
)

CONE = 45.0  # [deg] a modelling choice (see the module docstring)
HUMAN_ARM = ("{side}_shoulder", "{side}_elbow_flexion", "{side}_wrist_flexion")
HOLD_TOL = 1e-6  # [m] overshoot the verdict accepts


def _given_chains(given: Any, where: str, scope: Scope) -> tuple[tuple[str, ...], ...]:
    """``frames``: one chain, or several (a list of lists: both legs of a squat), each two frames or more, top first."""
    nested = isinstance(given, list) and bool(given) and all(isinstance(g, list) for g in given)
    chains = []
    for k, item in enumerate(given if nested else [given]):
        here = f"{where}.frames[{k}]" if nested else f"{where}.frames"
        chain = frames(scope, item, here)
        if len(chain) < 2:
            raise TaskError(here, f"expected at least two frames (a chain, top first), got {list(chain)!r}")
        chains.append(chain)
    return tuple(chains)


@dataclass
class HangTask(HardTask):
    """Chains of frames that hang: each below the one before, within a cone of straight down."""

    type: ClassVar[str] = "hang"
    keys: ClassVar[frozenset[str]] = frozenset({"frames", "cone"})
    summary: ClassVar[str] = ("an idle arm hangs: each of `frames` (a chain, or a list of chains) below the one "
                              "before, within `cone` deg (default 45) of straight down; by default the human's arms "
                              "that do not reach")

    chains: tuple[tuple[str, ...], ...] = ()
    cone: float = math.radians(CONE)  # [rad]
    _ids: list[list[int]] = field(default_factory=list, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> HangTask:
        cone = math.radians(number(raw.get("cone", CONE), f"{where}.cone", 0.0, 90.0))
        if "frames" in raw:
            return cls(_given_chains(raw["frames"], where, scope), cone)
        model = scope.body.model
        arms = [tuple(n.format(side=side) for n in HUMAN_ARM) for side in ("left", "right")]
        if not any(all(model.existFrame(n) for n in arm) for arm in arms):
            raise TaskError(f"{where}.frames", f"{scope.body.source}: no human arm ({', '.join(HUMAN_ARM)}) to hang "
                                               "by default; "
                            "give the chain's frames, top first")
        chains = []
        for chain in arms:
            if not all(model.existFrame(n) for n in chain) or scope.effector.startswith(chain[0].split("_")[0]):
                continue
            top, bottom = (int(model.frames[model.getFrameId(n)].parentJoint) for n in (chain[0], chain[-1]))
            if relative_motion(model, top, bottom, scope.active):
                chains.append(chain)
        return cls(tuple(chains), cone)

    @property
    def inert(self) -> bool:
        return not self.chains

    parametric: ClassVar[bool] = True  # the body enters only through the kinematics
    entered: ClassVar[bool] = True  # a squat's legs: standing, the hips are above the knees until the motion's end

    def bind(self, reference: Reference) -> None:
        self._ids = [[reference.body.frame_id(n) for n in chain] for chain in self.chains]

    def _links(self) -> list[tuple[int, int]]:
        return [(a, b) for ids in self._ids for a, b in zip(ids, ids[1:], strict=False)]

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        out = []
        for chain in self.chains:
            for a, b in zip(chain, chain[1:], strict=False):
                pa, pb = sym.kin.frame(a)[1], sym.kin.frame(b)[1]
                out.append(Constraint(pa[2] - pb[2] - math.cos(self.cone) * ca.norm_2(pb - pa), 0.0, np.inf))
        return out

    def _slack(self, num: Numeric, a: int, b: int) -> tuple[float, np.ndarray]:
        d = num.frame(b).translation - num.frame(a).translation
        length = float(np.linalg.norm(d))
        return -d[2] - math.cos(self.cone) * length, d / max(length, 1e-12)

    def rows(self, num: Numeric) -> list[Row]:
        assert num.jacobian is not None
        out = []
        for a, b in self._links():
            slack, unit = self._slack(num, a, b)
            if slack < BUFFER:
                jd = num.jacobian(b)[:3] - num.jacobian(a)[:3]
                out.append(Row((-jd[2] - math.cos(self.cone) * unit @ jd)[None], np.array([max(0.0, INSIDE - slack)])))
        return out

    def holds(self, num: Numeric) -> bool:
        return all(self._slack(num, a, b)[0] >= -HOLD_TOL for a, b in self._links())

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "chains": [list(c) for c in self.chains],
                "cone_deg": round(math.degrees(self.cone), 3)}
