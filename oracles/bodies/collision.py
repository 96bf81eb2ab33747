"""Collision geometry of a body: one capsule (a sphere-swept segment) per segment.

A capsule is a segment ``a``-``b`` fixed to a link, swept by a sphere of
``radius`` [m]. The generated human's capsules are sized from anthropometric
tables (:func:`oracles.bodies.human.human_capsules`) and written into its URDF as
``<collision>`` cylinders named ``capsule_<name>`` (URDF has no capsule
primitive; such a cylinder is read back as the capsule of the same axis and
radius). A URDF body's own ``<collision>`` elements become capsules:
cylinders and spheres as they are (a cylinder as the capsule of its axis and
radius, which encloses it), boxes by the capsule along their longest axis
that encloses them, meshes by one to four capsules along the mesh's principal axis (see
:func:`_mesh_capsules` for the rule; trimesh reads the file). Mesh paths
``package://PKG/...`` are resolved against ``package_dirs`` (each a folder
holding package ``PKG``) and plain relative paths against the URDF's folder.

:class:`CollisionModel` turns capsules into what the tasks need: end points
in their parent joint's frame, Pinocchio/coal geometry for the independent
check (``pinocchio.computeDistances``), and pairs.
"""

from __future__ import annotations

import fnmatch
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import coal
import numpy as np
import pinocchio as pin

from oracles.errors import ModelError

CAPSULE_PREFIX = "capsule_"


@dataclass(frozen=True)
class Capsule:
    """A segment a-b [m] in a link's frame, swept by a sphere of radius [m]."""

    name: str
    link: str
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.subtract(self.b, self.a)))

    def samples(self, spacing: float | None = None) -> np.ndarray:
        """Centres (n, 3) of spheres of the capsule's radius along its axis, at most ``spacing`` apart (default: the
        radius).

        Their union lies inside the capsule and misses at most
        ``radius - sqrt(radius^2 - (spacing/2)^2)`` (13 % of the radius) of its surface.
        """
        step = self.radius if spacing is None else spacing
        n = max(2, math.ceil(self.length / step) + 1) if self.length > 0 else 1
        t = np.linspace(0.0, 1.0, n)[:, None]
        return np.asarray(self.a) + t * (np.asarray(self.b) - np.asarray(self.a))  # type: ignore[no-any-return]


def _axis_frame(a: np.ndarray, b: np.ndarray) -> pin.SE3:
    """The placement whose z axis runs from a to b, centred between them (coal's capsules lie along z)."""
    d = b - a
    n = np.linalg.norm(d)
    z = d / n if n > 1e-12 else np.array([0.0, 0.0, 1.0])
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return pin.SE3(np.column_stack([x, np.cross(z, x), z]), 0.5 * (a + b))


@dataclass(frozen=True)
class Placed:
    """A capsule attached to a joint: end points [m] in the joint's frame."""

    capsule: Capsule
    joint: int
    a: np.ndarray
    b: np.ndarray

    @property
    def name(self) -> str:
        return self.capsule.name

    @property
    def radius(self) -> float:
        return self.capsule.radius


