"""The paper's priority mechanism: which strategy reaches a goal, and how.

For an effector and a goal, the strategies of that effector are tried in
priority order; the first whose tree holds the goal is chosen (the boundary
policy is configurable). The posture starts from the one stored at the
nearest reachable vertex of that tree, then is refined by the strategy's own
IK at the exact goal within a budget (of work with the batched engine: the same
answer on any machine; see oracles.ik.budget.Meter): the paper's "additional
inverse kinematics simulation". If refinement fails or runs out of budget, the
answer keeps the stored posture and says so.

**Answers that hold.** When the chosen strategy's refinement cannot reach
the exact goal (its tree held the goal from a boundary cell), the goal is
read as outside that strategy's volume and the next strategy holding it
answers. When none reaches it, the answer says so, as ``miss`` asks:
``unreachable`` (the default) answers ``reachable: false`` with the nearest
point a stored posture reaches and that posture; ``within`` answers
``reachable: true`` with ``within``. Every answer whose posture was not
solved at the goal (not refined, out of time, or missed) carries
``within``: the distance [m] that stored posture stops short of the goal.
So a "reachable" answer's posture reaches the goal unless ``within`` says
how near it comes.

**Handover.** A strategy that reaches a goal only with joints at (within
``handover``, default 5 deg, of) the end of their range or a coupled limit
passes the goal to the next strategy by priority that reaches it with fewer
joints at their limits; if none does, it answers itself. Limits the
reference posture rests at do not count (a straight knee stands at the end
of its range). This is the
paper's own future work ("the high-level library could exploit low level
information (i.e. joint level) that would drive the human to do the
reaching with another strategy", section 6): without it the upper body,
first by priority, answered goals at knee height with the lumbar spine at
its 60 deg limit and the neck fully flexed, the pelvis upright, where a
person bends at the hips (forward bending is lumbar and hip flexion
together, the lumbar spine leading only at its start: the lumbopelvic
rhythm, reviewed by Vazirian, Van Dillen & Bazrgari 2016, Int Musculoskelet
Med 38:51-58). 5 deg is the margin the project's posture figures count as
"at a limit" (``bench/posture.py``), a modelling choice. ``handover=0``
keeps the paper's plain priority.

**Batches.** :meth:`Selector.select_many` refines a batch's goals in passes,
one evaluate call per strategy each (the oracle's engine then solves them
together): every goal's first choice, then the next strategy for the goals
it failed, then the handover's candidates, within the budget of as many
refinements. The answers are those of one goal at a time. A query with a
``from`` is refined goal by goal (the omitted joints come from each goal's
own stored posture).
"""

from __future__ import annotations

import copy
import math
import time
from typing import Any, NamedTuple

import numpy as np

from oracles.protocol import Goals, Oracle, OracleSpec, Oriented, Preparable, Tunable
from reach.answers.answer import (
    ERROR,
    FAILED,
    NONE,
    REFINED,
    SKIPPED,
    TIMEOUT,
    UNAVAILABLE,
    Answer,
    split_posture,
    timed_out,
)
from reach.answers.defaults import HANDOVER, MISS, MISSES, REFINE_BUDGET
from reach.answers.oracles import Oracles
from reach.answers.passes import Passes
from reach.answers.refine import Prefetched, Purse, Refiner
from reach.answers.start import check_start
from reach.answers.stored import StoredPostures
from reach.errors import InputError, UnknownEffector, UnknownPolicy
from reach.maps.atlas import Atlas
from reach.maps.protocol import DEFAULT_POLICY, POLICIES, Policy

# outcomes whose posture is the nearest stored one, not one solved at the goal
STORED = (SKIPPED, TIMEOUT, FAILED, ERROR)


class Found(NamedTuple):
    """A strategy that answers a goal (see ``Selector._first_answer``)."""

    name: str
    posture: np.ndarray  # (nq,)
    residual: float | None  # [m] from the goal
    outcome: str  # the refinement's, one of the outcomes above
    row: int  # the nearest stored vertex's row


