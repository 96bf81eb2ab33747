"""Symbolic kinematics for CasADi, generated from a Pinocchio model.

The PyPI build of Pinocchio has no ``pinocchio.casadi``, so this module
rebuilds forward kinematics symbolically from the model's own data: joint
placements, joint types and axes, frame placements, link masses and centres
of mass. Tests compare it with Pinocchio's numeric ``framesForwardKinematics``
and ``centerOfMass`` at random configurations.

Joint types covered (everything Pinocchio's URDF parser yields, plus the
free flyer we add as root): revolute about x, y, z or any axis (bounded, and
unbounded with (cos, sin) coordinates), prismatic along x, y, z or any axis,
free flyer (x, y, z, qx, qy, qz, qw), planar (x, y, cos, sin), spherical
(quaternion), spherical ZYX, translation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.errors import ModelError

SE3 = tuple[ca.SX, ca.SX]  # (rotation 3x3, translation 3x1)


class Numbers(Protocol):
    """Named numbers as expressions (:class:`oracles.ik.parameters.BodyParameters`)."""

    def sx(self, name: str) -> ca.SX: ...


class Stacked:
    """Named arrays as one flat vector, each row by row (a vector a column, a number 1 x 1): what
    :class:`oracles.ik.parameters.BodyParameters` reads. A body's model arrays are stacked once and shared by its
    strategies' parameters (a population member's ~400 small arrays stacked again took 0.7 ms a strategy).

    Attributes:
        shapes: Each array's shape (rows, columns), in order.
        flat: The entries, in that order.
    """

    def __init__(self, arrays: Mapping[str, np.ndarray]) -> None:
        given = [np.asarray(v, float) for v in arrays.values()]
        self.shapes: dict[str, tuple[int, int]] = {k: (a.size, 1) if a.ndim <= 1 else (a.shape[0], a.shape[1])
                                                   for k, a in zip(arrays, given, strict=True)}
        self.flat = np.concatenate([a.ravel() for a in given]) if given else np.zeros(0)

    def __add__(self, other: Stacked) -> Stacked:
        if self.shapes.keys() & other.shapes.keys():
            raise ValueError(f"arrays named twice: {sorted(self.shapes.keys() & other.shapes.keys())}")
        out = Stacked({})
        out.shapes, out.flat = {**self.shapes, **other.shapes}, np.concatenate([self.flat, other.flat])
        return out


def model_arrays(model: pin.Model) -> dict[str, np.ndarray]:
    """The model's numbers the kinematics use, by the names :class:`SymbolicKinematics` asks ``numbers`` for: each
    joint's and frame's placement in its parent (``joint3.R``, ``joint3.p``, ``frame12.R`` ...) and each link's mass
    and centre of mass in its joint's frame (``inertia3.mass``, ``inertia3.lever``)."""
    out: dict[str, np.ndarray] = {}
    for j in range(1, model.njoints):
        m = model.jointPlacements[j]
        out[f"joint{j}.R"], out[f"joint{j}.p"] = np.asarray(m.rotation), np.asarray(m.translation)
        out[f"inertia{j}.mass"] = np.array([model.inertias[j].mass])
        out[f"inertia{j}.lever"] = np.asarray(model.inertias[j].lever)
    for fid in range(model.nframes):
        m = model.frames[fid].placement
        out[f"frame{fid}.R"], out[f"frame{fid}.p"] = np.asarray(m.rotation), np.asarray(m.translation)
    return out


def _rot(axis: np.ndarray, c: ca.SX, s: ca.SX) -> ca.SX:
    """Rotation matrix about a unit axis from cos and sin (Rodrigues)."""
    x, y, z = (float(a) for a in axis)
    k = ca.SX(np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]]))
    return ca.SX.eye(3) + s * k + (1 - c) * (k @ k)


def _quat(qx: ca.SX, qy: ca.SX, qz: ca.SX, qw: ca.SX) -> ca.SX:
    """Rotation matrix of a unit quaternion (Pinocchio order x, y, z, w)."""
    return ca.vertcat(
        ca.horzcat(1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)),
        ca.horzcat(2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)),
        ca.horzcat(2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)),
    )


_AXES = {"X": np.array([1.0, 0, 0]), "Y": np.array([0, 1.0, 0]), "Z": np.array([0, 0, 1.0])}


def _axis(joint: pin.JointModel, angular: bool) -> np.ndarray:
    """Axis of a one-axis joint, read from its motion subspace (not every binding exposes .axis)."""
    data = joint.createData()
    joint.calc(data, _neutral(joint))
    s = np.asarray(data.S).reshape(6, -1)[:, 0]
    return s[3:] if angular else s[:3]


def _neutral(joint: pin.JointModel) -> np.ndarray:
    model = pin.Model()
    model.addJoint(0, joint, pin.SE3.Identity(), "j")
    return pin.neutral(model)


