"""A population's accommodation volume: per point, the share of members whose tree holds it.

``reach report POPULATION -o DIR`` (a folder built from a config with ``population:``) samples a grid over the union of
the members' boxes (``2**(level + 2)`` points an axis), and for each strategy, and for ``any`` (a member reaches the
point by one of its strategies), sums the weights of the members whose tree contains each point (the ``vertex``
policy, as ``reach evaluate --no-refine`` takes the trees' word). It writes:

* ``accommodation.json`` and ``accommodation.md``: per strategy, the volume [m^3] that at least 5 %, 50 % and 95 % of
  the population reach (grid cells counted; the grid's spacing bounds the error);
* ``accommodation_<strategy>.png``: a horizontal and a sagittal slice of the share, with its 5, 50 and 95 % contours;
* ``accommodation_<strategy>_<p>.ply``: the isosurface at p % (marching cubes, metres, the members' world frame),
  and ``accommodation_<strategy>_3d.png`` the three together.

The trees' word, not IK at each point: a member's boundary cells hold points no posture reaches within half a cell.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from reach.answers.accommodation import load_members, shares
from reach.maps.atlas import Atlas

LEVELS = (0.05, 0.5, 0.95)  # the shares drawn and tabulated (5 / 50 / 95 %)
VIEW_LEVEL = 3  # the viewer's grid: 32 points an axis (about 33,000 points; dots the size of the spacing)


def grid(atlases: list[Atlas], level: int) -> tuple[list[np.ndarray], np.ndarray]:
    """The axes and the points (N, 3) of a grid over the union of every member's trees' boxes."""
    lo = np.min([t.box.lo for a in atlases for t in a.trees.values()], axis=0)
    hi = np.max([t.box.hi for a in atlases for t in a.trees.values()], axis=0)
    n = 1 << (level + 2)
    axes = [np.linspace(lo[i], hi[i], n) for i in range(3)]
    return axes, np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def report(folder: str | Path, out: str | Path, level: int = 4, z: float | None = None,
           y: float = 0.0) -> dict[str, Any]:
    """Write the accommodation tables, slices and isosurfaces of a population folder (see the module)."""
    atlases, weights, _ = load_members(folder)
    axes, points = grid(atlases, level)
    n = len(axes[0])
    cell = float(np.prod([(a[-1] - a[0]) / (n - 1) for a in axes]))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    found = shares(atlases, weights, points)
    z = float(0.5 * (axes[2][0] + axes[2][-1])) if z is None else z
    table: dict[str, Any] = {"members": len(atlases), "grid": n, "cell_m3": cell, "strategies": {}, "figures": []}
    for name, share in found.items():
        volume = {f"{round(100 * p)}%": round(float(np.sum(share >= p - 1e-9)) * cell, 4) for p in LEVELS}
        table["strategies"][name] = {"volume_m3": volume, "max_share": round(float(share.max()), 4)}
        cube = share.reshape(n, n, n)
        table["figures"].append(str(_slices(name, cube, axes, z, y, out / f"accommodation_{name}.png")))
        table["figures"] += [str(p) for p in _isosurfaces(name, cube, axes, out)]
    (out / "accommodation.json").write_text(json.dumps(table, indent=1))
    (out / "accommodation.md").write_text(markdown(table, str(folder)))
    return table


def markdown(table: dict[str, Any], title: str) -> str:
    lines = [f"# Accommodation: {title}", "",
             f"{table['members']} members; grid {table['grid']}^3 points, a cell {table['cell_m3']:.2e} m^3. Volume "
             "[m^3] that at least 5 / 50 / 95 % of the population reach, by the trees (`any`: by some strategy).", "",
             "| strategy | 5 % | 50 % | 95 % |", "| --- | --- | --- | --- |"]
    for name, s in table["strategies"].items():
        v = s["volume_m3"]
        lines.append(f"| {name} | {v['5%']:.3f} | {v['50%']:.3f} | {v['95%']:.3f} |")
    return "\n".join(lines) + "\n"


def _slices(name: str, cube: np.ndarray, axes: list[np.ndarray], z: float, y: float, path: Path) -> Path:
    # matplotlib only when a figure is drawn
    import matplotlib.pyplot as plt

    iz = int(np.argmin(np.abs(axes[2] - z)))
    iy = int(np.argmin(np.abs(axes[1] - y)))
    fig, ax = plt.subplots(1, 2, figsize=(11, 5))
    for a, (u, v, plane, title, vlabel) in zip(ax, (
            (axes[0], axes[1], cube[:, :, iz], f"horizontal slice, z = {axes[2][iz]:.2f} m", "y left [m]"),
            (axes[0], axes[2], cube[:, iy, :], f"sagittal slice, y = {axes[1][iy]:.2f} m", "z up [m]")), strict=True):
        gu, gv = np.meshgrid(u, v, indexing="ij")
        filled = a.contourf(gu, gv, 100 * plane, levels=np.linspace(0, 100, 11), cmap="viridis")
        if 0 < plane.max() and plane.min() < 1:
            lines = a.contour(gu, gv, 100 * plane, levels=[100 * p for p in LEVELS], colors=["w", "orange", "r"])
            a.clabel(lines, fmt="%d %%", fontsize=7)
        a.set_title(f"{name}: {title}")
        a.set_xlabel("x forward [m]")
        a.set_ylabel(vlabel)
        a.set_aspect("equal")
    fig.colorbar(filled, ax=ax, label="members whose tree holds the point [%]", shrink=0.8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _isosurfaces(name: str, cube: np.ndarray, axes: list[np.ndarray], out: Path) -> list[Path]:
    # scikit-image, trimesh and matplotlib only when surfaces are written
    import matplotlib.pyplot as plt
    import trimesh
    from skimage.measure import marching_cubes

    spacing = tuple(float((a[-1] - a[0]) / (len(a) - 1)) for a in axes)
    origin = np.array([a[0] for a in axes]) - np.array(spacing)
    padded = np.pad(cube, 1)
    written: list[Path] = []
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(111, projection="3d")
    for p, colour in zip(LEVELS, ("tab:blue", "tab:orange", "tab:red"), strict=True):
        if not (padded.max() >= p > 0):
            continue
        verts, faces, _, _ = marching_cubes(padded, level=p - 1e-6, spacing=spacing)
        verts += origin
        path = out / f"accommodation_{name}_{round(100 * p)}.ply"
        trimesh.Trimesh(vertices=verts, faces=faces[:, ::-1], process=False).export(path)
        written.append(path)
        ax.plot_trisurf(verts[:, 0], verts[:, 1], faces, verts[:, 2], color=colour, alpha=0.25 if p < 0.9 else 0.6,
                        linewidth=0)
        ax.plot([], [], color=colour, label=f"{round(100 * p)} %")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(f"{name}: reached by at least 5 / 50 / 95 % of members")
    ax.legend(fontsize=8, loc="upper left")
    ax.set_box_aspect([float(a[-1] - a[0]) for a in axes])
    figure = out / f"accommodation_{name}_3d.png"
    fig.savefig(figure, dpi=110)
    plt.close(fig)
    return [*written, figure]
