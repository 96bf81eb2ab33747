"""Asking an atlas: query, evaluate, place (motion: :mod:`reach.tools.commands.motion`)."""


from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from reach.answers.defaults import REFINE_BUDGET
from reach.errors import ConfigError, InputError
from reach.serving import protocol as P
from reach.tools.commands.common import (
    dask_client,
    from_posture,
    goal_values,
    goals_file,
    handover_margin,
    handover_option,
    policy_option,
    print_json,
)
from reach.tools.commands.motion import add_motion

QUERY_BUDGET = 1.0  # [s] default refinement budget of a local `reach query`: one question, no frame to keep


def cmd_query(args: argparse.Namespace) -> int:
    if args.goals is not None:
        return _query_many(args)
    atlas, goal = goal_values(args.values, args.connect is None)
    refine = None if args.refine is None else args.refine == "on"
    start = from_posture(args.start)
    wire = _orientation(args)
    if args.connect:
        with _client(args) as client:
            effectors = [args.effector] if args.effector else client.strategies()["effectors"]
            # The reply's envelope fields are not part of the answer.
            replies = [client.query(e, goal, refine, start, miss=args.miss, orientation=wire) for e in effectors]
            answers = [{k: v for k, v in reply.items() if k not in ("ok", "id")} for reply in replies]
    else:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.answers.answer import orientation_of

        selector = _selector(args, atlas, refine)
        effectors = [args.effector] if args.effector else selector.effectors
        aim = orientation_of(wire)
        assert not isinstance(aim, list)  # one goal, one orientation
        answers = [selector.select(e, np.array(goal), start=start, orientation=aim).to_dict() for e in effectors]
    if args.json:
        print_json({"answers": answers})
        return 0
    for a in answers:
        print("\n".join(_answer_lines(a)))
    return 0


def _orientation(args: argparse.Namespace) -> dict[str, list[float]] | None:
    """``--direction`` or ``--quaternion`` as the protocol's ``orientation`` field, checked as the server checks it."""
    wire = ({"direction": args.direction} if args.direction else {"quaternion": args.quaternion} if args.quaternion
            else None)
    if wire is not None:
        try:
            P.check_orientation(wire)  # the server's own check of the field
        except P.Invalid as exc:
            raise InputError("--direction" if args.direction else "--quaternion", str(exc)) from None
        if not args.effector:
            raise InputError("--effector", "give the effector with --direction or --quaternion")
    return wire


def _answer_lines(a: dict[str, Any]) -> list[str]:
    """One answer as ``reach query`` prints it."""
    if not a["reachable"]:
        if a.get("nearest"):
            n = a["nearest"]
            return [f"{a['effector']}: goal {a['goal']} not reachable: {n['strategy']}'s tree holds it but no "
                    f"refinement reached it; the nearest point a stored posture reaches is {n['point']}, "
                    f"{1000 * n['distance']:.1f} mm away"]
        return [f"{a['effector']}: goal {a['goal']} not reachable by any strategy"]
    also = f" (also: {', '.join(a['alternatives'])})" if a["alternatives"] else ""
    out = [f"{a['effector']}: goal {a['goal']} reachable with strategy {a['strategy']}{also}"]
    if a.get("handover"):
        out.append(f"  handed over by {a['handover']['from']}, whose posture came near these limits: "
                   f"{', '.join(a['handover']['limits'])}")
    if a.get("within") is not None:
        out.append(f"  within {1000 * a['within']:.1f} mm only: no refinement reached the goal; the posture is "
                   "the nearest stored one")
    if a.get("posture"):
        moved = {k: round(v, 4) for k, v in a["posture"].items() if abs(v) > 1e-9}
        out.append(f"  posture [rad] (refined: {a['refined']}, residual {a['residual']:.2e} m): {moved}")
    if a.get("root"):
        r = a["root"]
        out.append(f"  root: position {np.round(r['position'], 4).tolist()} [m], quaternion (x, y, z, w) "
                   f"{np.round(r['quaternion'], 5).tolist()}")
    if a.get("step"):
        st = a["step"]
        out.append(f"  step: {st['foot']} set down at {np.round(st['position'], 4).tolist()} [m], turned "
                   f"{np.degrees(st['yaw']):.1f} deg")
    return out


