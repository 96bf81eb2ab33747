"""The abstract task, and the contexts in which engines and the verdict use it.

A task is one thing a strategy asks of a posture: the effector at the goal,
the feet held, the centre of mass over them, the eyes on the goal... Each
task is one class (one module of :mod:`oracles.tasks`) that owns

* its config keys, their validation and error messages (:meth:`Task.parse`);
* whether it is hard (a constraint no other task may violate) or soft (an
  objective, solved lexicographically by ``priority``);
* its CasADi expression, for ``casadi-ik`` (:meth:`HardTask.constraints`,
  :meth:`SoftTask.objective`);
* its numeric residual and Jacobian, for ``dls`` (:meth:`HardTask.rows`,
  :meth:`SoftTask.level`);
* its independent check, for the verdict (:meth:`Task.holds`).

Engines and the verdict compose tasks; they hold no task-specific branch.
"""

from __future__ import annotations

import fnmatch
import functools
import math
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body
from oracles.bodies.kinematics import SymbolicKinematics
from oracles.errors import TaskError

BUFFER = 0.005  # [m] dls: distance from an inequality's bound at which its row becomes active
INSIDE = 1e-4  # [m] dls: how far inside its bound a violated row is pushed


class Constraint(NamedTuple):
    """Rows ``lower <= expr <= upper`` of a nonlinear program (bounds apply to every row).

    ``frozen``: symbols of ``expr`` and the expressions they stand for, held constant when differentiating
    (the nearest points' parameters of a distance, whose derivative vanishes where they are optimal:
    the envelope theorem); the batched engine substitutes them after differentiating, which keeps the
    Jacobian a tenth of the size of the closed form's own.
    """

    expr: ca.SX
    lower: float
    upper: float
    frozen: tuple[tuple[ca.SX, ca.SX], ...] = ()


class Row(NamedTuple):
    """A task level of damped least squares: Jacobian (m, n_x) and error (m,) to close."""

    jacobian: np.ndarray
    error: np.ndarray


class Cut(NamedTuple):
    """One inequality of a lazy task linearised at a posture: ``gap + jacobian @ dx >= need``.

    ``gap`` [m] is the distance now (coal's closed form, ours), ``jacobian``
    (n_x,) its gradient over the active coordinates, ``need`` [m] the least
    distance the task allows.
    """

    jacobian: np.ndarray
    gap: float
    need: float


def rows_of_cuts(cuts: Sequence[Cut]) -> list[Row]:
    """The ``dls`` rows of a lazy task: each cut within ``BUFFER`` of its bound, pushed ``INSIDE`` it."""
    return [Row(c.jacobian[None], np.array([max(0.0, c.need + INSIDE - c.gap)])) for c in cuts
            if c.gap < c.need + BUFFER]


@dataclass(frozen=True)
class Scope:
    """What a task may look at while it is parsed: the body, the strategy's effector and its active joints."""

    body: Body
    effector: str
    active: frozenset[str]

    def moves(self, frame: str) -> bool:
        """Whether any active joint lies between the world and a frame."""
        return moved(self.body.model, int(self.body.model.frames[self.body.frame_id(frame)].parentJoint), self.active)


@dataclass(frozen=True)
class Reference:
    """The body at its reference posture, for tasks that hold something where it stands."""

    body: Body
    data: pin.Data  # frames placed at body.q_ref

    def placement(self, frame: str) -> pin.SE3:
        return self.data.oMf[self.body.frame_id(frame)].copy()


@dataclass(frozen=True)
class Symbolic:
    """The symbols of ``casadi-ik``'s programs.

    Attributes:
        kin: Kinematics of the posture q(x).
        x: Active coordinates (n_x,).
        goal: The goal [m] (3,), a parameter of the program.
        x_ref: Reference values of x.
        span: Range (upper - lower) of each coordinate of x.
        names: Name of each coordinate of x (joint names; ``root_x`` ... ``root_yaw``).
        lower: Lower bound of each coordinate of x.
        start: The character's current posture as x (n_x,), a parameter (continuity).
        start_weight: Weight of the displacement from ``start``, a parameter (0 without one).
        targets: Each goal's target, by the key of the task that declares it (:attr:`Task.target_key`), as
            parameters of the programs (one compiled program serves every goal's target).
        numbers, prefixes: The body's numbers as the programs take them (see :meth:`number`).
    """

    kin: SymbolicKinematics
    x: ca.SX
    goal: ca.SX
    x_ref: np.ndarray | ca.SX
    span: np.ndarray | ca.SX
    names: tuple[str, ...] = ()
    lower: np.ndarray | ca.SX | None = None
    start: ca.SX | None = None
    start_weight: ca.SX | None = None
    targets: Mapping[str, ca.SX] = field(default_factory=dict)
    # the body's numbers as expressions (oracles.ik.parameters.BodyParameters), each task's under its prefix (by
    # the task's id); None: every number a constant
    numbers: Any = None
    prefixes: Mapping[int, str] = field(default_factory=dict)

    def number(self, task: object, name: str, value: np.ndarray | float) -> ca.SX:
        """A number a task took from the body, as its expressions take it: ``value`` itself, a constant, or, when the
        programs are lifted, the body's parameter of that name (:meth:`Task.numbers`)."""
        if self.numbers is None or id(task) not in self.prefixes:
            a = np.asarray(value, float)
            return ca.SX(a.reshape(-1, 1) if a.ndim <= 1 else a)
        return self.numbers.sx(self.prefixes[id(task)] + name)


