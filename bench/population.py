"""A population's cost and agreement (docs/population.md): JSON lines.

* ``direct``: ``reach evaluate --direct`` of ``configs/targets/workstation_right.csv`` for the first ``--direct``
  members of ``configs/population.yaml``'s draw widened to that many (the same seed and mix), wall and CPU seconds;
  ``--survey``: of the whole survey instead (6,068 members, each sex weighted to half);
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
  targets) against the standard's 5th-percentile woman and 95th-percentile man (``MIL_STD``);
* ``--overhead-reach``: overhead fingertip reach sitting, a dimension no body is built from, asked the same way
  (``configs/examples/overhead_reach_sitting_{women,men}.yaml``, ``configs/targets/overhead_reach_sitting.csv``: the
  right middle fingertip at heights above each person's own seat, seated upright, arm and shoulder girdle free): per
  height the model people's share reaching it with its Wilson interval, beside the survey's share whose measured
  overhead reach is at least that high, and whether it lies in the model's interval;
* ``--boundary-coverage``: the 95 % boundary family of both sexes (``{boundary: {sex: both, coverage: 0.95}}``, 30
  manikins) asked the functional reach targets 5 mm apart; the layout set at its limit (the farthest target every
  manikin reaches, each strategy), then the share of the whole survey (its model people, each sex weighted to half)
  reaching that target: the family's coverage against its nominal 95 % (docs/population.md, "Checks against the
  survey").

    python bench/population.py [--direct 500] [--build 4 | --folder out/population] [--random 20] [--workers 2]
    python bench/population.py --functional-reach [--workers 2]
    python bench/population.py --overhead-reach [--workers 2]
    python bench/population.py --boundary-coverage [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Iterator
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
    for sex, ahead, by, result, spent in survey_check("functional_reach", "thumbtipreach", 0, STRATEGIES, workers):
        functional, extended, share = MIL_STD[sex]
        reach = survey_column(sex, "thumbtipreach")
        for kind, published in (("functional", functional), ("extended", extended)):
            # shares fall with the distance: the distance at which the model's share passes `share`
            d = float(np.interp(-share, -by[kind], ahead))
            emit(bench="functional_reach_at", sex=sex, kind=kind, share=share, model_m=round(d, 4),
                 mil_std_m=published, deviation_mm=round(1000 * (d - published), 1),
                 sd_mm=round(1000 * float(reach.std()), 1), members=result["members"], wall_s=spent[0],
                 cpu_s=spent[1], refuted_by_check=result["refuted_by_check"])


def boundary_coverage(workers: int, coverage: float = 0.95) -> None:
    """See the module docstring."""
    data = read_yaml(ROOT / "configs" / "examples" / "functional_reach.yaml")
    data["population"] = {"boundary": {"sex": "both", "coverage": coverage, "components": 3}}
    family = parse_config(data, "configs/examples/functional_reach.yaml (the boundary family)", "family")
    ahead = np.round(np.arange(0.55, 1.0001, 0.005), 3)
    dense = [Target(f"ahead_{round(1000 * d)}", (float(d), -0.16, 0.0), "right_pinch", "back") for d in ahead]
    result = direct(family, dense, workers=workers)
    limits = {}
    for kind, strategy in STRATEGIES.items():
        # each manikin's reach: the farthest target it reaches (5 mm apart); the layout's limit, the farthest every
        # manikin reaches
        reach = [max((d for d, hit, chosen, also in zip(ahead, m["reached"], m["strategy"], m["also"], strict=True)
                      if hit and (chosen == strategy or strategy in also)), default=0.0) for m in result["by_member"]]
        limits[kind] = float(min(reach))
    at = [Target(f"{kind}_limit", (d, -0.16, 0.0), "right_pinch", "back") for kind, d in limits.items()]
    shares: dict[str, dict[str, float]] = {k: {} for k in limits}
    for sex, name in (("female", "women"), ("male", "men")):
        config = parse_config(read_yaml(ROOT / "configs" / "examples" / f"functional_reach_{name}.yaml"),
                              f"configs/examples/functional_reach_{name}.yaml", name)
        whole = direct(config, at, workers=workers)
        for (kind, strategy), row in zip(STRATEGIES.items(), whole["targets"], strict=True):
            shares[kind][sex] = row["by_strategy"][strategy]["share"]
    for kind, d in limits.items():
        # the family stands for a 50:50 mix of the sexes: the survey weighted so
        model = 0.5 * shares[kind]["female"] + 0.5 * shares[kind]["male"]
        measured = {sex: float(np.mean(survey_column(sex, "thumbtipreach") >= d - 1e-9)) for sex in ("female", "male")}
        emit(bench="boundary_coverage", kind=kind, nominal=coverage, manikins=result["members"], limit_m=round(d, 3),
             model_share=round(model, 4), model_by_sex=shares[kind],
             survey_thumbtip_share=round(0.5 * measured["female"] + 0.5 * measured["male"], 4)
             if kind == "functional" else None, deviation_points=round(100 * (model - coverage), 1))


def overhead_reach(workers: int) -> None:
    """See the module docstring."""
    for sex, _, by, result, spent in survey_check("overhead_reach_sitting", "overheadfingertipreachsitting", 2,
                                                  {"overhead": "right_girdle_fingertip"}, workers):
        column = survey_column(sex, "overheadfingertipreachsitting")
        emit(bench="overhead_reach_sitting", sex=sex, members=result["members"], wall_s=spent[0], cpu_s=spent[1],
             refuted_by_check=result["refuted_by_check"],
             survey_p05_p50_p95_m=np.round(np.percentile(column, [5, 50, 95]), 4).tolist(),
             within_interval=int(np.sum(by["within"])), targets=len(by["within"]))


def survey_column(sex: str, column: str) -> np.ndarray:
    from oracles.bodies import ansur

    return ansur.sample(sex).column(column)  # type: ignore[arg-type]


def survey_check(stem: str, column: str, axis: int, strategies: dict[str, str],
                 workers: int) -> Iterator[tuple[str, np.ndarray, dict, dict, tuple[float, float]]]:
    """Each sex of the whole survey asked ``configs/examples/{stem}_{women,men}.yaml``'s targets
    (``configs/targets/{stem}.csv``, each at a distance along ``axis`` from a landmark of each person's own body): per
    target and strategy the share of the model people reaching it, with its Wilson interval, beside the share of the
    survey's people whose measured ``column`` is at least that distance (with its own). Yields, a sex at a time, the
    targets' distances, each strategy's shares (and ``within``: whether the survey's share lies in the model's
    interval, for the first strategy), the result and (wall, CPU) seconds."""
    from reach.answers.accommodation import wilson

    targets = load_targets(ROOT / "configs" / "targets" / f"{stem}.csv")
    distance = np.array([t.point[axis] for t in targets])
    for sex in ("female", "male"):
        name = {"female": "women", "male": "men"}[sex]
        config = parse_config(read_yaml(ROOT / "configs" / "examples" / f"{stem}_{name}.yaml"),
                              f"configs/examples/{stem}_{name}.yaml", name)
        t0, c0 = time.monotonic(), cpu()
        result = direct(config, targets, workers=workers)
        spent = (round(time.monotonic() - t0, 1), round(cpu() - c0, 1))
        measured = survey_column(sex, column)
        rows = [{k: t["by_strategy"][s] for k, s in strategies.items()} for t in result["targets"]]
        by = {k: np.array([r[k]["share"] for r in rows]) for k in strategies}
        first = next(iter(strategies))
        within = []
        for i, t in enumerate(targets):
            survey = float(np.mean(measured >= distance[i] - 1e-9))
            model = rows[i][first]
            within.append(model["low"] <= survey <= model["high"])
            emit(bench=stem, sex=sex, target=t.name, distance_m=float(distance[i]),
                 **{f"{k}_share": [r["share"], r["low"], r["high"]] for k, r in rows[i].items()},
                 survey_share=[round(survey, 4), *(round(v, 4) for v in wilson(survey, len(measured)))],
                 survey_in_model_interval=within[-1])
        yield sex, distance, {**by, "within": np.array(within)}, result, spent


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def config_of(n: int):  # noqa: ANN201
    """configs/population.yaml with n members of its draw, or the whole survey (n = 0; each sex weighted to half)."""
    data = read_yaml(ROOT / "configs" / "population.yaml")
    data["population"] = ({"ansur": {"all": True, "female_share": 0.5}} if n == 0
                          else {"ansur": {**data["population"]["ansur"], "n": n}})
    return parse_config(data, f"configs/population.yaml (n = {n or 'all'})", "population")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--direct", type=int, default=500, help="members solved directly (default 500; 0: none)")
    parser.add_argument("--survey", action="store_true", help="the whole survey (6,068 members) solved directly "
                                                              "instead")
    parser.add_argument("--build", type=int, default=4, help="members built (default 4; 0: none)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--folder", help="a built population of configs/population.yaml: its agreement, no build")
    parser.add_argument("--random", type=int, default=0, help="N random targets in RANDOM_BOX instead of the "
                                                                 "workstation's")
    parser.add_argument("--seed", type=int, default=47, help="the random targets' seed (default 47)")
    parser.add_argument("--functional-reach", action="store_true", help="MIL-STD-1472G's functional reach on the "
                        "whole survey's own bodies instead (see the module docstring)")
    parser.add_argument("--boundary-coverage", action="store_true", help="the 95 %% boundary family's coverage of "
                        "the whole survey on a layout at its limits instead (see the module docstring)")
    parser.add_argument("--overhead-reach", action="store_true", help="overhead fingertip reach sitting on the whole "
                        "survey's own bodies instead (see the module docstring)")
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=os.cpu_count())
    if args.functional_reach:
        functional_reach(args.workers)
        return
    if args.overhead_reach:
        overhead_reach(args.workers)
        return
    if args.boundary_coverage:
        boundary_coverage(args.workers)
        return
    if args.random:
        points = np.random.default_rng(args.seed).uniform(RANDOM_BOX[0], RANDOM_BOX[1], (args.random, 3))
        targets = [Target(f"random_{k}", tuple(float(v) for v in p), "right_hand") for k, p in enumerate(points)]
    else:
        targets = load_targets(TARGETS)
    if args.direct or args.survey:
        config = config_of(0 if args.survey else args.direct)
        t0, c0 = time.monotonic(), cpu()
        result = direct(config, targets, workers=args.workers)
        wall, spent = time.monotonic() - t0, cpu() - c0
        emit(bench="direct", members=result["members"], targets=len(targets), strategies=len(config.strategies),
             wall_s=round(wall, 1), cpu_s=round(spent, 1), per_member_s=round(wall / result["members"], 3),
             refuted_by_check=result["refuted_by_check"],
             shares={t["target"]: [t["share"], t["low"], t["high"]] for t in result["targets"]})
    if args.folder:
        with tempfile.TemporaryDirectory() as tmp:
            folder, members = built_part(Path(args.folder), Path(tmp))
            agreement(from_atlases(folder, targets), direct(config_of(len(members)), targets, workers=args.workers,
                                                            members=members), folder, targets)
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
            agreement(from_atlases(out, targets), direct(config, targets, workers=args.workers), out, targets)


def built_part(folder: Path, tmp: Path) -> tuple[Path, list]:
    """A population folder's built members: the folder itself when all are, else a population of those alone in
    ``tmp`` (their atlases linked), with the members as ``direct`` takes them (a build still running)."""
    from oracles.bodies.population import Member
    from reach.building.population import MANIFEST, read_manifest

    doc = read_manifest(folder)
    done = [m for m in doc["members"] if (folder / m["atlas"] / "manifest.json").is_file()]
    members = [Member(m["name"], m["body"]["human"], m["sex"], m["weight"]) for m in done]
    if len(done) == len(doc["members"]):
        return folder, members
    for m in done:
        (tmp / m["atlas"]).symlink_to((folder / m["atlas"]).resolve())
    (tmp / MANIFEST).write_text(json.dumps({**doc, "members": done}))
    emit(bench="agreement_members", built=len(done), of=len(doc["members"]))
    return tmp, members


def agreement(trees: dict, by_ik: dict, folder: str | Path | None = None, targets: list[Target] | None = None) -> None:
    """Member x target pairs on which the atlases' verdicts (refined) and the direct solves agree; then per strategy
    (``folder`` and ``targets`` given): each way's share and the pairs on which they differ, by the kind of the
    member's tree's cell at the target (a boundary cell's verdict is the boundary policy's, within its stated
    error: half a cell; an inner or outer cell's differs beyond it)."""
    names = [t["target"] for t in trees["targets"]]
    pairs = [(m["name"], t, a, b) for m, n in zip(trees["by_member"], by_ik["by_member"], strict=True)
             for t, a, b in zip(names, m["reached"], n["reached"], strict=True)]
    emit(bench="agreement", pairs=len(pairs), agree=sum(a == b for *_, a, b in pairs),
         disagree=[{"member": m, "target": t, "atlas": a, "direct": b} for m, t, a, b in pairs if a != b],
         atlas_reached=sum(a for *_, a, _ in pairs), direct_reached=sum(b for *_, b in pairs),
         shares_atlases={t["target"]: t["share"] for t in trees["targets"]},
         shares_direct={t["target"]: t["share"] for t in by_ik["targets"]})
    if folder is None or targets is None:
        return
    from reach.answers.accommodation import load_members
    from reach.maps.kinds import FINAL, INNER, OUTER

    atlases, _, _ = load_members(folder)
    points = np.array([t.point for t in targets], float)
    kinds = {OUTER: "outer", INNER: "inner", FINAL: "boundary"}
    for strategy in trees["strategies"]:
        differ: dict[str, list] = {"inner": [], "boundary": [], "outer": []}
        for atlas, m, n in zip(atlases, trees["by_member"], by_ik["by_member"], strict=True):
            cells = atlas.trees[strategy].classify(points)
            for i, name in enumerate(names):
                a, b = (strategy == x["strategy"][i] or strategy in x["also"][i] for x in (m, n))
                if a != b:
                    differ[kinds[int(cells[i])]].append({"member": m["name"], "target": name, "atlas": a, "direct": b})
        share = {way: {t["target"]: t["by_strategy"].get(strategy, {}).get("share") for t in result["targets"]}
                 for way, result in (("atlases", trees), ("direct", by_ik))}
        gap = {t: round(abs((share["atlases"][t] or 0) - (share["direct"][t] or 0)), 4) for t in names}
        worst = max(gap, key=gap.__getitem__)
        emit(bench="agreement_by_strategy", strategy=strategy, pairs=len(pairs),
             differ={k: len(v) for k, v in differ.items()}, largest_gap=gap[worst], largest_gap_target=worst,
             shares_atlases=share["atlases"], shares_direct=share["direct"], beyond_boundary=differ["inner"]
             + differ["outer"], in_boundary_cells=differ["boundary"])


if __name__ == "__main__":
    main()
