"""Reach strategies: the effector, the joints it may move, and the tasks.

A strategy is parsed from a config mapping::

    effector: right_hand
    joints: [root, "lumbar_*", "thoracic_*", "right_*", "*_hip_*", "*_ankle_*"]
    tasks:
      - {type: reach}                       # the goal, the verdict's task
      - {type: feet, heels: down}           # feet planted (hard)
      - {type: balance, margin: 0.02}       # CoM over the support polygon (hard)
      - {type: gaze, frame: eyes}           # look at the goal
      - {type: comfort, weight: 1.0}        # stay near the reference posture

``joints`` are joint names or glob patterns; ``root`` frees the floating
base. Joints not named are locked at the reference posture.

Priorities (Baerlocher & Boulic 1998): the hard tasks (feet, balance,
joint limits) are constraints that no other task may violate; the soft tasks
(reach, gaze, comfort) are solved lexicographically in increasing
``priority`` (defaults 1, 2, 3), each never degrading the ones before it.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field
from typing import Any

from oracles.body import ROOT, Body
from reach.errors import ModelError

SOFT_TASKS = ("reach", "gaze", "comfort")
TASK_KEYS = {
    "reach": {"type", "priority", "tolerance"},
    "feet": {"type", "frames", "heels", "support"},
    "contacts": {"type", "fixed", "hinge", "above_floor", "support"},
    "balance": {"type", "margin", "support"},
    "gaze": {"type", "priority", "frame"},
    "comfort": {"type", "priority", "weight"},
}


@dataclass(frozen=True)
class Contact:
    """A frame held on the floor at its reference placement.

    ``fixed`` holds position and orientation; ``hinge`` holds the position and
    one local axis, so the frame may pivot about it (a heel rising about the
    ball of the foot).
    """

    frame: str
    mode: str = "fixed"
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)


@dataclass(frozen=True)
class Strategy:
    """Everything the IK oracles need to know about how to reach.

    Attributes:
        effector: Frame that must reach the goal.
        joints: Active joints, in model order (``root`` when the base floats).
        contacts: Frames held on the floor (hard).
        above_floor: Frames kept at z >= 0 (hard), e.g. heels that may rise.
        support: Frames whose reference ground positions span the support polygon.
        margin: Balance margin [m] by which the polygon shrinks; None: no balance task.
        gaze: Frame whose x axis must point at the goal, or None.
        comfort: Weight of the comfort task; 0 disables it.
        order: Soft tasks present, highest priority first.
        tolerance: Reach tolerance [m] of the verdict.
    """

    effector: str
    joints: tuple[str, ...]
    contacts: tuple[Contact, ...] = ()
    above_floor: tuple[str, ...] = ()
    support: tuple[str, ...] = ()
    margin: float | None = None
    gaze: str | None = None
    comfort: float = 0.0
    order: tuple[str, ...] = ("reach",)
    tolerance: float = 0.005
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def floating(self) -> bool:
        return ROOT in self.joints


def _side_frames(body: Body, foot: str, parts: list[str]) -> list[str]:
    prefix = foot[: -len("foot")] if foot.endswith("foot") else f"{foot}_"
    names = [f"{prefix}{p}" for p in parts]
    return names if all(body.model.existFrame(n) for n in names) else [foot]


def _moves(body: Body, frame: str, active: set[str]) -> bool:
    """Whether any active joint lies between the world and a frame."""
    model = body.model
    j = int(model.frames[body.frame_id(frame)].parentJoint)
    while j > 0:
        if str(model.names[j]) in active:
            return True
        j = int(model.parents[j])
    return False


def _number(value: Any, where: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise ModelError(f"{where}: expected a number in [{lo}, {hi}], got {value!r}")
    return float(value)


def _frames(body: Body, value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ModelError(f"{where}: expected a list of frame names, got {value!r}")
    for name in value:
        body.frame_id(name)
    return tuple(value)


def parse_strategy(body: Body, effector: str, joints: list[str], tasks: list[dict[str, Any]] | None = None) -> Strategy:
    """Validate a strategy against a body; errors name the task, key and value."""
    body.frame_id(effector)
    if not isinstance(joints, list) or not joints or not all(isinstance(j, str) for j in joints):
        raise ModelError(f"joints: expected a non-empty list of joint names or patterns, got {joints!r}")
    names = [ROOT, *body.joint_names]
    active = set()
    for pattern in joints:
        hits = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
        if not hits:
            raise ModelError(f"{body.source}: joints: no joint matches {pattern!r}; joints are: {', '.join(names)}")
        active.update(hits)
    ordered = tuple(n for n in names if n in active)
    tasks = [{"type": "reach"}] if tasks is None else tasks
    if not isinstance(tasks, list):
        raise ModelError(f"tasks: expected a list of task mappings, got {tasks!r}")
    contacts: list[Contact] = []
    above: list[str] = []
    support: list[str] = []
    margin = gaze = None
    comfort, tolerance = 0.0, 0.005
    priorities: dict[str, float] = {}
    for i, task in enumerate(tasks):
        where = f"tasks[{i}]"
        if not isinstance(task, dict) or task.get("type") not in TASK_KEYS:
            raise ModelError(f"{where}: expected a mapping with type one of {sorted(TASK_KEYS)}, got {task!r}")
        kind = task["type"]
        unknown = set(task) - TASK_KEYS[kind]
        if unknown:
            raise ModelError(f"{where}: unknown keys {sorted(unknown)} for a {kind} task; allowed: {sorted(TASK_KEYS[kind])}")
        if kind in SOFT_TASKS:
            priorities[kind] = _number(task.get("priority", SOFT_TASKS.index(kind) + 1), f"{where}.priority", 0, 100)
        if kind == "reach":
            tolerance = _number(task.get("tolerance", 0.005), f"{where}.tolerance", 1e-6, 1.0)
        elif kind == "feet":
            feet = _frames(body, task.get("frames", ["right_foot", "left_foot"]), f"{where}.frames")
            heels = task.get("heels", "down")
            if heels not in ("down", "rise"):
                raise ModelError(f"{where}.heels: expected 'down' or 'rise', got {heels!r}")
            for f in feet:
                if heels == "down":
                    contacts.append(Contact(f, "fixed"))
                    support += _side_frames(body, f, ["heel_inner", "heel_outer", "toe_inner", "toe_outer"])
                else:
                    contacts.append(Contact(f, "hinge"))
                    above += _side_frames(body, f, ["heel"])
                    support += _side_frames(body, f, ["ball_inner", "ball_outer", "toe_inner", "toe_outer"])
            if "support" in task:
                support = list(_frames(body, task["support"], f"{where}.support"))
        elif kind == "contacts":
            contacts += [Contact(f, "fixed") for f in _frames(body, task.get("fixed", []), f"{where}.fixed")]
            contacts += [Contact(f, "hinge") for f in _frames(body, task.get("hinge", []), f"{where}.hinge")]
            above += _frames(body, task.get("above_floor", []), f"{where}.above_floor")
            support += _frames(body, task.get("support", []), f"{where}.support")
        elif kind == "balance":
            margin = _number(task.get("margin", 0.02), f"{where}.margin", 0.0, 0.5)
            if "support" in task:
                support = list(_frames(body, task["support"], f"{where}.support"))
        elif kind == "gaze":
            gaze = _frames(body, [task.get("frame", "eyes")], f"{where}.frame")[0]
        elif kind == "comfort":
            comfort = _number(task.get("weight", 1.0), f"{where}.weight", 0.0, 1e6)
    if "reach" not in priorities:
        raise ModelError("tasks: a strategy needs a reach task")
    if margin is not None and len(set(support)) < 3:
        raise ModelError("balance needs a support polygon: give a feet or contacts task, or balance.support with 3 frames or more")
    # A contact no active joint can move holds by itself; as a constraint it
    # would only be a constant (and degenerate for the solver), so it is dropped.
    contacts = [c for c in contacts if _moves(body, c.frame, set(ordered))]
    above = [f for f in above if _moves(body, f, set(ordered))]
    order = tuple(sorted(priorities, key=lambda k: (priorities[k], SOFT_TASKS.index(k))))
    return Strategy(
        effector, ordered, tuple(contacts), tuple(dict.fromkeys(above)), tuple(dict.fromkeys(support)),
        margin, gaze, comfort, order, tolerance,
    )
