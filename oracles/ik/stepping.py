"""A step's frames: the weight shifted over the stance foot, the stepping foot lifted, carried and set down.

The step strategy's posture (:mod:`oracles.tasks.step`) has the foot already
where it lands; a motion must get it there. Its frames, in two parts:

* the weight shift: from the start posture to one whose centre of mass lies
  over the stance foot alone, both feet where they stood (solved by damped
  least squares, the ``dls`` engine: no compilation; the stepping foot as
  the effector, kept where it is, the stance foot held, balance over its
  sole);
* the swing: the stepping foot carried along an arc from where it stood to
  where it lands, ``lift`` [m] above the straight line at mid-swing, turned
  from its start orientation to its landing one, by the stepping leg's own
  joints (its 6-D placement, damped Newton); the rest of the body stays over
  the stance foot until the foot's highest point (half the swing; sooner,
  ``FALLS``, for a step longer than the leg reaches from there), then moves
  on the configuration space, by minimum jerk, to where it stands when the
  foot lands: the step's pelvis and legs (both feet where they end) under
  the weight shift's trunk and arms, which then reach. In walking the centre
  of mass leaves the stance foot's support in the second half of single support
  and the swing foot catches it (Winter, D.A. 1995, "Human balance and
  posture control during standing and walking", Gait & Posture 3:193-214;
  not read in its source here); held over the stance foot to the end, the
  50th-percentile man's step stopped 0.41 m ahead of it, short of the step
  region's 0.72 m.

The reach from the landing to the step's posture, both feet down, is the
planner's (:mod:`reach.motion.planner`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from oracles.protocol import Goals
from oracles.tasks.step import StepTask

LIFT = 0.08  # [m] the swing foot's clearance at mid-swing (a modelling choice: a step over a flat floor)
# the share of the swing with the body held over the stance foot (see the module docstring): half, or less for a step
# longer than the leg reaches from there (the body then moves sooner)
FALLS = (0.5, 0.25, 0.0)
# the weight shift's tasks a swing frame may break: the foot leaves its orientation, the weight leaves the stance foot
FREE_IN_SWING = frozenset({"orientation", "balance"})
SWING_TOLERANCE = 0.5  # [deg] the weight shift's foot orientation within this of where it stands (the task's least)
LEG_ITER = 100  # damped Newton iterations of the stepping leg's inverse kinematics
LEG_DAMPING = 1e-3  # their damping [m or rad]


def shift_params(params: dict[str, Any], task: StepTask) -> dict[str, Any]:
    """The weight shift's oracle spec of a stepping strategy's: the stepping foot as its effector, the stance foot
    held, balance over its sole, the foot's orientation a goal's target, the posture task below."""
    tasks = [{"type": "reach"}, {"type": "feet", "frames": [task.stance], "heels": "down"},
             {"type": "balance", "margin": task.margin}, {"type": "orientation", "tolerance": SWING_TOLERANCE},
             {"type": "self_collision"}, {"type": "floor"}, {"type": "posture"}]
    return {**params, "effector": task.foot, "tasks": tasks, "restarts": 0, "secondary": True}


def arc(start: np.ndarray, end: np.ndarray, s: float, lift: float) -> np.ndarray:
    """The swing's point at s in [0, 1]: the straight line from start to end, raised by lift x sin(pi s)."""
    out = start + s * (end - start)
    out[2] += lift * np.sin(np.pi * s)
    return out


def minimum_jerk(u: float) -> float:
    """Minimum-jerk progress at u in [0, 1] (Flash & Hogan 1985): no jump in speed at either end."""
    return float(u**3 * (10.0 - 15.0 * u + 6.0 * u * u))


