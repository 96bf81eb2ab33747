"""Routes through the postures stored at a tree's reachable vertices (the paper's stored postural data).

Two graphs over a strategy's stored postures: the motion graph checked at build time (:mod:`reach.maps.graph`),
whose shortest paths from the reference posture are taken as they are, and a graph linking each stored posture to its
nearest by the effector, weighted by posture distance, whose edges are checked lazily as a route is looked for. Either
route is then shortened by dropping every waypoint a direct segment can skip.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from reach.errors import MotionError
from reach.maps.atlas import Atlas
from reach.maps.graph import REACH, MotionGraph, graph_of
from reach.maps.tree import VATree
from reach.motion.holding import EDGE_HOLD, HOLD_STEP, Holding
from reach.motion.paths import Body, rounded
from reach.motion.timing import Frames, Timing, timed

NEIGHBOURS = 10  # stored vertices each one links to in the routing graph
ENTRIES = 12  # stored vertices tried as the route's first and last waypoints
ROUNDS = 100  # shortest paths tried before the route is given up
LAST_STRETCHES = 3  # stored postures near the end tried as the graph's last waypoint
JOINS = 4  # stored postures near a start that is not the reference tried as the graph's first waypoint

Near = tuple[cKDTree, np.ndarray, np.ndarray, csr_matrix]  # effector positions' k-d tree, postures, positions, links
Paths = tuple[csr_matrix, tuple[np.ndarray, np.ndarray]]  # a weighted graph and its shortest paths from the reference


class Routes:
    """The routes of one atlas's strategies (see the module docstring).

    Args:
        atlas: The atlas whose trees store the postures.
        holding: The planner's checks and holds (and its deadline).
        graph: Use the strategies' motion graphs where the atlas has them.
    """

    def __init__(self, atlas: Atlas, holding: Holding, graph: bool = True) -> None:
        self.atlas = atlas
        self.holding = holding
        self.use_graph = graph
        self._near: dict[str, Near] = {}
        self._paths: dict[str, Paths | None] = {}

    # -- the stored postures ----------------------------------------------------
    def near(self, name: str) -> Near:
        """The reachable stored vertices of a strategy: a k-d tree of their effector positions, their postures,
        those positions, and the graph linking each to its nearest, weighted by posture distance."""
        if name not in self._near:
            found = self.atlas.maps[name].stored()
            assert found is not None  # only strategies that store postures are routed
            rows, points, postures = found
            kd = cKDTree(points)
            k = min(NEIGHBOURS + 1, len(rows))
            _, near = kd.query(points, k=k)
            near = np.asarray(near).reshape(len(rows), k)
            a = np.repeat(np.arange(len(rows)), k - 1)
            b = near[:, 1:].ravel()
            w = np.linalg.norm(postures[a] - postures[b], axis=1) + 1e-9
            graph = csr_matrix((np.concatenate([w, w]), (np.concatenate([a, b]), np.concatenate([b, a]))),
                               shape=(len(rows), len(rows)))
            self._near[name] = (kd, postures, points, graph)
        return self._near[name]

    def nearest_stored(self, name: str, goal: np.ndarray) -> np.ndarray:
        """The stored posture whose effector lies nearest the goal."""
        kd, postures, _, _ = self.near(name)
        distance, i = kd.query(goal)
        if not np.isfinite(distance) or int(i) >= len(postures):  # a goal so far that its distance overflows
            raise MotionError(f"the goal {np.asarray(goal).tolist()} is too far from every stored posture to start a "
                              "motion towards it", "unreachable")
        return postures[int(i)].copy()  # type: ignore[no-any-return]

    def _nearby(self, name: str, point: np.ndarray, q: np.ndarray) -> list[int]:
        """The ``ENTRIES`` stored vertices nearest ``point`` by the effector, nearest to ``q`` in posture first."""
        kd, postures, _, _ = self.near(name)
        _, near = kd.query(point, k=min(ENTRIES, len(postures)))
        return sorted((i for i in np.atleast_1d(near).tolist() if i < len(postures)),
                      key=lambda i: float(np.linalg.norm(postures[i] - q)))

    # -- the motion graph ---------------------------------------------------------
    def motion_graph(self, name: str, oracle: Body) -> Paths | None:
        """The strategy's motion graph as a weighted graph (posture distance) over its stored postures and the
        reference (the last node), with the shortest paths from the reference; None without a graph."""
        if name not in self._paths:
            graph = self._stored_graph(name) if self.use_graph else None
            self._paths[name] = None if graph is None else self._weighted(name, graph, oracle)
        return self._paths[name]

    def _weighted(self, name: str, graph: MotionGraph, oracle: Body) -> Paths:
        _, postures, _, _ = self.near(name)
        n = len(postures)
        home = np.nonzero(graph.home)[0]
        a = np.concatenate([graph.edges[:, 0], home]).astype(np.int64)
        b = np.concatenate([graph.edges[:, 1], np.full(len(home), n)]).astype(np.int64)
        ends = np.vstack([postures, np.asarray(oracle.reference_posture(), float)[None]])
        w = np.linalg.norm(ends[a] - ends[b], axis=1) + 1e-9
        adjacency = csr_matrix((np.concatenate([w, w]), (np.concatenate([a, b]), np.concatenate([b, a]))),
                               shape=(n + 1, n + 1))
        dist, pred = dijkstra(adjacency, indices=n, return_predecessors=True)
        return adjacency, (dist, pred)

    def _stored_graph(self, name: str) -> MotionGraph | None:
        """The strategy's motion graph stored beside its tree, when it was made for that tree; else None."""
        tree = self.atlas.maps[name]
        # a graph missing, stale or unreadable: the planner plans every motion as without one
        return graph_of(self.atlas.path / f"{name}.npz", tree)[0] if isinstance(tree, VATree) else None

    def homeward(self, name: str, goal: np.ndarray, oracle: Body) -> list[np.ndarray]:
        """The stored postures nearest the goal that the strategy's motion graph reaches from the reference posture
        (at most ``LAST_STRETCHES``), nearest first; none without a graph."""
        paths = self.motion_graph(name, oracle)
        if paths is None:
            return []
        dist = paths[1][0]
        kd, postures, _, _ = self.near(name)
        _, near = kd.query(goal, k=min(ENTRIES, len(postures)))
        return [postures[i] for i in np.atleast_1d(near).tolist() if i < len(postures) and np.isfinite(dist[i])][
            :LAST_STRETCHES]

    def via_graph(self, name: str, oracle: Body, names: tuple[str, ...], q0: np.ndarray, q1: np.ndarray,
                  rate: float, timing: Timing) -> tuple[Frames, int] | None:
        """Frames along the strategy's motion graph and the stored postures they pass: from the start (the reference,
        the graph's home, or joined to a stored posture near it by a segment checked now), the shortest path over
        motions checked at build time to a stored posture near the end, then to the end; shortened where a direct
        segment holds, timed, and every frame checked. None when the strategy has no graph or no such path holds."""
        paths = self.motion_graph(name, oracle)
        if paths is None:
            return None
        adjacency, home = paths
        _, postures, _, _ = self.near(name)
        at_home = np.array_equal(q0, np.asarray(oracle.reference_posture(), float))
        entry = len(postures) if at_home else self._join(name, oracle, q0)
        if entry is None:
            return None
        dist, pred = home if at_home else dijkstra(adjacency, indices=entry, return_predecessors=True)
        for i in self._exits(name, oracle, q1, dist):
            self.holding.in_time()
            chain = [i]
            while chain[-1] != entry:
                chain.append(int(pred[chain[-1]]))
            found = self._through(oracle, names, [q0, *(postures[k] for k in reversed(chain) if k < len(postures)), q1],
                                  rate, timing)
            if found is not None:
                return found
        return None

    def _through(self, oracle: Body, names: tuple[str, ...], path: list[np.ndarray], rate: float,
                 timing: Timing) -> tuple[Frames, int] | None:
        """The frames through a graph path's waypoints whose every frame holds, tried shortened (and rounded) first,
        with the stored postures they pass; None when none holds."""
        # Through several stored postures, shortened first (the hand's path zigzags between them otherwise);
        # through one, as it is (it lies beside the end: a detour of a few cm). Each corner of a body on a fixed
        # root rounded first: turned at once, the hand's speed dropped by a third mid-stride at the stored posture
        # (docs/figures/motion_arm.png). A standing body's are not: its rounded frames, checked and then checked
        # again unrounded, doubled the whole body's median (27 -> 51 ms, bench/motion.py).
        shortened = self.holding.skipped(oracle, path) if len(path) > 3 else path
        root = [k for k, n in enumerate(names) if n.startswith("root_")]
        round_first = len(shortened) > 2 and all(np.array_equal(w[root], path[0][root]) for w in shortened)
        tries = ([rounded(oracle, shortened)] if round_first else []) + [shortened]
        for waypoints in tries + ([path] if len(shortened) < len(path) else []):
            frames = timed(oracle, names, waypoints, rate, timing)
            # Every frame checked: the build's samples, ``STEP`` apart, miss brushes between them (a frame of a
            # whole-body motion in 30 broke the balance or a collision where every sample held).
            if not any(any(f) for f in self.holding.faults(oracle, frames[0][1:])):
                return frames, (len(path) if waypoints is path else len(shortened)) - 2
        return None

    def _exits(self, name: str, oracle: Body, q1: np.ndarray, dist: np.ndarray) -> Iterator[int]:
        """Stored postures near the end that the graph reaches (finite ``dist``), no more than the graph's edges'
        ``REACH`` from it in posture, whose segment to the end holds (checked at postures ``EDGE_STEP`` apart, one at
        a time as they are asked for); nearest in posture first, at most ``LAST_STRETCHES``."""
        _, postures, _, _ = self.near(name)
        goal = np.asarray(oracle.effector_positions(q1[None]))[0]
        near = [i for i in self._nearby(name, goal, q1) if np.isfinite(dist[i])]
        linked = (i for i in near if np.linalg.norm(postures[i] - q1) <= REACH
                  and self.holding.holds(oracle, postures[i], q1))
        yield from itertools.islice(linked, LAST_STRETCHES)

    def _join(self, name: str, oracle: Body, q0: np.ndarray) -> int | None:
        """A stored posture near a start that is not the reference, linked to it by a segment that holds (checked
        now, at postures ``EDGE_STEP`` apart): the nearest in posture of the ``ENTRIES`` nearest by the effector,
        trying at most ``JOINS``; None when none does."""
        _, postures, _, _ = self.near(name)
        start = np.asarray(oracle.effector_positions(q0[None]))[0]
        return next((i for i in self._nearby(name, start, q0)[:JOINS] if self.holding.holds(oracle, q0, postures[i])),
                    None)

    # -- routing through stored postures, checked now ---------------------------------
    def route(self, name: str, oracle: Body, q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray]:
        """Waypoints from q0 to q1 through stored postures whose segments hold every task (lazily checked), then
        shortened."""
        _, postures, _, graph = self.near(name)
        graph = graph.tolil()
        ends = np.asarray(oracle.effector_positions(np.stack([q0, q1])))
        # The route's ends link by segments held as closely as its inner ones, or failing that as closely as frames are.
        firsts = self._entries(name, ends[0], q0, oracle, True) or self._entries(name, ends[0], q0, oracle, True,
                                                                                  HOLD_STEP)
        lasts = self._entries(name, ends[1], q1, oracle, False) or self._entries(name, ends[1], q1, oracle, False,
                                                                                 HOLD_STEP)
        if not firsts or not lasts:
            raise MotionError(f"no motion of strategy {name} found: no stored posture near the start or the end "
                              "links to it")
        good: set[tuple[int, int]] = set()
        for _ in range(ROUNDS):
            dist, pred = dijkstra(graph.tocsr(), indices=firsts[0], return_predecessors=True)
            last = min(lasts, key=lambda j: dist[j])
            if not np.isfinite(dist[last]):
                break
            chain = [last]
            while chain[-1] != firsts[0]:
                chain.append(int(pred[chain[-1]]))
            broken = self._broken_link(oracle, postures, chain[::-1], good)
            if broken is None:
                return self.holding.shorten(oracle, [q0, *postures[chain[::-1]], q1])
            graph[broken[0], broken[1]] = graph[broken[1], broken[0]] = 0.0  # lil: an explicit zero removes the edge
        raise MotionError(f"no motion of strategy {name} found through its stored postures that holds every task")

    def _broken_link(self, oracle: Body, postures: np.ndarray, chain: list[int],
                     good: set[tuple[int, int]]) -> tuple[int, int] | None:
        """The first link of the chain whose segment cannot be held (links found good are added to ``good``)."""
        for a, b in zip(chain[:-1], chain[1:], strict=True):
            if (a, b) not in good:
                if not self.holding.clear(oracle, postures[a], postures[b]):
                    return a, b
                good.add((a, b))
        return None

    def _entries(self, name: str, point: np.ndarray, q: np.ndarray, oracle: Body, first: bool,
                 limit: float = EDGE_HOLD) -> list[int]:
        """Stored vertices near ``point`` linked to ``q`` by a segment that holds (from q when ``first``, else to it),
        nearest in posture first: one for the route's start, up to three for its end."""
        _, postures, _, _ = self.near(name)
        linked = (i for i in self._nearby(name, point, q)
                  if (self.holding.clear(oracle, q, postures[i], limit) if first
                      else self.holding.clear(oracle, postures[i], q, limit)))
        return list(itertools.islice(linked, 1 if first else 3))
