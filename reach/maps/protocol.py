"""What answers, motions, placements, the index and the viewer ask of a map of reach.

A :class:`ReachMap` says which points a strategy reaches (membership), which
postures it keeps and for which goals (the stored postures, found nearest a
point), the reachability index at a point, and the box it covers. The VATree
(:class:`~reach.maps.tree.VATree`) implements it, and with its index
:class:`~reach.maps.index.IndexedTree`; a compact or learned map would
implement the same methods and be served by the same selector and planner
(``tests/test_maps.py`` serves a dense grid of its own).

Stored postures are named by ids: integers a map gives out and takes back
(a VATree's are the rows of its vertex table), stable for the map's life.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple, Protocol, runtime_checkable

import numpy as np

from reach.maps.box import Box

Policy = Literal["conservative", "optimistic", "vertex"]  # how a map answers for the cells it is unsure of
POLICIES = ("conservative", "optimistic", "vertex")
DEFAULT_POLICY: Policy = "vertex"  # what the selector, the server and the CLI use unless told


class Stored(NamedTuple):
    """The reachable stored postures of a map: their ids (n,), the goals they reach (n, dim) [m] and the
    postures themselves (n, nq), in the map's ``posture_names``."""

    ids: np.ndarray
    points: np.ndarray
    postures: np.ndarray


@runtime_checkable
class ReachMap(Protocol):
    """A strategy's reachable volume and the postures that reach it (see the module docstring)."""

    @property
    def box(self) -> Box:
        """The box the map covers (world frame, metres)."""

    @property
    def dim(self) -> int:
        """The dimension of its points (3 for a body)."""

    @property
    def posture_names(self) -> tuple[str, ...]:
        """The names of the stored postures' coordinates; empty when the map keeps no posture."""

    @property
    def meta(self) -> dict[str, Any]:
        """JSON metadata: the strategy's ``name``, ``effector``, ``priority`` and ``oracle`` spec, among others."""

    def prepare(self) -> Any:
        """Build the lookup structures now (a server does at load), not on the first request."""

    def contains(self, points: np.ndarray, policy: Policy = "conservative") -> np.ndarray:
        """Membership of points (n, dim) [m]: (n,) bool, with ``policy`` for the cells the map is unsure of."""

    def contains_one(self, point: list[float], policy: Policy = "conservative") -> bool:
        """Membership of one point, without array overhead (a server's single goal)."""

    def stored(self) -> Stored | None:
        """Every reachable stored posture with the goal it reaches; None when the map keeps no posture."""

    def postures(self, ids: np.ndarray | int) -> np.ndarray:
        """The stored postures of ids: (nq,) for one id, (n, nq) for an array of them."""

    def nearest_stored(self, point: list[float]) -> int:
        """A stored reachable posture at the map's own sample nearest the point, or -1 (then search ``stored``)."""

    def unreached(self) -> np.ndarray:
        """Points (m, dim) [m] the map knows it does not reach: how deep a point lies inside is its distance to them."""

    def index_at(self, points: np.ndarray, held: bool = True) -> np.ndarray:
        """The reachability index at points (n, dim): the share of approach directions reached, at the points the
        map holds (every point with ``held`` false); NaN elsewhere, or everywhere for a map without an index."""


def raster(m: ReachMap, level: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Occupancy of a regular grid of 2**level cells per axis over the map's box, and the cell edges per axis."""
    n = 1 << level
    edges = [np.linspace(lo, hi, n + 1) for lo, hi in zip(m.box.lo, m.box.hi, strict=True)]
    centres = [0.5 * (e[1:] + e[:-1]) for e in edges]
    grid = np.stack(np.meshgrid(*centres, indexing="ij"), axis=-1).reshape(-1, m.dim)
    return m.contains(grid, "vertex").reshape((n,) * m.dim), edges
