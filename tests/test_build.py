"""Algorithm 1 (reach.building.tree): the paper's worked example, one oracle call per vertex, warm starts, refinements,
determinism."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import TwoLinkArm, same_tree

from oracles.protocol import OracleSpec
from oracles.shapes import circle, sphere
from reach.building.tree import build_tree, warm_hints
from reach.errors import TreeError
from reach.maps.box import Box
from reach.maps.tree import FINAL, INNER, OUTER, Lattice

SQUARE = Box([-1.0, -1.0], [1.0, 1.0])
CUBE = Box([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])


def test_paper_figure2_counts_per_depth_and_type():
    # Circle inscribed in B0, D_min 1, D_max 3, as in the paper's Figure 2.
    # The text's depth-2 counts (4 inner, 12 parent) hold. At depth 3 the text
    # says 28 outer; the geometry gives 28 final, 16 inner and 4 outer: each
    # of the 12 depth-2 parents has 4 children, and only the 4 corner-most
    # children (one per B0 corner) lie wholly outside the circle.
    tree = build_tree(circle(radius=1.0), SQUARE, 1, 3)
    counts = tree.node_counts()
    assert counts[0] == {"outer": 0, "inner": 0, "parent": 1, "final": 0}
    assert counts[1] == {"outer": 0, "inner": 0, "parent": 4, "final": 0}
    assert counts[2] == {"outer": 0, "inner": 4, "parent": 12, "final": 0}
    assert counts[3] == {"outer": 4, "inner": 16, "parent": 0, "final": 28}


def test_paper_figure2_no_oracle_call_below_dmin_or_for_depth1_labels(counting):
    oracle = counting(circle(radius=1.0))
    tree = build_tree(oracle, SQUARE, 1, 3)
    # Depth 0 is below D_min: the root is a parent without any call.
    # Depth 1 asks for the 3x3 vertices; depth 2 adds the 16 new ones of the
    # 5x5 grid; depth 3 adds the new vertices of the 48 children of 12 parents.
    sizes = [len(a) for a in oracle.asked]
    assert sizes[0] == 9 and sizes[1] == 25 - 9
    assert tree.oracle_calls == oracle.calls == 73


def test_every_distinct_vertex_is_asked_once(counting):
    oracle = counting(sphere(center=(0.1, -0.2, 0.05), radius=0.8))
    tree = build_tree(oracle, CUBE, 2, 5, chunk_size=300)
    asked = np.concatenate(oracle.asked)
    lat = Lattice(CUBE, 5)
    keys = lat.keys(np.rint((asked - CUBE.lo) / lat.resolution).astype(np.int64))
    assert np.unique(keys).size == keys.size  # never twice
    # Independent truth: the union of the vertices of every node at depth >= D_min.
    expected = set()
    for d in range(2, 6):
        sel = tree.depth == d
        expected.update(lat.node_vertex_keys(tree.corner[sel], d).ravel().tolist())
    assert set(keys.tolist()) == expected
    assert tree.oracle_calls == len(expected)
    assert tree.oracle_calls < lat.vertex_count


def test_dmin_finds_a_small_sphere_in_a_large_box():
    # Figure 1(c): every vertex of a coarse tree misses a small volume.
    small = sphere(center=(0.3, 0.3, 0.3), radius=0.12)
    missed = build_tree(small, CUBE, 0, 6)
    assert missed.volume(INNER) == 0.0 and len(missed) == 1 and missed.kind[0] == OUTER
    found = build_tree(small, CUBE, 3, 6)
    true = 4.0 / 3.0 * np.pi * 0.12**3
    assert found.volume(INNER) > 0.0
    assert found.volume(INNER) <= true <= found.volume(INNER) + found.volume(FINAL)


def test_build_refuses_bad_depths_and_dimension_mismatch():
    with pytest.raises(TreeError, match="must not exceed"):
        build_tree(sphere(), CUBE, 5, 3)
    with pytest.raises(TreeError, match="2-D but B0 is 3-D"):
        build_tree(circle(), CUBE, 1, 3)


def test_build_is_deterministic():
    spec = OracleSpec("torus", {"major": 0.6, "minor": 0.2})
    t1 = build_tree(spec, CUBE, 2, 5)
    t2 = build_tree(spec, CUBE, 2, 5, chunk_size=17)
    assert np.array_equal(t1.kind, t2.kind) and np.array_equal(t1.corner, t2.corner)
    assert np.array_equal(t1.vertices.keys, t2.vertices.keys)


def test_warm_hints_are_the_postures_of_the_nearest_reachable_vertices():
    from reach.maps.tree import VertexTable

    lat = Lattice(CUBE, 2)  # 5 x 5 x 5 vertices, 0.5 m apart
    coords = np.array([[0, 0, 0], [4, 4, 4], [2, 2, 2]])
    postures = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    table = VertexTable(lat.keys(coords), np.array([True, True, False]), np.zeros(3), postures, ("a", "b"))
    order = np.argsort(table.keys)
    table = VertexTable(table.keys[order], table.reachable[order], table.residual[order], postures[order], ("a", "b"))
    hints = warm_hints(table, lat, np.array([[-0.9, -0.9, -0.9], [0.1, 0.1, 0.1], [0.9, 0.8, 0.9]]))
    # The unreachable centre vertex is never a hint, however near: (0.1, 0.1, 0.1) gets the corner (1, 1, 1)'s.
    assert hints.tolist() == [[1.0, 1.0], [2.0, 2.0], [2.0, 2.0]]
    assert warm_hints(VertexTable.empty(), lat, np.zeros((2, 3))) is None  # no postures, no hints


def test_builder_sends_hints_to_oracles_with_postures(counting):
    oracle = counting(TwoLinkArm(shoulder=(0.0, 0.0, 0.0)))
    build_tree(oracle, CUBE, 2, 4)
    assert oracle.hints[0] is None or np.all(np.isnan(oracle.hints[0]))  # nothing is known before the first depth
    later = [h for h in oracle.hints[1:] if h is not None and len(h)]
    assert later and all(np.all(np.isfinite(h)) for h in later)  # every later vertex starts near a reached one


def test_an_empty_volume_is_one_outer_root_per_depth_rule():
    tree = build_tree(sphere(center=(5.0, 5.0, 5.0), radius=0.1), CUBE, 0, 4)
    assert len(tree) == 1 and tree.volume(INNER) == 0.0


@pytest.mark.parametrize("d_min", [0, 2])
def test_d_min_levels_are_all_parents(d_min):
    tree = build_tree(OracleSpec("sphere", {"radius": 0.5}), CUBE, d_min, 3)
    counts = tree.node_counts()
    for d in range(d_min):
        assert counts[d]["parent"] == 8**d


def test_meets_errs_towards_meeting_and_agrees_with_coal():
    """reach.building.tree.meets against coal's capsule-box distance: every box coal finds meeting is flagged, no box
    farther than the sampling slack is."""
    import coal

    from reach.building.tree import meets

    rng = np.random.default_rng(3)
    a, b, r = np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.3, 0.6]), 0.08
    axis = (b - a) / np.linalg.norm(b - a)
    x = np.cross(axis, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    pose = coal.Transform3s(np.column_stack([x, np.cross(axis, x), axis]), 0.5 * (a + b))
    size = 0.05
    lo = rng.uniform(-0.1, 0.7, (400, 3))
    flagged = meets(lo, lo + size, np.array([[*a, *b, r]]))
    for k in range(len(lo)):
        d = coal.distance(coal.Capsule(r, float(np.linalg.norm(b - a))), pose, coal.Box(size, size, size),
                          coal.Transform3s(np.eye(3), lo[k] + size / 2), coal.DistanceRequest(), coal.DistanceResult())
        if d <= 0:
            assert flagged[k]
        elif d > 0.5 * 0.5 * min(r, size):  # beyond the sampling slack
            assert not flagged[k]
    assert 20 < flagged.sum() < 380


def test_no_inner_cell_meets_a_keep_out_capsule():
    """A ball with a keep-out capsule through it (as the trunk for an arm): the cells the corners alone would
    paint inner over the capsule are split down to D_max and left final."""
    from reach.building.tree import meets

    capsule = np.array([[-0.2, 0.0, -0.3, 0.2, 0.0, 0.3, 0.1]])
    plain = build_tree(sphere(radius=0.9), CUBE, 2, 5)
    kept = build_tree(sphere(radius=0.9), CUBE, 2, 5, keep_out=capsule)

    def inner_meeting(tree):  # depth by depth, as the build asks
        out = 0
        for d in range(2, 6):
            rows = np.nonzero((tree.kind == INNER) & (tree.depth == d))[0]
            lo = Lattice(CUBE, 5).points(tree.corner[rows])
            out += int(meets(lo, lo + tree.lattice.cell_size(tree.depth[rows]), capsule).sum())
        return out

    assert inner_meeting(plain) > 0  # the corners alone paint it inner
    assert inner_meeting(kept) == 0
    assert kept.volume(INNER) < plain.volume(INNER)
    # nothing reachable is lost: it is final instead
    assert kept.volume(INNER) + kept.volume(FINAL) >= plain.volume(INNER)


def test_a_build_inherits_only_the_verified_reachable_vertices_of_a_sub_strategy():
    from reach.building.tree import Inherited
    from reach.maps.tree import VertexTable

    arm = TwoLinkArm(shoulder=(0.0, 0.0, 0.0))
    plain = build_tree(arm, CUBE, 2, 4)
    checks = []

    def verify(points: np.ndarray, postures: np.ndarray) -> np.ndarray:
        checks.append(len(points))
        return np.linalg.norm(arm.effector_positions(postures) - points, axis=1) <= 1e-6

    v = plain.vertices
    heir = TwoLinkArm(shoulder=(0.0, 0.0, 0.0))
    tree = build_tree(heir, CUBE, 2, 4, inherit=Inherited("arm", v, verify))
    same_tree(tree, plain)
    # Only the unreachable vertices were solved; the reachable ones were checked, not solved.
    assert heir.solved == int((~v.reachable).sum()) == tree.oracle_calls
    assert tree.meta["build"]["inherited"] == int(v.reachable.sum()) == sum(checks)
    # A source that claims every vertex reachable: its postures of the unreachable ones miss, and are solved again.
    liar = VertexTable(v.keys, np.ones_like(v.reachable), v.residual, v.posture, v.posture_names)
    third = TwoLinkArm(shoulder=(0.0, 0.0, 0.0))
    same_tree(build_tree(third, CUBE, 2, 4, inherit=Inherited("liar", liar, verify)), plain)
    assert third.solved == heir.solved
    # A smaller arm's postures put the hand short of this arm's vertices: nothing inherited, all solved.
    short = build_tree(TwoLinkArm(upper=0.25, fore=0.2, shoulder=(0.0, 0.0, 0.0)), CUBE, 2, 4)
    fourth = TwoLinkArm(shoulder=(0.0, 0.0, 0.0))
    same_tree(build_tree(fourth, CUBE, 2, 4, inherit=Inherited("short", short.vertices, verify)), plain)
    assert fourth.solved == len(v)
