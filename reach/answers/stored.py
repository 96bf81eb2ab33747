"""The stored postures of an atlas as answers look them up: the nearest to a goal, their index, their JSON.

Per strategy, a k-d tree over the goals its stored postures reach and where each puts the effector, built once (at
warm-up for a server), so that a request costs one k-d tree query; and a bounded cache of stored postures encoded as
an answer's JSON.
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from reach.answers.answer import split_posture
from reach.maps.protocol import ReachMap

POSTURE_CACHE = 4096  # stored postures kept encoded, most recently used first


class Lookup(NamedTuple):
    """A strategy's stored postures as the selector looks them up (built once, at warm-up for a server)."""

    kd: cKDTree  # over the goals the stored postures reach
    ids: np.ndarray  # (n,) their ids in the map, in the k-d tree's order
    reached: np.ndarray  # (size, 3) by id: where each posture puts the effector [m] (NaN for no stored posture)
    share: np.ndarray  # (size,) by id: the reachability index where it was stored (NaN: the map has none)


class StoredPostures:
    """The atlas's stored postures by strategy (see the module docstring).

    Args:
        maps: The atlas's trees by strategy.
        effector_positions: Where a strategy's postures (n, nq) put its effector [m] (NaN where its oracle cannot
            tell).
    """

    def __init__(self, maps: Mapping[str, ReachMap],
                 effector_positions: Callable[[str, np.ndarray], np.ndarray]) -> None:
        self.maps, self.effector_positions = maps, effector_positions
        self._kd: dict[str, Lookup | None] = {}
        self._postures: OrderedDict[tuple[str, int],
                                    tuple[dict[str, float], dict[str, list[float]] | None, bytes]] = OrderedDict()

    def lookup(self, name: str) -> Lookup | None:
        """The strategy's lookup structure (None when it stores no posture)."""
        self.nearest(name, self.maps[name].box.lo[None])
        return self._kd[name]

    def nearest(self, name: str, goals: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Ids of the nearest reachable stored postures and where they put the effector [m].

        The k-d tree and the effector positions are computed once per strategy
        (at warm-up for a server), so a request costs one k-d tree query.
        """
        if name not in self._kd:
            tree = self.maps[name]
            found = tree.stored()
            self._kd[name] = None
            if found is not None and len(found.ids):
                size = int(found.ids.max()) + 1
                reached, index = np.full((size, 3), np.nan), np.full(size, np.nan)
                reached[found.ids] = self.effector_positions(name, found.postures)
                # Once here, not per answer: the index at each stored goal (its own vertex's for a tree).
                index[found.ids] = tree.index_at(found.points, held=False)
                self._kd[name] = Lookup(cKDTree(found.points), found.ids, reached, index)
        lookup = self._kd[name]
        if lookup is None:
            return None
        _, i = lookup.kd.query(goals)
        rows = lookup.ids[np.asarray(i)]
        return rows, lookup.reached[rows]

    def nearest_row(self, name: str, goal: list[float]) -> tuple[int, np.ndarray] | None:
        """The nearest reachable stored posture of one goal: its id and effector position.

        Usually the map's sample nearest to the goal is reachable and found
        by one lookup; otherwise the k-d tree answers.
        """
        if name not in self._kd:
            self.nearest(name, np.asarray([goal]))
        found = self._kd[name]
        if found is None:
            return None
        row = self.maps[name].nearest_stored(goal)
        if row >= 0:
            return row, found.reached[row]
        rows, eff = self.nearest(name, np.asarray([goal]))  # type: ignore[misc]
        return int(rows[0]), eff[0]

    def index_of(self, name: str, row: int) -> float | None:
        """The reachability index where a stored posture was stored (None when the map has none)."""
        found = self._kd.get(name)
        if found is None or row < 0:
            return None
        value = float(found.share[row])
        return None if math.isnan(value) else value

    def neighbours(self, name: str, goal: np.ndarray, k: int) -> np.ndarray | None:
        """The strategy's k stored postures (k, nq) nearest the goal, or None when it stores none."""
        found = self._kd.get(name)
        if found is None:
            return None
        _, near = found.kd.query(goal, k=min(k, len(found.ids)))
        return self.maps[name].postures(found.ids[np.atleast_1d(near)])

    def encoded(self, name: str, row: int) -> tuple[dict[str, float], dict[str, list[float]] | None, bytes]:
        """The stored posture of a vertex as dicts and as encoded JSON, from a bounded cache.

        The dicts are shared between answers: treat them as read-only.
        """
        key = (name, row)
        hit = self._postures.get(key)
        if hit is None:
            tree = self.maps[name]
            posture, root = split_posture(tree.posture_names, tree.postures(row))
            fragment = json.dumps({"posture": posture, "root": root}, separators=(",", ":")).encode()[1:-1]
            hit = self._postures[key] = (posture, root, fragment)
            if len(self._postures) > POSTURE_CACHE:
                self._postures.popitem(last=False)
        else:
            self._postures.move_to_end(key)
        return hit
