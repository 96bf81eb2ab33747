"""An answer and its parts: the refinement's outcomes, a posture as joint values and a root, a request's orientation.

What the selector (:mod:`reach.answers.select`) returns and the serving layer, the motion planner and the tools read:
joint names and units as the model's (radians, metres), the root's pose in the world frame.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from oracles.protocol import COS, SIN
from reach.errors import InputError

# Outcomes of refinement, in Answer.refined.
REFINED = "ok"  # the IK reached the exact goal; posture and residual are its own
FAILED = "failed"  # the IK did not reach it; posture is the stored one
TIMEOUT = "timeout"  # the budget ran out; posture is the stored one
SKIPPED = "skipped"  # refinement was not asked for
UNAVAILABLE = "unavailable"  # the strategy's oracle stores no postures (analytic shapes)
NONE = "none"  # no strategy reaches the goal: there is no posture to refine
ERROR = "error"  # the refinement could not run (a server's worker died); posture is the stored one


@dataclass(frozen=True)
class Answer:
    """The selector's answer for one goal.

    Attributes:
        effector: The effector asked about.
        goal: The goal [m] in the atlas's world frame.
        strategy: The chosen strategy, or None when none reaches.
        reachable: Whether any strategy reaches the goal.
        alternatives: Other strategies that also reach it, in priority order
            (one before the chosen strategy was passed over: its posture had
            more joints at their limits; see the module docstring).
        posture: Joint name -> angle [rad] (or length [m] for prisms), or None.
        root: Pose of a floating base, ``{"position": [x, y, z], "quaternion":
            [qx, qy, qz, qw]}`` [m], or None.
        residual: Effector-to-goal distance [m] of that posture, or None.
        refined: One of ``ok``, ``failed``, ``timeout``, ``skipped``, ``unavailable``, or ``none`` for an unreachable
            goal.
        seconds: Time spent answering [s].
        handover: When a strategy of higher priority passed the goal over,
            ``{"from": its name, "limits": the limits its posture came
            near}`` (see the module docstring); else None.
        within: When the posture is a stored one (refinement skipped, out of
            time or missed, see ``refined``): the distance [m] it stops short
            of the goal; None when the posture was solved at the goal (or
            there is none).
        nearest: With ``miss="unreachable"``, for a goal the trees hold but
            no refinement reached: ``{"strategy", "point" [m], "distance"
            [m], "posture", "root"}``, the nearest point a stored posture of
            the first such strategy reaches; else None.
        index: The reachability index (see :mod:`reach.maps.index`) of the chosen
            strategy's nearest reachable stored vertex, the share of
            approach directions reached there, when its tree has one; else None.
        step: For a strategy that steps (the ``step`` task), where its posture sets the stepping foot down:
            ``{"foot", "position": [x, y, z] [m], "yaw": [rad] about +z from where it stood}``; else None.
    """

    effector: str
    goal: tuple[float, ...]
    strategy: str | None
    reachable: bool
    alternatives: tuple[str, ...] = ()
    posture: dict[str, float] | None = None
    root: dict[str, list[float]] | None = None
    residual: float | None = None
    refined: str = SKIPPED
    seconds: float = 0.0
    handover: dict[str, Any] | None = None
    within: float | None = None
    nearest: dict[str, Any] | None = None
    posture_json: bytes | None = field(default=None, repr=False, compare=False)
    index: float | None = None
    step: dict[str, Any] | None = None

    def to_json(self) -> bytes:
        """UTF-8 JSON of to_dict(), reusing the posture's cached encoding when there is one."""
        if self.posture_json is None:
            return json.dumps(self.to_dict(), allow_nan=False, separators=(",", ":")).encode()
        head = {k: v for k, v in self.to_dict().items() if k not in ("posture", "root")}
        return json.dumps(head, allow_nan=False, separators=(",", ":")).encode()[:-1] + b"," + self.posture_json + b"}"

    def as_start(self) -> dict[str, float] | None:
        """This answer's posture as the next query's ``from``: joint values and,
        for a floating base, ``root_x`` ... ``root_qw``; None when it has no posture."""
        if self.posture is None:
            return None
        start = dict(self.posture)
        if self.root is not None:
            start.update(zip(("root_x", "root_y", "root_z"), self.root["position"], strict=True))
            start.update(zip(("root_qx", "root_qy", "root_qz", "root_qw"), self.root["quaternion"], strict=True))
        return start

    def to_dict(self) -> dict[str, Any]:
        # By hand rather than dataclasses.asdict, whose deep copies cost more than the lookup.
        return {
            "effector": self.effector, "goal": list(self.goal), "strategy": self.strategy, "reachable": self.reachable,
            "alternatives": list(self.alternatives), "posture": self.posture, "root": self.root,
            "residual": self.residual, "refined": self.refined, "seconds": self.seconds, "handover": self.handover,
            "within": self.within, "nearest": self.nearest, "index": self.index, "step": self.step,
        }


