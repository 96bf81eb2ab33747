"""Frames held on the floor: ``{type: contacts, fixed: [...], hinge: [...], above_floor: [...], support: [...]}``.

``fixed`` frames keep their reference position and orientation; ``hinge``
frames keep their position and one local axis, so they may pivot about it
(a heel rising about the ball of the foot); ``above_floor`` frames stay at
z >= 0; ``support`` frames span the support polygon of a balance task.
A frame that no active joint can move holds by itself: as a constraint it
would only be a constant (and degenerate for the solver), so it is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.tasks.base import (
    BUFFER,
    INSIDE,
    Constraint,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    frames,
    perpendicular_basis,
)

CONTACT_TOL = 1e-4  # [m] contact position drift the verdict accepts
ANGLE_TOL = 1e-3  # [rad] contact orientation drift the verdict accepts


@dataclass(frozen=True)
class Contact:
    """A frame held on the floor at its reference placement.

    ``fixed`` holds position and orientation; ``hinge`` holds the position and
    one local axis, so the frame may pivot about it.
    """

    frame: str
    mode: str = "fixed"
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)


@dataclass
class ContactsTask(HardTask):
    """Frames held fixed or hinged where they stand, others kept above the floor."""

    type: ClassVar[str] = "contacts"
    keys: ClassVar[frozenset[str]] = frozenset({"fixed", "hinge", "above_floor", "support"})
    summary: ClassVar[str] = "any frames held fixed or hinged where they stand, others kept at z >= 0 (for URDF bodies)"

    contacts: tuple[Contact, ...] = ()
    above_floor: tuple[str, ...] = ()
    support: tuple[str, ...] = ()
    _ref: list[pin.SE3] = field(default_factory=list, init=False, repr=False, compare=False)
    _ids: dict[str, int] = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> ContactsTask:
        contacts = [Contact(f, "fixed") for f in frames(scope, raw.get("fixed", []), f"{where}.fixed")]
        contacts += [Contact(f, "hinge") for f in frames(scope, raw.get("hinge", []), f"{where}.hinge")]
        above = frames(scope, raw.get("above_floor", []), f"{where}.above_floor")
        support = frames(scope, raw.get("support", []), f"{where}.support")
        return cls.held(scope, contacts, list(above), list(support))

    @classmethod
    def held(cls, scope: Scope, contacts: list[Contact], above: list[str], support: list[str]) -> ContactsTask:
        """The task for these frames, keeping only those an active joint can move."""
        return cls(
            tuple(c for c in contacts if scope.moves(c.frame)),
            tuple(dict.fromkeys(f for f in above if scope.moves(f))),
            tuple(dict.fromkeys(support)),
        )

    @property
    def held_frames(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(c.frame for c in self.contacts)

    def bind(self, reference: Reference) -> None:
        self._ref = [reference.placement(c.frame) for c in self.contacts]
        self._ids = {f: reference.body.frame_id(f) for f in (*self.held_frames, *self.above_floor)}

    parametric: ClassVar[bool] = True

    def numbers(self) -> dict[str, np.ndarray]:
        out = {}
        for k, (c, ref) in enumerate(zip(self.contacts, self._ref, strict=True)):
            out[f"at{k}"] = np.asarray(ref.translation)
            if c.mode == "fixed":
                out[f"turn{k}"] = np.asarray(ref.rotation.T)
            else:
                out[f"across{k}"] = np.array(perpendicular_basis(ref.rotation @ np.asarray(c.axis)))
        return out

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        out = []
        for k, (c, ref) in enumerate(zip(self.contacts, self._ref, strict=True)):
            rot, pos = sym.kin.frame(c.frame)
            out.append(Constraint(pos - sym.number(self, f"at{k}", ref.translation), 0.0, 0.0))
            if c.mode == "fixed":
                rel = sym.number(self, f"turn{k}", ref.rotation.T) @ rot
                out.append(Constraint(ca.vertcat(rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]),
                                      0.0, 0.0))
            else:
                across = sym.number(self, f"across{k}",
                                    np.array(perpendicular_basis(ref.rotation @ np.asarray(c.axis))))
                w = rot @ ca.SX(np.asarray(c.axis))
                out.append(Constraint(ca.vertcat(ca.dot(w, across[0, :].T), ca.dot(w, across[1, :].T)), 0.0, 0.0))
        out += [Constraint(sym.kin.frame(f)[1][2], 0.0, np.inf) for f in self.above_floor]
        return out

    def rows(self, num: Numeric) -> list[Row]:
        assert num.jacobian is not None  # dls always evaluates Jacobians
        out = []
        for c, ref in zip(self.contacts, self._ref, strict=True):
            cur, jac = num.frame(self._ids[c.frame]), num.jacobian(self._ids[c.frame])
            out.append(Row(jac[:3], ref.translation - cur.translation))
            if c.mode == "fixed":
                out.append(Row(jac[3:], pin.log3(ref.rotation @ cur.rotation.T)))
            else:
                w, w_ref = cur.rotation @ np.asarray(c.axis), ref.rotation @ np.asarray(c.axis)
                basis = perpendicular_basis(w)
                out.append(Row(basis @ jac[3:], basis @ np.cross(w, w_ref)))
        # Inequalities as an active set with a buffer: a row near its bound
        # holds still (error 0); a row past it is pushed back inside.
        for f in self.above_floor:
            z = num.frame(self._ids[f]).translation[2]
            if z < BUFFER:
                out.append(Row(num.jacobian(self._ids[f])[2:3], np.array([max(0.0, INSIDE - z)])))
        return out

    def holds(self, num: Numeric) -> bool:
        ok = True
        for c, ref in zip(self.contacts, self._ref, strict=True):
            cur = num.frame(self._ids[c.frame])
            ok &= bool(np.linalg.norm(cur.translation - ref.translation) <= CONTACT_TOL)
            if c.mode == "fixed":
                ok &= bool(np.linalg.norm(pin.log3(ref.rotation.T @ cur.rotation)) <= ANGLE_TOL)
            else:
                axis = np.asarray(c.axis)
                ok &= bool(np.linalg.norm(cur.rotation @ axis - ref.rotation @ axis) <= ANGLE_TOL)
        for f in self.above_floor:
            ok &= bool(num.frame(self._ids[f]).translation[2] >= -CONTACT_TOL)
        return ok
