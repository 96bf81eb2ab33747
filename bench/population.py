"""A population's cost and agreement (docs/history.md): JSON lines.

* ``direct``: ``reach evaluate --direct`` of ``configs/targets/workstation_right.csv`` for the first ``--direct``
  members of ``configs/population.yaml``'s draw widened to that many (the same seed and mix), wall and CPU seconds;
* ``build``: ``reach build`` of ``--build`` members (the demo's right-hand strategies at its resolution, D_max 5),
  wall and CPU seconds, and the same members' accommodation from their atlases against the direct answers
  (``agreement``: member x target pairs whose verdicts agree);
* ``--folder OUT``: instead of building, the ``agreement`` of a population already built (``reach build
  configs/population.yaml -o OUT``);
* ``--random N``: instead of the workstation's targets, N targets drawn uniformly (``--seed``) in the box in front of
  and beside the right side, ``RANDOM_BOX`` (200 random member x target pairs: ``--build 10 --random 20``).

    python bench/population.py [--direct 500] [--build 4 | --folder out/population] [--random 20] [--workers 2]
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reach.answers.accommodation import direct, from_atlases  # noqa: E402
from reach.answers.evaluate import Target, load_targets  # noqa: E402
from reach.building.config import parse_config, read_yaml  # noqa: E402

TARGETS = ROOT / "configs" / "targets" / "workstation_right.csv"
# [m] world frame (x ahead, y left, z up, the feet at the origin): ahead and to the right of a standing body, floor
# to above the tallest member's overhead reach, where the members' volumes end (a choice of where to ask).
RANDOM_BOX = np.array([[-0.2, -1.0, 0.0], [1.1, 0.4, 2.4]])


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def config_of(n: int):  # noqa: ANN201
    data = read_yaml(ROOT / "configs" / "population.yaml")
    data["population"]["ansur"]["n"] = n
    return parse_config(data, f"configs/population.yaml (n = {n})", "population")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--direct", type=int, default=500, help="members solved directly (default 500)")
    parser.add_argument("--build", type=int, default=4, help="members built (default 4; 0: none)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--folder", help="a built population of configs/population.yaml: its agreement, no build")
    parser.add_argument("--random", type=int, default=0, help="N random targets in RANDOM_BOX instead of the "
                                                                 "workstation's")
    parser.add_argument("--seed", type=int, default=47, help="the random targets' seed (default 47)")
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=os.cpu_count())
    if args.random:
        points = np.random.default_rng(args.seed).uniform(RANDOM_BOX[0], RANDOM_BOX[1], (args.random, 3))
        targets = [Target(f"random_{k}", tuple(float(v) for v in p), "right_hand") for k, p in enumerate(points)]
    else:
        targets = load_targets(TARGETS)
    if args.direct:
        config = config_of(args.direct)
        t0, c0 = time.monotonic(), cpu()
        result = direct(config, targets, workers=args.workers)
        wall, spent = time.monotonic() - t0, cpu() - c0
        emit(bench="direct", members=args.direct, targets=len(targets), strategies=len(config.strategies),
             wall_s=round(wall, 1), cpu_s=round(spent, 1), per_member_s=round(wall / args.direct, 2),
             refuted_by_check=result["refuted_by_check"],
             shares={t["target"]: [t["share"], t["low"], t["high"]] for t in result["targets"]})
    if args.folder:
        from reach.building.population import read_manifest

        n = len(read_manifest(args.folder)["members"])
        agreement(from_atlases(args.folder, targets), direct(config_of(n), targets, workers=args.workers))
    elif args.build:
        from reach.building.atlas import build_atlas
        from reach.building.executor import ProcessExecutor
        from reach.building.population import build_population

        config = config_of(args.build)
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "population"
            t0, c0 = time.monotonic(), cpu()
            build_population(config, out, lambda member, folder: build_atlas(
                member, folder, executor_factory=lambda spec: ProcessExecutor(spec, args.workers, config.chunk_size)))
            wall, spent = time.monotonic() - t0, cpu() - c0
            emit(bench="build", members=args.build, strategies=len(config.strategies), d_max=config.d_max,
                 workers=args.workers, wall_s=round(wall, 1), cpu_s=round(spent, 1),
                 per_member_wall_s=round(wall / args.build, 1))
            agreement(from_atlases(out, targets), direct(config, targets, workers=args.workers))


def agreement(trees: dict, by_ik: dict) -> None:
    """Member x target pairs on which the atlases' verdicts (refined) and the direct solves agree."""
    names = [t["target"] for t in trees["targets"]]
    pairs = [(m["name"], t, a, b) for m, n in zip(trees["by_member"], by_ik["by_member"], strict=True)
             for t, a, b in zip(names, m["reached"], n["reached"], strict=True)]
    emit(bench="agreement", pairs=len(pairs), agree=sum(a == b for *_, a, b in pairs),
         disagree=[{"member": m, "target": t, "atlas": a, "direct": b} for m, t, a, b in pairs if a != b],
         atlas_reached=sum(a for *_, a, _ in pairs), direct_reached=sum(b for *_, b in pairs),
         shares_atlases={t["target"]: t["share"] for t in trees["targets"]},
         shares_direct={t["target"]: t["share"] for t in by_ik["targets"]})


if __name__ == "__main__":
    main()
