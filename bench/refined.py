"""Refined query latency on the demo atlas; prints JSON lines.

The issue's figure: one client, one refinement worker, single-goal queries
with the default refinement (``--budget-ms``, 20 ms), on an idle machine.
Goals are drawn as ``bench/motion.py`` draws them (the stored reachable
vertices of each right-hand strategy, jittered by up to half a finest cell,
kept where the stored answer chooses that strategy). Per group: the round
trip's median and p99 [ms] and how the refinements ended (``refined``:
``ok``, ``timeout``, ``failed``), over the wire to ``reach serve``.

Run: ``.venv/bin/python bench/refined.py ATLAS [--goals 50] [--seed 1] [--workers 1]``
(ATLAS: the demo atlas, ``make run``'s ``out/demo``).
"""

from __future__ import annotations

import argparse
import collections
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
from motion import EFFECTOR, goals_by_group, served, stats

from reach.answers.select import Selector
from reach.maps.atlas import load_atlas


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas", help="the demo atlas (make run's out/demo)")
    parser.add_argument("--goals", type=int, default=50, help="goals per group (default 50)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    if not Path(args.atlas, "manifest.json").exists():
        sys.exit(f"{args.atlas}: no atlas there (make run builds out/demo)")
    emit(machine=platform.processor() or platform.machine(), python=platform.python_version(), workers=args.workers)
    groups = goals_by_group(Selector(load_atlas(args.atlas)), args.goals, np.random.default_rng(args.seed))
    with served(args.atlas, args.workers) as sock:
        for group, goals in groups.items():
            for goal in goals[:2]:  # warm: the first refinement of each strategy in each worker
                sock.send(json.dumps({"op": "query", "effector": EFFECTOR, "goal": goal.tolist()}).encode())
                sock.recv()
            ms, ended = [], collections.Counter()
            for goal in goals:
                t0 = time.perf_counter()
                sock.send(json.dumps({"op": "query", "effector": EFFECTOR, "goal": goal.tolist()}).encode())
                reply = json.loads(sock.recv())
                ms.append(1e3 * (time.perf_counter() - t0))
                ended[str(reply.get("refined", reply.get("error")))] += 1
            emit(bench="refined_query", group=group, goals=len(goals), **stats(ms), refined=dict(ended))


if __name__ == "__main__":
    main()
