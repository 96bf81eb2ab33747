"""Inspecting atlases: info, report, export, audit."""



from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from reach.tools.commands.common import (
    add_executor_arguments,
    executor_factory,
    policy_option,
    print_json,
)


def _share(rate: dict[str, Any]) -> str:
    """An audit's rate as ``x.x % of n``."""
    return f"{100 * rate['rate']:.1f} % of {rate['of']}"


def cmd_info(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.audit import summary
    from reach.building.atlas import face_text
    from reach.maps.atlas import load_atlas

    info = summary(load_atlas(args.atlas))
    if args.json:
        print_json(info)
        return 0
    print(f"atlas {info['name']} at {info['path']}")
    for name, s in info["strategies"].items():
        _print_strategy(name, s, face_text)
    for note in info.get("config_warnings", []):
        print(f"  warning (config): {note}")
    for note in info.get("audit_warnings", []):
        print(f"  warning (audit): {note}")
    return 0


def _print_strategy(name: str, s: dict[str, Any], face_text: Any) -> None:
    """One strategy's lines of ``reach info``."""
    ext = s["extent"]
    print(
        f"  {name} (effector {s['effector']}, priority {s['priority']}): "
        f"inner volume {s['volume']['inner']:.6g}, boundary {s['volume']['boundary']:.6g}, "
        + (f"mirrored from {s['mirrored_from']} (no oracle call)" if s["mirrored_from"]
           else f"{s['oracle_calls']} oracle calls of {s['lattice_vertices']} lattice vertices")
        + (f", {s['inherited_vertices']} reachable vertices inherited from {s['inherited_from']}"
           if s.get("inherited_from") else "")
        + (f", {s['turned_vertices']} vertices given their twin's verdict a quarter turn away"
           if s.get("turned_vertices") else "")
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
    g = s.get("motion_graph")
    if g is not None:
        print(f"    motion graph: {g['reached_from_reference']} of {g['stored']} stored postures reached from the "
              f"reference, {g['edges']} motions between them" if g["state"] == "ok" else
              f"    motion graph: {g['state']} (reach build --resume makes it; motions are planned without it)")
    if s["on_faces"]:
        print(f"    warning: {face_text(s['on_faces'])}")
    for line in s.get("audit_warnings", []):
        print(f"    warning: {line}")


def add_info(sub: Any) -> None:
    """Register ``reach info``."""
    p = sub.add_parser("info", help="summarise an atlas", description="Print node counts, volumes, extents and "
        "oracle calls of every strategy of an atlas.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_info)


def cmd_report(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.building.atlas import face_text
    from reach.building.population import is_population
    from reach.maps.atlas import load_atlas
    from reach.tools.report import markdown, report

    if is_population(args.atlas):
        from reach.tools import accommodation_report

        table = accommodation_report.report(args.atlas, args.output, args.level, args.slice_z,
                                            0.0 if args.slice_y is None else args.slice_y)
        print(accommodation_report.markdown(table, args.atlas))
        print("figures: " + ", ".join(table["figures"]))
        return 0
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
    p.add_argument("atlas", help="atlas folder written by 'reach build'; or a population folder: its accommodation "
                                 "volume (per point, the share of members whose tree holds it), tables, slices and "
                                 "isosurfaces at 5 / 50 / 95 %%")
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
    from reach.maps.atlas import load_atlas
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
    from reach.maps.atlas import load_atlas, save_audit

    atlas = load_atlas(args.atlas)
    names = atlas.select(args.strategies.split(",")) if args.strategies else None
    # Small chunks: a few hundred probes per strategy still spread over every worker.
    factory, client, how = executor_factory(args, chunk_size=16)
    try:
        result = audit(atlas, args.samples, args.policy, args.seed, args.restarts, names, executor_factory=factory)
    finally:
        if client is not None:
            client.close()
    if args.truth:
        _against_truth(atlas, Path(args.truth), args.policy, result)
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
        _print_audit_details(name, r)
    return 0


def _print_audit_details(name: str, r: dict[str, Any]) -> None:
    """One strategy's audit beyond its rates: near the surface, along rays, twins, the truth suite, the index."""
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
    if "truth" in r:
        t = r["truth"]
        print(f"{name}: against the truth suite ({t['goals']} goals, {t['proven']} proven reachable): "
              f"{t['proven_called_unreachable']} proven goals called unreachable ({100 * t['rate']:.1f} %)"
              + (f", e.g. {t['missed_goals']}" if t["missed_goals"] else "")
              + f"; {t['reachable_unproven']} called reachable that the referee did not reach")
    if "index" in r and r["index"].get("pairs"):
        i = r["index"]
        fr, fu = i["false_reached"], i["false_missed"]
        print(f"{name}: reachability index on {i['pairs']} (vertex, direction) pairs: reached but not by the "
              f"referee {100 * fr['rate']:.1f} % [{100 * fr['ci95'][0]:.1f}, {100 * fr['ci95'][1]:.1f}] of "
              f"{fr['of']}; missed but reached by the referee {100 * fu['rate']:.1f} % "
              f"[{100 * fu['ci95'][0]:.1f}, {100 * fu['ci95'][1]:.1f}] of {fu['of']}; share "
              f"{i['share_by_index']:.3f} by the index, {i['share_by_referee']:.3f} by the referee")


def _against_truth(atlas: Any, folder: Path, policy: str, result: dict[str, Any]) -> None:
    """Each audited strategy against its truth suite in folder (``reach.maps.truth``), when the suite has one made
    for the tree's body; kept in the result as ``truth``."""
    from reach.maps.truth import compare, load_suite, provenance

    made = provenance(folder)["strategies"]
    for name, r in result["strategies"].items():
        if name not in made:
            continue
        tree = atlas.trees[name]
        body, ours = made[name].get("body_hash"), tree.meta.get("model_hash")
        if body != ours:
            print(f"warning: {name}: the truth suite in {folder} was made for another body (hash {body}, the "
                  f"tree's {ours}): not compared", file=sys.stderr)
            continue
        r["truth"] = {"folder": str(folder), **compare(tree, load_suite(name, folder), policy)}  # type: ignore[arg-type]


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
    p.add_argument("--truth", metavar="FOLDER", help="also compare each strategy with its truth suite in FOLDER "
                   "(the repository's: tests/data/truth; made by bench/truth.py): proven goals the tree calls "
                   "unreachable, and goals it calls reachable that the referee did not reach")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_audit)


# Each registers its command's subparser.
COMMANDS = (add_info, add_report, add_export, add_audit)
