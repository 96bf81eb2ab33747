"""Accuracy: the audit against exact geometry, and refinements that close holes the vertex rule misses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from oracles.protocol import Goals, OracleSpec
from reach.answers.audit import audit_tree, referee, wilson
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.building.tree import Refine, build_tree
from reach.maps.atlas import load_atlas
from reach.maps.box import Box
from reach.maps.store import save_tree
from reach.maps.tree import FINAL, INNER, OUTER
from reach.tools.cli import main

CUBE = Box([-1, -1, -1], [1, 1, 1])
HOLE_CENTRE, HOLE_R = (0.25, 0.25, 0.25), 0.2
# A ball with a hollow smaller than a depth-2 cell (0.5 m): no vertex of the
# depth-2 lattice lies in it, so the plain rule calls its cell inner.
HOLLOW = OracleSpec("difference", {"oracles": [
    {"name": "sphere", "params": {"radius": 0.9}},
    {"name": "sphere", "params": {"center": list(HOLE_CENTRE), "radius": HOLE_R}},
]})


def hole_volume() -> float:
    return 4 / 3 * np.pi * HOLE_R**3


def test_plain_rule_misses_the_hole_and_the_audit_reports_it():
    tree = build_tree(HOLLOW, CUBE, 2, 4)
    assert tree.classify(np.array([HOLE_CENTRE]))[0] == INNER  # the vertex rule's blind spot
    result = audit_tree(tree, HOLLOW.create(), samples=3000, policy="conservative", seed=1)
    # Exact geometry: with the conservative policy the tree says yes on its
    # inner cells, and the only false yes is the hollow, wholly inside them.
    truth = hole_volume() / tree.volume(INNER)
    inner = result["by_type"]["inner"]["false_reachable"]
    assert inner["errors"] > 0
    assert inner["ci95"][0] <= truth <= inner["ci95"][1]
    # False no: the part of the ball in the cells that say no (final and outer), over their volume.
    ball = 4 / 3 * np.pi * 0.9**3
    truth_fu = (ball - tree.volume(INNER)) / (CUBE.volume - tree.volume(INNER))
    final = result["by_type"]["final"]["false_unreachable"]
    assert final["errors"] > 0
    assert abs(result["false_unreachable"] - truth_fu) < 0.03


def test_centre_probes_find_the_hole(counting):
    plain = counting(HOLLOW.create())
    refined_oracle = counting(HOLLOW.create())
    plain_tree = build_tree(plain, CUBE, 2, 4)
    tree = build_tree(refined_oracle, CUBE, 2, 4, refine=Refine(centres=True))
    assert tree.classify(np.array([HOLE_CENTRE]))[0] != INNER
    assert tree.volume(INNER) < plain_tree.volume(INNER)
    # The inner volume no longer contains the hollow: probes inside it are never inner.
    pts = np.array(HOLE_CENTRE) + np.random.default_rng(0).normal(scale=HOLE_R / 3, size=(2000, 3))
    pts = pts[np.linalg.norm(pts - HOLE_CENTRE, axis=1) < HOLE_R * 0.9]
    assert not np.any(tree.classify(pts) == INNER)
    assert refined_oracle.calls <= 1.3 * plain.calls
    assert tree.meta["build"]["refine"] == {"centres": True, "faces": False, "isolated": False}


def test_audit_rates_match_exact_geometry_for_a_ball():
    ball = OracleSpec("sphere", {"radius": 0.8})
    tree = build_tree(ball, CUBE, 2, 4)
    result = audit_tree(tree, ball.create(), samples=3000, policy="optimistic", seed=2)
    # Optimistic: inner and final cells say yes; false yes = final-cell volume outside the ball.
    truth = (tree.volume(INNER) + tree.volume(3) - 4 / 3 * np.pi * 0.8**3) / (tree.volume(INNER) + tree.volume(3))
    fr = result["counts"]["false_reachable"]
    lo, hi = wilson(fr["errors"], fr["of"])
    # The probe mix is stratified; compare the volume-weighted estimate with a generous interval.
    assert abs(result["false_reachable"] - truth) < 3 * (hi - lo)
    assert result["false_unreachable"] == 0.0  # outer cells lie wholly outside a convex ball


def test_isolated_vertices_are_retried_from_their_neighbours(tmp_path):
    # A human arm: a few unreachable vertices surrounded by reachable ones get a second chance.
    data = {
        "name": "iso", "body": {"human": {"sex": "male", "percentile": 50}},
        "box": {"min": [-0.6, -1.0, 0.5], "max": [0.9, 1.0, 2.1]}, "depth": {"min": 1, "max": 3},
        "oracle": {"name": "casadi-ik", "params": {"restarts": 0, "secondary": False}},
        "build": {"refine": {"isolated": True}},
        "strategies": [{"name": "right_arm", "effector": "right_hand",
                        "joints": ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"],
                        "tasks": [{"type": "reach"}]}],
    }
    tree = build_atlas(parse_config(data, "iso", "iso"), tmp_path / "iso").trees["right_arm"]
    b = tree.meta["build"]
    assert b["refine"]["isolated"] is True
    assert b["oracle_calls"] == b["distinct_vertices"] + sum(lv["retried"] for lv in b["levels"])
    # The audit's referee is thorough whatever built the tree: IPOPT, more restarts, every start tried.
    judge = referee(tree, 6)
    assert (judge.solver.name, judge.search.restarts, judge.search.give_up_distance) == ("ipopt", 6, np.inf)


def test_reach_audit_cli_json(tmp_path, capsys):
    data = {"name": "hollow", "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 2, "max": 4},
            "oracle": HOLLOW.to_dict(), "strategies": [{"name": "hollow", "effector": "point"}]}
    build_atlas(parse_config(data, "hollow", "hollow"), tmp_path / "a")
    assert main(["audit", str(tmp_path / "a"), "--samples", "300", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)["strategies"]["hollow"]
    assert {"false_reachable", "false_unreachable", "probes"} <= set(r) and r["probes"] == 300
    assert set(r["by_type"]) == {"inner", "final", "outer"} and r["by_depth"]
    assert main(["audit", str(tmp_path / "a"), "--samples", "60"]) == 0
    assert "false reachable" in capsys.readouterr().out


class StubbornBall:
    """A ball oracle with postures that fails one vertex the first time it is asked: an IK local minimum in
    miniature."""

    dim = 3
    posture_names = ("x",)

    def __init__(self, trap):
        self.ball = OracleSpec("sphere", {"radius": 0.9}).create()
        self.trap = np.asarray(trap)
        self.asked = 0

    def evaluate(self, goals):
        points = Goals.of(goals).points
        v = self.ball.evaluate(points)
        trapped = np.all(np.isclose(points, self.trap), axis=1)
        reach = v.reachable & ~(trapped & (self.asked == 0))
        self.asked += int(trapped.sum())
        return type(v)(reach, v.residual, points[:, :1].copy())


def test_retry_turns_an_isolated_failure_into_a_verdict():
    trap = (0.5, 0.25, 0.25)  # a depth-3 vertex inside the ball whose depth-3 neighbours are all inside
    plain = build_tree(StubbornBall(trap), CUBE, 2, 4)
    fixed = build_tree(StubbornBall(trap), CUBE, 2, 4, refine=Refine(isolated=True))
    key = plain.lattice.keys(np.rint((np.array([trap]) - CUBE.lo) / plain.lattice.resolution).astype(np.int64))
    assert plain.vertices.index(key)[0] >= 0 and fixed.vertices.index(key)[0] >= 0
    assert not plain.vertices.reachable[plain.vertices.index(key)][0]
    assert fixed.vertices.reachable[fixed.vertices.index(key)][0]
    assert sum(lv["retried"] for lv in fixed.meta["build"]["levels"]) == 1
    assert fixed.volume(INNER) > plain.volume(INNER)


TURNTABLE = Path(__file__).parent / "data" / "turntable.urdf"


def _turntable(tmp_path: Path) -> Path:
    config = {"name": "turntable", "body": {"urdf": str(TURNTABLE), "reference": {"extend": 0.1}},
              "box": {"min": [-0.7, -0.7, -0.2], "max": [0.7, 0.7, 0.9]}, "depth": {"min": 2, "max": 4},
              "oracle": {"name": "casadi-ik", "params": {"restarts": 1}},
              "strategies": [{"name": "arm", "effector": "tool", "joints": ["base_turn", "shoulder", "extend"],
                              "tasks": [{"type": "reach"}]}]}
    build_atlas(parse_config(config, "turntable", "turntable"), tmp_path / "turntable")
    return tmp_path / "turntable"


def _lacking(tree, y: float) -> None:
    """The tree made to lack the region past ``y`` [m] (cells and vertices), as a build whose starts all missed it
    would."""
    leaf = np.isin(tree.kind, [INNER, FINAL])
    centre = tree.lattice.points(tree.corner) + tree.lattice.cell_size(tree.depth) / 2
    tree.kind[leaf & (centre[:, 1] > y)] = OUTER
    tree.vertices.reachable[tree.lattice.points(tree.lattice.coords(tree.vertices.keys))[:, 1] > y] = False


@pytest.mark.slow
def test_the_audit_finds_a_region_the_tree_lacks_along_rays_and_by_twins(tmp_path, capsys):
    """A UR5's tree lacked everything above 0.888 m and its audit said 1.5 % false unreachable. A
    turntable arm (a continuous base joint) audited as built: its twins about the base agree and no ray stops short.
    The same tree made to lack the region y > 0.15 m: rays towards +y stop short of the referee (warned), twins turned
    90 deg disagree, and the referee reaches the ones the tree calls unreachable."""
    folder = _turntable(tmp_path)
    judge = referee(load_atlas(folder).trees["arm"], 2)
    assert judge.free_turn() is not None and np.allclose(judge.free_turn()[1], [0, 0, 1])
    whole = audit_tree(load_atlas(folder).trees["arm"], judge, samples=90, seed=4)
    assert whole["rays"]["short"] == [] and whole["twins"]["disagree"]["rate"] <= 0.1
    assert whole["surface"]["edges"] > 0 and whole["surface"]["probes"] == 60
    lacking = load_atlas(folder).trees["arm"]
    _lacking(lacking, 0.15)
    cut = audit_tree(lacking, judge, samples=90, seed=4)
    assert cut["rays"]["short"] and all(ray["direction"][1] > 0 for ray in cut["rays"]["short"])
    assert (cut["twins"]["disagree"]["rate"] >= 0.2
            and cut["twins"]["unreachable_but_reached"] >= cut["twins"]["checked"] // 2 > 0)
    assert main(["audit", str(folder), "--samples", "30", "--restarts", "1", "-j", "1"]) == 0
    out = capsys.readouterr().out
    assert "along 16 rays from" in out and "twins turned 90 deg about the free axis [0.0, 0.0, 1.0]" in out


def _consistent(tree) -> None:
    """Label the leaves of a tree cut by :func:`_lacking` by their vertices' verdicts, as a build would have (an
    inner cell's all reachable, an outer cell's none, a boundary cell's some), so that the atlas loads."""
    leaf = np.nonzero(np.isin(tree.kind, [INNER, FINAL, OUTER]))[0]
    for d in np.unique(tree.depth[leaf]):
        cells = leaf[tree.depth[leaf] == d]
        rows = tree.vertices.index(tree.lattice.node_vertex_keys(tree.corner[cells], int(d)))
        ok = (rows >= 0) & tree.vertices.reachable[np.maximum(rows, 0)]
        tree.kind[cells[ok.all(axis=1)]] = INNER
        tree.kind[cells[~ok.any(axis=1)]] = OUTER
        tree.kind[cells[ok.any(axis=1) & ~ok.all(axis=1)]] = FINAL


