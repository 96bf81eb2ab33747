"""No segment through another: ``{type: self_collision, margin: 0.01, exclude: [[a, b], ...]}``.

Every pair of the body's collision capsules (:mod:`oracles.collision`) keeps
``margin`` [m] between them, except

* adjacent segments: capsules on one joint, or on joints with no capsule
  between them in the tree (the upper arm and the thorax, across the
  shoulder girdle);
* pairs that no active joint moves relative to each other (their distance
  is a constant);
* pairs the config excludes (``exclude``, capsule names or glob patterns),
  or that involve none of the capsules ``only`` names (when given: e.g. the
  reaching hand and forearm, the segments that pass through the trunk in
  whole-body reaches; each pair costs solver time).

A pair already closer than the margin at the reference posture (the hanging
forearm against the waist) keeps its reference clearance instead: it may not
come closer than it stands, so the hand still cannot pass through the trunk.
These pairs are listed by ``reach model``.

In ``casadi-ik`` each pair is one constraint row: the squared distance of
the two capsules' segments (a piecewise-smooth closed form) at least the sum
of their radii and the clearance, squared. The task is *lazy*: the engine
first solves without it and adds it only when that posture collides (most
postures do not), so the pairs cost time only where they matter. In ``dls``
the pairs closer than the margin plus a buffer become inequality rows along
the line of their nearest points. The verdict is coal's
(``pinocchio.computeDistances`` on the capsules): no pair closer than its
clearance (0 for most pairs), within 0.1 mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.collision import CollisionModel, nearest_points
from oracles.tasks.base import (
    Constraint,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    number,
    relative_motion,
    world_point,
)
from oracles.tasks.contacts import BUFFER, INSIDE
from reach.errors import TaskError

MARGIN = 0.01  # [m] default clearance between segments
CHECK_TOL = 1e-4  # [m] the verdict's tolerance on coal's distance
# [m] how much deeper than at the reference posture the verdict lets a pair in
# contact there go (soft tissue): the hanging hand against the thigh may
# press a little, not pass through.
CONTACT_GIVE = 0.01


@dataclass(frozen=True)
class Pair:
    """Two capsules (indices in the collision model) kept ``clearance`` [m] apart."""

    first: int
    second: int
    clearance: float
    floor: float  # [m] the least coal distance the verdict accepts


def _adjacent(model: pin.Model, bearing: set[int], a: int, b: int) -> bool:
    """One joint, or one an ancestor of the other with no capsule-bearing joint between them."""
    if a == b:
        return True
    for lo, hi in ((a, b), (b, a)):
        j = int(model.parents[lo])
        while j > 0 and j != hi and j not in bearing:
            j = int(model.parents[j])
        if j == hi:
            return True
    return False


def _clamp(v: ca.SX) -> ca.SX:
    return ca.fmin(ca.fmax(v, 0.0), 1.0)


def segment_segment_sq(p: ca.SX, q: ca.SX, a: ca.SX, b: ca.SX) -> ca.SX:
    """Squared distance between segments p-q and a-b, as one CasADi expression.

    The clamped closed form of :func:`oracles.collision.nearest_points`
    (Ericson, *Real-Time Collision Detection*, 2005, 5.1.9): piecewise
    smooth, continuous, and one constraint row per pair of capsules.
    """
    d1, d2, r = q - p, b - a, p - a
    aa, ee, f = ca.dot(d1, d1) + 1e-12, ca.dot(d2, d2) + 1e-12, ca.dot(d2, r)
    c, bb = ca.dot(d1, r), ca.dot(d1, d2)
    den = aa * ee - bb * bb
    s = _clamp((bb * f - c * ee) / (den + 1e-12))
    t = (bb * s + f) / ee
    s = ca.if_else(t < 0, _clamp(-c / aa), ca.if_else(t > 1, _clamp((bb - c) / aa), s))
    t = _clamp(t)
    return ca.sumsqr((p + s * d1) - (a + t * d2))


@dataclass
class SelfCollisionTask(HardTask):
    """Keep every non-adjacent pair of segments apart (see the module docstring)."""

    type: ClassVar[str] = "self_collision"
    lazy: ClassVar[bool] = True
    keys: ClassVar[frozenset[str]] = frozenset({"margin", "exclude", "only"})
    summary: ClassVar[str] = "no two non-adjacent segments' capsules closer than `margin` [m] (default 1 cm); `exclude` more pairs"

    margin: float = MARGIN
    pairs: tuple[Pair, ...] = ()
    at_reference: tuple[tuple[str, str, float], ...] = ()  # pairs closer than the margin at the reference: names, distance [m]
    _model: CollisionModel | None = field(default=None, repr=False, compare=False)
    _floors: np.ndarray = field(default_factory=lambda: np.zeros(0), init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> SelfCollisionTask:
        margin = number(raw.get("margin", MARGIN), f"{where}.margin", 0.0, 0.2)
        model = scope.body.collision
        if not model.placed:
            raise TaskError(where, f"{scope.body.source}: the body has no collision geometry")
        excluded: set[frozenset[str]] = set()
        exclude = raw.get("exclude", [])
        if not isinstance(exclude, list) or not all(isinstance(e, list) and len(e) == 2 and all(isinstance(n, str) for n in e) for e in exclude):
            raise TaskError(f"{where}.exclude", f"expected a list of [capsule, capsule] pairs, got {exclude!r}")
        try:
            for a, b in exclude:
                excluded.update(frozenset((x, y)) for x in model.names([a]) for y in model.names([b]))
        except Exception as exc:
            raise TaskError(f"{where}.exclude", str(exc)) from exc
        only_raw = raw.get("only")
        if only_raw is not None and (not isinstance(only_raw, list) or not all(isinstance(n, str) for n in only_raw)):
            raise TaskError(f"{where}.only", f"expected a list of capsule names or patterns, got {only_raw!r}")
        try:
            only = set(model.names(only_raw)) if only_raw is not None else None
        except Exception as exc:
            raise TaskError(f"{where}.only", str(exc)) from exc
        pm = scope.body.model
        bearing = {p.joint for p in model.placed}
        candidates = []
        for i, pi in enumerate(model.placed):
            for j in range(i + 1, len(model.placed)):
                pj = model.placed[j]
                if frozenset((pi.name, pj.name)) in excluded or _adjacent(pm, bearing, pi.joint, pj.joint):
                    continue
                if only is not None and pi.name not in only and pj.name not in only:
                    continue
                if relative_motion(pm, pi.joint, pj.joint, scope.active):
                    candidates.append((i, j))
        ref = model.distances(scope.body.q_ref, candidates)
        pairs, close = [], []
        for (i, j), d in zip(candidates, ref, strict=True):
            clearance = margin if d >= margin else float(d)
            if d < margin:
                close.append((model.placed[i].name, model.placed[j].name, round(float(d), 4)))
            pairs.append(Pair(i, j, clearance, clearance - CHECK_TOL if d >= margin else min(0.0, clearance) - CONTACT_GIVE))
        return cls(margin, tuple(pairs), tuple(close))

    def bind(self, reference: Reference) -> None:
        self._model = reference.body.collision
        self._floors = np.array([p.floor for p in self.pairs])

    def describe(self) -> dict[str, Any]:
        names = [p.name for p in self._model.placed] if self._model else []
        return {
            **super().describe(), "margin": self.margin,
            "pairs": [[names[p.first], names[p.second]] for p in self.pairs] if names else len(self.pairs),
            "at_reference": [{"pair": [a, b], "distance": d} for a, b, d in self.at_reference],
        }

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        assert self._model is not None
        rows, lo = [], []
        for pair in self.pairs:
            s, o = self._model.placed[pair.first], self._model.placed[pair.second]
            a, b = world_point(sym, o.joint, o.a), world_point(sym, o.joint, o.b)
            reach = s.radius + o.radius + pair.clearance
            rows.append(segment_segment_sq(world_point(sym, s.joint, s.a), world_point(sym, s.joint, s.b), a, b))
            lo.append(reach * abs(reach))
        return [Constraint(row, bound, np.inf) for row, bound in zip(rows, lo, strict=True)]

    def distances(self, q: np.ndarray) -> np.ndarray:
        """Coal's distance [m] of every pair at q."""
        assert self._model is not None
        return self._model.distances(q, [(p.first, p.second) for p in self.pairs])

    def rows(self, num: Numeric) -> list[Row]:
        assert self._model is not None
        out = []
        for pair in self.pairs:
            s, o = self._model.placed[pair.first], self._model.placed[pair.second]
            pa, pb = self._model.world(num.data, pair.first)
            qa, qb = self._model.world(num.data, pair.second)
            ps, po, gap = nearest_points(pa, pb, qa, qb)
            gap -= s.radius + o.radius
            if gap >= pair.clearance + BUFFER:
                continue
            n = (ps - po) / max(np.linalg.norm(ps - po), 1e-9)
            jac = n @ (num.point_jacobian(s.joint, ps) - num.point_jacobian(o.joint, po))
            out.append(Row(jac[None], np.array([max(0.0, pair.clearance + INSIDE - gap)])))
        return out

    def holds(self, num: Numeric) -> bool:
        if not self.pairs:
            return True
        return bool(np.all(self.distances(num.q) >= self._floors))