@dataclass
class Numeric:
    """A posture evaluated by Pinocchio, for ``dls`` and for the verdict.

    ``data`` holds frame placements at ``q``. For ``dls`` it also holds joint
    Jacobians, and ``jacobian(frame_id)`` gives a frame's (6, n_x) Jacobian
    (world-aligned, columns of the active coordinates); ``x_of_joints`` maps
    the joint columns of x to their configuration indices.
    """

    model: pin.Model
    data: pin.Data
    q: np.ndarray
    goal: np.ndarray
    jacobian: Callable[[int], np.ndarray] | None = None
    # a joint's (6, n_x) Jacobian at its origin, world-aligned
    joint_jacobian: Callable[[int], np.ndarray] | None = None
    columns: np.ndarray | None = None  # velocity indices of x's coordinates
    joint_columns: np.ndarray | None = None  # positions within x of the joint coordinates
    joint_q: np.ndarray | None = None  # configuration indices of those joints
    x_ref: np.ndarray | None = None
    max_reach_step: float = np.inf  # [m] largest reach error pursued per iteration
    x: np.ndarray | None = None  # the active coordinates of q
    span: np.ndarray | None = None
    start: np.ndarray | None = None  # the character's current posture as x, when a query gives one
    start_weight: float = 0.0
    # the goal's targets by key (Task.target_key), as parameters
    targets: Mapping[str, np.ndarray] = field(default_factory=dict)

    def frame(self, frame_id: int) -> pin.SE3:
        return self.data.oMf[frame_id]

    def point_jacobian(self, joint: int, point: np.ndarray) -> np.ndarray:
        """(3, n_x) Jacobian of a world point [m] fixed to a joint."""
        assert self.joint_jacobian is not None
        jac = self.joint_jacobian(joint)
        r = point - self.data.oMi[joint].translation
        return jac[:3] - pin.skew(r) @ jac[3:]  # type: ignore[no-any-return]


def world_point(sym: Symbolic, joint: int, local: np.ndarray | ca.SX) -> ca.SX:
    """A point fixed to a joint (local coordinates [m], numbers or an expression) in the world, as an expression."""
    rot, pos = sym.kin.placements[joint]
    return rot @ (local if isinstance(local, ca.SX) else ca.SX(np.asarray(local, float).reshape(3, 1))) + pos


def active_ancestors(model: pin.Model, active: frozenset[str]) -> list[int]:
    """Each joint's active ancestors, itself included, as the bits of an integer (bit j: joint j). An active joint
    moves joint a relative to joint b when it lies on the tree path between them: the ancestors one has and the other
    has not, ``masks[a] ^ masks[b]``."""
    masks = [0] * model.njoints
    for j in range(1, model.njoints):
        masks[j] = masks[int(model.parents[j])] | ((1 << j) if str(model.names[j]) in active else 0)
    return masks


def relative_motion(model: pin.Model, a: int, b: int, active: frozenset[str]) -> bool:
    """Whether an active joint moves joint a relative to joint b (one lies on the tree path between them)."""
    masks = active_ancestors(model, active)
    return bool(masks[a] ^ masks[b])


def moved(model: pin.Model, joint: int, active: frozenset[str]) -> bool:
    """Whether an active joint moves a joint in the world."""
    j = joint
    while j > 0:
        if str(model.names[j]) in active:
            return True
        j = int(model.parents[j])
    return False


# -- parsing helpers, shared by every task's parse ---------------------------

