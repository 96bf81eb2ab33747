"""Bodies as Pinocchio models: any URDF, or the generated human.

Every body gets a floating root joint named ``root`` (a free flyer), so that
the centre of mass includes the root link and whole-body strategies can move
the pelvis. The reference configuration ``q_ref`` places the root at
``root_position`` with identity orientation and every joint at zero (clipped
into its range); for the generated human that is standing, soles on z = 0.

A body is described by a JSON-compatible spec, so that workers can rebuild it:

* ``{"human": {"sex": "male", "percentile": 50, "mass": 80}}``; a human takes
  ANSUR II's dimensions by name [m] (``acromialheight: 1.44``), a subject
  (``ansur: {sex: female, subject: 10037}``) and ``proportions`` (``ansur``,
  the default, or ``de_leva``): see :mod:`oracles.bodies.anthropometry`
* ``{"urdf": "path/to/robot.urdf", "root_position": [0, 0, 0.5], "up": "y"}``

The world frame is z-up, in metres. A URDF body takes

* ``root_position`` [m]: where its root link stands (default the origin);
* ``up``: the model's own up axis (``z``, ``-z``, ``y``, ``-y``, ``x`` or
  ``-x``; default ``z``), turned onto the world's z;
* ``forward``: the model's own forward axis, perpendicular to ``up``, turned
  onto the world's x (default ``x``, or ``z`` when ``up`` is ``x`` or ``-x``);
  a glTF-style character is ``up: y, forward: z``;
* ``root_rpy`` [rad]: a further rotation of the root, roll, pitch, yaw about
  the world's fixed x, y, z (R = Rz(yaw) Ry(pitch) Rx(roll)), after those;
* ``package_dirs``: folders holding the packages its ``package://`` meshes
  name (the folder above each package's folder);
* ``srdf``: the robot's SRDF, whose ``disable_collisions`` pairs of links
  the ``self_collision`` task leaves alone (MoveIt's convention).

Either body takes

* ``ranges``: joint name or glob pattern -> ``[lower, upper]`` in radians,
  or ``{"scale": f}`` to scale both limits towards zero (an impaired or
  fatigued joint);
* ``frames``: name -> ``{"parent": FRAME, "xyz": [m], "rpy": [rad]}``, frames
  added on an existing one (grip points, tool centre points, sole corners);
* ``reference``: the reference posture, ``zero`` (the default: every joint at
  zero, clipped into its range, each clipped joint noted), ``middle`` (every
  joint at its range's middle), ``auto`` (the middle, and then for each
  strategy the nearest posture holding its hard tasks: see
  ``oracles.ik.oracle.IKOracle``), or joint name -> value [rad or m] over ``zero``
  (a value outside the joint's range is an error).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.bodies.ansur import COLUMNS as ANSUR_COLUMNS
from oracles.bodies.ansur import MASS as ANSUR_MASS
from oracles.bodies.anthropometry import Anthropometry, anthropometry
from oracles.bodies.collision import Capsule, CollisionModel, urdf_capsules
from oracles.bodies.environment import Box
from oracles.bodies.human import human_capsules, human_urdf, root_height
from oracles.bodies.kinematics import Stacked, model_arrays
from oracles.bodies.seat import KNEE_MOST, KNEE_STEP, Seated, fit, parse_seat, seated
from oracles.bodies.urdf import (
    add_frames,
    apply_ranges,
    check_limits,
    disabled_pairs,
    no_doctype,
    numbers,
    parse,
    root_rotation,
    set_reference,
)
from oracles.errors import ModelError
from oracles.protocol import COS, SIN


@dataclass
class Body:
    """A Pinocchio model with its reference posture and named frames.

    Attributes:
        model: The Pinocchio model, root joint ``root`` (free flyer).
        q_ref: (nq,) reference configuration.
        source: Where it came from (a file path or ``human``), for messages.
        spec: The JSON-compatible spec it was built from.
        urdf: The URDF text.
        anthropometry: Dimensions, for generated humans.
        capsules: Collision capsules on the links.
        notes: What loading changed without being asked (a reference joint
            clipped into its range), for warnings.
    """

    model: pin.Model
    q_ref: np.ndarray
    source: str
    spec: dict[str, Any]
    urdf: str
    anthropometry: Anthropometry | None = None
    capsules: tuple[Capsule, ...] = ()
    notes: tuple[str, ...] = ()  # what the loader changed without being asked (a clipped reference joint)
    furniture: tuple[Box, ...] = ()  # static boxes that come with the body (a seated human's seat)
    # pairs of links whose collisions the robot's SRDF disables (``srdf``): self_collision leaves their capsules apart
    disabled: frozenset[frozenset[str]] = frozenset()

    @cached_property
    def collision(self) -> CollisionModel:
        """The capsules placed on the model's joints, with coal geometry (built once)."""
        return CollisionModel(self.model, self.capsules, self.source)

    @cached_property
    def arrays(self) -> Stacked:
        """The model's numbers the kinematics read (:func:`oracles.bodies.kinematics.model_arrays`), read and stacked
        once: a population member's strategies share one body (1.6 ms a strategy read again)."""
        return Stacked(model_arrays(self.model))

    @cached_property
    def structure(self) -> tuple[tuple[str, str, int], ...]:
        """The joints' names, kinds and parents: what a program built on the model follows."""
        model = self.model
        return tuple((str(model.names[j]), model.joints[j].shortname(), int(model.parents[j]))
                     for j in range(model.njoints))

    def capsules_at(self, q: np.ndarray | None = None) -> np.ndarray:
        """The collision capsules (K, 7: end points a, b [m], radius [m]; world frame) at a posture (the reference by
        default)."""
        col = self.collision
        data = self.model.createData()
        pin.forwardKinematics(self.model, data, self.q_ref if q is None else np.asarray(q, float))
        return np.array([[*np.concatenate(col.world(data, i)), p.radius]
                         for i, p in enumerate(col.placed)]).reshape(-1, 7)

    @property
    def joint_names(self) -> list[str]:
        """Names of the joints after the root, in model order."""
        return list(self._joint_names)

    @cached_property
    def _joint_names(self) -> tuple[str, ...]:
        # read once: a population member's oracles ask 150 times (2.4 ms a member read each time)
        return tuple(str(n) for n in self.model.names[2:])

    @property
    def q_names(self) -> list[str]:
        """A name for each configuration coordinate (root: root_x ... root_qw; a continuous joint's pair:
        ``NAME.cos``, ``NAME.sin``, which answers and files give as the one angle ``NAME``)."""
        names = [f"root_{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
        for j in range(2, self.model.njoints):
            jm = self.model.joints[j]
            n = str(self.model.names[j])
            names += ([n] if jm.nq == 1 else [n + COS, n + SIN] if _continuous(jm)
                      else [f"{n}_{k}" for k in range(jm.nq)])
        return names

    @property
    def mass(self) -> float:
        return float(pin.computeTotalMass(self.model))

    @property
    def hash(self) -> str:
        """Identifies the model (URDF text and range overrides) in stored atlases."""
        return self._hash(with_ranges=True)

    @property
    def shape_hash(self) -> str:
        """Identifies the model's shape: its hash but for the joint ranges (a strategy's own ranges leave it the same
        body, whose postures another strategy may take, each checked against its own ranges)."""
        return self._hash(with_ranges=False)

    def _hash(self, with_ranges: bool) -> str:
        text = self.urdf + (json.dumps(self.spec.get("ranges", {}), sort_keys=True) if with_ranges else "")
        placed = {k: self.spec[k] for k in PLACING if k in self.spec}
        human = self.spec.get("human") or {}
        if "posture" in human or "seat" in human:
            placed["human"] = {k: human.get(k) for k in ("posture", "seat")}
        if placed:  # older atlases (no such keys) keep their hash
            text += json.dumps(placed, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def frame_id(self, name: str) -> int:
        if not self.model.existFrame(name):
            known = sorted({str(f.name) for f in self.model.frames} - {"universe"})
            raise ModelError(f"no frame {name!r}; frames are: {', '.join(known)}", source=self.source, name=name)
        return int(self.model.getFrameId(name))

    def joint_id(self, name: str) -> int:
        if name not in self._joint_names:
            raise ModelError(f"no joint {name!r}; joints are: {', '.join(self.joint_names)}", source=self.source,
                             name=name)
        return int(self.model.getJointId(name))

    def configuration(self, joints: dict[str, float], root: dict[str, list[float]] | None = None) -> np.ndarray:
        """The configuration q of an answer's posture: joint name -> value [rad or m] and the root pose
        (``{"position": [x, y, z], "quaternion": [qx, qy, qz, qw]}``); the rest at the reference."""
        q = self.q_ref.copy()
        if root:
            q[:3], q[3:7] = root["position"], root["quaternion"]
        for name, value in joints.items():
            q[self.model.joints[self.joint_id(name)].idx_q] = value
        return q

    def frame_positions(self, q: np.ndarray | None = None, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """World positions [m] of frames at configuration q (reference by default)."""
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, self.q_ref if q is None else q)
        if names is None:
            names = [str(f.name) for f in self.model.frames if str(f.name) != "universe"]
        return {n: np.array(data.oMf[self.frame_id(n)].translation) for n in names}

    def center_of_mass(self, q: np.ndarray | None = None) -> np.ndarray:
        data = self.model.createData()
        return np.array(pin.centerOfMass(self.model, data, self.q_ref if q is None else q))

    def describe(self) -> dict[str, Any]:
        """What ``reach model`` prints: source, hash, mass [kg], joints and ranges [rad, m], frames [m], centre of
        mass [m]."""
        continuous = self.continuous
        info: dict[str, Any] = {
            "source": self.source,
            "hash": self.hash,
            "mass": self.mass,
            "nq": int(self.model.nq),
            "joints": [{"name": n, "lower": lo, "upper": hi, **({"continuous": True} if n in continuous else {})}
                       for n, lo, hi in self.limits()],
            "frames": {name: pos.round(6).tolist() for name, pos in self.frame_positions().items()},
            "center_of_mass": self.center_of_mass().round(6).tolist(),
            "capsules": [{"name": c.name, "link": c.link, "radius": round(c.radius, 6), "length": round(c.length, 6),
                          "a": [round(float(v), 6) for v in c.a], "b": [round(float(v), 6) for v in c.b]}
                              for c in self.capsules],
            "units": {"length": "m", "angle": "rad", "mass": "kg"},
        }
        if self.anthropometry is not None:
            info["stature"] = self.anthropometry.stature
            info["sex"] = self.anthropometry.sex
            info["proportions"] = self.anthropometry.proportions
        human = self.spec.get("human") or {}
        if human.get("posture") == "seated" and self.anthropometry is not None:
            info["seat"] = self._seat(human.get("seat"), info["frames"]["right_heel"])
        if self.furniture:
            info["furniture"] = [b.to_dict() for b in self.furniture]
        return info

    def _seat(self, seat_spec: Any, heel: list[float]) -> dict[str, Any]:
        """The seat a seated human sits on, as fitted to the body: angles [deg], lengths [m]."""
        assert self.anthropometry is not None
        seat = fit(self.anthropometry, parse_seat(seat_spec))
        fitted = seat.feet_x is not None and math.isnan(seat.feet_x)  # with the legs: where the heel came to rest
        if fitted:
            knee = float(self.q_ref[self.model.joints[self.model.getJointId("right_knee_flexion")].idx_q])
            seat = replace(seat, feet_x=round(float(heel[0]), 4), knee=knee)
        angles = ("back_angle", "ankle", "knee")  # [deg] in the description; the knee only where it fitted a heel
        return {k: round(math.degrees(v), 3) if k in angles and v is not None else v
                for k, v in asdict(seat).items() if k != "knee" or fitted}

    @property
    def continuous(self) -> frozenset[str]:
        """The continuous joints (turning without limit; their angle is given in (-pi, pi])."""
        return frozenset(str(self.model.names[j]) for j in range(2, self.model.njoints)
                         if _continuous(self.model.joints[j]))

    def limits(self) -> list[tuple[str, float, float]]:
        """(name, lower, upper) of every joint after the root [rad or m]; a continuous joint's angle is (-pi, pi]."""
        out = []
        for j in range(2, self.model.njoints):
            i, nq = self.model.joints[j].idx_q, self.model.joints[j].nq
            if _continuous(self.model.joints[j]):
                out.append((str(self.model.names[j]), -math.pi, math.pi))
                continue
            for k in range(nq):  # a planar or free joint (not one a strategy moves) by its coordinates
                name = str(self.model.names[j]) if nq == 1 else f"{self.model.names[j]}_{k}"
                out.append((name, float(self.model.lowerPositionLimit[i + k]),
                            float(self.model.upperPositionLimit[i + k])))
        return out


def _continuous(joint: pin.JointModel) -> bool:
    """Whether a joint is a continuous one (Pinocchio's unbounded revolute: (cos, sin), one velocity)."""
    return bool(joint.nq == 2 and joint.nv == 1)


def _finish(model: pin.Model, urdf: str, source: str, spec: dict[str, Any], root: np.ndarray, capsules: list[Capsule],
            anthro: Anthropometry | None = None, sitting: Seated | None = None) -> Body:
    check_limits(model, source)
    apply_ranges(model, dict(spec.get("ranges", {})), source)
    add_frames(model, spec.get("frames", {}), source)
    # The free flyer's translation has no meaningful limits; bound it so
    # that random configurations and solvers stay finite.
    model.lowerPositionLimit[:3] = root - 2.0
    model.upperPositionLimit[:3] = root + 2.0
    model.lowerPositionLimit[3:7] = -1.0
    model.upperPositionLimit[3:7] = 1.0
    q = pin.neutral(model)
    q[:3] = root
    if sitting is None:
        q[3:7] = pin.Quaternion(root_rotation(spec, source)).coeffs()
    else:
        q = _seated_q(model, sitting)
    notes = set_reference(model, q, spec.get("reference"), source)
    return Body(model, q, source, spec, urdf, anthro, tuple(capsules), tuple(notes), () if sitting is None
                else sitting.furniture)


def human_body(sex: str | None = None, stature: float | None = None, percentile: float | None = None,
               mass: float | None = None,
               ranges: dict[str, Any] | None = None, frames: dict[str, Any] | None = None, reference: Any = None,
               posture: str | None = None, seat: dict[str, Any] | None = None, ansur: dict[str, Any] | None = None,
               proportions: str = "ansur", dims: dict[str, float] | None = None) -> Body:
    """The generated human (see :mod:`oracles.bodies.human`), standing on z = 0, facing +x; or seated (``posture:
    seated``) on a seat (see :mod:`oracles.bodies.seat`). ``dims``: ANSUR II dimensions by name [m]; ``ansur``:
    ``{sex, subject}``, a surveyed person."""
    sex, subject = _subject(ansur, sex)
    anthro = anthropometry(sex, stature, percentile, mass, dims, subject, proportions)  # type: ignore[arg-type]
    human = {"sex": sex, "stature": stature, "percentile": percentile, "mass": mass, "posture": posture, "seat": seat,
             "ansur": ansur, "proportions": proportions, **(dims or {})}
    spec: dict[str, Any] = {"human": {k: v for k, v in human.items() if v is not None}}
    spec.update(_given(ranges=ranges, frames=frames, reference=reference))
    urdf = human_urdf(anthro)
    if posture not in (None, "standing", "seated"):
        raise ModelError(f"expected standing or seated, got {posture!r}", source="human", key="human.posture")
    if posture != "seated":
        if seat is not None:
            raise ModelError("a seat needs posture: seated", source="human", key="human.seat")
        root = np.array([0.0, 0.0, root_height(anthro)])
        return _finish(parse(urdf, "human", ours=True), urdf, "human", spec, root, human_capsules(anthro), anthro)
    return _seated_body(anthro, urdf, spec, parse_seat(seat))


def _subject(ansur: dict[str, Any] | None, sex: str | None) -> tuple[str, int | None]:
    """The body's sex and ANSUR II subject id (None: none) from ``human.ansur`` ``{sex, subject}`` and ``human.sex``
    (male by default)."""
    if ansur is None:
        return ("male" if sex is None else sex), None
    if not isinstance(ansur, dict) or set(ansur) - {"sex", "subject"} or "subject" not in ansur:
        raise ModelError(f"expected {{sex: male|female, subject: ID}}, got {ansur!r}", source="human",
                         key="human.ansur")
    subject = ansur["subject"]
    if isinstance(subject, bool) or not isinstance(subject, int):
        raise ModelError(f"expected a subject id (an integer), got {subject!r}", source="human",
                         key="human.ansur.subject")
    if sex is not None and ansur.get("sex", sex) != sex:
        raise ModelError(f"the subject's sex {ansur.get('sex')!r} is not human.sex {sex!r}", source="human",
                         key="human.ansur.sex")
    sex = ansur.get("sex", sex)
    return ("male" if sex is None else sex), subject


def _seated_body(anthro: Anthropometry, urdf: str, spec: dict[str, Any], chosen: Any) -> Body:
    """The human seated on the seat: a driver whose calf meets the cushion's edge sits closer, the knee flexed
    more, until the seat fits."""
    model = parse(urdf, "human", ours=True)
    while True:
        sitting = seated(anthro, chosen)
        _frames_at(model, sitting)
        body = _finish(model, urdf, "human", spec, sitting.root, sitting.capsules(human_capsules(anthro)), anthro,
                       sitting)
        clash = _seat_clash(body)
        if clash is None:
            return body
        capsule, box, depth = clash
        refit = (chosen.kind == "car" and chosen.feet_x is not None and math.isnan(chosen.feet_x)
                 and capsule.endswith("shank") and box == "seat_pan" and chosen.knee + KNEE_STEP <= KNEE_MOST + 1e-9)
        if not refit:
            raise ModelError(f"seated, the {capsule} passes {depth:.3f} m into the seat's {box}: the seat does not fit "
                             "this body (check its depth, height, back_angle and feet)", source="human",
                             key="human.seat")
        # the calf on the cushion's edge: the driver sits closer, the knee flexed more (oracles/bodies/seat.py)
        chosen = replace(chosen, knee=chosen.knee + KNEE_STEP)
        model = parse(urdf, "human", ours=True)


def _frames_at(model: pin.Model, sitting: Seated) -> None:
    """The seated body's contact frames, at their world points in the seated reference posture."""
    data = model.createData()
    q = _seated_q(model, sitting)
    pin.framesForwardKinematics(model, data, q)
    for name, (parent, point) in sitting.frames.items():
        pid = model.getFrameId(parent)
        on = model.frames[pid]
        joint = data.oMi[on.parentJoint]
        # Axes parallel to the world's in the seated reference (a hinge about the frame's y pitches about the world's
        # y).
        model.addFrame(pin.Frame(name, on.parentJoint, pid, pin.SE3(joint.rotation.T, joint.actInv(point)),
                                 pin.FrameType.OP_FRAME))


def _seated_q(model: pin.Model, sitting: Seated) -> np.ndarray:
    q = pin.neutral(model)
    q[:3] = sitting.root
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, sitting.pitch, 0.0)).coeffs()
    for name, value in sitting.joints.items():
        q[model.joints[model.getJointId(name)].idx_q] = value
    return q