def _query_many(args: argparse.Namespace) -> int:
    """``reach query --goals FILE``: every goal of the file (the batch of a script), one answer a line as JSON, in
    the file's order, by effector; one process, its solvers built once."""
    atlas, goals = goals_file(args.goals, args.connect is None, args.values)
    refine = None if args.refine is None else args.refine == "on"
    start = from_posture(args.start)
    if args.direction or args.quaternion:
        raise InputError("--goals", "a file of goals takes no --direction or --quaternion (ask them one by one)")
    if args.connect:
        with _client(args) as client:
            for effector in [args.effector] if args.effector else client.strategies()["effectors"]:
                for a in range(0, len(goals), P.MAX_BATCH):
                    for reply in client.query_many(effector, goals[a:a + P.MAX_BATCH], refine, start, miss=args.miss):
                        _print_line(reply)
        return 0
    selector = _selector(args, atlas, refine)
    for effector in [args.effector] if args.effector else selector.effectors:
        for answer in selector.select_many(effector, np.array(goals), start=start):
            _print_line(answer.to_dict())
    return 0


def _client(args: argparse.Namespace) -> Any:
    """The query's client of ``--connect`` (with its CURVE keys)."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.serving.client import Client

    return Client(args.connect, timeout=args.timeout, curve_server_key=args.curve_server_key,
                  curve_client_key=args.curve_client_key)


def _selector(args: argparse.Namespace, atlas: str | None, refine: bool | None) -> Any:
    """The query's selector of an atlas folder, with the command's options."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.select import Selector
    from reach.maps.atlas import load_atlas

    return Selector(load_atlas(atlas), policy=args.policy, refine=refine is not False,  # type: ignore[arg-type]
                    budget=args.budget_ms / 1000.0, handover=handover_margin(args), miss=args.miss)


def _print_line(answer: dict[str, Any]) -> None:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.serving.protocol import finite

    print(json.dumps(finite(answer), sort_keys=True, allow_nan=False), flush=True)


