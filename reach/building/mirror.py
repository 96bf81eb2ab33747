"""Left from right: deriving a strategy's tree by mirroring another's.

Allowed only when the source strategy's oracle is
:class:`~oracles.protocol.Mirrorable` and its body passes the symmetry check
(:mod:`oracles.bodies.mirror`), which gives the map of postures.

The mirrored tree is rebuilt by the same Algorithm 1 with an oracle that
answers from the source tree's vertex table (points and postures
reflected), so it is exactly the tree a build of the mirrored strategy would
give from mirrored verdicts, at no IK cost.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from oracles.bodies.mirror import REFLECT
from oracles.protocol import Goals, Verdicts
from reach.errors import OracleError
from reach.maps.tree import Lattice, VATree


class MirrorOracle:
    """Answers from a source tree's vertex table, reflected about y = 0."""

    dim = 3

    def __init__(self, source: VATree, mirror: Callable[[np.ndarray], np.ndarray] | None) -> None:
        lo, hi = source.box.lo, source.box.hi
        if not np.isclose(lo[1], -hi[1]):
            raise OracleError(f"mirroring needs B0 symmetric about y = 0, got y in [{lo[1]}, {hi[1]}]")
        self.source, self.mirror = source, mirror
        self.lattice: Lattice = source.lattice
        self.posture_names = tuple(source.vertices.posture_names)

    def evaluate(self, goals: Goals | np.ndarray) -> Verdicts:
        pts = Goals.points_of(goals, 3) * REFLECT
        lat = self.lattice
        coords = np.rint((pts - lat.box.lo) / lat.resolution).astype(np.int64)
        row = self.source.vertices.index(lat.keys(coords))
        if np.any(row < 0):
            raise OracleError(f"{int(np.sum(row < 0))} mirrored vertices were never evaluated in the source tree")
        v = self.source.vertices
        posture = None
        if v.posture is not None and self.mirror is not None:
            posture = self.mirror(v.posture[row])
        return Verdicts(v.reachable[row].copy(), v.residual[row].copy(), posture)
