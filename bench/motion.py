"""Reach motion latency; prints JSON lines.

Goals are drawn at the stored reachable vertices of each right-hand strategy
(jittered by up to half a finest cell) and kept where the selector's stored
answer chooses that strategy, so each group is what a query of that kind of
goal plans: an arm reach, an upper-body reach, a whole-body reach, a crouch.
Each goal's motion at 30 Hz from the reference posture is timed:

* in-process (``Planner.plan``, the server's 0.4 s refinement budget);
* over the wire: a ``motion`` request to ``reach serve`` with 2 workers
  (the request and its whole reply, frames included), one client.

One JSON line per group and path: median and p99 [ms], the motions' median
duration [s] and frame count, how many were routed through stored postures,
the goals no motion was found for (``no_motion``: no path held every task),
how many went through the motion graph (``via_graph``, reach.maps.graph) and
had their end posture settled from a stored one (``settled``), and the frames
that break a task by the tasks' own checks (``broken_frames``, every frame of
every motion, outside the timing), and for the motions along the graph, the
hand's path against the same goal's planned without the graphs
(``path_ratio_median``, ``path_ratio_max``; untimed);
in-process, the frames that broke a task and were held by the batched hold
(``held_in_batch``) and one at a time, its fallback (``held_alone``).

Run: ``.venv/bin/python bench/motion.py ATLAS [--goals 20] [--seed 0] [--no-wire]``
(ATLAS: the demo atlas, ``make run``'s ``out/demo``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import platform
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import zmq

from reach.answers.select import Selector
from reach.maps.atlas import load_atlas
from reach.motion.planner import MotionError, Planner

GROUPS = ("arm", "upper_body", "whole_body", "crouch")
EFFECTOR = "right_hand"


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def goals_by_group(selector: Selector, per_group: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Goals whose stored answer is each group's right-hand strategy."""
    out: dict[str, list[np.ndarray]] = {g: [] for g in GROUPS}
    atlas = selector.atlas
    for group in GROUPS:
        tree = atlas.trees.get(f"right_{group}")
        if tree is None or tree.vertices.posture is None:
            continue
        points = tree.lattice.points(tree.lattice.coords(tree.vertices.keys[tree.vertices.reachable]))
        half = 0.5 * tree.lattice.cell_size(np.array([tree.d_max]))[0]
        for i in rng.permutation(len(points)):
            goal = points[i] + rng.uniform(-half, half, 3)
            answer = selector.select(EFFECTOR, goal, False)
            if answer.reachable and answer.strategy == f"right_{group}":
                out[group].append(goal)
            if len(out[group]) == per_group:
                break
    return {g: np.array(v) for g, v in out.items() if v}


def stats(ms: list[float]) -> dict[str, float]:
    return {"median_ms": round(float(np.median(ms)), 1), "p99_ms": round(float(np.percentile(ms, 99)), 1),
            "max_ms": round(float(np.max(ms)), 1)}


def hand_path(m: object) -> float:
    return float(np.linalg.norm(np.diff(m.path, axis=0), axis=1).sum())  # type: ignore[attr-defined]


def in_process(planner: Planner, groups: dict[str, np.ndarray]) -> None:
    # the same goals planned without the motion graphs (untimed): the hand's path, graph's over planner's
    plain = Planner(planner.served, graph=False)
    for group, goals in groups.items():
        ms, durations, frames, routed, failed, ratios = [], [], [], 0, [], []
        graph = settled = broken = 0
        for goal in goals[:2]:  # the first plan of a strategy builds its oracle and graph
            try:
                planner.plan(EFFECTOR, goal)
            except MotionError:
                pass
        held = dict(planner.holding.counts)
        for goal in goals:
            t0 = time.perf_counter()
            try:
                m = planner.plan(EFFECTOR, goal)
            except MotionError as exc:
                failed.append([round(float(v), 3) for v in goal] + [exc.code])
                continue
            finally:
                ms.append(1e3 * (time.perf_counter() - t0))
            durations.append(m.duration)
            frames.append(len(m.times))
            routed += m.waypoints > 0
            graph += m.route == "graph"
            settled += m.end == "settled"
            # every frame by the tasks' own checks (Pinocchio forward kinematics, the collision distances), untimed
            broken += sum(bool(f) for f in planner.body(m.strategy).faults(m.postures))
            if m.route == "graph":
                with contextlib.suppress(MotionError):
                    ratios.append(hand_path(m) / max(hand_path(plain.plan(EFFECTOR, goal)), 1e-9))
        emit(bench="motion", path="in_process", group=group, goals=len(goals), **stats(ms),
             duration_s=round(float(np.median(durations)), 3),
             frames=int(np.median(frames)) if frames else 0, routed=routed, via_graph=graph, settled=settled,
             broken_frames=broken, failed=failed,
             path_ratio_median=round(float(np.median(ratios)), 3) if ratios else None,
             path_ratio_max=round(float(np.max(ratios)), 3) if ratios else None,
             held_in_batch=planner.holding.counts["batch"] - held["batch"],
             held_alone=planner.holding.counts["alone"] - held["alone"])


@contextlib.contextmanager
def served(atlas: str, workers: int) -> Iterator[zmq.Socket]:
    """``reach serve`` of the atlas in a process of its own, its workers ready, and a REQ socket to it."""
    proc = subprocess.Popen([sys.executable, "-m", "reach.tools.cli", "serve", atlas, "--bind", "tcp://127.0.0.1:*",
                             "--pub", "none", "--workers", str(workers)], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()  # type: ignore[union-attr]
        address = line.split(" on ")[1].split(",")[0].strip()
        sock = zmq.Context.instance().socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(address)
        for _ in range(600):  # the workers have loaded the atlas and built their solvers
            sock.send(b'{"op": "health"}')
            if json.loads(sock.recv())["workers_ready"] >= workers:
                break
            time.sleep(0.1)
        yield sock
        sock.close()
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def over_the_wire(atlas: str, groups: dict[str, np.ndarray]) -> None:
    with served(atlas, 2) as sock:
        for group, goals in groups.items():
            for goal in goals[:2]:  # each worker's first plan of the strategy
                sock.send(json.dumps({"op": "motion", "effector": EFFECTOR, "goal": goal.tolist()}).encode())
                sock.recv()
            ms, sizes, failed = [], [], 0
            for goal in goals:
                t0 = time.perf_counter()
                sock.send(json.dumps({"op": "motion", "effector": EFFECTOR, "goal": goal.tolist()}).encode())
                reply = sock.recv()
                ms.append(1e3 * (time.perf_counter() - t0))
                sizes.append(len(reply))
                failed += not json.loads(reply).get("ok")
            emit(bench="motion", path="wire_2_workers", group=group, goals=len(goals), **stats(ms),
                 reply_kib=round(float(np.median(sizes)) / 1024, 1),
                 failed=failed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas", help="the demo atlas (make run's out/demo)")
    parser.add_argument("--goals", type=int, default=20, help="goals per group (default 20)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-wire", action="store_true", help="in-process only")
    args = parser.parse_args()
    if not Path(args.atlas, "manifest.json").exists():
        sys.exit(f"{args.atlas}: no atlas there (make run builds out/demo)")
    emit(machine=platform.processor() or platform.machine(), python=platform.python_version())
    selector = Selector(load_atlas(args.atlas)).warm_up()
    groups = goals_by_group(selector, args.goals, np.random.default_rng(args.seed))
    in_process(Planner(selector), groups)
    if not args.no_wire:
        over_the_wire(args.atlas, groups)


if __name__ == "__main__":
    main()
