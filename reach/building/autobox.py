"""``box: auto``: B0 derived from the body's size, and the provable bound it may grow to when reachable vertices lie
on its faces (see :mod:`reach.building.config` for the keys)."""

from __future__ import annotations

from typing import Any

import numpy as np

from oracles.protocol import Floored, Oracle, Probing, ReachBound
from reach.errors import ConfigError
from reach.maps.box import Box

# of a probed extent, added on each side: the 26 probes find the extremes along their own directions only
PROBE_PAD = 0.15


def derive_box(source: str, oracles: list[Oracle], auto: dict[str, Any], symmetric: bool) -> tuple[Box, Box]:
    """B0 from the bodies' size, and the provable bound it may grow to (see :func:`grown`).

    Each strategy's reach bound (a ball about its fixed anchor) bounds its
    volume; where the oracle can probe its extent (:class:`~oracles.protocol.Probing`),
    the probed extent padded by ``PROBE_PAD`` of itself and the margin,
    within the ball, sizes its box instead (a standing body's ball about a
    foot is 4 m wide; its reach is not).
    """
    lows, highs, limit_lo, limit_hi = [], [], [], []
    for o in oracles:
        bound = o.reach_bound() if isinstance(o, ReachBound) else None
        if bound is None:
            raise ConfigError(source, "box", "box: auto needs body strategies whose reach is bounded (a fixed root, "
                                             "or feet on the floor); give box.min and box.max")
        centre, radius = bound
        ball_lo, ball_hi = np.asarray(centre - radius - auto["margin"],
                                      float), np.asarray(centre + radius + auto["margin"], float)
        # The floor z = 0 cuts a strategy's box where the strategy itself keeps its effector above it (auto),
        # or everywhere (true); a robot without a floor task reaches below its base's plane.
        floor = (o.lowest() if isinstance(o, Floored) else None) if auto["floor"] == "auto" else (0.0
            if auto["floor"] else None)
        if floor is not None:
            ball_lo[2] = max(ball_lo[2], floor)
        low, high = ball_lo.copy(), ball_hi.copy()
        extent = o.reach_extent() if isinstance(o, Probing) else None
        if extent is not None:
            pad = PROBE_PAD * (extent[1] - extent[0]) + auto["margin"]
            low, high = np.maximum(extent[0] - pad, ball_lo), np.minimum(extent[1] + pad, ball_hi)
        lows.append(low)
        highs.append(high)
        limit_lo.append(ball_lo)
        limit_hi.append(ball_hi)
    lo, hi = np.min(lows, axis=0), np.max(highs, axis=0)
    top_lo, top_hi = np.min(limit_lo, axis=0), np.max(limit_hi, axis=0)
    if symmetric:
        for a, b in ((lo, hi), (top_lo, top_hi)):
            half = max(-a[1], b[1])
            a[1], b[1] = -half, half
    return Box(np.round(lo, 4), np.round(hi, 4)), Box(np.round(top_lo, 4), np.round(top_hi, 4))


GROW = 0.25  # of the box's extent, by which a face that reachable vertices lie on moves out (within the limit)


def grown(box: Box, limit: Box, faces: set[str]) -> Box | None:
    """B0 with each named face (``x-``, ``z+`` ...) moved out by ``GROW`` of the box's extent, within limit; None if
    none can move."""
    lo, hi = box.lo.copy(), box.hi.copy()
    size = hi - lo
    for face in faces:
        axis = "xyz".index(face[0])
        if face[1] == "-":
            lo[axis] = max(limit.lo[axis], lo[axis] - GROW * size[axis])
        else:
            hi[axis] = min(limit.hi[axis], hi[axis] + GROW * size[axis])
    if np.array_equal(lo, box.lo) and np.array_equal(hi, box.hi):
        return None
    return Box(np.round(lo, 4), np.round(hi, 4))
