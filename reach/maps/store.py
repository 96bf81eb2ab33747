"""Trees and atlases on disk.

A tree is one ``.npz`` file (a zip of ``.npy`` arrays, read with
``allow_pickle=False``) holding the node arrays, the vertex table and a
``meta`` array of UTF-8 JSON. An atlas is a folder with one tree per strategy
and a ``manifest.json``.

Every failure to read names the file and what is wrong with it; a numpy or
zip traceback never reaches the user, and nothing is ever unpickled.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import time
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from reach.errors import StoreError, TreeError, UnknownStrategy
from reach.maps.box import Box
from reach.maps.index import IndexedTree, ReachIndex
from reach.maps.protocol import ReachMap
from reach.maps.tree import FINAL, INNER, MAX_DEPTH, OUTER, PARENT, Lattice, VATree, VertexTable, bfs_children

TREE_FORMAT = "reach.vatree"
TREE_VERSION = 1
ATLAS_FORMAT = "reach.atlas"
ATLAS_VERSION = 1
MANIFEST = "manifest.json"


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
        **tree.meta, "format": TREE_FORMAT, "version": TREE_VERSION,
        "box": tree.box.to_dict(), "d_min": tree.d_min,
        "d_max": tree.d_max, "posture_names": list(tree.vertices.posture_names),
    }
    arrays: dict[str, np.ndarray] = {
        "depth": tree.depth.astype(np.uint8), "corner": tree.corner.astype(np.int64),
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


def read_arrays(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise StoreError(path, "no such tree file")
    if not zipfile.is_zipfile(path):
        raise StoreError(path, "not a readable tree file (not an .npz zip archive; truncated or corrupt?)")
    try:
        # Sizes read from the archive's directory before anything is inflated: a member of gigabytes of zeros
        # compresses to a few megabytes, and every member was decompressed on load.
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if info.file_size > MAX_MEMBER_BYTES:
                    raise StoreError(path, f"member {info.filename!r} inflates to {info.file_size} bytes, more than "
                                           f"the {MAX_MEMBER_BYTES} a tree's array may hold")
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
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


def read_header(path: Path, raw: bytes, fmt: str, version: int, what: str) -> dict[str, Any]:
    """Parse JSON metadata and check its format and version, or raise a StoreError naming the file."""
    try:
        meta = json.loads(raw.decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StoreError(path, f"metadata is not valid JSON ({exc})") from exc
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
    arrays = read_arrays(path)
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
    n, dim = kind.shape[0], box.dim
    problems = []
    if n == 0 or depth.shape != (n,) or corner.shape != (n, dim):
        problems.append(f"node arrays disagree: {n} kinds, {depth.shape[0]} depths, corners {corner.shape}")
    elif kind.max() > FINAL or depth.max() > d_max or n != 1 + np.count_nonzero(kind == PARENT) * (1 << dim):
        problems.append("node kinds, depths or parent count are inconsistent")
    if not (keys.shape == reach_.shape == residual.shape) or (keys.size > 1 and np.any(np.diff(keys) <= 0)):
        problems.append("vertex table arrays disagree in length or keys are not sorted")
    if posture is not None and posture.shape != (keys.shape[0], len(names)):
        problems.append(f"postures {posture.shape} do not match {keys.shape[0]} vertices x {len(names)} names")
    elif posture is not None and not np.all(np.isfinite(posture)):
        problems.append(f"{int(np.sum(~np.all(np.isfinite(posture), axis=1)))} stored postures hold NaN or infinite "
                        "values")
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
    return VATree(box, d_min, d_max, depth, corner, kind, bfs_children(kind, dim), vertices, meta), index


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


@dataclass
class Atlas:
    """The trees of every strategy of a config, with its manifest.

    Attributes:
        path: The atlas folder.
        manifest: The parsed ``manifest.json``.
        trees: Strategy name -> tree, in priority order.
        indexes: Strategy name -> its reachability index, for the strategies that have one.
    """

    path: Path
    manifest: dict[str, Any]
    trees: dict[str, VATree]
    indexes: dict[str, ReachIndex] = field(default_factory=dict)
    maps: dict[str, ReachMap] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # What answers, motions and placements ask (reach.maps.protocol): each tree, with its index when it has one.
        # An atlas made in memory may give maps of another kind instead (tests/test_maps.py: a dense grid).
        for name, tree in self.trees.items():
            self.maps.setdefault(name, IndexedTree(tree, self.indexes[name]) if name in self.indexes else tree)

    def map(self, name: str) -> ReachMap:
        """The map of a strategy (:mod:`reach.maps.protocol`); UnknownStrategy names the ones there are."""
        if name not in self.maps:
            raise UnknownStrategy(name, list(self.maps))
        return self.maps[name]

    @property
    def strategies(self) -> list[dict[str, Any]]:
        """Manifest entries of the strategies, in priority order."""
        return list(self.manifest["strategies"])

    def tree(self, name: str) -> VATree:
        """The tree of a strategy; UnknownStrategy names the ones there are."""
        if name not in self.trees:
            raise UnknownStrategy(name, list(self.trees))
        return self.trees[name]

    def select(self, names: list[str] | None) -> list[str]:
        """The names asked for (every strategy for None), each checked to exist."""
        if not names:
            return list(self.maps)
        for n in names:
            self.map(n)
        return list(names)


def manifest_digest(manifest: dict[str, Any]) -> str:
    """The digest of a manifest's content, its own ``digest`` field left out (canonical JSON, SHA-256)."""
    body = {k: v for k, v in manifest.items() if k != "digest"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:32]


