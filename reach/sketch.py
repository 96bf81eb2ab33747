"""Flat drawings of a body: its capsules and its furniture (a seat, a table) seen from the side or from above.

``reach model CONFIG --figure PNG`` draws the reference posture; the seated
examples' figures add the volumes' slices and the targets. Views: ``side``
(x forward to the right, z up) and ``top`` (x forward to the right, y left
up); metres, the world frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from oracles.environment import Box

AXES = {"side": (0, 2), "top": (0, 1)}
SKIN = (0.90, 0.78, 0.67)
FURNITURE = (0.55, 0.55, 0.58)


def draw_capsules(ax: Any, capsules: np.ndarray, view: str = "side", colour: Any = SKIN, edge: Any = (0.45, 0.35, 0.3)) -> None:
    """Capsules (K, 7: end points a, b [m], radius [m]) as their outlines projected on the view's plane, far ones first."""
    from matplotlib.patches import Circle, Polygon

    i, j = AXES[view]
    depth = 3 - i - j  # the axis the view looks along
    # The side view looks from the body's right (-y), the top view from above: the nearest drawn last.
    order = np.argsort(0.5 * (capsules[:, depth] + capsules[:, 3 + depth]) * (-1 if view == "side" else 1))
    for cap in capsules[order]:
        a, b, r = cap[[i, j]], cap[[3 + i, 3 + j]], float(cap[6])
        d = b - a
        n = float(np.linalg.norm(d))
        if n > 1e-9:
            normal = np.array([-d[1], d[0]]) / n * r
            ax.add_patch(Polygon([a + normal, b + normal, b - normal, a - normal], closed=True, facecolor=colour, edgecolor="none", zorder=3))
            ax.plot([a[0] + normal[0], b[0] + normal[0]], [a[1] + normal[1], b[1] + normal[1]], color=edge, lw=0.6, zorder=4)
            ax.plot([a[0] - normal[0], b[0] - normal[0]], [a[1] - normal[1], b[1] - normal[1]], color=edge, lw=0.6, zorder=4)
        for end in (a, b):
            ax.add_patch(Circle(tuple(end), r, facecolor=colour, edgecolor=edge, lw=0.6, zorder=3))


def draw_boxes(ax: Any, boxes: Sequence[Box], view: str = "side", colour: Any = FURNITURE) -> None:
    """Boxes as the outline of their corners projected on the view's plane (their convex hull)."""
    from matplotlib.patches import Polygon
    from scipy.spatial import ConvexHull

    i, j = AXES[view]
    for box in boxes:
        pts = box.corners()[:, [i, j]]
        hull = ConvexHull(pts)
        ax.add_patch(Polygon(pts[hull.vertices], closed=True, facecolor=colour, edgecolor="k", lw=0.5, alpha=0.8, zorder=2))


def body_figure(capsules: np.ndarray, boxes: Sequence[Box], path: Any, title: str = "") -> Any:
    """Side and top views of a posture's capsules and the furniture, written to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 5.5))
    for ax, view in zip(axes, AXES, strict=True):
        draw_boxes(ax, boxes, view)
        draw_capsules(ax, capsules, view)
        frame(ax, view, capsules, boxes)
    axes[0].set_title(f"{title} (side)" if title else "side")
    axes[1].set_title(f"{title} (top)" if title else "top")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def frame(ax: Any, view: str, capsules: np.ndarray, boxes: Sequence[Box], points: np.ndarray | None = None) -> None:
    """Equal axes around everything drawn, labelled in metres; the floor line on a side view."""
    i, j = AXES[view]
    pts = [capsules[:, [i, j]] - capsules[:, 6:7], capsules[:, [i, j]] + capsules[:, 6:7],
           capsules[:, [3 + i, 3 + j]] - capsules[:, 6:7], capsules[:, [3 + i, 3 + j]] + capsules[:, 6:7]]
    pts += [b.corners()[:, [i, j]] for b in boxes]
    if points is not None and len(points):
        pts.append(points[:, [i, j]])
    allp = np.vstack(pts)
    lo, hi = allp.min(0) - 0.08, allp.max(0) + 0.08
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(min(lo[1], -0.02) if view == "side" else lo[1], hi[1])
    if view == "side":
        ax.axhline(0.0, color="k", lw=1.0, zorder=1)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x forward [m]")
    ax.set_ylabel("z up [m]" if view == "side" else "y left [m]")
