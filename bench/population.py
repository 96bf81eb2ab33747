"""A population's cost and agreement (docs/population.md): JSON lines.

* ``direct``: ``reach evaluate --direct`` of ``configs/targets/workstation_right.csv`` for the first ``--direct``
  members of ``configs/population.yaml``'s draw widened to that many (the same seed and mix), wall and CPU seconds;
* ``build``: ``reach build`` of ``--build`` members (the demo's right-hand strategies at its resolution, D_max 5),
  wall and CPU seconds, and the same members' accommodation from their atlases against the direct answers
  (``agreement``: member x target pairs whose verdicts agree);
* ``--folder OUT``: instead of building, the ``agreement`` of a population already built (``reach build
  configs/population.yaml -o OUT``);
* ``--random N``: instead of the workstation's targets, N targets drawn uniformly (``--seed``) in the box in front of
  and beside the right side, ``RANDOM_BOX`` (200 random member x target pairs: ``--build 10 --random 20``);
* ``--functional-reach``: instead of all that, MIL-STD-1472G's functional reach asked on every person's own body
  (``configs/examples/functional_reach_{women,men}.yaml``, ``configs/targets/functional_reach.csv``: the right thumb
  tip ahead of the wall behind the shoulders), each sex of the whole survey: per distance the share of the model
  people reaching it with the arm alone and with the shoulder girdle, beside the survey's own share whose thumb-tip
  reach is at least that distance; and the distance 95 % of the women and 5 % of the men reach (linear between the
  targets) against the standard's 5th-percentile woman and 95th-percentile man (``MIL_STD``).

    python bench/population.py [--direct 500] [--build 4 | --folder out/population] [--random 20] [--workers 2]
    python bench/population.py --functional-reach [--workers 2]
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
from reach.building.config import parse_config  # noqa: E402
from reach.building.documents import read_yaml  # noqa: E402

TARGETS = ROOT / "configs" / "targets" / "workstation_right.csv"
# [m] world frame (x ahead, y left, z up, the feet at the origin): ahead and to the right of a standing body, floor
# to above the tallest member's overhead reach, where the members' volumes end (a choice of where to ask).
RANDOM_BOX = np.array([[-0.2, -1.0, 0.0], [1.1, 0.4, 2.4]])
# MIL-STD-1472G Appendix B via NUREG-0700 Rev. 3 Table 11.4 (read there, not in the standard; bench/validation.py):
# functional and extended functional reach [m], the 5th-percentile woman's and the 95th-percentile man's, and the
# share of the sex reaching that far (95 % and 5 %).
MIL_STD = {"female": (0.677, 0.735, 0.95), "male": (0.886, 0.942, 0.05)}
STRATEGIES = {"functional": "right_arm_pinch", "extended": "right_girdle_pinch"}


def functional_reach(workers: int) -> None:
    """See the module docstring."""
    from oracles.bodies import ansur

    targets = load_targets(ROOT / "configs" / "targets" / "functional_reach.csv")
    ahead = np.array([t.point[0] for t in targets])
    for sex, (functional, extended, share) in MIL_STD.items():
        name = {"female": "women", "male": "men"}[sex]
        config = parse_config(read_yaml(ROOT / "configs" / "examples" / f"functional_reach_{name}.yaml"),
                              f"configs/examples/functional_reach_{name}.yaml", name)
        t0, c0 = time.monotonic(), cpu()
        result = direct(config, targets, workers=workers)
        wall, spent = time.monotonic() - t0, cpu() - c0
        reach = ansur.sample(sex).column("thumbtipreach")  # type: ignore[arg-type]
        by = {k: np.array([t["by_strategy"][s]["share"] for t in result["targets"]]) for k, s in STRATEGIES.items()}
        for i, t in enumerate(targets):
            emit(bench="functional_reach", sex=sex, target=t.name, ahead_m=float(ahead[i]),
                 functional_share=float(by["functional"][i]), extended_share=float(by["extended"][i]),
                 survey_thumbtip_share=round(float(np.mean(reach >= ahead[i] - 1e-9)), 4))
        for kind, published in (("functional", functional), ("extended", extended)):
            # shares fall with the distance: the distance at which the model's share passes `share`
            d = float(np.interp(-share, -by[kind], ahead))
            emit(bench="functional_reach_at", sex=sex, kind=kind, share=share, model_m=round(d, 4),
                 mil_std_m=published, deviation_mm=round(1000 * (d - published), 1),
                 sd_mm=round(1000 * float(reach.std()), 1), members=result["members"], wall_s=round(wall, 1),
                 cpu_s=round(spent, 1), refuted_by_check=result["refuted_by_check"])


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
    parser.add_argument("--functional-reach", action="store_true", help="MIL-STD-1472G's functional reach on the "
                        "whole survey's own bodies instead (see the module docstring)")
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=os.cpu_count())
    if args.functional_reach:
        functional_reach(args.workers)
        return
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
