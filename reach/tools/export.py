"""Meshes of reachable volumes: marching cubes over the vertex lattice.

The grid holds every vertex of the finest lattice, valued 1 where the tree
contains it (``vertex`` policy) and 0 elsewhere, padded with zeros so that
the surface closes at the box; scikit-image's marching cubes extracts the
0.5 level and trimesh writes STL or PLY. Coordinates are metres in the
atlas's world frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reach.errors import InputError
from reach.maps.tree import VATree

MAX_GRID = 1 << 24  # vertices; above this the lattice is sampled coarser


def mesh(tree: VATree, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) [m] and triangles (m, 3) of the volume's surface."""
    # scikit-image only when a mesh is exported
    from skimage.measure import marching_cubes

    if tree.dim != 3:
        raise InputError("strategy", "meshes need a 3-D tree")
    level = tree.d_max if level is None else min(level, tree.d_max)
    while level > 1 and ((1 << level) + 1) ** 3 > MAX_GRID:
        level -= 1
    n = (1 << level) + 1
    axes = [np.linspace(lo, hi, n) for lo, hi in zip(tree.box.lo, tree.box.hi, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    occ = tree.contains(grid, "vertex").reshape(n, n, n).astype(np.float32)
    if not occ.any():
        raise InputError("strategy", "the volume is empty: nothing to mesh")
    padded = np.pad(occ, 1)
    spacing = tuple(float(s) for s in tree.box.size / (n - 1))
    verts, faces, _, _ = marching_cubes(padded, level=0.5, spacing=spacing)
    verts += tree.box.lo - np.array(spacing)  # undo the padding's offset
    faces = faces[:, ::-1]  # outward normals: the volume is positive
    return verts, faces


def export_mesh(tree: VATree, path: str | Path, level: int | None = None) -> Path:
    """Write the surface as .stl or .ply (chosen by the file's extension)."""
    # trimesh only when meshes are read or written
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in (".stl", ".ply"):
        raise InputError("--output", f"{path}: expected a .stl or .ply file name")
    verts, faces = mesh(tree, level)
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(vertices=verts, faces=faces, process=False).export(path)
    return path
