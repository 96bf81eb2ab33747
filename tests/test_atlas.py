"""The atlas pipeline: executors, resume after SIGKILL, mirroring."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import ARM, LEFT_ARM, human_config, same_tree

from reach.building.atlas import build_atlas
from reach.building.config import load_config, parse_config
from reach.maps.atlas import load_atlas

pytestmark = pytest.mark.slow  # builds human atlases, kills and resumes a build

def _children(pid: int) -> list[int]:
    """PIDs whose parent is pid (from /proc)."""
    out = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(pid):
            out.append(int(status.parent.name))
    return out


def _alive(pid: int) -> bool:
    """Running, not gone nor a zombie waiting to be reaped."""
    try:
        state = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("State:"))
    except (OSError, StopIteration):
        return False
    return "Z" not in state.split()[1]


def test_killed_build_resumes_to_the_same_tree(tmp_path):
    cfg = tmp_path / "arm.yaml"
    cfg.write_text(yaml.safe_dump(human_config(d_max=4)))
    reference = build_atlas(load_config(cfg), tmp_path / "whole").trees["right_arm"]
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "reach.tools.cli", "build", str(cfg), "-o", str(out), "-q", "-j", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    partial = out / ".partial" / "right_arm.npz"
    deadline = time.monotonic() + 120
    while not partial.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    assert proc.poll() is None, "the build finished before it could be killed"
    time.sleep(0.3)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "right_arm.npz").exists() and partial.exists()
    done = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    same_tree(reference, load_atlas(out).trees["right_arm"])
    assert not partial.exists()
    again = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=300)
    assert "kept the finished tree" in again.stdout
    # A tree of another model of the same spec (a new version of the generated human) is rebuilt, not kept to be
    # refused by every answer.
    from reach.maps.store import load_tree, save_tree

    tree = load_tree(out / "right_arm.npz")
    model = tree.meta["model_hash"]
    tree.meta["model_hash"] = "0123456789abcdef"
    save_tree(tree, out / "right_arm.npz")
    redone = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=300)
    assert redone.returncode == 0, redone.stderr
    assert (f"right_arm: rebuilding (its body's model changed since right_arm.npz was built: 0123456789abcdef -> "
            f"{model})") in redone.stdout
    assert load_atlas(out).trees["right_arm"].meta["model_hash"] == model
    # A changed strategy is rebuilt, and the build says why.
    cfg.write_text(yaml.safe_dump(human_config(d_max=3)))
    changed = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=300)
    assert changed.returncode == 0, changed.stderr
    assert "right_arm: rebuilding (the config changed since right_arm.npz was built)" in changed.stdout
    assert load_atlas(out).trees["right_arm"].d_max == 3


@pytest.fixture(scope="module")
def both_sides(tmp_path_factory):
    strategies = [
        {"name": "right_arm", "effector": "right_hand", "joints": ARM, "tasks": [{"type": "reach"}]},
        {"name": "left_arm", "effector": "left_hand", "joints": LEFT_ARM, "tasks": [{"type": "reach"}],
         "mirror_of": "right_arm"},
    ]
    # D_max 4 (10-12 cm cells): at D_max 3 one vertex flips a 20 cm cell, too
    # coarse to compare volumes. Three restarts: at these spacings no hint is
    # near, and with one restart the arm's local minima alone move the two
    # sides' volumes apart by 3-4 %, which would hide what is tested here.
    data = human_config(d_max=4, strategies=strategies, name="sides")
    data["oracle"]["params"]["restarts"] = 3
    config = parse_config(data, "sides", "sides")
    tmp = tmp_path_factory.mktemp("sides")
    lines: list[str] = []
    mirrored = build_atlas(config, tmp / "mirrored", log=lines.append)
    built = build_atlas(config, tmp / "built", mirror=False)
    return mirrored, built, lines


def test_mirrored_left_matches_a_built_left(both_sides):
    mirrored, built, lines = both_sides
    assert any("left_arm: mirrored from right_arm" in line for line in lines)
    m, b = mirrored.trees["left_arm"], built.trees["left_arm"]
    assert m.meta["build"]["mirrored_from"] == "right_arm" and "mirrored_from" not in b.meta["build"]
    assert m.oracle_calls == 0 and m.meta["build"]["lookups"] == len(m.vertices)
    # Same lattice, verdicts from independent IK solves: they agree but for a few boundary vertices.
    common = np.intersect1d(m.vertices.keys, b.vertices.keys)
    agree = np.mean(m.vertices.reachable[m.vertices.index(common)] == b.vertices.reachable[b.vertices.index(common)])
    assert agree > 0.97
    assert abs(m.volume() - b.volume()) / b.volume() < 0.05


def test_mirrored_postures_reach_the_mirrored_vertices(both_sides):
    from oracles.bodies.body import human_body

    mirrored, _, _ = both_sides
    tree = mirrored.trees["left_arm"]
    body = human_body()
    ok = np.nonzero(tree.vertices.reachable)[0][:25]
    pts = tree.lattice.points(tree.lattice.coords(tree.vertices.keys[ok]))
    for p, q in zip(pts, tree.vertices.posture[ok], strict=True):
        assert np.linalg.norm(body.frame_positions(q, ["left_hand"])["left_hand"] - p) <= 0.005


def test_asymmetric_body_is_built_not_mirrored(tmp_path):
    strategies = [
        {"name": "right_arm", "effector": "right_hand", "joints": ARM, "tasks": [{"type": "reach"}]},
        {"name": "left_arm", "effector": "left_hand", "joints": LEFT_ARM, "tasks": [{"type": "reach"}],
         "mirror_of": "right_arm"},
    ]
    data = human_config(d_max=1, strategies=strategies)
    data["body"]["ranges"] = {"right_elbow_flexion": [0.0, 1.0]}
    lines: list[str] = []
    atlas = build_atlas(parse_config(data, "asym", "asym"), tmp_path / "asym", log=lines.append)
    assert any("left_arm: built, not mirrored: human: joint ranges are not mirror-symmetric" in line for line in lines)
    assert "mirrored_from" not in atlas.trees["left_arm"].meta["build"]


def test_mirror_oracle_refuses_a_lopsided_box_and_unknown_vertices():
    from oracles.protocol import OracleSpec
    from reach.building.mirror import MirrorOracle
    from reach.building.tree import build_tree
    from reach.errors import OracleError
    from reach.maps.box import Box

    tree = build_tree(OracleSpec("sphere", {"radius": 0.5}), Box([-1, -0.5, -1], [1, 1, 1]), 1, 2)
    with pytest.raises(OracleError, match="symmetric about y = 0"):
        MirrorOracle(tree, None)
    sym = build_tree(OracleSpec("sphere", {"radius": 0.5}), Box([-1, -1, -1], [1, 1, 1]), 1, 3)
    with pytest.raises(OracleError, match="never evaluated in the source tree"):
        MirrorOracle(sym, None).evaluate(np.array([[0.75, 0.75, 0.75]]))  # inside an outer depth-2 cell


@pytest.mark.parametrize(("sig", "group"), [(signal.SIGKILL, False), (signal.SIGTERM, False), (signal.SIGTERM, True)])
def test_a_killed_build_leaves_no_worker_behind(tmp_path, sig, group):
    cfg = tmp_path / "arm.yaml"
    cfg.write_text(yaml.safe_dump(human_config(d_max=5)))
    out = tmp_path / "out"
    # group: the signal reaches the build and its workers, as `kill -- -PGID` or a job control's stop sends it.
    proc = subprocess.Popen([sys.executable, "-m", "reach.tools.cli", "build", str(cfg), "-o", str(out), "-q", "-j",
                             "2"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=group)
    deadline = time.monotonic() + 120
    workers: list[int] = []
    while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)  # the pool starts its workers with the first batch
        workers = _children(proc.pid)
    assert proc.poll() is None, "the build finished before it could be killed"
    assert len(workers) >= 2, "the build runs its worker processes"
    time.sleep(0.3)  # let them take work
    if group:
        os.killpg(proc.pid, sig)
    else:
        os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=30)
    if sig == signal.SIGTERM:  # as Ctrl-C: a message and a documented status
        assert proc.returncode == 143 and "reach: terminated; run the same build with --resume" in err
    deadline = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    survivors = [w for w in workers if _alive(w)]
    for w in survivors:  # a failing run must not leave them behind either
        os.kill(w, signal.SIGKILL)
    assert not survivors, "a worker outlived the killed build"


def test_sub_strategies_of_the_demo_atlas():
    from reach.building.atlas import sub_strategies

    config = load_config(Path(__file__).parent.parent / "configs" / "demo.yaml")
    order = sorted(config.strategies, key=lambda s: s.mirror_of is not None)
    assert sub_strategies(order) == {
        f"{side}_{big}": f"{side}_{small}"
        for side in ("right", "left")
        for big, small in (("upper_body", "arm"), ("whole_body", "upper_body"), ("crouch", "whole_body"))
    }


def test_strategies_with_their_own_joint_ranges_inherit_on_the_same_body():
    """The torsion and the squat change joint ranges, not the body: they inherit, and are inherited from (each
    inherited posture is checked against the inheritor's own ranges by its verdict)."""
    from reach.building.atlas import sub_strategies

    config = load_config(Path(__file__).parent.parent / "configs" / "human.yaml")
    order = sorted(config.strategies, key=lambda s: s.mirror_of is not None)
    subs = sub_strategies(order)
    assert subs["right_torsion"] == "right_upper_body"
    assert subs["right_whole_body"] == "right_upper_body"  # the torsion's joints are the same, not fewer
    # the crouch's joints are the squat's own, not fewer; of the largest strict subsets the earliest, the torsion's
    assert subs["right_squat"] == "right_torsion"
    oracles = {s.name: s.oracle.create() for s in config.strategies if s.name in ("right_torsion", "right_upper_body")}
    assert oracles["right_torsion"].model_hash != oracles["right_upper_body"].model_hash


def test_a_crouch_inherits_the_whole_bodys_verified_postures(tmp_path):
    from oracles.protocol import OracleSpec

    whole = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "root", "*_hip_*", "*_ankle_*"]
    tasks = [{"type": "reach"}, {"type": "feet"}, {"type": "balance"}, {"type": "floor"}, {"type": "coupling"}]
    strategies = [
        {"name": "whole", "effector": "right_hand", "joints": whole, "tasks": tasks},
        {"name": "crouch", "effector": "right_hand", "joints": [*whole, "*_knee_*"], "tasks": tasks},
    ]
    data = human_config(d_max=3, strategies=strategies, name="inherit")
    data["box"] = {"min": [-0.2, -0.9, 0.0], "max": [1.0, 0.3, 1.8]}
    config = parse_config(data, "inherit", "inherit")
    lines: list[str] = []
    atlas = build_atlas(config, tmp_path / "a", log=lines.append)
    w, c = atlas.tree("whole"), atlas.tree("crouch")
    b = c.meta["build"]
    assert c.meta["inherited_from"] == "whole" and b["inherited"] > 0
    assert b["oracle_calls"] == b["distinct_vertices"] - b["inherited"]
    assert any(f"{b['inherited']} reachable vertices inherited from whole" in line for line in lines)
    from reach.answers.audit import summary

    info = summary(atlas)["strategies"]
    assert info["crouch"]["inherited_from"] == "whole" and info["crouch"]["inherited_vertices"] == b["inherited"]
    assert info["whole"]["inherited_from"] is None and info["whole"]["inherited_vertices"] == 0
    # The whole body's reachable vertices (those the crouch's tree has) are the
    # crouch's, by the same postures, which the crouch's own oracle accepts.
    rows = c.vertices.index(w.vertices.keys[w.vertices.reachable])
    rows = rows[rows >= 0]
    assert rows.size >= b["inherited"] and c.vertices.reachable[rows].all()
    crouch = OracleSpec.from_dict(c.meta["oracle"]).create()
    pts = c.lattice.points(c.lattice.coords(c.vertices.keys[rows]))
    assert crouch.verify(pts, c.vertices.posture[rows]).all()
    assert crouch.effector_positions(c.vertices.posture[rows]) == pytest.approx(pts, abs=0.006)
    # Without inheritance every vertex is solved.
    alone = build_atlas(config, tmp_path / "b", inherit=False).tree("crouch")
    assert alone.meta["build"]["oracle_calls"] == len(alone.vertices) > b["oracle_calls"]


def test_a_mirrored_trees_motion_graph_is_its_sources_image(both_sides):
    """The left arm's motion graph is the right's mirrored (no posture checked): a left stored posture reached from the
    reference exactly when its right image is, and two linked exactly when their images are, matched by the points
    they were stored at (reflected about y = 0)."""
    from reach.maps.graph import load_graph

    mirrored, _, lines = both_sides
    right, left = (load_graph(mirrored.path / f"{n}.graph.npz") for n in ("right_arm", "left_arm"))
    assert left.meta["mirrored"] and any(line.startswith("left_arm: motion graph") and "mirrored" in line
                                         for line in lines)
    assert right.meta["samples"] > 0 and len(right.edges) > 0
    _, right_points, _ = mirrored.trees["right_arm"].stored()
    _, left_points, _ = mirrored.trees["left_arm"].stored()
    image = {tuple(np.round(p * [1.0, -1.0, 1.0], 6) + 0.0): k for k, p in enumerate(right_points)}
    to_right = np.array([image[tuple(np.round(p, 6) + 0.0)] for p in left_points])
    assert np.array_equal(left.home, right.home[to_right])
    assert {tuple(sorted(e)) for e in to_right[left.edges].tolist()} == {tuple(e) for e in right.edges.tolist()}
