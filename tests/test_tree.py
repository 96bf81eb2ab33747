"""The VATree: the paper's worked example, analytic volumes, queries and booleans."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.shapes import Ball, Torus, circle, sphere
from reach.building.tree import build_tree
from reach.errors import TreeError
from reach.maps import boolean
from reach.maps.box import Box
from reach.maps.tree import FINAL, INNER, OUTER, PARENT

SQUARE = Box([-1.0, -1.0], [1.0, 1.0])
CUBE = Box([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])


@pytest.mark.parametrize("d_max", [4, 5, 6, 7])
def test_sphere_volume_is_bracketed(d_max):
    tree = build_tree(sphere(radius=1.0), CUBE, 2, d_max)
    true = 4.0 / 3.0 * np.pi
    assert tree.volume(INNER) <= true <= tree.volume(INNER) + tree.volume(FINAL)


def test_sphere_volume_converges_as_dmax_grows():
    true = 4.0 / 3.0 * np.pi
    gaps, errors = [], []
    for d_max in (4, 5, 6, 7):
        tree = build_tree(sphere(radius=1.0), CUBE, 2, d_max)
        gaps.append(tree.volume(FINAL))
        errors.append(true - tree.volume(INNER))
    assert all(b < a for a, b in zip(gaps, gaps[1:], strict=False))
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False))
    # The boundary shell halves with each depth (surface x cell edge).
    assert 0.4 < gaps[-1] / gaps[-2] < 0.6
    assert errors[-1] / true < 0.05


def test_circle_area_is_bracketed_in_2d():
    tree = build_tree(circle(center=(0.2, 0.1), radius=0.7), SQUARE, 1, 8)
    true = np.pi * 0.7**2
    assert tree.volume(INNER) <= true <= tree.volume(INNER) + tree.volume(FINAL)
    assert tree.volume(FINAL) < 0.05 * true


def test_torus_volume_is_bracketed():
    torus = Torus(major=0.6, minor=0.25)
    tree = build_tree(torus, Box([-0.9, -0.9, -0.3], [0.9, 0.9, 0.3]), 2, 6)
    assert tree.volume(INNER) <= torus.volume <= tree.volume(INNER) + tree.volume(FINAL)


def test_classify_points_outside_the_box_are_outer(unit_sphere_tree):
    pts = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, -1.0001, 0.0], [np.nan, 0, 0]])
    assert unit_sphere_tree.classify(pts).tolist() == [INNER, OUTER, OUTER, OUTER]


def test_classify_point_on_the_upper_face_is_in_the_last_cell():
    tree = build_tree(Ball([1.0, 1.0], 0.5), SQUARE, 1, 4)
    assert tree.classify(np.array([[1.0, 1.0]]))[0] == INNER


def test_classify_never_returns_parent_and_matches_truth_off_the_boundary(unit_sphere_tree):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1.2, 1.2, size=(100_000, 3))
    kinds = unit_sphere_tree.classify(pts)
    assert not np.any(kinds == PARENT)
    r = np.linalg.norm(pts, axis=1)
    assert np.all(r[kinds == INNER] <= 1.0)
    assert np.all(r[kinds == OUTER] > 1.0 - 1e-12)


def test_classify_agrees_with_a_plain_descent(unit_sphere_tree):
    # The dense lookup table is an optimisation: a naive per-point walk is the truth.
    tree = unit_sphere_tree
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1, 1, size=(300, 3))
    cells, _ = tree.lattice.cell_of(pts)
    expected = []
    for c in cells:
        node, depth = 0, 0
        while tree.kind[node] == PARENT:
            bits = sum(((int(c[i]) >> (tree.d_max - depth - 1)) & 1) << i for i in range(3))
            node, depth = int(tree.child[node]) + bits, depth + 1
        expected.append(node)
    assert tree.locator.locate(pts).tolist() == expected


def test_contains_policies_are_nested_and_vertex_is_most_accurate(unit_sphere_tree):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1.1, 1.1, size=(200_000, 3))
    cons = unit_sphere_tree.contains(pts, "conservative")
    opt = unit_sphere_tree.contains(pts, "optimistic")
    vert = unit_sphere_tree.contains(pts, "vertex")
    assert np.all(cons <= vert) and np.all(vert <= opt)
    truth = np.linalg.norm(pts, axis=1) <= 1.0
    assert np.all(truth <= opt) and np.all(cons <= truth)
    assert np.mean(vert != truth) < min(np.mean(cons != truth), np.mean(opt != truth))


def test_contains_rejects_unknown_policy_and_bad_shapes(unit_sphere_tree):
    with pytest.raises(TreeError, match="unknown policy 'maybe'"):
        unit_sphere_tree.contains(np.zeros((1, 3)), "maybe")  # type: ignore[arg-type]
    with pytest.raises(TreeError, match=r"shape \(N, 3\)"):
        unit_sphere_tree.classify(np.zeros((4, 2)))


def test_extent_bounds_the_inner_and_final_cells():
    tree = build_tree(sphere(center=(0.2, 0.0, -0.1), radius=0.5), CUBE, 2, 6)
    lo, hi = tree.extent()
    res = tree.lattice.resolution
    assert np.all(lo <= np.array([-0.3, -0.5, -0.6]) + 1e-12) and np.all(lo >= np.array([-0.3, -0.5, -0.6]) - res)
    assert np.all(hi >= np.array([0.7, 0.5, 0.4]) - 1e-12) and np.all(hi <= np.array([0.7, 0.5, 0.4]) + res)


def _lens(r: float, d: float) -> float:
    return np.pi * (4 * r + d) * (2 * r - d) ** 2 / 12.0


@pytest.fixture(scope="module")
def two_balls():
    a = build_tree(sphere(center=(-0.25, 0, 0), radius=0.6), CUBE, 2, 6)
    b = build_tree(sphere(center=(0.25, 0, 0), radius=0.6), CUBE, 2, 6)
    return a, b


def test_booleans_bracket_analytic_volumes(two_balls):
    a, b = two_balls
    ball, lens = 4 / 3 * np.pi * 0.6**3, _lens(0.6, 0.5)
    truth = {"intersection": lens, "union": 2 * ball - lens, "difference": ball - lens}
    for mode, true in truth.items():
        t = getattr(boolean, mode)(a, b)
        assert t.volume(INNER) <= true <= t.volume(INNER) + t.volume(FINAL), mode


def test_booleans_agree_pointwise_with_their_operands(two_balls):
    a, b = two_balls
    pts = np.random.default_rng(4).uniform(-1, 1, size=(50_000, 3))
    ka, kb = a.classify(pts), b.classify(pts)
    assert np.array_equal(boolean.intersection(a, b).classify(pts) == INNER, (ka == INNER) & (kb == INNER))
    assert np.array_equal(boolean.union(a, b).classify(pts) == OUTER, (ka == OUTER) & (kb == OUTER))
    assert np.array_equal(boolean.difference(a, b).classify(pts) == INNER, (ka == INNER) & (kb == OUTER))
    either = a.contains(pts, "vertex") | b.contains(pts, "vertex")
    assert np.array_equal(boolean.union(a, b).contains(pts, "vertex"), either)


def test_booleans_refuse_different_lattices(two_balls):
    a, _ = two_balls
    other = build_tree(sphere(radius=0.5), CUBE, 2, 5)
    with pytest.raises(TreeError, match="same B0 and D_max"):
        boolean.union(a, other)


def test_box_validation():
    with pytest.raises(TreeError, match="empty"):
        Box([0, 0, 0], [1, 0, 1])
    with pytest.raises(TreeError, match="2 or 3 coordinates"):
        Box([0, 0, 0], [1, 1])


def test_single_point_path_agrees_with_the_batch_path(unit_sphere_tree):
    # contains() of one point takes a plain-Python path; the vectorised path is the reference.
    pts = np.random.default_rng(5).uniform(-1.1, 1.1, size=(400, 3))
    for policy in ("conservative", "optimistic", "vertex"):
        batch = unit_sphere_tree.contains(pts, policy)
        single = np.array([unit_sphere_tree.contains(p[None], policy)[0] for p in pts])
        assert np.array_equal(batch, single), policy
    assert unit_sphere_tree.locator.locate(pts[:1])[0] == unit_sphere_tree.locator.locate(pts)[0]


class _DiscWithSpike:
    """A disc and a thin spike rising from it past a coarse cell's lower face, between that cell's corners: the cell
    above is labelled outer by its corners at depth 2, and only the finer vertices of the cell below, on the shared
    face, show the spike's cap (as a UR5's tool-down cap above a coarse cell, bench/ur5_truth.py)."""

    dim = 2
    posture_names: tuple[str, ...] = ()

    def evaluate(self, goals):
        from oracles.protocol import Goals, Verdicts

        p = Goals.points_of(goals, 2)
        disc = np.linalg.norm(p - [0.25, -0.5], axis=1) <= 0.45
        spike = (np.abs(p[:, 0] - 0.25) <= 0.05) & (p[:, 1] >= -0.5) & (p[:, 1] <= 0.1)
        inside = disc | spike
        return Verdicts(inside, np.where(inside, 0.0, 0.01), None)


def test_an_outer_cell_whose_face_holds_a_reachable_vertex_found_later_is_subdivided():
    tree = build_tree(_DiscWithSpike(), SQUARE, 2, 5)
    assert tree.meta["build"]["reopened"] >= 1
    cap = np.array([[x, y] for x in (0.21, 0.25, 0.29) for y in (0.01, 0.05, 0.09)])  # the spike above y = 0
    assert (tree.classify(cap) != OUTER).all()
    assert tree.contains(np.array([[0.25, 0.04]]), "vertex")[0]
    # the tree is whole: each node's children are where a plain descent by the cell's bits looks for them, and each
    # child lies inside its parent
    pts = np.random.default_rng(5).uniform(-1.0, 1.0, (2000, 2))
    cells, _ = tree.lattice.cell_of(pts)
    for c, leaf in zip(cells, tree.locator.locate(pts), strict=True):
        node, depth = 0, 0
        while tree.kind[node] == PARENT:
            bits = sum(((int(c[i]) >> (tree.d_max - depth - 1)) & 1) << i for i in range(2))
            node, depth = int(tree.child[node]) + bits, depth + 1
            size = 1 << (tree.d_max - depth)
            assert np.all((tree.corner[node] <= c) & (c < tree.corner[node] + size))
        assert node == leaf
    assert tree.classify(np.array([[0.75, 0.75]]))[0] == OUTER
    # the cells outside the spike keep their label: the volume does not grow past the shape
    truth = _DiscWithSpike().evaluate(pts).reachable
    assert not (tree.classify(pts)[~truth] == INNER).any()
