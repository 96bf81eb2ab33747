"""A motion's path on the configuration space: segments, their rounded corners, postures along waypoints.

What the planner (:mod:`reach.motion.planner`) builds its motions from, asking each strategy's oracle only what
:class:`Body` names: its interpolation (a standing body's feet kept by its legs), its holds and its checks.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import numpy as np

from oracles.protocol import EffectorPositions, Moving, Shaped, Verifying
from reach.answers.refine import start_posture

EDGE_STEP = 0.1  # [rad] posture distance between the checked postures of a routed segment
# share of each segment beside an inner waypoint that its rounded corner takes (under half: corners never overlap)
BLEND = 0.4
BLEND_SAMPLES = 9  # postures along each rounded corner
# [m] a motion's end this near its goal reaches it, for oracles without a verdict of their own (the reach task's
# default)
REACH_TOLERANCE = 0.005


@runtime_checkable
class Body(Moving, Shaped, EffectorPositions, Protocol):
    """What the planner asks of a strategy's oracle: the capabilities it combines."""


def segment(oracle: Body, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The postures of the segment a -> b that are checked, ends included: ``EDGE_STEP`` apart, three at least."""
    return oracle.interpolate(a, b, fractions(a, b))


def fractions(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where :func:`segment`'s postures lie along a -> b, from 0 to 1."""
    return np.linspace(0.0, 1.0, max(3, int(math.ceil(np.linalg.norm(b - a) / EDGE_STEP)) + 1))


def reaches(oracle: Body, goal: np.ndarray, end: np.ndarray, point: np.ndarray) -> bool:
    """Whether the motion's last frame reaches the goal: the verdict's own check where the oracle offers it,
    else the effector within the default reach tolerance of the goal."""
    if isinstance(oracle, Verifying):
        return bool(oracle.verify(goal[None], end[None])[0])
    return float(np.linalg.norm(point - goal)) <= REACH_TOLERANCE


def along(oracle: Body, waypoints: list[np.ndarray], s: np.ndarray, exact: bool = True) -> np.ndarray:
    """Postures at fractions s of the waypoints' total posture length, each segment on the configuration space
    (``exact``: see :meth:`oracles.protocol.Moving.interpolate`)."""
    lengths = np.array([np.linalg.norm(b - a) for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)])
    total = float(lengths.sum())
    if total == 0.0:
        return np.tile(waypoints[0], (len(s), 1))
    ends = np.concatenate([[0.0], np.cumsum(lengths) / total])
    out = np.empty((len(s), len(waypoints[0])))
    seg = np.clip(np.searchsorted(ends, s, side="right") - 1, 0, len(lengths) - 1)
    for k in np.unique(seg):
        rows = np.nonzero(seg == k)[0]
        local = (s[rows] - ends[k]) / max(ends[k + 1] - ends[k], 1e-12)
        out[rows] = oracle.interpolate(waypoints[k], waypoints[k + 1], np.clip(local, 0.0, 1.0), exact)
    return out


def largest_step(postures: np.ndarray) -> float:
    """The largest change of any coordinate between consecutive frames."""
    return float(np.abs(np.diff(postures, axis=0)).max()) if len(postures) > 1 else 0.0


def held(oracle: Body, q: np.ndarray, before: tuple[np.ndarray, np.ndarray], limit: float) -> np.ndarray | None:
    """The oracle's hold of a posture that breaks a task (it holds every task, by the protocol), when it moves
    no coordinate more than ``limit`` (a larger change would be a jump between frames)."""
    fixed = oracle.hold(q, before)
    return None if fixed is None or np.abs(fixed - q).max() > limit else fixed


def rounded(oracle: Body, waypoints: list[np.ndarray]) -> list[np.ndarray]:
    """The waypoints with each inner corner replaced by a quadratic Bezier curve on the configuration space
    (de Casteljau with the body's interpolation) from ``BLEND`` of the way back along its incoming segment
    to ``BLEND`` along its outgoing one, the waypoint its control point: the path's direction turns smoothly."""
    out = [waypoints[0]]
    for before, corner, after in zip(waypoints[:-2], waypoints[1:-1], waypoints[2:], strict=True):
        share = np.array([BLEND])
        a, b = oracle.interpolate(corner, before, share)[0], oracle.interpolate(corner, after, share)[0]
        for t in np.linspace(0.0, 1.0, BLEND_SAMPLES)[:, None]:
            out.append(oracle.interpolate(oracle.interpolate(a, corner, t)[0],
                                          oracle.interpolate(corner, b, t)[0], t)[0])
    out.append(waypoints[-1])
    return out


def start_of(oracle: Body, tree: Any, start: dict[str, float] | None) -> np.ndarray:
    """A motion's first posture: the reference with a query's ``from`` joints set (see
    :func:`reach.answers.refine.start_posture`)."""
    reference = np.array(oracle.reference_posture(), dtype=float)
    q = start_posture(tree, reference, start)
    return reference if q is None else q
