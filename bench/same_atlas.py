"""Check that two builds of an atlas are identical: same oracle calls, node counts, verdicts and postures.

Usage: python bench/same_atlas.py ATLAS_A ATLAS_B

Prints one JSON line per strategy and exits 1 when any differs. Used to
check that a refactoring changed no tree (e.g. the demo atlas built before
and after it).
"""

from __future__ import annotations

import json
import sys

import numpy as np

from reach.maps.atlas import load_atlas


def compare(a_path: str, b_path: str) -> bool:
    a, b = load_atlas(a_path), load_atlas(b_path)
    same = set(a.trees) == set(b.trees)
    for name in sorted(set(a.trees) & set(b.trees)):
        ta, tb = a.trees[name], b.trees[name]
        va, vb = ta.vertices, tb.vertices
        row = {
            "strategy": name, "oracle_calls": [ta.oracle_calls, tb.oracle_calls],
            "nodes": [len(ta), len(tb)], "node_counts_equal": ta.node_counts() == tb.node_counts(),
            "kinds_equal": bool(np.array_equal(ta.kind, tb.kind) and np.array_equal(ta.corner, tb.corner)),
            "vertex_keys_equal": bool(np.array_equal(va.keys, vb.keys)),
            "verdicts_equal": bool(np.array_equal(va.keys, vb.keys) and np.array_equal(va.reachable, vb.reachable)),
            "postures_max_abs_diff": None if va.posture is None or vb.posture is None
            or va.posture.shape != vb.posture.shape
            else float(np.max(np.abs(va.posture - vb.posture), initial=0.0)),
        }
        ok = row["oracle_calls"][0] == row["oracle_calls"][1] and row["nodes"][0] == row["nodes"][1] and all(
            row[k] for k in ("node_counts_equal", "kinds_equal", "vertex_keys_equal", "verdicts_equal"))
        row["identical"] = ok
        same &= ok
        print(json.dumps(row))
    return same


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(0 if compare(sys.argv[1], sys.argv[2]) else 1)
