"""``reach place``'s speed; prints JSON lines.

Ranks 10,000 placements (25 x 25 positions, 0.05 m apart, times 16 headings)
of the atlases given (a population: e.g. ``demo_female_p05``, ``demo`` and
``demo_male_p95``) against 50 seeded targets on a panel in front of the
layout's origin (x 0.6-1.0 m, y -0.5-0.3 m, z 0.8-1.6 m, the right hand's),
then verifies the best five placements by IK (1 s refinement budget per
target). Goal: the ranking under 1 s.

Run: ``.venv/bin/python bench/place.py ATLAS [ATLAS ...] [--repeat 3]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time

import numpy as np

from reach.answers.evaluate import Target
from reach.answers.place import Space, rank, verify
from reach.maps.atlas import load_atlas


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlases", nargs="+")
    parser.add_argument("--targets", type=int, default=50)
    parser.add_argument("--effector", default="right_hand")
    parser.add_argument("--repeat", type=int, default=3, help="rankings timed (the best is reported with the others)")
    parser.add_argument("--verify", type=int, default=5)
    args = parser.parse_args()
    atlases = [load_atlas(a) for a in args.atlases]
    rng = np.random.default_rng(0)
    points = rng.uniform([0.6, -0.5, 0.8], [1.0, 0.3, 1.6], size=(args.targets, 3))
    targets = [Target(f"t{k}", (float(x), float(y), float(z)), args.effector) for k, (x, y, z) in enumerate(points)]
    space = Space((-0.6, 0.6), (-0.6, 0.6), yaw=(-math.pi, math.pi), step=0.05, yaw_step=math.radians(22.5))
    for a in atlases:  # the trees' lookup tables, as a server has them after loading
        for t in a.trees.values():
            t.prepare()
    seconds = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        ranking = rank(atlases, targets, space)
        seconds.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    checked = verify(ranking, atlases, targets, args.verify, args.effector)
    verify_s = time.perf_counter() - t0
    machine = {"machine": platform.processor() or platform.machine(), "cores": os.cpu_count()}
    best = ranking.row(0, targets)
    print(json.dumps({"bodies": len(atlases), "targets": len(targets), "placements": len(ranking.placements),
                      "rank_seconds": [round(s, 3) for s in seconds],
                      "goal_s": 1.0, "verify_best": args.verify, "verify_seconds": round(verify_s, 2),
                      "best": {k: best[k] for k in ("position", "yaw_deg", "accommodated", "reached", "preference")},
                      "verified": checked, **machine}), flush=True)


if __name__ == "__main__":
    main()
