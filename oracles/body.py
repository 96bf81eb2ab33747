"""Bodies as Pinocchio models: any URDF, or the generated human.

Every body gets a floating root joint named ``root`` (a free flyer), so that
the centre of mass includes the root link and whole-body strategies can move
the pelvis. The reference configuration ``q_ref`` places the root at
``root_position`` with identity orientation and every joint at zero (clipped
into its range); for the generated human that is standing, soles on z = 0.

A body is described by a JSON-compatible spec, so that workers can rebuild it:

* ``{"human": {"sex": "male", "percentile": 50, "mass": 80}}``
* ``{"urdf": "path/to/robot.urdf", "root_position": [0, 0, 0.5]}``

either with optional ``ranges``: joint name or glob pattern -> ``[lower,
upper]`` in radians, or ``{"scale": f}`` to scale both limits towards zero
(an impaired or fatigued joint).
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.anthropometry import Anthropometry, anthropometry
from oracles.collision import Capsule, CollisionModel, urdf_capsules
from oracles.errors import ModelError
from oracles.human import human_capsules, human_urdf, root_height

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
    """

    model: pin.Model
    q_ref: np.ndarray
    source: str
    spec: dict[str, Any]
    urdf: str
    anthropometry: Anthropometry | None = None
    capsules: tuple[Capsule, ...] = ()

    @cached_property
    def collision(self) -> CollisionModel:
        """The capsules placed on the model's joints, with coal geometry (built once)."""
        return CollisionModel(self.model, self.capsules, self.source)

    @property
    def joint_names(self) -> list[str]:
        """Names of the joints after the root, in model order."""
        return [str(n) for n in self.model.names[2:]]

    @property
    def q_names(self) -> list[str]:
        """A name for each configuration coordinate (root: root_x ... root_qw)."""
        names = [f"root_{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
        for j in range(2, self.model.njoints):
            jm = self.model.joints[j]
            n = str(self.model.names[j])
            names += [n] if jm.nq == 1 else [f"{n}_{k}" for k in range(jm.nq)]
        return names

    @property
    def mass(self) -> float:
        return float(pin.computeTotalMass(self.model))

    @property
    def hash(self) -> str:
        """Identifies the model (URDF text and range overrides) in stored atlases."""
        text = self.urdf + json.dumps(self.spec.get("ranges", {}), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def frame_id(self, name: str) -> int:
        if not self.model.existFrame(name):
            known = sorted({str(f.name) for f in self.model.frames} - {"universe"})
            raise ModelError(f"no frame {name!r}; frames are: {', '.join(known)}", source=self.source, name=name)
        return int(self.model.getFrameId(name))

    def joint_id(self, name: str) -> int:
        if name not in self.joint_names:
            raise ModelError(f"no joint {name!r}; joints are: {', '.join(self.joint_names)}", source=self.source, name=name)
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
        """What ``reach model`` prints: source, hash, mass [kg], joints and ranges [rad, m], frames [m], centre of mass [m]."""
        info: dict[str, Any] = {
            "source": self.source,
            "hash": self.hash,
            "mass": self.mass,
            "nq": int(self.model.nq),
            "joints": [{"name": n, "lower": lo, "upper": hi} for n, lo, hi in self.limits()],
            "frames": {name: pos.round(6).tolist() for name, pos in self.frame_positions().items()},
            "center_of_mass": self.center_of_mass().round(6).tolist(),
            "capsules": [{"name": c.name, "link": c.link, "radius": round(c.radius, 6), "length": round(c.length, 6),
                          "a": [round(float(v), 6) for v in c.a], "b": [round(float(v), 6) for v in c.b]} for c in self.capsules],
            "units": {"length": "m", "angle": "rad", "mass": "kg"},
        }
        if self.anthropometry is not None:
            info["stature"] = self.anthropometry.stature
            info["sex"] = self.anthropometry.sex
        return info

    def limits(self) -> list[tuple[str, float, float]]:
        """(name, lower, upper) of every joint coordinate after the root."""
        out = []
        for j in range(2, self.model.njoints):
            i, nq = self.model.joints[j].idx_q, self.model.joints[j].nq
            for k in range(nq):
                name = str(self.model.names[j]) if nq == 1 else f"{self.model.names[j]}_{k}"
                out.append((name, float(self.model.lowerPositionLimit[i + k]), float(self.model.upperPositionLimit[i + k])))
        return out


def _parse(urdf: str, source: str) -> pin.Model:
    try:
        return pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer(), ROOT)
    except (RuntimeError, ValueError, IndexError) as exc:
        raise ModelError(f"not a valid URDF ({exc})", source=source) from exc


def _apply_ranges(model: pin.Model, ranges: dict[str, Any], source: str) -> None:
    names = [str(n) for n in model.names[2:]]
    for pattern, value in ranges.items():
        hits = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
        if not hits:
            raise ModelError(f"ranges: no joint matches {pattern!r}; joints are: {', '.join(names)}", source=source)
        for n in hits:
            jm = model.joints[model.getJointId(n)]
            if jm.nq != 1:
                raise ModelError(f"ranges: joint {n!r} has {jm.nq} coordinates; only 1-coordinate joints take ranges", source=source)
            i = jm.idx_q
            if isinstance(value, dict) and set(value) == {"scale"} and isinstance(value["scale"], (int, float)) and 0 < value["scale"] <= 1:
                model.lowerPositionLimit[i] *= value["scale"]
                model.upperPositionLimit[i] *= value["scale"]
            elif isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value) and value[0] <= value[1]:
                model.lowerPositionLimit[i], model.upperPositionLimit[i] = float(value[0]), float(value[1])
            else:
                raise ModelError(f"ranges.{pattern}: expected [lower, upper] in radians or {{scale: f}} with 0 < f <= 1, got {value!r}", source=source)


