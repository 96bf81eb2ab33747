"""The inverse-kinematics oracle: the paper's ``isPointInside`` for a body.

:class:`IKOracle` is a body and a strategy on it (:class:`~oracles.ik.tasked.TaskedBody`),
the search (:class:`~oracles.ik.search.Search`: warm starts, restarts, giving
up) and the solver it holds (:mod:`oracles.ik.solvers`: the batched steps,
fatrop's or IPOPT's programs, damped least squares), all built from one
serialisable spec. A point is reachable only if an independent Pinocchio
forward-kinematics check of the returned posture puts the effector within the
strategy's tolerance (default 5 mm) of the goal and every hard task holds; a
solver's status is never trusted.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Generator
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.bodies.anthropometry import legacy_body
from oracles.bodies.body import Body, load_body
from oracles.errors import ModelError, OracleError
from oracles.ik.joined import run_joined
from oracles.ik.problem import ReachProblem
from oracles.ik.rounds import NO_CALL, Call
from oracles.ik.search import Search
from oracles.ik.solvers import make
from oracles.ik.solvers.dls import DampedLeastSquares
from oracles.ik.strategy import parse_strategy
from oracles.ik.tasked import TaskedBody
from oracles.protocol import Goals, Oracle, OracleSpec, Purpose, Verdicts, check_purpose
from oracles.tasks.feet import DOWN_SUPPORT, corner_frames

__all__ = ["NO_CALL", "Call", "IKOracle", "dls", "fresh_stats"]

# Steps of a motion's end posture settled from a stored one (IKOracle.settle): the reach task's own step is at most
# 5 cm (dls's max_reach_step) and a stored posture lies within half a finest cell's diagonal (6.5 cm on the demo).
SETTLE_ITER = 30
# Batched starts of the search for a home (ReachProblem.x_home; fatrop or IPOPT take half as many random restarts):
# the squat's was found for its hand where it hangs standing from 64, not from the 16 of a cold goal (docs/results.md).
HOME_STARTS = 64
# The registry names whose factories build an IKOracle, and what each adds to a spec's params (``sibling``).
SIBLINGS: dict[str, dict[str, Any]] = {"casadi-ik": {}, "dls": {"solver": "dls"}}


def fresh_stats() -> dict[str, int]:
    return {"points": 0, "prefiltered": 0, "solves": 0, "reachable": 0, "cut_rounds": 0}


def strategy_ranges(body: dict[str, Any], ranges: Any) -> dict[str, Any]:
    """The body spec with a strategy's own joint ranges over the body's (``ranges``: joint name or pattern ->
    ``[lower, upper]`` [rad] or ``{scale: f}``, as the body's own key takes them).

    Why: some ranges belong to a way of reaching, not to the body. A knee flexes about 135 deg by its own muscles
    (AAOS 1965, the body's range) but 157 +- 6 deg in a squat with the heels up, the thigh pressed onto the calf by
    the body's weight (Hemmerich et al. 2006, J Orthop Res 24:770-781, abstract): the squat strategy alone takes it.
    """
    if not ranges:
        return body
    if not isinstance(ranges, dict):
        raise ModelError(f"expected joint name or pattern -> [lower, upper] in radians, got {ranges!r}", key="ranges")
    return {**body, "ranges": {**body.get("ranges", {}), **ranges}}


class IKOracle(TaskedBody):
    """A body, a strategy on it, a search and the solver it holds (see the module docstring).

    What the body shows is :class:`~oracles.bodies.posed.PosedBody`'s, what the tasks say
    :class:`~oracles.ik.tasked.TaskedBody`'s; this adds the spec, the variants, the verdicts and the holds a motion
    needs, each asked of the solver.

    Args:
        body: Body spec (see :func:`oracles.bodies.body.load_body`).
        effector: Frame that reaches.
        joints: Active joints (names or glob patterns; ``root`` frees the base).
        tasks: Task list (see :mod:`oracles.ik.strategy`).
        search: How to look for a posture (see :class:`~oracles.ik.search.Search`).
        ranges: The strategy's own joint ranges over the body's (:func:`strategy_ranges`).
        solver: The solver's name (:data:`oracles.ik.solvers.SOLVERS`): ``batch`` (the default), ``fatrop``,
            ``ipopt`` or ``dls``.
        options: The solver's own options (see each solver's class).

    The registry builds it with :meth:`from_params` (``casadi-ik``) or :func:`dls`, from one flat mapping holding the
    body, the search's fields, the solver and its options.
    """

    dim = 3

    def __init__(self, body: dict[str, Any], effector: str, joints: list[str],
                 tasks: list[dict[str, Any]] | None = None,
                 search: Search | None = None, ranges: dict[str, Any] | None = None, solver: str = "batch",
                 loaded: Body | None = None, **options: Any) -> None:
        self.search = search if search is not None else Search()
        params: dict[str, Any] = {"body": body, "effector": effector, "joints": joints, "tasks": tasks,
                                  **({"ranges": ranges} if ranges else {})}
        own = strategy_ranges(body, ranges)
        if loaded is None:
            try:
                loaded = load_body(own)
            except ModelError as exc:
                # an error in the strategy's own ranges names them, not the body's
                mine = bool(ranges) and (exc.key or "").startswith("ranges.") and (exc.key or "")[7:] in (ranges or {})
                raise exc if mine else exc.under("body") from None
        self._loaded = loaded  # the body as its spec loads it (``sibling``), before any reference of this strategy
        super().__init__(loaded, parse_strategy(loaded, effector, joints, tasks), own, params)
        self.stats = fresh_stats()
        self._transits: dict[tuple[str, ...], IKOracle | None] = {}  # motions' twins by the tasks a start breaks
        self.reference_pending = False  # reference: auto found no posture by projection (see _auto_reference)
        self.solver = make(solver, self, options, "dls" if solver == "dls" else "casadi-ik")
        if isinstance(self.solver, DampedLeastSquares):
            self._projector = self.solver  # holds postures with its own options
        if body.get("reference") == "auto":
            self._auto_reference(own, effector, joints, tasks)
        if self.reference_pending and self.solver.thorough:
            self._search_reference()

    @property
    def name(self) -> str:
        """The registry name of this oracle (``casadi-ik``, ``dls``)."""
        return self.solver.oracle

    def _auto_reference(self, body: dict[str, Any], effector: str, joints: list[str],
                        tasks: list[dict[str, Any]] | None) -> None:
        """``reference: auto``: the middle of the ranges, moved by damped least squares on this strategy's hard tasks
        (the effector kept where it is) to the nearest posture that holds them all, when the middle breaks one
        (a tool held pointing down, a tether); kept as it is when none is found (``diagnose`` then warns)."""
        q = self.body.q_ref
        if not self.faults(q[None])[0]:
            return
        twin = IKOracle({**body, "reference": "middle"}, effector, joints, tasks, solver="dls")
        held = twin.solver.project(q, q)  # type: ignore[attr-defined]
        if self.faults(held[None])[0]:
            # Damped least squares stays near the middle: a tool turned half a turn (pointing down) is far. A thorough
            # solver tries when it is set up (``_search_reference``).
            self.reference_pending = True
            return
        self.use_reference(held)

    def _search_reference(self) -> None:
        """``reference: auto`` where projection found nothing: this solver's search for the effector where it is,
        every hard task held, from the reference and its random restarts, uncompiled (a probe, not worth a compile);
        its posture becomes the reference when it holds the hard tasks (a UR5's tool-down strategy kept
        every joint at zero and warned)."""
        probe = copy.copy(self)
        probe.stats = fresh_stats()
        probe.solver = self.solver.twin(probe, compiled=False)
        found = probe.evaluate(Goals(self.effector_positions(self.body.q_ref[None])))
        if found.posture is not None and not self.faults(found.posture[:1])[0]:
            self.use_reference(found.posture[0])
            self.reference_pending = False

    def use_reference(self, q: np.ndarray) -> None:
        super().use_reference(q)
        self.solver = self.solver.twin(self)  # the reference's numbers (contacts, polygon) are the new posture's

    def sibling(self, spec: OracleSpec) -> IKOracle | None:
        """Another strategy's oracle on this oracle's body, the body not loaded again (see
        :class:`oracles.protocol.Sibling`): None when ``spec`` is not this room's or its body (with its strategy's own
        ranges) is another."""
        engine = SIBLINGS.get(spec.name)
        if engine is None:
            return None
        search, rest = Search.split({**spec.params, **engine})
        body = rest.get("body")
        if not isinstance(body, dict) or strategy_ranges(body, rest.get("ranges")) != self._body_spec:
            return None
        return type(self)(search=search, loaded=self._loaded, **rest)

    @classmethod
    def from_params(cls, **params: Any) -> IKOracle:
        """The oracle of a spec's flat params: the body's, the search's, the solver and its options (the registry's
        ``casadi-ik``)."""
        search, rest = Search.split(params)
        return cls(search=search, **rest)

    # -- optional capabilities of the oracle protocol ----------------------
    @property
    def spec(self) -> OracleSpec:
        """The spec that rebuilds this oracle in another process."""
        options = self.solver.options()
        if self.solver.oracle != self.solver.name:  # the oracle's name does not say which solver: the spec does
            options.setdefault("solver", self.solver.name)
        return OracleSpec(self.name, {**self.strategy_params, **self.search.to_params(), **options})

    def as_built(self, model_hash: str) -> tuple[Oracle, str] | None:
        """This oracle on the body a stored tree was built with: a human spec read as earlier versions built it
        (``proportions: de_leva``), when that body's hash is the tree's."""
        body, note = legacy_body(self.strategy_params["body"])
        if note is None:
            return None
        spec = self.spec.to_dict()
        oracle = OracleSpec.from_dict({**spec, "params": {**spec["params"], "body": body}}).create()
        return (oracle, note) if isinstance(oracle, IKOracle) and oracle.model_hash == model_hash else None

    def reach_extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The effector's farthest positions found reaching for goals on the reach bound's sphere in 26 directions
        (the cube's faces, edges and corners), postures breaking a hard task left out: an estimate of the volume's
        bounds [m], not a bound (see :class:`oracles.protocol.Probing`). One start each, interpreted (no
        compilation), by the solver's one-start-at-a-time twin (the batched solver's fatrop: it converges on the
        nearest point to an unreachable goal, where the batched steps stop once progress stalls, 5 mm short below
        configs/examples/arm7_table.yaml's table): an extreme is sought, not a natural posture."""
        bound = self.reach_bound()
        if bound is None:
            return None
        dirs = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], float) - 1.0
        goals = bound.centre + bound.radius * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        probe = copy.copy(self)
        probe.search = dataclasses.replace(self.search, restarts=1, secondary=False)
        probe.problem, probe.stats = ReachProblem(self.body, self.strategy), fresh_stats()  # its own home, if any
        probe.solver = self.solver.twin(probe, purpose="index", compiled=False)
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

    def settle(self, posture: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Damped least squares on the stack down to the reach task, from ``posture`` towards ``goal`` (see
        :class:`oracles.protocol.Settling`): a stored posture lies within a finest cell of its goal, a few steps
        from it, where a solve costs 20-100 ms (a refinement with the motion's budget, bench/motion.py)."""
        goal = np.asarray(goal, float)
        q = self._dls().towards(np.asarray(posture, float), goal, SETTLE_ITER)
        return q if self.problem.check(q, goal, self._data).reachable else None

    def transit(self, broken: list[str]) -> IKOracle | None:
        """The oracle whose tasks a motion's frames hold from a start that breaks ``broken`` (see
        :class:`oracles.protocol.Transiting`): the tasks the start breaks are the end's alone (a squat's hips below
        the knees), but balance, which holds over the feet's whole soles instead of their balls and toes while the
        heels may rise (standing flat, the body's weight is over the heels too). None when the start breaks anything
        else (a segment through another or the floor, a contact, a joint's range): such a start is refused. Made once
        per set of broken tasks (a server plans many motions)."""
        entered = self.strategy.entered
        if not broken or any(b not in entered for b in broken):
            return None
        key = tuple(sorted(broken))
        if key not in self._transits:
            self._transits[key] = self._transit_twin(broken)
        return self._transits[key]

    def _transit_twin(self, broken: list[str]) -> IKOracle | None:
        tasks = []
        for raw in self.strategy_params.get("tasks") or []:
            kind = raw.get("type")
            if kind in broken and kind != "balance":
                continue
            if (kind == "feet" and raw.get("heels") == "rise" and "balance" in broken
                    and not {"support", "soles"} & set(raw)):
                feet = raw.get("frames", ["right_foot", "left_foot"])
                raw = {**raw, "support": [c for f in feet for c in corner_frames(self.body.model, f, DOWN_SUPPORT)]}
            tasks.append(raw)
        params = {**self.spec.params, "tasks": tasks}
        if "jit" in params:
            params["jit"] = False  # a motion's holds; compiling the twin's programs would cost minutes
        twin = OracleSpec(self.name, params).create()
        return twin if isinstance(twin, IKOracle) else None

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """Each posture (F, nq) held as one batch, a NaN row where none is held (the batched solver's; the others hold
        none here, and the caller holds them one at a time with :meth:`hold`)."""
        return self.solver.hold_many(np.asarray(postures, float), deadline)

    def variant(self, purpose: Purpose, *, budget: float | None = None, restarts: int = 6) -> IKOracle:
        """This oracle set up for a purpose (see :class:`oracles.protocol.Tunable`).

        The variant shares the body, the problem and the compiled programs; it has its own search and solver options
        and counts its own stats.
        """
        check_purpose(purpose)
        twin = copy.copy(self)
        twin.search = self.search.for_purpose(purpose, budget=budget, restarts=restarts)
        twin.stats = fresh_stats()
        twin.solver = self.solver.twin(twin, purpose=purpose)
        return twin

    def prepare(self) -> None:
        """Build the solver's programs now rather than on the first evaluate, and find the strategy's home."""
        self.solver.prepare()
        self._seek_home()

    def _seek_home(self) -> None:
        """Where a strategy whose reference breaks its hard tasks (the squat's hips above its knees, its weight over the
        heels) starts its searches: this solver's answer, from HOME_STARTS starts and never giving up, for the effector
        where the reference holds it. From the standing reference, the squat's cold goals were reached by no placed
        start and by few random ones spread about it (24 of the truth suite's 67 proven goals missed)."""
        p = self.problem
        if p.home_sought or not self.solver.thorough:
            return
        p.home_sought = True  # before the probe, whose own search must not seek again (variants share the problem)
        if not self.faults(self.body.q_ref[None])[0]:
            return
        probe = copy.copy(self)
        probe.stats = fresh_stats()
        probe.search = dataclasses.replace(self.search, give_up=None, max_seconds=None,
                                           restarts=max(self.search.restarts, HOME_STARTS // 2))
        probe.solver = self.solver.twin(probe, starts=HOME_STARTS)
        found = probe.evaluate(Goals(self.effector_positions(self.body.q_ref[None])))
        if found.reachable[0] and found.posture is not None:
            p.use_home(found.posture[0])

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        """How much the lower tasks dislike a posture (lower is better; 0 when the solver cannot tell)."""
        return self.solver.preference(posture, goal, call)

    def share_programs(self, other: Any) -> bool:
        """Take ``other``'s compiled programs when one program serves both bodies (see
        :class:`oracles.protocol.Sharing`); whether it did."""
        return isinstance(other, IKOracle) and self.solver.share(other.solver)

    def evaluate(self, goals: Goals | np.ndarray) -> Verdicts:
        """Verdicts for goals [m] (see :class:`oracles.protocol.Goals`): held to their targets, warm-started from
        their seeds ((N, nq), or (N, k, nq) tried in order), or from the current posture with a small cost on
        displacement from it."""
        return self.solver.evaluate(*self._asked(goals))

    def evaluate_steps(self, goals: Goals | np.ndarray) -> Generator[Any, Any, Verdicts]:
        """:meth:`evaluate` as steps (see :class:`oracles.protocol.Joining`): the batched engine's batches of starts
        yielded to be run joined with other oracles' (:func:`run_joined`); another engine's call has none."""
        asked = self._asked(goals)
        steps = getattr(self.solver, "evaluate_steps", None)
        if steps is not None:
            return steps(*asked)  # type: ignore[no-any-return]
        return _no_steps(self.solver.evaluate(*asked))

    @staticmethod
    def run_joined(requests: list[Any]) -> list[Any]:
        """The ends of batches of starts that :meth:`evaluate_steps` of several oracles yielded, those of one program
        iterated as one (:mod:`oracles.ik.joined`)."""
        return run_joined(requests)

    def _asked(self, goals: Goals | np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                                                        np.ndarray | None]:
        """What the solver is asked for goals: points, seeds, the current posture as x, targets (see
        :meth:`evaluate`)."""
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
        if n:
            self._seek_home()
        return g.points, seeds, start, targets


def _no_steps(verdicts: Verdicts) -> Generator[Any, Any, Verdicts]:
    """A call with no batch of starts to yield: its verdicts."""
    return verdicts
    yield  # (a generator)


def dls(**params: Any) -> IKOracle:
    """The oracle of a spec's flat params with the damped least squares as its solver (the registry's ``dls``)."""
    return IKOracle.from_params(**params, solver="dls")
