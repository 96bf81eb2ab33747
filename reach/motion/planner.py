"""Reach motion: a timed, collision-free motion from the character's posture now to the selector's answer.

The paper leaves "the timing of motion in order to get more smooth and
realistic reaching animations ... an interpolation scheme ... storing
postural data in each reachable node of the tree" as future work (section
6). :class:`Planner` does it in three steps:

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
   nearest posture that keeps the hand where it was and every hard task
   (:mod:`reach.motion.holding`); where that fails, the path is routed
   through the postures stored at the tree's reachable vertices (the paper's
   stored postural data, :mod:`reach.motion.routes`): a shortest path over
   neighbouring vertices in posture distance, edges checked lazily, then
   shortened by dropping every waypoint a direct segment can skip, its
   corners rounded (quadratic Bezier curves on the configuration space)
   where the rounded frames can be held. A strategy whose atlas carries a
   motion graph goes through it first (:mod:`reach.maps.graph`).
3. **The duration and the timing** (:mod:`reach.motion.timing`): MTM-1's
   movement times for the hand's path and the body's motions, minimum jerk
   along the hand's path.

Frames are in the atlas's world frame: metres, radians, the model's joint names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from oracles.protocol import Settling, Stepping, Transiting
from reach.answers.answer import posture_vector, split_posture
from reach.answers.select import Selector
from reach.errors import InputError, MotionError
from reach.motion.holding import Holding
from reach.motion.paths import Body, reaches, rounded, start_of
from reach.motion.routes import Routes
from reach.motion.timing import PACE, TMU, Frames, Timing, timings

__all__ = ["Motion", "MotionError", "Planner", "Timing"]

STEP_MOVES = 0.01  # [m] an end posture whose stepping foot lies farther than this from where it stood takes a step
RATE = 30.0  # [Hz] frames per second by default
MAX_RATE = 240.0  # [Hz]
# [s] the end posture's refinement budget: a motion is not a 50 Hz query, and a stored posture stops short. A budget of
# work (oracles.ik.budget.Meter): a whole-body refinement's lower tasks are charged about 0.19 s, and a handover starts
# with a quarter of the budget left; at 0.25 s none did, and the demo's reach behind the body to (-0.42, 0.25, 0.59)
# kept a posture with nine joints at their limits (the idle arm raised overhead) and found no motion
# (bench/motion.py).
BUDGET = 0.4
REACHED, NEAREST = "reached", "nearest"
# How a motion's end posture was found: the stored answer settled onto the goal by a few local steps, or the
# selector's refinement (a solve), when settling found none or the motion starts from a given posture.
SETTLED, REFINED = "settled", "refined"
# How a motion's frames were found: through a stored posture whose motion from the reference was checked at build time
# (reach.maps.graph; the last stretch checked now), or planned now (every frame checked, broken ones held or routed).
GRAPH, PLANNED = "graph", "planned"
MOTION_MISSES = ("nearest", "error")


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
        self.holding = Holding()
        self.routes = Routes(selector.atlas, self.holding, graph)

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
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and 1.0 <= rate <= MAX_RATE):
            raise InputError("rate", f"expected frames per second in [1, {MAX_RATE:g}], got {rate!r}")
        if miss not in MOTION_MISSES:
            raise InputError("miss", f"expected one of {', '.join(MOTION_MISSES)}, got {miss!r}")
        self.holding.deadline = math.inf if deadline is None else float(deadline)
        try:
            motion = self._plan(effector, np.asarray(goal, float).reshape(1, -1), start, rate, timing or Timing(), miss)
            return motion.and_back() if back else motion
        finally:
            self.holding.deadline = math.inf

    def _plan(self, effector: str, g: np.ndarray, start: dict[str, float] | None, rate: float, timing: Timing,
              miss: str) -> Motion:
        names = [n for n in self.selector.check_goals(effector, g, start) if self.selector.atlas.maps[n].posture_names]
        if not names:
            raise MotionError(f"the strategies of {effector!r} store no postures: there is no body to move",
                              "no_motion")
        goal = g[0]
        answer, settled = self._settled(effector, goal) if start is None else (None, None)
        if answer is None:
            answer = self.selector.select(effector, goal, True, start=start, miss="unreachable")
        name, outcome = self._outcome(effector, goal, answer, names, miss)
        oracle = self.body(name)
        tree = self.selector.atlas.maps[name]
        labels = tree.posture_names
        q0 = start_of(oracle, tree, start)
        mover = self._mover(name, oracle, q0)
        q1 = settled if settled is not None else self._end(name, outcome, answer, labels, q0, goal)
        frames, waypoints, held, route = self._frames(name, oracle, mover, labels, q0, q1, rate, timing,
                                                      outcome == REACHED)
        path = np.asarray(oracle.effector_positions(frames[0]))
        if outcome == REACHED and not reaches(oracle, goal, frames[0][-1], path[-1]):
            # honest: held frames (or a stored end posture) that stop short of the goal did not reach it
            outcome = NEAREST
        within = (None if settled is not None else answer.within) if outcome == REACHED else float(
            np.linalg.norm(path[-1] - goal))
        return Motion(effector, tuple(goal.tolist()), name, outcome, tuple(path[-1].tolist()), labels, float(rate),
                      frames[1], frames[0], path, "ok" if settled is not None else answer.refined, within, waypoints,
                      held, frames[2], SETTLED if settled is not None else REFINED, route)

    @staticmethod
    def _outcome(effector: str, goal: np.ndarray, answer: Any, names: list[str], miss: str) -> tuple[str, str]:
        """The strategy the motion ends in and whether it reaches the goal or its nearest point."""
        if answer.reachable:
            assert answer.strategy is not None
            return answer.strategy, REACHED
        if miss == "error":
            raise MotionError(f"{effector} cannot reach {goal.tolist()}: no strategy's posture reaches it",
                              "unreachable")
        return (answer.nearest["strategy"] if answer.nearest is not None else names[0]), NEAREST

    @staticmethod
    def _mover(name: str, oracle: Body, q0: np.ndarray) -> Body:
        """The oracle whose tasks the frames hold: the strategy's, or its transit twin from a start that breaks some
        of its tasks (a tiptoe's or squat's balance over the balls, the squat's hips below the knees, from standing:
        the frames hold the twin, the end all)."""
        broken = oracle.faults(q0[None])[0]
        mover = oracle.transit(broken) if broken and isinstance(oracle, Transiting) else oracle
        if mover is None or (broken and mover.faults(q0[None])[0]):
            raise InputError("from", f"the start posture breaks {', '.join(broken)} for strategy {name}")
        return mover

    def _end(self, name: str, outcome: str, answer: Any, labels: tuple[str, ...], q0: np.ndarray,
             goal: np.ndarray) -> np.ndarray:
        """The end posture: the answer's, its nearest point's, or the stored posture nearest the goal."""
        if outcome == REACHED:
            return posture_vector(labels, q0, answer.posture, answer.root)
        if answer.nearest is not None:
            return posture_vector(labels, q0, answer.nearest["posture"], answer.nearest["root"])
        return self.routes.nearest_stored(name, goal)

    def _frames(self, name: str, oracle: Body, mover: Body, labels: tuple[str, ...], q0: np.ndarray, q1: np.ndarray,
                rate: float, timing: Timing, reached: bool) -> tuple[Frames, int, int, str]:
        """The frames, the stored postures they pass, the frames held, and how they were found (``graph`` or
        ``planned``): a step first when the end posture's foot moved, then the motion graph, else a path planned
        now."""
        step = self._step(oracle, q0, q1, rate) if reached else None
        via = (self.routes.via_graph(name, mover, labels, q0, q1, rate, timing)
               if step is None and mover is oracle else None)
        if via is not None:
            return via[0], via[1], 0, GRAPH
        frames, waypoints, held = self._path(name, mover, labels, q0 if step is None else step[-1], q1, rate, timing)
        if step is not None:
            # the step's frames (the foot lifted, carried and set down), then the reach from where it landed
            postures, reach_times, parts = frames
            lead = len(step) - 1
            times = np.concatenate([np.arange(lead) / rate, reach_times + lead / rate])
            frames = (np.vstack([step[:-1], postures]), times, {"step": PACE, **parts})
        return frames, waypoints, held, PLANNED

    def _path(self, name: str, oracle: Body, names: tuple[str, ...], q0: np.ndarray, q1: np.ndarray, rate: float,
              timing: Timing) -> tuple[Frames, int, int]:
        """Frames (postures, times, the duration's parts), the stored postures routed through and the frames held:
        the direct path if its frames can be held, else the route through stored postures."""
        for routed in (False, True):
            route = self.routes.route(name, oracle, q0, q1) if routed else [q0, q1]
            # Timed by the hand's path first; by the posture's path when that cannot be held (the body then moves
            # most where the hand moves least, which holding may not follow).
            for waypoints in ([rounded(oracle, route)] if len(route) > 2 else []) + [route]:
                for timed in timings(oracle, names, waypoints, rate, timing):
                    held = self.holding.hold_path(oracle, timed[0])
                    if held is not None:
                        return (held[0], timed[1], timed[2]), len(route) - 2, held[1]
        raise MotionError(f"no motion of strategy {name} found that holds every task at every frame")

    def body(self, name: str) -> Body:
        """The oracle of strategy ``name``, which moves its body (:class:`~oracles.protocol.Moving`)."""
        oracle = self.selector.oracle(name)
        if not isinstance(oracle, Body):
            raise MotionError(f"strategy {name}'s oracle cannot plan motions (it offers no Moving capability)",
                              "no_motion")
        return oracle

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
            seeds = self.routes.homeward(name, goal, oracle)
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
