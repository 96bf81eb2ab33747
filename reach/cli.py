"""The ``reach`` command line.

Every command has ``--help``. Errors from reach (bad configs, files, names)
print one line naming what was wrong and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reach import protocol as P
from reach.errors import ConfigError, InputError, ReachError, TreeError
from reach.select import HANDOVER, MISS, MISSES, REFINE_BUDGET
from reach.tree import DEFAULT_POLICY, POLICIES

QUERY_BUDGET = 1.0  # [s] default refinement budget of a local `reach query`: one question, no frame to keep
MOTION_FILES = (".json", ".bvh", ".glb", ".gltf")  # reach motion -o: by the file's extension
ANIMATION_FILES = (".bvh", ".glb", ".gltf")  # ... those written from the motion's bones (its rig)


def _print_json(data: Any) -> None:
    from reach.protocol import finite

    print(json.dumps(finite(data), indent=2, sort_keys=True, allow_nan=False))


def cmd_build(args: argparse.Namespace) -> int:
    from reach.atlas import build_atlas
    from reach.config import load_config

    config = load_config(args.config)
    for note in config.notes:
        print(f"warning: {config.source}: {note}", file=sys.stderr, flush=True)
    if args.strict and config.notes:
        raise ConfigError(config.source, "", f"{len(config.notes)} warning(s) above, and --strict makes them errors")
    if args.refine_centres or args.refine_faces or args.retry_isolated:
        import dataclasses

        from reach.build import Refine

        r = config.refine
        config = dataclasses.replace(config, refine=Refine(r.centres or args.refine_centres, r.faces or args.refine_faces, r.isolated or args.retry_isolated))
    out = Path(args.output) if args.output else Path("out") / config.name
    factory, client, how = _executor_factory(args, config.chunk_size)
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminated)  # as Ctrl-C: the checkpoints stay, a message, status 143
    print(f"building {len(config.strategies)} strateg{'y' if len(config.strategies) == 1 else 'ies'} of {config.source} into {out} ({how})", flush=True)
    try:
        atlas = build_atlas(config, out, executor_factory=factory, progress=not args.quiet, log=lambda line: print(line, flush=True),
                    resume=args.resume, mirror=not args.no_mirror,
                    inherit=not args.no_inherit)
    finally:
        if client is not None:
            client.close()
    print(f"atlas written to {out}")
    cut = [w["strategy"] for w in atlas.manifest.get("warnings", {}).get("faces", [])]
    if args.strict and cut:
        raise TreeError(f"the box cuts the volume of {', '.join(cut)} (warnings above), and --strict makes that an error; the atlas is kept")
    return 0


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled as SIGINT is."""


def _terminated(signum: int, frame: Any) -> None:
    raise Terminated


def _executor_factory(args: argparse.Namespace, chunk_size: int) -> tuple[Any, Any, str]:
    """The executor factory the build options ask for, the Dask client if any, and a description."""
    import os

    from reach.executor import DaskExecutor, InlineExecutor, ProcessExecutor

    workers = args.workers or os.cpu_count() or 1
    if args.scheduler or args.dask:
        from distributed import Client, LocalCluster

        if args.scheduler:
            client = Client(args.scheduler)
            how = f"Dask scheduler {args.scheduler}"
        else:
            client = Client(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None))
            how = f"Dask LocalCluster, {workers} workers"
        return (lambda spec: DaskExecutor(spec, client, chunk_size)), client, how
    if workers == 1:
        return (lambda spec: InlineExecutor(spec, chunk_size)), None, "inline"
    return (lambda spec: ProcessExecutor(spec, workers, chunk_size)), None, f"{workers} processes"


def cmd_info(args: argparse.Namespace) -> int:
    from reach.atlas import face_text, summary
    from reach.store import load_atlas

    info = summary(load_atlas(args.atlas))
    if args.json:
        _print_json(info)
        return 0
    print(f"atlas {info['name']} at {info['path']}")
    for name, s in info["strategies"].items():
        ext = s["extent"]
        print(
            f"  {name} (effector {s['effector']}, priority {s['priority']}): "
            f"inner volume {s['volume']['inner']:.6g}, boundary {s['volume']['boundary']:.6g}, "
            + (f"mirrored from {s['mirrored_from']} (no oracle call)" if s["mirrored_from"] else f"{s['oracle_calls']} oracle calls of {s['lattice_vertices']} lattice vertices")
            + (f", {s['inherited_vertices']} reachable vertices inherited from {s['inherited_from']}" if s.get("inherited_from") else "")
        )
        if ext:
            print(f"    inner and boundary cells span min {np.round(ext['min'], 4).tolist()} max {np.round(ext['max'], 4).tolist()} [m]")
        if s["reachable_extent"]:
            r = s["reachable_extent"]
            print(f"    reachable vertices span min {np.round(r['min'], 4).tolist()} max {np.round(r['max'], 4).tolist()} [m]")
        if s.get("index"):
            i = s["index"]
            print(f"    reachability index over {i['directions']} directions: mean {i['mean']:.3f}, quartiles {i['quartiles']} at reachable vertices"
                  + (f" ({i['goals']} goals solved, {i['seconds']:.1f} s)" if i.get("goals") is not None else ""))
        if s["on_faces"]:
            print(f"    warning: {face_text(s['on_faces'])}")
        for line in s.get("audit_warnings", []):
            print(f"    warning: {line}")
    for note in info.get("config_warnings", []):
        print(f"  warning (config): {note}")
    for note in info.get("audit_warnings", []):
        print(f"  warning (audit): {note}")
    return 0


