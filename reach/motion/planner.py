"""Reach motion: a timed, collision-free motion from the character's posture now to the selector's answer.

The paper leaves "the timing of motion in order to get more smooth and
realistic reaching animations ... an interpolation scheme ... storing
postural data in each reachable node of the tree" as future work (section
6). :class:`Planner` does it in four steps:

1. **The end posture** is the selector's answer for the goal, refined from
   the start posture (the query's ``from``): the strategy is chosen as a
   query chooses it (priority, handover, answers that hold).
2. **The path** interpolates the start and end postures on the body's own
   configuration space (the oracle's :class:`~oracles.protocol.Moving`
   capability: a floating root on SE(3)), so the hand's path curves as
   people's do rather than following a straight line (Faraway 1997, "Regression
   analysis for a functional response", Technometrics 39(3):254-261, fitted
   reach trajectories). Where a frame breaks a hard task (a collision, a
   foot that drifts, the balance), the oracle's ``hold`` moves it to the
   nearest posture that keeps the hand where it was and every hard task;
   where that fails, the path is routed through the postures stored at the
   tree's reachable vertices (the paper's stored postural data): a shortest
   path over neighbouring vertices in posture distance, edges checked
   lazily, then shortened by dropping every waypoint a direct segment can
   skip, its corners rounded (quadratic Bezier curves on the configuration
   space) where the rounded frames can be held.
3. **The duration** follows MTM-1 (Maynard, Stegemerten & Schwab 1948,
   Methods-Time Measurement, McGraw-Hill; the MTM Association's MTM-1 data
   card): the reach table's case A (an object in a fixed location) for the
   distance the hand travels, plus a body motion when the body takes part:
   a stoop or bend (B/S, 29.0 TMU) when the pelvis drops or tilts, a foot
   motion (FM, 8.5 TMU) when it rises onto the toes. MTM-1 counts them one
   after the other; here they share the frames, as a person's overlap.
4. **The timing** is minimum jerk (Flash & Hogan 1985, J Neurosci
   5(7):1688-1703) along the hand's path: the share of the path covered
   (the hand's, with a tenth of the posture's) is s(t) = 10 u^3 - 15 u^4 +
   6 u^5, u = t / T, so the hand's speed is bell-shaped with its peak near
   the middle of the motion.

Frames are in the atlas's world frame: metres, radians, the model's joint names.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from oracles.protocol import Settling, Stepping, Transiting
from reach.answers.answer import posture_vector, split_posture
from reach.answers.select import Selector
from reach.errors import InputError, ReachError
from reach.maps.graph import REACH, MotionGraph, graph_of
from reach.maps.tree import VATree
from reach.motion.paths import Body, along, held, largest_step, reaches, rounded, segment, start_of

TMU = 0.036  # [s] one time measurement unit, 0.00001 h (MTM-1 data card)
INCH = 0.0254  # [m]
# MTM-1 Reach, case A (to an object in a fixed location): TMU by the distance the hand moves [in] (MTM-1 data card).
REACH_A = ((0.0, 0.0), (0.75, 2.0), (1, 2.5), (2, 4.0), (3, 5.3), (4, 6.1), (5, 6.5), (6, 7.0), (7, 7.4), (8, 7.9),
           (9, 8.3),
           (10, 8.7), (12, 9.6), (14, 10.5), (16, 11.4), (18, 12.3), (20, 13.1), (22, 14.0), (24, 14.9), (26, 15.8),
           (28, 16.7), (30, 17.5))
PAST_30 = 0.4  # TMU per inch past 30 in (same table)
STOOP = 29.0  # TMU: bend, stoop or kneel on one knee (B, S, KOK; MTM-1 body motions)
FOOT = 8.5  # TMU: foot motion pivoted at the ankle (FM), the MTM-1 element nearest a rise onto the toes
# TMU: one pace of walking (W-P, MTM-1 body motions; as quoted, the card not read here): a step's weight shift and
# swing, 0.54 s, about a walking step's time (a swing of about 0.4 s in a gait cycle of 1.0-1.1 s: Perry & Burnfield
# 2010, *Gait Analysis*, 2nd ed., ch. 1; not read in its source here)
PACE = 15.0
STEP_MOVES = 0.01  # [m] an end posture whose stepping foot lies farther than this from where it stood takes a step
DROP = 0.10  # [m] a pelvis lowered this much stoops or crouches (a modelling choice: a knee bend of about 30 deg)
TILT = math.radians(30.0)  # [rad] a pelvis tilted this much bends (a modelling choice)
LIFT = 0.01  # [m] a pelvis raised this much rises onto the toes (a modelling choice)
RATE = 30.0  # [Hz] frames per second by default
MAX_RATE = 240.0  # [Hz]
MAX_DURATION = 20.0  # [s] an explicit duration at most this
CHECK_FRAMES = 16  # frames checked between two readings of the deadline (about 2 ms of the whole body's checks)
# [s] the end posture's refinement budget: a motion is not a 50 Hz query, and a stored posture stops short. A budget of
# work (oracles.ik.budget.Meter): a whole-body refinement's lower tasks are charged about 0.19 s, and a handover starts
# with a quarter of the budget left; at 0.25 s none did, and the demo's reach behind the body to (-0.42, 0.25, 0.59)
# kept a posture with nine joints at their limits (the idle arm raised overhead) and found no motion
# (bench/motion.py).
BUDGET = 0.4
# [rad or m] a frame that holding moves more than this (any coordinate) leaves the path: it is routed instead
HOLD_STEP = 0.25
# a held path whose largest step between frames is this many times the unheld path's has a jump: it is routed instead
JUMP = 2.0
# [rad or m] a routed segment's checked posture that holding moves more than this would jump between frames
EDGE_HOLD = 0.05
NEIGHBOURS = 10  # stored vertices each one links to in the routing graph
ENTRIES = 12  # stored vertices tried as the route's first and last waypoints
ROUNDS = 100  # shortest paths tried before the route is given up
FINE = 128  # postures sampled along a path to measure the hand's path and time it
POSTURE_SHARE = 0.1  # the posture path's share in a motion's progress (a modelling choice: the rest is the hand's path)
REACHED, NEAREST = "reached", "nearest"
# How a motion's end posture was found: the stored answer settled onto the goal by a few local steps, or the
# selector's refinement (a solve), when settling found none or the motion starts from a given posture.
SETTLED, REFINED = "settled", "refined"
# How a motion's frames were found: through a stored posture whose motion from the reference was checked at build time
# (reach.maps.graph; the last stretch checked now), or planned now (every frame checked, broken ones held or routed).
GRAPH, PLANNED = "graph", "planned"
LAST_STRETCHES = 3  # stored postures near the end tried as the graph's last waypoint
JOINS = 4  # stored postures near a start that is not the reference tried as the graph's first waypoint
SKIPS = 6  # direct segments a graph's path tries to skip waypoints by
MOTION_MISSES = ("nearest", "error")


def minimum_jerk(u: np.ndarray) -> np.ndarray:
    """Flash & Hogan's minimum-jerk path parameter at normalised times u in [0, 1]."""
    u = np.clip(np.asarray(u, float), 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)  # type: ignore[no-any-return]


