"""The ``cells`` operation's replies, made once per atlas when it loads.

A level-6 reply is about 2 MB of JSON and took the request loop 0.36-0.43 s to make (commit 30fbe76): every strategy's
reachable cells at every level a request may ask are rasterised and encoded once, beside the selector (at start-up
and in a reload's background thread), and a request joins the fragments it asks for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reach.answers.select import Selector
from reach.maps.protocol import raster
from reach.serving import protocol as P


@dataclass(frozen=True)
class Served:
    """What the loop serves: the selector and its ``cells`` fragments, ``(strategy, level) -> b'"name":{...}'``."""

    selector: Selector
    cells: dict[tuple[str, int], bytes]


def serve(selector: Selector) -> Served:
    """A selector with its ``cells`` fragments made (about half a second for the demo's eight strategies)."""
    atlas = selector.atlas
    cells: dict[tuple[str, int], bytes] = {}
    for name in atlas.select(None):
        tree = atlas.trees[name]
        made: dict[int, bytes] = {}  # levels past the tree's depth ask the same raster
        for level in range(1, P.MAX_CELLS_LEVEL + 1):
            at = min(level, tree.d_max)
            if at not in made:
                occ, edges = raster(atlas.map(name), at)
                mid = [0.5 * (e[1:] + e[:-1]) for e in edges]
                centres = np.stack(np.meshgrid(*mid, indexing="ij"), axis=-1)[occ]
                body = {"effector": tree.meta.get("effector"), "priority": tree.meta.get("priority"),
                        "size": (tree.box.size / (1 << at)).tolist(), "centres": np.round(centres, 6).tolist()}
                made[at] = P.encode_value(name) + b":" + P.encode(body)
            cells[(name, level)] = made[at]
    return Served(selector, cells)


def reply(served: Served, names: list[str], level: int) -> bytes:
    """The encoded result of a ``cells`` request for these strategies at this level."""
    return (b'{"cells":{' + b",".join(served.cells[(name, level)] for name in names) + b'},"level":'
            + str(level).encode() + b"}")
