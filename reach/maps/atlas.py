"""An atlas: a folder with one tree file per strategy (:mod:`reach.maps.store`), its ``manifest.json``, the last
audit beside it and the lock a build holds.

Every failure to read names the file and what is wrong with it.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import math
import os
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from reach.errors import StoreError, UnknownName, UnknownStrategy
from reach.maps.index import IndexedTree, ReachIndex
from reach.maps.protocol import ReachMap
from reach.maps.store import atomic_write, load_indexed, read_header
from reach.maps.tree import VATree

ATLAS_FORMAT = "reach.atlas"
ATLAS_VERSION = 1
MANIFEST = "manifest.json"


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

    def landmark(self, name: str) -> list[float]:
        """A frame's position [m] in the body's reference posture, as the build recorded it (the manifest's
        ``landmarks``). StoreError when it recorded none (an atlas built before they were, or of a shape without named
        frames; ``reach build --resume`` records them, keeping the trees); UnknownName for a frame the body lacks."""
        path = self.path / MANIFEST
        found = self.manifest.get("landmarks")
        if found is None:
            raise StoreError(path, "no landmarks recorded (built before they were, or a body without named frames): "
                                   "run reach build --resume on its config to record them")
        if not isinstance(found, dict):
            raise StoreError(path, "landmarks: expected an object of frame name -> [x, y, z]")
        if name not in found:
            raise UnknownName(name, sorted(found), "relative_to")
        point = found[name]
        if not (isinstance(point, list) and len(point) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in point)):
            raise StoreError(path, f"landmarks.{name}: expected [x, y, z] in metres")
        return [float(v) for v in point]

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
        raise StoreError(path, "not a regular file (a FIFO, a device or a folder); expected an atlas's manifest"
                         if path.exists() or path.is_symlink() else
                         "missing; this folder is not an atlas written by 'reach build'")
    manifest = read_header(path, _manifest_bytes(path), ATLAS_FORMAT, ATLAS_VERSION, "atlas")
    if manifest.get("digest") != manifest_digest(manifest):
        # Priorities, strategies or model hashes edited by hand would change the answers silently.
        raise StoreError(path, "its content does not match its digest: it was edited after 'reach build' wrote it "
                               "(or written by an older reach); rebuild the atlas, or accept the manifest as it is "
                               "with 'reach accept ATLAS'")
    _check_strategies(path, folder, manifest)
    return manifest


# The largest manifest read [bytes]: the demo's is about 20 KB; a 300 MB one was read whole.
MAX_MANIFEST_BYTES = 16 * 2**20


def _manifest_bytes(path: Path) -> bytes:
    """A manifest's bytes: a regular file inside its folder (not a link out of it), of bounded size."""
    if path.is_symlink():
        raise StoreError(path, "is a symbolic link; an atlas's manifest is a file of its own folder")
    return bounded_bytes(path, MAX_MANIFEST_BYTES, "a manifest", " (is this an atlas?)")


def bounded_bytes(path: Path, limit: int, what: str, hint: str = "") -> bytes:
    """A regular file's bytes, at most ``limit`` of them: a FIFO would block the reader for ever and a device (a link
    to /dev/zero) fill its memory, so both are refused, as is a larger file (``what`` names it in the error, ``hint``
    ends it)."""
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise StoreError(path, f"not a regular file (a FIFO, a device or a folder); expected {what}")
        if info.st_size > limit:
            raise StoreError(path, f"{info.st_size} bytes; {what} is at most {limit}{hint}")
        with open(path, "rb") as fh:
            data = fh.read(limit + 1)
    except OSError as exc:
        raise StoreError(path, f"cannot read: {exc.strerror or exc}") from exc
    if len(data) > limit:
        raise StoreError(path, f"more than {limit} bytes; {what} is at most {limit}{hint}")
    return data


def _check_strategies(path: Path, folder: Path, manifest: dict[str, Any]) -> None:
    """A manifest's strategy list: at least one, each a name and a tree file inside the atlas folder."""
    strategies = manifest.get("strategies")
    if not isinstance(strategies, list) or not all(isinstance(s, dict) and "name" in s and "file" in s
                                                   for s in strategies):
        raise StoreError(path, "'strategies' must be a list of objects with 'name' and 'file'")
    if not strategies:
        raise StoreError(path, "'strategies' is empty: an atlas holds at least one tree; rebuild it with 'reach build'")
    names = [s["name"] for s in strategies]
    twice = sorted({n for n in names if not isinstance(n, str) or names.count(n) > 1}, key=str)
    if twice:
        raise StoreError(path, f"strategy {twice[0]!r} is listed twice (or is not a name); rebuild the atlas")
    # A tree file is a plain name inside the atlas folder: a path out of it (../, absolute, a link) is refused unread.
    outside = next((s for s in strategies if not _inside(folder, s["file"])), None)
    if outside is not None:
        raise StoreError(path, f"strategy {outside.get('name')!r}: 'file' must name a file inside the atlas folder, "
                               f"got {outside['file']!r}")


def _inside(folder: Path, name: Any) -> bool:
    """Whether a manifest's file name is a plain name inside the folder (not a path, not a link)."""
    return isinstance(name, str) and Path(name).name == name and name not in (".", "..") and not (
        folder / name).is_symlink()


def accept_manifest(folder: str | Path) -> Atlas:
    """Accept an atlas's manifest as it now is (a deliberate hand edit): stamp its digest, once the atlas loads with
    it."""
    folder = Path(folder)
    path = folder / MANIFEST
    if not path.is_file():
        raise StoreError(path, "not a regular file (a FIFO, a device or a folder); expected an atlas's manifest"
                         if path.exists() or path.is_symlink() else
                         "missing; this folder is not an atlas written by 'reach build'")
    manifest = read_header(path, _manifest_bytes(path), ATLAS_FORMAT, ATLAS_VERSION, "atlas")
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
