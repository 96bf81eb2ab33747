"""A motion's frames checked against every hard task, and held where they break one, within a deadline.

Holding moves a frame to the nearest posture that keeps the hand where it was and every hard task (the oracle's
:class:`~oracles.protocol.Moving` ``hold``); a path whose holds jump between frames is not held.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import numpy as np

from reach.errors import MotionError
from reach.motion.paths import Body, fractions, held, largest_step, segment

CHECK_FRAMES = 16  # frames checked between two readings of the deadline (about 2 ms of the whole body's checks)
# [rad or m] a frame that holding moves more than this (any coordinate) leaves the path: it is routed instead
HOLD_STEP = 0.25
# a held path whose largest step between frames is this many times the unheld path's has a jump: it is routed instead
JUMP = 2.0
# [rad or m] a routed segment's checked posture that holding moves more than this would jump between frames
EDGE_HOLD = 0.05
SKIPS = 6  # direct segments a graph's path tries to skip waypoints by


class Holding:
    """Checks and holds of one planner's frames, and the deadline of the plan in progress.

    Attributes:
        deadline: ``time.perf_counter()`` past which a check raises MotionError (code ``timeout``).
        counts: Frames that broke a task and were held: by the batched hold (``batch``), or one at a time
            (``alone``, its fallback: how often is a figure of bench/motion.py), since it was made.
    """

    def __init__(self) -> None:
        self.deadline = math.inf
        self.counts = {"batch": 0, "alone": 0}

    def in_time(self) -> None:
        if time.perf_counter() > self.deadline:
            raise MotionError("the motion was not planned by its deadline", "timeout")

    def faults(self, oracle: Body, postures: np.ndarray) -> Iterator[list[str]]:
        """The oracle's faults of each posture, ``CHECK_FRAMES`` at a time with the deadline read between them."""
        for k in range(0, len(postures), CHECK_FRAMES):
            self.in_time()
            yield from oracle.faults(postures[k : k + CHECK_FRAMES])

    def holds(self, oracle: Body, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether the direct segment a -> b holds every task at postures ``EDGE_STEP`` apart (no hold)."""
        # Made and checked CHECK_FRAMES postures at a time, up to the first that breaks a task: a standing body's
        # postures each hold a planted foot by its leg's IK, and the whole body's segments that fail (37 of 62 a
        # bench run) broke at their 14th posture of 31 on average. (Each batch's first posture is held from itself,
        # not from the posture before it.)
        inner = fractions(a, b)[1:-1]
        for k in range(0, len(inner), CHECK_FRAMES):
            postures = oracle.interpolate(a, b, inner[k : k + CHECK_FRAMES])
            if any(any(f) for f in self.faults(oracle, postures)):
                return False
        return True

    def clear(self, oracle: Body, a: np.ndarray, b: np.ndarray, limit: float = EDGE_HOLD) -> bool:
        """Whether the segment a -> b holds every task at postures ``EDGE_STEP`` apart, held where it breaks one
        (see :meth:`hold_path`)."""
        # Its checked postures are farther apart than frames: a hold that passes the jump test here may fail it
        # at the frames' steps, so it may move a posture less. A check is one pass (the batch's holds, the rest one
        # at a time): the second pass, every broken posture held alone, is for a path's frames; a segment that
        # needed it is passed over (in-process, 20 goals a kind: the whole body's p99 3.5-3.7 s against 4.6-5.7,
        # the crouch's 3.9-4.0 against 4.9-7.2, no goal without a motion; bench/motion.py).
        return self.hold_path(oracle, segment(oracle, a, b), limit, once=True) is not None

    def hold_path(self, oracle: Body, postures: np.ndarray, limit: float = HOLD_STEP,
                  once: bool = False) -> tuple[np.ndarray, int] | None:
        """The postures with each inner one that breaks a task held (and how many), or None when one cannot
        be held, or holding makes a jump: a frame moved more than ``limit``, or a step between frames
        ``JUMP`` times the largest before. ``once``: without the second pass (every broken posture held alone)."""
        broken = [k for k, f in enumerate(self.faults(oracle, postures)) if f and 0 < k < len(postures) - 1]
        if not broken:
            return postures.copy(), 0
        # The broken frames held together first, as one batch, each from itself; a frame the batch leaves unheld or
        # moves past the limit is held alone from its neighbour's correction. When that fails or the frames jump,
        # every broken frame is held one at a time (each from its neighbour's correction keeps consecutive frames alike:
        # held each on its own, 25 of 40 upper-body paths jumped somewhere).
        together = oracle.hold_many(postures[broken], self.deadline)
        alone: list[np.ndarray | None] = [None] * len(broken)
        # (An engine without a batched hold held none: the one-at-a-time pass is the only one.)
        passes = ([*together],) if once else ([*together], alone)
        forward = None  # the last pass that held every frame but jumped
        for guesses in passes if np.isfinite(together).all(axis=1).any() else (alone,):
            out = self._forward(oracle, postures, broken, guesses, limit)
            if out is not None:
                if largest_step(out) <= JUMP * largest_step(postures):
                    return out, len(broken)
                forward = out
        return None if once or forward is None else self._spliced(oracle, postures, broken, forward, limit)

    def _forward(self, oracle: Body, postures: np.ndarray, broken: list[int], guesses: list[np.ndarray | None],
                 limit: float) -> np.ndarray | None:
        """The postures with each broken frame taken from its guess, or held alone from its predecessor's correction
        where the guess is missing or moved too far; None when a frame cannot be held."""
        # A batch's frame moved more than a jump between frames would allow is held alone too (each frame held from
        # itself, a few landed in another basin, 0.2-0.5 rad away, where their neighbours did not).
        bound = min(limit, JUMP * largest_step(postures))
        out = postures.copy()
        for k, fixed in zip(broken, guesses, strict=True):
            self.in_time()
            if fixed is None or not np.all(np.isfinite(fixed)) or np.abs(fixed - postures[k]).max() > bound:
                self.counts["alone"] += 1
                fixed = held(oracle, postures[k], (postures[k - 1], out[k - 1]), limit)
            else:
                self.counts["batch"] += 1
            if fixed is None:
                return None
            out[k] = fixed
        return out

    def _spliced(self, oracle: Body, postures: np.ndarray, broken: list[int], forward: np.ndarray,
                 limit: float) -> tuple[np.ndarray, int] | None:
        """The broken frames held from the path's end backwards too (each from its successor's correction), and the
        path joined from the two holds where they come nearest, or None when that still jumps. Held from its start
        alone, a path whose every frame breaks the feet drifted from its end posture (which is not held) and jumped
        to it: 0.16-0.44 rad in the last frames of 2 of 20 whole-body motions (bench/motion.py)."""
        back = postures.copy()
        for k in reversed(broken):
            self.in_time()
            self.counts["alone"] += 1
            fixed = held(oracle, postures[k], (postures[k + 1], back[k + 1]), limit)
            if fixed is None:
                return None
            back[k] = fixed
        # the last frame taken from the forward hold: where its next frame's backward hold is nearest to it
        gaps = np.abs(back[1:] - forward[:-1]).max(axis=1)
        m = int(np.argmin(gaps))
        out = np.concatenate([forward[: m + 1], back[m + 1 :]])
        return (out, len(broken)) if largest_step(out) <= JUMP * largest_step(postures) else None

    def shorten(self, oracle: Body, waypoints: list[np.ndarray]) -> list[np.ndarray]:
        """Drop every waypoint that a direct segment between its neighbours can skip, held where it breaks a task
        (greedy, farthest first)."""
        out, i = [waypoints[0]], 0
        while i < len(waypoints) - 1:
            j = next((j for j in range(len(waypoints) - 1, i + 1, -1)
                      if self.clear(oracle, waypoints[i], waypoints[j])), i + 1)
            out.append(waypoints[j])
            i = j
        return out

    def skipped(self, oracle: Body, waypoints: list[np.ndarray]) -> list[np.ndarray]:
        """The waypoints without those a direct segment between their neighbours can skip (it holds, checked now at
        postures ``EDGE_STEP`` apart), farthest first, at most ``SKIPS`` segments checked."""
        out, i, tries = [waypoints[0]], 0, 0
        while i < len(waypoints) - 1:
            j = i + 1
            for k in range(len(waypoints) - 1, i + 1, -1):
                if tries == SKIPS:
                    break
                tries += 1
                if self.holds(oracle, waypoints[i], waypoints[k]):
                    j = k
                    break
            out.append(waypoints[j])
            i = j
        return out
