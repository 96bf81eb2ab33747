"""Twin vertices a quarter turn apart: a volume that a quarter turn about a vertical axis maps onto itself.

A robot whose base joint turns a full turn, standing on a floor or among
boxes that look the same turned (a :class:`~oracles.protocol.QuarterTurning`
oracle), reaches a point exactly when it reaches the point turned 90 deg
about the base: its posture is the same with the base joint turned. The
build solves one vertex of each set of lattice twins (the one of least key)
and gives the others its verdict, their postures turned and checked by the
oracle's own forward kinematics (a turned posture that fails the check is
solved on its own). Capability maps of arms on a turning base do the same
with the first joint (Zacharias, Borst & Hirzinger, IROS 2007: the map of
one half-plane turned about the base). Twins then agree by construction,
whatever the search finds or misses at one azimuth, and a build asks the
oracle about a quarter of the vertices of a box centred on the axis.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from oracles.protocol import QuarterTurning, Verdicts, Verifying
from reach.maps.tree import Lattice

TURNS = 4  # a quarter turn's twins: the vertex itself and three turns
ON_LATTICE = 1e-6  # [lattice steps] a turned vertex this near a lattice point is that point


@dataclass(frozen=True)
class Twins:
    """The quarter turn of a build: its axis's x, y [m], and the oracle's turn and check of postures."""

    centre: np.ndarray
    turned: Callable[[np.ndarray, np.ndarray], np.ndarray]
    verify: Callable[[np.ndarray, np.ndarray], np.ndarray]

    @staticmethod
    def of(oracle: object) -> Twins | None:
        """The twins of an oracle's volume, or None when it has no quarter turn (or cannot turn and check postures)."""
        if not (isinstance(oracle, QuarterTurning) and isinstance(oracle, Verifying)):
            return None
        turn = oracle.quarter_turn()
        if turn is None:
            return None
        return Twins(np.asarray(turn[0], float)[:2].copy(), oracle.turned, oracle.verify)

    def orbits(self, lattice: Lattice, keys: np.ndarray) -> np.ndarray:
        """(N, 4) each key's vertex turned by 0, 1, 2 and 3 quarters anticlockwise about the axis: its key, or -1 where
        the turned point is no vertex of the lattice (off its points, or outside its box)."""
        out = np.full((len(keys), TURNS), -1, np.int64)
        if lattice.dim != 3 or not len(keys):
            return out
        out[:, 0] = keys
        pts = lattice.points(lattice.coords(keys))
        rel = pts[:, :2] - self.centre
        for j in range(1, TURNS):
            c, s = np.rint(np.cos(j * np.pi / 2)), np.rint(np.sin(j * np.pi / 2))
            turned = pts.copy()
            turned[:, 0] = self.centre[0] + c * rel[:, 0] - s * rel[:, 1]
            turned[:, 1] = self.centre[1] + s * rel[:, 0] + c * rel[:, 1]
            steps = (turned - lattice.box.lo) / lattice.resolution
            near = np.rint(steps)
            ok = np.all(np.abs(steps - near) <= ON_LATTICE, axis=1) & np.all((near >= 0) & (near <= lattice.cells),
                                                                             axis=1)
            out[ok, j] = lattice.keys(near[ok].astype(np.int64))
        return out


def shared(twins: Twins, lattice: Lattice, keys: np.ndarray, known: Callable[[np.ndarray], np.ndarray],
           stored: Callable[[np.ndarray], Verdicts], solve: Callable[[np.ndarray], Verdicts]) -> tuple[Verdicts, int]:
    """Verdicts for ``keys`` (N,), each from a twin's: one known (``known``: keys -> the table's rows, -1 where
    unknown; ``stored``: rows -> their verdicts), else the least twin asked, solved now (``solve``: keys ->
    verdicts; itself, maybe); their postures turned, and checked where reachable. And how many keys were not solved."""
    n = len(keys)
    orbit = twins.orbits(lattice, keys)
    valid = orbit >= 0
    rows = np.where(valid, known(np.where(valid, orbit, 0)), -1)
    has_known = (rows >= 0).any(axis=1)
    asked = valid & np.isin(orbit, keys)
    turn = np.where(has_known, np.argmax(rows >= 0, axis=1),
                    np.argmin(np.where(asked, orbit, np.iinfo(np.int64).max), axis=1))
    source = orbit[np.arange(n), turn]
    ask = np.unique(source[~has_known])
    parts = [(np.nonzero(has_known)[0], stored(rows[np.arange(n), turn][has_known]))]
    if ask.size:
        fresh = solve(ask)
        at = np.searchsorted(ask, source[~has_known])
        parts.append((np.nonzero(~has_known)[0], Verdicts(fresh.reachable[at], fresh.residual[at],
                                                          None if fresh.posture is None else fresh.posture[at])))
    reachable, residual, posture = np.zeros(n, bool), np.full(n, np.inf), None
    for idx, v in parts:
        if not idx.size:
            continue
        reachable[idx], residual[idx] = v.reachable, v.residual
        if v.posture is not None:
            posture = np.zeros((n, v.posture.shape[1])) if posture is None else posture
            # the key is its source turned back: by -turn quarters
            posture[idx] = twins.turned(v.posture, (TURNS - turn[idx]) % TURNS)
    solved = int(ask.size)
    # every reachable verdict given to a twin is checked on its turned posture; one that fails is solved on its own
    given = np.nonzero(reachable & (source != keys))[0]
    if given.size and posture is not None:
        bad = given[~np.asarray(twins.verify(lattice.points(lattice.coords(keys[given])), posture[given]), bool)]
        if bad.size:
            again = solve(keys[bad])
            reachable[bad], residual[bad] = again.reachable, again.residual
            if again.posture is not None:
                posture[bad] = again.posture
            solved += int(bad.size)
    return Verdicts(reachable, residual, posture), n - solved
