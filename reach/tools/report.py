"""Reports comparing the strategies of an atlas: tables and figures in the paper's manner.

``reach report ATLAS -o DIR`` writes:

* ``report.md`` and ``report.json``: volume per strategy (inner, boundary),
  extents (highest, lowest, farthest forward, farthest to the side), and the
  volume of every pairwise intersection and difference (the paper's Figure 9);
* ``strategy_<name>.png``: one strategy drawn as boxes;
* ``figure8.png``: several strategies in colours, each cell in the colour of
  the first strategy (by priority) that holds it;
* ``figure11.png``: an overlay of one effector's strategies by priority
  (e.g. arm only as boxes, upper body as dots, whole body as a wireframe);
* ``slices.png``: horizontal and sagittal slices through every strategy;
* ``index_<name>.png``: the reachability index of a strategy built with
  ``directions: N`` as a heat map on the same two slices.

Figures rasterise the trees on a regular grid of cells (at most 2**4 per
axis by default), each cell decided at its centre with the ``vertex`` policy.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reach.answers.audit import lacking
from reach.answers.evaluate import Target
from reach.answers.place import Ranking
from reach.maps.atlas import Atlas
from reach.maps.boolean import difference, intersection
from reach.maps.index import summary as index_summary
from reach.maps.protocol import ReachMap, raster
from reach.maps.tree import FINAL, INNER, VATree
from reach.serving.protocol import finite

# matplotlib's tab10, then tab20's light half: configs/human.yaml's 17 strategies each get a colour of their own
COLOURS = ["#d62728", "#2ca02c", "#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f",
           "#ff9896", "#98df8a", "#aec7e8", "#ffbb78", "#c5b0d5", "#c49c94", "#f7b6d2", "#9edae5", "#dbdb8d", "#c7c7c7"]


def extents(tree: VATree) -> dict[str, float | None]:
    """Highest, lowest, farthest forward and to either side [m], over inner and final cells."""
    ext = tree.extent()
    if ext is None:
        return {"highest": None, "lowest": None, "forward": None, "backward": None, "left": None, "right": None}
    lo, hi = ext
    out = {"forward": float(hi[0]), "backward": float(lo[0]), "left": float(hi[1]), "right": float(lo[1])}
    if tree.dim == 3:
        out.update(highest=float(hi[2]), lowest=float(lo[2]))
    return out  # type: ignore[return-value]


def tables(atlas: Atlas) -> dict[str, Any]:
    """Volumes, extents and pairwise booleans of every strategy."""
    names = list(atlas.trees)
    per = {
        n: {"effector": t.meta.get("effector"), "priority": t.meta.get("priority"), "volume_inner": t.volume(INNER),
            "volume_boundary": t.volume(FINAL), **extents(t),
            "on_faces": t.faces(), "index": index_summary(t, atlas.indexes.get(n))}
        for n, t in atlas.trees.items()
    }
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ta, tb = atlas.trees[a], atlas.trees[b]
            if ta.box != tb.box or ta.d_max != tb.d_max:
                continue
            pairs.append({
                "a": a, "b": b, "intersection": intersection(ta, tb).volume(INNER),
                "a_minus_b": difference(ta, tb).volume(INNER),
                "b_minus_a": difference(tb, ta).volume(INNER),
            })
    for n, lines in lacking(atlas).items():
        if n in per:
            per[n]["audit_warnings"] = lines
    return {"strategies": per, "pairs": pairs, "units": "m and m^3, world frame (z up, x forward, y left)"}


def markdown(t: dict[str, Any], title: str) -> str:
    def f(v: Any) -> str:
        return "-" if v is None else f"{v:.3f}"

    lines = [f"# Reach report: {title}", "", "Volumes [m^3] (inner cells; boundary cells apart) and extents [m] of "
                                             "the inner and boundary cells.", "",
             "| strategy | effector | priority | inner | boundary | highest | lowest | forward | left | right |", "| "
             "--- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for n, s in t["strategies"].items():
        lines.append(f"| {n} | {s['effector']} | {s['priority']} | {f(s['volume_inner'])} | "
                     f"{f(s['volume_boundary'])} | {f(s.get('highest'))} | {f(s.get('lowest'))} | {f(s['forward'])} "
                     f"| {f(s['left'])} | {f(s['right'])} |")
    lines += _warnings(t["strategies"])
    indexed = {n: s["index"] for n, s in t["strategies"].items() if s.get("index")}
    if indexed:
        lines += ["", "Reachability index (share of approach directions reached at the reachable vertices; "
                      "`index_<strategy>.png`):", "",
                  "| strategy | directions | mean | quartiles |", "| --- | --- | --- | --- |"]
        lines += [f"| {n} | {i['directions']} | {f(i['mean'])} | {', '.join(f(v) for v in i['quartiles'])} |"
                  for n, i in indexed.items()]
    lines += ["", "Pairwise volumes [m^3] (inner cells of the boolean trees):", "", "| a | b | a and b | a not b | b "
        "not a |", "| --- | --- | --- | --- | --- |"]
    for p in t["pairs"]:
        lines.append(f"| {p['a']} | {p['b']} | {p['intersection']:.3f} | {p['a_minus_b']:.3f} | {p['b_minus_a']:.3f} |")
    return "\n".join(lines) + "\n"


def _warnings(strategies: dict[str, Any]) -> list[str]:
    """The report's warnings: volumes the box cuts, and regions the last audit found the trees lack."""
    lines = []
    cut = {n: s["on_faces"] for n, s in strategies.items() if s.get("on_faces")}
    if cut:
        lines += ["", "**Warning: the box cuts these volumes** (reachable vertices on its faces; enlarge the box "
                      "there):", ""]
        lines += [f"- {n}: " + ", ".join(f"{k} on {f}" for f, k in faces.items()) for n, faces in cut.items()]
    lacks = {n: s["audit_warnings"] for n, s in strategies.items() if s.get("audit_warnings")}
    if lacks:
        lines += ["", "**Warning: regions the trees lack**, by the atlas's last `reach audit` (`audit.json`):", ""]
        lines += [f"- {n}: {w}" for n, ws in lacks.items() for w in ws]
    return lines


