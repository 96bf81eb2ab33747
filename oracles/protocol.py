"""The oracle protocol: everything ``reach`` may ask of an oracle.

An oracle answers, for a batch of goals (:class:`Goals`: points, each
goal's task targets such as an orientation, the current posture, warm
starts), whether each is inside the volume (reachable), how far from it the
best attempt ended (the residual, metres), and, for oracles that find one,
the posture that reaches it (:class:`Oracle`). The builder never shows an
oracle the tree; it only sends batches of goals with optional warm-start
postures (seeds). There is one ``evaluate``: a new kind of goal is a task
that declares its per-goal target (:mod:`oracles.tasks.base`), not a new
method here.

Oracles may also offer optional capabilities, each a protocol of its own;
``reach`` checks for them with ``isinstance`` and does without when absent:

* :class:`Specified`: the spec that rebuilds the oracle in another process;
* :class:`ModelHashed`: a hash of the body model, stored with trees;
* :class:`EffectorPositions`: where postures put the effector (the
  selector's nearest-posture index);
* :class:`ReachBound`: a ball that holds every reachable point (``box: auto``);
* :class:`Turning`: the axis a volume turns freely about (the audit's twins);
* :class:`QuarterTurning`: a vertical axis a quarter turn about which maps the
  volume onto itself, and postures turned about it (a build's twin vertices);
* :class:`Stepping`: where a step's foot lands at a posture (an answer's ``step``);
* :class:`Shaped`: the body's capsules at a posture, to draw it (``reach view``);
* :class:`Furnished`: the static boxes around the body (a seat, a table);
* :class:`KeepOut`: capsules no reachable point lies in (the static parts of
  the body), so that the builder never labels a cell that meets them inner;
* :class:`Tunable`: a variant set up for a purpose, ``"refine"`` (the
  selector's quick solve at the exact goal, secondary tasks on, within a
  budget: see :class:`Verdicts`' ``spent``), ``"referee"`` (the audit's thorough solve) or ``"index"``
  (the reachability index's quick verdicts from neighbouring postures);
* :class:`Described`: what the oracle checks, for ``reach model``;
* :class:`Preparable`: build now what the first evaluate would build;
* :class:`Mirrorable`: the map of postures to their mirror images about
  y = 0, for deriving left-side trees from right-side ones;
* :class:`Limited`: the joint limits a posture comes near, so that the
  selector may hand a goal over to the next strategy rather than answer
  with a body bent to its limits;
* :class:`Preferring`: how much the lower tasks like a posture, so that the
  selector may also start a refinement from the best-liked stored posture
  near the goal;
* :class:`Bounded`: the range of each posture coordinate, so that a
  query's ``from`` outside the body's joint ranges is refused;
* :class:`Moving`: postures between two postures on the body's own
  configuration space, what a posture breaks (limits, collisions, feet,
  balance), and the posture nearest one that holds every hard task, so that
  :mod:`reach.motion.planner` plans a reach motion without seeing the model;
* :class:`Oriented`: which orientations (an approach direction, a full
  rotation) its goals may carry (``Goals.targets["orientation"]``), for
  queries' ``orientation`` and the reachability index;
* :class:`Articulated`: the body's skeleton (its joints grouped into bones)
  and each bone's world transform at postures, for animation files (BVH,
  glTF);
* :class:`Sharing`, :class:`Joining`, :class:`Sibling`: a population's members, one program serving every body
  of one shape, their calls run joined, a member's strategies built on one loaded body.

``reach`` asks nothing else: not an oracle's parameters, registry names or
internals, so a third-party oracle registered through the ``reach.oracles``
entry point works everywhere a built-in one does.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple, Protocol, cast, runtime_checkable

import numpy as np

from oracles import registry
from oracles.errors import OracleError

# The posture coordinates of a continuous joint (Pinocchio's unbounded revolute, stored as (cos, sin)) are named
# NAME.cos and NAME.sin in ``posture_names``; answers, motions, files and configs give the one angle NAME instead.
COS, SIN = ".cos", ".sin"


class Verdicts(NamedTuple):
    """Per-point answers of an oracle.

    Attributes:
        reachable: (N,) bool.
        residual: (N,) float, distance [m] between the goal and what was reached
            (0 for analytic oracles inside the volume).
        posture: (N, nq) float configurations, or None for oracles without
            postures. Rows of unreachable points hold the best attempt.
        spent: (N,) float, the work [s] each goal spent of a budgeted call's (``Search.max_seconds``), all of it
            where the budget ran out; None from oracles whose budget is the clock. A budget of work, not time, gives
            the same request the same answer on any machine (see ``oracles.ik.budget.Meter``).
    """

    reachable: np.ndarray
    residual: np.ndarray
    posture: np.ndarray | None
    spent: np.ndarray | None = None

    @staticmethod
    def concatenate(parts: list[Verdicts]) -> Verdicts:
        """Join the verdicts of consecutive chunks."""
        if not parts:
            return Verdicts(np.zeros(0, bool), np.zeros(0), None)
        posture = None
        if parts[0].posture is not None:
            posture = np.concatenate([p.posture for p in parts if p.posture is not None])
        return Verdicts(
            np.concatenate([p.reachable for p in parts]),
            np.concatenate([p.residual for p in parts]),
            posture,
            None if any(p.spent is None for p in parts) else np.concatenate([p.spent for p in parts]),  # type: ignore[misc]
        )


@dataclass(frozen=True)
class Goals:
    """A batch of goals: everything one :meth:`Oracle.evaluate` is asked.

    Attributes:
        points: (N, dim) goal points [m], world frame.
        targets: Each goal's targets for the strategy's tasks, by the key a task declares
            (:attr:`oracles.tasks.base.Task.target_key`): ``orientation``, (N, 3) world directions of the
            effector's approach axis or (N, 3, 3) effector rotations. A goal kind is a task and its key.
        current: The character's posture (nq,) when there is one: the warm start of every goal, with a
            small cost on displacement from it (continuity between answers).
        seeds: Warm starts, (N, nq) or (N, k, nq) tried in order (a NaN row: none); the first stands for
            the neighbour's posture in a build. Without seeds, ``current`` seeds every goal.
    """

    points: np.ndarray
    targets: Mapping[str, np.ndarray] = field(default_factory=dict)
    current: np.ndarray | None = None
    seeds: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @staticmethod
    def of(goals: Goals | np.ndarray, dim: int = 3) -> Goals:
        """Goals as given, or a plain (N, dim) array of points as goals with nothing else; points checked."""
        if isinstance(goals, Goals):
            points = check_points(goals.points, dim)  # the same array when it is already a float (N, dim) one
            return goals if points is goals.points else Goals(points, goals.targets, goals.current, goals.seeds)
        return Goals(check_points(goals, dim))

    @staticmethod
    def points_of(goals: Goals | np.ndarray, dim: int) -> np.ndarray:
        """The points of goals for an oracle that holds no target (an analytic volume): (N, dim), checked; raises
        OracleError naming a target's key when the goals carry one."""
        g = Goals.of(goals, dim)
        if g.targets:
            key = next(iter(g.targets))
            raise OracleError(f"this oracle holds no goal's {key!r}", key=key)
        return g.points

    def take(self, index: slice | np.ndarray) -> Goals:
        """The goals at ``index`` (a slice, indices or a mask), each with its own targets and seeds."""
        return Goals(self.points[index], {k: np.asarray(v)[index] for k, v in self.targets.items()}, self.current,
                     None if self.seeds is None else self.seeds[index])


