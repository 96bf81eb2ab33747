"""Trees on disk (an atlas's folder: :mod:`reach.maps.atlas`).

A tree is one ``.npz`` file (a zip of ``.npy`` arrays, read with
``allow_pickle=False``) holding the node arrays, the vertex table, the
reachability index when there is one, and a ``meta`` array of UTF-8 JSON.

Every failure to read names the file and what is wrong with it; a numpy or
zip traceback never reaches the user, and nothing is ever unpickled.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from reach.errors import StoreError, TreeError
from reach.maps.box import Box
from reach.maps.index import ReachIndex
from reach.maps.tree import FINAL, INNER, MAX_DEPTH, OUTER, PARENT, Lattice, VATree, VertexTable, bfs_children

TREE_FORMAT = "reach.vatree"
TREE_VERSION = 1


def atomic_write(path: Path, write: Any) -> None:
    """Write through a temporary file so a killed process never leaves half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def digest(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 of a tree's arrays (every one but ``meta``: names, dtypes, shapes and bytes), in hex."""
    h = hashlib.sha256()
    for name in sorted(k for k in arrays if k != "meta"):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_tree(tree: VATree, path: str | Path, index: ReachIndex | None = None) -> Path:
    """Write a tree, and its reachability index when it has one, to path (``.npz``), with the digest of its arrays
    in its metadata; returns the path."""
    path = Path(path)
    meta = {
        **tree.meta,
        "format": TREE_FORMAT,
        "version": TREE_VERSION,
        "box": tree.box.to_dict(),
        "d_min": tree.d_min,
        "d_max": tree.d_max, "posture_names": list(tree.vertices.posture_names),
    }
    arrays: dict[str, np.ndarray] = {
        "depth": tree.depth.astype(np.uint8),
        "corner": tree.corner.astype(np.int64),
        "kind": tree.kind.astype(np.uint8), "vertex_keys": tree.vertices.keys.astype(np.int64),
        "vertex_reachable": tree.vertices.reachable.astype(bool),
        "vertex_residual": tree.vertices.residual.astype(float),
    }
    if tree.vertices.posture is not None:
        arrays["vertex_posture"] = tree.vertices.posture.astype(float)
    if index is not None:
        arrays.update(index.to_arrays())
    meta["digest"] = tree.meta["digest"] = digest(arrays)
    arrays["meta"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda fh: np.savez_compressed(fh, **arrays))  # type: ignore[arg-type]
    return path


# [bytes] the most one array of a tree file may inflate to: a D_max 9 tree's postures (about 2 million vertices x 42
# coordinates x 8 bytes) fit four times over.
MAX_MEMBER_BYTES = 2**31


# The largest value a stored posture may hold (a joint's angle [rad], a root's position [m]): postures of 1e308 were
# accepted (its measurement not found again: as first written).
MAX_COORDINATE = 1e4

# The members a tree file holds (save_tree); others are never inflated.
TREE_MEMBERS = frozenset({"meta", "depth", "corner", "kind", "vertex_keys", "vertex_reachable", "vertex_residual",
                          "vertex_posture", "index_directions", "index_bits"})
# The most a file's members read may inflate to together: three members each under MAX_MEMBER_BYTES took a command
# to 4.2 GB before it refused them (commit 5f7c646). The demo's largest tree inflates to about 30 MB.
MAX_TOTAL_BYTES = 2**31


def read_arrays(path: Path, members: frozenset[str] | None = None) -> dict[str, np.ndarray]:
    """The arrays of an .npz file: those named in ``members`` (all when None), each and all together bounded in size
    before anything is inflated."""
    if not path.is_file():
        raise StoreError(path, "no such tree file")
    if not zipfile.is_zipfile(path):
        raise StoreError(path, "not a readable tree file (not an .npz zip archive; truncated or corrupt?)")
    try:
        wanted = _bounded_members(path, members)
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in wanted}
    except StoreError:
        raise
    except (zipfile.BadZipFile, EOFError) as exc:
        raise StoreError(path, f"not a readable tree file (truncated or corrupt zip: {exc})") from exc
    except ValueError as exc:
        raise StoreError(path, f"corrupt or unsafe array data ({exc})") from exc
    except OSError as exc:
        raise StoreError(path, f"cannot read: {exc}") from exc
    except Exception as exc:  # zlib.error, struct.error and friends from a damaged member
        raise StoreError(path, f"corrupt tree file ({type(exc).__name__}: {exc})") from exc


