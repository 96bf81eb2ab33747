"""Reach strategies: the effector, the joints it may move, and the tasks.

A strategy is parsed from a config mapping::

    effector: right_hand
    joints: [root, "lumbar_*", "thoracic_*", "right_*", "*_hip_*", "*_ankle_*"]
    tasks:
      - {type: reach}                       # the goal, the verdict's task
      - {type: feet, heels: down}           # feet planted (hard)
      - {type: balance, margin: 0.02}       # CoM over the support polygon (hard)
      - {type: self_collision}              # no segment through another (hard)
      - {type: floor}                       # nothing below z = 0 but the feet (hard)
      - {type: coupling}                    # the hamstrings' hip limit (hard)
      - {type: gaze, frame: eyes}           # look at the goal
      - {type: posture}                     # a natural posture

``joints`` are joint names or glob patterns; ``root`` frees the floating
base. Joints not named are locked at the reference posture. Each task type
is a class of :mod:`oracles.tasks`, which owns its keys.

Priorities (Baerlocher & Boulic 1998): the hard tasks (feet, balance,
collisions, couplings, joint limits) are constraints that no other task may
violate; the soft tasks (reach, gaze, posture or comfort) are solved
lexicographically in increasing ``priority`` (defaults 1, 2, 3), each never
degrading the ones before it beyond its hold (reach keeps half its
tolerance).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from oracles.bodies.body import Body
from oracles.bodies.urdf import ROOT
from oracles.errors import ModelError, OracleError, TaskError
from oracles.tasks import TASKS, FeetTask, HardTask, ReachTask, Scope, SoftTask, Task
from oracles.tasks.base import matching


@dataclass(frozen=True)
class Strategy:
    """Everything the IK oracles need to know about how to reach.

    Attributes:
        effector: Frame that must reach the goal.
        joints: Active joints, in model order (``root`` when the base floats).
        tasks: The tasks, in the config's order.
    """

    effector: str
    joints: tuple[str, ...]
    tasks: tuple[Task, ...]

    @property
    def floating(self) -> bool:
        return ROOT in self.joints

    @property
    def hard(self) -> tuple[HardTask, ...]:
        """The constraints, in the config's order."""
        return tuple(t for t in self.tasks if isinstance(t, HardTask))

    @property
    def soft(self) -> tuple[SoftTask, ...]:
        """The objectives, highest priority first (ties: reach, gaze, comfort)."""
        soft = [t for t in self.tasks if isinstance(t, SoftTask)]
        return tuple(sorted(soft, key=lambda t: (t.priority, t.default_priority)))

    @property
    def reach(self) -> ReachTask:
        return next(t for t in self.tasks if isinstance(t, ReachTask))

    @property
    def entered(self) -> set[str]:
        """The hard tasks (types) a posture may enter rather than hold all along: the posture classes (``Task.entered``:
        a squat's hips below the knees) and, where the heels may rise, balance over the balls (standing flat, the
        weight is over the heels too)."""
        rising = any(isinstance(t, FeetTask) and t.rising for t in self.hard)
        return {t.type for t in self.hard if t.entered} | ({"balance"} if rising else set())

    @property
    def tolerance(self) -> float:
        """Reach tolerance [m] of the verdict."""
        return self.reach.tolerance

    @property
    def held_frames(self) -> tuple[str, ...]:
        """Frames the hard tasks hold where they stand."""
        return tuple(f for t in self.hard for f in t.held_frames)

    def task(self, kind: str) -> Task | None:
        """The task of a type, or None."""
        return next((t for t in self.tasks if t.type == kind), None)

    @property
    def targeted(self) -> tuple[Task, ...]:
        """The tasks that take a per-goal target (:attr:`Task.target_key`), in the config's order."""
        return tuple(t for t in self.tasks if t.target_key is not None)

    @property
    def target_size(self) -> int:
        """How many numbers of the programs' parameters the goals' targets fill."""
        return sum(t.target_size for t in self.targeted)

    def target_rows(self, targets: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """(n, target_size) program parameters of n goals' targets (``Goals.targets``), each task's in order.

        Raises OracleError (its key: the target's) for a key no task of the strategy takes, or a value its task refuses.
        """
        takes = {t.target_key for t in self.targeted}
        for key in targets:
            if key not in takes:
                kinds = [c.type for c in TASKS.values() if c.target_key == key]
                add = f"; add a task {{type: {kinds[0]}, ...}} to the strategy" if kinds else ""
                raise OracleError(f"no task of this strategy takes a goal's {key!r}{add}", key=key)
        parts = [np.zeros((n, 0))]
        for t in self.targeted:
            assert t.target_key is not None
            raw = targets.get(t.target_key)
            try:
                values = t.targets(None if raw is None else np.asarray(raw, float), n)
            except ValueError as exc:
                raise OracleError(str(exc), key=t.target_key) from None
            parts.append(values.reshape(n, t.target_size))
        return np.concatenate(parts, axis=1)

    def target_dict(self, row: Any) -> dict[str, Any]:
        """One goal's target parameters (a row of :meth:`target_rows`, numbers or symbols) split by task key."""
        out, k = {}, 0
        for t in self.targeted:
            assert t.target_key is not None
            out[t.target_key] = row[k : k + t.target_size]
            k += t.target_size
        return out


def active_joints(body: Body, joints: Any) -> tuple[str, ...]:
    """The joints named by names or glob patterns, in model order."""
    if not isinstance(joints, list) or not joints or not all(isinstance(j, str) for j in joints):
        raise ModelError(f"expected a non-empty list of joint names or patterns, got {joints!r}", key="joints")
    names = [ROOT, *body.joint_names]
    active: set[str] = set()
    for pattern in joints:
        hits = matching(names, pattern)
        if not hits:
            raise ModelError(f"no joint matches {pattern!r}; joints are: {', '.join(names)}", key="joints")
        active.update(hits)
    return tuple(n for n in names if n in active)


def parse_task(raw: Any, where: str, scope: Scope) -> Task:
    """One task from its mapping; errors name the task, key and value."""
    if not isinstance(raw, dict) or raw.get("type") not in TASKS:
        raise TaskError(where, f"expected a mapping with type one of {sorted(TASKS)}, got {raw!r}")
    cls = TASKS[raw["type"]]
    unknown = set(raw) - cls.allowed_keys()
    if unknown:
        raise TaskError(where, f"unknown keys {sorted(unknown)} for a {cls.type} task; allowed: "
                               f"{sorted(cls.allowed_keys())}")
    return cls.parse(raw, where, scope)


def parse_strategy(body: Body, effector: str, joints: list[str], tasks: list[dict[str, Any]] | None = None) -> Strategy:
    """Validate a strategy against a body; errors name the task, key and value."""
    try:
        body.frame_id(effector)
    except ModelError as exc:
        raise exc.under("effector") from None
    ordered = active_joints(body, joints)
    tasks = [{"type": "reach"}] if tasks is None else tasks
    if not isinstance(tasks, list):
        raise ModelError(f"expected a list of task mappings, got {tasks!r}", key="tasks")
    scope = Scope(body, effector, frozenset(ordered))
    parsed: list[Task] = []
    for i, raw in enumerate(tasks):
        task = parse_task(raw, f"tasks[{i}]", scope)
        if any(t.type == task.type for t in parsed):
            raise TaskError(f"tasks[{i}]", f"a second {task.type} task; give each type once")
        parsed.append(task)
    if not any(isinstance(t, ReachTask) for t in parsed):
        raise TaskError("tasks", "a strategy needs a reach task")
    parsed = [t.resolve(parsed, f"tasks[{i}]") for i, t in enumerate(parsed)]
    return Strategy(effector, ordered, tuple(t for t in parsed if not t.inert))
