"""No segment through another: ``{type: self_collision, margin: 0.01, exclude: [[a, b], ...]}``.

Every pair of the body's collision capsules (:mod:`oracles.bodies.collision`) keeps
``margin`` [m] between them, except

* adjacent segments: capsules on one joint, or on joints with no capsule
  between them in the tree (the upper arm and the thorax, across the
  shoulder girdle);
* pairs that no active joint moves relative to each other (their distance
  is a constant);
* pairs of links a URDF body's SRDF disables (``body.srdf``: adjacent links, links that never or always
  collide, as MoveIt's setup assistant finds them);
* pairs the config excludes (``exclude``, capsule names or glob patterns),
  or that involve none of the capsules ``only`` names (when given: e.g. the
  reaching hand and forearm, the segments that pass through the trunk in
  whole-body reaches; each pair costs solver time).

A pair already closer than the margin at the reference posture (the hanging
forearm against the waist) keeps its reference clearance instead: it may not
come closer than it stands, so the hand still cannot pass through the trunk.
These pairs are listed by ``reach model``.

The task is *lazy* (see :class:`~oracles.tasks.base.HardTask`): a pair's
distance is the closed form of the nearest points of the two capsules'
segments (:func:`oracles.bodies.collision.nearest_points`) less their radii, and its
gradient the difference of the two nearest points' Jacobians along the line
between them. ``casadi-ik`` solves without the pairs, and when the posture
collides, again with the near and colliding pairs linearised at it, until it
does not (most postures never collide, and any number of pairs costs the
programs nothing). In ``dls`` the pairs closer than the margin plus a buffer
become inequality rows along the same line. The verdict is coal's
(``pinocchio.computeDistances`` on the capsules): no pair closer than its
clearance (0 for most pairs), within 0.1 mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pinocchio as pin

from oracles.bodies.collision import CollisionModel, nearest_points, segment_gap
from oracles.errors import TaskError
from oracles.tasks.base import (
    BUFFER,
    Constraint,
    Cut,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    active_ancestors,
    moved,
    number,
    rows_of_cuts,
    world_point,
)

MARGIN = 0.01  # [m] default clearance between segments
CHECK_TOL = 1e-4  # [m] the verdict's tolerance on coal's distance
SCREEN = 1e-4  # [m] coal may place a pair this much farther than our nearest points and still be cut
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


def _keep_out(scope: Scope, model: CollisionModel, pairs: list[Pair]) -> tuple[int, ...]:
    """Capsules that no active joint moves and that a capsule holding the effector point is kept from.

    The effector point lies inside its capsule, ``inside`` [m] from its
    surface; a point of a static capsule is then unreachable whenever the two
    may not overlap by ``inside`` (the pair's least accepted distance, its
    floor, above ``-inside``).
    """
    pm, data = scope.body.model, scope.body.model.createData()
    pin.framesForwardKinematics(pm, data, scope.body.q_ref)
    fid = scope.body.frame_id(scope.effector)
    point = data.oMf[fid].translation
    depth = {}
    for i, p in enumerate(model.placed):
        if p.joint == int(pm.frames[fid].parentJoint):
            a, b = model.world(data, i)
            depth[i] = p.radius - nearest_points(a, b, point, point)[2]
    out = set()
    for pair in pairs:
        for e, other in ((pair.first, pair.second), (pair.second, pair.first)):
            if (depth.get(e, -1.0) > 0 and pair.floor > -depth[e]
                and not moved(pm, model.placed[other].joint, scope.active)):
                out.add(other)
    return tuple(sorted(out))


def _excluded(raw: dict[str, Any], where: str, model: Any) -> set[frozenset[str]]:
    """The capsule pairs ``exclude`` names (patterns resolved), each as a set of two names."""
    exclude = raw.get("exclude", [])
    if not isinstance(exclude, list) or not all(isinstance(e, list) and len(e) == 2
                                                and all(isinstance(n, str) for n in e) for e in exclude):
        raise TaskError(f"{where}.exclude", f"expected a list of [capsule, capsule] pairs, got {exclude!r}")
    excluded: set[frozenset[str]] = set()
    try:
        for a, b in exclude:
            excluded.update(frozenset((x, y)) for x in model.names([a]) for y in model.names([b]))
    except Exception as exc:
        raise TaskError(f"{where}.exclude", str(exc)) from exc
    return excluded


def _candidates(model: Any, scope: Scope, excluded: set[frozenset[str]],
                only: set[str] | None) -> list[tuple[int, int]]:
    """The capsule pairs (i, j) that may collide: neither excluded (by the config, as adjacent, or by the body's
    SRDF), one of them in ``only`` when given, and moving relative to each other by the strategy's joints."""
    pm = scope.body.model
    # relative_motion's masks made once for every pair (600 pairs of the human's capsules, each walking its two
    # chains to the root, took 7 ms a strategy; a population's member pays it four times)
    moving = active_ancestors(pm, scope.active)
    candidates = []
    for i, pi in enumerate(model.placed):
        for j in range(i + 1, len(model.placed)):
            pj = model.placed[j]
            if not moving[pi.joint] ^ moving[pj.joint]:
                continue
            if (frozenset((pi.name, pj.name)) in excluded or model.adjacent(pi.joint, pj.joint)
                    or frozenset((pi.capsule.link, pj.capsule.link)) in scope.body.disabled
                    or (only is not None and pi.name not in only and pj.name not in only)):
                continue
            candidates.append((i, j))
    return candidates