def _goal(values: list[str], with_atlas: bool) -> tuple[str | None, list[float]]:
    expected = "ATLAS X Y [Z]" if with_atlas else "X Y [Z] (with --connect)"
    need = (3, 4) if with_atlas else (2, 3)
    if len(values) not in need:
        raise InputError("goal", f"query takes {expected}, got {len(values)} values")
    atlas = values[0] if with_atlas else None
    coords = values[1:] if with_atlas else values
    try:
        return atlas, [float(v) for v in coords]
    except ValueError as exc:
        raise InputError("goal", f"coordinates must be numbers in metres ({exc})") from exc


def cmd_query(args: argparse.Namespace) -> int:
    atlas, goal = _goal(args.values, args.connect is None)
    refine = None if args.refine is None else args.refine == "on"
    start = _start(args.start)
    wire = {"direction": args.direction} if args.direction else {"quaternion": args.quaternion} if args.quaternion else None
    if wire is not None:
        try:
            P.check_orientation(wire)  # the server's own check of the field
        except P.Invalid as exc:
            raise InputError("--direction" if args.direction else "--quaternion", str(exc)) from None
        if not args.effector:
            raise InputError("--effector", "give the effector with --direction or --quaternion")
    if args.connect:
        from reach.client import Client

        with Client(args.connect, timeout=args.timeout, curve_server_key=args.curve_server_key, curve_client_key=args.curve_client_key) as client:
            effectors = [args.effector] if args.effector else client.strategies()["effectors"]
            # The reply's envelope fields are not part of the answer.
            answers = [{k: v for k, v in client.query(e, goal, refine, start, miss=args.miss, orientation=wire).items() if k not in ("ok", "id")}
                       for e in effectors]
    else:
        from reach.select import Selector, orientation_of
        from reach.store import load_atlas

        selector = Selector(load_atlas(atlas), policy=args.policy, refine=refine is not False, budget=args.budget_ms / 1000.0,  # type: ignore[arg-type]
                            handover=_handover(args), miss=args.miss)
        effectors = [args.effector] if args.effector else selector.effectors
        aim = orientation_of(wire)
        assert not isinstance(aim, list)  # one goal, one orientation
        answers = [selector.select(e, np.array(goal), start=start, orientation=aim).to_dict() for e in effectors]
    if args.json:
        _print_json({"answers": answers})
        return 0
    for a in answers:
        if a["reachable"]:
            also = f" (also: {', '.join(a['alternatives'])})" if a["alternatives"] else ""
            print(f"{a['effector']}: goal {a['goal']} reachable with strategy {a['strategy']}{also}")
            if a.get("handover"):
                print(f"  handed over by {a['handover']['from']}, whose posture came near these limits: {', '.join(a['handover']['limits'])}")
            if a.get("within") is not None:
                print(f"  within {1000 * a['within']:.1f} mm only: no refinement reached the goal; the posture is the nearest stored one")
            if a.get("posture"):
                moved = {k: round(v, 4) for k, v in a["posture"].items() if abs(v) > 1e-9}
                print(f"  posture [rad] (refined: {a['refined']}, residual {a['residual']:.2e} m): {moved}")
            if a.get("root"):
                r = a["root"]
                print(f"  root: position {np.round(r['position'], 4).tolist()} [m], quaternion (x, y, z, w) {np.round(r['quaternion'], 5).tolist()}")
        elif a.get("nearest"):
            n = a["nearest"]
            print(f"{a['effector']}: goal {a['goal']} not reachable: {n['strategy']}'s tree holds it but no refinement reached it; "
                  f"the nearest point a stored posture reaches is {n['point']}, {1000 * n['distance']:.1f} mm away")
        else:
            print(f"{a['effector']}: goal {a['goal']} not reachable by any strategy")
    return 0


def cmd_motion(args: argparse.Namespace) -> int:
    """The reach motion to a goal, from a posture: a summary on stdout, the frames in ``-o FILE.json``."""
    atlas, goal = _goal(args.values, args.connect is None)
    if len(goal) != 3:
        raise InputError("goal", f"a motion's goal has 3 coordinates [m], got {len(goal)}")
    start = _start(args.start)
    kind = Path(args.output).suffix.lower() if args.output else None
    if kind is not None and kind not in MOTION_FILES:
        raise InputError("-o", f"{args.output}: expected a {', '.join(MOTION_FILES)} file")
    timing = {"duration": args.duration} if args.duration is not None else None
    if args.connect:
        from reach.client import Client

        with Client(args.connect, timeout=args.timeout) as client:
            fields = {"effector": args.effector, "goal": goal, "rate": args.rate, "miss": args.miss}
            fields.update({k: v for k, v in (("from", start), ("timing", timing)) if v is not None})
            if kind in ANIMATION_FILES:
                fields["bones"] = True  # the server's body gives the skeleton
            data = {k: v for k, v in client.call("motion", **fields).items() if k not in ("ok", "id")}
        if kind in ANIMATION_FILES:
            from reach.rig import Rig

            _write_animation(args.output, kind, Rig.from_dict(data.pop("rig", None)))
    else:
        from reach.motion import Planner, Timing
        from reach.select import Selector
        from reach.store import load_atlas

        # The solvers are built (warm_up) before planning starts, so the end posture's budget is not spent on them.
        planner = Planner(Selector(load_atlas(atlas), policy=args.policy).warm_up())  # type: ignore[arg-type]
        motion = planner.plan(args.effector, goal, start, rate=args.rate, timing=Timing.from_dict(timing, "--duration"), miss=args.miss)
        data = motion.to_dict()
        if kind in ANIMATION_FILES:
            from reach.rig import rig

            _write_animation(args.output, kind, rig(motion, planner.body(motion.strategy)))
    if kind == ".json":
        Path(args.output).write_text(json.dumps(data, indent=1) + "\n")
    summary = {k: v for k, v in data.items() if k != "frames"}
    if args.json:
        _print_json(summary)
        return 0
    where = f"reaches {summary['goal']}" if summary["outcome"] == "reached" else f"goes towards {summary['goal']}, out of reach, ending at {[round(v, 4) for v in summary['point']]}"
    print(f"{summary['effector']} {where} with strategy {summary['strategy']} in {summary['duration']:.3f} s "
          f"({summary['frame_count']} frames at {args.rate:g} Hz; {summary['waypoints']} stored postures on the way, {summary['held']} frames held)")
    if summary.get("within") is not None:
        print(f"  the end posture stops {1000 * summary['within']:.1f} mm short of the goal")
    if summary["timing_tmu"]:
        print("  MTM-1: " + ", ".join(f"{k} {v:.1f} TMU" for k, v in summary["timing_tmu"].items()))
    if args.output:
        print(f"frames written to {args.output}")
    return 0


