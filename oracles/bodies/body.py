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

import fnmatch
import hashlib
import json
import math
import xml.etree.ElementTree as ET
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
from oracles.bodies.seat import KNEE_MOST, KNEE_STEP, Seated, fit, parse_seat, seated
from oracles.errors import ModelError
from oracles.protocol import COS, SIN

ROOT = "root"


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
        return [str(n) for n in self.model.names[2:]]

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
        if name not in self.joint_names:
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
            seat = fit(self.anthropometry, parse_seat(human.get("seat")))
            fitted = seat.feet_x is not None and math.isnan(seat.feet_x)  # with the legs: where the heel came to rest
            if fitted:
                knee = float(self.q_ref[self.model.joints[self.model.getJointId("right_knee_flexion")].idx_q])
                seat = replace(seat, feet_x=round(float(info["frames"]["right_heel"][0]), 4), knee=knee)
            angles = ("back_angle", "ankle", "knee")  # [deg] in the description; the knee only where it fitted a heel
            info["seat"] = {k: round(math.degrees(v), 3) if k in angles and v is not None else v
                            for k, v in asdict(seat).items() if k != "knee" or fitted}
        if self.furniture:
            info["furniture"] = [b.to_dict() for b in self.furniture]
        return info

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


def _no_doctype(text: str, source: Any, kind: str) -> None:
    """Refuse a document type declaration: its entities could name local files or expand without bound, and a URDF
    or SRDF needs none (neither is resolved: the file is refused before any parser sees it)."""
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise ModelError(f"a document type declaration (<!DOCTYPE ...> or <!ENTITY ...>): refused, never resolved; "
                         f"a {kind} needs none", source=source)


def _check_xml(urdf: str, source: str) -> None:
    """What urdfdom accepts silently or reports over many lines: not XML, a negative or non-finite mass, a zero
    joint axis. Each is one line naming the link or joint."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as exc:
        raise ModelError(f"not a valid URDF (XML: {exc})", source=source) from None
    for link in root.iter("link"):
        mass = link.find("inertial/mass")
        if mass is not None:
            try:
                value = float(mass.get("value", "nan"))
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and value >= 0):
                raise ModelError(f"link {link.get('name')!r}: mass {mass.get('value')!r}; expected a finite number "
                                 ">= 0 [kg]", source=source)
    for joint in root.iter("joint"):
        axis = joint.find("axis")
        if axis is not None and joint.get("type") in ("revolute", "continuous", "prismatic"):
            try:
                xyz = [float(v) for v in axis.get("xyz", "1 0 0").split()]
            except ValueError:
                xyz = []
            if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz) or math.hypot(*xyz) < 1e-9:
                raise ModelError(f"joint {joint.get('name')!r}: axis {axis.get('xyz')!r}; expected three finite "
                                 "numbers, not all zero", source=source)


def _parse(urdf: str, source: str) -> pin.Model:
    _check_xml(urdf, source)
    try:
        return pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer(), ROOT)
    except (RuntimeError, ValueError, IndexError) as exc:
        raise ModelError(f"not a valid URDF ({exc})", source=source) from exc


def _apply_ranges(model: pin.Model, ranges: dict[str, Any], source: str) -> None:
    names = [str(n) for n in model.names[2:]]
    for pattern, value in ranges.items():
        hits = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
        if not hits:
            raise ModelError(f"no joint matches; joints are: {', '.join(names)}", source=source,
                             key=f"ranges.{pattern}")
        for n in hits:
            jm = model.joints[model.getJointId(n)]
            if jm.nq != 1:
                raise ModelError(f"joint {n!r} has {jm.nq} coordinates; only 1-coordinate joints take ranges",
                                 source=source, key=f"ranges.{pattern}")
            i = jm.idx_q
            if (isinstance(value, dict) and set(value) == {"scale"} and isinstance(value["scale"], (int, float))
                and 0 < value["scale"] <= 1):
                model.lowerPositionLimit[i] *= value["scale"]
                model.upperPositionLimit[i] *= value["scale"]
            elif (isinstance(value, (list, tuple)) and len(value) == 2
                  and all(isinstance(v, (int, float)) for v in value) and value[0] <= value[1]):
                model.lowerPositionLimit[i], model.upperPositionLimit[i] = float(value[0]), float(value[1])
            else:
                raise ModelError(f"expected [lower, upper] in radians or {{scale: f}} with 0 < f <= 1, got {value!r}",
                                 source=source, key=f"ranges.{pattern}")


def _check_limits(model: pin.Model, source: str) -> None:
    """Every one-coordinate joint's limits are numbers with lower <= upper (a URDF may say otherwise)."""
    for j in range(2, model.njoints):
        jm = model.joints[j]
        if jm.nq != 1:
            continue
        lo, hi = float(model.lowerPositionLimit[jm.idx_q]), float(model.upperPositionLimit[jm.idx_q])
        if np.isnan(lo) or np.isnan(hi) or lo > hi:
            name = str(model.names[j])
            raise ModelError(f"joint {name!r} has limits lower {lo} > upper {hi}; expected lower <= upper [rad or m]",
                             source=source, name=name)


