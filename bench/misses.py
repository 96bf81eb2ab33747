"""How often a "reachable" answer's posture misses its goal: goals drawn in boundary cells, asked as a query asks them.

For each strategy named (default: every right-hand one), goals are drawn
uniformly in its final (boundary) cells and asked of the selector with the
server's defaults (refinement within the 20 ms budget, or ``--budget-ms``;
handover on). An
answer *misses* when it says reachable and its posture puts the effector
farther than the tolerance (5 mm) from the goal, by an independent
Pinocchio forward kinematics of the body. Prints one JSON line per
strategy, then the latency of the answers.

Run: ``.venv/bin/python bench/misses.py ATLAS [--goals 60] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import pinocchio as pin

from oracles.bodies.body import load_body
from reach.answers.answer import posture_vector
from reach.answers.select import Selector
from reach.maps.atlas import load_atlas
from reach.maps.tree import FINAL

TOLERANCE = 0.005  # [m] the shipped strategies' reach tolerance


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas")
    parser.add_argument("--goals", type=int, default=60, help="goals per strategy (default 60)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--strategies", nargs="*", help="default: every right-hand strategy")
    parser.add_argument("--budget-ms", type=float, default=20.0, help="refinement budget per goal [ms] (default 20, "
        "the server's; reach query: 1000)")
    args = parser.parse_args()
    atlas = load_atlas(args.atlas)
    selector = Selector(atlas, budget=args.budget_ms / 1000.0).warm_up()
    rng = np.random.default_rng(args.seed)
    names = args.strategies or [n for n in atlas.trees if n.startswith("right_")]
    seconds: list[float] = []
    for name in names:
        tree = atlas.trees[name]
        spec = tree.meta["oracle"]["params"]
        body = load_body(spec["body"])
        model, data = body.model, body.model.createData()
        fid = model.getFrameId(spec["effector"])
        final = np.nonzero(tree.kind == FINAL)[0]
        cells = rng.choice(final, size=args.goals)
        lo = tree.lattice.points(tree.corner[cells])
        goals = lo + rng.uniform(size=lo.shape) * tree.lattice.cell_size(tree.depth[cells])
        misses: list[float] = []
        reachable = unreachable = within = 0
        outcomes: dict[str, int] = {}
        for goal in goals:
            t0 = time.perf_counter()
            answer = selector.select(spec["effector"], goal)
            seconds.append(time.perf_counter() - t0)
            outcomes[answer.refined] = outcomes.get(answer.refined, 0) + 1
            if getattr(answer, "within", None) is not None:
                within += 1  # said explicitly: reachable within so many metres
                continue
            if not answer.reachable or answer.posture is None:
                unreachable += not answer.reachable
                continue
            reachable += 1
            chosen = atlas.trees[answer.strategy]  # type: ignore[index]
            q = posture_vector(chosen.vertices.posture_names, body.q_ref, answer.posture, answer.root)
            pin.forwardKinematics(model, data, q)
            gap = float(np.linalg.norm(pin.updateFramePlacement(model, data, fid).translation - goal))
            if gap > TOLERANCE:
                misses.append(gap)
        print(json.dumps({"strategy": name, "budget_ms": args.budget_ms, "goals": args.goals, "reachable": reachable,
                          "unreachable": unreachable, "within": within,
                          "reachable_but_missed": len(misses), "worst_mm": round(1e3 * max(misses), 1) if misses
                          else None, "median_mm": round(1e3 * float(np.median(misses)), 1) if misses else None,
                          "refined": outcomes}), flush=True)
    lat = np.array(seconds) * 1e3
    print(json.dumps({"latency_ms": {"median": round(float(np.median(lat)), 2),
                                     "p99": round(float(np.percentile(lat, 99)), 2),
                                     "max": round(float(lat.max()), 2)}, "answers": len(lat)}))


if __name__ == "__main__":
    main()