def _axes3d(fig: Any, pos: int, title: str, tree: VATree) -> Any:
    ax = fig.add_subplot(pos, projection="3d")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x forward [m]")
    ax.set_ylabel("y left [m]")
    ax.set_zlabel("z up [m]")
    lo, hi = tree.box.lo, tree.box.hi
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(hi - lo))
    ax.view_init(elev=20, azim=-60)
    return ax


def overlay_names(trees: dict[str, VATree]) -> list[str]:
    """Up to three strategies for Figure 11: the paper's nesting of one effector's strategies.

    The effector of the first strategy; its strategies by priority, one per
    priority (e.g. arm only, upper body, whole body for one hand).
    """
    names = list(trees)
    effector = trees[names[0]].meta.get("effector")
    mine = sorted((n for n in names if trees[n].meta.get("effector") == effector),
                  key=lambda n: trees[n].meta.get("priority", 0))
    out: list[str] = []
    for n in mine:
        if not out or trees[n].meta.get("priority") != trees[out[-1]].meta.get("priority"):
            out.append(n)
    return out[:3]


def figures(atlas: Atlas, out: Path, level: int = 4, names: list[str] | None = None,
            planes: tuple[float | None, float | None] = (None, None)) -> list[Path]:
    """Write the PNG figures; returns their paths."""
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib.pyplot as plt

    names = names or list(atlas.trees)
    trees = {n: atlas.trees[n] for n in names}
    if any(t.dim != 3 for t in trees.values()):
        return []
    level = min(level, min(t.d_max for t in trees.values()))
    grids = {n: raster(t, level) for n, t in trees.items()}
    first = trees[names[0]]
    written = []
    for k, n in enumerate(names):
        occ, edges = grids[n]
        fig = plt.figure(figsize=(6, 6))
        ax = _axes3d(fig, 111, f"{n}: reachable cells", first)
        x, y, z = np.meshgrid(*edges, indexing="ij")
        ax.voxels(x, y, z, occ, facecolors=COLOURS[k % len(COLOURS)], edgecolors="k", linewidth=0.2, alpha=0.8)
        written.append(_save(fig, out / f"strategy_{n}.png"))
    written.append(_figure8(plt, trees, names, grids, out / "figure8.png"))
    written.append(_figure11(plt, trees, grids, out / "figure11.png"))
    written.append(slices(trees, out / "slices.png", level, *planes))
    written += [heat_map(n, atlas.map(n), out / f"index_{n}.png", level, *planes,
                         directions=len(atlas.indexes[n].directions))
                for n in trees if n in atlas.indexes]
    return written