@runtime_checkable
class Oracle(Protocol):
    """Anything that classifies points.

    Attributes:
        dim: Dimension of the points (2 or 3).
        posture_names: Names of the posture coordinates (empty when the oracle
            returns no postures; a continuous joint's pair: ``NAME.cos``, ``NAME.sin``).
    """

    dim: int
    posture_names: tuple[str, ...]

    def evaluate(self, goals: Goals) -> Verdicts:
        """Classify goals: their points, held to their targets, from their seeds or the current posture.

        An oracle that cannot use a field ignores it, except targets: a goal
        target that no task of the oracle takes is an OracleError naming its
        key. (The built-in oracles also take a plain (N, dim) array of points.)

        Returns:
            The verdicts, one per goal, in order.
        """
        ...


Purpose = Literal["refine", "referee", "index"]
PURPOSES: tuple[str, ...] = ("refine", "referee", "index")


def check_purpose(purpose: str) -> None:
    if purpose not in PURPOSES:
        raise OracleError(f"unknown oracle purpose {purpose!r}; expected one of {', '.join(PURPOSES)}", key="purpose")


@runtime_checkable
class Specified(Protocol):
    """An oracle that knows the spec rebuilding it (workers receive specs, never oracles)."""

    @property
    def spec(self) -> OracleSpec: ...