def _seat_clash(body: Body) -> tuple[str, str, float] | None:
    """The first segment that passes through the seat in the seated reference posture (coal), more than 5 mm: its
    capsule's name, the box's and how deep [m]; None when the seat fits the body."""
    # coal only when its distances are computed
    import coal

    model = body.collision
    data = model.model.createData()
    pin.forwardKinematics(model.model, data, body.q_ref)
    for i, obj in enumerate(model.geometry.geometryObjects):
        placement = data.oMi[obj.parentJoint] * obj.placement
        for box in body.furniture:
            d = coal.distance(obj.geometry, coal.Transform3s(placement.rotation, placement.translation),
                              coal.Box(*(2 * box.half)),
                              coal.Transform3s(box.matrix, box.centre), coal.DistanceRequest(), coal.DistanceResult())
            if d < -0.005:
                return model.placed[i].name, box.name, -d
    return None


def _given(**keys: Any) -> dict[str, Any]:
    """The spec's optional keys that were given (a spec without them keeps its hash)."""
    return {k: v for k, v in keys.items() if v is not None and v != {} and v != []}


URDF_MAX_BYTES = 64 * 1024 * 1024  # a URDF's XML: the largest in example-robot-data is under 1 MB


def urdf_body(path: str | Path, root_position: list[float] | None = None, ranges: dict[str, Any] | None = None,
              package_dirs: list[str] | None = None, *, up: str | None = None, forward: str | None = None,
              root_rpy: list[float] | None = None, frames: dict[str, Any] | None = None, reference: Any = None,
              srdf: str | None = None) -> Body:
    """Any URDF, with a floating root at root_position [m] turned by ``up`` and root_rpy; its collision geometry
    becomes capsules (meshes found by ``package://`` in package_dirs, or relative to the URDF's folder); ``srdf``:
    the robot's SRDF, whose ``disable_collisions`` pairs of links self-collision leaves alone."""
    path = Path(path)
    try:
        # A regular file of bounded size: /dev/zero was read for ever.
        if path.exists() and not path.is_file():
            raise ModelError("not a regular file: a URDF is an XML file", source=path)
        size = path.stat().st_size
        if size > URDF_MAX_BYTES:
            raise ModelError(f"{size} bytes: a URDF is at most {URDF_MAX_BYTES} bytes here (meshes live in their own "
                             "files)", source=path)
        urdf = path.read_text(encoding="utf-8")
        no_doctype(urdf, path, "URDF")
    except OSError as exc:
        raise ModelError(f"cannot read URDF ({exc.strerror or exc})", source=path) from exc
    except UnicodeDecodeError as exc:
        raise ModelError(f"not UTF-8 text (byte {exc.start}): a URDF is an XML file in UTF-8", source=path) from None
    spec: dict[str, Any] = {"urdf": str(path)}
    spec.update(_given(root_position=None if root_position is None else list(root_position), ranges=ranges,
                       package_dirs=None if package_dirs is None else list(package_dirs), up=up, forward=forward,
                       root_rpy=root_rpy, frames=frames, reference=reference, srdf=srdf))
    root = np.zeros(3) if root_position is None else numbers(root_position, 3, "root_position", "m", str(path))
    capsules = urdf_capsules(urdf, str(path), path.parent, package_dirs or ())
    model = parse(urdf, str(path))
    body = _finish(model, urdf, str(path), spec, root, capsules)
    return body if srdf is None else replace(body, disabled=disabled_pairs(srdf, model))


