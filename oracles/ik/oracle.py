"""Inverse-kinematics oracles: the paper's ``isPointInside`` for a body.

:class:`IKOracle` holds what every IK engine shares: the body, strategy and
problem built from a serialisable spec, the search (:class:`~oracles.ik.search.Search`:
warm starts, restarts, giving up) and the verdict. A point is reachable only
if an independent Pinocchio forward-kinematics check of the returned posture
puts the effector within the strategy's tolerance (default 5 mm) of the goal
and every hard task holds; a solver's status is never trusted. The engines
are :class:`~oracles.ik.engine.CasadiIK` and :class:`~oracles.ik.dls.DLSIK`.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
import zlib
from abc import ABC, abstractmethod
from typing import Any, ClassVar, NamedTuple

import numpy as np
import pinocchio as pin

from oracles import registry
from oracles.bodies.anthropometry import legacy_body
from oracles.bodies.body import ROOT, load_body
from oracles.bodies.mirror import MirrorMap
from oracles.bodies.skeleton import bone_frames, build_skeleton
from oracles.errors import ModelError, OracleError
from oracles.ik.problem import Check, ReachProblem
from oracles.ik.search import Search
from oracles.ik.strategy import parse_strategy
from oracles.protocol import Ball, Goals, Oracle, OracleSpec, Purpose, Skeleton, Verdicts, check_points, check_purpose
from oracles.tasks import ContactsTask, FloorTask, Numeric, ObstaclesTask, OrientationTask

# tasks that hold something fixed in the world, which a turn would move
WORLD_FIXED = frozenset({"obstacles", "tether"})
TARGET_RESTARTS = 4  # random starts at least, for a goal that carries a target (see IKOracle._evaluate)



class Call(NamedTuple):
    """What one ``evaluate`` call knows beyond its points, passed down to every solve (never stored).

    Attributes:
        start: The character's current posture as the problem's x (``Goals.current``), or None.
        deadline: ``time.perf_counter()`` past which no new solve starts (inf: no budget).
        target: The goal's task targets as the programs' parameters (``Strategy.target_rows``; set per goal),
            or None: the goal carries none.
    """

    start: np.ndarray | None = None
    deadline: float = np.inf
    target: np.ndarray | None = None


NO_CALL = Call()  # a call with neither current posture nor budget


def fresh_stats() -> dict[str, int]:
    return {"points": 0, "prefiltered": 0, "solves": 0, "reachable": 0, "cut_rounds": 0}


class IKOracle(ABC):
    """Shared driver of the IK oracles; subclasses implement :meth:`solve`.

    Args:
        body: Body spec (see :func:`oracles.bodies.body.load_body`).
        effector: Frame that reaches.
        joints: Active joints (names or glob patterns; ``root`` frees the base).
        tasks: Task list (see :mod:`oracles.ik.strategy`).
        search: How to look for a posture (see :class:`~oracles.ik.search.Search`).

    The registry builds it with :meth:`from_params`, from one flat mapping
    holding the body, the search's fields and the engine's own parameters.
    """

    dim = 3
    name: str  # the registry name
    # engine options of reach_extent's probe (it seeks extremes, not postures)
    extreme_params: ClassVar[dict[str, Any]] = {}

    def __init__(self, body: dict[str, Any], effector: str, joints: list[str],
                 tasks: list[dict[str, Any]] | None = None,
                 search: Search | None = None) -> None:
        self.search = search if search is not None else Search()
        self._strategy_params: dict[str, Any] = {"body": body, "effector": effector, "joints": joints, "tasks": tasks}
        try:
            self.body = load_body(body)
        except ModelError as exc:
            raise exc.under("body") from None
        self.strategy = parse_strategy(self.body, effector, joints, tasks)
        self.problem = ReachProblem(self.body, self.strategy)
        self.posture_names = tuple(self.body.q_names)
        self._data = self.body.model.createData()
        self.stats = fresh_stats()
        self.reference_pending = False  # reference: auto found no posture by projection (see _auto_reference)
        if body.get("reference") == "auto":
            self._auto_reference(body, effector, joints, tasks)
        self._bones: tuple[Skeleton, tuple[int, ...]] | None = None
        # the damped-least-squares twin that holds a posture's hard tasks (built on first use)
        self._projector: Any = None

    def _auto_reference(self, body: dict[str, Any], effector: str, joints: list[str],
                        tasks: list[dict[str, Any]] | None) -> None:
        """``reference: auto``: the middle of the ranges, moved by damped least squares on this strategy's hard tasks
        (the effector kept where it is) to the nearest posture that holds them all, when the middle breaks one
        (a tool held pointing down, a tether); kept as it is when none is found (``diagnose`` then warns)."""
        q = self.body.q_ref
        if not self.faults(q[None])[0]:
            return
        # The dls engine by its registry name: it is an IKOracle itself, so importing it here would be a cycle.
        twin = registry.create("dls",
                               {"body": {**body, "reference": "middle"}, "effector": effector, "joints": joints,
                                "tasks": tasks})
        held = twin.project(q, q)
        if self.faults(held[None])[0]:
            # Damped least squares stays near the middle: a tool turned half a turn (pointing down) is far. An engine
            # that can search (its restarts included) tries when it is set up (``search_reference``).
            self.reference_pending = True
            return
        self.use_reference(held)

    def use_reference(self, q: np.ndarray) -> None:
        """Make ``q`` the reference posture (every search's start, the contacts' places)."""
        self.body = dataclasses.replace(self.body, q_ref=np.asarray(q, float).copy())
        self.problem = ReachProblem(self.body, self.strategy)

    @classmethod
    def from_params(cls, **params: Any) -> IKOracle:
        """The oracle of a spec's flat params: the body's, the search's and the engine's (the registry's factory)."""
        search, rest = Search.split(params)
        return cls(search=search, **rest)

    def engine_params(self) -> dict[str, Any]:
        """The engine's own parameters, as a spec writes them (none by default)."""
        return {}

    # -- optional capabilities of the oracle protocol ----------------------
    @property
    def spec(self) -> OracleSpec:
        """The spec that rebuilds this oracle in another process."""
        return OracleSpec(self.name, {**self._strategy_params, **self.search.to_params(), **self.engine_params()})

    @property
    def model_hash(self) -> str:
        return self.body.hash

    def as_built(self, model_hash: str) -> tuple[Oracle, str] | None:
        """This oracle on the body a stored tree was built with: a human spec read as earlier versions built it
        (``proportions: de_leva``), when that body's hash is the tree's."""
        body, note = legacy_body(self._strategy_params["body"])
        if note is None:
            return None
        spec = self.spec.to_dict()
        oracle = OracleSpec.from_dict({**spec, "params": {**spec["params"], "body": body}}).create()
        return (oracle, note) if isinstance(oracle, IKOracle) and oracle.model_hash == model_hash else None

    def effector_positions(self, postures: np.ndarray) -> np.ndarray:
        """Effector positions [m] (N, 3) of postures (N, nq), by Pinocchio."""
        model, data, fid = self.body.model, self._data, self.problem.effector_id
        out = np.empty((len(postures), 3))
        for k, q in enumerate(postures):
            pin.forwardKinematics(model, data, q)
            out[k] = pin.updateFramePlacement(model, data, fid).translation
        return out

    def reach_bound(self) -> Ball | None:
        """A fixed point and the most the effector can be from it [m], or None when unbounded."""
        p = self.problem
        if p.anchor is None or not np.isfinite(p.max_reach):
            return None
        return Ball(p.anchor.copy(), float(p.max_reach))

    def free_turn(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The first active joint's axis when the volume turns freely about it (see
        :class:`oracles.protocol.Turning`)."""
        model, p = self.body.model, self.problem
        if self.strategy.floating or not p.joint_ids or self.body.furniture:
            return None
        if any(t.type in WORLD_FIXED for t in self.strategy.tasks):
            return None
        first = min(p.joint_ids)
        for j in p.joint_ids:
            while j > first:
                j = int(model.parents[j])
            if j != first:
                return None  # an active joint on another branch
        jm = model.joints[first]
        full = str(model.names[first]) in self.body.continuous or (
            jm.nq == 1 and model.upperPositionLimit[jm.idx_q] - model.lowerPositionLimit[jm.idx_q] >= 2 * np.pi - 1e-6)
        if not full:
            return None
        data = model.createData()
        pin.computeJointJacobians(model, data, self.body.q_ref)
        column = pin.getJointJacobian(model, data, first, pin.LOCAL_WORLD_ALIGNED)[:, jm.idx_v]
        if np.linalg.norm(column[3:]) < 0.5 or np.linalg.norm(column[:3]) > 1e-9:
            return None  # not a revolute joint
        axis = column[3:] / np.linalg.norm(column[3:])
        if self.strategy.task("floor") is not None and abs(axis[2]) < 1 - 1e-9:
            return None  # a floor turns with a vertical axis only
        return data.oMi[first].translation.copy(), axis

    def lowest(self) -> float | None:
        """0 when a floor task holds the effector's own capsule above z = 0 (the effector lies inside it), else None."""
        floor = self.strategy.task("floor")
        return 0.0 if isinstance(floor, FloorTask) and floor.eager else None

    def reference_posture(self) -> np.ndarray:
        return self.body.q_ref.copy()

    def shape(self, posture: np.ndarray) -> tuple[list[str], np.ndarray]:
        """The body's capsules (K, 7) at a posture, world frame (see :class:`oracles.protocol.Shaped`)."""
        return [p.name for p in self.body.collision.placed], self.body.capsules_at(posture)

    def furniture(self) -> tuple[list[str], np.ndarray]:
        """The body's seat and the obstacles task's boxes (see :class:`oracles.protocol.Furnished`)."""
        task = self.strategy.task("obstacles")
        boxes = list(dict.fromkeys([*self.body.furniture, *(task.boxes if isinstance(task, ObstaclesTask) else ())]))
        return [b.name or f"box{i}" for i, b in enumerate(boxes)], np.array([b.as_row() for b in boxes]).reshape(-1, 10)

    def verify(self, points: np.ndarray, postures: np.ndarray) -> np.ndarray:
        """The verdict's own check (Pinocchio forward kinematics, every hard task) of postures found elsewhere."""
        pts = check_points(points, 3)
        return np.array([self.problem.check(np.asarray(q, float), g, self._data).reachable
                         for g, q in zip(pts, postures, strict=True)], bool)

    def posture_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The model's joint ranges per posture coordinate; a floating base's position and a continuous joint are
        unbounded."""
        model = self.body.model
        lower, upper = model.lowerPositionLimit.astype(float).copy(), model.upperPositionLimit.astype(float).copy()
        for j in range(1, model.njoints):
            jm = model.joints[j]
            if j == 1 or jm.nq != 1:  # the root (its limits are the solvers' box) and continuous joints
                lower[jm.idx_q : jm.idx_q + jm.nq], upper[jm.idx_q : jm.idx_q + jm.nq] = -np.inf, np.inf
        return lower, upper

    def skeleton(self) -> Skeleton:
        """The body's bones (see :mod:`oracles.bodies.skeleton`), the effector among their ends."""
        return self._skeleton()[0]

    def bone_frames(self, postures: np.ndarray) -> np.ndarray:
        """World transforms (T, B, 4, 4) of the skeleton's bones at postures (T, nq), by Pinocchio."""
        return bone_frames(self.body.model, self._skeleton()[1], postures)

    def _skeleton(self) -> tuple[Skeleton, tuple[int, ...]]:
        if self._bones is None:
            self._bones = build_skeleton(self.body, self.strategy.effector)
        return self._bones

    def interpolate(self, q0: np.ndarray, q1: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Pinocchio's interpolation on the model's configuration space (see :class:`oracles.protocol.Moving`).

        With a floating root and a foot held fixed (a ``fixed`` contact of a
        hard task), the root is then placed so that this foot follows its
        own interpolation between its two placements: a standing body moves
        from its foot, as people do, and the feet hardly slide, so that
        :meth:`hold` has little to mend.
        """
        model, a, b = self.body.model, np.asarray(q0, float), np.asarray(q1, float)
        out = np.array([pin.interpolate(model, a, b, float(u)) for u in np.atleast_1d(s)]).reshape(-1, model.nq)
        anchor = self._anchor()
        if anchor is None:
            return out
        data = self._data
        ends = []
        for q in (a, b):
            pin.framesForwardKinematics(model, data, q)
            ends.append(data.oMf[anchor].copy())
        for k, u in enumerate(np.atleast_1d(s)):
            pin.framesForwardKinematics(model, data, out[k])
            target = pin.SE3.Interpolate(ends[0], ends[1], float(u))
            root = target * data.oMf[anchor].inverse() * data.oMi[1]
            out[k, :3], out[k, 3:7] = root.translation, pin.Quaternion(root.rotation).coeffs()
        return out

    def _anchor(self) -> int | None:
        """The frame a standing body moves from: the first ``fixed`` contact of a hard task, when the root floats."""
        if not self.strategy.floating:
            return None
        fixed = (c for t in self.strategy.hard if isinstance(t, ContactsTask) for c in t.contacts if c.mode == "fixed")
        contact = next(fixed, None)
        return None if contact is None else int(self.body.frame_id(contact.frame))

    def faults(self, postures: np.ndarray) -> list[list[str]]:
        """The joints outside their ranges and the hard tasks a posture breaks, by each task's own check."""
        model, data, p = self.body.model, self._data, self.problem
        out = []
        for q in np.atleast_2d(np.asarray(postures, float)):
            pin.framesForwardKinematics(model, data, q)
            num = Numeric(model, data, q, data.oMf[p.effector_id].translation.copy())
            out.append(p.out_of_limits(q) + [t.type for t in self.strategy.hard if not t.holds(num)])
        return out

    def _dls(self) -> Any:
        """The damped-least-squares twin of this oracle (itself for ``dls``), built on first use: no compilation."""
        if self._projector is None:
            self._projector = self if self.name == "dls" else registry.create("dls", dict(self._strategy_params))
        return self._projector

    def _project(self, posture: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """Damped least squares on the hard tasks' rows alone, from guess, pulled towards posture (may still break
        them)."""
        return np.asarray(self._dls().project(posture, guess))

    def reach_extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The effector's farthest positions found reaching for goals on the reach bound's sphere in 26 directions
        (the cube's faces, edges and corners), postures breaking a hard task left out: an estimate of the volume's
        bounds [m], not a bound (see :class:`oracles.protocol.Probing`). One start each, interpreted (no
        compilation): an extreme is sought, not a natural posture."""
        bound = self.reach_bound()
        if bound is None:
            return None
        dirs = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], float) - 1.0
        goals = bound.centre + bound.radius * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        params = {**self.spec.params, "restarts": 1, "secondary": False, **self.extreme_params}
        if "jit" in params:
            params["jit"] = False
        probe = OracleSpec(self.name, params).create()
        postures = probe.evaluate(goals).posture
        if postures is None:
            return None
        # An unreachable goal's best attempt may stop mid-way through a lazy task (a table, the body itself):
        # the least change that holds the hard tasks keeps it as an extreme.
        held = [q if not f else self._project(q, q) for q, f in zip(postures, self.faults(postures), strict=True)]
        held = [q for q, f in zip(held, self.faults(np.array(held)), strict=True) if not f]
        if not held:
            return None
        reached = self.effector_positions(np.array(held))
        return reached.min(axis=0), reached.max(axis=0)

    def hold(self, posture: np.ndarray, before: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray | None:
        """The least change that holds every hard task (damped least squares on their rows alone, a few
        iterations); failing that, the refinement's solve at the posture's own effector position, started
        from it and pulled towards it."""
        q = np.asarray(posture, float)
        model = self.body.model
        guesses = [q] if before is None else [pin.integrate(model, q, pin.difference(model, before[0], before[1])), q]
        for guess in guesses:
            held = self._project(q, guess)
            if not self.faults(held[None])[0]:
                return held
        v = self.evaluate(Goals(self.effector_positions(q[None]), current=q))
        return v.posture[0] if v.reachable[0] and v.posture is not None else None

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """Each posture (F, nq) held as one batch, a NaN row where none is held. An engine that solves one posture at a
        time holds none here: the caller holds them with :meth:`hold`, each from its neighbour's correction, as before
        (held here without it, then again there, a rejected batch cost the motion twice)."""
        return np.full(np.shape(postures), np.nan)

    def limits_near(self, posture: np.ndarray, margin: float) -> list[str]:
        """The joint limits a posture comes within margin [rad or m] of (see :meth:`ReachProblem.limits_near`)."""
        return self.problem.limits_near(np.asarray(posture, float), float(margin))

    def keep_out(self) -> np.ndarray:
        """Capsules (K, 7) that hold no reachable point: the static segments the effector may not enter."""
        out = [c for t in self.strategy.hard for c in t.keep_out()]
        return np.array(out, float).reshape(-1, 7)

    def describe(self) -> dict[str, Any]:
        """The strategy as parsed: effector, active joints and tasks (``reach model CONFIG``); with ``reference: auto``,
        the reference posture found for it (joint -> rad or m)."""
        out: dict[str, Any] = {"effector": self.strategy.effector, "joints": list(self.strategy.joints),
                               "tasks": [t.describe() for t in self.strategy.tasks]}
        if self._strategy_params["body"].get("reference") == "auto":
            model, q = self.body.model, self.body.q_ref
            out["reference"] = {}
            for name in self.strategy.joints:  # one value per joint: a continuous joint's angle
                if name != ROOT:
                    jm = model.joints[model.getJointId(name)]
                    value = math.atan2(q[jm.idx_q + 1], q[jm.idx_q]) if jm.nq == 2 else q[jm.idx_q]
                    out["reference"][name] = round(float(value), 6)
        return out

    def diagnose(self) -> list[str]:
        """What in the spec will likely give a wrong or empty volume (see :class:`oracles.protocol.Diagnosed`)."""
        out = list(self.body.notes)
        for task in self.strategy.hard:
            out += task.warnings()
        q = self.body.q_ref
        broken = self.faults(q[None])[0]
        # A start that breaks a hard task is common (one foot's balance from two feet) and the search leaves
        # it; only when the nearest posture holding the hard tasks cannot be found is the volume at risk.
        if broken and self.faults(self._project(q, q)[None])[0]:
            out.append(f"the reference posture breaks the hard tasks {broken} and no posture near it holds them: "
                       "every search starts "
                       "there, so the volume may come out empty; give body.reference (a posture that holds them) or "
                       "change the tasks")
        return out

    def variant(self, purpose: Purpose, *, budget: float | None = None, restarts: int = 6) -> IKOracle:
        """This oracle set up for a purpose (see :class:`oracles.protocol.Tunable`).

        The variant shares the body, the problem and the compiled programs; it
        has its own search and engine options and counts its own stats.
        """
        check_purpose(purpose)
        twin = copy.copy(self)
        twin.search = self.search.for_purpose(purpose, budget=budget, restarts=restarts)
        twin.stats = fresh_stats()
        twin.tune(purpose)
        return twin

    def tune(self, purpose: Purpose) -> None:  # noqa: B027 - engines without purpose-specific options need nothing
        """Set the engine's options for a purpose's variant (called on the variant, a shallow copy)."""

    def mirror(self) -> Any:
        """The map of postures to their mirror images about y = 0 (raises ModelError for an asymmetric body)."""
        return MirrorMap(self.body).mirror_q

    def prepare(self) -> None:  # noqa: B027 - engines without solvers to build need nothing
        """Build the solvers now rather than on the first evaluate."""

    @abstractmethod
    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        """A configuration q that tries to put the effector at goal, starting from x0 (with the lower tasks, or reach
        alone)."""

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        """How much the lower tasks dislike a posture (lower is better; 0 when the engine cannot tell)."""
        return 0.0

    def solve_batch(self, goals: np.ndarray, x0: np.ndarray, lower: np.ndarray | None = None, call: Call = NO_CALL,
                    targets: np.ndarray | None = None) -> np.ndarray:
        """Configurations (N, nq) for goals (N, 3) from starts (N, nx), with the lower tasks where lower (N,) is true,
        each goal with its targets (N, T) (``Strategy.target_rows``) when given; engines may batch. Past
        ``call.deadline`` no further solve starts: the first k <= N postures (k >= 1) are returned."""
        flags = np.ones(len(goals), bool) if lower is None else lower
        calls = [call] * len(goals) if targets is None else [call._replace(target=t) for t in targets]
        out: list[np.ndarray] = []
        for g, x, f, c in zip(goals, x0, flags, calls, strict=True):
            if out and time.perf_counter() > call.deadline:
                break
            out.append(self.solve(g, x, bool(f), c))
        return np.array(out)

    @property
    def orientation(self) -> OrientationTask | None:
        """The strategy's orientation task, if it has one."""
        task = self.strategy.task("orientation")
        return task if isinstance(task, OrientationTask) else None

    def orientation_kinds(self) -> tuple[str, ...]:
        """``direction`` and ``rotation`` for an axis-form orientation task, ``rotation`` for a full one, else none."""
        task = self.orientation
        return () if task is None else ("direction", "rotation") if task.axis is not None else ("rotation",)

    def _unsolved_residuals(self, pts: np.ndarray, residual: np.ndarray, posture: np.ndarray) -> None:
        """A goal no solve reached before the deadline keeps the reference posture: its true distance, not infinity."""
        for i in np.nonzero(np.isinf(residual))[0]:
            residual[i] = self.problem.effector_distance(posture[i], pts[i], self._data)

    def starts(self, goal: np.ndarray, hint: np.ndarray | None, call: Call = NO_CALL,
               restarts: int | None = None) -> list[np.ndarray]:
        """Initial postures: the hint(s), the reference, then seeded random ones (``restarts`` of them, the search's by
        default).

        With ``reference_first`` and no current posture (a refinement without
        ``from``), the reference and then the *ready* posture
        (:attr:`ReachProblem.x_ready`: every joint part of the way to the middle
        of its range, off the reference's straight elbow) come first, and the
        hint rescues a goal both miss.
        """
        out = []
        seeds = np.zeros((0, 0)) if hint is None else np.atleast_2d(hint)  # one hint, or several
        out += [self.problem.x_of_q(h) for h in seeds if np.all(np.isfinite(h))]
        if self.search.reference_first and call.start is None:
            out[:0] = [self.problem.x_ref.copy(), self.problem.x_ready.copy()]
        else:
            out.append(self.problem.x_ref.copy())
        rng = np.random.default_rng([self.search.seed, zlib.crc32(np.round(goal, 9).tobytes())])
        out += [self.problem.random_x(rng) for _ in range(self.search.restarts if restarts is None else restarts)]
        return out

    def evaluate(self, goals: Goals | np.ndarray) -> Verdicts:
        """Verdicts for goals [m] (see :class:`oracles.protocol.Goals`): held to their targets, warm-started from
        their seeds ((N, nq), or (N, k, nq) tried in order), or from the current posture with a small cost on
        displacement from it."""
        g = Goals.of(goals)
        n, nq = len(g), len(self.posture_names)
        targets = self.strategy.target_rows(g.targets, n) if g.targets else None
        seeds = None if g.seeds is None else np.asarray(g.seeds, float)
        if seeds is not None and not (seeds.ndim in (2, 3) and seeds.shape[0] == n and seeds.shape[-1] == nq):
            raise OracleError(f"seeds have shape {seeds.shape}, expected ({n}, {nq}) or ({n}, k, {nq})", key="seeds")
        start = None
        if g.current is not None:
            current = np.asarray(g.current, float)
            if current.shape != (nq,):
                raise OracleError(f"current posture has shape {current.shape}, expected ({nq},)", key="current")
            start = self.problem.x_of_q(current)
            seeds = np.tile(current, (n, 1)) if seeds is None else seeds
        return self._evaluate(g.points, seeds, start, targets)

    def _evaluate(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                  targets: np.ndarray | None = None) -> Verdicts:
        """Rounds of solves from each point's next start until it reaches, gives up or runs out of starts
        (each goal held to its targets (N, T), ``Strategy.target_rows``, when given).

        The first of a point's seeds stands for the neighbour's posture in a build.
        """
        pts = check_points(points, 3)
        hints = None if hints is None else np.asarray(hints, float)
        search, n = self.search, len(pts)
        give_up = search.give_up_distance
        self.stats["points"] += n
        call = Call(start, np.inf if search.max_seconds is None else time.perf_counter() + search.max_seconds)
        residual = np.array([self.problem.prefilter(g) for g in pts])
        prefiltered = residual > self.strategy.tolerance
        self.stats["prefiltered"] += int(prefiltered.sum())
        reach = np.zeros(n, bool)
        done = np.zeros(n, bool)  # reached, or given up
        # the check of the posture kept so far (a pre-filtered point keeps the reference)
        kept: list[Check | None] = [None] * n
        posture = np.tile(self.body.q_ref, (n, 1))
        residual[~prefiltered] = np.inf
        # A goal with a target (an orientation) gets random starts even in a refinement: the stored postures it is
        # seeded with were found for its position alone (measured on arm7_table: 2 of 24 oriented goals the
        # referee reaches were missed from the four other starts).
        # (Not the index's search, which gives up and tries no random start: its (vertex, direction) goals, about two
        # thirds of them out of reach, each took four more solves, and arm7_table's index 2.5 times as long.)
        restarts = max(search.restarts, TARGET_RESTARTS) if targets is not None and search.give_up is None else None
        starts = [self.starts(g, None if hints is None else hints[i], call, restarts) if not prefiltered[i] else []
                  for i, g in enumerate(pts)]
        preferred = np.full(n, np.inf)  # with prefer: the lower tasks' objective of the kept posture
        decisive = np.zeros(n, bool)  # the first start is a warm start from a nearby hint
        settled = np.zeros(n, bool)  # ... so near that it solves the reach stage alone (see Search.settle)
        hint_first = not (search.reference_first and start is None)
        first = None if hints is None else (hints[:, 0] if hints.ndim == 3 else hints)
        if first is not None and (np.isfinite(give_up) or (search.settle > 0 and hint_first)):
            for i in np.nonzero(~prefiltered & np.all(np.isfinite(first), axis=1))[0]:
                gap = self.problem.effector_distance(first[i], pts[i], self._data)
                decisive[i] = np.isfinite(give_up) and gap <= search.decisive
                settled[i] = hint_first and gap <= search.settle
        for r in range(max(len(s) for s in starts) if n else 0):
            todo = np.array([i for i in range(n) if not done[i] and len(starts[i]) > r], dtype=int)
            if todo.size == 0 or time.perf_counter() > call.deadline:
                break
            q = self.solve_batch(pts[todo], np.array([starts[i][r] for i in todo]), ~settled[todo] if r == 0
                                 else None, call, None if targets is None else targets[todo])
            todo = todo[: len(q)]  # the goals solved before the deadline
            self.stats["solves"] += int(todo.size)
            for k, i in enumerate(todo):
                check = self.problem.check(q[k], pts[i], self._data, None if targets is None else targets[i])
                if search.prefer and check.reachable:
                    liked = self.preference(q[k], pts[i], call if targets is None else call._replace(target=targets[i]))
                    if not reach[i] or liked < preferred[i]:
                        residual[i], posture[i], preferred[i], kept[i] = check.residual, q[k], liked, check
                    reach[i] = True
                    continue  # every start is tried; the best liked reaching posture is kept
                if search.prefer and reach[i]:
                    continue  # a start that fails never replaces one that reached
                before = kept[i]  # hard_ok is asked only between two postures that both fail
                if before is None or (check.hard_ok, -check.residual) > (before.hard_ok, -before.residual):
                    kept[i], residual[i], posture[i] = check, check.residual, q[k]
                reach[i] = check.reachable
                done[i] = check.reachable
                # A posture that misses by more than give_up with the engine's
                # own rows held: the lazy ones are only cut once a stage
                # reaches (cutting cannot bring a goal nearer), so they do not count.
                if not done[i] and r == 0 and decisive[i] and check.eager_ok and check.residual > give_up:
                    # Given up: no reference start, only the first `rescues` random ones.
                    starts[i] = [starts[i][0], *starts[i][2 : 2 + search.rescues]]
        self._unsolved_residuals(pts, residual, posture)
        self.stats["reachable"] += int(reach.sum())
        return Verdicts(reach, residual, posture)