def _replace_tree(folder: Path, tree) -> None:
    """Write a tree into an atlas in place of its strategy's, the manifest naming its digest, and accept it."""
    save_tree(tree, folder / "arm.npz")
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["strategies"][0]["digest"] = tree.meta["digest"]
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main(["accept", str(folder)]) == 0


@pytest.mark.slow
def test_reach_info_and_report_warn_of_a_region_the_last_audit_found_missing(tmp_path, capsys):
    """`reach audit` keeps its result beside the atlas (audit.json, read back here with the json
    module); `reach info` and `reach report` then warn of each ray along which the tree stops short of the referee,
    while the tree is the one audited, and say the audit is stale once the tree is rebuilt."""
    folder = _turntable(tmp_path)
    whole = load_atlas(folder).trees["arm"]
    tree = load_atlas(folder).trees["arm"]
    _lacking(tree, 0.15)
    _consistent(tree)
    _replace_tree(folder, tree)
    capsys.readouterr()
    assert main(["info", str(folder)]) == 0
    assert "reach audit" not in capsys.readouterr().out  # never audited: nothing to say
    assert main(["audit", str(folder), "--samples", "30", "--restarts", "1", "-j", "1", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    kept = json.loads((folder / "audit.json").read_text())
    assert kept["result"] == printed and kept["digests"] == {"arm": load_atlas(folder).trees["arm"].meta["digest"]}
    short = printed["strategies"]["arm"]["rays"]["short"]
    assert short and all(ray["direction"][1] > 0 for ray in short)
    assert main(["info", str(folder)]) == 0
    out = capsys.readouterr().out
    assert out.count("where the referee reaches") == len(short)
    assert f"the tree stops {short[0]['tree_m']} m out along {short[0]['direction']}" in out
    assert main(["info", str(folder), "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["strategies"]["arm"]["audit_warnings"]) == len(short)
    assert main(["report", str(folder), "-o", str(tmp_path / "report")]) == 0
    assert "regions the trees lack" in capsys.readouterr().out
    _replace_tree(folder, whole)  # another build of the tree: the audit no longer speaks for it
    capsys.readouterr()
    assert main(["info", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "where the referee reaches" not in out and "is of an earlier build of this tree" in out
    (folder / "audit.json").write_text("{not json")
    assert main(["info", str(folder)]) == 0  # a broken audit file is a warning naming it, never a failed info
    assert "audit.json" in capsys.readouterr().out


def test_reach_audit_compares_each_tree_with_its_truth_suite(tmp_path, capsys):
    """``reach audit --truth``: a ball of radius 0.8 m against a suite labelled by its exact geometry, with two goals
    labelled against it: a proven goal outside the ball (the tree calls it unreachable) and an unproven one inside
    (the tree calls it reachable). The counts are the exact ones; a suite made for another body is not compared."""
    from reach.maps.truth import Suite

    data = {"name": "ball", "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 2, "max": 5},
            "oracle": {"name": "sphere", "params": {"radius": 0.8}},
            "strategies": [{"name": "ball", "effector": "point"}]}
    build_atlas(parse_config(data, "ball", "ball"), tmp_path / "a")
    rng = np.random.default_rng(3)
    goals = rng.uniform(-1, 1, (200, 3))
    r = np.linalg.norm(goals, axis=1)
    goals = goals[(r < 0.7) | (r > 0.9)]  # away from the boundary, where the tree's cells decide
    label = np.linalg.norm(goals, axis=1) < 0.8
    out, inside = int(np.argmax(~label)), int(np.argmax(label))
    label[out], label[inside] = True, False  # the two mislabelled goals
    n = len(goals)
    Suite("ball", goals, label, np.zeros((n, 1)), np.zeros(n), np.array(["box"] * n), np.array([""] * n)).save(
        tmp_path / "truth")
    hash_ = load_atlas(tmp_path / "a").trees["ball"].meta.get("model_hash")
    (tmp_path / "truth" / "provenance.json").write_text(json.dumps({"strategies": {"ball": {"body_hash": hash_}}}))
    assert main(["audit", str(tmp_path / "a"), "--samples", "30", "--truth", str(tmp_path / "truth"), "--json"]) == 0
    t = json.loads(capsys.readouterr().out)["strategies"]["ball"]["truth"]
    assert t["proven"] == int(label.sum()) and t["proven_called_unreachable"] == 1
    assert t["missed_goals"] == [np.round(goals[out], 4).tolist()] and t["reachable_unproven"] == 1
    (tmp_path / "truth" / "provenance.json").write_text(json.dumps({"strategies": {"ball": {"body_hash": "other"}}}))
    assert main(["audit", str(tmp_path / "a"), "--samples", "30", "--truth", str(tmp_path / "truth")]) == 0
    captured = capsys.readouterr()
    assert "made for another body" in captured.err and "truth suite (" not in captured.out