def _bounded_members(path: Path, members: frozenset[str] | None) -> list[str]:
    """The archive's arrays to read (``members``, all when None), once their sizes, read from its directory, are
    within bounds: a member of gigabytes of zeros compresses to a few megabytes, and every member was decompressed
    on load."""
    wanted: list[str] = []
    total = 0
    with zipfile.ZipFile(path) as archive:
        infos = [i for i in archive.infolist() if members is None  # others are never inflated
                 or (i.filename.endswith(".npy") and i.filename.removesuffix(".npy") in members)]
    strange = [i.filename for i in infos if not i.filename.endswith(".npy")]
    if strange:
        raise StoreError(path, f"member {strange[0]!r} is not an .npy array")
    for info in infos:
        if info.file_size > MAX_MEMBER_BYTES:
            raise StoreError(path, f"member {info.filename!r} inflates to {info.file_size} bytes, more than the "
                                   f"{MAX_MEMBER_BYTES} a tree's array may hold")
        total += info.file_size
        if total > MAX_TOTAL_BYTES:
            raise StoreError(path, f"its arrays inflate to over {MAX_TOTAL_BYTES} bytes together, more than a tree "
                                   "file holds")
        wanted.append(info.filename.removesuffix(".npy"))
    return wanted


def read_header(path: Path, raw: bytes, fmt: str, version: int, what: str) -> dict[str, Any]:
    """Parse JSON metadata and check its format and version, or raise a StoreError naming the file."""
    try:
        meta = json.loads(raw.decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StoreError(path, f"metadata is not valid JSON ({exc})") from exc
    except RecursionError:
        raise StoreError(path, "metadata is JSON nested too deeply") from None
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        found = meta.get("format") if isinstance(meta, dict) else None
        raise StoreError(path, f"not a reach {what} (format {found!r}, expected {fmt!r})")
    if meta.get("version") != version:
        raise StoreError(path, f"{what} format version {meta.get('version')!r}, this reach reads version {version}; "
                               "rebuild it")
    return meta


def checked_field(path: Path, arrays: dict[str, np.ndarray], name: str, dtype: Any, ndim: int) -> np.ndarray:
    if name not in arrays:
        raise StoreError(path, f"missing array {name!r}")
    arr = arrays[name]
    if arr.ndim != ndim or not np.can_cast(arr.dtype, dtype, casting="same_kind"):
        raise StoreError(path, f"array {name!r} has dtype {arr.dtype} and {arr.ndim} dimensions, expected "
                               f"{np.dtype(dtype)} with {ndim}")
    return arr.astype(dtype, copy=False)


def read_vertices(path: Path, arrays: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                    np.ndarray | None]:
    """A vertex table's arrays as a tree or a build's checkpoint stores them: keys, verdicts, residuals, postures."""
    keys = checked_field(path, arrays, "vertex_keys", np.int64, 1)
    reachable = checked_field(path, arrays, "vertex_reachable", bool, 1)
    residual = checked_field(path, arrays, "vertex_residual", float, 1)
    posture = checked_field(path, arrays, "vertex_posture", float, 2) if "vertex_posture" in arrays else None
    return keys, reachable, residual, posture


def load_tree(path: str | Path) -> VATree:
    """Read a tree written by :func:`save_tree` (without its index: see :func:`load_indexed`)."""
    return load_indexed(path)[0]


def load_indexed(path: str | Path) -> tuple[VATree, ReachIndex | None]:
    """Read a tree written by :func:`save_tree`, and its reachability index (None when it has none).

    Raises:
        StoreError: The file is missing, truncated, corrupt, inconsistent or
            of another format version.
    """
    path = Path(path)
    arrays = read_arrays(path, TREE_MEMBERS)
    meta = read_header(path, checked_field(path, arrays, "meta", np.uint8, 1).tobytes(), TREE_FORMAT, TREE_VERSION,
                       "tree")
    try:
        box = Box(np.asarray(meta["box"]["min"], float), np.asarray(meta["box"]["max"], float))
        d_min, d_max = int(meta["d_min"]), int(meta["d_max"])
        names = tuple(str(n) for n in meta.get("posture_names", []))
    except (KeyError, TypeError, ValueError, TreeError) as exc:
        raise StoreError(path, f"metadata lacks a valid box or depths ({exc})") from exc
    if not 0 <= d_min <= d_max <= MAX_DEPTH:
        raise StoreError(path, f"depths D_min {d_min}, D_max {d_max} are outside 0 <= D_min <= D_max <= {MAX_DEPTH}")
    depth = checked_field(path, arrays, "depth", np.uint8, 1)
    corner = checked_field(path, arrays, "corner", np.int64, 2)
    kind = checked_field(path, arrays, "kind", np.uint8, 1)
    keys, reach_, residual, posture = read_vertices(path, arrays)
    problems = _tree_problems(box.dim, d_max, depth, corner, kind, keys, reach_, residual, posture, names)
    if problems:
        raise StoreError(path, "; ".join(problems))
    if "digest" in meta and meta["digest"] != digest({k: v for k, v in arrays.items() if k != "meta"}):
        raise StoreError(path, "its arrays do not match the digest in its metadata (altered after it was written?); "
                               "rebuild it")
    meta = {k: v for k, v in meta.items() if k not in ("format", "version", "box", "d_min", "d_max", "posture_names")}
    vertices = VertexTable(keys, reach_, residual, posture, names)
    wrong = _labels_contradicting_verdicts(Lattice(box, d_max), depth, corner, kind, vertices)
    if wrong:
        raise StoreError(path, f"{wrong} inner or outer cells contradict their vertices' verdicts (inverted verdicts "
                               "or shifted corners?)")
    index = ReachIndex.from_arrays(arrays, keys.shape[0], path)
    if index is not None and np.any(index.reached[~reach_]):
        raise StoreError(path, "the reachability index holds directions reached at unreachable vertices")
    return VATree(box, d_min, d_max, depth, corner, kind, bfs_children(kind, box.dim), vertices, meta), index


def _tree_problems(dim: int, d_max: int, depth: np.ndarray, corner: np.ndarray, kind: np.ndarray, keys: np.ndarray,
                   reach_: np.ndarray, residual: np.ndarray, posture: np.ndarray | None,
                   names: tuple[str, ...]) -> list[str]:
    """What makes a tree's arrays inconsistent with each other (none: an empty list)."""
    n = kind.shape[0]
    problems = []
    if n == 0 or depth.shape != (n,) or corner.shape != (n, dim):
        problems.append(f"node arrays disagree: {n} kinds, {depth.shape[0]} depths, corners {corner.shape}")
    elif kind.max() > FINAL or depth.max() > d_max or n != 1 + np.count_nonzero(kind == PARENT) * (1 << dim):
        problems.append("node kinds, depths or parent count are inconsistent")
    if not (keys.shape == reach_.shape == residual.shape) or (keys.size > 1 and np.any(np.diff(keys) <= 0)):
        problems.append("vertex table arrays disagree in length or keys are not sorted")
    if posture is not None:
        problems += _posture_problems(posture, keys.shape[0], names)
    if residual.shape == keys.shape and not np.all(np.isfinite(residual) | ~reach_.astype(bool)):
        problems.append(f"{int(np.sum(~np.isfinite(residual) & reach_.astype(bool)))} reachable vertices have NaN or "
                        "infinite residuals")
    return problems


def _posture_problems(posture: np.ndarray, vertices: int, names: tuple[str, ...]) -> list[str]:
    """What is wrong with a tree's stored postures (none: an empty list): their shape, or values no posture takes."""
    if posture.shape != (vertices, len(names)):
        return [f"postures {posture.shape} do not match {vertices} vertices x {len(names)} names"]
    if not np.all(np.isfinite(posture)):
        return [f"{int(np.sum(~np.all(np.isfinite(posture), axis=1)))} stored postures hold NaN or infinite values"]
    if posture.size and np.abs(posture).max() > MAX_COORDINATE:
        return [f"stored postures hold values up to {np.abs(posture).max():.3g}, past {MAX_COORDINATE:g} (rad or m)"]
    return []


def _labels_contradicting_verdicts(lattice: Lattice, depth: np.ndarray, corner: np.ndarray, kind: np.ndarray,
                                   vertices: VertexTable) -> int:
    """How many inner cells have a vertex not reachable (or never evaluated), and outer cells one reachable."""
    wrong = 0
    for label, want in ((INNER, True), (OUTER, False)):
        sel = np.nonzero(kind == label)[0]
        for d in np.unique(depth[sel]):
            cells = sel[depth[sel] == d]
            rows = vertices.index(lattice.node_vertex_keys(corner[cells], int(d)))
            ok = (rows >= 0) & (vertices.reachable[np.maximum(rows, 0)] == want)
            wrong += int(np.sum(~ok.all(axis=1)))
    return wrong