def number(value: Any, where: str, lo: float, hi: float) -> float:
    """A number in [lo, hi], or a TaskError naming the key."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise TaskError(where, f"expected a number in [{lo}, {hi}], got {value!r}")
    return float(value)


def frames(scope: Scope, value: Any, where: str) -> tuple[str, ...]:
    """A list of the body's frame names, or an error naming the key."""
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise TaskError(where, f"expected a list of frame names, got {value!r}")
    for name in value:
        if not scope.body.model.existFrame(name):
            known = sorted({str(f.name) for f in scope.body.model.frames} - {"universe"})
            raise TaskError(where, f"{scope.body.source}: no frame {name!r}; frames are: {', '.join(known)}")
    return tuple(value)


def frame(scope: Scope, value: Any, where: str) -> str:
    """One frame name of the body."""
    if not isinstance(value, str):
        raise TaskError(where, f"expected a frame name, got {value!r}")
    return frames(scope, [value], where)[0]


def matching(names: Sequence[str], pattern: str) -> list[str]:
    """The names that match a glob pattern, case-sensitively (as :func:`fnmatch.fnmatchcase`)."""
    # A plain name is looked up, a pattern compiled once (a population member's four strategies match ~400 names and
    # patterns, which name by name took 1.4 ms, and compiling each pattern again 1 ms).
    if not any(c in pattern for c in "*?["):
        return [n for n in names if n == pattern]
    match = _glob(pattern)
    return [n for n in names if match(n)]


@functools.lru_cache(maxsize=1024)
def _glob(pattern: str) -> Callable[[str], Any]:
    return re.compile(fnmatch.translate(pattern)).match


# -- the tasks ---------------------------------------------------------------

class Task(ABC):
    """One requirement on a posture (see the module docstring).

    Class attributes:
        type: The config's ``type`` that selects this class.
        keys: Config keys besides ``type`` (and ``priority`` for soft tasks).
        hard: Whether it is a constraint (True) or an objective (False).
        summary: One line for the README's task table.
    """

    type: ClassVar[str]
    keys: ClassVar[frozenset[str]] = frozenset()
    hard: ClassVar[bool]
    summary: ClassVar[str]

    #: Frames held where they stand at the reference posture (anchors of the reach pre-filter).
    held_frames: tuple[str, ...] = ()
    #: A posture class a motion may start outside of and enter by its end (a squat's hips below the knees), not a
    #: physical limit that every frame holds (:meth:`oracles.ik.oracle.IKOracle.transit`).
    entered: ClassVar[bool] = False
    #: Frames whose reference ground positions span a support polygon.
    support: tuple[str, ...] = ()
    #: A per-goal target the task takes (``Goals.targets[target_key]``; None: none) and how many numbers of the
    #: programs' parameters it fills per goal (:meth:`targets`, read back as ``Symbolic.targets[target_key]``
    #: and ``Numeric.targets[target_key]``). A new kind of goal is a task with these, and nothing else.
    target_key: ClassVar[str | None] = None
    target_size: ClassVar[int] = 0

    @property
    def inert(self) -> bool:
        """Whether the task, as configured, asks nothing (e.g. a zero weight); the strategy drops it."""
        return False

    @classmethod
    def allowed_keys(cls) -> frozenset[str]:
        return cls.keys | {"type"}

    @classmethod
    @abstractmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> Task:
        """Build the task from its config mapping (keys already checked); errors name ``where``."""

    def resolve(self, tasks: Sequence[Task], where: str) -> Task:
        """Settle what depends on the strategy's other tasks (e.g. a support polygon); default: nothing."""
        return self

    def targets(self, raw: np.ndarray | None, n: int) -> np.ndarray:
        """(n, target_size) parameters of n goals from their raw targets (None: the goals carry none, the task's
        configured default applies); raises ValueError saying what was expected."""
        return np.zeros((n, self.target_size))

    def bind(self, reference: Reference) -> None:  # noqa: B027 - most tasks need no reference
        """Record what the task holds at the reference posture (called once per problem)."""

    #: Whether every number the task's expressions take from the body (and its reference posture) comes through
    #: :meth:`Symbolic.number` under a name of :meth:`numbers`, or through the kinematics: then one program serves
    #: every body of one shape (:mod:`oracles.ik.parameters`).
    parametric: ClassVar[bool] = False

    def numbers(self) -> dict[str, np.ndarray]:
        """The body's numbers the task's expressions take (after :meth:`bind`), by the names it asks
        :meth:`Symbolic.number` for; default none."""
        return {}

    @abstractmethod
    def holds(self, num: Numeric) -> bool:
        """The independent check of the verdict, on Pinocchio's evaluation of a posture."""

    def describe(self) -> dict[str, Any]:
        """What ``reach model`` prints of the task (JSON-compatible); its ``text``, when given, is the line it
        prints."""
        return {"type": self.type, "hard": self.hard}

    def warnings(self) -> list[str]:
        """What the task, bound to the reference posture, finds suspect there (one sentence each; see
        ``IKOracle.diagnose``)."""
        return []


