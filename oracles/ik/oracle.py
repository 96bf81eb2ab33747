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
import time
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np
import pinocchio as pin

from oracles import registry
from oracles.bodies.anthropometry import legacy_body
from oracles.bodies.body import load_body
from oracles.errors import ModelError, OracleError
from oracles.ik import rounds
from oracles.ik.rounds import NO_CALL, Call, Rounds
from oracles.ik.search import Search
from oracles.ik.strategy import parse_strategy
from oracles.ik.tasked import TaskedBody
from oracles.protocol import Goals, Oracle, OracleSpec, Purpose, Verdicts, check_purpose
from oracles.tasks.feet import DOWN_SUPPORT, corner_frames

__all__ = ["NO_CALL", "Call", "IKOracle", "fresh_stats"]

# Steps of a motion's end posture settled from a stored one (IKOracle.settle): the reach task's own step is at most
# 5 cm (dls's max_reach_step) and a stored posture lies within half a finest cell's diagonal (6.5 cm on the demo).
SETTLE_ITER = 30


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


class IKOracle(TaskedBody, ABC):
    """The IK oracles' adapter to the protocol; subclasses implement :meth:`solve`.

    What the body shows is :class:`~oracles.bodies.posed.PosedBody`'s, what
    the tasks say :class:`~oracles.ik.tasked.TaskedBody`'s; this adds the
    spec, the variants, the search (one start at a time by default,
    :class:`~oracles.ik.rounds.Rounds`) and the holds a motion needs.

    Args:
        body: Body spec (see :func:`oracles.bodies.body.load_body`).
        effector: Frame that reaches.
        joints: Active joints (names or glob patterns; ``root`` frees the base).
        tasks: Task list (see :mod:`oracles.ik.strategy`).
        search: How to look for a posture (see :class:`~oracles.ik.search.Search`).
        ranges: The strategy's own joint ranges over the body's (:func:`strategy_ranges`).

    The registry builds it with :meth:`from_params`, from one flat mapping
    holding the body, the search's fields and the engine's own parameters.
    """

    dim = 3
    name: str  # the registry name
    # engine options of reach_extent's probe (it seeks extremes, not postures)
    extreme_params: ClassVar[dict[str, Any]] = {}

    def __init__(self, body: dict[str, Any], effector: str, joints: list[str],
                 tasks: list[dict[str, Any]] | None = None,
                 search: Search | None = None, ranges: dict[str, Any] | None = None) -> None:
        self.search = search if search is not None else Search()
        params: dict[str, Any] = {"body": body, "effector": effector, "joints": joints, "tasks": tasks,
                                  **({"ranges": ranges} if ranges else {})}
        own = strategy_ranges(body, ranges)
        try:
            loaded = load_body(own)
        except ModelError as exc:
            # an error in the strategy's own ranges names them, not the body's
            mine = bool(ranges) and (exc.key or "").startswith("ranges.") and (exc.key or "")[7:] in (ranges or {})
            raise exc if mine else exc.under("body") from None
        super().__init__(loaded, parse_strategy(loaded, effector, joints, tasks), own, params)
        self.stats = fresh_stats()
        self._transits: dict[tuple[str, ...], IKOracle | None] = {}  # motions' twins by the tasks a start breaks
        self.reference_pending = False  # reference: auto found no posture by projection (see _auto_reference)
        if body.get("reference") == "auto":
            self._auto_reference(own, effector, joints, tasks)

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

    def as_built(self, model_hash: str) -> tuple[Oracle, str] | None:
        """This oracle on the body a stored tree was built with: a human spec read as earlier versions built it
        (``proportions: de_leva``), when that body's hash is the tree's."""
        body, note = legacy_body(self._strategy_params["body"])
        if note is None:
            return None
        spec = self.spec.to_dict()
        oracle = OracleSpec.from_dict({**spec, "params": {**spec["params"], "body": body}}).create()
        return (oracle, note) if isinstance(oracle, IKOracle) and oracle.model_hash == model_hash else None

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
        for raw in self._strategy_params.get("tasks") or []:
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
        """Each posture (F, nq) held as one batch, a NaN row where none is held. An engine that solves one posture at a
        time holds none here: the caller holds them with :meth:`hold`, each from its neighbour's correction, as before
        (held here without it, then again there, a rejected batch cost the motion twice)."""
        return np.full(np.shape(postures), np.nan)

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

    def starts(self, goal: np.ndarray, hint: np.ndarray | None, call: Call = NO_CALL,
               restarts: int | None = None) -> list[np.ndarray]:
        """A goal's initial postures (see :func:`oracles.ik.rounds.starts`)."""
        return rounds.starts(self.problem, self.search, goal, hint, call, restarts)

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
        (each goal held to its targets (N, T), ``Strategy.target_rows``, when given)."""
        return Rounds(self, self._data, points, hints, start, targets, self.body.q_ref).run()