def write_manifest(folder: str | Path, manifest: dict[str, Any]) -> Path:
    """Write an atlas's manifest with the digest of its content, so that a hand edit is noticed on loading."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    body = {**{k: v for k, v in manifest.items() if k != "digest"}, "format": ATLAS_FORMAT, "version": ATLAS_VERSION}
    body["digest"] = manifest_digest(body)
    path = folder / MANIFEST
    atomic_write(path, lambda fh: fh.write(json.dumps(body, indent=2, sort_keys=True).encode()))
    return path


def read_manifest(folder: str | Path) -> dict[str, Any]:
    folder = Path(folder)
    path = folder / MANIFEST
    if not folder.is_dir():
        raise StoreError(folder, "no such atlas folder (expected the output of 'reach build')")
    if not path.is_file():
        raise StoreError(path, "missing; this folder is not an atlas written by 'reach build'")
    manifest = read_header(path, path.read_bytes(), ATLAS_FORMAT, ATLAS_VERSION, "atlas")
    if manifest.get("digest") != manifest_digest(manifest):
        # Priorities, strategies or model hashes edited by hand would change the answers silently.
        raise StoreError(path, "its content does not match its digest: it was edited after 'reach build' wrote it "
                               "(or written by an older reach); rebuild the atlas, or accept the manifest as it is "
                               "with 'reach accept ATLAS'")
    _check_strategies(path, folder, manifest)
    return manifest


def _check_strategies(path: Path, folder: Path, manifest: dict[str, Any]) -> None:
    """A manifest's strategy list: at least one, each a name and a tree file inside the atlas folder."""
    strategies = manifest.get("strategies")
    if not isinstance(strategies, list) or not all(isinstance(s, dict) and "name" in s and "file" in s
                                                   for s in strategies):
        raise StoreError(path, "'strategies' must be a list of objects with 'name' and 'file'")
    if not strategies:
        raise StoreError(path, "'strategies' is empty: an atlas holds at least one tree; rebuild it with 'reach build'")
    for s in strategies:
        # A tree file is a plain name inside the atlas folder: a path out of it (../, absolute, a link) is refused
        # unread.
        name = s["file"]
        if not isinstance(name, str) or Path(name).name != name or name in (".", "..") or (folder / name).is_symlink():
            raise StoreError(path, f"strategy {s.get('name')!r}: 'file' must name a file inside the atlas folder, "
                                   f"got {name!r}")


