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

from oracles.bodies.environment import Box
from oracles.protocol import Furnished, OracleSpec, Shaped
from reach.answers.evaluate import to_body
from reach.tools.report import COLOURS

AXES = {"side": (0, 2), "top": (0, 1)}
SKIN = (0.90, 0.78, 0.67)
FURNITURE = (0.55, 0.55, 0.58)


def draw_capsules(ax: Any, capsules: np.ndarray, view: str = "side", colour: Any = SKIN,
                  edge: Any = (0.45, 0.35, 0.3)) -> None:
    """Capsules (K, 7: end points a, b [m], radius [m]) as their outlines projected on the view's plane, far ones
    first."""
    # matplotlib (about half a second) only when a figure is drawn
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
            ax.add_patch(Polygon([a + normal, b + normal, b - normal, a - normal], closed=True, facecolor=colour,
                                 edgecolor="none", zorder=3))
            ax.plot([a[0] + normal[0], b[0] + normal[0]], [a[1] + normal[1], b[1] + normal[1]], color=edge, lw=0.6,
                    zorder=4)
            ax.plot([a[0] - normal[0], b[0] - normal[0]], [a[1] - normal[1], b[1] - normal[1]], color=edge, lw=0.6,
                    zorder=4)
        for end in (a, b):
            ax.add_patch(Circle(tuple(end), r, facecolor=colour, edgecolor=edge, lw=0.6, zorder=3))


def draw_boxes(ax: Any, boxes: Sequence[Box], view: str = "side", colour: Any = FURNITURE) -> None:
    """Boxes as the outline of their corners projected on the view's plane (their convex hull)."""
    # matplotlib (about half a second) only when a figure is drawn
    from matplotlib.patches import Polygon
    from scipy.spatial import ConvexHull

    i, j = AXES[view]
    for box in boxes:
        pts = box.corners()[:, [i, j]]
        hull = ConvexHull(pts)
        ax.add_patch(Polygon(pts[hull.vertices], closed=True, facecolor=colour, edgecolor="k", lw=0.5, alpha=0.8,
                             zorder=2))


def body_figure(capsules: np.ndarray, boxes: Sequence[Box], path: Any, title: str = "") -> Any:
    """Side and top views of a posture's capsules and the furniture, written to a PNG."""
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # matplotlib (about half a second) only when a figure is drawn
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


def from_row(row: np.ndarray) -> Box:
    """A box from a Furnished row: centre [m], half sizes [m], quaternion (w, x, y, z)."""
    # Pinocchio only when a body is loaded
    import pinocchio as pin

    rotation = pin.Quaternion(float(row[6]), float(row[7]), float(row[8]), float(row[9])).toRotationMatrix()
    return Box(tuple(row[:3] - row[3:6]), tuple(row[:3] + row[3:6]),
               tuple(tuple(float(v) for v in r) for r in rotation))  # type: ignore[arg-type,misc]


def _slice_image(ax: Any, matplotlib: Any, atlas: Any, names: list[str], colour: dict[str, Any], i: int, j: int,
                 shoulder: np.ndarray, resolution: float) -> None:
    """The volumes' slice on axes (i, j) through the shoulder: each cell in the colour of the first strategy, by
    priority, that holds it."""
    tree0 = atlas.trees[names[0]]
    lo, hi = tree0.box.lo, tree0.box.hi
    u = np.arange(lo[i], hi[i], resolution) + 0.5 * resolution
    v = np.arange(lo[j], hi[j], resolution) + 0.5 * resolution
    gu, gv = np.meshgrid(u, v, indexing="ij")
    pts = np.zeros((gu.size, 3))
    pts[:, i], pts[:, j] = gu.ravel(), gv.ravel()
    pts[:, 3 - i - j] = shoulder[3 - i - j]
    taken = np.zeros(gu.size, bool)
    image = np.ones((*gu.shape, 4))
    image[..., 3] = 0.0
    for n in names:
        held = atlas.trees[n].contains(pts, "vertex") & ~taken
        taken |= held
        image.reshape(-1, 4)[held] = matplotlib.colors.to_rgba(colour[n], 0.35)
    ax.imshow(np.transpose(image, (1, 0, 2)), origin="lower", extent=(lo[i], hi[i], lo[j], hi[j]), zorder=1,
              interpolation="nearest")


def layout_figure(atlases: Sequence[Any], results: dict[str, Any], path: Any, resolution: float = 0.01) -> Any:
    """Per atlas (a row): side and top views of the body in its reference posture, its furniture, the volumes' slices
    through the right shoulder (each cell in the colour of the first strategy, by priority, that holds it), and the
    targets (body frame) coloured by the strategy that reaches them, a red cross where none does."""
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(atlases), 2, figsize=(12, 5.5 * len(atlases)), squeeze=False)
    for row, (atlas, result) in enumerate(zip(atlases, results["atlases"], strict=True)):
        names = sorted(atlas.trees, key=lambda n: atlas.trees[n].meta.get("priority", 0))
        colour = {n: COLOURS[k % len(COLOURS)] for k, n in enumerate(names)}
        oracle = OracleSpec.from_dict(next(iter(atlas.trees.values())).meta["oracle"]).create()
        capsules = oracle.shape(oracle.reference_posture())[1] if isinstance(oracle, Shaped) else np.zeros((0, 7))
        boxes = [from_row(b) for b in oracle.furniture()[1]] if isinstance(oracle, Furnished) else []
        points = np.array([r["point"] for r in result["rows"]], float).reshape(-1, 3)
        if result.get("at"):
            a = result["at"]
            points = to_body(points, np.array([[a["x"], a["y"], a["z"], a["yaw"]]]))[0]
        names_of = oracle.shape(oracle.reference_posture())[0] if isinstance(oracle, Shaped) else []
        shoulder = capsules[names_of.index("right_upper_arm"), :3] if "right_upper_arm" in names_of else np.zeros(3)
        for col, view in enumerate(AXES):
            ax = axes[row, col]
            i, j = AXES[view]
            _slice_image(ax, matplotlib, atlas, names, colour, i, j, shoulder, resolution)
            draw_boxes(ax, boxes, view)
            draw_capsules(ax, capsules, view)
            for r, p in zip(result["rows"], points, strict=True):
                if r["reachable"]:
                    ax.scatter([p[i]], [p[j]], s=40, color=colour.get(r["strategy"], "k"), edgecolor="k", zorder=6)
                else:
                    ax.scatter([p[i]], [p[j]], s=50, marker="x", color="red", zorder=6)
            frame(ax, view, capsules, boxes, points)
            which = "y" if view == "side" else "z"
            ax.set_title(f"{result['name'] or atlas.path.name}: {view}, volumes at {which} = "
                         f"{shoulder[3 - i - j]:.2f} m (right shoulder)", fontsize=9)
        handles: list[Any] = [plt.Rectangle((0, 0), 1, 1, color=colour[n], alpha=0.6) for n in names]
        handles.append(plt.Line2D([], [], marker="x", color="red", linestyle=""))
        axes[row, 0].legend(handles, [*names, "unreachable"], fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