def _figure8(plt: Any, trees: dict[str, VATree], names: list[str], grids: dict[str, Any], path: Path) -> Path:
    """The paper's Figure 8: each cell in the colour of the first strategy, by priority, that holds it."""
    first = trees[names[0]]
    ordered = sorted(names, key=lambda n: trees[n].meta.get("priority", 0))
    fig = plt.figure(figsize=(7, 7))
    ax = _axes3d(fig, 111, "Strategies in colours (first by priority)", first)
    taken = np.zeros_like(grids[names[0]][0])
    x, y, z = np.meshgrid(*grids[names[0]][1], indexing="ij")
    for n in ordered:
        occ = grids[n][0] & ~taken
        taken |= grids[n][0]
        if occ.any():
            ax.voxels(x, y, z, occ, facecolors=COLOURS[names.index(n) % len(COLOURS)], edgecolors="k", linewidth=0.1,
                      alpha=0.7)
    ax.legend(handles=[plt.Rectangle((0, 0), 1, 1, color=COLOURS[names.index(n) % len(COLOURS)]) for n in ordered],
              labels=ordered, fontsize=7, loc="upper left")
    return _save(fig, path)


def _figure11(plt: Any, trees: dict[str, VATree], grids: dict[str, Any], path: Path) -> Path:
    """The paper's Figure 11: boxes, dots and a wireframe together, a strategy each."""
    first = next(iter(trees.values()))
    overlay = overlay_names(trees)
    fig = plt.figure(figsize=(7, 7))
    ax = _axes3d(fig, 111,
                 "Overlay: " + ", ".join(f"{n} ({s})"
                                         for n, s in zip(overlay, ("boxes", "dots", "wireframe"), strict=False)), first)
    x, y, z = np.meshgrid(*grids[next(iter(trees))][1], indexing="ij")
    for k, n in enumerate(overlay):
        occ, edges = grids[n]
        colour = COLOURS[k % len(COLOURS)]
        if k == 0:
            ax.voxels(x, y, z, occ, facecolors=colour, alpha=0.35)
        elif k == 1:
            centres = [0.5 * (e[1:] + e[:-1]) for e in edges]
            cx, cy, cz = np.meshgrid(*centres, indexing="ij")
            ax.scatter(cx[occ], cy[occ], cz[occ], s=3, color=colour)
        else:
            ax.voxels(x, y, z, occ, facecolors=(0, 0, 0, 0), edgecolors=colour, linewidth=0.3)
    return _save(fig, path)


def heat_map(name: str, tree: ReachMap, path: Path, level: int, z: float | None = None, y: float | None = None,
             directions: int = 0) -> Path:
    """The reachability index on the horizontal and sagittal slices (planes as :func:`slices`), nearest vertex's,
    blank outside."""
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib.pyplot as plt

    lo, hi = tree.box.lo, tree.box.hi
    z, y = _planes(tree, z, y)
    n = 1 << (level + 3)
    xs, ys, zs = (np.linspace(lo[i], hi[i], n) for i in range(3))
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    gx2, gz = np.meshgrid(xs, zs, indexing="ij")
    horiz = tree.index_at(np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], 1)).reshape(gx.shape)
    sag = tree.index_at(np.stack([gx2.ravel(), np.full(gx2.size, y), gz.ravel()], 1)).reshape(gx2.shape)
    for ax, (a, b, v) in zip(axes, ((gx, gy, horiz), (gx2, gz, sag)), strict=True):
        image = ax.pcolormesh(a, b, np.ma.masked_invalid(v), vmin=0.0, vmax=1.0, cmap="viridis", shading="nearest")
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
        ax.set_xlabel("x forward [m]")
    axes[0].set_title(f"{name}: index, z = {z:.2f} m")
    axes[0].set_ylabel("y left [m]")
    axes[1].set_title(f"{name}: index, y = {y:.2f} m")
    axes[1].set_ylabel("z up [m]")
    fig.colorbar(image, ax=axes, shrink=0.8, label=f"share of {directions} approach directions reached")
    return _save(fig, path, tight=False)


def _planes(tree: ReachMap, z: float | None, y: float | None) -> tuple[float, float]:
    """The slices' heights: z the box's middle and y = 0 unless given (y within the box)."""
    lo, hi = tree.box.lo, tree.box.hi
    return (float(0.5 * (lo[2] + hi[2])) if z is None else z), (0.0 if y is None or not lo[1] <= y <= hi[1] else y)