def timed_out(answer: Answer, late: bool) -> Answer:
    """An answer not refined because its request's deadline had passed: its stored posture, marked ``timeout``."""
    return dataclasses.replace(answer, refined=TIMEOUT) if late and answer.refined == SKIPPED else answer


def orientation_of(wire: dict[str,
                              list[float]] | list[dict[str,
                                                       list[float]]] | None) -> np.ndarray | list[np.ndarray] | None:
    """A request's ``orientation`` as the selector takes it: a unit direction (3,) or a rotation (3, 3) from a
    quaternion ``[qx, qy, qz, qw]`` (normalised), or a list of them, one per goal; None stays None."""
    if wire is None:
        return None
    if isinstance(wire, list):
        return [orientation_of(w) for w in wire]  # type: ignore[misc]
    key = "direction" if "direction" in wire else "quaternion"
    v = np.asarray(wire[key], float)
    # Scaled by the largest component before normalising: [1e200, 0, 0]'s norm overflowed to a zero direction.
    top = np.abs(v).max(initial=0.0)
    if not np.all(np.isfinite(v)) or top == 0.0:
        raise InputError(f"orientation.{key}", f"expected finite numbers, not all zero, got {wire[key]!r}")
    v = v / top
    if key == "direction":
        return v / np.linalg.norm(v)  # type: ignore[no-any-return]
    return np.asarray(Rotation.from_quat(v).as_matrix())


def split_posture(names: tuple[str, ...], q: np.ndarray) -> tuple[dict[str, float], dict[str, list[float]] | None]:
    """Joint name -> value [rad or m], and the root pose when the names carry one. A continuous joint's
    coordinates (``NAME.cos``, ``NAME.sin``) are its one angle ``NAME``, in (-pi, pi]."""
    joints: dict[str, float] = {}
    for k, n in enumerate(names):
        if n.startswith("root_") or n.endswith(SIN):
            continue
        if n.endswith(COS):
            angle = math.atan2(float(q[k + 1]), float(q[k]))
            joints[n[: -len(COS)]] = math.pi if angle <= -math.pi else angle
        else:
            joints[n] = float(q[k])
    if "root_x" not in names:
        return joints, None
    i = names.index("root_x")
    return joints, {"position": [float(v) for v in q[i : i + 3]], "quaternion": [float(v) for v in q[i + 3 : i + 7]]}


def joint_names(names: tuple[str, ...]) -> list[str]:
    """The names :func:`split_posture` gives values of: the joints, and the root's coordinates (``root_x`` ...)."""
    return [n[: -len(COS)] if n.endswith(COS) else n for n in names if not n.endswith(SIN)]


def set_joints(names: tuple[str, ...], q: np.ndarray, joints: dict[str, float], field: str = "posture") -> np.ndarray:
    """q (nq,) with the given joints' values [rad or m] (a continuous joint by its angle); returns q. Raises
    InputError naming ``field`` for a name that is none of :func:`joint_names`."""
    index = {n: k for k, n in enumerate(names)}
    for n, v in joints.items():
        if n in index:
            q[index[n]] = v
        elif n + COS in index:
            q[index[n + COS]], q[index[n + SIN]] = math.cos(v), math.sin(v)
        else:
            raise InputError(field, f"unknown joint {n!r}; the posture's names are {', '.join(joint_names(names))}")
    return q


def posture_vector(names: tuple[str, ...], reference: np.ndarray, joints: dict[str, float] | None,
                   root: dict[str, list[float]] | None) -> np.ndarray:
    """The inverse of :func:`split_posture`: a posture (nq,) from an answer's joints and root, ``reference``
    elsewhere."""
    q = set_joints(names, np.array(reference, float), joints or {})
    index = {n: k for k, n in enumerate(names)}
    if root is not None and "root_x" in index:
        i = index["root_x"]
        q[i : i + 3], q[i + 3 : i + 7] = root["position"], root["quaternion"]
    return q