class HardTask(Task):
    """A constraint: no soft task may trade it away.

    Class attributes:
        lazy: Many rows that rarely bind (collisions between any two
            segments): the task gives no rows to ``casadi-ik``'s programs
            (:meth:`constraints` is empty) but linearises its near and broken
            rows at a posture (:meth:`cuts`); the engine solves without them
            and, when that posture breaks the task, again with the cuts, as
            sequential convex optimisation does (Schulman et al., "Motion
            planning with sequential convex optimization and convex collision
            checking", IJRR 2014). Exact closed-form collision rows made each
            program's second derivatives 8 MB of C (46 s to compile per stage)
            or 17 ms per evaluation interpreted.
    """

    hard = True
    lazy: ClassVar[bool] = False

    @abstractmethod
    def constraints(self, sym: Symbolic) -> list[Constraint]:
        """The task as constraint rows of ``casadi-ik``'s programs (none for a lazy task)."""

    @abstractmethod
    def rows(self, num: Numeric) -> list[Row]:
        """The task's rows of damped least squares now (inequalities only when active)."""

    def cuts(self, num: Numeric, within: float) -> list[Cut]:
        """A lazy task's inequalities within ``within`` [m] of their bound at ``num.q``, linearised there."""
        return []

    def screened(self, sym: Symbolic) -> list[Constraint]:
        """A lazy task's rows that :meth:`constraints` leaves out, as expressions, for an engine that evaluates them
        all and keeps the near ones (the batched engine, :mod:`oracles.ik.batch`); none by default (the engine then
        leaves the task to its verdict and polish)."""
        return []

    def keep_out(self) -> list[np.ndarray]:
        """Capsules (a, b [m], radius [m]; world frame) the task keeps every reachable point out of."""
        return []

    def limit_slacks(self, q: np.ndarray) -> dict[str, float]:
        """How far [rad or m] configuration q keeps from each joint limit this task sets, by the limit's name (none:
        empty)."""
        return {}


class SoftTask(Task):
    """An objective, minimised lexicographically below the tasks of higher priority.

    Class attributes:
        default_priority: Priority when the config gives none; ties break on it.
        slack: How much a later stage may degrade this task's optimum.
    """

    hard = False
    default_priority: ClassVar[int]
    slack: ClassVar[float]
    priority: float

    @classmethod
    def allowed_keys(cls) -> frozenset[str]:
        return cls.keys | {"type", "priority"}

    @classmethod
    def priority_of(cls, raw: dict[str, Any], where: str) -> float:
        """The config's ``priority`` (lower first), or the class's default."""
        return number(raw.get("priority", cls.default_priority), f"{where}.priority", 0, 100)

    @abstractmethod
    def objective(self, sym: Symbolic) -> ca.SX:
        """The scalar objective of this task's stage."""

    def measure(self, sym: Symbolic) -> ca.SX:
        """The value a stage's optimum is: what :meth:`held_bounds` and :meth:`attained` judge.

        The objective by default; a task whose objective also steers the
        solver (a term that only picks among equally good postures) measures
        without it.
        """
        return self.objective(sym)

    def held(self, sym: Symbolic) -> ca.SX:
        """What later stages constrain to keep this task's optimum (default: the objective)."""
        return self.objective(sym)

    def held_bounds(self, optimum: float) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of :meth:`held` in later stages, given this stage's optimum."""
        return np.array([-np.inf]), np.array([max(optimum, self.free) + self.slack])

    @property
    def free(self) -> float:
        """The objective's level at or below which the task asks nothing more: later stages may spend up to it (-inf:
        every bit of the optimum is kept). The batched engine weighs only the excess over it
        (:mod:`oracles.ik.batch`)."""
        return -math.inf

    def attained(self, optimum: float) -> bool:
        """Whether lower stages can still matter after this optimum (default: yes)."""
        return True

    @abstractmethod
    def level(self, num: Numeric) -> Row | None:
        """The task's level of damped least squares, or None when it asks nothing."""

    def holds(self, num: Numeric) -> bool:
        """Soft tasks below reach never decide a verdict."""
        return True


def perpendicular_basis(axis: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows spanning the plane normal to a unit axis."""
    b1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(axis, b1)])
