"""A UR5's trees against exact analytic IK; prints JSON lines.

The repository's UR5 (configs/urdf/ur5.urdf) is ur-analytic-ik's ``ur5`` in another base frame
(tests/analytic_ur5.py, checked by tests/test_truth_ur5.py). Two strategies are built at ``--depth`` (D_max, default 6;
``box: auto``): ``down``, the tool axis within 5 deg of straight down, and ``position``, any orientation. Then, for
``--probes`` points drawn uniformly in each tree's box and for as many near its boundary (in its final cells), the
tree's word (the nearest vertex's, in a boundary cell) against the truth:

* ``down``: exact IK with the axis straight down says yes: a point the tree calls unreachable is a false unreachable;
  a point the tree calls reachable that no axis within the cone reaches (``--axes`` sampled within it, and straight
  down) is a false reachable (an upper bound: an axis between the samples may reach it);
* ``position``: some of ``--axes`` tool axes over the sphere reaches the point (a lower bound of the truth): false
  unreachable counted against it is a lower bound, false reachable an upper bound.

And the top of each volume: the highest z the truth reaches over the box's columns against the tree's highest
reachable vertex (the tool-down tree lacked its top 10 cm on example-robot-data's UR5).

    python bench/ur5_truth.py [--depth 6] [--probes 20000] [--axes 400] [--out DIR] [--no-twins]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from analytic_ur5 import URDF, any_reachable, cone, directions, down_reachable  # noqa: E402

from reach.maps.atlas import load_atlas  # noqa: E402
from reach.maps.tree import FINAL  # noqa: E402
from reach.tools.cli import main as reach  # noqa: E402

CONE = 5.0  # [deg] the tool-down strategy's cone


def config(depth: int) -> dict:
    return {"name": "ur5_truth", "description": "The repository's UR5 against ur-analytic-ik (bench/ur5_truth.py)",
            "body": {"urdf": str(URDF), "reference": "auto"}, "box": "auto", "depth": {"min": 2, "max": depth},
            "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "seed": 0, "jit": "auto"}},
            "strategies": [
                {"name": "down", "effector": "ee_link", "priority": 1, "joints": ["*_joint"],
                 "tasks": [{"type": "reach"},
                           {"type": "orientation", "axis": "x", "direction": "-z", "cone": CONE}]},
                {"name": "position", "effector": "ee_link", "priority": 2, "joints": ["*_joint"],
                 "tasks": [{"type": "reach"}]}]}


def truth(strategy: str, points: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Exact for ``down`` at the cone's axis; the sphere's sampled axes for ``position`` (see the docstring)."""
    return down_reachable(points) if strategy == "down" else any_reachable(points, axes)


def rates(tree_says: np.ndarray, truth_says: np.ndarray, upper: np.ndarray) -> dict[str, float]:
    """False reachable (tree yes, ``upper`` no) and false unreachable (tree no, ``truth_says`` yes), in % of probes."""
    n = len(tree_says)
    return {"false_reachable_pct": round(100 * float(np.sum(tree_says & ~upper)) / n, 2),
            "false_unreachable_pct": round(100 * float(np.sum(~tree_says & truth_says)) / n, 2),
            "truly_reachable_pct": round(100 * float(np.mean(truth_says)), 1)}


def top(tree, strategy: str, axes: np.ndarray) -> dict[str, float]:
    """The tree's highest reachable vertex against the truth's highest reachable z. The arm's base turns freely
    (+-2 pi), so the volume is one about the z axis: the truth's columns along +x (1 cm apart) serve."""
    v = tree.vertices
    points = tree.lattice.points(tree.lattice.coords(v.keys[v.reachable]))
    highest = float(points[:, 2].max()) if len(points) else float("nan")
    best = -np.inf
    for x in np.arange(0.0, float(tree.box.hi[0]) + 1e-9, 0.01):
        for z in np.arange(float(tree.box.hi[2]), float(tree.box.lo[2]), -0.002):
            if z <= best:
                break
            if truth(strategy, np.array([[x, 0.0, z]]), axes)[0]:
                best = z
                break
    return {"tree_top_vertex_z_m": round(highest, 3), "truth_top_z_m": round(float(best), 3),
            "cell_m": round(float(np.min(tree.lattice.resolution)), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--depth", type=int, default=6)
    parser.add_argument("--probes", type=int, default=20000)
    parser.add_argument("--axes", type=int, default=400, help="tool axes sampled for the sampled truths")
    parser.add_argument("--out", help="keep the atlas there (default: a temporary folder)")
    parser.add_argument("--seed", type=int, default=48)
    parser.add_argument("--no-twins", action="store_true", help="solve every vertex (build.twins: false)")
    args = parser.parse_args()
    print(json.dumps({"bench": "machine", "python": platform.python_version(),
                      "processor": platform.processor() or platform.machine(), "cores": os.cpu_count()}), flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp) / "ur5_truth"
        path = Path(tmp) / "ur5_truth.yaml"
        path.write_text(yaml.safe_dump({**config(args.depth), "build": {"twins": not args.no_twins}}))
        t0 = time.monotonic()
        if reach(["build", str(path), "-o", str(out), "-q"]) != 0:
            raise SystemExit("the build failed")
        atlas = load_atlas(out)
        calls = {name: tree.meta["build"]["oracle_calls"] for name, tree in atlas.trees.items()}
        turned = {name: tree.meta["build"].get("turned", 0) for name, tree in atlas.trees.items()}
        print(json.dumps({"bench": "build", "d_max": args.depth, "twins": not args.no_twins,
                          "wall_s": round(time.monotonic() - t0, 1), "oracle_calls": calls, "turned": turned}),
              flush=True)
        axes = directions(args.axes)
        rng = np.random.default_rng(args.seed)
        for name, tree in atlas.trees.items():
            uniform = rng.uniform(tree.box.lo, tree.box.hi, (args.probes, 3))
            final = uniform[tree.classify(uniform) == FINAL]  # the boundary's probes, as many as the draw gives
            more = rng.uniform(tree.box.lo, tree.box.hi, (args.probes * 8, 3))
            final = np.concatenate([final, more[tree.classify(more) == FINAL]])[: args.probes]
            for kind, pts in (("uniform", uniform), ("boundary", final)):
                says = tree.contains(pts, "vertex")
                yes = truth(name, pts, axes)
                # down: a reachable verdict is false only if no axis of the cone reaches (an upper bound); position:
                # the sampled axes are the only truth
                upper = yes | any_reachable(pts, cone(CONE)) if name == "down" else yes
                print(json.dumps({"bench": "truth", "strategy": name, "probes": kind, "n": len(pts),
                                  **rates(says, yes, upper)}), flush=True)
            print(json.dumps({"bench": "top", "strategy": name, **top(tree, name, axes)}), flush=True)


if __name__ == "__main__":
    main()