class CollisionModel:
    """Capsules of a body placed on its joints, with coal geometry for the independent check."""

    def __init__(self, model: pin.Model, capsules: Sequence[Capsule], source: str = "body") -> None:
        self.model = model
        self.placed: list[Placed] = []
        for c in capsules:
            if not model.existFrame(c.link):
                raise ModelError(f"capsule {c.name!r} is on link {c.link!r}, which the model does not have",
                                 source=source)
            frame = model.frames[model.getFrameId(c.link)]
            m = frame.placement
            self.placed.append(Placed(c, int(frame.parentJoint), m.act(np.asarray(c.a, float)),
                                      m.act(np.asarray(c.b, float))))
        self.index = {p.name: i for i, p in enumerate(self.placed)}
        # The geometry of each pair set, built once: a self-collision task's distances at the reference and its
        # verdict's check (:meth:`clear`) ask about one set.
        self._checks: dict[tuple[tuple[int, int], ...], tuple[pin.GeometryModel, pin.GeometryData, pin.Data]] = {}
        # the security margins last set on a geometry's collision requests, by its key (see _margined)
        self._margins: dict[tuple[Any, ...], bytes] = {}
        # The last answer per pair set: an IK engine's cut loop and the verdict's
        # independent check ask about the same posture one after the other.
        self._last: dict[tuple[tuple[int, int], ...], tuple[bytes, np.ndarray]] = {}
        self._adjacency: dict[tuple[int, int], bool] = {}
        # :meth:`above_floor`'s geometry by capsule set
        self._floors: dict[tuple[int, ...], tuple[pin.GeometryModel, pin.GeometryData, pin.Data]] = {}
        self.geometry = pin.GeometryModel()
        for p in self.placed:
            shape = coal.Capsule(p.radius, float(np.linalg.norm(p.b - p.a)))
            self.geometry.addGeometryObject(pin.GeometryObject(p.name, p.joint, _axis_frame(p.a, p.b), shape))

    def names(self, patterns: Sequence[str]) -> list[str]:
        """Capsule names matching glob patterns; an unknown pattern is an error naming the capsules."""
        out = []
        for pattern in patterns:
            hits = [n for n in self.index if fnmatch.fnmatchcase(n, pattern)]
            if not hits:
                raise ModelError(f"no capsule matches {pattern!r}; capsules are: {', '.join(self.index)}", name=pattern)
            out += hits
        return out

    def world(self, data: pin.Data, i: int) -> tuple[np.ndarray, np.ndarray]:
        """World end points of capsule i (data holds joint placements)."""
        p = self.placed[i]
        m = data.oMi[p.joint]
        return m.act(p.a), m.act(p.b)

    def distances(self, q: np.ndarray, pairs: Sequence[tuple[int, int]]) -> np.ndarray:
        """Coal's distances [m] between capsule pairs at q (negative: penetration depth)."""
        if not pairs:
            return np.zeros(0)
        key = pairs if isinstance(pairs, tuple) else tuple(pairs)
        q = np.asarray(q, float)
        last = self._last.get(key)
        if last is not None and last[0] == q.tobytes():
            return last[1].copy()
        geom, gdata, data = self._paired(key)
        pin.computeDistances(self.model, data, geom, gdata, q)
        out = np.array([r.min_distance for r in gdata.distanceResults])
        self._last[key] = (q.tobytes(), out)
        return out.copy()

    def clear(self, q: np.ndarray, pairs: tuple[tuple[int, int], ...], floors: np.ndarray) -> bool:
        """Whether every pair is at least its floor [m] apart at q (a negative floor: that much overlap allowed):
        coal's collision check with each pair's floor as its security margin, stopping at the first pair closer. The
        whole body's 119 pairs: 10 us a posture, where reading every distance took 90-100 us; the same verdict as
        :meth:`distances` on 238,000 pairs at 2,000 postures (tests/test_collision.py)."""
        if not pairs:
            return True
        geom, gdata, data = self._paired(pairs)
        self._margined(pairs, gdata, np.asarray(floors, float))
        return not pin.computeCollisions(self.model, data, geom, gdata, np.asarray(q, float), True)

    def above_floor(self, q: np.ndarray, capsules: tuple[int, ...], tol: float) -> bool:
        """Whether each capsule's lowest point lies at least ``-tol`` [m] above the floor z = 0 at q (its end points
        at least its radius less tol above it): coal's collision test of each against the floor's half-space, tol the
        overlap allowed. The whole body's 30 capsules: 3 us a posture, where their end points in Python took 40 us;
        the same verdict as the end points' heights (tests/test_collision.py)."""
        if not capsules:
            return True
        found = self._floors.get(capsules)
        if found is None:
            geom = pin.GeometryModel()
            for i in capsules:
                geom.addGeometryObject(self.geometry.geometryObjects[i])
            # the solid below z = 0, on the universe
            geom.addGeometryObject(pin.GeometryObject("floor", 0, pin.SE3.Identity(),
                                                      coal.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0)))
            for k in range(len(capsules)):
                geom.addCollisionPair(pin.CollisionPair(k, len(capsules)))
            found = self._floors[capsules] = (geom, pin.GeometryData(geom), self.model.createData())
        geom, gdata, data = found
        self._margined(capsules, gdata, np.full(len(capsules), -float(tol)))
        return not pin.computeCollisions(self.model, data, geom, gdata, np.asarray(q, float), True)

    def adjacent(self, a: int, b: int) -> bool:
        """Whether joints a and b are one, or one an ancestor of the other with no capsule-bearing joint between
        them (remembered: a population member's four strategies ask about the same joints)."""
        key = (min(a, b), max(a, b))
        found = self._adjacency.get(key)
        if found is None:
            found = self._adjacency[key] = _adjacent(self.model, {p.joint for p in self.placed}, a, b)
        return found

    def _margined(self, key: tuple[Any, ...], gdata: pin.GeometryData, margins: np.ndarray) -> None:
        """The collision requests' security margins set to ``margins``, unless they are those set last."""
        if self._margins.get(key) != margins.tobytes():
            for request, margin in zip(gdata.collisionRequests, margins, strict=True):
                request.security_margin = float(margin)
            self._margins[key] = margins.tobytes()

    def _paired(self, pairs: tuple[tuple[int, int], ...]) -> tuple[pin.GeometryModel, pin.GeometryData, pin.Data]:
        """The capsules' geometry with these pairs, its data and the model's (built once per pair set)."""
        found = self._checks.get(pairs)
        if found is None:
            geom = pin.GeometryModel()
            for o in self.geometry.geometryObjects:
                geom.addGeometryObject(o)
            for i, j in pairs:
                geom.addCollisionPair(pin.CollisionPair(i, j))
            found = self._checks[pairs] = (geom, pin.GeometryData(geom), self.model.createData())
        return found


