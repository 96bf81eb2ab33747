"""Saving and loading trees: round trips and clear errors on bad files."""

from __future__ import annotations

import json
import re
import zipfile

import numpy as np
import pytest

from reach.errors import StoreError
from reach.maps.atlas import accept_manifest, load_atlas, manifest_digest
from reach.maps.store import load_tree, save_tree


def test_round_trip_keeps_every_array_and_the_metadata(unit_sphere_tree, tmp_path):
    unit_sphere_tree.meta["name"] = "ball"
    path = save_tree(unit_sphere_tree, tmp_path / "ball.npz")
    back = load_tree(path)
    for name in ("depth", "corner", "kind", "child"):
        assert np.array_equal(getattr(back, name), getattr(unit_sphere_tree, name)), name
    assert np.array_equal(back.vertices.keys, unit_sphere_tree.vertices.keys)
    assert np.array_equal(back.vertices.reachable, unit_sphere_tree.vertices.reachable)
    assert back.box == unit_sphere_tree.box and (back.d_min, back.d_max) == (2, 6)
    assert back.meta["name"] == "ball" and back.meta["build"]["oracle_calls"] == unit_sphere_tree.oracle_calls
    pts = np.random.default_rng(0).uniform(-1, 1, (1000, 3))
    assert np.array_equal(back.classify(pts), unit_sphere_tree.classify(pts))


def test_postures_round_trip(tmp_path):
    from reach.maps.box import Box
    from reach.maps.tree import VATree, VertexTable, bfs_children

    kind = np.array([3], np.uint8)  # a boundary root: its vertices disagree
    table = VertexTable(np.array([0, 3]), np.array([True, False]), np.array([0.0, 0.2]),
                        np.array([[0.1, 0.2], [0.3, 0.4]]), ("a", "b"))
    tree = VATree(Box([0, 0], [1, 1]), 0, 1, np.zeros(1, np.uint8), np.zeros((1, 2), np.int64), kind,
                  bfs_children(kind, 2), table)
    back = load_tree(save_tree(tree, tmp_path / "p.npz"))
    assert back.vertices.posture_names == ("a", "b")
    assert np.array_equal(back.vertices.posture, table.posture)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(StoreError, match=r"nope\.npz: no such tree file"):
        load_tree(tmp_path / "nope.npz")


def test_truncated_file_is_a_clear_error(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "t.npz")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(StoreError, match=r"t\.npz: .*(truncated|corrupt)"):
        load_tree(path)


def test_a_member_that_inflates_past_the_bound_is_refused_before_it_is_inflated(unit_sphere_tree, tmp_path,
    monkeypatch):
    """A 2 GiB member of zeros (megabytes on disk) was decompressed on load. The bound is read from the
    archive's directory; here it is lowered so that the test writes little."""
    import zipfile

    import reach.maps.store as store

    path = save_tree(unit_sphere_tree, tmp_path / "z.npz")
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("vertex_posture.npy", bytes(10**7))  # a member trees hold (this tree has no postures)
    assert path.stat().st_size < 10**6  # megabytes of zeros take kilobytes
    monkeypatch.setattr(store, "MAX_MEMBER_BYTES", 8 * 10**6)
    with pytest.raises(StoreError, match=r"z\.npz: member 'vertex_posture\.npy' inflates to 10000000 bytes"):
        load_tree(path)


def test_members_a_tree_does_not_hold_are_never_inflated_and_all_are_bounded_together(unit_sphere_tree, tmp_path,
                                                                                      monkeypatch):
    """A 3 MB atlas with three 1 GiB members took every command to 4.2 GB before it refused it
    (each member was bounded, not their sum, and unused members were inflated too). Bounds lowered here so that the
    test writes little."""
    import reach.maps.store as store

    path = save_tree(unit_sphere_tree, tmp_path / "z.npz")
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as archive:
        for k in range(3):
            archive.writestr(f"padding{k}.npy", bytes(10**7))
        archive.writestr("notes.txt", b"not an array")
    monkeypatch.setattr(store, "MAX_MEMBER_BYTES", 2 * 10**7)
    monkeypatch.setattr(store, "MAX_TOTAL_BYTES", 2 * 10**7)
    assert load_tree(path).vertices.keys.shape == unit_sphere_tree.vertices.keys.shape  # the padding is never read
    with pytest.raises(StoreError, match=r"member 'notes\.txt' is not an \.npy array"):
        store.read_arrays(path)  # a reader of every member (a build's checkpoint) names it
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("vertex_posture.npy", bytes(10**7 - 100))
        archive.writestr("index_bits.npy", bytes(10**7 + 100))
    with pytest.raises(StoreError, match=r"z\.npz: its arrays inflate to over 20000000 bytes together"):
        load_tree(path)


