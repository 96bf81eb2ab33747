"""The paper's section 5 findings, on a coarse human atlas built here.

Built once for the module (D_max 4: 12.5-15 cm cells, two processes); each
test reads one finding off the trees.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from oracles.ik.search import Search
from reach.building.atlas import build_atlas
from reach.building.config import load_config, parse_config
from reach.building.documents import read_yaml
from reach.building.executor import ProcessExecutor
from reach.maps.tree import FINAL, INNER
from reach.tools.report import extents

pytestmark = pytest.mark.slow  # builds a human atlas (D_max 4-5) once for the module

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def atlas(tmp_path_factory):
    data = read_yaml(ROOT / "configs" / "demo.yaml")
    data["depth"] = {"min": 2, "max": 4}
    data["name"] = "findings"
    config = parse_config(data, "findings", "findings")
    return build_atlas(config, tmp_path_factory.mktemp("findings") / "atlas",
                       executor_factory=lambda s: ProcessExecutor(s, 2, 64))


def cells(tree, kinds=(INNER,)):
    """Centres [m] of the cells of the given kinds."""
    sel = np.isin(tree.kind, kinds)
    lo = tree.lattice.points(tree.corner[sel])
    return lo + 0.5 * tree.lattice.cell_size(tree.depth[sel])


def test_upper_body_reaches_higher_further_forward_and_to_the_side(atlas):
    arm, upper = extents(atlas.trees["right_arm"]), extents(atlas.trees["right_upper_body"])
    assert upper["highest"] > arm["highest"]
    assert upper["forward"] > arm["forward"]
    assert upper["right"] < arm["right"]  # further to the right (y negative)
    assert atlas.trees["right_upper_body"].volume() > atlas.trees["right_arm"].volume()


def test_whole_body_gains_lower_cells_than_the_upper_body(atlas):
    upper, whole = atlas.trees["right_upper_body"], atlas.trees["right_whole_body"]
    low = cells(whole)
    low = low[low[:, 2] < 0.6]
    gained = ~upper.contains(low, "optimistic")
    assert gained.sum() > 5, "hips should reach lower than the upper body"


def test_balance_costs_upper_front_goals():
    # The paper: controlling the centre of mass makes upper-front voxels
    # unreachable. Here the same whole-body chain with and without the balance
    # task: the upper-front goals it loses are the cost of balance. (Against
    # the upper-body strategy, whose pelvis is fixed, this model's whole body
    # loses none: its hips and ankles reach further than balance takes away;
    # see the README.)
    from oracles.ik.oracle import IKOracle

    # The whole-body chain without the idle arm, which the shipped strategy
    # frees so that it can hang: swung back, it is a counterweight that buys
    # back some of these goals.
    joints = [j for j in read_yaml(ROOT / "configs" / "demo.yaml")["strategies"][4]["joints"]
              if not j.startswith("left_")]
    planted = [{"type": "reach"}, {"type": "feet", "heels": "down"}]
    body = {"human": {"sex": "male", "percentile": 50}}
    free = IKOracle(body, "right_hand", joints, planted, search=Search(restarts=2))
    balanced = IKOracle(body, "right_hand", joints, [*planted, {"type": "balance", "margin": 0.02}],
                        search=Search(restarts=2))
    goals = np.array([[1.1, -0.2, 1.6], [1.2, -0.2, 1.4], [1.0, -0.2, 1.8]])
    assert free.evaluate(goals).reachable.all()
    assert not balanced.evaluate(goals).reachable.any()
    assert balanced.evaluate(np.array([[0.5, -0.2, 1.2]])).reachable[0]  # in front at chest height it still reaches


def test_crouch_reaches_lower_than_the_direct_strategies(atlas):
    def low_volume(tree, z=0.5):
        c = cells(tree)
        size = tree.lattice.cell_size(tree.depth[tree.kind == INNER]).prod(axis=1)
        return float(size[c[:, 2] < z].sum())

    crouch = atlas.trees["right_crouch"]
    for direct in ("right_arm", "right_upper_body", "right_whole_body"):
        assert low_volume(crouch) > low_volume(atlas.trees[direct]), direct
    assert extents(crouch)["lowest"] <= extents(atlas.trees["right_whole_body"])["lowest"]


def test_left_and_right_are_mirror_images(atlas):
    for side in ("arm", "upper_body", "whole_body", "crouch"):
        right, left = atlas.trees[f"right_{side}"], atlas.trees[f"left_{side}"]
        pts = cells(right, (INNER, FINAL))
        assert np.array_equal(right.classify(pts), left.classify(pts * [1, -1, 1])), side
        assert left.volume() == pytest.approx(right.volume())


def test_the_shipped_demo_config_is_what_was_built(atlas):
    demo = load_config(ROOT / "configs" / "demo.yaml")
    assert {s.name for s in demo.strategies} == set(atlas.trees)
