"""Seated reach against published figures: JSON lines, one per body and measure.

For each body (the 5th-percentile woman, the 50th-percentile man and woman, the 95th-percentile man):

* ``thumbtip``: the arm-only forward reach, by IK, from the back support to the thumb tip along the
  line through the shoulder perpendicular to the support: standing (a wall touching the back of the
  shoulders, the line horizontal, as ANSUR II measures thumb-tip reach: 811.9 +- 43.7 mm for men,
  744.0 +- 42.8 mm for women, Gordon et al. 2014) and seated on an office chair (the backrest, reclined
  15 deg, the line perpendicular to it). The same arm from the same back support should reach the same.
* ``lean``: how much farther the trunk-free strategy (the pelvis turning on the seat) reaches on the
  same seated line, and on a car seat horizontally ahead of the shoulder the driver example's belted strategy (a
  locked shoulder belt) against its unbelted lean (``configs/examples/driver.yaml``'s own tasks, on each body).

Each reach is the farthest distance IK verdicts (3 random restarts) find: a scan in 0.1 m steps, then a bisection to
5 mm.

    python bench/seated.py [--bodies female:5,male:95]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from oracles.bodies.anthropometry import ANSUR_THUMBTIP_REACH  # noqa: E402
from oracles.ik.oracle import IKOracle  # noqa: E402
from oracles.ik.search import Search  # noqa: E402

ARM = ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"]
# The examples' trunk strategies (configs/examples/*.yaml): the idle arm's shoulder and elbow move too.
TRUNK = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "neck_*", "root", "*_hip_*", "*_knee_*", "*_ankle_*",
         "left_shoulder_flexion", "left_shoulder_abduction", "left_elbow_flexion"]
SUPPORT = ["right_ischium", "left_ischium", "right_thigh_rest", "left_thigh_rest", "right_heel_inner",
           "right_heel_outer", "right_toe_inner",
           "right_toe_outer", "left_heel_inner", "left_heel_outer", "left_toe_inner", "left_toe_outer"]
COMMON = [{"type": "balance", "margin": 0.02}, {"type": "self_collision"}, {"type": "obstacles"}, {"type": "floor"},
          {"type": "coupling"}, {"type": "hang", "frames": ["left_shoulder", "left_elbow_flexion"]}]
LEAN = [{"type": "reach"},
        {"type": "contacts", "hinge": ["right_ischium", "left_ischium"], "fixed": ["right_foot", "left_foot"],
         "support": SUPPORT},
        *COMMON]
DRIVER = Path(__file__).resolve().parents[1] / "configs" / "examples" / "driver.yaml"


def driver_oracle(name: str, body: dict, search: Search) -> IKOracle:
    """The driver example's own strategy (its belt, door and idle-arm bound) on another body, compiled programs off."""
    from oracles.protocol import OracleSpec
    from reach.building.config import load_config

    spec = next(s for s in load_config(DRIVER).strategies if s.name == name).oracle
    params = {**spec.params, "body": body, "jit": False, "restarts": search.restarts, "seed": search.seed}
    oracle = OracleSpec(spec.name, params).create()
    assert isinstance(oracle, IKOracle)
    return oracle


def farthest(oracle: IKOracle, start: np.ndarray, direction: np.ndarray, lo: float = 0.2, hi: float = 1.6,
             tol: float = 0.005) -> float:
    """The farthest t [m] with start + t direction reached: a scan in 0.1 m steps from lo for the last reached
    distance before the first missed one, then a bisection between them."""
    steps = np.arange(lo, hi, 0.1)
    reached = oracle.evaluate(start + steps[:, None] * direction).reachable
    if not reached.any():
        return float("nan")
    last = int(np.nonzero(reached)[0].max())
    lo, hi = float(steps[last]), float(steps[last] + 0.1)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if oracle.evaluate(np.array([start + mid * direction])).reachable[0]:
            lo = mid
        else:
            hi = mid
        print(".", end="", file=sys.stderr, flush=True)
    return lo


def seated(sex: str, percentile: float, kind: str) -> dict:
    return {"human": {"sex": sex, "percentile": percentile, "posture": "seated", "seat": {"kind": kind}}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", default="female:5,female:50,male:50,male:95",
                        help="sex:percentile, comma-separated")
    args = parser.parse_args()
    search = Search(restarts=3, seed=0)
    for item in args.bodies.split(","):
        sex, pct = item.split(":")
        percentile = float(pct)
        standing_spec = {"human": {"sex": sex, "percentile": percentile}}
        # the thumb tip (right_pinch), as ANSUR II measures thumb-tip reach (the grip centre is 55-65 mm behind it)
        stand = IKOracle(standing_spec, "right_pinch", ARM, [{"type": "reach"}, {"type": "coupling"}], search=search)
        frames = stand.body.frame_positions()
        shoulder, back = frames["right_shoulder"], frames["back"]
        t = farthest(stand, shoulder, np.array([1.0, 0.0, 0.0]))
        standing = t + shoulder[0] - back[0]
        spec = seated(sex, percentile, "chair")
        arm = IKOracle(spec, "right_pinch", ARM, [{"type": "reach"}, {"type": "coupling"}, {"type": "obstacles"}],
                       search=search)
        grip = IKOracle(spec, "right_hand", ARM, [{"type": "reach"}, {"type": "coupling"}, {"type": "obstacles"}],
                        search=search)
        beta = math.radians(15.0)
        normal = np.array([math.cos(beta), 0.0, math.sin(beta)])
        s = arm.body.frame_positions()["right_shoulder"]
        foot = np.array([0.0, 0.0, next(b for b in arm.body.furniture if b.name == "seat_pan").hi[2]])
        plane = float((s - foot) @ normal)  # the shoulder's distance from the backrest's plane
        t_arm = farthest(arm, s, normal)
        t_grip = farthest(grip, s, normal)  # the lean's own effector, the grip centre: what the lean adds to
        mean, sd = ANSUR_THUMBTIP_REACH[sex]
        print(json.dumps({"bench": "seated", "measure": "thumbtip", "sex": sex, "percentile": percentile,
                          "standing_mm": round(1000 * standing, 1), "seated_mm": round(1000 * (t_arm + plane), 1),
                          "ansur_mean_mm": mean, "ansur_sd_mm": sd}), flush=True)
        lean = IKOracle(spec, "right_hand", TRUNK, LEAN, search=search)
        t_lean = farthest(lean, s, normal)
        car = seated(sex, percentile, "car")
        belted, free = driver_oracle("belted", car, search), driver_oracle("lean", car, search)
        c = belted.body.frame_positions()["right_shoulder"]
        ahead = np.array([1.0, 0.0, 0.0])
        t_belted, t_free = farthest(belted, c, ahead), farthest(free, c, ahead)
        print(json.dumps({"bench": "seated", "measure": "lean", "sex": sex, "percentile": percentile,
                          "chair_arm_mm": round(1000 * t_grip, 1), "chair_lean_mm": round(1000 * t_lean, 1),
                          "lean_adds_mm": round(1000 * (t_lean - t_grip), 1),
                          "car_belted_mm": round(1000 * t_belted, 1), "car_unbelted_mm": round(1000 * t_free, 1)}),
                              flush=True)


if __name__ == "__main__":
    main()
