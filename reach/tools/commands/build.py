"""Building and inspecting atlases: build, info, report, export, audit, accept, model."""


from __future__ import annotations

import argparse
import dataclasses
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from reach.errors import ConfigError, InputError, TreeError
from reach.serving import protocol as P
from reach.tools.commands.common import on_terminate, policy_option, print_json


def _executor_factory(args: argparse.Namespace, chunk_size: int) -> tuple[Any, Any, str]:
    """The executor factory the build options ask for, the Dask client if any, and a description."""

    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.build.executor import DaskExecutor, InlineExecutor, ProcessExecutor

    workers = args.workers or os.cpu_count() or 1
    if args.scheduler or args.dask:
        # Dask only when a build runs on it
        from distributed import Client, LocalCluster

        if args.scheduler:
            client = Client(args.scheduler)
            how = f"Dask scheduler {args.scheduler}"
        else:
            client = Client(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                         dashboard_address=None))
            how = f"Dask LocalCluster, {workers} workers"
        return (lambda spec: DaskExecutor(spec, client, chunk_size)), client, how
    if workers == 1:
        return (lambda spec: InlineExecutor(spec, chunk_size)), None, "inline"
    return (lambda spec: ProcessExecutor(spec, workers, chunk_size)), None, f"{workers} processes"


def _share(rate: dict[str, Any]) -> str:
    """An audit's rate as ``x.x % of n``."""
    return f"{100 * rate['rate']:.1f} % of {rate['of']}"


def _add_executor_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-j", "--workers", type=int, help="worker processes (default: all cores; 1 runs inline)")
    p.add_argument("--dask", action="store_true", help="run on a Dask LocalCluster of --workers processes")
    p.add_argument("--scheduler", metavar="ADDR", help="run on the Dask cluster at ADDR, e.g. tcp://10.0.0.5:8786")


def cmd_build(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.build.atlas import build_atlas
    from reach.build.config import load_config

    config = load_config(args.config)
    for note in config.notes:
        print(f"warning: {config.source}: {note}", file=sys.stderr, flush=True)
    if args.strict and config.notes:
        raise ConfigError(config.source, "", f"{len(config.notes)} warning(s) above, and --strict makes them errors")
    if args.refine_centres or args.refine_faces or args.retry_isolated:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.build.tree import Refine

        r = config.refine
        config = dataclasses.replace(config,
                                     refine=Refine(r.centres or args.refine_centres, r.faces or args.refine_faces,
                                                   r.isolated or args.retry_isolated))
    out = Path(args.output) if args.output else Path("out") / config.name
    factory, client, how = _executor_factory(args, config.chunk_size)

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_terminate)  # as Ctrl-C: the checkpoints stay, a message, status 143
    print(f"building {len(config.strategies)} strateg{'y' if len(config.strategies) == 1 else 'ies'} of "
          f"{config.source} into {out} ({how})", flush=True)
    try:
        atlas = build_atlas(config, out, executor_factory=factory, progress=not args.quiet,
                            log=lambda line: print(line, flush=True),
                    resume=args.resume, mirror=not args.no_mirror,
                    inherit=not args.no_inherit)
    finally:
        if client is not None:
            client.close()
    print(f"atlas written to {out}")
    cut = [w["strategy"] for w in atlas.manifest.get("warnings", {}).get("faces", [])]
    if args.strict and cut:
        raise TreeError(f"the box cuts the volume of {', '.join(cut)} (warnings above), and --strict makes that an "
                        "error; the atlas is kept")
    return 0


