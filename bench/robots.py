"""The robot examples against their own figures; prints JSON lines.

* One line per strategy of each atlas given: build seconds, oracle calls,
  inner and boundary volume [m^3], B0 and the faces reachable vertices lie on.
* The 7-DoF arm's reach against its datasheet: the Franka Emika Panda's
  "maximum reach 855 mm" (Franka Emika, Panda datasheet, 2019). The flange's
  farthest point along +x at the shoulder's height (joint 2, z = 0.333 m),
  by bisection on direct IK (the audit's thorough referee, 6 restarts) of the
  arm alone (no table, no self-collision), measured from joint 1's axis; and
  the same line read off the example atlas's tree (its tool centre point).

Run: ``.venv/bin/python bench/robots.py [ATLAS ...]`` (atlases built from
``configs/examples/*.yaml``).
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np

from oracles.protocol import OracleSpec, body_params
from reach.maps.atlas import load_atlas
from reach.maps.tree import FINAL, INNER

ARM7 = Path(__file__).resolve().parents[1] / "configs" / "urdf" / "arm7.urdf"
DATASHEET_REACH = 0.855  # [m] Franka Emika Panda datasheet, "maximum reach"
SHOULDER = 0.333  # [m] joint 2's height above the base (the Panda's d1)


def arm_reach() -> dict[str, float]:
    """The flange's farthest reach along +x at the shoulder's height, by bisection on direct IK [m]."""
    body = {"urdf": str(ARM7), "reference": {"arm7_joint4": -2.356194, "arm7_joint6": 1.570796}}
    oracle = OracleSpec("casadi-ik",
                        {**body_params(body, "arm7_flange", ["arm7_joint*"], [{"type": "reach"}]),
                         "jit": False}).create()
    referee = oracle.variant("referee")  # type: ignore[attr-defined]
    lo, hi = 0.5, 1.2
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        if referee.evaluate(np.array([[mid, 0.0, SHOULDER]])).reachable[0]:
            lo = mid
        else:
            hi = mid
    return {"ik_reach_m": round(lo, 4), "datasheet_m": DATASHEET_REACH,
            "difference_mm": round(1000 * (lo - DATASHEET_REACH), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlases", nargs="*")
    args = parser.parse_args()
    machine = {"machine": platform.processor() or platform.machine(), "cores": __import__("os").cpu_count()}
    for path in args.atlases:
        atlas = load_atlas(path)
        for name, tree in atlas.trees.items():
            b = tree.meta["build"]
            print(json.dumps({"atlas": atlas.manifest["name"], "strategy": name, "seconds": round(b["seconds"], 1),
                              "oracle_calls": b["oracle_calls"],
                              "inner_m3": round(tree.volume(INNER), 4), "boundary_m3": round(tree.volume(FINAL), 4),
                              "d_max": tree.d_max,
                              "box": [tree.box.lo.tolist(), tree.box.hi.tolist()], "on_faces": tree.faces(),
                              **machine}), flush=True)
            if name == "tcp":  # the arm example: its tree along +x at the shoulder's height
                xs = np.linspace(0.0, 1.2, 1201)
                inside = tree.contains(np.stack([xs, np.zeros_like(xs), np.full_like(xs, SHOULDER)], 1), "vertex")
                print(json.dumps({"atlas": atlas.manifest["name"], "strategy": name,
                                  "tree_reach_along_x_m": float(xs[inside].max()) if inside.any() else None}))
    print(json.dumps({"arm7_flange_reach": arm_reach(), **machine}), flush=True)


if __name__ == "__main__":
    main()
