"""A reach motion's duration and timing: MTM-1's movement times and minimum jerk along the hand's path.

The duration follows MTM-1 (Maynard, Stegemerten & Schwab 1948, Methods-Time Measurement, McGraw-Hill; the MTM
Association's MTM-1 data card): the reach table's case A (an object in a fixed location) for the distance the hand
travels, plus a body motion when the body takes part: a stoop or bend (B/S, 29.0 TMU) when the pelvis drops or tilts,
a foot motion (FM, 8.5 TMU) when it rises onto the toes. MTM-1 counts them one after the other; here they share the
frames, as a person's overlap.

The timing is minimum jerk (Flash & Hogan 1985, J Neurosci 5(7):1688-1703) along the hand's path: the share of the
path covered (the hand's, with a tenth of the posture's) is s(t) = 10 u^3 - 15 u^4 + 6 u^5, u = t / T, so the hand's
speed is bell-shaped with its peak near the middle of the motion.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from reach.errors import InputError
from reach.motion.paths import Body, along

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
DROP = 0.10  # [m] a pelvis lowered this much stoops or crouches (a modelling choice: a knee bend of about 30 deg)
TILT = math.radians(30.0)  # [rad] a pelvis tilted this much bends (a modelling choice)
LIFT = 0.01  # [m] a pelvis raised this much rises onto the toes (a modelling choice)
MAX_DURATION = 20.0  # [s] an explicit duration at most this
FINE = 128  # postures sampled along a path to measure the hand's path and time it
POSTURE_SHARE = 0.1  # the posture path's share in a motion's progress (a modelling choice: the rest is the hand's path)


def minimum_jerk(u: np.ndarray) -> np.ndarray:
    """Flash & Hogan's minimum-jerk path parameter at normalised times u in [0, 1]."""
    u = np.clip(np.asarray(u, float), 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)  # type: ignore[no-any-return]


def _coefficient(where: str, key: str, value: Any) -> float:
    """One coefficient of a timing mapping, or InputError naming it: a finite number >= 0; a duration in
    (0, MAX_DURATION]."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0
    if key == "duration":
        ok = ok and 0 < value <= MAX_DURATION
    if not ok:
        limit = f"a number of seconds in (0, {MAX_DURATION:g}]" if key == "duration" else "a finite number >= 0"
        raise InputError(f"{where}.{key}", f"expected {limit}, got {value!r}")
    return float(value)


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
        timing = cls(**{k: _coefficient(where, k, v) for k, v in raw.items()})
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


Frames = tuple[np.ndarray, np.ndarray, dict[str, float]]  # postures (T, nq), times (T,) [s], the duration's parts


def _excursion(names: tuple[str, ...], fine: np.ndarray) -> tuple[float, float, float]:
    """How far the root drops [m], tilts [rad] and rises [m] from its first posture along a sampled path (zeros for a
    body without a floating root)."""
    if "root_z" not in names or "root_qx" not in names:
        return 0.0, 0.0, 0.0
    z, quat = fine[:, names.index("root_z")], fine[:, names.index("root_qx") : names.index("root_qx") + 4]
    dots = np.abs(quat @ quat[0]) / np.linalg.norm(quat, axis=1) / np.linalg.norm(quat[0])
    tilt = float(2.0 * np.arccos(np.clip(dots.min(), -1.0, 1.0)))
    return max(0.0, float(z[0] - z.min())), tilt, max(0.0, float(z.max() - z[0]))


def timings(oracle: Body, names: tuple[str, ...], waypoints: list[np.ndarray], rate: float,
            timing: Timing) -> Iterator[Frames]:
    """Frames k / rate apart along the waypoints timed by minimum jerk along the hand's path, then the same path's
    frames timed by minimum jerk along the posture's path alone, both from one sampling of the path; each with the
    duration's parts."""
    # The hand's path length and the root's excursion, on a fine sampling of the path.
    sampled = np.linspace(0.0, 1.0, FINE)
    fine = along(oracle, waypoints, sampled, exact=False)
    hand = np.asarray(oracle.effector_positions(fine))
    steps = np.linalg.norm(np.diff(hand, axis=0), axis=1)
    seconds, parts = timing.seconds(float(steps.sum()), *_excursion(names, fine))
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


def timed(oracle: Body, names: tuple[str, ...], waypoints: list[np.ndarray], rate: float, timing: Timing) -> Frames:
    """The first frames of :func:`timings`: timed by minimum jerk along the hand's path."""
    return next(timings(oracle, names, waypoints, rate, timing))