BODY_KEYS = {"human", "urdf", "root_position", "ranges", "package_dirs", "up", "forward", "root_rpy", "frames",
             "reference", "srdf"}
URDF_ONLY = {"root_position", "package_dirs", "up", "forward", "root_rpy", "srdf"}
HUMAN_KEYS = {"sex", "stature", "percentile", "mass", "posture", "seat", "ansur", "proportions"}
DIMENSIONS = frozenset(ANSUR_COLUMNS) - {"stature", ANSUR_MASS}  # a human's measures by ANSUR II's names [m]
PLACING = ("up", "forward", "root_rpy", "frames", "reference")  # keys that move the body's frames: part of its hash


def load_body(spec: dict[str, Any]) -> Body:
    """Build a body from its JSON-compatible spec (see the module docstring)."""
    if not isinstance(spec, dict) or ("human" in spec) == ("urdf" in spec):
        raise ModelError(f"expected a mapping with exactly one of 'human' or 'urdf', got {spec!r}")
    unknown = set(spec) - BODY_KEYS
    if unknown:
        key = sorted(unknown)[0]
        raise ModelError(f"unknown key; allowed: {', '.join(sorted(BODY_KEYS))}", key=key)
    ranges = spec.get("ranges")
    if ranges is not None and not isinstance(ranges, dict):
        raise ModelError(f"expected a mapping of joint name to range, got {ranges!r}", key="ranges")
    if "human" in spec:
        return human_body(ranges=ranges, frames=spec.get("frames"), reference=spec.get("reference"),
                          **_human_keys(spec))
    dirs = spec.get("package_dirs")
    if dirs is not None and (not isinstance(dirs, list) or not all(isinstance(d, str) for d in dirs)):
        raise ModelError(f"expected a list of folders, got {dirs!r}", key="package_dirs")
    srdf = spec.get("srdf")
    if srdf is not None and not isinstance(srdf, str):
        raise ModelError(f"expected the path of the robot's SRDF, got {srdf!r}", key="srdf")
    return urdf_body(spec["urdf"], spec.get("root_position"), ranges, dirs, up=spec.get("up"),
                     forward=spec.get("forward"), root_rpy=spec.get("root_rpy"),
                     frames=spec.get("frames"), reference=spec.get("reference"), srdf=srdf)


def _human_keys(spec: dict[str, Any]) -> dict[str, Any]:
    """A human spec's keys as :func:`human_body` takes them (its ANSUR II dimensions as ``dims``), or ModelError
    naming the key it does not take."""
    human = spec["human"] or {}
    if not isinstance(human, dict):
        raise ModelError(f"expected a mapping with keys among {sorted(HUMAN_KEYS)}, got {human!r}", key="human")
    strange = sorted(set(human) - HUMAN_KEYS - DIMENSIONS)
    if strange:
        raise ModelError(f"unknown key; a human takes {', '.join(sorted(HUMAN_KEYS))} and ANSUR II's dimensions "
                         f"by name [m]: {', '.join(sorted(DIMENSIONS))}", key=f"human.{strange[0]}")
    dims = {k: v for k, v in human.items() if k in DIMENSIONS}
    human = {k: v for k, v in human.items() if k in HUMAN_KEYS}
    if dims:
        human["dims"] = dims
    placed = sorted(set(spec) & URDF_ONLY)
    if placed:
        raise ModelError("a URDF body's key; the generated human stands on z = 0 facing +x", key=placed[0])
    return human