def _only(raw: dict[str, Any], where: str, model: Any) -> set[str] | None:
    """The capsules ``only`` names (patterns resolved), or None: every capsule."""
    only_raw = raw.get("only")
    if only_raw is not None and (not isinstance(only_raw, list) or not all(isinstance(n, str) for n in only_raw)):
        raise TaskError(f"{where}.only", f"expected a list of capsule names or patterns, got {only_raw!r}")
    try:
        return set(model.names(only_raw)) if only_raw is not None else None
    except Exception as exc:
        raise TaskError(f"{where}.only", str(exc)) from exc


@dataclass
class SelfCollisionTask(HardTask):
    """Keep every non-adjacent pair of segments apart (see the module docstring)."""

    type: ClassVar[str] = "self_collision"
    lazy: ClassVar[bool] = True
    keys: ClassVar[frozenset[str]] = frozenset({"margin", "exclude", "only"})
    summary: ClassVar[str] = ("no two non-adjacent segments' capsules closer than `margin` [m] (default 1 cm); "
                              "`exclude` more pairs")

    margin: float = MARGIN
    pairs: tuple[Pair, ...] = ()
    # pairs closer than the margin at the reference: names, distance [m]
    at_reference: tuple[tuple[str, str, float], ...] = ()
    static: tuple[int, ...] = ()  # capsules that no active joint moves and the effector may not enter (see keep_out)
    tissue: bool = False  # capsules of flesh (the generated human), whose contacts at rest are by design
    _model: CollisionModel | None = field(default=None, repr=False, compare=False)
    _floors: np.ndarray = field(default_factory=lambda: np.zeros(0), init=False, repr=False, compare=False)
    _ids: tuple[tuple[int, int], ...] = field(default=(), init=False, repr=False, compare=False)
    _reference: Reference | None = field(default=None, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> SelfCollisionTask:
        margin = number(raw.get("margin", MARGIN), f"{where}.margin", 0.0, 0.2)
        model = scope.body.collision
        if not model.placed:
            raise TaskError(where, f"{scope.body.source}: the body has no collision geometry")
        candidates = _candidates(model, scope, _excluded(raw, where, model), _only(raw, where, model))
        ref = model.distances(scope.body.q_ref, candidates)
        pairs, close = [], []
        for (i, j), d in zip(candidates, ref, strict=True):
            clearance = margin if d >= margin else float(d)
            if d < margin:
                close.append((model.placed[i].name, model.placed[j].name, round(float(d), 4)))
            pairs.append(Pair(i, j, clearance, clearance - CHECK_TOL if d >= margin
                              else min(0.0, clearance) - CONTACT_GIVE))
        return cls(margin, tuple(pairs), tuple(close), _keep_out(scope, model, pairs),
                   scope.body.anthropometry is not None)

    def bind(self, reference: Reference) -> None:
        self._model = reference.body.collision
        self._reference = reference
        self._floors = np.array([p.floor for p in self.pairs])
        self._ids = tuple((p.first, p.second) for p in self.pairs)

    def describe(self) -> dict[str, Any]:
        names = [p.name for p in self._model.placed] if self._model else []
        close = ", ".join(f"{a}-{b} ({d:+.3f} m)" for a, b, d in self.at_reference)
        return {
            **super().describe(), "margin": self.margin,
            "pairs": [[names[p.first], names[p.second]] for p in self.pairs] if names else len(self.pairs),
            "at_reference": [{"pair": [a, b], "distance": d} for a, b, d in self.at_reference],
            "keep_out": [names[i] for i in self.static] if names else len(self.static),
            "text": f"{len(self.pairs)} pairs checked; closer than the margin at the reference (keep that "
                    f"clearance): {close or 'none'}",
        }

    def warnings(self) -> list[str]:
        # The generated human's arms rest against its trunk and thighs, flesh on flesh, by design; a robot's
        # capsules overlapping deeper than CONTACT_GIVE are its geometry or a reference posture folded into
        # itself, and the pair then keeps that overlap as its clearance.
        if self.tissue:
            return []
        return [f"capsules {a} and {b} overlap by {-d * 1000:.0f} mm at the reference posture; the pair keeps that "
                f"clearance instead of the margin: give body.reference where they are apart, exclude [{a}, {b}], or "
                "give the robot's SRDF (body.srdf), whose disabled pairs are left out"
                for a, b, d in self.at_reference if d < -CONTACT_GIVE]

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        return []  # lazy: see cuts

    parametric: ClassVar[bool] = True

    def numbers(self) -> dict[str, np.ndarray]:
        assert self._model is not None
        used = sorted({i for p in self.pairs for i in (p.first, p.second)})
        out = {f"{key}{i}": np.atleast_1d(v) for i in used
               for key, v in (("a", self._model.placed[i].a), ("b", self._model.placed[i].b),
                              ("radius", self._model.placed[i].radius),
                              ("length2", np.sum(np.subtract(self._model.placed[i].b, self._model.placed[i].a) ** 2)))}
        return {**out, "clearance": np.array([p.clearance for p in self.pairs])}

    def screened(self, sym: Symbolic) -> list[Constraint]:
        """Every pair's distance less its radii and its clearance, at least 0
        (:func:`oracles.bodies.collision.segment_gap`; the clearance in the row, not its bound: a row's bounds are the
        same for every body, :mod:`oracles.ik.parameters`)."""
        assert self._model is not None
        ends = {}
        out = []
        clearance = sym.number(self, "clearance", np.array([p.clearance for p in self.pairs]))
        for k, pair in enumerate(self.pairs):
            for i in (pair.first, pair.second):
                if i not in ends:
                    p = self._model.placed[i]
                    length2 = float(np.sum((np.subtract(p.b, p.a)) ** 2))
                    ends[i] = (world_point(sym, p.joint, sym.number(self, f"a{i}", p.a)),
                               world_point(sym, p.joint, sym.number(self, f"b{i}", p.b)), length2,
                               sym.number(self, f"length2{i}", length2), sym.number(self, f"radius{i}", p.radius))
            (pa, pb, aa, aa_sx, ra), (qa, qb, ee, ee_sx, rb) = ends[pair.first], ends[pair.second]
            gap, frozen = segment_gap(pa, pb, qa, qb, aa, ee, aa_sx, ee_sx)
            out.append(Constraint(gap - ra - rb - clearance[k], 0.0, np.inf, frozen))
        return out

    def keep_out(self) -> list[np.ndarray]:
        """The static capsules the effector may not enter, where they stand: a, b [m], radius [m]."""
        assert self._model is not None and self._reference is not None
        data = self._reference.data
        return [np.concatenate([*self._model.world(data, i), [self._model.placed[i].radius]]) for i in self.static]

    def distances(self, q: np.ndarray) -> np.ndarray:
        """Coal's distance [m] of every pair at q."""
        assert self._model is not None
        return self._model.distances(q, self._ids)  # set with _model by bind

    def cuts(self, num: Numeric, within: float) -> list[Cut]:
        assert self._model is not None
        out = []
        # Coal screens every pair in one call (about 60 us for the whole body's 119);
        # our nearest points, in Python, then serve only the near ones (3 ms for all).
        near = self.distances(num.q) < np.array([p.clearance for p in self.pairs]) + within + SCREEN
        for pair in (p for p, close in zip(self.pairs, near, strict=True) if close):
            s, o = self._model.placed[pair.first], self._model.placed[pair.second]
            pa, pb = self._model.world(num.data, pair.first)
            qa, qb = self._model.world(num.data, pair.second)
            ps, po, gap = nearest_points(pa, pb, qa, qb)
            gap -= s.radius + o.radius
            if gap >= pair.clearance + within:
                continue
            # Crossing axes (gap = -radii) have no nearest direction: push along the first capsule's normal.
            n = ps - po if np.linalg.norm(ps - po) > 1e-9 else np.cross(pb - pa, qb - qa)
            n = n / max(float(np.linalg.norm(n)), 1e-12)
            out.append(Cut(n @ (num.point_jacobian(s.joint, ps) - num.point_jacobian(o.joint, po)), float(gap),
                           pair.clearance))
        return out

    def rows(self, num: Numeric) -> list[Row]:
        return rows_of_cuts(self.cuts(num, BUFFER))

    def holds(self, num: Numeric) -> bool:
        assert self._model is not None
        return self._model.clear(num.q, self._ids, self._floors)