class Selector:
    """Answers goals from an atlas; per-tree lookup structures are built once.

    Args:
        atlas: The loaded atlas.
        policy: How boundary cells answer (see :meth:`reach.maps.protocol.ReachMap.contains`).
        refine: Refine postures by IK at the exact goal by default.
        budget: Time budget of one refinement [s].
        handover: [rad] A posture with joints this near their limits passes
            the goal to the next strategy that reaches it with fewer (see the
            module docstring); 0 keeps the plain priority.
        miss: What a goal the trees hold but no refinement reaches answers:
            ``unreachable`` or ``within`` (see the module docstring).
    """

    def __init__(self, atlas: Atlas, policy: Policy = DEFAULT_POLICY, refine: bool = True,
                 budget: float = REFINE_BUDGET, handover: float = HANDOVER, miss: str = MISS) -> None:
        if miss not in MISSES:
            raise InputError("miss", f"expected one of {', '.join(MISSES)}, got {miss!r}")
        self.miss = miss
        if policy not in POLICIES:
            raise UnknownPolicy(policy, POLICIES)
        if not (math.isfinite(handover) and handover >= 0):
            raise InputError("handover", f"expected a margin of 0 rad or more, got {handover!r}")
        self.handover = float(handover)
        self.atlas = atlas
        self.policy = policy
        self.refine = refine
        self.budget = budget
        self.oracles = Oracles(atlas, budget)
        self.stored = StoredPostures(atlas.maps, self.oracles.effector_positions)
        self.refiner = Refiner(atlas.maps, self.oracles, budget, self.stored.neighbours)
        self.order = [(s["name"], s["effector"]) for s in sorted(atlas.strategies, key=lambda s: s["priority"])]
        self._by_effector: dict[str, list[str]] = {}
        for name, effector in self.order:
            self._by_effector.setdefault(effector, []).append(name)
        for m in atlas.maps.values():
            m.prepare()  # the batch lookup table now, not on the first batch

    def warm_up(self, effector: str | None = None) -> Selector:
        """Build every strategy's refinement oracle (with its solvers) and posture index now, not on the first
        request; only the strategies of ``effector`` when given (a command about one effector: a right hand's motion
        compiled the left side's programs too, 78 of them on a cold cache)."""
        names = set(self.atlas.maps) if effector is None else set(self.strategies_for(effector))
        for name, m in self.atlas.maps.items():
            if m.posture_names and name in names:
                oracle = self.oracles(name)
                if isinstance(oracle, Preparable):
                    oracle.prepare()
                self.stored.lookup(name)
        return self

    @property
    def notes(self) -> list[str]:
        """What changed in the bodies of trees from earlier versions (:class:`~oracles.protocol.Rebuilt`)."""
        return self.oracles.notes

    @property
    def effectors(self) -> list[str]:
        return sorted(self._by_effector)

    def strategies_for(self, effector: str) -> list[str]:
        names = self._by_effector.get(effector) or self._by_effector.get(self._alias(effector) or "")
        if not names:
            raise UnknownEffector(effector, self.effectors)
        return names

    def _alias(self, frame: str) -> str | None:
        """The effector that a frame of the body names as well (the generated human's ``right_grip`` is its
        ``right_hand``): one on the same joint at the same placement; None when there is none."""
        for effector, names in self._by_effector.items():
            model = getattr(getattr(self.oracles(names[0]), "body", None), "model", None)
            if model is None or not (model.existFrame(frame) and model.existFrame(effector)):
                continue
            a, b = model.frames[model.getFrameId(frame)], model.frames[model.getFrameId(effector)]
            if a.parentJoint == b.parentJoint and a.placement.isApprox(b.placement, 1e-9):
                return effector
        return None

    def check_goals(self, effector: str, goals: np.ndarray, start: dict[str, float] | None = None) -> list[str]:
        """The effector's strategies, once the goals (N, d) and the ``from`` joints are known to be valid for them.

        Raises UnknownEffector, or InputError naming the field: what a query
        would refuse, checked before any work is queued.
        """
        names = self.strategies_for(effector)
        dim = self.atlas.maps[names[0]].dim
        if goals.ndim != 2 or goals.shape[1] != dim:
            raise InputError("goals", f"expected {dim} coordinates [m] each, got shape {list(goals.shape)}")
        if start:
            check_start(self.atlas.maps, self.oracles, names, start)
        return names

    def needs_ik(self, effector: str, goals: np.ndarray, start: dict[str, float] | None = None) -> bool:
        """Whether refining these goals would solve any IK: some strategy that stores postures holds one of them.

        Validates the request as :meth:`check_goals` does.
        """
        names = [n for n in self.check_goals(effector, goals, start) if self.atlas.maps[n].posture_names]
        if len(goals) == 1:
            point = goals[0].tolist()
            return any(self.atlas.maps[n].contains_one(point, self.policy) for n in names)
        return any(bool(self.atlas.maps[n].contains(goals, self.policy).any()) for n in names)

    def with_budget(self, budget: float) -> Selector:
        """This selector with another refinement budget [s], sharing its atlas, indexes and solvers
        (each oracle's ``"refine"`` variant with that budget)."""
        twin = copy.copy(self)
        twin.budget = float(budget)
        twin.oracles = self.oracles.with_budget(budget)
        twin.refiner = Refiner(self.atlas.maps, twin.oracles, budget, twin.stored.neighbours)
        return twin

    def oracle(self, name: str) -> Oracle:
        """The strategy's oracle as answers use it (its ``"refine"`` variant)."""
        return self.oracles(name)

    def oriented(self, effector: str, orientation: np.ndarray) -> list[str]:
        """The effector's strategies that hold a goal's orientation of this kind ((3,) direction or (3, 3) rotation),
        by priority."""
        kind = "direction" if orientation.shape == (3,) else "rotation"
        names = [n for n in self.strategies_for(effector) if isinstance(o := self.oracles(n), Oriented)
                 and kind in o.orientation_kinds()]
        if not names:
            raise InputError("orientation", f"no strategy of {effector!r} holds a goal's {kind}: give it an "
                                            "orientation task"
                             + (" with an axis" if kind == "direction" else ""))
        return names

    def select_many(self, effector: str, goals: np.ndarray, refine: bool | None = None,
                    start: dict[str, float] | None = None,
                    miss: str | None = None, orientation: np.ndarray | list[np.ndarray] | None = None,
                    deadline: float | None = None) -> list[Answer]:
        """Answers for goals (N, d) [m], one tree lookup per strategy for the whole batch.

        ``start`` is the character's current posture (joint name -> rad or m;
        ``root_x`` ... ``root_qw`` for a floating base), a query's ``from``:
        refinement then starts from it, with a small cost on displacement from
        it, so that the answer is the natural posture reached from there.
        Joints it omits keep the stored posture's values. ``miss`` overrides
        the selector's (see the module docstring). ``orientation``, a world
        direction (3,) of the effector's approach axis or its rotation (3, 3),
        holds every goal's orientation (a list of them: one per goal, of one
        kind): only the strategies with an orientation task answer, always by
        refinement, and a goal no refinement reaches with it is unreachable.
        ``deadline`` (a ``time.perf_counter()`` value): goals whose turn comes after it are not refined;
        their answers are the stored ones, marked ``timeout``.
        """
        t0 = time.perf_counter()
        g = np.asarray(goals, dtype=float)
        refine = self.refine if refine is None else refine
        names, aims, miss = self._asked(effector, g, refine, start, miss, orientation)
        if len(g) == 1:  # in plain Python: the server's per-request path
            out_of_time = refine and deadline is not None and time.perf_counter() > deadline
            point = g[0].tolist()
            hits = [n for n in names if self.atlas.maps[n].contains_one(point, self.policy)]
            nearest = self.stored.nearest_row(hits[0], point) if hits else None
            return [timed_out(self._answer(effector, g[0], hits, nearest, refine and not out_of_time, t0, start, miss,
                                           aims[0]), out_of_time)]
        return self._batch(effector, g, names, refine, start, miss, aims, deadline)

    def _asked(self, effector: str, g: np.ndarray, refine: bool, start: dict[str, float] | None, miss: str | None,
               orientation: np.ndarray | list[np.ndarray] | None) -> tuple[list[str], list[np.ndarray | None], str]:
        """A request's strategies, each goal's orientation (None: none) and its ``miss``, once they are valid."""
        names = self.check_goals(effector, g, start)
        aims: list[np.ndarray | None] = [None] * len(g)
        if orientation is not None:
            if not refine:
                raise InputError("refine", "a goal with an orientation is always refined (the trees hold positions); "
                                           "leave refine out or true")
            each = orientation if isinstance(orientation, list) else [orientation] * len(g)
            if len(each) != len(g) or len({np.shape(a) for a in each}) != 1 or np.shape(each[0]) not in ((3,), (3, 3)):
                raise InputError("orientation", "expected one direction (3,) or rotation (3, 3), or a list of one "
                                                f"per goal ({len(g)}), of one kind")
            aims = [np.asarray(a, float) for a in each]
            names = self.oriented(effector, np.asarray(each[0], float))
        miss = self.miss if miss is None else miss
        if miss not in MISSES:
            raise InputError("miss", f"expected one of {', '.join(MISSES)}, got {miss!r}")
        return names, aims, miss

    def _batch(self, effector: str, g: np.ndarray, names: list[str], refine: bool, start: dict[str, float] | None,
               miss: str, aims: list[np.ndarray | None], deadline: float | None) -> list[Answer]:
        """select_many for goals (N, d), N > 1: one tree lookup per strategy for the whole batch."""
        hits = np.stack([self.atlas.maps[n].contains(g, self.policy) for n in names])
        chosen = np.where(hits.any(axis=0), hits.argmax(axis=0), -1)
        nearest: dict[int, tuple[int, np.ndarray] | None] = {}
        for k in np.unique(chosen[chosen >= 0]):  # one k-d tree query per chosen strategy
            sel = np.nonzero(chosen == k)[0]
            found = self.stored.nearest(names[k], g[sel])
            for m, i in enumerate(sel):
                nearest[int(i)] = None if found is None else (int(found[0][m]), found[1][m])
        # Without a `from` (whose omitted joints each goal's stored posture fills in), every refinement is made ahead
        # in one evaluate call per strategy and pass; with one, goal by goal.
        batched = refine and start is None
        passes = Passes(self.refiner, self.stored, self.oracles.limits, self.handover)
        done, unrefined = (passes.run(g, names, hits, nearest, aims, deadline) if batched
                           else ([None] * len(g), None))
        out = []
        for n_goal in range(len(g)):
            # With a deadline, each goal is refined only while there is time.
            out_of_time = (bool(unrefined[n_goal]) if unrefined is not None
                           else refine and deadline is not None and time.perf_counter() > deadline)
            answer = self._answer(effector, g[n_goal], [n for j, n in enumerate(names) if hits[j, n_goal]],
                                  nearest.get(n_goal),
                                  refine and not out_of_time, time.perf_counter(), start, miss, aims[n_goal],
                                  done[n_goal])
            out.append(timed_out(answer, out_of_time))
        return out

    def _answer(self, effector: str, goal: np.ndarray, hits: list[str], nearest: tuple[int, np.ndarray] | None,
                refine: bool, t0: float,
                start: dict[str, float] | None = None, miss: str = MISS, aim: np.ndarray | None = None,
                done: Prefetched | None = None) -> Answer:
        """The answer for one goal, given the strategies that hold it (by priority) and the chosen one's nearest
        stored vertex (``done``: the refinements already made for it, by strategy; see :mod:`reach.answers.passes`)."""
        point = tuple(goal.tolist())
        if not hits:
            return Answer(effector, point, None, False, refined=NONE, seconds=time.perf_counter() - t0)
        name = hits[0]
        if nearest is None:  # its tree stores no posture
            return Answer(effector, point, name, True, tuple(hits[1:]), refined=UNAVAILABLE,
                          seconds=time.perf_counter() - t0)
        row, reached = nearest
        # The stored residual is the vertex's own; what matters is the distance to this goal
        # (unknown when the oracle cannot place its effector).
        gap = float(np.linalg.norm(goal - reached))
        residual = gap if np.isfinite(gap) else None
        q, outcome = self.atlas.maps[name].postures(row), SKIPPED
        # One budget for all of a goal's refinements (the first choice's, a fallback's, a handover's): the budget is
        # the query's (each had its own, and a query that fell back or handed over took two to four budgets). A
        # strategy's solvers are built before it refines, outside its budget (a server's at warm-up; `reach query`
        # builds them when a strategy is first asked: only the first choice's, unless it falls back or hands over,
        # where building every holding strategy's took 1.2 s of a fresh query's 2 s).
        purse = Purse(self.refiner.goal_budget(aim))
        if refine:
            q, residual, outcome = self.refiner.refine(name, goal, q, residual, start, aim, done, purse)
        found, others, handover = self._passed_on(goal, hits, q, outcome, refine, start, aim, done, purse)
        if found is not None:
            name, q, residual, outcome, row = found
        elif aim is not None and outcome != REFINED:
            # A stored posture holds no goal's orientation: what no refinement reached with it is unreachable.
            return Answer(effector, point, None, False, refined=outcome, seconds=time.perf_counter() - t0)
        elif outcome == FAILED and miss == "unreachable":
            # No strategy's refinement reaches the goal: not reachable, and the nearest point a stored posture
            # reaches.
            joints, pose, _ = self.stored.encoded(name, row)
            at = [float(v) for v in reached] if np.all(np.isfinite(reached)) else None
            return Answer(effector, point, None, False, refined=FAILED, seconds=time.perf_counter() - t0,
                          nearest={"strategy": name, "point": at, "distance": residual, "posture": joints,
                                   "root": pose})
        if outcome == REFINED:
            (posture, root), fragment = split_posture(self.atlas.maps[name].posture_names, q), None
        else:
            posture, root, fragment = self.stored.encoded(name, row)
        # a posture that was not refined at this goal says how near it comes
        within = residual if outcome in STORED else None
        return Answer(effector, point, name, True, tuple(others), posture, root, residual, outcome,
                      time.perf_counter() - t0, handover, within, None, fragment, self.stored.index_of(name, row),
                      self.oracles.landing(name, q))

    def _passed_on(self, goal: np.ndarray, hits: list[str], q: np.ndarray, outcome: str, refine: bool,
                   start: dict[str, float] | None, aim: np.ndarray | None, done: Prefetched | None,
                   purse: Purse) -> tuple[Found | None, list[str], dict[str, Any] | None]:
        """The strategy that answers instead of the first choice (None: none does), the strategies left as
        alternatives, and the handover (None: none)."""
        name, others = hits[0], hits[1:]
        if outcome == FAILED:
            # The IK says this strategy does not reach the exact goal (its tree said so from a coarse cell): the next
            # strategy by priority that does answers; else this one's stored posture.
            found = self._first_answer(goal, others, refine, start, aim=aim, done=done, purse=purse)
            return found, others if found is None else others[others.index(found.name) + 1 :], None
        near = self.handover and others and outcome in (REFINED, SKIPPED)
        limits = self.oracles.limits(name, q, self.handover) if near else []
        if limits:
            found = self._first_answer(goal, others, refine, start, below=len(limits), aim=aim, done=done,
                                       purse=purse)
            if found is not None:
                # the strategy passed over stays an alternative
                return found, [h for h in hits if h != found.name], {"from": name, "limits": limits}
        return None, others, None

    def probe(self, effector: str, goal: np.ndarray, restarts: int = 8) -> Answer | None:
        """For a goal no tree holds: the first strategy of the effector, by priority, whose thorough solve (its
        ``"referee"`` variant, ``restarts`` random starts besides its stored posture nearest the goal) reaches it, or
        None. Offline (``reach evaluate``): a coarse tree beside a thin obstacle (a counter's top) misses goals a
        posture reaches; the server never probes."""
        t0 = time.perf_counter()
        goal = np.asarray(goal, float)
        for name in self.strategies_for(effector):
            tree = self.atlas.maps[name]
            nearest = self.stored.nearest_row(name, goal.tolist())
            hint = None if nearest is None else tree.postures(nearest[0])[None]
            meta = tree.meta
            oracle = OracleSpec.from_dict(meta["oracle"]).create()
            thorough = oracle.variant("referee", restarts=restarts) if isinstance(oracle, Tunable) else oracle
            v = thorough.evaluate(Goals(goal[None], seeds=hint))
            if v.reachable[0] and v.posture is not None:
                posture, root = split_posture(tree.posture_names, v.posture[0])
                return Answer(effector, tuple(goal.tolist()), name, True, (), posture, root, float(v.residual[0]),
                              REFINED, time.perf_counter() - t0)
        return None

    def _first_answer(self, goal: np.ndarray, names: list[str], refine: bool, start: dict[str, float] | None,
                      below: int | None = None, aim: np.ndarray | None = None, done: Prefetched | None = None,
                      purse: Purse | None = None) -> Found | None:
        """The first of names (by priority) whose refinement reaches the goal (without refinement: whose tree
        holds a posture) and, given ``below``, with fewer joints near their limits: its name, posture,
        residual, refinement outcome and nearest stored row; None if none does (or, given ``below``, the time runs
        out)."""
        point = goal.tolist()
        for name in names:
            tree = self.atlas.maps[name]
            nearest = self.stored.nearest_row(name, point)
            if nearest is None:
                continue
            row, reached = nearest
            q: np.ndarray = tree.postures(row)
            gap = float(np.linalg.norm(goal - reached))
            residual: float | None = gap if np.isfinite(gap) else None
            outcome = SKIPPED
            if refine:
                q, residual, outcome = self.refiner.refine(name, goal, q, residual, start, aim, done, purse)
                if outcome == TIMEOUT:  # out of budget: no further strategy is tried
                    # A handover keeps the answer it had; a failed goal is answered by this strategy's
                    # stored posture, marked timeout: its tree holds the goal and nothing said otherwise.
                    return None if below is not None else Found(name, q, residual, outcome, row)
                if outcome != REFINED:
                    continue
            if below is None or len(self.oracles.limits(name, q, self.handover)) < below:
                return Found(name, q, residual, outcome, row)
        return None

    def select(self, effector: str, goal: np.ndarray, refine: bool | None = None, start: dict[str, float] | None = None,
               miss: str | None = None, orientation: np.ndarray | None = None) -> Answer:
        """Choose a strategy for one goal [m] (``start``, ``miss``, ``orientation``: see :meth:`select_many`)."""
        return self.select_many(effector, np.asarray(goal, dtype=float).reshape(1, -1), refine, start, miss,
                                orientation)[0]