def _adjacent(model: pin.Model, bearing: set[int], a: int, b: int) -> bool:
    """One joint, or one an ancestor of the other with no joint of ``bearing`` between them."""
    if a == b:
        return True
    for lo, hi in ((a, b), (b, a)):
        j = int(model.parents[lo])
        while j > 0 and j != hi and j not in bearing:
            j = int(model.parents[j])
        if j == hi:
            return True
    return False


def nearest_points(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Nearest points of segments p-q and a-b, and their distance [m] (our own computation, tested against coal)."""
    d1, d2, r = q - p, b - a, p - a
    aa, ee, f = d1 @ d1, d2 @ d2, d2 @ r
    c, bb = d1 @ r, d1 @ d2
    den = aa * ee - bb * bb
    if ee <= 1e-15:  # a-b is a point (a sphere): project it on p-q
        s, t = (float(np.clip(-c / aa, 0.0, 1.0)) if aa > 1e-15 else 0.0), 0.0
    else:
        s = float(np.clip((bb * f - c * ee) / den, 0.0, 1.0)) if den > 1e-15 and aa > 1e-15 else 0.0
        t = (bb * s + f) / ee
        if t < 0.0 or t > 1.0:
            t = float(np.clip(t, 0.0, 1.0))
            s = float(np.clip((t * bb - c) / aa, 0.0, 1.0)) if aa > 1e-15 else 0.0
    x, y = p + s * d1, a + t * d2
    return x, y, float(np.linalg.norm(x - y))


def segment_gap(p: ca.SX, q: ca.SX, a: ca.SX, b: ca.SX, aa: float, ee: float, aa_sx: ca.SX | float | None = None,
                ee_sx: ca.SX | float | None = None) -> tuple[ca.SX, tuple[tuple[ca.SX, ca.SX], ...]]:
    """Distance [m] between segments p-q and a-b as a CasADi expression: :func:`nearest_points`'s closed form,
    its branches as ``if_else``. ``aa`` and ``ee`` are the squared lengths of the two segments, constants of
    rigid capsules, so that a sphere's branch is chosen here rather than in the expression.

    Returns the distance in terms of two fresh symbols, the nearest points' parameters s and t, and those
    symbols with the expressions they stand for (a :class:`~oracles.tasks.base.Constraint`'s ``frozen``):
    the distance's derivative with s and t held is its derivative (they are optimal, or clamped). ``aa_sx`` and
    ``ee_sx``, when given, are the lengths as the expression takes them (a body's parameters): the general branch
    then serves every length, a sphere's too (its divisions guarded), since another body's capsule may be a segment."""
    aa_num, ee_num = aa, ee
    if aa_sx is not None and ee_sx is not None:
        aa_num = ee_num = 1.0  # the general branch
        aa, ee = ca.fmax(aa_sx, 1e-300), ca.fmax(ee_sx, 1e-300)  # type: ignore[assignment]
    d1, d2, r = q - p, b - a, p - a
    f, c, bb = ca.dot(d2, r), ca.dot(d1, r), ca.dot(d1, d2)

    def clip(v: ca.SX) -> ca.SX:
        return ca.fmin(ca.fmax(v, 0.0), 1.0)

    if ee_num <= 1e-15:
        s, t = (clip(-c / aa) if aa_num > 1e-15 else ca.SX(0.0)), ca.SX(0.0)
    elif aa_num <= 1e-15:
        s, t = ca.SX(0.0), clip(f / ee)
    else:
        den = aa * ee - bb * bb
        # Parallel axes (den -> 0): any s is as near; nearest_points takes s = 0 (relative threshold: den scales as aa
        # ee).
        s0 = ca.if_else(den > 1e-12 * aa * ee, clip((bb * f - c * ee) / ca.fmax(den, 1e-300)), 0.0)
        t0 = (bb * s0 + f) / ee
        t = clip(t0)
        s = ca.if_else(t0 != t, clip((t * bb - c) / aa), s0)
    s_sym, t_sym = ca.SX.sym("s"), ca.SX.sym("t")
    gap = (p + s_sym * d1) - (a + t_sym * d2)
    # The square root's derivative is infinite at 0 (crossing axes, deep inside a pair's radii): a floor keeps it
    # finite.
    return ca.sqrt(ca.dot(gap, gap) + 1e-12), ((s_sym, s), (t_sym, t))


# -- capsules from a URDF's own collision elements -----------------------------

def _resolve(filename: str, urdf_dir: Path | None, package_dirs: Sequence[str | Path], source: str) -> Path:
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        for root in package_dirs:
            candidate = Path(root) / rest
            if _is_file(candidate):
                return candidate
        package = rest.split("/", 1)[0]
        found = _package_parent(package, urdf_dir)
        hint = f"; {found} holds a folder {package!r}: give it" if found else ""
        raise ModelError(f"mesh {filename!r} not found in {[str(d) for d in package_dirs]}: give package_dirs the "
                         f"folder that holds the package folder {package!r} (the folder above it){hint}",
                         source=source, key="package_dirs")
    path = Path(filename.removeprefix("file://"))
    if not path.is_absolute() and urdf_dir is not None:
        path = urdf_dir / path
    if not _is_file(path):
        raise ModelError(f"mesh {filename!r} not found (looked for {path})", source=source)
    return path


def _is_file(path: Path) -> bool:
    """Whether path is a file, and False for a name the system cannot even look up (a 40,000-character mesh path
    raised OSError: File name too long)."""
    try:
        return path.is_file()
    except OSError:
        return False


def _package_parent(package: str, urdf_dir: Path | None) -> Path | None:
    """A folder holding a folder named ``package``, among the URDF's folder and its ancestors (a hint for the error)."""
    if urdf_dir is None:
        return None
    for folder in [urdf_dir.resolve(), *urdf_dir.resolve().parents]:
        if (folder / package).is_dir():
            return folder
    return None


MESH_PIECES = 4  # the most capsules one mesh becomes, along its long axis
PIECES_SLACK = 0.1  # ... the fewest whose volume is within this share of the best of 1..MESH_PIECES


def _mesh_capsules(path: Path, scale: np.ndarray, source: str) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """A mesh as capsules along its principal axis: it is cut into 1 to ``MESH_PIECES`` equal slabs across that axis,
    each slab's surface fitted by its own capsule, and the fewest pieces are kept whose total volume is within
    ``PIECES_SLACK`` of the least of them. A capsule's volume beyond its mesh is what overlaps the neighbours' (one
    capsule over a torso with a wide base was 0.25 m thick all the way up, and overlapped the arms' by 126 mm)."""
    # trimesh only when meshes are read or written
    import trimesh

    if path.suffix.lower() == ".dae":
        try:
            import collada  # noqa: F401 - trimesh reads COLLADA through it, and says little when it is missing
        except ImportError:
            raise ModelError(f"mesh {path} is COLLADA (.dae), which needs pycollada: pip install "
                             "'reach-volumes[meshes]' (or convert the mesh to .stl)", source=source) from None

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ModelError(f"cannot read mesh {path} ({exc})", source=source) from exc
    v = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64) * scale
    if v.shape[0] == 0:
        raise ModelError(f"mesh {path} has no vertices", source=source)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3), int)), int)
    if len(faces):
        # Small triangles, each given whole to the slab its centroid lies in: a capsule is convex, so it covers every
        # triangle whose corners it covers, and the pieces' union covers the surface (not only its vertices).
        extent = float(np.ptp(v, axis=0).max())
        v, faces = trimesh.remesh.subdivide_to_size(v, faces, max_edge=max(extent, 1e-9) / (2 * MESH_PIECES),
                                                    max_iter=12)
        v, faces = np.asarray(v, float), np.asarray(faces, int)
    else:
        faces = np.arange(len(v))[:, None]  # a point cloud: each point its own "face"
    centre = v.mean(axis=0)
    axis = np.linalg.svd(v - centre, full_matrices=False)[2][0]
    t = (v - centre) @ axis
    t_face = t[faces].mean(axis=1)
    fits = []
    for k in range(1, MESH_PIECES + 1):
        edges = np.linspace(t.min(), t.max(), k + 1)
        slab = np.clip(np.searchsorted(edges, t_face, side="right") - 1, 0, k - 1)
        fits.append([_capsule_along(v[np.unique(faces[slab == j])], axis) for j in range(k) if np.any(slab == j)])
    volume = [sum(math.pi * r**2 * (np.linalg.norm(b - a) + 4.0 * r / 3.0) for a, b, r in fit) for fit in fits]
    return next(fit for fit, vol in zip(fits, volume, strict=True) if vol <= (1.0 + PIECES_SLACK) * min(volume))