# A model's own axes, as ``up`` and ``forward`` name them.
AXES = {"x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
        "z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


def _numbers(value: Any, n: int, key: str, unit: str, source: str) -> np.ndarray:
    if (not isinstance(value, (list, tuple)) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
        raise ModelError(f"expected {n} numbers [{unit}], got {value!r}", source=source, key=key)
    return np.array(value, float)


def _root_rotation(spec: dict[str, Any], source: str) -> np.ndarray:
    """The root's orientation: the model's ``up`` onto the world's z and its ``forward`` onto x, then ``root_rpy``."""
    up = spec.get("up", "z")
    if up not in AXES:
        raise ModelError(f"expected one of {', '.join(AXES)} (the model's own up axis), got {up!r}", source=source,
                         key="up")
    u = np.array(AXES[up])
    # By default the model's x stays forward, or its z for a model whose x is up.
    forward = spec.get("forward", "x" if up not in ("x", "-x") else "z")
    if forward not in AXES or abs(float(np.dot(AXES[forward], u))) > 0.5:
        raise ModelError(f"expected one of {', '.join(a for a in AXES if abs(float(np.dot(AXES[a], u))) < 0.5)} (the "
                         f"model's own forward axis, perpendicular to up {up}), got {forward!r}", source=source,
                         key="forward")
    f = np.array(AXES[forward])
    turn = np.stack([f, np.cross(u, f), u])  # rows: model axes that become the world's x, y, z
    rpy = _numbers(spec.get("root_rpy", [0, 0, 0]), 3, "root_rpy", "rad", source)
    return np.asarray(pin.rpy.rpyToMatrix(*rpy) @ turn)


def _add_frames(model: pin.Model, frames: Any, source: str) -> None:
    """Frames the spec adds on existing ones (fixed placements: grip points, tool centre points, sole corners)."""
    if not isinstance(frames, dict):
        raise ModelError(f"expected a mapping of name to {{parent, xyz, rpy}}, got {frames!r}", source=source,
                         key="frames")
    for name, raw in frames.items():
        key = f"frames.{name}"
        if not isinstance(raw, dict) or "parent" not in raw or set(raw) - {"parent", "xyz", "rpy"}:
            raise ModelError(f"expected {{parent: FRAME, xyz: [x, y, z], rpy: [r, p, y]}}, got {raw!r}",
                             source=source, key=key)
        if model.existFrame(str(name)):
            raise ModelError(f"the model already has a frame {name!r}; choose another name", source=source, key=key)
        parent = raw["parent"]
        if not isinstance(parent, str) or not model.existFrame(parent):
            known = sorted({str(f.name) for f in model.frames} - {"universe"})
            raise ModelError(f"no frame {parent!r}; frames are: {', '.join(known)}", source=source, key=f"{key}.parent")
        xyz = _numbers(raw.get("xyz", [0, 0, 0]), 3, f"{key}.xyz", "m", source)
        rpy = _numbers(raw.get("rpy", [0, 0, 0]), 3, f"{key}.rpy", "rad", source)
        pid = model.getFrameId(parent)
        on = model.frames[pid]
        placement = on.placement * pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)
        model.addFrame(pin.Frame(str(name), on.parentJoint, pid, placement, pin.FrameType.OP_FRAME))


def _reference(model: pin.Model, q: np.ndarray, reference: Any, source: str) -> list[str]:
    """Set q's joints to the reference posture; the notes say which joints zero had to be clipped for."""
    lower, upper = model.lowerPositionLimit, model.upperPositionLimit
    if reference is None or reference in ("zero", "middle", "auto"):
        given: dict[str, Any] = {}
    elif isinstance(reference, dict):
        given = dict(reference)
    else:
        raise ModelError("expected zero, middle, auto or a mapping of joint name to value [rad or m], got "
                         f"{reference!r}", source=source, key="reference")
    names = [str(n) for n in model.names[2:]]
    for name in given:
        if name not in names:
            raise ModelError(f"no such joint; joints are: {', '.join(names)}", source=source, key=f"reference.{name}")
    notes = []
    for j in range(2, model.njoints):
        name, jm = str(model.names[j]), model.joints[j]
        i = jm.idx_q
        if name in given:
            value = given[name]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ModelError(f"expected a number [rad or m], got {value!r}", source=source, key=f"reference.{name}")
            if jm.nq == 2:  # an unbounded revolute, stored as (cos, sin)
                q[i:i + 2] = np.cos(value), np.sin(value)
            elif jm.nq == 1 and not lower[i] - 1e-9 <= value <= upper[i] + 1e-9:
                raise ModelError(f"{value} is outside the joint's range [{lower[i]:.6g}, {upper[i]:.6g}]",
                                 source=source, key=f"reference.{name}")
            elif jm.nq == 1:
                q[i] = value
        elif jm.nq == 1 and reference in ("middle", "auto"):
            q[i] = 0.5 * (lower[i] + upper[i])
        elif jm.nq == 1 and not lower[i] <= q[i] <= upper[i]:
            clipped = float(np.clip(q[i], lower[i], upper[i]))
            notes.append(f"reference: joint {name!r} at 0 is outside its range [{lower[i]:.6g}, {upper[i]:.6g}]; "
                         f"it stands at {clipped:.6g} (give body.reference to choose)")
            q[i] = clipped
    return notes


def _finish(model: pin.Model, urdf: str, source: str, spec: dict[str, Any], root: np.ndarray, capsules: list[Capsule],
            anthro: Anthropometry | None = None, sitting: Seated | None = None) -> Body:
    _check_limits(model, source)
    _apply_ranges(model, dict(spec.get("ranges", {})), source)
    _add_frames(model, spec.get("frames", {}), source)
    # The free flyer's translation has no meaningful limits; bound it so
    # that random configurations and solvers stay finite.
    model.lowerPositionLimit[:3] = root - 2.0
    model.upperPositionLimit[:3] = root + 2.0
    model.lowerPositionLimit[3:7] = -1.0
    model.upperPositionLimit[3:7] = 1.0
    q = pin.neutral(model)
    q[:3] = root
    if sitting is None:
        q[3:7] = pin.Quaternion(_root_rotation(spec, source)).coeffs()
    else:
        q = _seated_q(model, sitting)
    notes = _reference(model, q, spec.get("reference"), source)
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
    subject = None
    if ansur is not None:
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
    sex = "male" if sex is None else sex
    anthro = anthropometry(sex, stature, percentile, mass, dims, subject, proportions)  # type: ignore[arg-type]
    human = {"sex": sex, "stature": stature, "percentile": percentile, "mass": mass, "posture": posture, "seat": seat,
             "ansur": ansur, "proportions": proportions, **(dims or {})}
    spec: dict[str, Any] = {"human": {k: v for k, v in human.items() if v is not None}}
    spec.update(_given(ranges=ranges, frames=frames, reference=reference))
    urdf = human_urdf(anthro)
    model = _parse(urdf, "human")
    if posture not in (None, "standing", "seated"):
        raise ModelError(f"expected standing or seated, got {posture!r}", source="human", key="human.posture")
    if posture != "seated":
        if seat is not None:
            raise ModelError("a seat needs posture: seated", source="human", key="human.seat")
        return _finish(model, urdf, "human", spec, np.array([0.0, 0.0, root_height(anthro)]), human_capsules(anthro),
                       anthro)
    chosen = parse_seat(seat)
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
        model = _parse(urdf, "human")


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
        _no_doctype(urdf, path, "URDF")
    except OSError as exc:
        raise ModelError(f"cannot read URDF ({exc.strerror or exc})", source=path) from exc
    except UnicodeDecodeError as exc:
        raise ModelError(f"not UTF-8 text (byte {exc.start}): a URDF is an XML file in UTF-8", source=path) from None
    spec: dict[str, Any] = {"urdf": str(path)}
    spec.update(_given(root_position=None if root_position is None else list(root_position), ranges=ranges,
                       package_dirs=None if package_dirs is None else list(package_dirs), up=up, forward=forward,
                       root_rpy=root_rpy, frames=frames, reference=reference, srdf=srdf))
    root = np.zeros(3) if root_position is None else _numbers(root_position, 3, "root_position", "m", str(path))
    capsules = urdf_capsules(urdf, str(path), path.parent, package_dirs or ())
    model = _parse(urdf, str(path))
    body = _finish(model, urdf, str(path), spec, root, capsules)
    return body if srdf is None else replace(body, disabled=disabled_pairs(srdf, model))


SRDF_MAX_BYTES = 16 * 1024 * 1024  # an SRDF's XML (example-robot-data's are under 100 kB)


def disabled_pairs(srdf: str | Path, model: pin.Model) -> frozenset[frozenset[str]]:
    """The pairs of links an SRDF's ``<disable_collisions link1=... link2=...>`` elements name (MoveIt's convention:
    adjacent links, links that never or always collide), each a link of the model."""
    path = Path(srdf)
    try:
        if path.exists() and not path.is_file():
            raise ModelError("not a regular file: an SRDF is an XML file", source=path, key="srdf")
        if path.stat().st_size > SRDF_MAX_BYTES:
            raise ModelError(f"larger than {SRDF_MAX_BYTES} bytes: not an SRDF", source=path, key="srdf")
        text = path.read_text(encoding="utf-8")
        _no_doctype(text, path, "SRDF")
        root = ET.fromstring(text)
    except OSError as exc:
        raise ModelError(f"cannot read the SRDF ({exc.strerror or exc})", source=path, key="srdf") from exc
    except (ET.ParseError, UnicodeDecodeError) as exc:
        raise ModelError(f"not an SRDF (not well-formed XML in UTF-8: {exc})", source=path, key="srdf") from None
    links = {str(f.name) for f in model.frames if f.type == pin.FrameType.BODY}
    out: set[frozenset[str]] = set()
    for k, element in enumerate(root.iter("disable_collisions")):
        pair = [element.get("link1") or "", element.get("link2") or ""]
        for name in pair:
            if name not in links:
                raise ModelError(f"disable_collisions #{k + 1} names link {name!r}, which the URDF does not have "
                                 f"(links: {', '.join(sorted(links))})", source=path, key="srdf")
        out.add(frozenset(pair))
    return frozenset(out)


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
        return human_body(ranges=ranges, frames=spec.get("frames"), reference=spec.get("reference"), **human)
    dirs = spec.get("package_dirs")
    if dirs is not None and (not isinstance(dirs, list) or not all(isinstance(d, str) for d in dirs)):
        raise ModelError(f"expected a list of folders, got {dirs!r}", key="package_dirs")
    srdf = spec.get("srdf")
    if srdf is not None and not isinstance(srdf, str):
        raise ModelError(f"expected the path of the robot's SRDF, got {srdf!r}", key="srdf")
    return urdf_body(spec["urdf"], spec.get("root_position"), ranges, dirs, up=spec.get("up"),
                     forward=spec.get("forward"), root_rpy=spec.get("root_rpy"),
                     frames=spec.get("frames"), reference=spec.get("reference"), srdf=srdf)

