"""A standing body's interpolation with its centre of mass kept over the feet.

Interpolated on the configuration space, the path between two balanced postures can take the centre of mass out of
the support polygon (and the pelvis out of its bounds): on the demo's crouch, 253 of 300 neighbour pairs the motion
graph could not link broke the balance first (docs/decisions/0027). Each such posture's root is moved aside by the
least that brings its centre of mass (and pelvis) back inside, the feet then held again by their legs' inverse
kinematics. The least move is a projection: it grows from nothing as a posture nears the bound, so the corrected path
is as continuous as the plain one (a posture moved all the way to a line between the ends' centres of mass, where it
left the polygon, jumped: the hand's speed with it; 0027).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

from oracles.tasks.balance import BALANCE_TOL

# [m] how far inside its bounds a posture outside them is moved: a posture moved to the bound exactly would fail its
# check by rounding, and one inside is not moved, so the path jumps by this much where a move begins (a choice)
DEPTH = 1e-4
# how far the centre of mass moves for the root's move with the feet held again: the legs carry part of their mass
# back (0.81-0.91 on the demo's crouch, measured; the lowest taken, so that the centre of mass ends inside)
GAIN = 0.8
# damped Newton steps of a moved posture's legs (a plain path's get 100, oracles.ik.stepping): on 3,000 neighbour
# pairs of the demo's crouch, 99 % of the moved legs' holds that succeeded took at most 5 steps and 20 of 7,575 more
# than 10, while those that failed took every step given; 10 steps cost the crouch's graph 39 of its 5,266 edges for
# about 5 % less CPU, 50 none (measured)
HOLD_ITER = 50

Hold = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def com_xy(model: pin.Model, data: pin.Data, postures: np.ndarray) -> np.ndarray:
    """The centres of mass's ground projections (B, 2) [m] of postures (B, nq)."""
    return np.array([pin.centerOfMass(model, data, q, False)[:2] for q in postures]).reshape(-1, 2)


def balanced(model: pin.Model, data: pin.Data, a: np.ndarray, b: np.ndarray, s: np.ndarray, plain: np.ndarray,
             polygon: np.ndarray, hull: np.ndarray | None, hold: Hold) -> np.ndarray:
    """The postures ``plain`` (at fractions s of a -> b), each whose centre of mass lies outside ``polygon`` (or whose
    root lies outside ``hull``) moved aside by the least that brings it inside, the feet held by
    ``hold(a, b, postures)``.

    ``polygon`` and ``hull``: rows (a_x, a_y, c), a . p + c <= 0 inside (the balance task's, for the centre of mass
    and the pelvis)."""
    com = com_xy(model, data, plain)
    out_of = np.max(com @ polygon[:, :2].T + polygon[:, 2], axis=1) > BALANCE_TOL
    if hull is not None and len(hull):
        out_of |= np.max(plain[:, :2] @ hull[:, :2].T + hull[:, 2], axis=1) > BALANCE_TOL
    shifts = {k: least_shift(polygon, hull, com[k], plain[k, :2]) for k in np.flatnonzero(out_of)}
    moved = np.array([k for k, d in shifts.items() if d.any()], int)
    if not moved.size:
        return plain
    out = np.array(plain, float, copy=True)
    out[moved, :2] += np.array([shifts[k] for k in moved])
    out[moved] = hold(a, b, out[moved])
    return out


def least_shift(polygon: np.ndarray, hull: np.ndarray | None, com: np.ndarray, root: np.ndarray) -> np.ndarray:
    """The shortest move d (2,) [m] of the root with com + GAIN d DEPTH inside ``polygon`` and root + d DEPTH inside
    ``hull``; zero when the posture lies within them (to the balance's tolerance), or when no move does."""
    rows = polygon[:, :2] * GAIN
    value = polygon[:, :2] @ com + polygon[:, 2]
    if hull is not None and len(hull):
        rows = np.vstack([rows, hull[:, :2]])
        value = np.concatenate([value, hull[:, :2] @ root + hull[:, 2]])
    if np.all(value <= BALANCE_TOL):
        return np.zeros(2)
    bound = -(value + DEPTH)
    # The least-norm point of a polygon of a few rows: on one row's line or at two rows' corner (Cramer's rule).
    singles = rows * (bound / np.einsum("ij,ij->i", rows, rows))[:, None]
    i, j = np.triu_indices(len(rows), 1)
    det = rows[i, 0] * rows[j, 1] - rows[i, 1] * rows[j, 0]
    ok = np.abs(det) > 1e-12
    i, j, det = i[ok], j[ok], det[ok]
    corners = np.column_stack([bound[i] * rows[j, 1] - bound[j] * rows[i, 1],
                               rows[i, 0] * bound[j] - rows[j, 0] * bound[i]]) / det[:, None]
    candidates = np.vstack([singles, corners])
    feasible = candidates[np.all(candidates @ rows.T <= bound + 1e-12, axis=1)]
    if not len(feasible):
        return np.zeros(2)
    return feasible[np.argmin(np.einsum("ij,ij->i", feasible, feasible))]