def _capsule_along(v: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The capsule with the given axis direction that encloses the points v (N, 3): through their centre, its radius
    the farthest point's distance from that line, its segment the shortest whose hemispherical caps still cover them."""
    centre = v.mean(axis=0)
    t = (v - centre) @ axis
    radial = np.linalg.norm((v - centre) - np.outer(t, axis), axis=1)
    radius = max(float(radial.max()), 1e-6)
    inner = np.sqrt(np.maximum(radius**2 - radial**2, 0.0))
    lo, hi = float(np.min(t + inner)), float(np.max(t - inner))
    if lo > hi:
        lo = hi = 0.5 * (lo + hi)
    return centre + lo * axis, centre + hi * axis, radius


def urdf_capsules(urdf: str, source: str, urdf_dir: Path | None = None,
                  package_dirs: Sequence[str | Path] = ()) -> list[Capsule]:
    """Capsules of a URDF's ``<collision>`` elements (see the module docstring)."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as exc:
        raise ModelError(f"not a valid URDF (not well-formed XML: {exc})", source=source) from exc
    out: list[Capsule] = []
    for link in root.iter("link"):
        lname = link.get("name", "")
        for k, col in enumerate(link.findall("collision")):
            name = col.get("name") or f"{lname}_{k}"
            origin = col.find("origin")
            xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
            rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
            placement = pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)
            more: list[tuple[np.ndarray, np.ndarray, float]] = []
            geom = col.find("geometry")
            shape = None if geom is None else next(iter(geom), None)
            if shape is None:
                raise ModelError(f"link {lname!r}: collision {name!r} has no geometry", source=source)
            where = f"{source}: link {lname!r}: collision {name!r}"
            try:
                if shape.tag == "cylinder":
                    r, half = float(shape.get("radius", "")), 0.5 * float(shape.get("length", ""))
                    a, b = np.array([0, 0, -half]), np.array([0, 0, half])
                    name = name.removeprefix(CAPSULE_PREFIX) if name.startswith(CAPSULE_PREFIX) else name
                elif shape.tag == "sphere":
                    r = float(shape.get("radius", ""))
                    a = b = np.zeros(3)
                elif shape.tag == "box":
                    size = np.array([float(v) for v in shape.get("size", "").split()])
                    long = int(np.argmax(size))
                    others = np.delete(size, long)
                    r = 0.5 * float(np.linalg.norm(others))
                    a, b = np.zeros(3), np.zeros(3)
                    a[long], b[long] = -0.5 * size[long], 0.5 * size[long]
                elif shape.tag == "mesh":
                    scale = np.array([float(v) for v in shape.get("scale", "1 1 1").split()])
                    pieces = _mesh_capsules(_resolve(shape.get("filename", ""), urdf_dir, package_dirs, where), scale,
                                            where)
                    (a, b, r), more = pieces[0], pieces[1:]
                else:
                    raise ModelError(f"{where}: unsupported geometry <{shape.tag}>")
            except ValueError as exc:
                raise ModelError(f"{where}: malformed <{shape.tag}> ({exc})") from exc
            if not r > 0:
                raise ModelError(f"{where}: the radius must be positive, got {r}")
            # A mesh's first piece keeps the element's name; the others are NAME_1, NAME_2, ...
            for j, (end_a, end_b, rad) in enumerate([(a, b, r), *more]):
                out.append(Capsule(f"{name}_{j}" if j else name, lname, tuple(placement.act(end_a)),
                                   tuple(placement.act(end_b)),  # type: ignore[arg-type]
                                   float(rad)))
    return out