def _write_animation(path: str, kind: str, bones: Any) -> None:
    """A motion's rig (:class:`reach.rig.Rig`) as BVH or glTF."""
    if kind == ".bvh":
        from reach.bvh import write_bvh

        write_bvh(bones, path)
    else:
        from reach.gltf import write_gltf

        write_gltf(bones, path)


def _start(value: str | None) -> dict[str, float] | None:
    """--from: a JSON object of joint name -> value, or a file holding one."""
    if value is None:
        return None
    text = Path(value).read_text() if not value.lstrip().startswith("{") and Path(value).is_file() else value
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise InputError("--from", f"expected a JSON object of joint name -> value [rad or m] or a file holding one ({exc})") from exc
    if not isinstance(data, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in data.values()):
        raise InputError("--from", f"expected a JSON object of joint name -> number, got {text[:80]!r}")
    return {str(k): float(v) for k, v in data.items()}


def cmd_serve(args: argparse.Namespace) -> int:
    import logging

    from reach.server import Server

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    # One core is left to the request loop: on 2 cores the stored answers' p99 under refinement
    # load was 0.52-0.80 ms with one worker, 0.61-1.78 ms with two (bench/server.py; README, Benchmarks).
    workers = max(1, (os.cpu_count() or 1) - 1) if args.workers is None else args.workers
    if workers < 0:
        raise InputError("--workers", f"expected 0 or more worker processes, got {workers}")
    server = Server(args.atlas, args.bind, None if args.pub == "none" else args.pub, policy=args.policy,
                    refine=not args.no_refine, budget=args.budget_ms / 1000.0, curve_secret=args.curve_secret_key, workers=workers, curve_clients=args.curve_clients, chunk=args.chunk,
                    handover=_handover(args), miss=args.miss, allow_reload=args.allow_reload)
    server.handle_signals()
    print(f"serving {args.atlas} on {server.endpoint}" + (f", publishing on {server.pub_endpoint}" if server.pub_endpoint else ""), flush=True)
    server.serve_forever()
    print("server stopped", flush=True)
    return 0