def _check_limits(model: pin.Model, source: str) -> None:
    """Every one-coordinate joint's limits are numbers with lower <= upper (a URDF may say otherwise)."""
    for j in range(2, model.njoints):
        jm = model.joints[j]
        if jm.nq != 1:
            continue
        lo, hi = float(model.lowerPositionLimit[jm.idx_q]), float(model.upperPositionLimit[jm.idx_q])
        if np.isnan(lo) or np.isnan(hi) or lo > hi:
            name = str(model.names[j])
            raise ModelError(f"joint {name!r} has limits lower {lo} > upper {hi}; expected lower <= upper [rad or m]", source=source, name=name)


def _finish(model: pin.Model, urdf: str, source: str, spec: dict[str, Any], root: np.ndarray, capsules: list[Capsule], anthro: Anthropometry | None = None) -> Body:
    _check_limits(model, source)
    _apply_ranges(model, dict(spec.get("ranges", {})), source)
    # The free flyer's translation has no meaningful limits; bound it so
    # that random configurations and solvers stay finite.
    model.lowerPositionLimit[:3] = root - 2.0
    model.upperPositionLimit[:3] = root + 2.0
    model.lowerPositionLimit[3:7] = -1.0
    model.upperPositionLimit[3:7] = 1.0
    q = pin.neutral(model)
    q[:3] = root
    q[7:] = np.clip(q[7:], model.lowerPositionLimit[7:], model.upperPositionLimit[7:])
    return Body(model, q, source, spec, urdf, anthro, tuple(capsules))


def human_body(sex: str = "male", stature: float | None = None, percentile: float | None = None, mass: float | None = None, ranges: dict[str, Any] | None = None) -> Body:
    """The generated human (see :mod:`oracles.human`)."""
    anthro = anthropometry(sex, stature, percentile, mass)  # type: ignore[arg-type]
    human = {"sex": sex, "stature": stature, "percentile": percentile, "mass": mass}
    spec: dict[str, Any] = {"human": {k: v for k, v in human.items() if v is not None}}
    if ranges:
        spec["ranges"] = ranges
    urdf = human_urdf(anthro)
    model = _parse(urdf, "human")
    return _finish(model, urdf, "human", spec, np.array([0.0, 0.0, root_height(anthro)]), human_capsules(anthro), anthro)


def urdf_body(path: str | Path, root_position: list[float] | None = None, ranges: dict[str, Any] | None = None,
              package_dirs: list[str] | None = None) -> Body:
    """Any URDF, with a floating root at root_position [m]; its collision geometry becomes capsules
    (meshes found by ``package://`` in package_dirs, or relative to the URDF's folder)."""
    path = Path(path)
    try:
        urdf = path.read_text()
    except OSError as exc:
        raise ModelError(f"cannot read URDF ({exc.strerror or exc})", source=path) from exc
    spec: dict[str, Any] = {"urdf": str(path)}
    if root_position is not None:
        spec["root_position"] = list(root_position)
    if ranges:
        spec["ranges"] = ranges
    if package_dirs:
        spec["package_dirs"] = list(package_dirs)
    root = np.zeros(3) if root_position is None else np.asarray(root_position, float)
    if root.shape != (3,):
        raise ModelError(f"root_position must be [x, y, z] in metres, got {root_position!r}", source=path)
    capsules = urdf_capsules(urdf, str(path), path.parent, package_dirs or ())
    return _finish(_parse(urdf, str(path)), urdf, str(path), spec, root, capsules)


BODY_KEYS = {"human", "urdf", "root_position", "ranges", "package_dirs"}
HUMAN_KEYS = {"sex", "stature", "percentile", "mass"}


def load_body(spec: dict[str, Any]) -> Body:
    """Build a body from its JSON-compatible spec (see the module docstring)."""
    if not isinstance(spec, dict) or ("human" in spec) == ("urdf" in spec):
        raise ModelError(f"body spec needs exactly one of 'human' or 'urdf', got {spec!r}", source="body spec")
    unknown = set(spec) - BODY_KEYS
    if unknown:
        raise ModelError(f"unknown keys {sorted(unknown)}; allowed: {sorted(BODY_KEYS)}", source="body spec")
    ranges = spec.get("ranges")
    if ranges is not None and not isinstance(ranges, dict):
        raise ModelError(f"ranges must be a mapping of joint name to range, got {ranges!r}", source="body spec", name="ranges")
    if "human" in spec:
        human = spec["human"] or {}
        if not isinstance(human, dict) or set(human) - HUMAN_KEYS:
            raise ModelError(f"human takes {sorted(HUMAN_KEYS)}, got {human!r}", source="body spec", name="human")
        return human_body(ranges=ranges, **human)
    dirs = spec.get("package_dirs")
    if dirs is not None and (not isinstance(dirs, list) or not all(isinstance(d, str) for d in dirs)):
        raise ModelError(f"package_dirs must be a list of folders, got {dirs!r}", source="body spec", name="package_dirs")
    return urdf_body(spec["urdf"], spec.get("root_position"), ranges, dirs)