@runtime_checkable
class ModelHashed(Protocol):
    """An oracle on a body model; the hash identifies the model in stored trees."""

    @property
    def model_hash(self) -> str: ...


@runtime_checkable
class ShapeHashed(Protocol):
    """An oracle on a body model whose shape (links, joints, frames and placement, the joint ranges aside) a hash
    names: a strategy may inherit the postures of another on the same shape, each checked against its own ranges."""

    @property
    def shape_hash(self) -> str: ...


@runtime_checkable
class Rebuilt(Protocol):
    """An oracle that can rebuild itself with the body model a stored tree was built with, where this version of its
    spec builds another (a human from before ANSUR II bodies)."""

    def as_built(self, model_hash: str) -> tuple[Oracle, str] | None:
        """The oracle on the model of that hash and a note of what changed, or None when it cannot be built."""


@runtime_checkable
class EffectorPositions(Protocol):
    """An oracle whose postures can be mapped to effector positions."""

    def effector_positions(self, postures: np.ndarray) -> np.ndarray:
        """(N, dim) effector positions [m] of (N, nq) postures."""
        ...


@runtime_checkable
class Landmarked(Protocol):
    """An oracle on a body whose frames can be named: targets given on a person's own body (a point ahead of the
    acromion, above the seat) are placed from them."""

    def landmarks(self, names: list[str] | None) -> dict[str, np.ndarray]:
        """World positions [m] (3,) of the named frames in the body's reference posture (None: every frame of the
        body); an unknown name raises an error listing the frames."""
        ...


class Ball(NamedTuple):
    """A ball: ``centre`` [m] (dim,) and ``radius`` [m]."""

    centre: np.ndarray
    radius: float


@runtime_checkable
class ReachBound(Protocol):
    """An oracle that bounds its volume by a ball."""

    def reach_bound(self) -> Ball | tuple[np.ndarray, float] | None:
        """A ball (centre [m], radius [m]) holding every reachable point, or None when unbounded."""
        ...


@runtime_checkable
class Turning(Protocol):
    """An oracle whose volume turns freely about an axis (a robot's base joint of a full turn or more)."""

    def free_turn(self) -> tuple[np.ndarray, np.ndarray] | None:
        """A point [m] and a unit axis (world frame) about which the volume is symmetric: the strategy's first active
        joint turns about it through a full turn or more, every other active joint lies after it, and no task holds
        anything fixed in the world that the turn would move (an obstacle, a belt's anchor); else None."""
        ...


@runtime_checkable
class QuarterTurning(Protocol):
    """An oracle whose volume a quarter turn about a vertical axis maps onto itself, and that turns postures about it
    (a robot's base joint of a full turn, with a floor or boxes that look the same turned): a build solves one vertex
    of each four twins and turns its posture for the others."""

    def quarter_turn(self) -> tuple[np.ndarray, np.ndarray] | None:
        """A point [m] and the vertical unit axis through it about which a quarter turn maps the volume onto itself:
        the strategy's first active joint turns a full turn about it, every other active joint lies after it, and
        every box the world holds fixed (an obstacle, a seat) is the same turned; else None."""
        ...

    def turned(self, postures: np.ndarray, quarters: np.ndarray) -> np.ndarray:
        """Postures (N, nq) turned by quarters (N,) x 90 deg about the axis, anticlockwise seen from above (+z)."""
        ...