def add_query(sub: Any) -> None:
    """Register ``reach query``."""
    p = sub.add_parser(
        "query", help="which strategy reaches a goal",
        description="Ask which strategy reaches the goal X Y [Z] (metres, atlas world frame), by priority: "
        "'reach query ATLAS X Y [Z]' reads the atlas (a second or two: it loads the solvers), 'reach query --connect "
        "ADDR X Y [Z]' asks a running server (milliseconds). Many goals: --goals FILE, a server, or the Python API "
        "(reach.Selector) in a process of your own.",
    )
    p.usage = ("reach query [options] ATLAS X Y [Z]\n       reach query [options] --goals FILE ATLAS\n"
               "       reach query --connect ADDR [options] X Y [Z]")
    p.add_argument("values", nargs="*", metavar="ATLAS X Y [Z]", help="atlas folder (omitted with --connect) and one "
        "goal [m]")
    p.add_argument("--goals", metavar="FILE", help="many goals: a file (or - for standard input) of X Y [Z] [m] a "
                                                   "line, commas or spaces; one answer a line as JSON, in order (a "
                                                   "script's hundred queries in one process)")
    p.add_argument("--connect", metavar="ADDR", help=f"ask the server at ADDR (e.g. {P.DEFAULT_BIND}) instead of "
                                                     "reading an atlas")
    p.add_argument("--effector", help="effector to ask about (default: every effector of the atlas)")
    policy_option(p)
    p.add_argument("--refine", choices=["on", "off"], help="refine the posture by IK at the exact goal (default: on)")
    p.add_argument("--from", dest="start", metavar="POSTURE",
                   help="the character's current posture, a JSON object of joint name -> value [rad or m] (or a file "
                        "holding one): the answer is the natural posture reached from it")
    aim = p.add_mutually_exclusive_group()
    aim.add_argument("--direction", nargs=3, type=float, metavar=("X", "Y", "Z"),
                     help="hold the effector's approach axis along this world direction (strategies with an "
                          "orientation task that has an axis)")
    aim.add_argument("--quaternion", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                     help="hold the effector's rotation in the world (strategies with an orientation task)")
    p.add_argument("--budget-ms", type=float, default=QUERY_BUDGET * 1000,
                   help="reading an atlas: budget of the IK refinement [ms], work priced in the reference machine's "
                        f"time (default {QUERY_BUDGET * 1000:g}: a "
                        f"one-off question lets it converge; a server's default is {REFINE_BUDGET * 1000:g}, a frame)")
    handover_option(p, "reading an atlas: ")
    p.add_argument("--timeout", type=int, default=P.REQUEST_TIMEOUT_MS, help="with --connect: ms to wait for each "
        f"reply (default {P.REQUEST_TIMEOUT_MS})")
    p.add_argument("--curve-server-key", metavar="FILE", help="with --connect: the server's CURVE public-key file")
    p.add_argument("--curve-client-key", metavar="FILE", help="with --curve-server-key: this client's secret-key "
                                                              "file (for a server with --curve-clients)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_query)


def cmd_evaluate(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.evaluate import evaluate, load_targets, text_table
    from reach.maps.atlas import load_atlas

    at = None if not args.at else np.array([[x, y, z, math.radians(yaw)] for x, y, z, yaw in args.at])
    if (args.scheduler or args.dask) and not args.direct:
        raise InputError("--scheduler" if args.scheduler else "--dask", "Dask solves a population's members with "
                                                                        "--direct only; built atlases answer here")
    if args.direct or any(_is_population(a) for a in args.atlas):
        return _accommodation(args, at)
    atlases = [load_atlas(_atlas_folder(a)) for a in args.atlas]
    results = evaluate(atlases, load_targets(args.targets), args.effector, args.policy, refine=not args.no_refine,
                       placements=at)
    if args.figure:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.tools.sketch import layout_figure

        layout_figure(atlases, results, Path(args.figure))
    if args.json:
        print_json(results)
    else:
        print(text_table(results))
        if args.figure:
            print(f"wrote {args.figure}")
    return 0


def _atlas_folder(path: str) -> str:
    """An atlas folder to evaluate, or InputError for a config given in its place."""
    if Path(path).is_file() and Path(path).suffix in (".yaml", ".yml"):
        raise InputError("atlas", f"{path} is a config, not an atlas folder: give --direct to solve its strategies "
                                  f"for the targets without trees, or build it first (reach build {path}) and "
                                  "evaluate the folder it writes (out/NAME)")
    return path


def _is_population(path: str) -> bool:
    from reach.building.population import is_population

    return is_population(path)


def _accommodation(args: argparse.Namespace, at: np.ndarray | None) -> int:
    """``reach evaluate`` of a population: a built population's folder, or a config with --direct."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers import accommodation
    from reach.answers.evaluate import load_targets

    if len(args.atlas) != 1:
        raise ConfigError("atlas", "", "a population is evaluated alone: give one population folder (or one config "
                                       f"with --direct), got {len(args.atlas)}")
    if at is not None and len(at) != 1:
        raise ConfigError("--at", "", "a population takes one placement, for every member")
    if args.figure:
        raise ConfigError("--figure", "", "a population's figure is not drawn yet: omit --figure")
    targets = load_targets(args.targets)
    if args.direct:
        from reach.building.config import load_config

        config = load_config(args.atlas[0])
        if config.population is None:
            raise ConfigError(config.source, "population", "--direct needs a config with population: (see "
                                                           "docs/population.md)")
        log = None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
        workers = args.workers or os.cpu_count() or 1
        client = dask_client(args, workers)
        try:
            result = accommodation.direct(config, targets, args.effector, at, log=log, workers=workers, client=client)
        finally:
            if client is not None:
                client.close()
    else:
        result = accommodation.from_atlases(args.atlas[0], targets, args.effector, refine=not args.no_refine,
                                            placement=at)
    if args.json:
        print_json(result)
    else:
        print(accommodation.text(result))
    return 0


def add_evaluate(sub: Any) -> None:
    """Register ``reach evaluate``."""
    p = sub.add_parser("evaluate", help="which strategy reaches each target, per atlas", description="For each "
        "target of a CSV (name, x, y, z [m], optional effector), which strategy each atlas chooses; several atlases "
        "give a population table.")
    p.add_argument("atlas", nargs="+", help="atlas folders; or one population folder (reach build of a config with "
                                            "population:), for the share of its members that reach each target; "
                                            "or, with --direct, one such config")
    p.add_argument("--targets", required=True, help="CSV file with name, x, y, z[, effector]")
    p.add_argument("--direct", action="store_true", help="ATLAS is a config with population: solve every member x "
                   "target with the strategies' oracles, no trees (cheaper than building for a few targets)")
    p.add_argument("-j", "--workers", type=int, help="with --direct: processes solving members (default: all cores)")
    p.add_argument("--dask", action="store_true", help="with --direct: solve the members on a Dask LocalCluster of "
                   "--workers processes")
    p.add_argument("--scheduler", metavar="ADDR", help="with --direct: solve the members on the Dask cluster at ADDR, "
                   "e.g. tcp://10.0.0.5:8786")
    p.add_argument("--effector", help="effector for targets without one")
    policy_option(p)
    p.add_argument("--no-refine", action="store_true",
                   help=("take the trees' word: no IK at the targets (a target counts as reachable when a tree holds "
                         "it)"))
    p.add_argument("--at", type=float, nargs=4, action="append", metavar=("X", "Y", "Z", "YAW"),
                   help="where the body's frame stands in the targets' frame: position [m] and heading [deg]; once "
                        "for every atlas, or once per atlas in order (a driver's seat slid to her heel point); "
                        "default: the targets are in the body's frame")
    p.add_argument("--figure", metavar="PNG", help="per atlas, side and top views of the body, its furniture, the "
                                                   "volumes through the right shoulder and the targets coloured by "
                                                   "the strategy that reaches them")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_evaluate)


def cmd_place(args: argparse.Namespace) -> int:
    """Rank placements of the body (a population of atlases) against a layout's targets; verify the best by IK."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.evaluate import load_targets
    from reach.answers.place import Space, rank, verify
    from reach.tools.report import placement_map

    atlases, members = _atlases(args.atlas)
    targets = load_targets(args.targets)
    weights = _weights(args.weight or [])
    space = Space(tuple(args.x), tuple(args.y), tuple(args.z), (math.radians(args.yaw[0]), math.radians(args.yaw[1])),
                  args.step, math.radians(args.yaw_step))
    ranking = rank(atlases, targets, space, args.effector, args.policy, weights, body_weights=members,
                   need=args.targets_share)
    if args.verify:
        verify(ranking, atlases, targets, args.verify, args.effector, args.policy, body_weights=members,
               need=args.targets_share)
    kept = [k for k in range(len(ranking.placements)) if ranking.accommodated[k] >= args.accommodate - 1e-9]
    rows = [ranking.row(k, targets) for k in kept[:args.top]]
    if args.figure:
        placement_map(ranking, targets, Path(args.figure))
    if args.json:
        print_json({"candidates": len(ranking.placements), "accommodating": len(kept), "ranked": rows,
                    "verified": ranking.verified})
    else:
        _print_ranking(args, ranking, len(atlases), len(targets), kept, rows)
    return 0


def _weights(items: list[str]) -> dict[str, float]:
    """--weight STRATEGY=NUMBER, each."""
    weights = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            weights[name] = float(value)
        except ValueError:
            raise InputError("--weight", f"expected STRATEGY=NUMBER, got {item!r}") from None
    return weights


def _print_ranking(args: argparse.Namespace, ranking: Any, bodies: int, targets: int, kept: list[int],
                   rows: list[dict[str, Any]]) -> None:
    """A placement ranking as a table for a person, and its verified placements."""
    print(f"{len(ranking.placements)} placements of {bodies} bodies against {targets} targets (trees' "
          "word; best first)" + (f"; {len(kept)} accommodate at least {100 * args.accommodate:.0f}% of the bodies"
                                 if args.accommodate > 0 else ""))
    print(f"{'rank':>4}  {'x [m]':>7} {'y [m]':>7} {'z [m]':>7} {'yaw':>6}  {'bodies':>7} {'targets':>7} "
          f"{'weight':>7} {'margin':>7}")
    for r in rows:
        x, y, z = r["position"]
        margin = "" if r["margin"] is None else f"{r['margin']:>7.3f}"
        print(f"{r['rank']:>4}  {x:>7.3f} {y:>7.3f} {z:>7.3f} {r['yaw_deg']:>5.0f}°  "
              f"{100 * r['accommodated']:>6.0f}% {100 * r['reached']:>6.0f}% {r['preference']:>7.3f} {margin}")
    for v in ranking.verified:
        moved = f", the trees' rank {v['trees_rank']}" if v["trees_rank"] != v["rank"] else ""
        print(f"rank {v['rank']} verified by IK: {100 * v['reached']:.0f}% of targets reached, "
              f"{100 * v['accommodated']:.0f}% of bodies accommodated "
              f"(trees: {100 * v['claimed_reached']:.0f}%{moved})")
    if args.figure:
        print(f"figure: {args.figure}")


def _atlases(paths: list[str]) -> tuple[list[Any], np.ndarray | None]:
    """The atlases named, a population folder standing for its members' atlases (with their weights)."""
    from reach.answers.accommodation import load_members
    from reach.building.population import is_population
    from reach.maps.atlas import load_atlas

    if not any(is_population(p) for p in paths):
        return [load_atlas(a) for a in paths], None
    if len(paths) != 1:
        raise ConfigError("atlas", "", "a population folder is placed alone (its members are the bodies), got "
                                       f"{len(paths)} folders")
    atlases, weights, _ = load_members(paths[0])
    return atlases, weights


def add_place(sub: Any) -> None:
    """Register ``reach place``."""
    p = sub.add_parser("place", help="where the body should stand, sit or be mounted to reach a layout's targets",
                       description="Score a grid of placements (position [m] and heading [deg] of the body's frame "
                                   "in the layout's frame) of one "
                       "body or a population (several atlases) against a targets CSV by the trees, rank them (bodies "
                       "accommodated, targets reached, strategies needed), and verify the best by IK.")
    p.add_argument("atlas", nargs="+", help="atlas folders (several: a population), or one population folder (reach "
                                            "build of a config with population:; its members weighted as it says)")
    p.add_argument("--targets", required=True, help="CSV file with name, x, y, z[, effector] in the layout's frame [m]")
    p.add_argument("--accommodate", type=float, default=0.0, metavar="SHARE",
                   help="print only placements at which at least this share of the bodies is accommodated, e.g. 0.95 "
                        "(default 0: all)")
    p.add_argument("--targets-share", type=float, default=1.0, metavar="SHARE",
                   help="a body is accommodated when it reaches at least this share of the targets (default 1: every "
                        "target)")
    p.add_argument("--effector", help="effector for targets without one")
    p.add_argument("--x", nargs=2, type=float, required=True, metavar=("MIN", "MAX"), help="range of the body's x [m]")
    p.add_argument("--y", nargs=2, type=float, required=True, metavar=("MIN", "MAX"), help="range of the body's y [m]")
    p.add_argument("--z", nargs=2, type=float, default=[0.0, 0.0], metavar=("MIN", "MAX"), help="range of its height "
        "[m] (default 0: on the floor)")
    p.add_argument("--yaw", nargs=2, type=float, default=[-180.0, 180.0], metavar=("MIN", "MAX"), help="range of its "
        "heading [deg] (default a full turn)")
    p.add_argument("--step", type=float, default=0.05, help="position step [m] (default 0.05)")
    p.add_argument("--yaw-step", type=float, default=15.0, help="heading step [deg] (default 15)")
    p.add_argument("--weight", action="append", metavar="STRATEGY=W", help="a strategy's weight (default: 1, 0.8, "
        "0.6, ... by priority)")
    p.add_argument("--top", type=int, default=10, help="placements to print (default 10)")
    p.add_argument("--verify", type=int, default=5, help="the best placements to verify by IK (default 5; 0: none)")
    p.add_argument("--figure", metavar="PNG", help="write the floor heat map (share of targets reached per position)")
    policy_option(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_place)


# Each registers its command's subparser.
COMMANDS = (add_query, add_motion, add_evaluate, add_place)
