"""A query's ``from``: the character's posture now (joint name -> rad or m, ``root_*`` for a floating base), checked
before any work is queued."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from oracles.protocol import Bounded, Oracle
from reach.answers.answer import joint_names
from reach.errors import InputError
from reach.maps.protocol import ReachMap

# [rad] (or m) a `from` joint this far past its range is still accepted (rounding in a client)
FROM_TOLERANCE = math.radians(1.0)
FROM_QUATERNION = 1e3  # the largest component of a `from` root quaternion (it is normalised)
FROM_REACH = 1000.0  # [m] a `from` root farther than this from the world origin is a mistake, not a scene


def check_start(maps: Mapping[str, ReachMap], oracle: Callable[[str], Oracle], names: list[str],
                start: dict[str, float]) -> None:
    """A ``from`` names the posture's coordinates of the strategies ``names``, within their ranges
    (``FROM_TOLERANCE``); a root's position is within ``FROM_REACH`` of the origin and its quaternion is not zero.

    Raises InputError naming ``from``.
    """
    _check_quaternion(start)
    posed = [s for s in names if maps[s].posture_names]
    known = {n for s in posed for n in joint_names(maps[s].posture_names)}
    unknown = sorted(set(start) - known)
    if unknown:
        raise InputError("from", f"unknown joints {unknown[:5]}; the posture's names are {', '.join(sorted(known))}")
    bounded = next((s for s in posed if isinstance(oracle(s), Bounded)), None)
    if bounded is not None:  # the strategies of an effector share a body
        _check_ranges(maps[bounded].posture_names, oracle(bounded), start)
    if any(abs(start.get(f"root_{c}", 0.0)) > FROM_REACH for c in "xyz"):
        raise InputError("from", f"the root's position must be within {FROM_REACH:g} m of the world origin")


def _check_quaternion(start: dict[str, float]) -> None:
    """A ``from`` root quaternion's components are not huge, and not all zero."""
    quat = [start[f"root_q{c}"] for c in "xyzw" if f"root_q{c}" in start]
    if any(abs(v) > FROM_QUATERNION for v in quat):  # 1e300 overflowed where the quaternion is normalised
        raise InputError("from", f"the root's quaternion components must be within +-{FROM_QUATERNION:g} (a unit "
                                 f"quaternion, normalised if off by a little), got {quat}")
    if len(quat) == 4 and math.hypot(*quat) < 1e-9:
        raise InputError("from", "the root's quaternion (root_qx, root_qy, root_qz, root_qw) must not be zero")


def _check_ranges(names: tuple[str, ...], oracle: Oracle, start: dict[str, float]) -> None:
    assert isinstance(oracle, Bounded)
    lower, upper = oracle.posture_bounds()
    for k, n in enumerate(names):
        if n in start and not lower[k] - FROM_TOLERANCE <= start[n] <= upper[k] + FROM_TOLERANCE:
            raise InputError("from", f"{n} = {start[n]:.6g} is outside its range [{lower[k]:.4f}, {upper[k]:.4f}] rad "
                                     "or m")