@runtime_checkable
class Transiting(Protocol):
    """An oracle whose motions may start from a posture that breaks some of its strategy's tasks: a tiptoe's or a
    squat's balance over the balls of the feet, a squat's hips below the knees, from standing."""

    def transit(self, broken: list[str]) -> Any | None:
        """The oracle that a motion's frames hold, from a start breaking ``broken`` (task types) to this strategy's
        end posture: the strategy without those tasks, balance over the feet's whole soles where the heels may rise
        (the end posture holds every task); None when the start breaks anything else (a segment through another or
        the floor, a contact, a joint's range): such a start is refused."""
        ...


@runtime_checkable
class Settling(Protocol):
    """An oracle that moves a stored posture to a nearby goal without a search (a motion's end posture)."""

    def settle(self, posture: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """A posture near ``posture`` (nq,) that reaches ``goal`` [m] (3,) and holds every hard task, by the verdict's
        own check, found by a few local steps from it; None when they find none (the caller then solves)."""
        ...


@runtime_checkable
class Stepping(Protocol):
    """An oracle whose strategy may take a step: where the stepping foot lands at a posture."""

    def landing(self, posture: np.ndarray) -> dict[str, Any] | None:
        """The stepping foot's frame and where a posture sets it down, ``{"foot", "position": [x, y, z] [m], "yaw":
        [rad] about +z from where it stood}``; None for a strategy without a step."""
        ...

    def swing(self, q0: np.ndarray, q1: np.ndarray, count: int) -> np.ndarray | None:
        """``count`` + 1 postures from q0 (both feet down) to the stepping foot set down where q1 puts it: the weight
        shifted over the stance foot, the foot lifted, carried and set down (a motion's step); None when no such
        frames are found."""
        ...


@runtime_checkable
class Probing(Protocol):
    """An oracle that can estimate its volume's bounds by reaching far in a few directions (``box: auto``)."""

    def reach_extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Lowest and highest effector positions [m] (3,) found reaching far: an estimate, not a bound; None if none
        was found."""
        ...


@runtime_checkable
class Floored(Protocol):
    """An oracle whose reachable points lie on or above a height (a floor the effector cannot pass)."""

    def lowest(self) -> float | None:
        """The least world z [m] of any reachable point, or None when nothing bounds it below."""
        ...


@runtime_checkable
class Shaped(Protocol):
    """An oracle whose body can be drawn."""

    posture_names: tuple[str, ...]

    def reference_posture(self) -> np.ndarray:
        """The body's reference posture (nq,), in the order of ``posture_names``."""
        ...

    def shape(self, posture: np.ndarray) -> tuple[list[str], np.ndarray]:
        """Names and capsules (K, 7: end points a, b [m], radius [m]; world frame) of the body at a posture (nq,)."""
        ...


@runtime_checkable
class Furnished(Protocol):
    """An oracle whose body comes with static boxes (a seated body's seat) or whose strategy keeps out of some (a
    table)."""

    def furniture(self) -> tuple[list[str], np.ndarray]:
        """Names and boxes (K, 10: centre [m], half sizes [m], orientation quaternion w, x, y, z; world frame)."""
        ...


@runtime_checkable
class KeepOut(Protocol):
    """An oracle that knows regions its volume never enters."""

    def keep_out(self) -> np.ndarray:
        """Capsules (K, 7): end points a, b [m] and radius [m], world frame, that hold no reachable point."""
        ...


@runtime_checkable
class Verifying(Protocol):
    """An oracle that can check a posture found elsewhere (by another strategy's oracle on the same body)."""

    def verify(self, points: np.ndarray, postures: np.ndarray) -> np.ndarray:
        """Whether each posture (N, nq) puts the effector on its point (N, 3) with every hard task of this oracle
        held."""
        ...


@runtime_checkable
class Sharing(Protocol):
    """An oracle whose programs can serve another body of the same shape (a population's members): built once, used
    by every member (its spec's ``body_parameters``)."""

    def share_programs(self, other: Any) -> bool:
        """Take ``other``'s programs when they serve this body too; whether it did."""
        ...


@runtime_checkable
class Sibling(Protocol):
    """An oracle that builds another strategy's oracle on its own body without loading the body again (a population's
    member asked with each of its strategies: loading a generated human costs about 9 ms)."""

    def sibling(self, spec: OracleSpec) -> Oracle | None:
        """The oracle of ``spec`` on this oracle's body, or None when ``spec`` names another body or engine."""
        ...


def create_siblings(specs: Sequence[OracleSpec]) -> list[Oracle]:
    """Each spec's oracle (:meth:`OracleSpec.create`); a spec of the first's body is built by the first's
    :meth:`Sibling.sibling` when it can, the same oracle without loading the body again."""
    out: list[Oracle] = []
    for spec in specs:
        first = out[0] if out else None
        made = first.sibling(spec) if isinstance(first, Sibling) else None
        out.append(made if made is not None else spec.create())
    return out


@runtime_checkable
class Joining(Protocol):
    """An oracle whose calls can run joined with other oracles' calls of the same programs (a population's members,
    each its own body with one program's parameters): a call as steps, and the steps of several run together."""

    def evaluate_steps(self, goals: Goals | np.ndarray) -> Generator[Any, Any, Verdicts]:
        """:meth:`Oracle.evaluate` as a generator: it yields the work it needs done, takes each result back, and
        returns the verdicts."""
        ...

    def run_joined(self, requests: list[Any]) -> list[Any]:
        """The results of work that several oracles' :meth:`evaluate_steps` yielded, in order."""
        ...


def evaluate_together(oracles: Sequence[Oracle], goals: Sequence[Goals | np.ndarray]) -> list[Verdicts]:
    """Each oracle's verdicts on its goals, as its ``evaluate`` gives them; where every oracle is :class:`Joining`,
    their work is run joined (one batch for calls of one program), each call's steps in turn."""
    if len(oracles) < 2 or not all(isinstance(o, Joining) for o in oracles):
        return [o.evaluate(Goals.of(g)) for o, g in zip(oracles, goals, strict=True)]
    joining = cast(Sequence[Joining], oracles)
    steps = [o.evaluate_steps(g) for o, g in zip(joining, goals, strict=True)]
    out: list[Verdicts | None] = [None] * len(steps)
    pending: dict[int, Any] = {}

    def advance(k: int, result: Any) -> None:
        try:
            pending[k] = next(steps[k]) if result is None else steps[k].send(result)
        except StopIteration as done:
            out[k] = done.value

    for k in range(len(steps)):
        advance(k, None)
    while pending:
        asked, pending = pending, {}
        for k, result in zip(asked, joining[0].run_joined(list(asked.values())), strict=True):
            advance(k, result)
    return [v for v in out if v is not None]


@runtime_checkable
class Tunable(Protocol):
    """An oracle that can be set up for a purpose.

    ``variant("refine", budget=s)``: fast, secondary tasks on, at most
    ``budget`` seconds per ``evaluate``. ``variant("referee", restarts=n)``:
    thorough, every start tried, at least ``n`` random restarts.
    ``variant("index")``: a verdict only, from the hints and the reference
    (no random restart), a hint at the goal solved alone. Variants are
    :class:`Specified` when their oracle is.
    """

    def variant(self, purpose: Purpose, *, budget: float | None = None, restarts: int = 6) -> Oracle: ...


@runtime_checkable
class Described(Protocol):
    """An oracle that can say what it checks (``reach model CONFIG`` prints it)."""

    def describe(self) -> dict[str, Any]:
        """A JSON-compatible description: for body oracles the effector, joints and tasks with their pairs."""
        ...


@runtime_checkable
class Diagnosed(Protocol):
    """An oracle that can say, before solving anything, what in its spec will likely give a wrong or empty volume."""

    def diagnose(self) -> list[str]:
        """One sentence per finding, naming the joint, pair or task and what to give instead (empty: nothing found).

        For a body: reference joints clipped into their ranges, hard tasks the
        reference posture breaks, collision pairs overlapping at the reference.
        """
        ...


@runtime_checkable
class Preparable(Protocol):
    """An oracle that builds heavy structures (solvers, compiled code) on its first evaluate."""

    def prepare(self) -> None:
        """Build them now (a server does at load), so that no request pays for them."""
        ...


@runtime_checkable
class Mirrorable(Protocol):
    """An oracle whose body may be mirror-symmetric about y = 0."""

    def mirror(self) -> Callable[[np.ndarray], np.ndarray]:
        """The map of (..., nq) postures to their mirror images; raises ModelError when the body is not symmetric."""
        ...


@runtime_checkable
class Limited(Protocol):
    """An oracle whose postures have joint limits (ranges, and limits coupled between joints)."""

    def limits_near(self, posture: np.ndarray, margin: float) -> list[str]:
        """The limits (active joints' range ends, coupled limits) the posture (nq,) comes within ``margin``
        [rad or m] of, by name; not those the reference posture rests at."""
        ...


@runtime_checkable
class Preferring(Protocol):
    """An oracle that ranks reaching postures by its lower tasks (and tries every seed a goal gives)."""

    def preference(self, posture: np.ndarray, goal: np.ndarray) -> float:
        """How much the lower tasks dislike a posture (nq,) for a goal [m] (lower is better)."""
        ...


@runtime_checkable
class Bounded(Protocol):
    """An oracle whose posture coordinates have ranges."""

    def posture_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds (nq,) of each posture coordinate [rad or m], -inf/inf where unbounded
        (a floating base's position, a continuous joint)."""
        ...


@runtime_checkable
class Moving(Protocol):
    """An oracle whose body moves between postures (:mod:`reach.motion.planner`)."""

    def interpolate(self, q0: np.ndarray, q1: np.ndarray, s: np.ndarray, exact: bool = True) -> np.ndarray:
        """Postures (T, nq) at fractions ``s`` (T,) in [0, 1] of the way from ``q0`` to ``q1`` (nq,), on the
        configuration space (a floating base on SE(3)), not by straight lines in the posture's numbers.
        ``exact=False``: only the effector's and the root's paths are wanted (a motion's timing measures them); the
        body may skip work that moves neither (a foot kept where it stands by its leg)."""
        ...

    def faults(self, postures: np.ndarray) -> list[list[str]]:
        """For each posture (T, nq), what it breaks among the joint ranges and the hard tasks (by name;
        empty when it holds them all)."""
        ...

    def hold(self, posture: np.ndarray, before: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray | None:
        """A posture near ``posture`` (nq,) that holds every hard task with the effector where ``posture``
        puts it, or None when none is found. ``before``: the previous frame and its hold, whose
        displacement is the first guess (so that consecutive frames are held alike)."""
        ...

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """Each posture (F, nq) held as :meth:`hold` holds it without ``before``, all as one batch: (F, nq), a NaN row
        where none is found, the deadline (``time.perf_counter()``) passed, or the engine holds one posture at a time
        (the caller then holds that one with :meth:`hold`)."""
        ...


@dataclass(frozen=True)
class Skeleton:
    """A body's joints grouped into bones, as animation files want them.

    Attributes:
        bones: Bone names (the links they move), parents before children.
        joints: The joints each bone turns by (several at one point, such as a shoulder's three).
        parents: Each bone's parent (-1: the root, the body's floating base).
        ends: (name, bone, offset [m] in the bone's frame): where leaf bones end, and the effector.
        capsule_names: The body's capsules.
        capsules: (K, 7) end points a, b [m] in their bone's frame, radius [m].
        capsule_bones: (K,) the bone each capsule moves with.
    """

    bones: tuple[str, ...]
    joints: tuple[tuple[str, ...], ...]
    parents: tuple[int, ...]
    ends: tuple[tuple[str, int, tuple[float, float, float]], ...]
    capsule_names: tuple[str, ...] = ()
    capsules: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    capsule_bones: tuple[int, ...] = ()


@runtime_checkable
class Oriented(Protocol):
    """Goals with an orientation (``Goals.targets["orientation"]``): the strategy holds its effector to each
    goal's (see :mod:`oracles.tasks.orientation`)."""

    def orientation_kinds(self) -> tuple[str, ...]:
        """What a goal's orientation may be for this strategy: ``direction`` (of its approach axis) and
        ``rotation``, only ``rotation``, or none (the strategy holds no orientation)."""
        ...


@runtime_checkable
class Articulated(Protocol):
    """An oracle whose body is a tree of bones (:mod:`reach.motion.rig`)."""

    def skeleton(self) -> Skeleton:
        """The body's bones, their parents, ends and capsules."""
        ...

    def bone_frames(self, postures: np.ndarray) -> np.ndarray:
        """World transforms (T, B, 4, 4) [m] of every bone of :meth:`skeleton` at postures (T, nq)."""
        ...


def body_params(body: Any, effector: str, joints: Any, tasks: Any, ranges: Any = None) -> dict[str, Any]:
    """The params a config gives a body strategy's oracle, over the oracle's own.

    Every body oracle's factory (``casadi-ik``, ``dls``, or a third party's)
    takes these keyword arguments: the body spec (:func:`oracles.bodies.body.load_body`),
    the effector frame, the active joints and the task list (:mod:`oracles.ik.strategy`);
    and ``ranges``, the strategy's own joint ranges over the body's, when the config gives them.
    """
    return {"body": body, "effector": effector, "joints": joints, "tasks": tasks,
            **({"ranges": ranges} if ranges is not None else {})}


@dataclass(frozen=True)
class OracleSpec:
    """A serialisable description from which any process can build an oracle.

    Workers receive specs, never oracle objects, so heavy solver objects are
    built once per worker and never pickled per task.

    Attributes:
        name: Registry name, e.g. ``sphere`` or ``casadi-ik``.
        params: JSON-compatible keyword arguments of the oracle's factory.
    """

    name: str
    params: dict[str, Any] = field(default_factory=dict)

    def create(self) -> Oracle:
        """Build the oracle through the registry."""
        return cast(Oracle, registry.create(self.name, self.params))

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "params": dict(self.params)}

    @staticmethod
    def from_dict(data: dict[str, Any]) -> OracleSpec:
        return OracleSpec(str(data["name"]), dict(data.get("params", {})))


def check_points(points: np.ndarray, dim: int) -> np.ndarray:
    """Return points as a float (N, dim) array or raise a clear error."""
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise OracleError(f"points must have shape (N, {dim}), got {arr.shape}", key="points")
    return arr


def check_verdicts(verdicts: Verdicts, n: int, nq: int) -> Verdicts:
    """Validate what an oracle returned for n points with nq posture coordinates."""
    reach = np.asarray(verdicts.reachable, dtype=bool)
    res = np.asarray(verdicts.residual, dtype=float)
    if reach.shape != (n,) or res.shape != (n,):
        raise OracleError(
            f"oracle returned reachable {reach.shape} and residual {res.shape}, expected ({n},)"
        )
    posture = verdicts.posture
    if nq and posture is None:
        raise OracleError(f"oracle declares {nq} posture names but returned no postures", key="posture")
    if posture is not None:
        posture = np.asarray(posture, dtype=float)
        if posture.shape != (n, nq):
            raise OracleError(f"oracle returned postures {posture.shape}, expected ({n}, {nq})", key="posture")
    return Verdicts(reach, res, posture)