def accept_manifest(folder: str | Path) -> Atlas:
    """Accept an atlas's manifest as it now is (a deliberate hand edit): stamp its digest, once the atlas loads with
    it."""
    folder = Path(folder)
    path = folder / MANIFEST
    if not path.is_file():
        raise StoreError(path, "missing; this folder is not an atlas written by 'reach build'")
    manifest = read_header(path, path.read_bytes(), ATLAS_FORMAT, ATLAS_VERSION, "atlas")
    _check_strategies(path, folder, manifest)
    trees, indexes = _load_trees(folder, manifest)  # the edited manifest must hold, trees and all, before it is stamped
    write_manifest(folder, manifest)
    return Atlas(folder, read_manifest(folder), trees, indexes)


def load_atlas(folder: str | Path) -> Atlas:
    """Read an atlas folder: its manifest and every strategy's tree."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    return Atlas(folder, manifest, *_load_trees(folder, manifest))


def _load_trees(folder: Path, manifest: dict[str, Any]) -> tuple[dict[str, VATree], dict[str, ReachIndex]]:
    trees, indexes = {}, {}
    for s in manifest["strategies"]:
        path = folder / s["file"]
        tree, index = load_indexed(path)
        if index is not None:
            indexes[s["name"]] = index
        # A tree file copied over another's would otherwise be served under the wrong name.
        for key in ("name", "effector", "fingerprint", "digest"):
            if key in s and key in tree.meta and tree.meta[key] != s[key]:
                raise StoreError(path, f"holds the tree of {key} {tree.meta[key]!r}, but the manifest lists it for "
                                       f"{s[key]!r}; rebuild the atlas")
        trees[s["name"]] = tree
    return trees, indexes


AUDIT = "audit.json"  # the last `reach audit` of an atlas, beside its manifest
AUDIT_FORMAT = "reach.audit"


def save_audit(atlas: Atlas, result: dict[str, Any]) -> Path:
    """Keep an audit's result beside the atlas it audited (``audit.json``), each strategy with its tree's digest:
    ``reach info`` and ``reach report`` then warn of the regions the tree lacks, while the tree is the one audited."""
    record = {"format": AUDIT_FORMAT, "version": 1, "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "digests": {name: atlas.trees[name].meta.get("digest") for name in result.get("strategies", {})},
              "result": result}
    path = atlas.path / AUDIT
    atomic_write(path, lambda fh: fh.write(json.dumps(record, indent=1).encode()))
    return path


def load_audit(atlas: Atlas) -> dict[str, Any]:
    """The atlas's last audit (see :func:`save_audit`) by strategy: ``{"when", "current"}`` and, for a tree that is
    still the one audited (``current``), its short rays (``short``); empty without an audit. A file that cannot be
    read is a StoreError naming it (it is the audit's, never the atlas's: ``reach audit`` writes it again)."""
    path = atlas.path / AUDIT
    if not path.is_file():
        return {}
    record = read_header(path, path.read_bytes(), AUDIT_FORMAT, 1, "audit")
    digests, strategies = record.get("digests"), record.get("result", {}).get("strategies")
    if not isinstance(digests, dict) or not isinstance(strategies, dict):
        raise StoreError(path, "expected 'digests' and 'result.strategies' objects; run 'reach audit' again")
    out: dict[str, Any] = {}
    for name, tree in atlas.trees.items():
        if name not in digests or name not in strategies:
            continue
        current = digests[name] is not None and digests[name] == tree.meta.get("digest")
        short = strategies[name].get("rays", {}).get("short", []) if current else []
        out[name] = {"when": record.get("when"), "current": current, "short": short}
    return out


LOCK = ".lock"


@contextmanager
def build_lock(folder: str | Path) -> Iterator[None]:
    """Hold the atlas folder's build lock: a second build into the same folder is refused, not interleaved.

    An advisory ``flock`` on ``FOLDER/.lock``: the operating system releases
    it when the holder exits, even when killed, so no stale lock remains.
    """
    path = Path(folder) / LOCK
    fh = path.open("a+")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip() or "another process"
        fh.close()
        raise StoreError(folder, f"another build is writing into this folder ({holder}); wait for it or choose "
                                 "another output folder") from None
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()}")
        fh.flush()
        yield
    finally:
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()
