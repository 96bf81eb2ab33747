"""Mirror symmetry of a body about the sagittal plane y = 0.

A body is mirror-symmetric when swapping every ``left_``/``right_`` joint
and frame, negating the central joints whose axes lie in that plane's
normal direction (lateral bending, axial rotations), and reflecting the
root, maps every frame onto the mirror image of its counterpart at random
configurations, and the joint ranges mirror too.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body
from oracles.errors import ModelError

SIDES = (("left_", "right_"), ("right_", "left_"))
REFLECT = np.array([1.0, -1.0, 1.0])  # a point's mirror image about the world frame's y = 0


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
                raise ModelError(f"joint {n!r} has no mirror counterpart {other!r}", source=body.source)
            j, k = model.joints[model.getJointId(n)], model.joints[model.getJointId(other)]
            if j.nq != 1 or k.nq != 1:
                raise ModelError(f"mirroring supports one-coordinate joints only ({n!r})", source=body.source)
            self.perm[j.idx_q] = k.idx_q
        self.frames = [str(f.name) for f in model.frames if str(f.name) != "universe"
                       and _counterpart(str(f.name)) in {str(g.name) for g in model.frames}]
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
            raise ModelError(f"joint ranges are not mirror-symmetric ({', '.join(sorted(bad)[:4])}); build both "
                             "sides instead", source=body.source)
        rng = np.random.default_rng(seed)
        for _ in range(samples):
            q = body.q_ref.copy()
            q[7:] = rng.uniform(lo, hi)
            q[:3] += rng.normal(scale=0.05, size=3)
            q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*rng.normal(scale=0.2, size=3))).coeffs()
            err = self._error(q)
            if err > tol:
                raise ModelError(f"the model is not mirror-symmetric about y = 0 (frames differ by {err:.3g} m); "
                                 "build both sides instead", source=body.source)

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