@dataclass(frozen=True)
class Timing:
    """The movement-time law's coefficients (MTM-1 by default; see the module docstring).

    Attributes:
        tmu: Seconds per TMU; a slower or faster performer scales every element.
        past_30: TMU per inch of reach past 30 in.
        stoop: TMU added when the pelvis drops by ``drop`` or tilts by ``tilt``.
        foot: TMU added when the pelvis rises by ``lift`` (onto the toes).
        drop: [m] see ``stoop``.
        tilt: [rad] see ``stoop``.
        lift: [m] see ``foot``.
        duration: [s] the motion's duration, instead of the law's (None: the law's).
    """

    tmu: float = TMU
    past_30: float = PAST_30
    stoop: float = STOOP
    foot: float = FOOT
    drop: float = DROP
    tilt: float = TILT
    lift: float = LIFT
    duration: float | None = None

    @classmethod
    def from_dict(cls, raw: dict[str, Any] | None, where: str = "timing") -> Timing:
        """Overrides of the defaults, each a finite number >= 0 (``duration`` > 0, at most ``MAX_DURATION``)."""
        if raw is None:
            return cls()
        if not isinstance(raw, dict):
            raise InputError(where, f"expected a mapping of coefficients, got {type(raw).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(raw) - known)
        if unknown:
            raise InputError(where, f"unknown keys {unknown}; expected some of {', '.join(sorted(known))}")
        for k, v in raw.items():
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
            if k == "duration":
                ok = ok and 0 < v <= MAX_DURATION
            if not ok:
                limit = f"a number of seconds in (0, {MAX_DURATION:g}]" if k == "duration" else "a finite number >= 0"
                raise InputError(f"{where}.{k}", f"expected {limit}, got {v!r}")
        timing = cls(**{k: float(v) for k, v in raw.items()})
        # A reach of an inch, the shortest any motion asks, timed by these coefficients: known before any planning, a
        # request that cannot fit is refused before it is queued (tmu 1e300 was refused by the worker seconds later).
        shortest = timing.duration if timing.duration is not None else timing.reach_tmu(INCH) * timing.tmu
        if shortest > MAX_DURATION:
            raise InputError(where, f"these coefficients time a reach of an inch at {shortest:.3g} s; a motion lasts "
                                    f"at most {MAX_DURATION:g} s")
        return timing

    def reach_tmu(self, distance: float) -> float:
        """MTM-1 R-A time [TMU] of a reach whose hand travels ``distance`` [m]."""
        inches = distance / INCH
        if inches > 30.0:
            return REACH_A[-1][1] + self.past_30 * (inches - 30.0)
        d, t = zip(*REACH_A, strict=True)
        return float(np.interp(inches, d, t))

    def seconds(self, hand_path: float, root_drop: float, root_tilt: float,
                root_lift: float) -> tuple[float, dict[str, float]]:
        """The duration [s] and its parts [TMU]: the reach, and the body motions the root's excursion calls for."""
        if self.duration is not None:
            return self.duration, {}
        parts = {"reach": self.reach_tmu(hand_path)}
        if root_drop >= self.drop or root_tilt >= self.tilt:
            parts["stoop"] = self.stoop
        elif root_lift >= self.lift:
            parts["foot"] = self.foot
        return sum(parts.values()) * self.tmu, parts


class MotionError(ReachError):
    """No motion could be planned: the goal is out of reach (with ``miss="error"``), or no path holds every task."""

    def __init__(self, message: str, code: str = "no_motion") -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Motion:
    """A planned reach motion.

    Attributes:
        effector: The effector.
        goal: The goal [m].
        strategy: The strategy whose end posture it reaches.
        outcome: ``reached`` (the last frame reaches the goal, by the verdict's own check), or ``nearest``
            (the goal is out of reach; the motion goes to the nearest point a
            stored posture reaches).
        point: Where the effector ends [m].
        names: The posture's coordinate names (``root_x`` ... ``root_qw`` for
            a floating base, then the joints).
        rate: [Hz] frames per second: ``times`` are k / rate, the law's duration rounded up to a whole frame.
        times: (T,) [s] from 0 to the duration.
        postures: (T, nq) one posture per frame.
        path: (T, 3) [m] the effector's position at each frame.
        refined: The end posture's refinement outcome, as a query's answer says it (``ok``, or ``timeout`` /
            ``failed`` ... when the end posture is the stored one, ``within`` of the goal).
        within: [m] how far short of the goal the end posture stops when it was not solved at the goal; else None.
        waypoints: Stored postures the path goes through (0: direct).
        held: Frames moved to hold every hard task (a foot, the balance, a collision).
        parts: The duration's parts [TMU] (empty for an explicit duration).
        end: How the end posture was found: ``settled`` (the stored posture moved onto the goal by a few local
            steps) or ``refined`` (the selector's refinement, a solve).
        route: ``graph`` (through a stored posture whose motion from the reference was checked at build time; the
            last stretch checked now) or ``planned`` (every frame checked now, broken ones held or routed).
    """

    effector: str
    goal: tuple[float, ...]
    strategy: str
    outcome: str
    point: tuple[float, ...]
    names: tuple[str, ...]
    rate: float
    times: np.ndarray
    postures: np.ndarray
    path: np.ndarray
    refined: str
    within: float | None
    waypoints: int
    held: int
    parts: dict[str, float]
    end: str = REFINED
    route: str = PLANNED

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def frames(self) -> list[dict[str, Any]]:
        """One dict per frame: ``t`` [s], ``posture`` (joint -> rad or m), ``root`` (position, quaternion
        [qx, qy, qz, qw]) or None, ``effector`` [m]."""
        out = []
        for t, q, p in zip(self.times, self.postures, self.path, strict=True):
            joints, root = split_posture(self.names, q)
            out.append({"t": round(float(t), 6), "posture": joints, "root": root, "effector": [float(v) for v in p]})
        return out

    def summary(self) -> dict[str, Any]:
        """Everything but the frames."""
        return {"effector": self.effector, "goal": list(self.goal), "strategy": self.strategy, "outcome": self.outcome,
                "point": list(self.point), "refined": self.refined, "within": self.within, "duration": self.duration,
                "rate": self.rate, "frame_count": len(self.times), "waypoints": self.waypoints, "held": self.held,
                "timing_tmu": self.parts, "end": self.end, "route": self.route}

    def to_dict(self) -> dict[str, Any]:
        return {**self.summary(), "frames": self.frames()}

    def and_back(self) -> Motion:
        """This motion, then the same frames in reverse to the first posture (a squat descends, reaches and rises),
        as long again; ``parts`` gains ``return`` (the way there's total, TMU)."""
        back = slice(-2, None, -1)  # the end posture is not repeated
        times = np.concatenate([self.times, 2.0 * self.times[-1] - self.times[back]])
        parts = {**self.parts, "return": round(sum(self.parts.values()), 6)} if self.parts else {}
        return replace(self, times=times, postures=np.vstack([self.postures, self.postures[back]]),
                       path=np.vstack([self.path, self.path[back]]), parts=parts)


class Planner:
    """Plans reach motions on a selector's atlas (see the module docstring).

    Args:
        selector: The selector whose answers end the motions; its strategies'
            oracles must offer :class:`~oracles.protocol.Moving`.
        budget: [s] the end posture's refinement budget.
        graph: Use the strategies' motion graphs (:mod:`reach.maps.graph`) where the atlas has them.
    """

    def __init__(self, selector: Selector, budget: float = BUDGET, graph: bool = True) -> None:
        self.served = selector  # the selector given (a server compares it after a reload)
        self.selector = selector.with_budget(budget)
        self.use_graph = graph
        self._graphs: dict[str, tuple[cKDTree, np.ndarray, np.ndarray, csr_matrix]] = {}
        # each strategy's motion graph as a weighted graph, and its shortest paths from the reference (see _routes)
        self._motion_graphs: dict[str, tuple[csr_matrix, tuple[np.ndarray, np.ndarray]] | None] = {}
        self._deadline = math.inf  # time.perf_counter() past which the plan in progress stops (see plan)
        # Frames that broke a task and were held: by the batched hold, or one at a time (its fallback: how often is
        # a figure of bench/motion.py), since this planner was made.
        self.holds = {"batch": 0, "alone": 0}

    def plan(self, effector: str, goal: np.ndarray | list[float], start: dict[str, float] | None = None, *,
             rate: float = RATE,
             timing: Timing | None = None, miss: str = "nearest", deadline: float | None = None,
             back: bool = False) -> Motion:
        """The motion from ``start`` (joint name -> rad or m, ``root_*`` for the base; the reference posture
        where omitted) to the answer for ``goal`` [m], at ``rate`` frames per second.

        ``deadline``: ``time.perf_counter()`` past which planning stops (a server's request deadline): the
        frames are checked one at a time, so it stops within one hold of a frame. ``back``: then back to the start
        (:meth:`Motion.and_back`).

        Raises InputError for a bad goal, start posture, rate or ``miss``, and
        MotionError when the goal is out of reach (``miss="error"``), no
        path holds every task, or the deadline passed (code ``timeout``).
        """
        self._deadline = math.inf if deadline is None else float(deadline)
        try:
            motion = self._plan(effector, goal, start, rate, timing, miss)
            return motion.and_back() if back else motion
        finally:
            self._deadline = math.inf

    def _plan(self, effector: str, goal: np.ndarray | list[float], start: dict[str, float] | None, rate: float,
              timing: Timing | None, miss: str) -> Motion:
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and 1.0 <= rate <= MAX_RATE):
            raise InputError("rate", f"expected frames per second in [1, {MAX_RATE:g}], got {rate!r}")
        if miss not in MOTION_MISSES:
            raise InputError("miss", f"expected one of {', '.join(MOTION_MISSES)}, got {miss!r}")
        timing = timing or Timing()
        g = np.asarray(goal, float).reshape(1, -1)
        names = [n for n in self.selector.check_goals(effector, g, start) if self.selector.atlas.maps[n].posture_names]
        if not names:
            raise MotionError(f"the strategies of {effector!r} store no postures: there is no body to move",
                              "no_motion")
        answer, settled = self._settled(effector, g[0]) if start is None else (None, None)
        if answer is None:
            answer = self.selector.select(effector, g[0], True, start=start, miss="unreachable")
        if answer.reachable:
            name, outcome, q1 = answer.strategy, REACHED, None
        elif miss == "error":
            raise MotionError(f"{effector} cannot reach {g[0].tolist()}: no strategy's posture reaches it",
                              "unreachable")
        elif answer.nearest is not None:
            name, outcome = answer.nearest["strategy"], NEAREST
        else:
            name, outcome = names[0], NEAREST
        assert name is not None
        oracle = self.body(name)
        tree = self.selector.atlas.maps[name]
        labels = tree.posture_names
        q0 = start_of(oracle, tree, start)
        broken = oracle.faults(q0[None])[0]
        # A start that breaks some of the strategy's tasks (a tiptoe's or squat's balance over the balls, the
        # squat's hips below the knees, from standing): the frames hold the strategy's transit twin, the end all.
        mover = oracle.transit(broken) if broken and isinstance(oracle, Transiting) else oracle
        if mover is None or (broken and mover.faults(q0[None])[0]):
            raise InputError("from", f"the start posture breaks {', '.join(broken)} for strategy {name}")
        if settled is not None:
            q1 = settled
        elif outcome == REACHED:
            q1 = posture_vector(labels, q0, answer.posture, answer.root)
        elif answer.nearest is not None:
            q1 = posture_vector(labels, q0, answer.nearest["posture"], answer.nearest["root"])
        else:
            q1 = self._nearest_stored(name, g[0])
        step = self._step(oracle, q0, q1, rate) if outcome == REACHED else None
        via = self._via_graph(name, mover, labels, q0, q1, rate, timing) if step is None and mover is oracle else None
        if via is not None:
            (postures, waypoints), held, route = via, 0, GRAPH
        else:
            postures, waypoints, held = self._path(name, mover, labels, q0 if step is None else step[-1], q1, rate,
                                                   timing)
            route = PLANNED
        if step is not None:
            # the step's frames (the foot lifted, carried and set down), then the reach from where it landed
            frames, reach_times, parts = postures
            lead = len(step) - 1
            postures = (np.vstack([step[:-1], frames]),
                        np.concatenate([np.arange(lead) / rate, reach_times + lead / rate]), {"step": PACE, **parts})
        times = postures[1]
        path = np.asarray(oracle.effector_positions(postures[0]))
        if outcome == REACHED and not reaches(oracle, g[0], postures[0][-1], path[-1]):
            # honest: held frames (or a stored end posture) that stop short of the goal did not reach it
            outcome = NEAREST
        within = (None if settled is not None else answer.within) if outcome == REACHED else float(
            np.linalg.norm(path[-1] - g[0]))
        return Motion(effector, tuple(g[0].tolist()), name, outcome, tuple(path[-1].tolist()), labels, float(rate),
                      times, postures[0], path, "ok" if settled is not None else answer.refined, within, waypoints,
                      held, postures[2], SETTLED if settled is not None else REFINED, route)

    # -- the motion graph ------------------------------------------------------
    def _via_graph(self, name: str, oracle: Body, names: tuple[str, ...], q0: np.ndarray, q1: np.ndarray,
                   rate: float, timing: Timing) -> tuple[tuple[np.ndarray, np.ndarray, dict[str, float]], int] | None:
        """Frames along the strategy's motion graph (:mod:`reach.maps.graph`) and the stored postures they pass: from
        the start (the reference, the graph's home, or joined to a stored posture near it by a segment checked now),
        the shortest path over motions checked at build time to a stored posture near the end, then to the end;
        shortened where a direct segment holds, timed, and every frame checked. None when the strategy has no graph
        or no such path holds."""
        routes = self._routes(name)
        if routes is None:
            return None
        adjacency, home = routes
        kd, postures, _, _ = self._graph(name)
        joined = (len(postures) if np.array_equal(q0, np.asarray(oracle.reference_posture(), float))
                  else self._join(oracle, kd, postures, q0))
        if joined is None:
            return None
        entry = joined
        dist, pred = home if entry == len(postures) else dijkstra(adjacency, indices=entry, return_predecessors=True)
        for i in self._exits(oracle, kd, postures, q1, dist):
            self._in_time()
            chain = [i]
            while chain[-1] != entry:
                chain.append(int(pred[chain[-1]]))
            path = [q0, *(postures[k] for k in reversed(chain) if k < len(postures)), q1]
            # Through several stored postures, shortened first (the hand's path zigzags between them otherwise);
            # through one, as it is (it lies beside the end: a detour of a few cm). Each corner of a body on a fixed
            # root rounded first: turned at once, the hand's speed dropped by a third mid-stride at the stored posture
            # (docs/figures/motion_arm.png). A standing body's are not: its rounded frames, checked and then checked
            # again unrounded, doubled the whole body's median (27 -> 51 ms, bench/motion.py).
            shortened = self._skipped(oracle, path) if len(path) > 3 else path
            root = [k for k, n in enumerate(names) if n.startswith("root_")]
            round_first = len(shortened) > 2 and all(np.array_equal(w[root], q0[root]) for w in shortened)
            tries = ([rounded(oracle, shortened)] if round_first else []) + [shortened]
            for waypoints in tries + ([path] if len(shortened) < len(path) else []):
                frames, times, parts = self._timed(oracle, names, waypoints, rate, timing)
                # Every frame checked: the build's samples, ``STEP`` apart, miss brushes between them (a frame of a
                # whole-body motion in 30 broke the balance or a collision where every sample held).
                if not any(any(f) for f in self._faults(oracle, frames[1:])):
                    return (frames, times, parts), (len(path) if waypoints is path else len(shortened)) - 2
        return None

    def _exits(self, oracle: Body, kd: cKDTree, postures: np.ndarray, q1: np.ndarray,
               dist: np.ndarray) -> Iterator[int]:
        """Stored postures near the end that the graph reaches (finite ``dist``), no more than the graph's edges'
        ``REACH`` from it in posture, whose segment to the end holds (checked at postures ``EDGE_STEP`` apart, one at
        a time as they are asked for); nearest in posture first, at most ``LAST_STRETCHES``."""
        goal = np.asarray(oracle.effector_positions(q1[None]))[0]
        _, near = kd.query(goal, k=min(ENTRIES, len(postures)))
        gap = {i: float(np.linalg.norm(postures[i] - q1)) for i in np.atleast_1d(near).tolist()
               if i < len(postures) and np.isfinite(dist[i])}
        linked = (i for i in sorted(gap, key=gap.__getitem__)
                  if gap[i] <= REACH and self._holds(oracle, postures[i], q1))
        yield from itertools.islice(linked, LAST_STRETCHES)

    def _join(self, oracle: Body, kd: cKDTree, postures: np.ndarray, q0: np.ndarray) -> int | None:
        """A stored posture near a start that is not the reference, linked to it by a segment that holds (checked
        now, at postures ``EDGE_STEP`` apart): the nearest in posture of the ``ENTRIES`` nearest by the effector,
        trying at most ``JOINS``; None when none does."""
        start = np.asarray(oracle.effector_positions(q0[None]))[0]
        _, near = kd.query(start, k=min(ENTRIES, len(postures)))
        near = sorted((i for i in np.atleast_1d(near).tolist() if i < len(postures)),
                      key=lambda i: float(np.linalg.norm(postures[i] - q0)))
        return next((i for i in near[:JOINS] if self._holds(oracle, q0, postures[i])), None)

    def _skipped(self, oracle: Body, waypoints: list[np.ndarray]) -> list[np.ndarray]:
        """The waypoints without those a direct segment between their neighbours can skip (it holds, checked now at
        postures ``EDGE_STEP`` apart), farthest first, at most ``SKIPS`` segments checked."""
        out, i, tries = [waypoints[0]], 0, 0
        while i < len(waypoints) - 1:
            j = i + 1
            for k in range(len(waypoints) - 1, i + 1, -1):
                if tries == SKIPS:
                    break
                tries += 1
                if self._holds(oracle, waypoints[i], waypoints[k]):
                    j = k
                    break
            out.append(waypoints[j])
            i = j
        return out

    def _holds(self, oracle: Body, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether the direct segment a -> b holds every task at postures ``EDGE_STEP`` apart (no hold)."""
        return not any(any(f) for f in self._faults(oracle, segment(oracle, a, b)[1:-1]))

    def _routes(self, name: str) -> tuple[csr_matrix, tuple[np.ndarray, np.ndarray]] | None:
        """The strategy's motion graph as a weighted graph (posture distance) over its stored postures and the
        reference (the last node), with the shortest paths from the reference; None without a graph."""
        if name not in self._motion_graphs:
            graph = self._stored_graph(name) if self.use_graph else None
            if graph is None:
                self._motion_graphs[name] = None
            else:
                _, postures, _, _ = self._graph(name)
                oracle = self.body(name)
                n = len(postures)
                home = np.nonzero(graph.home)[0]
                a = np.concatenate([graph.edges[:, 0], home]).astype(np.int64)
                b = np.concatenate([graph.edges[:, 1], np.full(len(home), n)]).astype(np.int64)
                ends = np.vstack([postures, np.asarray(oracle.reference_posture(), float)[None]])
                w = np.linalg.norm(ends[a] - ends[b], axis=1) + 1e-9
                adjacency = csr_matrix((np.concatenate([w, w]), (np.concatenate([a, b]), np.concatenate([b, a]))),
                                       shape=(n + 1, n + 1))
                dist, pred = dijkstra(adjacency, indices=n, return_predecessors=True)
                self._motion_graphs[name] = (adjacency, (dist, pred))
        return self._motion_graphs[name]

    def _stored_graph(self, name: str) -> MotionGraph | None:
        """The strategy's motion graph stored beside its tree, when it was made for that tree; else None."""
        tree = self.selector.atlas.maps[name]
        # a graph missing, stale or unreadable: the planner plans every motion as without one
        return graph_of(self.selector.atlas.path / f"{name}.npz", tree)[0] if isinstance(tree, VATree) else None

    def _settled(self, effector: str, goal: np.ndarray) -> tuple[Any, np.ndarray | None]:
        """The stored answer for the goal and an end posture settled onto the goal by local steps
        (:class:`~oracles.protocol.Settling`), or (None, None) when there is none: the selector then refines it.
        The strategies whose trees hold the goal are tried by priority, as a refinement hands over: the first
        that settles answers (one whose settling fails at its tree's boundary is mostly one whose refinement fails
        too: 5 of the demo's 40 arm and whole-body goals, all handed over, bench/motion.py)."""
        answer = self.selector.select(effector, goal, False, miss="unreachable")
        if not answer.reachable or answer.strategy is None:
            return None, None
        names = self.selector.strategies_for(effector)
        holding = [n for n in names[names.index(answer.strategy):]
                   if n == answer.strategy or self.selector.atlas.maps[n].contains_one(goal.tolist(),
                                                                                      self.selector.policy)]
        for name in holding:
            oracle = self.body(name)
            if not isinstance(oracle, Settling):
                continue
            seeds = self._homeward(name, goal)
            if name == answer.strategy:
                # the stored answer's own posture last: the motion graph's lead somewhere
                reference = np.array(oracle.reference_posture(), dtype=float)
                seeds.append(posture_vector(self.selector.atlas.maps[name].posture_names, reference, answer.posture,
                                            answer.root))
            for seed in seeds:
                q = oracle.settle(seed, goal)
                if q is not None:
                    return replace(answer, strategy=name), q
        return None, None

    def _homeward(self, name: str, goal: np.ndarray) -> list[np.ndarray]:
        """The stored postures nearest the goal that the strategy's motion graph reaches from the reference posture
        (at most ``LAST_STRETCHES``), nearest first; none without a graph."""
        routes = self._routes(name)
        if routes is None:
            return []
        dist = routes[1][0]
        kd, postures, _, _ = self._graph(name)
        _, near = kd.query(goal, k=min(ENTRIES, len(postures)))
        return [postures[i] for i in np.atleast_1d(near).tolist() if i < len(postures) and np.isfinite(dist[i])][
            :LAST_STRETCHES]

    @staticmethod
    def _step(oracle: Body, q0: np.ndarray, q1: np.ndarray, rate: float) -> np.ndarray | None:
        """A step's frames when the end posture's stepping foot left where it stood (its oracle's
        :class:`~oracles.protocol.Stepping`): the weight shifted, the foot lifted, carried and set down, one pace of
        MTM-1 long (``PACE``); else None. Raises MotionError when no such frames are found."""
        if not isinstance(oracle, Stepping):
            return None
        landing, stood = oracle.landing(q1), oracle.landing(q0)
        if landing is None or stood is None:
            return None
        if float(np.linalg.norm(np.subtract(landing["position"], stood["position"]))) <= STEP_MOVES:
            return None
        frames = oracle.swing(q0, q1, max(3, int(math.ceil(PACE * TMU * rate - 1e-9))))
        if frames is None:
            raise MotionError(f"no step found that sets {landing['foot']} down at {landing['position']} with the "
                              "weight over the other foot", "no_motion")
        return frames

    # -- the path -----------------------------------------------------------
    def _path(self, name: str, oracle: Body, names: tuple[str, ...], q0: np.ndarray, q1: np.ndarray, rate: float,
              timing: Timing) -> tuple[tuple[np.ndarray, np.ndarray, dict[str, float]], int, int]:
        """Frames (postures, times, the duration's parts), the stored postures routed through and the frames held:
        the direct path if its frames can be held, else the route through stored postures."""
        for routed in (False, True):
            route = self._route(name, oracle, q0, q1) if routed else [q0, q1]
            # Timed by the hand's path first; by the posture's path when that cannot be held (the body then moves
            # most where the hand moves least, which holding may not follow).
            for waypoints in ([rounded(oracle, route)] if len(route) > 2 else []) + [route]:
                for timed in self._timings(oracle, names, waypoints, rate, timing):
                    held = self._hold_path(oracle, timed[0])
                    if held is not None:
                        return (held[0], timed[1], timed[2]), len(route) - 2, held[1]
        raise MotionError(f"no motion of strategy {name} found that holds every task at every frame")

    def _timed(self, oracle: Body, names: tuple[str, ...], waypoints: list[np.ndarray], rate: float,
               timing: Timing) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
        """Frames k / rate apart along the waypoints, timed by minimum jerk along the hand's path, and the duration's
        parts."""
        return next(self._timings(oracle, names, waypoints, rate, timing))

    def _timings(self, oracle: Body, names: tuple[str, ...], waypoints: list[np.ndarray], rate: float,
                 timing: Timing) -> Iterator[tuple[np.ndarray, np.ndarray, dict[str, float]]]:
        """The frames of :meth:`_timed`, then the same path's frames timed by minimum jerk along the posture's path
        alone, both from one sampling of the path."""
        # The hand's path length and the root's excursion, on a fine sampling of the path.
        sampled = np.linspace(0.0, 1.0, FINE)
        fine = along(oracle, waypoints, sampled, exact=False)
        hand = np.asarray(oracle.effector_positions(fine))
        steps = np.linalg.norm(np.diff(hand, axis=0), axis=1)
        drop = tilt = lift = 0.0
        if "root_z" in names and "root_qx" in names:
            z, quat = fine[:, names.index("root_z")], fine[:, names.index("root_qx") : names.index("root_qx") + 4]
            drop, lift = max(0.0, float(z[0] - z.min())), max(0.0, float(z.max() - z[0]))
            dots = np.abs(quat @ quat[0]) / np.linalg.norm(quat, axis=1) / np.linalg.norm(quat[0])
            tilt = float(2.0 * np.arccos(np.clip(dots.min(), -1.0, 1.0)))
        seconds, parts = timing.seconds(float(steps.sum()), drop, tilt, lift)
        if not math.isfinite(seconds) or seconds > MAX_DURATION:
            # Bounded whatever the coefficients: a motion is at most MAX_DURATION x rate frames.
            raise InputError("timing", f"these coefficients time this motion at {seconds:.3g} s; a motion lasts at "
                                       f"most {MAX_DURATION:g} s")
        frames = max(1, int(math.ceil(seconds * rate - 1e-9)))  # the law's duration, rounded up to a whole frame
        times = np.arange(frames + 1) / rate
        # Minimum jerk is a law of the hand's path (Flash and Hogan 1985): progress is the share of the hand's path
        # covered, with a little of the posture's share so that a stretch where the hand stays still takes time too.
        share = minimum_jerk(times / times[-1])
        if steps.sum() > 0.0:
            covered = np.concatenate([[0.0], np.cumsum(steps)]) / steps.sum()
            progress = (1.0 - POSTURE_SHARE) * covered + POSTURE_SHARE * sampled
            yield along(oracle, waypoints, np.interp(share, progress, sampled)), times, parts
        yield along(oracle, waypoints, share), times, parts

    # -- routing through stored postures -------------------------------------
    def _graph(self, name: str) -> tuple[cKDTree, np.ndarray, np.ndarray, csr_matrix]:
        """The reachable stored vertices of a strategy: a k-d tree of their effector positions, their postures,
        those positions, and the graph linking each to its nearest, weighted by posture distance."""
        if name not in self._graphs:
            found = self.selector.atlas.maps[name].stored()
            assert found is not None  # only strategies that store postures are routed
            rows, points, postures = found
            kd = cKDTree(points)
            k = min(NEIGHBOURS + 1, len(rows))
            _, near = kd.query(points, k=k)
            near = np.asarray(near).reshape(len(rows), k)
            a = np.repeat(np.arange(len(rows)), k - 1)
            b = near[:, 1:].ravel()
            w = np.linalg.norm(postures[a] - postures[b], axis=1) + 1e-9
            graph = csr_matrix((np.concatenate([w, w]), (np.concatenate([a, b]), np.concatenate([b, a]))),
                               shape=(len(rows), len(rows)))
            self._graphs[name] = (kd, postures, points, graph)
        return self._graphs[name]

    def _route(self, name: str, oracle: Body, q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray]:
        """Waypoints from q0 to q1 through stored postures whose segments hold every task (lazily checked), then
        shortened."""
        kd, postures, _, graph = self._graph(name)
        graph = graph.tolil()
        ends = np.asarray(oracle.effector_positions(np.stack([q0, q1])))
        # The route's ends link by segments held as closely as its inner ones, or failing that as closely as frames are.
        firsts = self._entries(kd, postures, ends[0], q0, oracle, True) or self._entries(kd, postures, ends[0], q0,
            oracle, True, HOLD_STEP)
        lasts = self._entries(kd, postures, ends[1], q1, oracle, False) or self._entries(kd, postures, ends[1], q1,
            oracle, False, HOLD_STEP)
        if not firsts or not lasts:
            raise MotionError(f"no motion of strategy {name} found: no stored posture near the start or the end "
                              "links to it")
        good: set[tuple[int, int]] = set()
        for _ in range(ROUNDS):
            dist, pred = dijkstra(graph.tocsr(), indices=firsts[0], return_predecessors=True)
            last = min(lasts, key=lambda j: dist[j])
            if not np.isfinite(dist[last]):
                break
            chain = [last]
            while chain[-1] != firsts[0]:
                chain.append(int(pred[chain[-1]]))
            chain.reverse()
            broken = None
            for a, b in zip(chain[:-1], chain[1:], strict=True):
                if (a, b) not in good:
                    if not self._clear(oracle, postures[a], postures[b]):
                        broken = (a, b)
                        break
                    good.add((a, b))
            if broken is None:
                return self._shorten(oracle, [q0, *postures[chain], q1])
            graph[broken[0], broken[1]] = graph[broken[1], broken[0]] = 0.0  # lil: an explicit zero removes the edge
        raise MotionError(f"no motion of strategy {name} found through its stored postures that holds every task")

    def _entries(self, kd: cKDTree, postures: np.ndarray, point: np.ndarray, q: np.ndarray, oracle: Body, first: bool,
                 limit: float = EDGE_HOLD) -> list[int]:
        """Stored vertices near ``point`` linked to ``q`` by a segment that holds (from q when ``first``, else to it),
        nearest in posture first: one for the route's start, up to three for its end."""
        _, near = kd.query(point, k=min(ENTRIES, len(postures)))
        near = sorted(np.atleast_1d(near).tolist(), key=lambda i: float(np.linalg.norm(postures[i] - q)))
        linked = (i for i in near
                  if (self._clear(oracle, q, postures[i], limit) if first
                      else self._clear(oracle, postures[i], q, limit)))
        return list(itertools.islice(linked, 1 if first else 3))

    def _clear(self, oracle: Body, a: np.ndarray, b: np.ndarray, limit: float = EDGE_HOLD) -> bool:
        """Whether the segment a -> b holds every task at postures ``EDGE_STEP`` apart (see ``_hold_path``)."""
        # Its checked postures are farther apart than frames: a hold that passes the jump test here may fail it
        # at the frames' steps, so it may move a posture less. A check is one pass (the batch's holds, the rest one
        # at a time): the second pass, every broken posture held alone, is for a path's frames; a segment that
        # needed it is passed over (in-process, 20 goals a kind: the whole body's p99 3.5-3.7 s against 4.6-5.7,
        # the crouch's 3.9-4.0 against 4.9-7.2, no goal without a motion; bench/motion.py).
        return self._hold_path(oracle, segment(oracle, a, b), limit, once=True) is not None

    def _hold_path(self, oracle: Body, postures: np.ndarray, limit: float = HOLD_STEP,
                   once: bool = False) -> tuple[np.ndarray, int] | None:
        """The postures with each inner one that breaks a task held (and how many), or None when one cannot
        be held, or holding makes a jump: a frame moved more than ``limit``, or a step between frames
        ``JUMP`` times the largest before. ``once``: without the second pass (every broken posture held alone)."""
        broken = [k for k, f in enumerate(self._faults(oracle, postures)) if f and 0 < k < len(postures) - 1]
        if not broken:
            return postures.copy(), 0
        # The broken frames held together first, as one batch, each from itself; a frame the batch leaves unheld or
        # moves past the limit is held alone from its neighbour's correction. When that fails or the frames jump,
        # every broken frame is held one at a time (each from its neighbour's correction keeps consecutive frames alike:
        # held each on its own, 25 of 40 upper-body paths jumped somewhere).
        together = oracle.hold_many(postures[broken], self._deadline)
        # A batch's frame moved more than a jump between frames would allow is held alone too (each frame held from
        # itself, a few landed in another basin, 0.2-0.5 rad away, where their neighbours did not).
        bound = min(limit, JUMP * largest_step(postures))
        alone: list[np.ndarray | None] = [None] * len(broken)
        # (An engine without a batched hold held none: the one-at-a-time pass is the only one.)
        passes = ([*together],) if once else ([*together], alone)
        forward = None  # the last pass that held every frame but jumped
        for guesses in passes if np.isfinite(together).all(axis=1).any() else (alone,):
            out = postures.copy()
            for k, fixed in zip(broken, guesses, strict=True):
                self._in_time()
                if fixed is None or not np.all(np.isfinite(fixed)) or np.abs(fixed - postures[k]).max() > bound:
                    self.holds["alone"] += 1
                    fixed = held(oracle, postures[k], (postures[k - 1], out[k - 1]), limit)
                else:
                    self.holds["batch"] += 1
                if fixed is None:
                    break
                out[k] = fixed
            else:
                if largest_step(out) <= JUMP * largest_step(postures):
                    return out, len(broken)
                forward = out
        return None if once or forward is None else self._spliced(oracle, postures, broken, forward, limit)

    def _spliced(self, oracle: Body, postures: np.ndarray, broken: list[int], forward: np.ndarray,
                 limit: float) -> tuple[np.ndarray, int] | None:
        """The broken frames held from the path's end backwards too (each from its successor's correction), and the
        path joined from the two holds where they come nearest, or None when that still jumps. Held from its start
        alone, a path whose every frame breaks the feet drifted from its end posture (which is not held) and jumped
        to it: 0.16-0.44 rad in the last frames of 2 of 20 whole-body motions (bench/motion.py)."""
        back = postures.copy()
        for k in reversed(broken):
            self._in_time()
            self.holds["alone"] += 1
            fixed = held(oracle, postures[k], (postures[k + 1], back[k + 1]), limit)
            if fixed is None:
                return None
            back[k] = fixed
        # the last frame taken from the forward hold: where its next frame's backward hold is nearest to it
        gaps = np.abs(back[1:] - forward[:-1]).max(axis=1)
        m = int(np.argmin(gaps))
        out = np.concatenate([forward[: m + 1], back[m + 1 :]])
        return (out, len(broken)) if largest_step(out) <= JUMP * largest_step(postures) else None

    def _faults(self, oracle: Body, postures: np.ndarray) -> Iterator[list[str]]:
        """The oracle's faults of each posture, ``CHECK_FRAMES`` at a time with the deadline read between them."""
        for k in range(0, len(postures), CHECK_FRAMES):
            self._in_time()
            yield from oracle.faults(postures[k : k + CHECK_FRAMES])

    def _in_time(self) -> None:
        if time.perf_counter() > self._deadline:
            raise MotionError("the motion was not planned by its deadline", "timeout")

    def _shorten(self, oracle: Body, waypoints: list[np.ndarray]) -> list[np.ndarray]:
        """Drop every waypoint that a direct segment between its neighbours can skip (greedy, farthest first)."""
        out, i = [waypoints[0]], 0
        while i < len(waypoints) - 1:
            j = next((j for j in range(len(waypoints) - 1, i + 1, -1)
                      if self._clear(oracle, waypoints[i], waypoints[j])), i + 1)
            out.append(waypoints[j])
            i = j
        return out

    # -- postures -----------------------------------------------------------
    def body(self, name: str) -> Body:
        """The oracle of strategy ``name``, which moves its body (:class:`~oracles.protocol.Moving`)."""
        oracle = self.selector.oracle(name)
        if not isinstance(oracle, Body):
            raise MotionError(f"strategy {name}'s oracle cannot plan motions (it offers no Moving capability)",
                              "no_motion")
        return oracle

    def _nearest_stored(self, name: str, goal: np.ndarray) -> np.ndarray:
        kd, postures, _, _ = self._graph(name)
        distance, i = kd.query(goal)
        if not np.isfinite(distance) or int(i) >= len(postures):  # a goal so far that its distance overflows
            raise MotionError(f"the goal {np.asarray(goal).tolist()} is too far from every stored posture to start a "
                              "motion towards it", "unreachable")
        return postures[int(i)].copy()  # type: ignore[no-any-return]
