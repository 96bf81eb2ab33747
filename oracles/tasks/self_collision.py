"""No segment through another: ``{type: self_collision, margin: 0.01, exclude: [[a, b], ...]}``.

Every pair of the body's collision capsules (:mod:`oracles.collision`) keeps
``margin`` [m] between them, except

* adjacent segments: capsules on one joint, or on joints with no capsule
  between them in the tree (the upper arm and the thorax, across the
  shoulder girdle);
* pairs that no active joint moves relative to each other (their distance
  is a constant);
* pairs the config excludes (``exclude``, capsule names or glob patterns).

A pair already closer than the margin at the reference posture (the hanging
forearm against the waist) keeps its reference clearance instead: it may not
come closer than it stands, so the hand still cannot pass through the trunk.
These pairs are listed by ``reach model``.

In ``casadi-ik`` each pair is a set of smooth constraints: spheres of one
capsule's radius along its axis (:meth:`~oracles.collision.Capsule.samples`),
each kept from the other capsule's segment. In ``dls`` the pairs closer than
the margin plus a buffer become inequality rows along the line of their
nearest points. The verdict is coal's (``pinocchio.computeDistances`` on the
capsules): no pair closer than its clearance less the sampling's sag.
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


@dataclass(frozen=True)
class Pair:
    """Two capsules kept apart: ``sampled``'s spheres from ``other``'s segment, by ``clearance`` [m]."""

    sampled: int
    other: int
    clearance: float
    floor: float  # [m] the least coal distance the verdict accepts


def _sag(radius: float, spacing: float) -> float:
    return radius - float(np.sqrt(max(radius**2 - (0.5 * spacing) ** 2, 0.0)))


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


def segment_point_sq(p: ca.SX, a: ca.SX, b: ca.SX) -> ca.SX:
    """Squared distance from point p to segment a-b (C1: the clamp's kinks vanish in the square)."""
    d = b - a
    t = ca.fmin(ca.fmax(ca.dot(p - a, d) / (ca.dot(d, d) + 1e-12), 0.0), 1.0)
    return ca.sumsqr(p - (a + t * d))


@dataclass
class SelfCollisionTask(HardTask):
    """Keep every non-adjacent pair of segments apart (see the module docstring)."""

    type: ClassVar[str] = "self_collision"
    keys: ClassVar[frozenset[str]] = frozenset({"margin", "exclude"})
    summary: ClassVar[str] = "no two non-adjacent segments' capsules closer than `margin` [m] (default 1 cm); `exclude` more pairs"

    margin: float = MARGIN
    pairs: tuple[Pair, ...] = ()
    at_reference: tuple[tuple[str, str, float], ...] = ()  # pairs closer than the margin at the reference: names, distance [m]
    _model: CollisionModel | None = field(default=None, repr=False, compare=False)

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
        pm = scope.body.model
        bearing = {p.joint for p in model.placed}
        candidates = []
        for i, pi in enumerate(model.placed):
            for j in range(i + 1, len(model.placed)):
                pj = model.placed[j]
                if frozenset((pi.name, pj.name)) in excluded or _adjacent(pm, bearing, pi.joint, pj.joint):
                    continue
                if relative_motion(pm, pi.joint, pj.joint, scope.active):
                    candidates.append((i, j))
        ref = model.distances(scope.body.q_ref, candidates)
        pairs, close = [], []
        for (i, j), d in zip(candidates, ref, strict=True):
            # Sample the capsule that needs fewer spheres.
            si, sj = model.placed[i].capsule.samples(), model.placed[j].capsule.samples()
            s, o = (i, j) if len(si) <= len(sj) else (j, i)
            sag = _sag(model.placed[s].radius, model.placed[s].capsule.length / max(len(model.placed[s].capsule.samples()) - 1, 1))
            clearance = margin if d >= margin + sag else min(margin, float(d) - sag)
            if d < margin + sag:
                close.append((model.placed[i].name, model.placed[j].name, round(float(d), 4)))
            pairs.append(Pair(s, o, clearance, min(0.0, clearance - sag) - CHECK_TOL))
        return cls(margin, tuple(pairs), tuple(close))

    def bind(self, reference: Reference) -> None:
        self._model = reference.body.collision

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        assert self._model is not None
        out = []
        for pair in self.pairs:
            s, o = self._model.placed[pair.sampled], self._model.placed[pair.other]
            a, b = world_point(sym, o.joint, o.a), world_point(sym, o.joint, o.b)
            reach = s.radius + o.radius + pair.clearance
            # The sphere centres, in the sampled capsule's joint frame.
            m = np.linspace(0.0, 1.0, len(s.capsule.samples()))[:, None]
            centres = s.a + m * (s.b - s.a)
            rows = [segment_point_sq(world_point(sym, s.joint, c), a, b) for c in centres]
            out.append(Constraint(ca.vertcat(*rows), reach * abs(reach), np.inf))
        return out

    def distances(self, q: np.ndarray) -> np.ndarray:
        """Coal's distance [m] of every pair at q."""
        assert self._model is not None
        return self._model.distances(q, [(p.sampled, p.other) for p in self.pairs])

    def rows(self, num: Numeric) -> list[Row]:
        assert self._model is not None
        out = []
        for pair in self.pairs:
            s, o = self._model.placed[pair.sampled], self._model.placed[pair.other]
            pa, pb = self._model.world(num.data, pair.sampled)
            qa, qb = self._model.world(num.data, pair.other)
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
        return bool(np.all(self.distances(num.q) >= np.array([p.floor for p in self.pairs])))