def swing_frames(oracle: Any, q0: np.ndarray, q1: np.ndarray, count: int, lift: float = LIFT) -> np.ndarray | None:
    """``count`` + 1 postures from q0 (both feet down) through the weight shift and the swing to the foot set down
    where q1 puts it, or None when one cannot be found (see the module docstring). ``oracle``: the stepping
    strategy's (a :class:`~oracles.ik.oracle.IKOracle` with a ``step`` task)."""
    task = oracle.strategy.task("step")
    if not isinstance(task, StepTask):
        return None
    model = oracle.body.model
    data = model.createData()
    fid = oracle.body.frame_id(task.foot)
    placed = []
    for q in (q0, q1):
        pin.framesForwardKinematics(model, data, q)
        placed.append(data.oMf[fid].copy())
    shift, swing = max(1, count // 3), count - max(1, count // 3)
    single = type(oracle).from_params(**shift_params(oracle.strategy_params, task), solver="dls")
    held = single.evaluate(Goals(placed[0].translation[None], {"orientation": placed[0].rotation[None]},
                                 seeds=q0[None]))
    if not held.reachable[0] or held.posture is None:
        return None
    q_shift = held.posture[0]
    leg = chain(model, fid)
    # where the body stands when the foot lands: the step's legs and pelvis (both feet where they end) under the
    # upper body of the weight shift (the trunk and arms not yet moved to reach): a step, then a reach
    q_land = _stepped(model, q_shift, q1, [leg, chain(model, oracle.body.frame_id(task.stance))])
    if oracle.faults(q_land[None])[0]:
        return None
    shifted = [*oracle.interpolate(q0, q_shift, np.linspace(0.0, 1.0, shift + 1))]
    for fall in FALLS:
        carried = _swing(oracle, model, leg, fid, q_shift, q_land, placed, swing, lift, fall)
        # the leg's own inverse kinematics sees no other segment: a swing that passes a segment through another, or
        # through the floor, or moves the stance foot, is not a step
        if carried is not None and not any(set(f) - FREE_IN_SWING for f in single.faults(np.array(carried))):
            return np.array([*shifted, *carried])
    return None


def _swing(oracle: Any, model: pin.Model, leg: list[int], fid: int, q_shift: np.ndarray, q_land: np.ndarray,
           placed: list[pin.SE3], swing: int, lift: float, fall: float) -> list[np.ndarray] | None:
    """The swing's frames: the foot along its arc by the leg's own joints, the body held at q_shift for ``fall`` of
    the swing, then moving to q_land by minimum jerk; None when the leg cannot reach a frame's point."""
    frames = []
    for s in np.linspace(0.0, 1.0, swing + 1)[1:]:
        w = 0.0 if s <= fall else minimum_jerk((s - fall) / (1.0 - fall))
        body = oracle.interpolate(q_shift, q_land, np.array([w]))[0]
        turn = pin.SE3.Interpolate(pin.SE3(placed[0].rotation, np.zeros(3)), pin.SE3(placed[1].rotation, np.zeros(3)),
                                   float(s)).rotation
        target = pin.SE3(turn, arc(placed[0].translation, placed[1].translation, s, lift))
        q = _leg_ik(model, leg, fid, body, target)
        if q is None:
            return None
        frames.append(q)
    return frames


def planted(model: pin.Model, frame: int, q0: np.ndarray, q1: np.ndarray, postures: np.ndarray,
            iterations: int = LEG_ITER) -> np.ndarray:
    """Postures between q0 and q1 with the stepping foot (``frame``) kept where both put it, when they put it at one
    place (within 0.1 mm and 1 mrad): the leg's own inverse kinematics at each (at most ``iterations`` steps); else
    the postures as they are."""
    data = model.createData()
    ends = []
    for q in (q0, q1):
        pin.framesForwardKinematics(model, data, q)
        ends.append(data.oMf[frame].copy())
    gap = pin.log6(ends[0].actInv(ends[1])).vector
    if np.linalg.norm(gap[:3]) > 1e-4 or np.linalg.norm(gap[3:]) > 1e-3:
        return postures
    leg = chain(model, frame)
    rows = np.concatenate([np.arange(model.joints[j].idx_q, model.joints[j].idx_q + model.joints[j].nq) for j in leg])
    out = np.array(postures, float, copy=True)
    shift = np.zeros(len(rows))  # the previous frame's correction of the leg, the next one's first guess
    for k, q in enumerate(out):
        # a posture whose foot is where it stood is kept as it is (the path's ends: their legs are a verdict's)
        if _placed(model, data, frame, q, ends[0]):
            shift = np.zeros(len(rows))
            continue
        guess = q.copy()
        guess[rows] += shift
        held = _leg_ik(model, leg, frame, guess, ends[0], data, iterations)
        if held is None and shift.any():
            held = _leg_ik(model, leg, frame, q, ends[0], data, iterations)
        if held is not None:
            shift = held[rows] - q[rows]
            out[k] = held
    return out


def _stepped(model: pin.Model, upper: np.ndarray, lower: np.ndarray, legs: list[list[int]]) -> np.ndarray:
    """``lower``'s floating root and legs' joints under ``upper``'s other joints."""
    out = np.asarray(upper, float).copy()
    out[:7] = lower[:7]  # the floating root: position and quaternion
    for j in (j for leg in legs for j in leg):
        jm = model.joints[j]
        out[jm.idx_q : jm.idx_q + jm.nq] = lower[jm.idx_q : jm.idx_q + jm.nq]
    return out


def chain(model: pin.Model, frame: int) -> list[int]:
    """The joints between the floating root and a frame (the stepping leg's), root side first."""
    out, j = [], int(model.frames[frame].parentJoint)
    while j > 1:
        out.append(j)
        j = int(model.parents[j])
    return out[::-1]


def _placed(model: pin.Model, data: Any, frame: int, q: np.ndarray, target: pin.SE3) -> bool:
    """Whether the frame lies at ``target`` at q, within the contacts' own checks (0.1 mm, 1 mrad)."""
    pin.framesForwardKinematics(model, data, q)
    err = pin.log6(data.oMf[frame].actInv(target)).vector
    return bool(np.linalg.norm(err[:3]) <= 1e-4 and np.linalg.norm(err[3:]) <= 1e-3)


def _leg_ik(model: pin.Model, leg: list[int], frame: int, q: np.ndarray, target: pin.SE3,
            data: Any = None, iterations: int = LEG_ITER) -> np.ndarray | None:
    """q with the leg's joints moved (damped Newton on the frame's 6-D error, within the joints' ranges) until the
    frame reaches ``target`` (within 0.1 mm and 1 mrad, the contacts' own checks), or None when it cannot."""
    q = np.asarray(q, float).copy()
    data = model.createData() if data is None else data
    cols = [model.joints[j].idx_v for j in leg]
    rows = [model.joints[j].idx_q for j in leg]
    lo, hi = model.lowerPositionLimit[rows], model.upperPositionLimit[rows]
    damping = LEG_DAMPING**2 * np.eye(6)
    for _ in range(iterations):
        pin.framesForwardKinematics(model, data, q)
        err = pin.log6(data.oMf[frame].actInv(target)).vector
        if err[:3] @ err[:3] <= 1e-8 and err[3:] @ err[3:] <= 1e-6:  # 0.1 mm and 1 mrad
            return q
        jac = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL)[:, cols]
        moved = np.clip(q[rows] + jac.T @ np.linalg.solve(jac @ jac.T + damping, err), lo, hi)
        if np.array_equal(moved, q[rows]):
            return None  # the ranges hold the leg where it is: every further iteration would be this one
        q[rows] = moved
    return None
