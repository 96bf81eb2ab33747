"""Where to stand, sit or mount: placements of a body that reach a layout's targets.

A placement puts the body's world frame (the frame its trees are built in:
for the generated human, the floor between the ankles, x forward) at a
position ``(x, y, z)`` [m] of the layout's frame, turned by ``yaw`` [rad]
about z: a target ``t`` of the layout lies at ``Rz(-yaw) (t - position)`` in
the body's frame. The trees never move; only the targets do, so that every
candidate of a grid is scored by the trees' vectorised lookups at once.

Per body (an atlas; several atlases are a population) and candidate, each
target is taken by the first strategy of its effector, by priority, whose
tree holds it (the ``vertex`` policy by default), as the selector chooses.
Candidates are ranked, best first, by

1. the share of bodies *accommodated* (reaching every target, or the share ``need`` of them; bodies weighted by
   ``body_weights``, a population's members' weights);
2. the share of targets reached, over bodies;
3. the mean strategy weight of the targets, over bodies (0 for a target no
   strategy reaches): the effector's k-th strategy by priority weighs
   ``max(1 - 0.2 k, 0.2)`` (arm only 1, upper body 0.8, whole body 0.6,
   crouch 0.4 in the shipped human atlases): the fewer joints a reach
   needs, the better the placement. A modelling choice, not a measured
   figure; ``weights`` overrides it per strategy name;
4. on a tie, the *margin*: how deep inside the volumes the targets lie, the
   least over bodies and targets of the distance [m] from a target to the
   nearest stored vertex its strategy's tree does not reach (the surface is
   within half a cell of it). The middle of the tie is not preferred: on a
   robot's table it stood the base among the targets, where the trees'
   boundary cells claim what no posture reaches (docs/decisions/0024);
5. then the nearness to the centroid of the tied candidates.

The best few are then verified: each target is asked of the selector, refined
by IK at the moved target (a target the trees hold but no posture reaches
counts as unreached), the verified figures are reported beside the trees'
claim, and the verified candidates are ranked again among themselves by them
(bodies accommodated, then targets reached), the trees' order breaking ties.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from reach.answers.evaluate import Target, to_body
from reach.answers.select import Selector
from reach.errors import InputError, ReachError
from reach.maps.atlas import Atlas
from reach.maps.protocol import POLICIES, Policy

# each later strategy by priority weighs this much less (a modelling choice; see the module docstring)
WEIGHT_STEP = 0.2
WEIGHT_FLOOR = 0.2  # ... and never less than this
MAX_CANDIDATES = 1_000_000  # candidates of one ranking at most
VERIFY_BUDGET = 1.0  # [s] refinement budget per target when verifying
MARGIN_TIES = 5000  # tied best candidates whose margin is measured at most (each a k-d tree query per target and body)
# k-d tree queries of the margins at most (tied candidates x targets): 1,681 tied candidates x 1,000 targets held a
# server's worker for over 1,000 s (measured with commit 0059659); this many take about 0.1 s
MARGIN_QUERIES = 200_000
# points a tree's lookup (0.3 s for 1.68 M quiet; 1 s beside two CPU-bound processes, a worker's nice 5) or a k-d tree
# query takes at once between two looks at the deadline
CONTAINS_CHUNK = 100_000
KD_CHUNK = 20_000


class PastDeadline(ReachError):
    """A ranking stopped at its deadline (a server's ``place``); its reply is ``timeout``."""

    code = "timeout"


@dataclass(frozen=True)
class Space:
    """The candidate placements: a grid of positions [m] and headings [rad].

    Each axis is ``(min, max)`` sampled every ``step`` [m] (a single value
    when min equals max); ``yaw`` is ``(min, max)`` sampled every
    ``yaw_step`` [rad], the max left out when the range is a full turn.
    """

    x: tuple[float, float]
    y: tuple[float, float]
    z: tuple[float, float] = (0.0, 0.0)
    yaw: tuple[float, float] = (0.0, 0.0)
    step: float = 0.05
    yaw_step: float = math.radians(15.0)
    max_candidates: int = MAX_CANDIDATES

    def __post_init__(self) -> None:
        for name in ("x", "y", "z", "yaw"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise InputError(name, f"expected min <= max, finite, got {lo!r}, {hi!r}")
        if not (self.step > 0 and self.yaw_step > 0):
            raise InputError("step", f"expected positive steps, got {self.step!r} m and {self.yaw_step!r} rad")
        count = math.prod(len(a) for a in self._axes())
        if count > self.max_candidates:
            raise InputError("step", f"{count} candidates; at most {self.max_candidates}: coarsen the steps or "
                                     "narrow the ranges")

    @staticmethod
    def _axis(lo: float, hi: float, step: float, turn: bool = False) -> np.ndarray:
        count = (hi - lo) / step  # inf for a step of 1e-320 or a range of +-1e308: refused below, not an overflow
        if not math.isfinite(count) or count + 1 > MAX_CANDIDATES:
            raise InputError("step", f"{count + 1:.3g} values on one axis; at most {MAX_CANDIDATES} candidates: "
                                     "coarsen the steps or narrow the ranges")
        n = int(math.floor(count + 1e-9)) + 1
        values = lo + step * np.arange(n)
        if turn and hi - lo >= 2 * math.pi - 1e-9:
            values = values[values < lo + 2 * math.pi - 1e-9]
        return values

    def _axes(self) -> list[np.ndarray]:
        return [self._axis(*self.x, self.step), self._axis(*self.y, self.step), self._axis(*self.z, self.step),
                self._axis(*self.yaw, self.yaw_step, turn=True)]

    def candidates(self) -> np.ndarray:
        """(C, 4) placements: x, y, z [m] and yaw [rad]."""
        return np.stack(np.meshgrid(*self._axes(), indexing="ij"), axis=-1).reshape(-1, 4)


@dataclass
class Ranking:
    """The scored candidates, best first, and what the figures need.

    Attributes:
        placements: (C, 4) x, y, z [m], yaw [rad], best first.
        accommodated: (C,) share of bodies reaching every target.
        reached: (C,) share of targets reached, over bodies.
        preference: (C,) mean strategy weight, over bodies and targets.
        margin: (C,) the least depth [m] of a reached target inside its strategy's volume, measured for the tied best
            candidates (NaN elsewhere; inf when no tree has an unreachable vertex).
        strategies: (C, B, T) index of the strategy taking each target per body (-1: none), in the names' order.
        names: Per body, its strategy names in ``strategies``' numbering.
        verified: The best placements verified by IK: one dict each (see :func:`verify`).
    """

    placements: np.ndarray
    accommodated: np.ndarray
    reached: np.ndarray
    preference: np.ndarray
    strategies: np.ndarray
    names: list[list[str]]
    margin: np.ndarray = field(default_factory=lambda: np.zeros(0))
    verified: list[dict[str, Any]] = field(default_factory=list)

    def row(self, k: int, targets: Sequence[Target]) -> dict[str, Any]:
        """Candidate k as a JSON-compatible dict."""
        x, y, z, yaw = (float(v) for v in self.placements[k])
        by = [{t.name: (names[s] if s >= 0 else None) for t, s in zip(targets, self.strategies[k, b], strict=True)}
              for b, names in enumerate(self.names)]
        margin = float(self.margin[k]) if k < len(self.margin) and np.isfinite(self.margin[k]) else None
        return {"rank": k + 1, "position": [x, y, z], "yaw_deg": math.degrees(yaw),
                "accommodated": float(self.accommodated[k]),
                "reached": float(self.reached[k]), "preference": float(self.preference[k]), "margin": margin,
                "strategies": by}


def weights_of(atlas: Atlas, effector: str, overrides: dict[str, float] | None = None) -> tuple[list[str], np.ndarray]:
    """An effector's strategies by priority and their weights (see the module docstring)."""
    names = [s["name"] for s in sorted(atlas.strategies, key=lambda s: s["priority"]) if s["effector"] == effector]
    if not names:
        raise InputError("effector", f"{atlas.path}: no strategy for effector {effector!r}")
    w = np.array([max(1.0 - WEIGHT_STEP * k, WEIGHT_FLOOR) for k in range(len(names))])
    for k, n in enumerate(names):
        if overrides and n in overrides:
            w[k] = float(overrides[n])
    return names, w


def rank(atlases: Sequence[Atlas], targets: Sequence[Target], space: Space, effector: str | None = None,
         policy: Policy = "vertex", weights: dict[str, float] | None = None,
         deadline: float | None = None, body_weights: np.ndarray | None = None, need: float = 1.0) -> Ranking:
    """Score every candidate of the space against the targets by the trees (see the module docstring); best first.

    ``deadline`` (``time.perf_counter()``): checked between chunks of the trees' lookups and of the margins' queries;
    past it, PastDeadline.
    ``body_weights`` (B,): the bodies' weights (default equal); ``need``: the share of targets a body must reach to be
    accommodated (default all).
    """

    def in_time() -> None:
        if deadline is not None and time.perf_counter() > deadline:
            raise PastDeadline("the placement was not ranked by its deadline")

    _check_request(atlases, targets, policy)
    placements = space.candidates()
    points = np.array([t.point for t in targets], float)
    n_c, n_t = len(placements), len(targets)
    moved = np.empty((n_c, n_t, 3))
    step = max(1, CONTAINS_CHUNK // n_t)
    for a in range(0, n_c, step):  # 1.68 M points moved at once held a worker 0.3 s (its first call), 2 s beside load
        in_time()
        moved[a : a + step] = to_body(points, placements[a : a + step])
    body = moved.reshape(-1, 3)
    taken = np.full((n_c, len(atlases), n_t), -1, np.int16)
    weight = np.zeros((n_c, len(atlases), n_t))
    all_names = [_held_by(atlas, targets, body.reshape(n_c, n_t, 3), effector, weights, policy, in_time,
                          taken[:, b], weight[:, b]) for b, atlas in enumerate(atlases)]
    reached_bt = taken >= 0
    w = _body_weights(body_weights, len(atlases))
    accommodated = _accommodated(reached_bt, need) @ w
    reached = reached_bt.mean(axis=2) @ w
    preference = weight.mean(axis=2) @ w
    # Lexicographic, best first; ties broken by the margin, then by nearness to the tied candidates' centroid
    # (positions, and headings on the circle).
    key = np.round(np.stack([accommodated, reached, preference], axis=1), 9)
    top = np.all(key == key[np.lexsort(key.T[::-1])[-1]], axis=1)
    spread = _spread(placements, top)
    margin = np.full(n_c, np.nan)
    tied = np.nonzero(top)[0]
    distinct, same = np.unique(points, axis=0, return_inverse=True)  # a repeated target is queried once
    tied = tied[np.argsort(spread[tied], kind="stable")][:max(1, min(MARGIN_TIES, MARGIN_QUERIES // len(distinct)))]
    in_time()
    margin[tied] = margins(atlases, all_names, taken[tied], body.reshape(n_c, n_t, 3)[tied], in_time, same.ravel())
    order = np.lexsort((spread, -np.nan_to_num(margin, nan=-np.inf), -preference, -reached, -accommodated))
    return Ranking(placements[order], accommodated[order], reached[order], preference[order], taken[order], all_names,
                   margin[order])


def _check_request(atlases: Sequence[Atlas], targets: Sequence[Target], policy: str) -> None:
    """A ranking's atlases, targets and policy, or InputError naming the field."""
    if not atlases or not targets:
        raise InputError("targets" if atlases else "atlases", "expected at least one atlas and one target")
    on_body = [t.name for t in targets if t.relative_to]
    if on_body:
        # A target on the body moves with it: no placement brings it nearer.
        raise InputError("targets", f"{on_body[0]} is given on the body (relative_to), which moves with the body: "
                                    "placement ranks targets in the layout's frame only")
    if policy not in POLICIES:
        raise InputError("policy", f"expected one of {', '.join(POLICIES)}, got {policy!r}")


def _held_by(atlas: Atlas, targets: Sequence[Target], body: np.ndarray, effector: str | None,
             weights: dict[str, float] | None, policy: Policy, in_time: Callable[[], None], taken: np.ndarray,
             weight: np.ndarray) -> list[str]:
    """Which strategy of one atlas first holds each target at each candidate (``taken`` (C, T), -1: none) and its
    weight (``weight`` (C, T)), filled in place from the targets in the body's frame ``body`` (C, T, 3); the
    atlas's strategies in the order ``taken`` counts them."""
    n_c = len(body)
    names_b: list[str] = []
    for eff in sorted({t.effector or effector or "" for t in targets}):
        if not eff:
            raise InputError("effector", "a target has no effector: give an effector column or --effector")
        cols = np.array([k for k, t in enumerate(targets) if (t.effector or effector) == eff])
        names, w = weights_of(atlas, eff, weights)
        sub = body[:, cols].reshape(-1, 3)
        open_ = np.ones((n_c, len(cols)), bool)
        for k, name in enumerate(names):
            held = np.empty(len(sub), bool)
            for a in range(0, len(sub), CONTAINS_CHUNK):  # the deadline looked at between chunks
                in_time()
                held[a : a + CONTAINS_CHUNK] = atlas.maps[name].contains(sub[a : a + CONTAINS_CHUNK], policy)
            held = held.reshape(n_c, len(cols)) & open_
            taken[:, cols] = np.where(held, len(names_b) + k, taken[:, cols])
            weight[:, cols] = np.where(held, w[k], weight[:, cols])
            open_ &= ~held
        names_b += names
    return names_b


def _spread(placements: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Each candidate's distance from the centroid of the ``top`` ones: positions [m], and headings on the circle
    (a tenth of a radian's weight)."""
    centre = placements[top, :3].mean(axis=0)
    heading = math.atan2(np.sin(placements[top, 3]).mean(), np.cos(placements[top, 3]).mean())
    return np.linalg.norm(placements[:, :3] - centre,  # type: ignore[no-any-return]
                          axis=1) + 0.1 * np.abs(np.angle(np.exp(1j * (placements[:, 3] - heading))))


def _body_weights(body_weights: np.ndarray | None, n: int) -> np.ndarray:
    """The bodies' weights normalised to sum 1 (equal by default)."""
    w = np.ones(n) if body_weights is None else np.asarray(body_weights, float).reshape(-1)
    if len(w) != n or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise InputError("weights", f"expected {n} body weights >= 0, not all 0, got {w.tolist()}")
    return w / w.sum()


def _accommodated(reached: np.ndarray, need: float) -> np.ndarray:
    """Per body (last-but-one axis), whether it reaches the share ``need`` of the targets (last axis)."""
    if not 0.0 < need <= 1.0:
        raise InputError("need", f"expected a share of targets in (0, 1], got {need!r}")
    return reached.mean(axis=-1) >= need - 1e-9


def margins(atlases: Sequence[Atlas], names: list[list[str]], taken: np.ndarray, points: np.ndarray,
            in_time: Any = None, same: np.ndarray | None = None) -> np.ndarray:
    """Per candidate, the least distance [m] from a reached target (its point in the body's frame, ``points``
    (C, T, 3)) to the nearest vertex of its strategy's tree that does not reach (``taken``: (C, B, T), see
    :class:`Ranking`); inf when no reached target's tree has such a vertex. ``same`` (T,): targets at one point share
    a number (default: each its own)."""
    same = np.arange(points.shape[1]) if same is None else same
    out = np.full(len(points), np.inf)
    for b, atlas in enumerate(atlases):
        for s, name in enumerate(names[b]):
            c, t = np.nonzero(taken[:, b] == s)
            if not c.size:
                continue
            outside = atlas.maps[name].unreached()
            if not len(outside):
                continue
            # A layout's repeated point is asked once a candidate (1,000 identical targets held a worker in one
            # query), and the rest in chunks with the deadline looked at between them.
            pairs, first, back = np.unique(c * len(same) + same[t], return_index=True, return_inverse=True)
            asked = points[c[first], t[first]]
            tree, depth = cKDTree(outside), np.empty(len(pairs))
            for a in range(0, len(asked), KD_CHUNK):
                if in_time is not None:
                    in_time()
                depth[a : a + KD_CHUNK] = tree.query(asked[a : a + KD_CHUNK])[0]
            np.minimum.at(out, c, depth[back.ravel()])
    return out


def verify(ranking: Ranking, atlases: Sequence[Atlas], targets: Sequence[Target], best: int = 5,
           effector: str | None = None,
           policy: Policy = "vertex", budget: float = VERIFY_BUDGET, body_weights: np.ndarray | None = None,
           need: float = 1.0) -> list[dict[str, Any]]:
    """The best placements checked by IK: per placement, the share of bodies accommodated and of targets reached when
    each target, moved into the body's frame, is answered by the selector with refinement (unreached when no posture
    reaches it); also stored in ``ranking.verified``."""
    selectors = [Selector(a, policy, refine=True, budget=budget, miss="unreachable") for a in atlases]
    points = np.array([t.point for t in targets], float)
    out = []
    count = min(best, len(ranking.placements))
    for k in range(count):
        body = to_body(points, ranking.placements[k : k + 1])[0]
        ok = np.array([[s.select(t.effector or effector or "", p).reachable
                        for t, p in zip(targets, body, strict=True)] for s in selectors])
        w = _body_weights(body_weights, len(atlases))
        reached = float(ok.mean(axis=1) @ w)
        out.append({"rank": k + 1, "trees_rank": k + 1, "accommodated": float(_accommodated(ok, need) @ w),
                    "reached": reached, "claimed_reached": float(ranking.reached[k]),
                    "agree": bool(np.isclose(reached, ranking.reached[k]))})
    # The verified candidates ranked again by what IK verified (stable: the trees' order breaks ties).
    again = sorted(range(count), key=lambda k: (-out[k]["accommodated"], -out[k]["reached"]))
    if again != list(range(count)):
        idx = np.array(again + list(range(count, len(ranking.placements))))
        for name in ("placements", "accommodated", "reached", "preference", "strategies", "margin"):
            values = getattr(ranking, name)
            if len(values) == len(idx):
                setattr(ranking, name, values[idx])
        out = [{**out[k], "rank": r + 1} for r, k in enumerate(again)]
    ranking.verified = out
    return out