def slices(trees: dict[str, VATree], path: Path, level: int, z: float | None = None, y: float | None = None) -> Path:
    """Horizontal (z = const, default the box's middle) and sagittal (y = const, default 0) slices of every strategy."""
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib.pyplot as plt

    first = next(iter(trees.values()))
    lo, hi = first.box.lo, first.box.hi
    z, y = _planes(first, z, y)
    n = 1 << (level + 2)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    xs, ys, zs = (np.linspace(lo[i], hi[i], n) for i in range(3))
    for k, (name, tree) in enumerate(trees.items()):
        colour = COLOURS[k % len(COLOURS)]
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        horiz = tree.contains(np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], 1), "vertex").reshape(gx.shape)
        gx2, gz = np.meshgrid(xs, zs, indexing="ij")
        sag = tree.contains(np.stack([gx2.ravel(), np.full(gx2.size, y), gz.ravel()], 1), "vertex").reshape(gx2.shape)
        for ax, (a, b, occ) in zip(axes, ((gx, gy, horiz), (gx2, gz, sag)), strict=True):
            if occ.any() and not occ.all():
                ax.contour(a, b, occ.astype(float), levels=[0.5], colors=[colour])
            ax.plot([], [], color=colour, label=name)
    axes[0].set_title(f"horizontal slice, z = {z:.2f} m")
    axes[0].set_xlabel("x forward [m]")
    axes[0].set_ylabel("y left [m]")
    axes[1].set_title(f"sagittal slice, y = {y:.2f} m")
    axes[1].set_xlabel("x forward [m]")
    axes[1].set_ylabel("z up [m]")
    for ax in axes:
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, loc="upper right")
    return _save(fig, path)


def _save(fig: Any, path: Path, tight: bool = True) -> Path:
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def report(atlas: Atlas, out: str | Path, level: int = 4, names: list[str] | None = None,
           planes: tuple[float | None, float | None] = (None, None)) -> dict[str, Any]:
    """Write the tables and figures into out; returns the tables with the figure paths. ``planes``: the
    slices' z and y [m] (None: the box's middle height, and y = 0)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t = tables(atlas)
    (out / "report.md").write_text(markdown(t, str(atlas.manifest.get("name", atlas.path))))
    t["figures"] = [str(p) for p in figures(atlas, out, level, names, planes)]

    (out / "report.json").write_text(json.dumps(finite(t), indent=2, allow_nan=False))
    return t


def placement_map(ranking: Ranking, targets: Sequence[Target], path: Any, title: str = "") -> Any:
    """A figure of the floor (x, y): per position, the best share of targets reached over headings and heights, the
    targets, and the best placement's position and heading; or of a seat's track (x, z) when y is fixed and z is not."""
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # matplotlib (about half a second) only when a figure is drawn
    import matplotlib.pyplot as plt

    p = ranking.placements
    track = np.unique(p[:, 1]).size == 1 and np.unique(p[:, 2]).size > 1
    a, b = (0, 2) if track else (0, 1)
    xs, ys = np.unique(p[:, a]), np.unique(p[:, b])
    grid = np.full((len(xs), len(ys)), np.nan)
    ix, iy = np.searchsorted(xs, p[:, a]), np.searchsorted(ys, p[:, b])
    np.fmax.at(grid, (ix, iy), ranking.reached)
    fig, ax = plt.subplots(figsize=(7, 6))
    image = ax.pcolormesh(xs, ys, grid.T, vmin=0.0, vmax=1.0, cmap="viridis", shading="nearest")
    t = np.array([tg.point for tg in targets])
    best = p[0]
    if track:
        ax.plot([best[0]], [best[2]], "o", color="white", label=f"best: x {best[0]:.3f} m, z {best[2]:.3f} m")
        ax.set_ylabel("z: the seat's height offset [m]")
        ax.set_xlabel("x: the seat's position on its track [m]")
        ax.set_title(title or "share of targets reached along the seat's track")
    else:
        bx, by, _, yaw = best
        ax.scatter(t[:, 0], t[:, 1], marker="x", color="red", label="targets")
        ax.arrow(bx, by, 0.15 * math.cos(yaw), 0.15 * math.sin(yaw), width=0.01, color="white",
                 length_includes_head=True)
        ax.plot([bx], [by], "o", color="white", label=f"best: ({bx:.2f}, {by:.2f}) m, {math.degrees(yaw):.0f} deg")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(title or "share of targets reached, best heading per position")
    ax.legend(fontsize=7, loc="upper right")
    fig.colorbar(image, ax=ax, shrink=0.8, label="share of targets reached (over bodies)")
    return _save(fig, path)