def test_flipped_bytes_are_a_clear_error(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "c.npz")
    data = bytearray(path.read_bytes())
    for i in range(200, len(data) - 200, 97):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=r"c\.npz"):
        load_tree(path)


def test_garbage_file_is_a_clear_error(tmp_path):
    path = tmp_path / "g.npz"
    path.write_text("this is not a tree")
    with pytest.raises(StoreError, match=r"g\.npz: not a readable tree file"):
        load_tree(path)


def _rewrite(path, keep_digest=False, **changes):
    """Change a tree file's arrays or metadata; without keep_digest, as a writer that records no digest would."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(arrays["meta"].tobytes())
    if not keep_digest:
        meta.pop("digest", None)
    for k, v in changes.items():
        if k == "drop":
            arrays.pop(v)
        elif k.startswith("array_"):
            arrays[k[6:]] = v
        else:
            meta[k] = v
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(path, **arrays)


def test_other_format_version_is_refused(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "v.npz")
    _rewrite(path, version=99)
    with pytest.raises(StoreError, match=r"v\.npz: tree format version 99, this reach reads version 1"):
        load_tree(path)


def test_missing_array_is_named(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "m.npz")
    _rewrite(path, drop="kind")
    with pytest.raises(StoreError, match="missing array 'kind'"):
        load_tree(path)


def test_inconsistent_arrays_are_refused(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "i.npz")
    _rewrite(path, array_kind=unit_sphere_tree.kind[:-8])
    with pytest.raises(StoreError, match="node arrays disagree"):
        load_tree(path)


def test_pickled_object_arrays_are_never_loaded(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "o.npz")
    with zipfile.ZipFile(path, "a") as zf, zf.open("vertex_posture.npy", "w") as fh:  # a member trees hold
        np.save(fh, np.array([{"x": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(StoreError, match=r"o\.npz: corrupt or unsafe"):
        load_tree(path)


def test_atlas_without_manifest_is_named(tmp_path):
    with pytest.raises(StoreError, match="manifest.json: missing"):
        load_atlas(tmp_path)
    with pytest.raises(StoreError, match="no such atlas folder"):
        load_atlas(tmp_path / "absent")
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(StoreError, match="manifest.json: metadata is not valid JSON"):
        load_atlas(tmp_path)


def _checkpoint(tmp_path):
    from reach.building.checkpoint import save_state
    from reach.building.tree import BuildState
    from reach.maps.tree import VertexTable

    state = BuildState(2, np.zeros((4, 3), np.int64), [np.array([3], np.uint8), np.zeros(8, np.uint8)],
                       [np.zeros((1, 3), np.int64), np.zeros((8, 3), np.int64)],
                       VertexTable(np.array([1, 5]), np.array([True, False]), np.zeros(2), np.ones((2, 2)),
                                   ("a", "b")), [{"depth": 0}])
    return save_state(state, tmp_path / "s.npz", "fp")


def test_checkpoint_round_trip(tmp_path):
    from reach.building.checkpoint import load_state

    state = load_state(_checkpoint(tmp_path), "fp")
    assert state.depth == 2 and [k.size for k in state.kinds] == [1, 8] and state.vertices.posture_names == ("a", "b")
    assert load_state(tmp_path / "s.npz", "other") is None  # another build's checkpoint is ignored


@pytest.mark.parametrize(("field", "value", "message"), [
    ("sizes", [1, 7], r"checkpoint sizes \[1, 7\] do not match 9 kinds"),
    ("sizes", "many", "checkpoint metadata lacks valid sizes"),
    ("posture_names", ["a"], "checkpoint vertex arrays disagree"),
    ("depth", None, "checkpoint metadata lacks valid sizes, depth"),
])
def test_corrupt_checkpoint_metadata_is_a_clear_error(tmp_path, field, value, message):
    from reach.building.checkpoint import load_state

    path = _checkpoint(tmp_path)
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays["meta"].tobytes())
    meta[field] = value
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(path, **arrays)
    with pytest.raises(StoreError, match=message):
        load_state(path, "fp")


def test_an_impossible_depth_names_the_file(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "d.npz")
    _rewrite(path, d_max=40)
    with pytest.raises(StoreError, match=r"d\.npz: depths D_min 2, D_max 40 are outside"):
        load_tree(path)


def _two_vertex_tree(reachable, residual, postures):
    from reach.maps.box import Box
    from reach.maps.tree import VATree, VertexTable, bfs_children

    kind = np.array([1], np.uint8)
    table = VertexTable(np.array([0, 3]), np.array(reachable), np.array(residual), np.array(postures), ("a", "b"))
    return VATree(Box([0, 0], [1, 1]), 0, 1, np.zeros(1, np.uint8), np.zeros((1, 2), np.int64), kind,
                  bfs_children(kind, 2), table)


def test_huge_postures_and_nan_residuals_of_reached_vertices_are_refused(tmp_path):
    """Postures of 1e308 and NaN residuals were accepted silently."""
    huge = _two_vertex_tree([True, False], [0.0, 0.2], [[0.1, 1e308], [0.3, 0.4]])
    with pytest.raises(StoreError, match=r"stored postures hold values up to 1e\+308"):
        load_tree(save_tree(huge, tmp_path / "huge.npz"))
    nan = _two_vertex_tree([True, False], [np.nan, 0.2], [[0.1, 0.2], [0.3, 0.4]])
    with pytest.raises(StoreError, match="1 reachable vertices have NaN or infinite residuals"):
        load_tree(save_tree(nan, tmp_path / "nan_residual.npz"))


def test_a_manifest_that_is_a_link_too_large_too_deep_or_lists_a_strategy_twice_is_refused(tmp_path):
    """A manifest linked out of its folder, one of 300 MB, JSON nested 100,000 deep (a traceback)
    and duplicated strategies were read."""
    import reach.maps.atlas as atlas_module

    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text("{}")
    folder = tmp_path / "atlas"
    folder.mkdir()
    (folder / "manifest.json").symlink_to(elsewhere)
    with pytest.raises(StoreError, match="manifest.json: is a symbolic link"):
        load_atlas(folder)
    (folder / "manifest.json").unlink()
    (folder / "manifest.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(StoreError, match="manifest.json: metadata is JSON nested too deeply"):
        load_atlas(folder)
    (folder / "manifest.json").write_text(" " * 2000)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(atlas_module, "MAX_MANIFEST_BYTES", 1000)
        with pytest.raises(StoreError, match="manifest.json: 2000 bytes; a manifest is at most 1000"):
            load_atlas(folder)
    manifest = {"strategies": [{"name": "a", "file": "a.npz"}, {"name": "a", "file": "b.npz"}]}
    with pytest.raises(StoreError, match="strategy 'a' is listed twice"):
        atlas_module._check_strategies(folder / "manifest.json", folder, manifest)


def test_nan_postures_are_refused(tmp_path):
    from reach.maps.box import Box
    from reach.maps.tree import VATree, VertexTable, bfs_children

    kind = np.array([1], np.uint8)
    table = VertexTable(np.array([0, 3]), np.array([True, False]), np.array([0.0, 0.2]),
                        np.array([[0.1, np.nan], [0.3, 0.4]]), ("a", "b"))
    tree = VATree(Box([0, 0], [1, 1]), 0, 1, np.zeros(1, np.uint8), np.zeros((1, 2), np.int64), kind,
                  bfs_children(kind, 2), table)
    with pytest.raises(StoreError, match="1 stored postures hold NaN or infinite values"):
        load_tree(save_tree(tree, tmp_path / "nan.npz"))


def test_two_builds_into_one_folder_are_refused(tmp_path):
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config
    from reach.maps.atlas import build_lock

    config = parse_config({"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 3},
                           "oracle": {"name": "sphere", "params": {"radius": 0.9}}, "strategies": [{"name": "ball"}]})
    (tmp_path / "out").mkdir()
    with build_lock(tmp_path / "out"), pytest.raises(StoreError, match=r"another build is writing into this folder "
        r"\(pid \d+\)"):
        build_atlas(config, tmp_path / "out")
    assert build_atlas(config, tmp_path / "out").trees["ball"].volume() > 0  # released: the next build runs


def test_a_tree_copied_over_another_is_refused(tmp_path):
    import shutil

    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config

    config = parse_config({"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 2},
                           "oracle": {"name": "sphere", "params": {"radius": 0.9}},
                           "strategies": [{"name": "right", "effector": "a"}, {"name": "left", "effector": "b"}]})
    build_atlas(config, tmp_path / "out")
    shutil.copy(tmp_path / "out" / "left.npz", tmp_path / "out" / "right.npz")
    with pytest.raises(StoreError, match=r"right\.npz: holds the tree of name 'left', but the manifest lists it for "
                                         r"'right'"):
        load_atlas(tmp_path / "out")


def test_arrays_altered_after_writing_are_refused_by_their_digest(unit_sphere_tree, tmp_path):
    path = save_tree(unit_sphere_tree, tmp_path / "a.npz")
    residual = unit_sphere_tree.vertices.residual.copy()
    residual[3] += 0.01  # a change no structural check can see
    _rewrite(path, keep_digest=True, array_vertex_residual=residual)
    with pytest.raises(StoreError, match=r"a\.npz: its arrays do not match the digest"):
        load_tree(path)


def test_a_tree_replaced_by_another_build_of_the_same_strategy_is_refused(tmp_path):
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config

    raw = {"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 2},
           "oracle": {"name": "sphere", "params": {"radius": 0.9}}, "strategies": [{"name": "ball"}]}
    build_atlas(parse_config(raw), tmp_path / "a")
    build_atlas(parse_config({**raw, "depth": {"min": 1, "max": 3}}), tmp_path / "b")
    assert load_atlas(tmp_path / "a").manifest["strategies"][0]["digest"] == load_atlas(tmp_path
        / "a").trees["ball"].meta["digest"]
    import shutil

    shutil.copy(tmp_path / "b" / "ball.npz", tmp_path / "a" / "ball.npz")
    with pytest.raises(StoreError, match=r"ball\.npz: holds the tree of (fingerprint|digest)"):
        load_atlas(tmp_path / "a")


@pytest.mark.parametrize("change", ["invert", "shift"])
def test_verdicts_contradicting_the_labels_are_refused(unit_sphere_tree, tmp_path, change):
    path = save_tree(unit_sphere_tree, tmp_path / "t.npz")
    if change == "invert":
        _rewrite(path, array_vertex_reachable=~unit_sphere_tree.vertices.reachable)
    else:
        _rewrite(path, array_corner=unit_sphere_tree.corner + 1)
    with pytest.raises(StoreError, match=r"t\.npz: \d+ inner or outer cells contradict their vertices' verdicts"):
        load_tree(path)


def test_a_checkpoint_is_at_most_one_and_a_half_times_the_tree(tmp_path):
    """The last checkpoint of a build holds what the tree holds: no more bytes than the tree's arrays (it was 8x).

    Checkpoints are written uncompressed (the build's time), trees compressed."""
    from helpers import TwoLinkArm

    from reach.building.checkpoint import save_state
    from reach.building.tree import build_tree
    from reach.maps.box import Box

    states = []
    tree = build_tree(TwoLinkArm(), Box([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]), 2, 5, on_level=states.append)
    assert tree.vertices.posture is not None  # postures are most of the bytes
    with np.load(save_tree(tree, tmp_path / "tree.npz")) as z:
        raw = sum(z[k].nbytes for k in z.files)
    checkpoint = save_state(states[-1], tmp_path / "state.npz", "fp").stat().st_size
    assert checkpoint <= 1.5 * raw


@pytest.mark.parametrize(("file", "message"), [
    ("../../../../etc/passwd", "'file' must name a file inside the atlas folder, got '../../../../etc/passwd'"),
    ("/etc/passwd", "'file' must name a file inside the atlas folder, got '/etc/passwd'"),
    ("link.npz", "'file' must name a file inside the atlas folder, got 'link.npz'"),
])
def test_manifest_files_are_confined_to_the_atlas_folder(tmp_path, file, message):
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config

    config = parse_config({"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 2},
                           "oracle": {"name": "sphere", "params": {"radius": 0.9}},
                           "strategies": [{"name": "s", "effector": "a"}]})
    out = tmp_path / "out"
    build_atlas(config, out)
    (out / "link.npz").symlink_to(out / "s.npz")
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["strategies"][0]["file"] = file
    manifest["digest"] = manifest_digest(manifest)  # as if accepted: the confinement still holds
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(StoreError, match=f"manifest.json: strategy 's': {re.escape(message)}"):
        load_atlas(out)
    with pytest.raises(StoreError, match=f"manifest.json: strategy 's': {re.escape(message)}"):
        accept_manifest(out)
    manifest["strategies"] = []
    manifest["digest"] = manifest_digest(manifest)
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(StoreError, match="'strategies' is empty: an atlas holds at least one tree"):
        load_atlas(out)


def test_a_hand_edited_manifest_is_refused_until_accepted(tmp_path, capsys):
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config
    from reach.tools.cli import main

    config = parse_config({"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 2},
                           "oracle": {"name": "sphere", "params": {"radius": 0.9}},
                           "strategies": [{"name": "a", "effector": "p", "priority": 1},
                                          {"name": "b", "effector": "p", "priority": 2}]})
    out = tmp_path / "out"
    build_atlas(config, out)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["digest"] == manifest_digest(manifest) and load_atlas(out).manifest["digest"] == manifest["digest"]
    for edit in ({"swap": True}, {"strategies": manifest["strategies"][:1]}, {"drop_digest": True}):
        edited = json.loads(json.dumps(manifest))
        if edit.get("swap"):
            edited["strategies"][0]["priority"], edited["strategies"][1]["priority"] = 2, 1
        elif "strategies" in edit:
            edited["strategies"] = edit["strategies"]
        else:
            del edited["digest"]
        (out / "manifest.json").write_text(json.dumps(edited))
        with pytest.raises(StoreError, match="does not match its digest: it was edited after 'reach build' wrote "
                                             "it.*reach accept ATLAS"):
            load_atlas(out)
    assert main(["accept", str(out)]) == 0  # the last edit (no digest) accepted deliberately
    assert "manifest accepted as it is (2 strategies: a, b)" in capsys.readouterr().out
    assert set(load_atlas(out).trees) == {"a", "b"}