def cmd_accept(args: argparse.Namespace) -> int:
    from reach.store import accept_manifest

    atlas = accept_manifest(args.atlas)
    print(f"{atlas.path}: manifest accepted as it is ({len(atlas.trees)} strategies: {', '.join(atlas.trees)})")
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    import zmq.auth

    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    for suffix in ("key", "key_secret"):
        if (folder / f"{args.name}.{suffix}").exists():
            raise InputError(str(folder / f"{args.name}.{suffix}"), "exists; choose another --name or folder (keys are never overwritten)")
    public, secret = zmq.auth.create_certificates(str(folder), args.name)
    os.chmod(secret, 0o600)
    print(f"public key: {public}\nsecret key: {secret} (keep it private; reach serve --curve-secret-key {secret})")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    import time

    from reach.store import load_atlas

    try:
        from reach.view import Viewer
    except ImportError as exc:  # viser is an extra
        raise ReachError(f"reach view needs viser: pip install 'reach[view]' ({exc})") from exc
    viewer = Viewer([load_atlas(a) for a in args.atlas], host=args.host, port=args.port, connect=args.connect,
                    spacing=args.spacing, policy=args.policy, refine=not args.no_refine)
    print(f"viewing {', '.join(args.atlas)} at {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return 0


def cmd_model(args: argparse.Namespace) -> int:
    from oracles.body import human_body, load_body
    from oracles.protocol import Described

    spec = args.spec
    strategies: dict[str, Any] = {}
    warnings: list[str] = []
    placing = {"up": args.up, "forward": args.forward, "root_position": args.root_position, "root_rpy": args.root_rpy, "package_dirs": args.package_dir}
    given = sorted(k for k, v in placing.items() if v is not None)
    if given and (spec == "human" or spec.endswith((".yaml", ".yml"))):
        raise InputError(given[0], "options for a URDF (a config gives them in its body; the generated human stands on z = 0 facing +x)")
    if spec == "human":
        body = human_body(args.sex, args.stature, args.percentile, args.mass)
    elif spec.endswith((".yaml", ".yml")):
        from reach.config import load_config, read_yaml

        config = load_config(spec)  # errors name the file and the key
        data = read_yaml(Path(spec))
        if not isinstance(data, dict) or "body" not in data:
            raise ConfigError(spec, "body", "the config names no body")
        body = load_body(data["body"])
        for s in config.strategies:
            oracle = s.oracle.create()
            if isinstance(oracle, Described):
                strategies[s.name] = oracle.describe()
        warnings = list(config.notes)
    else:
        body = load_body({"urdf": spec, **{k: v for k, v in placing.items() if v is not None}})
        warnings = list(body.notes)
    info = {**body.describe(), "world_frame": P.WORLD_AXES, "warnings": warnings, **({"strategies": strategies} if strategies else {})}
    if args.figure:
        from reach.sketch import body_figure

        body_figure(body.capsules_at(), body.furniture, Path(args.figure), Path(spec).stem if spec != "human" else "human")
        info["figure"] = args.figure
    if args.json:
        _print_json(info)
        return 0
    print(f"{body.source}: {len(info['joints'])} joints, mass {info['mass']:.2f} kg" + (f", stature {info['stature']:.4f} m" if "stature" in info else ""))
    for j in info["joints"]:
        print(f"  {j['name']:<28} " + ("continuous (-pi, pi]" if j.get("continuous") else f"[{j['lower']:+.4f}, {j['upper']:+.4f}]"))
    print(f"  centre of mass {info['center_of_mass']}")
    print(f"  {len(info['frames'])} frames at the reference posture [m]:")
    for name, pos in info["frames"].items():
        print(f"    {name:<28} {np.round(pos, 4).tolist()}")
    print(f"  {len(info['capsules'])} collision capsules [m]:")
    for c in info["capsules"]:
        print(f"    {c['name']:<20} on {c['link']:<16} radius {c['radius']:.4f} length {c['length']:.4f}")
    if "seat" in info:
        print("  seated on " + ", ".join(f"{k} {v}" for k, v in info["seat"].items()) + " [m, deg]")
        for b in info["furniture"]:
            print(f"    {b['name']:<20} min {b['min']} max {b['max']}" + (f" turned rpy {np.round(b['rpy'], 4).tolist()} [rad]" if "rpy" in b else ""))
    if args.figure:
        print(f"  wrote {args.figure}")
    for name, d in strategies.items():
        for t in d["tasks"]:
            if t.get("text"):  # the task's own line (see oracles.tasks.base.Task.describe)
                print(f"  {name}: {t['text']}")
        if "reference" in d:  # reference: auto, as found for this strategy
            print(f"  {name}: reference (auto) " + ", ".join(f"{k} {v:+.4f}" for k, v in d["reference"].items()))
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from reach.atlas import face_text
    from reach.report import markdown, report
    from reach.store import load_atlas

    atlas = load_atlas(args.atlas)
    names = atlas.select(args.strategies.split(",")) if args.strategies else None
    tables = report(atlas, args.output, args.level, names, (args.slice_z, args.slice_y))
    print(markdown(tables, str(atlas.manifest.get("name", atlas.path))))
    print("figures: " + ", ".join(tables["figures"]))
    for name, s in tables["strategies"].items():
        if s["on_faces"]:
            print(f"warning: {name}: {face_text(s['on_faces'])}", file=sys.stderr)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from reach.export import export_mesh
    from reach.store import load_atlas

    atlas = load_atlas(args.atlas)
    path = export_mesh(atlas.tree(args.strategy), args.output, args.level)
    print(f"wrote {path}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from reach.evaluate import evaluate, load_targets, text_table
    from reach.store import load_atlas

    at = None if not args.at else np.array([[x, y, z, math.radians(yaw)] for x, y, z, yaw in args.at])
    atlases = [load_atlas(a) for a in args.atlas]
    results = evaluate(atlases, load_targets(args.targets), args.effector, args.policy, refine=not args.no_refine,
                       placements=at)
    if args.figure:
        from reach.sketch import layout_figure

        layout_figure(atlases, results, Path(args.figure))
    if args.json:
        _print_json(results)
    else:
        print(text_table(results))
        if args.figure:
            print(f"wrote {args.figure}")
    return 0


def cmd_place(args: argparse.Namespace) -> int:
    """Rank placements of the body (a population of atlases) against a layout's targets; verify the best by IK."""
    from reach.evaluate import load_targets
    from reach.place import Space, heat_map, rank, verify
    from reach.store import load_atlas

    atlases = [load_atlas(a) for a in args.atlas]
    targets = load_targets(args.targets)
    weights = {}
    for item in args.weight or []:
        name, _, value = item.partition("=")
        try:
            weights[name] = float(value)
        except ValueError:
            raise InputError("--weight", f"expected STRATEGY=NUMBER, got {item!r}") from None
    space = Space(tuple(args.x), tuple(args.y), tuple(args.z), (math.radians(args.yaw[0]), math.radians(args.yaw[1])), args.step,
                  math.radians(args.yaw_step))
    ranking = rank(atlases, targets, space, args.effector, args.policy, weights)
    if args.verify:
        verify(ranking, atlases, targets, args.verify, args.effector, args.policy)
    rows = [ranking.row(k, targets) for k in range(min(args.top, len(ranking.placements)))]
    if args.figure:
        heat_map(ranking, targets, Path(args.figure))
    if args.json:
        _print_json({"candidates": len(ranking.placements), "ranked": rows, "verified": ranking.verified})
        return 0
    print(f"{len(ranking.placements)} placements of {len(atlases)} bodies against {len(targets)} targets (trees' word; best first)")
    print(f"{'rank':>4}  {'x [m]':>7} {'y [m]':>7} {'z [m]':>7} {'yaw':>6}  {'bodies':>7} {'targets':>7} {'weight':>7} {'margin':>7}")
    for r in rows:
        x, y, z = r["position"]
        margin = "" if r["margin"] is None else f"{r['margin']:>7.3f}"
        print(f"{r['rank']:>4}  {x:>7.3f} {y:>7.3f} {z:>7.3f} {r['yaw_deg']:>5.0f}°  {100 * r['accommodated']:>6.0f}% {100 * r['reached']:>6.0f}% "
              f"{r['preference']:>7.3f} {margin}")
    for v in ranking.verified:
        moved = f", the trees' rank {v['trees_rank']}" if v["trees_rank"] != v["rank"] else ""
        print(f"rank {v['rank']} verified by IK: {100 * v['reached']:.0f}% of targets reached, {100 * v['accommodated']:.0f}% of bodies accommodated "
              f"(trees: {100 * v['claimed_reached']:.0f}%{moved})")
    if args.figure:
        print(f"figure: {args.figure}")
    return 0


def cmd_audit(args: argparse.Namespace) -> int:
    from reach.audit import audit
    from reach.store import load_atlas, save_audit

    atlas = load_atlas(args.atlas)
    names = atlas.select(args.strategies.split(",")) if args.strategies else None
    # Small chunks: a few hundred probes per strategy still spread over every worker.
    factory, client, how = _executor_factory(args, chunk_size=16)
    try:
        result = audit(atlas, args.samples, args.policy, args.seed, args.restarts, names, executor_factory=factory)
    finally:
        if client is not None:
            client.close()
    try:
        saved = save_audit(atlas, result)  # reach info and reach report warn of the regions it finds missing
    except OSError as exc:
        saved = None
        print(f"warning: the audit was not kept beside the atlas ({exc})", file=sys.stderr)
    if args.json:
        _print_json(result)
        return 0
    print(f"audit of {atlas.path}: {args.samples} probes per strategy, policy {args.policy}, seed {args.seed} ({how})"
          + (f"; kept in {saved}" if saved else ""))
    print(f"{'strategy':<22} {'false reachable':>22} {'false unreachable':>22}")
    for name, r in result["strategies"].items():
        fr, fu = r["false_reachable_ci95"], r["false_unreachable_ci95"]
        print(f"{name:<22} {100 * r['false_reachable']:>6.2f} % [{100 * fr[0]:.1f}, {100 * fr[1]:.1f}]  {100 * r['false_unreachable']:>6.2f} % [{100 * fu[0]:.1f}, {100 * fu[1]:.1f}]")
    for name, r in result["strategies"].items():
        surface, rays, twins = r.get("surface", {}), r.get("rays", {}), r.get("twins")
        if surface.get("edges"):
            print(f"{name}: near the surface ({surface['probes']} probes on {surface['edges']} edges it crosses): "
                  f"just inside, false unreachable {_share(surface['inside']['false_unreachable'])}; "
                  f"just outside, false reachable {_share(surface['outside']['false_reachable'])}")
        if rays:
            print(f"{name}: along {rays['rays']} rays from {rays['centre']} to {rays['radius']} m: false unreachable "
                  f"{_share(rays['false_unreachable'])}, false reachable {_share(rays['false_reachable'])}")
            for ray in rays["short"]:
                print(f"warning: {name}: the tree stops {ray['tree_m']} m out along {ray['direction']}, the referee reaches "
                      f"{ray['referee_m']} m: a region the tree lacks (build deeper, or check the strategy's box)", file=sys.stderr)
        if twins:
            print(f"{name}: twins turned {twins['turn_deg']:.0f} deg about the free axis {twins['axis']}: the tree disagrees on "
                  f"{_share(twins['disagree'])} of pairs; of {twins['checked']} checked, the referee reaches "
                  f"{twins['unreachable_but_reached']} the tree calls unreachable")
    for name, r in result["strategies"].items():
        if "index" in r and r["index"].get("pairs"):
            i = r["index"]
            fr, fu = i["false_reached"], i["false_missed"]
            print(f"{name}: reachability index on {i['pairs']} (vertex, direction) pairs: reached but not by the referee {100 * fr['rate']:.1f} % "
                  f"[{100 * fr['ci95'][0]:.1f}, {100 * fr['ci95'][1]:.1f}] of {fr['of']}; missed but reached by the referee {100 * fu['rate']:.1f} % "
                  f"[{100 * fu['ci95'][0]:.1f}, {100 * fu['ci95'][1]:.1f}] of {fu['of']}; share {i['share_by_index']:.3f} by the index, "
                  f"{i['share_by_referee']:.3f} by the referee")
    return 0


def _share(rate: dict[str, Any]) -> str:
    """An audit's rate as ``x.x % of n``."""
    return f"{100 * rate['rate']:.1f} % of {rate['of']}"


def _add_executor_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-j", "--workers", type=int, help="worker processes (default: all cores; 1 runs inline)")
    p.add_argument("--dask", action="store_true", help="run on a Dask LocalCluster of --workers processes")
    p.add_argument("--scheduler", metavar="ADDR", help="run on the Dask cluster at ADDR, e.g. tcp://10.0.0.5:8786")


def _handover_option(p: argparse.ArgumentParser, where: str = "") -> None:
    p.add_argument("--handover-deg", type=float, default=math.degrees(HANDOVER), metavar="DEG",
                   help=f"{where}a strategy whose posture has joints within DEG of their limits hands the goal to the next that "
                        f"reaches it with fewer (default {math.degrees(HANDOVER):g}; 0: the paper's plain priority)")
    p.add_argument("--miss", choices=MISSES, default=MISS,
                   help="a goal the trees hold but no refinement reaches answers 'unreachable' with the nearest point a stored posture "
                        "reaches (default), or 'within': reachable, with the distance the posture stops short")


def _handover(args: argparse.Namespace) -> float:
    if not (math.isfinite(args.handover_deg) and args.handover_deg >= 0):
        raise InputError("--handover-deg", f"expected 0 or more degrees, got {args.handover_deg}")
    return math.radians(args.handover_deg)


def _policy_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", default=DEFAULT_POLICY, choices=POLICIES, help=f"how boundary cells answer (default: {DEFAULT_POLICY})")


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="reach",
        description="Reachable volumes as adaptive octrees (VATrees): build, inspect and query them.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("build", help="build every strategy's tree of a config", description="Build every strategy of CONFIG into an atlas folder (one tree per strategy plus manifest.json).")
    p.add_argument("config", help="YAML configuration, e.g. configs/sphere.yaml")
    p.add_argument("-o", "--output", help="output folder (default: out/<config name>)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    _add_executor_arguments(p)
    p.add_argument("--resume", action="store_true", help="keep finished trees and continue interrupted ones from their last depth")
    p.add_argument("--no-mirror", action="store_true", help="build both sides instead of mirroring 'mirror_of' strategies")
    p.add_argument("--no-inherit", action="store_true",
                   help="solve every vertex, instead of taking a sub-strategy's verified reachable vertices (the crouch the whole body's)")
    p.add_argument("--refine-centres", action="store_true", help="probe the centre of each would-be inner cell; split it if the probe fails")
    p.add_argument("--refine-faces", action="store_true", help="also probe the centres of its faces")
    p.add_argument("--retry-isolated", action="store_true", help="retry unreachable vertices whose neighbours are all reachable, from their postures")
    p.add_argument("--strict", action="store_true",
                   help="make warnings errors (exit 2): the config's (a clipped reference joint, a hard task the reference breaks, "
                        "capsules overlapping there) before building, and reachable vertices on a face of the box after (the atlas is kept)")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("info", help="summarise an atlas", description="Print node counts, volumes, extents and oracle calls of every strategy of an atlas.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser(
        "query", help="which strategy reaches a goal",
        description="Ask which strategy reaches the goal X Y [Z] (metres, atlas world frame), by priority: "
        "'reach query ATLAS X Y [Z]' reads the atlas, 'reach query --connect ADDR X Y [Z]' asks a running server.",
    )
    p.usage = "reach query [options] ATLAS X Y [Z]\n       reach query --connect ADDR [options] X Y [Z]"
    p.add_argument("values", nargs="+", metavar="ATLAS X Y [Z]", help="atlas folder (omitted with --connect) and one goal [m]")
    p.add_argument("--connect", metavar="ADDR", help=f"ask the server at ADDR (e.g. {P.DEFAULT_BIND}) instead of reading an atlas")
    p.add_argument("--effector", help="effector to ask about (default: every effector of the atlas)")
    _policy_option(p)
    p.add_argument("--refine", choices=["on", "off"], help="refine the posture by IK at the exact goal (default: on)")
    p.add_argument("--from", dest="start", metavar="POSTURE",
                   help="the character's current posture, a JSON object of joint name -> value [rad or m] (or a file holding one): "
                        "the answer is the natural posture reached from it")
    aim = p.add_mutually_exclusive_group()
    aim.add_argument("--direction", nargs=3, type=float, metavar=("X", "Y", "Z"),
                     help="hold the effector's approach axis along this world direction (strategies with an orientation task that has an axis)")
    aim.add_argument("--quaternion", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                     help="hold the effector's rotation in the world (strategies with an orientation task)")
    p.add_argument("--budget-ms", type=float, default=QUERY_BUDGET * 1000,
                   help=f"reading an atlas: time budget of the IK refinement [ms] (default {QUERY_BUDGET * 1000:g}: a one-off question "
                        f"lets it converge; a server's default is {REFINE_BUDGET * 1000:g}, a frame)")
    _handover_option(p, "reading an atlas: ")
    p.add_argument("--timeout", type=int, default=P.REQUEST_TIMEOUT_MS, help=f"with --connect: ms to wait for each reply (default {P.REQUEST_TIMEOUT_MS})")
    p.add_argument("--curve-server-key", metavar="FILE", help="with --connect: the server's CURVE public-key file")
    p.add_argument("--curve-client-key", metavar="FILE", help="with --curve-server-key: this client's secret-key file (for a server with --curve-clients)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_query)

    p = sub.add_parser(
        "motion", help="the timed reach motion to a goal",
        description="Plan the reach motion of an effector to the goal X Y Z (metres, atlas world frame) from a posture (the reference by default): "
        "the strategy chosen as a query chooses it, MTM-1 timing, minimum-jerk, collision-free frames holding feet and balance.",
    )
    p.add_argument("values", nargs="+", metavar="ATLAS X Y Z", help="atlas folder (omitted with --connect) and goal [m]")
    p.add_argument("--effector", required=True, help="the effector that reaches, e.g. right_hand")
    p.add_argument("--connect", metavar="ADDR", help="ask the server at ADDR instead of reading an atlas")
    p.add_argument("--from", dest="start", metavar="POSTURE", help="the first frame's posture: a JSON object of joint name -> value [rad or m], or a file holding one")
    p.add_argument("--rate", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--duration", type=float, help="the motion's duration [s] instead of MTM-1's")
    p.add_argument("--miss", choices=["nearest", "error"], default="nearest", help="a goal out of reach: move towards the nearest reachable point (default), or fail")
    p.add_argument("-o", "--output", metavar="FILE", help="write the frames: .json (time, posture, root, effector), .bvh (Biovision hierarchy), "
                   ".glb or .gltf (glTF 2.0: skinned capsules and their animation)")
    _policy_option(p)
    p.add_argument("--timeout", type=int, default=P.REQUEST_TIMEOUT_MS, help=f"with --connect: ms to wait for the reply (default {P.REQUEST_TIMEOUT_MS})")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_motion)

    p = sub.add_parser(
        "serve", help="answer queries over ZeroMQ",
        description="Serve an atlas: JSON requests on a ROUTER socket (REQ or DEALER clients), every choice published on a PUB socket. See docs/protocol.md.",
    )
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--bind", default=P.DEFAULT_BIND, help=f"request address (default {P.DEFAULT_BIND})")
    p.add_argument("--pub", default=P.DEFAULT_PUB, help=f"publishing address, or 'none' (default {P.DEFAULT_PUB})")
    _policy_option(p)
    p.add_argument("--no-refine", action="store_true", help="answer with stored postures; no IK refinement unless a request asks")
    p.add_argument("--budget-ms", type=float, default=REFINE_BUDGET * 1000, help=f"time budget of one IK refinement [ms] (default {REFINE_BUDGET * 1000:g})")
    p.add_argument("--curve-secret-key", metavar="FILE", help="encrypt with CURVE, using this server secret-key file (zmq.auth.create_certificates)")
    p.add_argument("--curve-clients", metavar="DIR", help="with --curve-secret-key: let in only the clients whose public-key files (*.key) are in DIR")
    p.add_argument("--workers", type=int, metavar="N", help="refinement worker processes (default: one fewer than the cores, at least 1; 0 refines in the request loop)")
    p.add_argument("--chunk", type=int, default=P.CHUNK_GOALS, metavar="N",
                   help=f"refined goals per worker task at most (default {P.CHUNK_GOALS}); within it a task is sized to about 20 ms of measured work, "
                        "so that another client's query waits about that for a busy worker")
    p.add_argument("--allow-reload", metavar="ROOT", help="let clients 'reload' atlases from folders under ROOT (default: reload is refused)")
    _handover_option(p)
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("accept", help="accept a hand-edited atlas manifest",
                       description="Stamp an atlas's manifest.json with the digest of its content as it now is, after checking that the atlas loads with it. "
                                   "A manifest edited by hand (priorities, strategies, model hashes) is refused until accepted so.")
    p.add_argument("atlas", help="atlas folder")
    p.set_defaults(func=cmd_accept)

    p = sub.add_parser("keys", help="write a CURVE key pair", description="Write a CURVE key pair (ZeroMQ certificate files NAME.key and NAME.key_secret) for 'reach serve --curve-secret-key' and its clients. See docs/protocol.md.")
    p.add_argument("folder", help="folder to write the two files into")
    p.add_argument("--name", default="server", help="base name of the files (default: server)")
    p.set_defaults(func=cmd_keys)

    p = sub.add_parser(
        "view", help="interactive 3-D view in the browser",
        description="Serve a 3-D view of one or more atlases (viser): volumes per strategy, the body, and a goal to drag whose answer "
                    "(strategy, posture) is shown. Open the printed address in a browser; the page works offline.",
    )
    p.add_argument("atlas", nargs="+", help="atlas folder(s); several stand side by side (a population study)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--connect", metavar="ADDR", help="take answers from a running 'reach serve' at ADDR, e.g. tcp://127.0.0.1:5555")
    p.add_argument("--spacing", type=float, default=1.5, help="distance between atlases along y [m] (default 1.5)")
    _policy_option(p)
    p.add_argument("--no-refine", action="store_true", help="show stored postures; no IK refinement")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("report", help="tables and figures comparing strategies", description="Write report.md, report.json and PNG figures (boxes, colours as the paper's Figure 8, overlay as Figure 11, slices) of an atlas into DIR.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the report")
    p.add_argument("--strategies", help="comma-separated strategies for the figures (default: all)")
    p.add_argument("--level", type=int, default=4, help="figure grid: 2**LEVEL cells per axis (default 4; 5 is finer and slower)")
    p.add_argument("--slice-z", type=float, metavar="Z", help="height [m] of the horizontal slice (default: the box's middle)")
    p.add_argument("--slice-y", type=float, metavar="Y", help="y [m] of the sagittal slice (default 0)")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("export", help="mesh of a strategy's volume", description="Write the surface of a strategy's reachable volume (marching cubes) as STL or PLY, in metres.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("strategy", help="strategy name")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="FILE.stl or FILE.ply")
    p.add_argument("--level", type=int, help="lattice depth to sample (default: D_max)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("evaluate", help="which strategy reaches each target, per atlas", description="For each target of a CSV (name, x, y, z [m], optional effector), which strategy each atlas chooses; several atlases give a population table.")
    p.add_argument("atlas", nargs="+", help="atlas folders")
    p.add_argument("--targets", required=True, help="CSV file with name, x, y, z[, effector]")
    p.add_argument("--effector", help="effector for targets without one")
    _policy_option(p)
    p.add_argument("--no-refine", action="store_true",
                   help="take the trees' word: no IK at the targets (a target counts as reachable when a tree holds it)")
    p.add_argument("--at", type=float, nargs=4, action="append", metavar=("X", "Y", "Z", "YAW"),
                   help="where the body's frame stands in the targets' frame: position [m] and heading [deg]; once for every atlas, or "
                        "once per atlas in order (a driver's seat slid to her heel point); default: the targets are in the body's frame")
    p.add_argument("--figure", metavar="PNG", help="per atlas, side and top views of the body, its furniture, the volumes through the right "
                                                   "shoulder and the targets coloured by the strategy that reaches them")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("place", help="where the body should stand, sit or be mounted to reach a layout's targets",
                       description="Score a grid of placements (position [m] and heading [deg] of the body's frame in the layout's frame) of one "
                       "body or a population (several atlases) against a targets CSV by the trees, rank them (bodies accommodated, targets "
                       "reached, strategies needed), and verify the best by IK.")
    p.add_argument("atlas", nargs="+", help="atlas folders (several: a population)")
    p.add_argument("--targets", required=True, help="CSV file with name, x, y, z[, effector] in the layout's frame [m]")
    p.add_argument("--effector", help="effector for targets without one")
    p.add_argument("--x", nargs=2, type=float, required=True, metavar=("MIN", "MAX"), help="range of the body's x [m]")
    p.add_argument("--y", nargs=2, type=float, required=True, metavar=("MIN", "MAX"), help="range of the body's y [m]")
    p.add_argument("--z", nargs=2, type=float, default=[0.0, 0.0], metavar=("MIN", "MAX"), help="range of its height [m] (default 0: on the floor)")
    p.add_argument("--yaw", nargs=2, type=float, default=[-180.0, 180.0], metavar=("MIN", "MAX"), help="range of its heading [deg] (default a full turn)")
    p.add_argument("--step", type=float, default=0.05, help="position step [m] (default 0.05)")
    p.add_argument("--yaw-step", type=float, default=15.0, help="heading step [deg] (default 15)")
    p.add_argument("--weight", action="append", metavar="STRATEGY=W", help="a strategy's weight (default: 1, 0.8, 0.6, ... by priority)")
    p.add_argument("--top", type=int, default=10, help="placements to print (default 10)")
    p.add_argument("--verify", type=int, default=5, help="the best placements to verify by IK (default 5; 0: none)")
    p.add_argument("--figure", metavar="PNG", help="write the floor heat map (share of targets reached per position)")
    _policy_option(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_place)

    p = sub.add_parser("audit", help="check a tree's verdicts against direct IK", description="Draw seeded random probes in the inner, boundary and outer cells of each strategy, check each by direct IK (IPOPT, extra restarts, every start tried), and report false-reachable and false-unreachable rates with 95 % confidence intervals.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--samples", type=int, default=300, help="probes per strategy, split over the three cell types (default 300)")
    p.add_argument("--strategies", help="comma-separated strategies (default: all)")
    _policy_option(p)
    p.add_argument("--restarts", type=int, default=6, help="restarts of the direct IK (default 6)")
    p.add_argument("--seed", type=int, default=0, help="seed of the probes (default 0)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    _add_executor_arguments(p)
    p.set_defaults(func=cmd_audit)

    p = sub.add_parser(
        "model", help="describe a body", description="Describe a body: its joints and ranges [rad], mass [kg], stature [m] and frame positions [m] in the reference posture (world frame: z up, x forward, y left)."
    )
    p.add_argument("spec", help="a config file (its body), a URDF file, or 'human'")
    p.add_argument("--sex", default="male", choices=["male", "female"], help="for 'human' (default male)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--percentile", type=float, help="for 'human': stature percentile of ANSUR II (default 50)")
    group.add_argument("--stature", type=float, help="for 'human': stature [m]")
    p.add_argument("--mass", type=float, help="for 'human': body mass [kg] (default: ANSUR II mean at constant BMI)")
    p.add_argument("--up", help="for a URDF: the model's own up axis (z, -z, y, -y, x, -x; default z), turned onto the world's z")
    p.add_argument("--forward", help="for a URDF: the model's own forward axis, turned onto the world's x (default x; z when up is x)")
    p.add_argument("--root-position", type=float, nargs=3, metavar=("X", "Y", "Z"), help="for a URDF: where its root link stands [m]")
    p.add_argument("--root-rpy", type=float, nargs=3, metavar=("R", "P", "Y"), help="for a URDF: a further root rotation [rad]")
    p.add_argument("--package-dir", action="append", metavar="DIR",
                   help="for a URDF: a folder holding a package its package:// meshes name (the folder above the package's); repeatable")
    p.add_argument("--figure", metavar="PNG", help="draw the reference posture and the body's furniture (a seat), side and top views")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_model)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except ReachError as exc:
        print(f"reach: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        # A build keeps its checkpoint of the last finished depth: --resume goes on from there.
        hint = "; run the same build with --resume to go on from its last finished depth" if args.func is cmd_build else ""
        if isinstance(exc, Terminated):
            print(f"reach: terminated{hint}", file=sys.stderr)
            return 143
        print(f"reach: interrupted{hint}", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``reach info ... | head``): not an error of ours.
        # Point stdout at /dev/null so that Python's exit flush does not raise again.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