def joint_motion(joint: pin.JointModel, q: ca.SX) -> SE3:
    """Placement of a joint's child frame relative to its parent frame at q (the joint's own coordinates)."""
    kind = joint.shortname()
    zero = ca.SX.zeros(3, 1)
    if kind in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return _rot(_AXES[kind[-1]], ca.cos(q[0]), ca.sin(q[0])), zero
    if kind == "JointModelRevoluteUnaligned":
        return _rot(_axis(joint, True), ca.cos(q[0]), ca.sin(q[0])), zero
    if kind in ("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ"):
        return _rot(_AXES[kind[-1]], q[0], q[1]), zero
    if kind == "JointModelRevoluteUnboundedUnaligned":
        return _rot(_axis(joint, True), q[0], q[1]), zero
    if kind in ("JointModelPX", "JointModelPY", "JointModelPZ"):
        return ca.SX.eye(3), ca.SX(_AXES[kind[-1]]) * q[0]
    if kind == "JointModelPrismaticUnaligned":
        return ca.SX.eye(3), ca.SX(_axis(joint, False)) * q[0]
    if kind == "JointModelFreeFlyer":
        return _quat(q[3], q[4], q[5], q[6]), q[0:3]
    if kind == "JointModelSpherical":
        return _quat(q[0], q[1], q[2], q[3]), zero
    if kind == "JointModelTranslation":
        return ca.SX.eye(3), q[0:3]
    if kind == "JointModelPlanar":
        return _rot(_AXES["Z"], q[2], q[3]), ca.vertcat(q[0], q[1], 0)
    if kind == "JointModelSphericalZYX":
        rz = _rot(_AXES["Z"], ca.cos(q[0]), ca.sin(q[0]))
        ry = _rot(_AXES["Y"], ca.cos(q[1]), ca.sin(q[1]))
        rx = _rot(_AXES["X"], ca.cos(q[2]), ca.sin(q[2]))
        return rz @ ry @ rx, zero
    raise ModelError(f"joint type {kind} is not supported by the symbolic kinematics", name=str(kind))


def _compose(a: SE3, b: SE3) -> SE3:
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def _const(m: pin.SE3) -> SE3:
    return ca.SX(np.asarray(m.rotation)), ca.SX(np.asarray(m.translation).reshape(3, 1))


class SymbolicKinematics:
    """Forward kinematics of a Pinocchio model as CasADi expressions of q.

    ``numbers``, when given, supplies the model's numbers (:func:`model_arrays`'s names) as expressions, lifted to
    parameters or not (:class:`oracles.ik.parameters.BodyParameters`); else they are the model's own constants.

    Attributes:
        q: The (nq, 1) CasADi symbol.
        placements: World placement (R, p) of every joint, index = joint id.
    """

    def __init__(self, model: pin.Model, q: ca.SX | None = None, numbers: Numbers | None = None) -> None:
        self.model = model
        self.numbers = numbers
        self.q = ca.SX.sym("q", model.nq) if q is None else q
        self.placements: list[SE3] = [(ca.SX.eye(3), ca.SX.zeros(3, 1))]
        for j in range(1, model.njoints):
            jm = model.joints[j]
            local = joint_motion(jm, self.q[jm.idx_q : jm.idx_q + jm.nq])
            parent = self.placements[model.parents[j]]
            self.placements.append(_compose(_compose(parent, self._placement(f"joint{j}", model.jointPlacements[j])),
                                            local))

    def _placement(self, name: str, m: pin.SE3) -> SE3:
        if self.numbers is None:
            return _const(m)
        return self.numbers.sx(f"{name}.R"), self.numbers.sx(f"{name}.p")

    def frame(self, name: str) -> SE3:
        """World placement (R, p) of a frame."""
        if not self.model.existFrame(name):
            raise ModelError(f"no frame {name!r} in the model", name=name)
        fid = self.model.getFrameId(name)
        f = self.model.frames[fid]
        return _compose(self.placements[f.parentJoint], self._placement(f"frame{fid}", f.placement))

    def center_of_mass(self) -> ca.SX:
        """World position of the centre of mass (3, 1)."""
        total = ca.SX.zeros(3, 1)
        mass: float | ca.SX = 0.0
        for j in range(1, self.model.njoints):
            inertia = self.model.inertias[j]
            if inertia.mass <= 0.0:
                continue  # a massless link (its zero is part of a lifted body's signature)
            rot, pos = self.placements[j]
            if self.numbers is None:
                m, lever = inertia.mass, ca.SX(np.asarray(inertia.lever).reshape(3, 1))
            else:
                m, lever = self.numbers.sx(f"inertia{j}.mass"), self.numbers.sx(f"inertia{j}.lever")
            total += m * (rot @ lever + pos)
            mass += m
        if isinstance(mass, float) and mass <= 0.0:
            raise ModelError("the model has no mass; the centre of mass is undefined")
        return total / mass

    def function(self, frames: Sequence[str], com: bool = True) -> ca.Function:
        """A CasADi Function q -> (frame positions 3xK, frame rotations 3x3K, com 3x1)."""
        placed = [self.frame(n) for n in frames]
        pos = ca.horzcat(*[p for _, p in placed]) if placed else ca.SX.zeros(3, 0)
        rot = ca.horzcat(*[r for r, _ in placed]) if placed else ca.SX.zeros(3, 0)
        outs = [pos, rot] + ([self.center_of_mass()] if com else [])
        names = ["positions", "rotations"] + (["com"] if com else [])
        return ca.Function("forward_kinematics", [self.q], outs, ["q"], names)
