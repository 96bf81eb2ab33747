"""Tasks: one class per module, registered here by its config ``type``.

A new task is one new module with a :class:`~oracles.tasks.base.HardTask`
or :class:`~oracles.tasks.base.SoftTask` subclass, plus one line in
``TASKS``. :func:`table` writes the README's task table from the classes.
"""

from __future__ import annotations

from oracles.tasks.balance import BalanceTask
from oracles.tasks.base import Constraint, Cut, HardTask, Numeric, Reference, Row, Scope, SoftTask, Symbolic, Task
from oracles.tasks.comfort import ComfortTask
from oracles.tasks.contacts import Contact, ContactsTask
from oracles.tasks.coupling import CouplingTask
from oracles.tasks.feet import FeetTask
from oracles.tasks.floor import FloorTask
from oracles.tasks.gaze import GazeTask
from oracles.tasks.hang import HangTask
from oracles.tasks.obstacles import ObstaclesTask
from oracles.tasks.orientation import OrientationTask
from oracles.tasks.posture import PostureTask
from oracles.tasks.reach import ReachTask
from oracles.tasks.self_collision import SelfCollisionTask
from oracles.tasks.step import StepTask
from oracles.tasks.tether import TetherTask
from oracles.tasks.within import WithinTask

TASKS: dict[str, type[Task]] = {
    ReachTask.type: ReachTask,
    FeetTask.type: FeetTask,
    ContactsTask.type: ContactsTask,
    BalanceTask.type: BalanceTask,
    StepTask.type: StepTask,
    SelfCollisionTask.type: SelfCollisionTask,
    FloorTask.type: FloorTask,
    ObstaclesTask.type: ObstaclesTask,
    TetherTask.type: TetherTask,
    OrientationTask.type: OrientationTask,
    CouplingTask.type: CouplingTask,
    HangTask.type: HangTask,
    WithinTask.type: WithinTask,
    GazeTask.type: GazeTask,
    PostureTask.type: PostureTask,
    ComfortTask.type: ComfortTask,
}


def table() -> str:
    """The README's task table (Markdown), from the registered classes."""
    lines = ["| task | kind | keys | meaning |", "| --- | --- | --- | --- |"]
    for name, cls in TASKS.items():
        kind = f"soft, priority {cls.default_priority}" if issubclass(cls, SoftTask) else "hard"
        keys = ", ".join(f"`{k}`" for k in sorted(cls.allowed_keys() - {"type"}))
        lines.append(f"| `{name}` | {kind} | {keys or '-'} | {cls.summary} |")
    return "\n".join(lines)


__all__ = [
    "TASKS",
    "BalanceTask",
    "ComfortTask",
    "Constraint",
    "Contact",
    "ContactsTask",
    "CouplingTask",
    "Cut",
    "FeetTask",
    "FloorTask",
    "GazeTask",
    "HangTask",
    "HardTask",
    "Numeric",
    "ObstaclesTask",
    "OrientationTask",
    "PostureTask",
    "ReachTask",
    "Reference",
    "Row",
    "Scope",
    "SelfCollisionTask",
    "SoftTask",
    "StepTask",
    "Symbolic",
    "Task",
    "TetherTask",
    "WithinTask",
    "table",
]