def add_build(sub: Any) -> None:
    """Register ``reach build``."""
    p = sub.add_parser("build", help="build every strategy's tree of a config", description="Build every strategy of "
        "CONFIG into an atlas folder (one tree per strategy plus manifest.json).")
    p.add_argument("config", help="YAML configuration, e.g. configs/sphere.yaml")
    p.add_argument("-o", "--output", help="output folder (default: out/<config name>)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    _add_executor_arguments(p)
    p.add_argument("--resume", action="store_true", help="keep finished trees and continue interrupted ones from "
                                                         "their last depth")
    p.add_argument("--no-mirror", action="store_true", help="build both sides instead of mirroring 'mirror_of' "
                                                            "strategies")
    p.add_argument("--no-inherit", action="store_true",
                   help="solve every vertex, instead of taking a sub-strategy's verified reachable vertices (the "
                        "crouch the whole body's)")
    p.add_argument("--refine-centres", action="store_true", help="probe the centre of each would-be inner cell; "
        "split it if the probe fails")
    p.add_argument("--refine-faces", action="store_true", help="also probe the centres of its faces")
    p.add_argument("--retry-isolated", action="store_true", help="retry unreachable vertices whose neighbours are "
        "all reachable, from their postures")
    p.add_argument("--strict", action="store_true",
                   help="make warnings errors (exit 2): the config's (a clipped reference joint, a hard task the "
                        "reference breaks, capsules overlapping there) before building, and reachable vertices on a "
                        "face of the box after (the atlas is kept)")
    p.set_defaults(func=cmd_build)


def cmd_info(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.audit import summary
    from reach.build.atlas import face_text
    from reach.maps.store import load_atlas

    info = summary(load_atlas(args.atlas))
    if args.json:
        print_json(info)
        return 0
    print(f"atlas {info['name']} at {info['path']}")
    for name, s in info["strategies"].items():
        ext = s["extent"]
        print(
            f"  {name} (effector {s['effector']}, priority {s['priority']}): "
            f"inner volume {s['volume']['inner']:.6g}, boundary {s['volume']['boundary']:.6g}, "
            + (f"mirrored from {s['mirrored_from']} (no oracle call)" if s["mirrored_from"]
               else f"{s['oracle_calls']} oracle calls of {s['lattice_vertices']} lattice vertices")
            + (f", {s['inherited_vertices']} reachable vertices inherited from {s['inherited_from']}"
               if s.get("inherited_from") else "")
        )
        if ext:
            print(f"    inner and boundary cells span min {np.round(ext['min'], 4).tolist()} max "
                  f"{np.round(ext['max'], 4).tolist()} [m]")
        if s["reachable_extent"]:
            r = s["reachable_extent"]
            print(f"    reachable vertices span min {np.round(r['min'], 4).tolist()} max "
                  f"{np.round(r['max'], 4).tolist()} [m]")
        if s.get("index"):
            i = s["index"]
            print(f"    reachability index over {i['directions']} directions: mean {i['mean']:.3f}, quartiles "
                  f"{i['quartiles']} at reachable vertices"
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


def add_info(sub: Any) -> None:
    """Register ``reach info``."""
    p = sub.add_parser("info", help="summarise an atlas", description="Print node counts, volumes, extents and "
        "oracle calls of every strategy of an atlas.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_info)


def cmd_report(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.build.atlas import face_text
    from reach.maps.store import load_atlas
    from reach.tools.report import markdown, report

    atlas = load_atlas(args.atlas)
    names = atlas.select(args.strategies.split(",")) if args.strategies else None
    tables = report(atlas, args.output, args.level, names, (args.slice_z, args.slice_y))
    print(markdown(tables, str(atlas.manifest.get("name", atlas.path))))
    print("figures: " + ", ".join(tables["figures"]))
    for name, s in tables["strategies"].items():
        if s["on_faces"]:
            print(f"warning: {name}: {face_text(s['on_faces'])}", file=sys.stderr)
    return 0


def add_report(sub: Any) -> None:
    """Register ``reach report``."""
    p = sub.add_parser("report", help="tables and figures comparing strategies", description="Write report.md, "
        "report.json and PNG figures (boxes, colours as the paper's Figure 8, overlay as Figure 11, slices) of an "
        "atlas into DIR.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the report")
    p.add_argument("--strategies", help="comma-separated strategies for the figures (default: all)")
    p.add_argument("--level", type=int, default=4, help="figure grid: 2**LEVEL cells per axis (default 4; 5 is finer "
                                                        "and slower)")
    p.add_argument("--slice-z", type=float, metavar="Z", help="height [m] of the horizontal slice (default: the "
                                                              "box's middle)")
    p.add_argument("--slice-y", type=float, metavar="Y", help="y [m] of the sagittal slice (default 0)")
    p.set_defaults(func=cmd_report)


def cmd_export(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.maps.store import load_atlas
    from reach.tools.export import export_mesh

    atlas = load_atlas(args.atlas)
    path = export_mesh(atlas.tree(args.strategy), args.output, args.level)
    print(f"wrote {path}")
    return 0


def add_export(sub: Any) -> None:
    """Register ``reach export``."""
    p = sub.add_parser("export", help="mesh of a strategy's volume", description="Write the surface of a strategy's "
        "reachable volume (marching cubes) as STL or PLY, in metres.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("strategy", help="strategy name")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="FILE.stl or FILE.ply")
    p.add_argument("--level", type=int, help="lattice depth to sample (default: D_max)")
    p.set_defaults(func=cmd_export)


def cmd_audit(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.audit import audit
    from reach.maps.store import load_atlas, save_audit

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
        print_json(result)
        return 0
    print(f"audit of {atlas.path}: {args.samples} probes per strategy, policy {args.policy}, seed {args.seed} ({how})"
          + (f"; kept in {saved}" if saved else ""))
    print(f"{'strategy':<22} {'false reachable':>22} {'false unreachable':>22}")
    for name, r in result["strategies"].items():
        fr, fu = r["false_reachable_ci95"], r["false_unreachable_ci95"]
        print(f"{name:<22} {100 * r['false_reachable']:>6.2f} % [{100 * fr[0]:.1f}, {100 * fr[1]:.1f}]  "
              f"{100 * r['false_unreachable']:>6.2f} % [{100 * fu[0]:.1f}, {100 * fu[1]:.1f}]")
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
                print(f"warning: {name}: the tree stops {ray['tree_m']} m out along {ray['direction']}, the referee "
                      f"reaches {ray['referee_m']} m: a region the tree lacks (build deeper, or check the strategy's "
                      "box)", file=sys.stderr)
        if twins:
            print(f"{name}: twins turned {twins['turn_deg']:.0f} deg about the free axis {twins['axis']}: the tree "
                  f"disagrees on {_share(twins['disagree'])} of pairs; of {twins['checked']} checked, the referee "
                  f"reaches {twins['unreachable_but_reached']} the tree calls unreachable")
    for name, r in result["strategies"].items():
        if "index" in r and r["index"].get("pairs"):
            i = r["index"]
            fr, fu = i["false_reached"], i["false_missed"]
            print(f"{name}: reachability index on {i['pairs']} (vertex, direction) pairs: reached but not by the "
                  f"referee {100 * fr['rate']:.1f} % [{100 * fr['ci95'][0]:.1f}, {100 * fr['ci95'][1]:.1f}] of "
                  f"{fr['of']}; missed but reached by the referee {100 * fu['rate']:.1f} % "
                  f"[{100 * fu['ci95'][0]:.1f}, {100 * fu['ci95'][1]:.1f}] of {fu['of']}; share "
                  f"{i['share_by_index']:.3f} by the index, {i['share_by_referee']:.3f} by the referee")
    return 0


def add_audit(sub: Any) -> None:
    """Register ``reach audit``."""
    p = sub.add_parser("audit", help="check a tree's verdicts against direct IK", description="Draw seeded random "
        "probes in the inner, boundary and outer cells of each strategy, check each by direct IK (IPOPT, extra "
        "restarts, every start tried), and report false-reachable and false-unreachable rates with 95 % confidence "
        "intervals.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--samples", type=int, default=300, help="probes per strategy, split over the three cell types "
                                                            "(default 300)")
    p.add_argument("--strategies", help="comma-separated strategies (default: all)")
    policy_option(p)
    p.add_argument("--restarts", type=int, default=6, help="restarts of the direct IK (default 6)")
    p.add_argument("--seed", type=int, default=0, help="seed of the probes (default 0)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    _add_executor_arguments(p)
    p.set_defaults(func=cmd_audit)


def cmd_accept(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.maps.store import accept_manifest

    atlas = accept_manifest(args.atlas)
    print(f"{atlas.path}: manifest accepted as it is ({len(atlas.trees)} strategies: {', '.join(atlas.trees)})")
    return 0


def add_accept(sub: Any) -> None:
    """Register ``reach accept``."""
    p = sub.add_parser("accept", help="accept a hand-edited atlas manifest",
                       description="Stamp an atlas's manifest.json with the digest of its content as it now is, "
                                   "after checking that the atlas loads with it. A manifest edited by hand "
                                   "(priorities, strategies, model hashes) is refused until accepted so.")
    p.add_argument("atlas", help="atlas folder")
    p.set_defaults(func=cmd_accept)


def cmd_model(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from oracles.bodies.body import human_body, load_body
    from oracles.protocol import Described

    spec = args.spec
    strategies: dict[str, Any] = {}
    warnings: list[str] = []
    placing = {"up": args.up, "forward": args.forward, "root_position": args.root_position, "root_rpy": args.root_rpy,
               "package_dirs": args.package_dir}
    given = sorted(k for k, v in placing.items() if v is not None)
    if given and (spec == "human" or spec.endswith((".yaml", ".yml"))):
        raise InputError(given[0], "options for a URDF (a config gives them in its body; the generated human stands "
                                   "on z = 0 facing +x)")
    if spec == "human":
        body = human_body(args.sex, args.stature, args.percentile, args.mass)
    elif spec.endswith((".yaml", ".yml")):
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.build.config import load_config, read_yaml

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
    info = {**body.describe(), "world_frame": P.WORLD_AXES, "warnings": warnings,
            **({"strategies": strategies} if strategies else {})}
    if args.figure:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.tools.sketch import body_figure

        body_figure(body.capsules_at(), body.furniture, Path(args.figure), Path(spec).stem if spec != "human"
                    else "human")
        info["figure"] = args.figure
    if args.json:
        print_json(info)
        return 0
    print(f"{body.source}: {len(info['joints'])} joints, mass {info['mass']:.2f} kg" + (", stature "
        f"{info['stature']:.4f} m" if "stature" in info else ""))
    for j in info["joints"]:
        print(f"  {j['name']:<28} " + ("continuous (-pi, pi]" if j.get("continuous") else f"[{j['lower']:+.4f}, "
            f"{j['upper']:+.4f}]"))
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
            print(f"    {b['name']:<20} min {b['min']} max {b['max']}" + (" turned rpy "
                f"{np.round(b['rpy'], 4).tolist()} [rad]" if "rpy" in b else ""))
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


def add_model(sub: Any) -> None:
    """Register ``reach model``."""
    p = sub.add_parser(
        "model", help="describe a body", description="Describe a body: its joints and ranges [rad], mass [kg], "
                                                     "stature [m] and frame positions [m] in the reference posture "
                                                     "(world frame: z up, x forward, y left)."
    )
    p.add_argument("spec", help="a config file (its body), a URDF file, or 'human'")
    p.add_argument("--sex", default="male", choices=["male", "female"], help="for 'human' (default male)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--percentile", type=float, help="for 'human': stature percentile of ANSUR II (default 50)")
    group.add_argument("--stature", type=float, help="for 'human': stature [m]")
    p.add_argument("--mass", type=float, help="for 'human': body mass [kg] (default: ANSUR II mean at constant BMI)")
    p.add_argument("--up", help="for a URDF: the model's own up axis (z, -z, y, -y, x, -x; default z), turned onto "
                                "the world's z")
    p.add_argument("--forward", help="for a URDF: the model's own forward axis, turned onto the world's x (default "
                                     "x; z when up is x)")
    p.add_argument("--root-position", type=float, nargs=3, metavar=("X", "Y", "Z"), help="for a URDF: where its root "
        "link stands [m]")
    p.add_argument("--root-rpy", type=float, nargs=3, metavar=("R", "P", "Y"), help="for a URDF: a further root "
        "rotation [rad]")
    p.add_argument("--package-dir", action="append", metavar="DIR",
                   help="for a URDF: a folder holding a package its package:// meshes name (the folder above the "
                        "package's); repeatable")
    p.add_argument("--figure", metavar="PNG", help="draw the reference posture and the body's furniture (a seat), "
                                                   "side and top views")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_model)


# Each registers its command's subparser.
COMMANDS = (add_build, add_info, add_report, add_export, add_audit, add_accept, add_model)
