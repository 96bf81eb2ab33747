"""The map behind a protocol (reach/maps/protocol.py): answers and motions ask a ReachMap, never a tree's rows.

A dense grid of IK verdicts of our own, which is no VATree, is served through the selector and the motion
planner; its answers are checked by Pinocchio's forward kinematics, independently of both.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ARM, human_config
from scipy.spatial import cKDTree

from oracles.bodies.body import human_body
from oracles.protocol import OracleSpec
from reach.answers.answer import REFINED
from reach.answers.select import Selector
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.maps.atlas import Atlas
from reach.maps.box import Box
from reach.maps.index import IndexedTree, ReachIndex
from reach.maps.protocol import ReachMap, Stored, raster
from reach.motion.planner import Planner

STRATEGY = [{"name": "right_arm", "effector": "right_hand", "joints": ARM,
             "tasks": [{"type": "reach"}, {"type": "self_collision"}, {"type": "posture"}]}]
STEP = 0.1  # [m] the grid's spacing
GRID_BOX = Box(np.array([0.0, -0.7, 0.9]), np.array([0.7, 0.1, 1.6]))  # [m] before and beside the right shoulder


class GridMap:
    """A regular grid of verdicts and postures over a box: membership is the nearest grid point's verdict."""

    def __init__(self, oracle, box: Box, step: float, meta: dict, posture_names: tuple[str, ...]) -> None:
        axes = [np.arange(lo, hi + 1e-9, step) for lo, hi in zip(box.lo, box.hi, strict=True)]
        self.points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        verdicts = oracle.evaluate(self.points)
        self.reached, self.stored_postures = verdicts.reachable, verdicts.posture
        self._box, self.step, self._meta, self._names = box, step, meta, posture_names
        self.kd = cKDTree(self.points)

    @property
    def box(self) -> Box:
        return self._box

    @property
    def dim(self) -> int:
        return 3

    @property
    def posture_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def meta(self) -> dict:
        return self._meta

    def prepare(self) -> GridMap:
        return self

    def contains(self, points: np.ndarray, policy: str = "conservative") -> np.ndarray:
        pts = np.asarray(points, float).reshape(-1, 3)
        inside = np.all((pts >= self._box.lo - 1e-9) & (pts <= self._box.hi + 1e-9), axis=1)
        _, near = self.kd.query(pts)
        return inside & self.reached[near]

    def contains_one(self, point: list[float], policy: str = "conservative") -> bool:
        return bool(self.contains(np.asarray([point]), policy)[0])

    def stored(self) -> Stored | None:
        ids = np.nonzero(self.reached)[0]
        return Stored(ids, self.points[ids], self.stored_postures[ids])

    def postures(self, ids: np.ndarray | int) -> np.ndarray:
        return self.stored_postures[ids]

    def nearest_stored(self, point: list[float]) -> int:
        _, k = self.kd.query(point)
        return int(k) if self.reached[k] else -1

    def unreached(self) -> np.ndarray:
        return self.points[~self.reached]

    def index_at(self, points: np.ndarray, held: bool = True) -> np.ndarray:
        return np.full(len(np.asarray(points).reshape(-1, 3)), np.nan)


@pytest.fixture(scope="module")
def grid_atlas(tmp_path_factory):
    """The arm's atlas (its manifest and the tree's metadata: the strategy, its oracle) with a grid as its map."""
    arm = build_atlas(parse_config(human_config(d_max=2, strategies=STRATEGY), "arm", "arm"),
                      tmp_path_factory.mktemp("grid") / "arm")
    tree = arm.trees["right_arm"]
    oracle = OracleSpec.from_dict(tree.meta["oracle"]).create()
    grid = GridMap(oracle, GRID_BOX, STEP, tree.meta, tree.vertices.posture_names)
    return Atlas(arm.path, arm.manifest, {}, maps={"right_arm": grid}), grid


def hand(body, names: tuple[str, ...], posture: np.ndarray) -> np.ndarray:
    """Pinocchio's forward kinematics of a posture given in a map's coordinate names."""
    q = body.q_ref.copy()
    for name, value in zip(names, posture, strict=True):
        if name.startswith("root_"):
            continue
        q[body.model.joints[body.joint_id(name)].idx_q] = value
    return body.frame_positions(q, ["right_hand"])["right_hand"]


def test_the_tree_and_the_grid_both_answer_the_protocol(grid_atlas, unit_sphere_tree):
    atlas, grid = grid_atlas
    assert isinstance(grid, ReachMap) and isinstance(unit_sphere_tree, ReachMap)
    indexed = IndexedTree(unit_sphere_tree, ReachIndex(np.eye(3), np.ones((len(unit_sphere_tree.vertices), 3), bool)))
    assert isinstance(indexed, ReachMap)
    # The tree without an index says NaN; with one, the share of directions reached at its nearest reachable vertex.
    assert np.isnan(unit_sphere_tree.index_at(np.zeros((1, 3)))).all()
    assert indexed.index_at(np.zeros((1, 3))).tolist() == [1.0]
    # raster asks membership alone: the grid's reachable cells at level 3 hold the reachable grid points' share.
    occupied, edges = raster(grid, 3)
    assert occupied.shape == (8, 8, 8) and len(edges) == 3 and 0 < occupied.mean() < 1
    assert 20 < grid.reached.sum() < len(grid.reached)


def test_the_selector_answers_from_a_grid_map_and_refines_at_the_goal(grid_atlas):
    atlas, grid = grid_atlas
    body = human_body()
    selector = Selector(atlas, budget=0.5)
    inside = grid.points[grid.reached]
    # Near the middle of the reached grid points, off the grid: its nearest grid point is reached.
    goal = inside[np.argmin(np.linalg.norm(inside - inside.mean(axis=0), axis=1))] + np.array([0.02, -0.02, 0.01])
    answer = selector.select("right_hand", goal)
    assert answer.reachable and answer.strategy == "right_arm" and answer.refined == REFINED
    q = np.array([answer.posture.get(n, 0.0) for n in grid.posture_names])
    assert np.linalg.norm(hand(body, grid.posture_names, q) - goal) < 0.005
    far = selector.select("right_hand", np.array([2.0, 2.0, 3.0]))
    assert not far.reachable and far.strategy is None


def test_the_planner_routes_over_a_grid_maps_stored_postures(grid_atlas):
    atlas, grid = grid_atlas
    body = human_body()
    planner = Planner(Selector(atlas, budget=0.5))
    inside = grid.points[grid.reached]
    goal = inside[np.argmax(inside[:, 2])]  # the highest reachable grid point: the hand lifts from hanging
    motion = planner.plan("right_hand", goal)
    assert motion.strategy == "right_arm" and motion.outcome == "reached"
    names = motion.names
    last = motion.postures[-1]
    q = body.q_ref.copy()
    for name, value in zip(names, last, strict=True):
        if not name.startswith("root_"):
            q[body.model.joints[body.joint_id(name)].idx_q] = value
    assert np.linalg.norm(body.frame_positions(q, ["right_hand"])["right_hand"] - goal) < 0.005
    assert np.allclose(motion.path[-1], body.frame_positions(q, ["right_hand"])["right_hand"], atol=1e-6)
