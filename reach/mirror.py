"""Left from right: deriving a strategy's tree by mirroring another's.

Allowed only when the body has been checked to be mirror-symmetric about the
sagittal plane y = 0: swapping every ``left_``/``right_`` joint and frame,
negating the central joints whose axes lie in that plane's normal direction
(lateral bending, axial rotations), and reflecting the root, must map every
frame onto the mirror image of its counterpart at random configurations.

The mirrored tree is rebuilt by the same Algorithm 1 with an oracle that
answers from the source tree's vertex table (points and postures
reflected), so it is exactly the tree a build of the mirrored strategy would
give from mirrored verdicts, at no IK cost.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from oracles.body import Body
from oracles.protocol import Verdicts, check_points
from reach.errors import ModelError, OracleError
from reach.tree import Lattice, VATree

SIDES = (("left_", "right_"), ("right_", "left_"))
REFLECT = np.array([1.0, -1.0, 1.0])


def _counterpart(name: str) -> str:
    for a, b in SIDES:
        if name.startswith(a):
            return b + name[len(a):]
    return name


class MirrorMap:
    """The map of configurations of a mirror-symmetric body; raises ModelError otherwise."""

    def __init__(self, body: Body, samples: int = 8, seed: int = 0, tol: float = 1e-7) -> None:
        self.body = body
        model = body.model
        names = body.joint_names
        self.perm = np.arange(model.nq)
        self.sign = np.ones(model.nq)
        for n in names:
            other = _counterpart(n)
            if other not in names:
                raise ModelError(f"{body.source}: joint {n!r} has no mirror counterpart {other!r}")
            j, k = model.joints[model.getJointId(n)], model.joints[model.getJointId(other)]
            if j.nq != 1 or k.nq != 1:
                raise ModelError(f"{body.source}: mirroring supports one-coordinate joints only ({n!r})")
            self.perm[j.idx_q] = k.idx_q
        self.frames = [str(f.name) for f in model.frames if str(f.name) != "universe" and _counterpart(str(f.name)) in {str(g.name) for g in model.frames}]
        # Central joints: pick the sign that mirrors the frames; side joints keep theirs.
        for n in names:
            if _counterpart(n) == n:
                i = model.joints[model.getJointId(n)].idx_q
                q = body.q_ref.copy()
                q[i] = 0.3
                self.sign[i] = 1.0
                plus = self._error(q)
                self.sign[i] = -1.0
                if self._error(q) > plus:
                    self.sign[i] = 1.0
        lo, hi = model.lowerPositionLimit[7:], model.upperPositionLimit[7:]
        # Ranges must mirror too: a side joint's equal its counterpart's, a negated joint's be symmetric.
        mlo = np.where(self.sign[7:] > 0, lo, -hi)[self.perm[7:] - 7]
        mhi = np.where(self.sign[7:] > 0, hi, -lo)[self.perm[7:] - 7]
        bad = [names[i] for i in range(len(names)) if not (np.isclose(mlo[i], lo[i]) and np.isclose(mhi[i], hi[i]))]
        if bad:
            raise ModelError(f"{body.source}: joint ranges are not mirror-symmetric ({', '.join(sorted(bad)[:4])}); build both sides instead")
        rng = np.random.default_rng(seed)
        for _ in range(samples):
            q = body.q_ref.copy()
            q[7:] = rng.uniform(lo, hi)
            q[:3] += rng.normal(scale=0.05, size=3)
            q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*rng.normal(scale=0.2, size=3))).coeffs()
            err = self._error(q)
            if err > tol:
                raise ModelError(f"{body.source}: the model is not mirror-symmetric about y = 0 (frames differ by {err:.3g} m); build both sides instead")

    def mirror_q(self, q: np.ndarray) -> np.ndarray:
        """The mirror image of configuration(s) q, shape (..., nq)."""
        q = np.asarray(q, dtype=float)
        out = np.empty_like(q)
        out[..., self.perm[7:]] = q[..., 7:] * self.sign[7:]
        out[..., :3] = q[..., :3] * REFLECT
        # Reflecting R by S = diag(1, -1, 1): S R S; for quaternions (x, y, z, w) -> (-x, y, -z, w).
        out[..., 3:7] = q[..., 3:7] * np.array([-1.0, 1.0, -1.0, 1.0])
        return out

    def _error(self, q: np.ndarray) -> float:
        """Largest distance between frames (and centres of mass) and the mirror of their counterparts."""
        mq = self.mirror_q(q)
        a = self.body.frame_positions(q, self.frames)
        b = self.body.frame_positions(mq, self.frames)
        com = float(np.abs(self.body.center_of_mass(mq) - self.body.center_of_mass(q) * REFLECT).max())
        return max([com] + [float(np.abs(b[_counterpart(n)] - a[n] * REFLECT).max()) for n in self.frames])


class MirrorOracle:
    """Answers from a source tree's vertex table, reflected about y = 0."""

    dim = 3

    def __init__(self, source: VATree, mirror: MirrorMap | None) -> None:
        lo, hi = source.box.lo, source.box.hi
        if not np.isclose(lo[1], -hi[1]):
            raise OracleError(f"mirroring needs B0 symmetric about y = 0, got y in [{lo[1]}, {hi[1]}]")
        self.source, self.mirror = source, mirror
        self.lattice: Lattice = source.lattice
        self.posture_names = tuple(source.vertices.posture_names)

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None = None) -> Verdicts:
        pts = check_points(points, 3) * REFLECT
        lat = self.lattice
        coords = np.rint((pts - lat.box.lo) / lat.resolution).astype(np.int64)
        row = self.source.vertices.index(lat.keys(coords))
        if np.any(row < 0):
            raise OracleError(f"{int(np.sum(row < 0))} mirrored vertices were never evaluated in the source tree")
        v = self.source.vertices
        posture = None
        if v.posture is not None and self.mirror is not None:
            posture = self.mirror.mirror_q(v.posture[row])
        return Verdicts(v.reachable[row].copy(), v.residual[row].copy(), posture)
