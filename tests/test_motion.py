"""Reach motion (reach.motion.planner): end postures, timing law, minimum jerk, held tasks, routing, errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM, Y_UP, bvh_chain, bvh_end, human_config, quat_matrix

from oracles.bodies.body import human_body
from reach.answers.answer import posture_vector
from reach.answers.select import Selector
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.errors import InputError
from reach.motion import paths
from reach.motion.holding import Holding
from reach.motion.planner import MotionError, Planner
from reach.motion.rig import Rig
from reach.motion.routes import Routes
from reach.motion.timing import INCH, TMU, Timing, minimum_jerk, timed

TOL = 0.005  # [m] the reach task's default tolerance
UPPER = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*"]
STRATEGIES = [
    {"name": "arm", "effector": "right_hand", "priority": 1, "joints": ARM,
     "tasks": [{"type": "reach"}, {"type": "self_collision"}]},
    {"name": "whole", "effector": "right_hand", "priority": 2,
     "joints": [*UPPER, "root", "*_hip_*", "*_knee_*", "*_ankle_*"],
     "tasks": [{"type": "reach"}, {"type": "self_collision"}, {"type": "posture"}, {"type": "feet", "heels": "down"},
               {"type": "balance"}, {"type": "coupling"}]},
]


@pytest.fixture(scope="module")
def planner(tmp_path_factory):
    config = human_config(d_max=3, strategies=STRATEGIES, name="motion")
    # the arm needs depth 4 to hold its volume
    config["box"], config["depth"] = {"min": [-0.2, -0.7, 0.3], "max": [0.7, 0.3, 1.6]}, {"min": 2, "max": 4}
    atlas = build_atlas(parse_config(config, "motion", "motion"), tmp_path_factory.mktemp("motion") / "atlas")
    # A budget no machine runs out of: the same request then gives the same frames.
    return Planner(Selector(atlas, policy="optimistic").warm_up(), budget=5.0)


@pytest.fixture(scope="module")
def body():
    return human_body()


def hand(body, q):
    data = body.model.createData()
    pin.framesForwardKinematics(body.model, data, q)
    return data.oMf[body.frame_id("right_hand")].translation.copy()


def test_mtm_reach_table_and_body_motions():
    t = Timing()
    assert t.reach_tmu(10 * INCH) == pytest.approx(8.7)  # MTM-1 R-A, 10 in
    assert t.reach_tmu(30 * INCH) == pytest.approx(17.5)
    assert t.reach_tmu(40 * INCH) == pytest.approx(17.5 + 10 * 0.4)  # 0.4 TMU per inch past 30
    assert t.reach_tmu(11 * INCH) == pytest.approx((8.7 + 9.6) / 2)
    seconds, parts = t.seconds(10 * INCH, root_drop=0.2, root_tilt=0.0, root_lift=0.0)
    assert parts == {"reach": pytest.approx(8.7), "stoop": 29.0} and seconds == pytest.approx((8.7 + 29.0) * 0.036)
    assert t.seconds(10 * INCH, 0.0, 0.0, 0.02)[1]["foot"] == 8.5
    assert Timing.from_dict({"tmu": 0.05}).seconds(10 * INCH, 0, 0, 0)[0] == pytest.approx(8.7 * 0.05)
    assert Timing.from_dict({"duration": 2.0}).seconds(1.0, 0, 0, 0) == (2.0, {})
    with pytest.raises(InputError, match=r"timing: unknown keys \['speed'\]"):
        Timing.from_dict({"speed": 2})
    with pytest.raises(InputError, match="timing.duration: expected a number of seconds"):
        Timing.from_dict({"duration": 0})


@pytest.mark.slow  # builds the planner's programs (4 s)
def test_an_arm_reach_starts_at_the_start_ends_at_the_answer_and_is_minimum_jerk(planner, body):
    goal = np.array([0.45, -0.25, 1.2])
    m = planner.plan("right_hand", goal)
    stored = planner.selector.select("right_hand", goal, False)
    names = m.names
    assert m.strategy == stored.strategy == "arm" and m.outcome == "reached" and m.refined == "ok"
    np.testing.assert_allclose(m.postures[0], body.q_ref, atol=1e-12)  # the reference posture by default
    # the end: a stored posture near the goal (one the reference's direct motion reaches, or the answer's own) settled
    # onto the goal by local steps, no solve
    assert m.end == "settled" and m.within is None
    home = planner.routes.homeward("arm", goal, planner.body("arm"))
    seeds = [*home, posture_vector(names, body.q_ref, stored.posture, stored.root)]
    settled = [q for q in (planner.body("arm").settle(seed, goal) for seed in seeds) if q is not None]
    np.testing.assert_allclose(m.postures[-1], settled[0], atol=1e-9)
    assert np.linalg.norm(hand(body, m.postures[-1]) - goal) <= TOL  # by our own forward kinematics
    np.testing.assert_allclose(m.path, [hand(body, q) for q in m.postures], atol=1e-9)
    # Timing: MTM-1 for the hand's path, frames at 30 Hz from 0 to the duration.
    length = float(np.linalg.norm(np.diff(m.path, axis=0), axis=1).sum())
    assert m.parts == {"reach": pytest.approx(Timing().reach_tmu(length), rel=0.05)}
    # The law's duration rounded up to a whole frame.
    assert m.parts["reach"] * TMU <= m.duration < m.parts["reach"] * TMU + 1 / 30 and m.times[0] == 0.0
    np.testing.assert_allclose(np.diff(m.times), 1 / 30, rtol=1e-12)
    # Nothing was held, and the progress is the minimum-jerk fraction of the way: nine parts the hand's path
    # covered, one part the posture's (arm joints interpolate linearly), the hand's path measured between frames.
    # Along the motion graph (through the stored posture the end was settled from, unless a direct segment holds):
    # the posture's path measured between frames too.
    assert m.held == 0 and m.waypoints <= 1 and m.route == "graph"
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(m.postures, axis=0), axis=1))])
    s /= s[-1]
    covered = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(m.path, axis=0), axis=1))])
    # (the planner measures both on 128 samples of the path, here between frames: chords where it turns, up to 0.006)
    np.testing.assert_allclose(0.9 * covered / covered[-1] + 0.1 * s, minimum_jerk(m.times / m.duration), atol=0.01)
    # The hand's speed: one peak, between 40 % and 60 % of the duration.
    speed = np.linalg.norm(np.diff(m.path, axis=0), axis=1) / np.diff(m.times)
    peak = int(np.argmax(speed))
    assert 0.4 <= (m.times[peak] + m.times[peak + 1]) / 2 / m.duration <= 0.6
    assert np.all(np.diff(speed[: peak + 1]) > -1e-3) and np.all(np.diff(speed[peak:]) < 1e-3)
    assert not any(planner.body("arm").faults(m.postures))


def test_a_low_reach_holds_the_feet_and_balance_at_every_frame_and_adds_a_stoop(planner, body):
    goal = np.array([0.35, -0.2, 0.45])
    m = planner.plan("right_hand", goal)
    assert m.strategy == "whole" and m.outcome == "reached"
    assert np.linalg.norm(hand(body, m.postures[-1]) - goal) <= TOL
    law = sum(m.parts.values()) * TMU
    assert "stoop" in m.parts and law <= m.duration < law + 1 / 30
    oracle = planner.body("whole")
    assert not any(oracle.faults(m.postures))  # limits, self-collision, feet, balance, by each task's own check
    # The progress is the minimum-jerk fraction of the duration (Flash and Hogan's law is the hand's): nine parts the
    # hand's path covered, one the posture's, though the body stoops and the path turns at a stored posture.
    covered = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(m.path, axis=0), axis=1))])
    posture = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(m.postures, axis=0), axis=1))])
    progress = 0.9 * covered / covered[-1] + 0.1 * posture / posture[-1]
    np.testing.assert_allclose(progress, minimum_jerk(m.times / m.duration), atol=0.01)
    # Independently: the soles' frames stay where they stood, and the centre of mass over the feet.
    data = body.model.createData()
    corners = [body.frame_id(f"{side}_{end}_{edge}") for side in ("right", "left") for end in ("heel", "toe")
               for edge in ("inner", "outer")]
    first = None
    for q in m.postures:
        pin.framesForwardKinematics(body.model, data, q)
        where = np.array([data.oMf[f].translation for f in corners])
        first = where if first is None else first
        np.testing.assert_allclose(where, first, atol=2e-4)
        com = pin.centerOfMass(body.model, data, q)
        # within the soles' bounds
        assert np.all(first[:, :2].min(axis=0) <= com[:2]) and np.all(com[:2] <= first[:, :2].max(axis=0))
    # Pinocchio's own interpolation between the end postures slides the feet; the oracle's, moving from the foot (the
    # anchor, the right), does not slide it (the other foot is kept by its leg's own IK where the leg reaches: not
    # here, its knee straight).
    plain = [pin.interpolate(body.model, m.postures[0], m.postures[-1], u) for u in np.linspace(0, 1, 11)]
    slide = []
    for q in plain:
        pin.framesForwardKinematics(body.model, data, q)
        slide.append(np.abs(np.array([data.oMf[f].translation for f in corners]) - first).max())
    kept = []
    for q in oracle.interpolate(m.postures[0], m.postures[-1], np.linspace(0, 1, 11)):
        pin.framesForwardKinematics(body.model, data, q)
        kept.append(np.abs(np.array([data.oMf[f].translation for f in corners[:4]]) - first[:4]).max())
    assert oracle.anchor == "right_foot"
    assert max(slide) > 0.001 and max(kept) < 0.1 * max(slide)  # here 36 mm against under 0.01 mm


def test_a_reach_across_the_body_avoids_the_collision_of_direct_interpolation(planner, body, monkeypatch):
    goal = np.array([0.1, 0.2, 0.9])  # the right hand across the body to the left of the belly
    monkeypatch.setattr(Routes, "motion_graph", lambda *args: None)  # the planner's own way, as without a graph
    m = planner.plan("right_hand", goal)
    oracle = planner.body(m.strategy)
    q0, q1 = m.postures[0], m.postures[-1]
    direct = oracle.faults(oracle.interpolate(q0, q1, np.linspace(0, 1, 40)))
    assert any("self_collision" in f for f in direct)  # the precondition: straight through the body
    # around the body: through the motion graph's stored posture, or by held frames
    assert not any(oracle.faults(m.postures)) and (m.held > 0 or m.route == "graph")
    assert np.linalg.norm(hand(body, q1) - goal) <= TOL
    # The route through stored postures, as the planner takes it when holding the frames fails: its inner
    # waypoints are postures stored in the tree, and its frames, held, break nothing.
    waypoints = planner.routes.route(m.strategy, oracle, q0, q1)
    stored = planner.selector.atlas.trees[m.strategy].vertices.posture
    assert all(np.any(np.all(stored == w, axis=1)) for w in waypoints[1:-1])
    frames = timed(oracle, m.names, waypoints, 30.0, Timing())[0]
    held = planner.holding.hold_path(oracle, frames)
    assert held is not None and not any(oracle.faults(held[0]))


def largest_turn(path: np.ndarray) -> float:
    """The largest angle [deg] between the hand's consecutive moves of more than 0.1 mm."""
    v = np.diff(path, axis=0)
    n = np.linalg.norm(v, axis=1)
    moving = (n[:-1] > 1e-4) & (n[1:] > 1e-4)
    cos = np.sum(v[:-1] * v[1:], axis=1)[moving] / (n[:-1] * n[1:])[moving]
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max())


def test_a_routes_corners_are_rounded_and_still_hold(planner, body, monkeypatch):
    """Through a stored posture the hand would turn at once; the rounded route turns it over several frames,
    and its frames, held, break nothing."""
    monkeypatch.setattr(Routes, "motion_graph", lambda *args: None)
    goal = np.array([0.1, 0.2, 0.9])
    m = planner.plan("right_hand", goal)
    oracle = planner.body(m.strategy)
    route = planner.routes.route(m.strategy, oracle, m.postures[0], m.postures[-1])
    assert len(route) > 2  # the precondition: a corner to round
    rounded = paths.rounded(oracle, route)
    assert np.array_equal(rounded[0], route[0]) and np.array_equal(rounded[-1], route[-1])
    turns = []
    for waypoints in (route, rounded):
        frames = timed(oracle, m.names, waypoints, 30.0, Timing())[0]
        held = planner.holding.hold_path(oracle, frames)
        assert held is not None and not any(oracle.faults(held[0]))
        turns.append(largest_turn(np.asarray(oracle.effector_positions(held[0]))))
    assert turns[1] < 0.8 * turns[0], turns  # here 50 -> 36 deg


def test_the_same_request_gives_the_same_frames(planner):
    a = planner.plan("right_hand", [0.4, -0.3, 1.0], rate=60)
    b = planner.plan("right_hand", [0.4, -0.3, 1.0], rate=60)
    np.testing.assert_array_equal(a.postures, b.postures)
    np.testing.assert_array_equal(a.times, b.times)
    assert a.frames() == b.frames() and a.rate == 60 and np.allclose(np.diff(a.times), 1 / 60)


def test_out_of_reach_goes_to_the_nearest_point_or_is_an_error(planner):
    far = [2.0, -0.3, 1.2]
    m = planner.plan("right_hand", far)
    assert m.outcome == "nearest" and m.within == pytest.approx(np.linalg.norm(np.array(m.point) - far))
    assert m.within > 0.5
    with pytest.raises(MotionError, match="cannot reach"):
        planner.plan("right_hand", far, miss="error")


def test_bad_start_postures_and_options_are_refused_by_name(planner):
    with pytest.raises(InputError, match="from: right_elbow_flexion = 9 is outside its range"):
        planner.plan("right_hand", [0.45, -0.25, 1.2], start={"right_elbow_flexion": 9.0})
    with pytest.raises(InputError, match="from: the start posture breaks .*self_collision"):
        # The upper arm drawn in across the trunk.
        planner.plan("right_hand", [0.45, -0.25, 1.2],
                     start={"right_shoulder_abduction": -0.3, "right_elbow_flexion": 2.0})
    with pytest.raises(InputError, match=r"rate: expected frames per second in \[1, 240\]"):
        planner.plan("right_hand", [0.45, -0.25, 1.2], rate=0)
    with pytest.raises(InputError, match="miss: expected one of nearest, error"):
        planner.plan("right_hand", [0.45, -0.25, 1.2], miss="within")


@pytest.mark.parametrize("workers", [0, 1])
def test_the_motion_operation_over_the_wire(planner, workers):
    import threading

    import zmq

    from reach.serving.client import Client, ServerError
    from reach.serving.server import Server

    server = Server(planner.selector.atlas.path, "tcp://127.0.0.1:*", "tcp://127.0.0.1:*", workers=workers)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"right_hand")
    sub.setsockopt(zmq.SUBSCRIBE, b"hello")
    sub.connect(server.pub_endpoint)
    try:
        with Client(server.endpoint, timeout=60_000) as c:
            goal = [0.45, -0.25, 1.2]
            while not sub.poll(100):  # hello until the subscription has reached the server
                c.hello(tag="sync")
            while sub.poll(100):
                sub.recv_multipart()  # the hellos
            m = c.motion(effector="right_hand", goal=goal, rate=60, tag="t1")
            assert m["strategy"] == "arm" and m["outcome"] == "reached" and m["frame_count"] == len(m["frames"])
            assert m["frames"][0]["t"] == 0.0 and m["frames"][-1]["t"] == pytest.approx(m["duration"])
            assert np.linalg.norm(np.array(m["frames"][-1]["effector"]) - goal) <= TOL
            local = planner.plan("right_hand", goal, rate=60)
            assert m["frames"] == json.loads(json.dumps(local.frames()))  # the same frames as in-process
            topic, body = sub.recv_multipart()
            published = json.loads(body)
            assert (topic == b"right_hand" and published["tag"] == "t1" and published["duration"] == m["duration"]
                    and "frames" not in published)
            # "return": the way there and back, the end posture once, the parts' TMU twice
            both = c.call("motion", effector="right_hand", goal=goal, rate=60, **{"return": True})
            assert both["frame_count"] == 2 * m["frame_count"] - 1 == len(both["frames"])
            assert both["frames"][: m["frame_count"]] == m["frames"]
            assert both["frames"][-1]["posture"] == m["frames"][0]["posture"]
            assert both["frames"][m["frame_count"] - 2]["posture"] == m["frames"][-2]["posture"] == \
                both["frames"][m["frame_count"]]["posture"]
            assert both["duration"] == pytest.approx(2 * m["duration"])
            assert np.all(np.diff([f["t"] for f in both["frames"]]) > 0)
            assert both["timing_tmu"]["return"] == pytest.approx(sum(m["timing_tmu"].values()))
            with pytest.raises(ServerError, match="bad_request: .*return"):
                c.call("motion", effector="right_hand", goal=goal, **{"return": "yes"})
            with pytest.raises(ServerError, match="unreachable"):
                c.motion(effector="right_hand", goal=[2.0, 0.0, 1.0], miss="error")
            with pytest.raises(ServerError, match="bad_request: .*rate"):
                c.motion(effector="right_hand", goal=goal, rate=1000)
            with pytest.raises(ServerError, match="bad_request: .*timing"):
                c.motion(effector="right_hand", goal=goal, timing={"speed": 2})
            with pytest.raises(ServerError, match="bad_request: .*goal"):
                c.motion(effector="right_hand", goal=[0.4, 0.2])
            with pytest.raises(ServerError, match="unknown_effector"):
                c.motion(effector="left_foot", goal=goal)
            with pytest.raises(ServerError, match="timeout"):  # with --workers 0 the deadline was ignored
                c.motion(effector="right_hand", goal=[0.35, -0.2, 0.45], rate=240, deadline=0.001)
            assert c.health()["status"] == "serving"
    finally:
        sub.close(linger=0)
        server.stop()
        thread.join(timeout=10)


def test_reach_motion_writes_the_frames_and_names_bad_input(planner, tmp_path, capsys):
    from reach.tools.cli import main

    atlas = str(planner.selector.atlas.path)
    out = tmp_path / "reach.json"
    assert main(["motion", atlas, "0.45", "-0.25", "1.2", "--effector", "right_hand", "--rate", "50", "-o",
                 str(out)]) == 0
    assert "reaches [0.45, -0.25, 1.2] with strategy arm" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert (data["rate"] == 50 and len(data["frames"]) == data["frame_count"]
            and data["frames"][-1]["t"] == pytest.approx(data["duration"]))
    there_and_back = tmp_path / "back.json"
    assert main(["motion", atlas, "0.45", "-0.25", "1.2", "--effector", "right_hand", "--rate", "50", "--return",
                 "-o", str(there_and_back)]) == 0
    back = json.loads(there_and_back.read_text())
    assert back["frame_count"] == 2 * data["frame_count"] - 1 and back["frames"][-1]["posture"] == \
        data["frames"][0]["posture"]
    assert main(["motion", atlas, "0.45", "-0.25", "1.2", "--effector", "right_hand", "-o",
                 str(tmp_path / "reach.fbx")]) == 2
    assert "-o: " in capsys.readouterr().err and not (tmp_path / "reach.fbx").exists()
    for name in ("reach.motion.bvh", "reach.glb"):
        assert main(["motion", atlas, "0.45", "-0.25", "1.2", "--effector", "right_hand", "-o",
                     str(tmp_path / name)]) == 0
        assert (tmp_path / name).stat().st_size > 1000
    assert main(["motion", atlas, "0.45", "-0.25", "--effector", "right_hand"]) == 2
    assert "goal: a motion's goal has 3 coordinates" in capsys.readouterr().err


# -- animation files ---------------------------------------------------------


@pytest.fixture(scope="module")
def crouch(planner):
    """A low reach: the root moves and turns, the legs bend (the whole-body strategy)."""
    m = planner.plan("right_hand", [0.35, -0.2, 0.45])
    assert m.strategy == "whole"
    return m


def test_the_skeleton_groups_joints_at_one_point_into_bones(planner):
    sk = planner.body("whole").skeleton()
    bone = dict(zip(sk.bones, sk.joints, strict=True))
    assert bone["right_upper_arm"] == ("right_shoulder_flexion", "right_shoulder_abduction", "right_shoulder_rotation")
    assert bone["pelvis"] == ("root",) and bone["right_shank"] == ("right_knee_flexion",)
    assert sum(len(j) for j in sk.joints) == planner.body("whole").body.model.njoints - 1  # every joint in one bone
    parent = {b: sk.bones[p] for b, p in zip(sk.bones, sk.parents, strict=True) if p >= 0}
    assert parent["right_forearm"] == "right_upper_arm" and parent["right_thigh"] == "pelvis"
    assert ("right_hand", sk.bones.index("right_palm")) == sk.ends[[e[0] for e in sk.ends].index("right_hand")][:2]


def test_a_skeleton_refuses_a_joint_that_translates_and_a_rig_needs_a_skeleton(crouch):
    from pathlib import Path

    from oracles.bodies.body import urdf_body
    from oracles.bodies.skeleton import build_skeleton
    from oracles.errors import ModelError
    from reach.motion.rig import rig

    with pytest.raises(ModelError, match="joint 'prismatic_x' is a JointModelPX, which translates; a skeleton's "
                                         "bones only turn"):
        build_skeleton(urdf_body(Path(__file__).parent / "data" / "all_joints.urdf"))
    with pytest.raises(InputError, match="has no skeleton .no Articulated capability.: write the motion as .json"):
        rig(crouch, object())


def test_bvh_round_trip_puts_the_hand_where_pinocchio_does(planner, crouch, tmp_path):
    """bvhio parses the file (its own Euler-to-rotation reading of the channels); the forward kinematics is this
    test's."""
    import bvhio

    from reach.motion.bvh import write_bvh
    from reach.motion.rig import rig

    path = write_bvh(rig(crouch, planner.body(crouch.strategy)), tmp_path / "crouch.bvh")
    parsed = bvhio.readAsBvh(str(path))
    assert parsed.FrameCount == len(crouch.times) and parsed.FrameTime == pytest.approx(1 / 30, abs=1e-7)

    arm = bvh_chain(parsed.Root, "right_palm")
    assert [j.Name for j in arm] == ["pelvis", "abdomen", "thorax", "right_clavicle", "right_upper_arm",
                                     "right_forearm", "right_palm"]
    assert (arm[0].Channels[:3] == ["Xposition", "Yposition", "Zposition"]
            and arm[4].Channels == ["Zrotation", "Xrotation", "Yrotation"])
    error = [np.linalg.norm(bvh_end(arm, parsed.Root, k) - crouch.path[k]) for k in range(parsed.FrameCount)]
    assert max(error) < 0.001
    assert np.ptp(crouch.path, axis=0).max() > 0.2  # the hand travelled: the check is not of a still pose


def _gltf_validator():
    """The Khronos glTF Validator (npm gltf-validator), installed by make beside the venv."""
    import os
    import shutil
    from pathlib import Path

    modules = Path(__file__).resolve().parents[1] / ".venv" / "node" / "node_modules"
    if shutil.which("node") is None or not (modules / "gltf-validator").exists():
        if os.environ.get("CI"):
            pytest.fail(f"node or the glTF validator ({modules}) is missing on CI")
        pytest.skip("node or the npm package gltf-validator is missing (make .venv/.installed-test installs it)")
    return modules


def _accessor(doc, blob: bytes, index: int) -> np.ndarray:
    acc = doc.accessors[index]
    view = doc.bufferViews[acc.bufferView]
    dtype = {5126: np.float32, 5123: np.uint16, 5125: np.uint32, 5121: np.uint8}[acc.componentType]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    return np.frombuffer(blob, dtype, acc.count * width, start).reshape(acc.count, width).astype(float)


def test_gltf_passes_the_khronos_validator_and_its_hand_follows_pinocchio(planner, crouch, tmp_path):
    import subprocess

    import pygltflib

    from reach.motion.gltf import write_gltf
    from reach.motion.rig import rig

    bones = rig(crouch, planner.body(crouch.strategy))
    files = [write_gltf(bones, tmp_path / "crouch.glb"), write_gltf(bones, tmp_path / "crouch.gltf")]
    modules = _gltf_validator()
    script = Path(__file__).parent / "tools" / "gltf_validate.js"
    out = subprocess.run(["node", str(script), *map(str, files)], capture_output=True, text=True, check=True,
                         env={**os.environ, "NODE_PATH": str(modules)})
    reports = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r["errors"] for r in reports] == [0, 0], reports
    assert reports[0]["info"]["animationCount"] == 1 and reports[0]["info"]["hasSkins"]

    # An independent reading: pygltflib for the document, this test's own sampling and matrix product.
    doc = pygltflib.GLTF2().load(str(files[0]))
    blob = doc.binary_blob()
    (anim,) = doc.animations
    parent = {c: n for n, node in enumerate(doc.nodes) for c in (node.children or [])}
    tracks = {}
    for ch in anim.channels:
        sampler = anim.samplers[ch.sampler]
        tracks[(ch.target.node, ch.target.path)] = (_accessor(doc, blob, sampler.input)[:, 0],
                                                    _accessor(doc, blob, sampler.output))
    keys = tracks[(0, "rotation")][0]
    np.testing.assert_allclose(keys, crouch.times, atol=1e-6)
    hand_node = [n.name for n in doc.nodes].index("right_hand")

    def world(n: int, k: int) -> np.ndarray:
        node, local = doc.nodes[n], np.eye(4)
        t = tracks[(n, "translation")][1][k] if (n, "translation") in tracks else (node.translation or [0, 0, 0])
        x, y, z, w = tracks[(n, "rotation")][1][k] if (n, "rotation") in tracks else (node.rotation or [0, 0, 0, 1])
        local[:3, :3], local[:3, 3] = quat_matrix(w, x, y, z), t
        return local if n not in parent else world(parent[n], k) @ local

    error = [np.linalg.norm(Y_UP.T @ world(hand_node, k)[:3, 3] - crouch.path[k]) for k in range(len(keys))]
    assert max(error) < 0.001

    # The skin: each capsule's vertices, moved by their bone to the last key, lie on that capsule as Pinocchio places
    # it.
    (prim,) = doc.meshes[0].primitives
    verts, joints = _accessor(doc, blob, prim.attributes.POSITION), _accessor(doc, blob,
        prim.attributes.JOINTS_0)[:, 0].astype(int)
    ibm = _accessor(doc, blob, doc.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    last = len(keys) - 1
    skinned = np.array([(world(doc.skins[0].joints[j], last) @ ibm[j] @ np.append(v, 1.0))[:3]
                        for v, j in zip(verts, joints, strict=True)])
    names, capsules = planner.body(crouch.strategy).shape(crouch.postures[-1])
    per = len(verts) // len(names)
    for i, (a, b, r) in enumerate((c[:3], c[3:6], c[6]) for c in capsules):
        p = skinned[i * per : (i + 1) * per] @ Y_UP  # back to the world's axes
        u = np.clip((p - a) @ (b - a) / max((b - a) @ (b - a), 1e-12), 0, 1)
        dist = np.linalg.norm(p - (a + u[:, None] * (b - a)), axis=1)
        # the mesh's vertices are on the capsule's surface (float32 file)
        assert np.abs(dist - r).max() < 1e-4, names[i]


def test_a_motion_is_reached_only_when_its_last_frame_reaches_the_goal(planner, body, monkeypatch):
    """With no time to refine and no settling, answers are stored postures a few centimetres off; a motion to
    one of them says ``nearest`` with its distance, never ``reached``; every ``reached`` motion's last frame
    passes the verdict's own check and puts the hand within the tolerance."""
    monkeypatch.setattr(Planner, "_settled", lambda *args: (None, None))
    hurried = Planner(planner.served, budget=1e-9)
    goals = np.random.default_rng(3).uniform([0.2, -0.6, 0.8], [0.55, -0.1, 1.4], (12, 3))
    outcomes = []
    for goal in goals:
        m = hurried.plan("right_hand", goal)
        outcomes.append(m.outcome)
        end = np.linalg.norm(hand(body, m.postures[-1]) - goal)
        if m.outcome == "reached":
            oracle = hurried.body(m.strategy)
            assert end <= 0.005 and oracle.verify(goal[None], m.postures[-1][None])[0]
        else:
            assert m.within == pytest.approx(end, abs=1e-9)
    assert "nearest" in outcomes  # the check can fail: stored postures stop short


def test_timing_coefficients_cannot_make_a_motion_longer_than_its_bound(planner):
    """Duration was capped but not the law's coefficients (tmu: 36 planned for 100 s; 1e300 was
    an internal error). Both are refused, naming the timing."""
    for timing, goal in (({"tmu": 36.0}, [0.4, -0.3, 1.0]), ({"tmu": 1e300}, [0.4, -0.3, 1.0]),
                         ({"past_30": 1e300}, [2.0, -0.3, 1.2])):
        with pytest.raises(InputError, match="a motion lasts at most"):
            planner.plan("right_hand", goal, rate=240, timing=Timing.from_dict(timing))
    assert planner.plan("right_hand", [0.4, -0.3, 1.0], timing=Timing.from_dict({"tmu": 0.036})).duration < 20


def test_planning_stops_at_its_deadline_within_a_frame(planner, monkeypatch):
    """A worker planned on for 100 s after its request's deadline. The planner reads the clock
    before holding each frame (here a clock that moves 1 s a reading): it stops at the deadline, after a few
    frames of the motion's hundreds, with a timeout."""
    import reach.motion.holding as motion

    class Clock:
        now = 0.0

        def perf_counter(self) -> float:
            self.now += 1.0
            return self.now

    clock = Clock()
    oracle = planner.body("whole")
    checked = []
    real = oracle.faults
    monkeypatch.setattr(oracle, "faults", lambda postures: checked.append(len(postures)) or real(postures))
    monkeypatch.setattr(motion, "time", clock)
    with pytest.raises(MotionError, match="deadline") as err:
        planner.plan("right_hand", [0.35, -0.2, 0.5], rate=240, deadline=3.5)
    assert err.value.code == "timeout" and clock.now <= 5.0
    stopped = sum(checked)
    monkeypatch.setattr(motion, "time", __import__("time"))
    checked.clear()
    m = planner.plan("right_hand", [0.35, -0.2, 0.5], rate=240)  # the same motion, without a deadline
    assert m.strategy == "whole" and len(m.times) > 200
    # Three readings of the deadline, then it stopped (and the start posture's own check), long before the end.
    assert stopped <= 3 * motion.CHECK_FRAMES + 1 < sum(checked)


@pytest.mark.parametrize("workers", [0, 1])
def test_reach_motion_over_the_wire_writes_the_same_animation_files(planner, tmp_path, capsys, workers):
    """`reach motion --connect ADDR -o FILE.bvh|.glb` asks the server for the motion's bones (the
    `bones` field; the client has no body) and writes the file the atlas folder writes for the same request."""
    import threading

    from reach.serving.server import Server
    from reach.tools.cli import main

    atlas = str(planner.selector.atlas.path)
    server = Server(atlas, "tcp://127.0.0.1:*", None, workers=workers)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        for name in ("reach.motion.bvh", "reach.motion.gltf"):
            here, there = tmp_path / f"here_{name}", tmp_path / f"there_{name}"
            assert main(["motion", atlas, "0.45", "-0.25", "1.2", "--effector", "right_hand", "--rate", "40", "-o",
                         str(here)]) == 0
            assert main(["motion", "0.45", "-0.25", "1.2", "--effector", "right_hand", "--rate", "40", "--connect",
                         server.endpoint, "-o", str(there)]) == 0
            assert "frames written to" in capsys.readouterr().out
            assert there.read_text() == here.read_text()
    finally:
        server.stop()
        thread.join(timeout=10)
    with pytest.raises(InputError, match="rig: a motion's bones are malformed"):
        Rig.from_dict({"bones": ["a"]})


def test_a_paths_broken_frames_are_held_as_one_batch_by_the_batched_engine(planner, body, monkeypatch):
    """The low reach's frames with the root pushed (its feet broken), held by the batched
    engine, most as one batch (the others alone, from their neighbour's correction): every frame then holds every
    task by the fatrop
    oracle's own checks, and independently the soles stay where they stood, the centre of mass over them."""
    import time

    from oracles.protocol import OracleSpec

    m = planner.plan("right_hand", np.array([0.35, -0.2, 0.5]))
    fatrop = planner.body("whole")
    spec = planner.selector.atlas.trees["whole"].meta["oracle"]
    batch = OracleSpec(spec["name"], {**spec["params"], "solver": "batch"}).create()
    frames = timed(fatrop, m.names, [m.postures[0], m.postures[-1]], 30.0, Timing())[0].copy()
    # The root pushed forward along a smooth bump (1 cm at mid-path): the feet slide, as a plain interpolation's do.
    frames[:, 0] += 0.01 * np.sin(np.pi * np.linspace(0.0, 1.0, len(frames)))
    broken = [k for k, f in enumerate(fatrop.faults(frames)) if f]
    assert len(broken) >= 5  # the precondition: the plain path breaks tasks
    alone = []
    monkeypatch.setattr(batch, "hold", lambda q, before=None: alone.append(q) or fatrop.hold(q, before))
    monkeypatch.setattr(planner.holding, "deadline", time.perf_counter() + 60.0)
    counted = dict(planner.holding.counts)
    held = planner.holding.hold_path(batch, frames)
    assert held is not None and held[1] == len(broken)
    # the planner's counts (bench/motion.py's held_in_batch, held_alone) are what happened
    assert planner.holding.counts["alone"] - counted["alone"] == len(alone)
    assert planner.holding.counts["batch"] - counted["batch"] == len(broken) - len(alone)
    # here 18 of 44 held alone (unheld by the batch, or moved too far), 26 in one batch
    assert len(alone) <= 0.5 * len(broken)
    assert not any(fatrop.faults(held[0]))
    data = body.model.createData()
    corners = [body.frame_id(f"{side}_{end}_{edge}") for side in ("right", "left") for end in ("heel", "toe")
               for edge in ("inner", "outer")]
    pin.framesForwardKinematics(body.model, data, frames[0])
    first = np.array([data.oMf[f].translation for f in corners])
    for q in held[0]:
        pin.framesForwardKinematics(body.model, data, q)
        np.testing.assert_allclose([data.oMf[f].translation for f in corners], first, atol=2e-4)
        com = pin.centerOfMass(body.model, data, q)
        assert np.all(first[:, :2].min(axis=0) <= com[:2]) and np.all(com[:2] <= first[:, :2].max(axis=0))


def test_a_path_held_from_its_start_alone_that_jumps_to_its_end_is_held_from_both_ends(planner, body, monkeypatch):
    """Every frame of this whole-body path breaks the feet; held each from its predecessor's correction, the frames
    drift from the end posture (never held: it holds) and jump to it, and the motion took a detour through stored
    postures. Held from the end backwards too and joined where the two holds meet, every frame holds every task, by the
    oracle's checks and independently (the soles where they stood, the centre of mass over them), with no jump."""
    goal = np.array([0.57727608, 0.28119504, 1.54437323])
    # The second foot slides as the body moves from the first (the interpolation's anchor) when its leg does not keep
    # it: every frame breaks the feet.
    # The end posture refined by a solve, not settled from the stored one, is where the drift jumped.
    monkeypatch.setattr("oracles.ik.tasked.planted_frames", lambda *args: [])
    monkeypatch.setattr(Planner, "_settled", lambda *args: (None, None))
    with monkeypatch.context() as patch:
        patch.setattr(Holding, "_spliced", lambda *args: None)
        routed = planner.plan("right_hand", goal)
    m = planner.plan("right_hand", goal)
    # without the hold from both ends the direct path jumps and the motion takes a detour through stored postures
    assert routed.waypoints > 0 and m.waypoints == 0
    oracle = planner.body(m.strategy)
    assert m.strategy == "whole" and m.held > 0
    assert not any(oracle.faults(m.postures))
    steps = np.abs(np.diff(m.postures, axis=0)).max(axis=1)
    assert steps.max() <= 2.0 * np.median(steps) + 0.05  # no frame jumps (the planner's JUMP is 2x the plain path's)
    data = body.model.createData()
    corners = [body.frame_id(f"{side}_{end}_{edge}") for side in ("right", "left") for end in ("heel", "toe")
               for edge in ("inner", "outer")]
    pin.framesForwardKinematics(body.model, data, m.postures[0])
    first = np.array([data.oMf[f].translation for f in corners])
    for q in m.postures:
        pin.framesForwardKinematics(body.model, data, q)
        np.testing.assert_allclose([data.oMf[f].translation for f in corners], first, atol=2e-4)
        com = pin.centerOfMass(body.model, data, q)
        assert np.all(first[:, :2].min(axis=0) <= com[:2]) and np.all(com[:2] <= first[:, :2].max(axis=0))


def read_npz_independently(path):
    """The arrays of an .npz by the zip and .npy formats alone (not np.load)."""
    import ast
    import zipfile

    out = {}
    with zipfile.ZipFile(path) as z:
        for name in z.namelist():
            raw = z.read(name)
            assert raw[:6] == b"\x93NUMPY"
            size = int.from_bytes(raw[8:10], "little") if raw[6] == 1 else int.from_bytes(raw[8:12], "little")
            start = 10 if raw[6] == 1 else 12
            header = ast.literal_eval(raw[start : start + size].decode("latin1"))
            data = np.frombuffer(raw[start + size :], dtype=np.dtype(header["descr"]))
            out[name.removesuffix(".npy")] = data.reshape(header["shape"])
    return out


def test_the_motion_graph_is_built_with_the_tree_and_its_verdicts_hold_by_our_own_kinematics(planner, body):
    """``reach build`` writes each tree's motion graph beside it: which stored postures the reference posture's direct
    motion reaches with every hard task held, and which pairs of neighbours are linked so. Read without numpy's loader,
    it names the tree's stored postures; at the build's samples, a motion it keeps (from the reference, or along an
    edge) keeps the soles where they stood and the centre of mass over them (our own Pinocchio forward kinematics), and
    one it says does not hold breaks a task at some sample."""
    import json

    from reach.maps.graph import STEP

    folder = planner.selector.atlas.path
    raw = read_npz_independently(folder / "whole.graph.npz")
    meta = json.loads(raw["meta"].tobytes())
    tree = planner.selector.atlas.trees["whole"]
    rows, _, postures = tree.stored()
    assert meta["format"] == "reach-motion-graph" and meta["tree_digest"] == tree.meta["digest"]
    assert np.array_equal(raw["rows"], rows) and raw["home"].dtype == bool and 0 < raw["home"].sum() < len(rows)
    oracle = planner.body("whole")
    reference = np.asarray(oracle.reference_posture(), float)
    data = body.model.createData()
    corners = [body.frame_id(f"{side}_{end}_{edge}") for side in ("right", "left") for end in ("heel", "toe")
               for edge in ("inner", "outer")]
    pin.framesForwardKinematics(body.model, data, reference)
    soles = np.array([data.oMf[f].translation for f in corners])
    assert raw["edges"].dtype == np.int32 and raw["edges"].shape[1] == 2 and len(raw["edges"]) > 0
    reached, missed = np.nonzero(raw["home"])[0][:5], np.nonzero(~raw["home"])[0][:5]
    motions = [(reference, postures[k], k in missed) for k in [*reached, *missed]]
    motions += [(postures[a], postures[b], False) for a, b in raw["edges"][:: max(1, len(raw["edges"]) // 5)]]
    for a, b, breaks in motions:
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / STEP)))
        samples = oracle.interpolate(a, b, np.arange(1, n) / n)
        if breaks:
            assert any(oracle.faults(samples))
            continue
        for q in samples:
            pin.framesForwardKinematics(body.model, data, q)
            np.testing.assert_allclose([data.oMf[f].translation for f in corners], soles, atol=2e-4)
            com = pin.centerOfMass(body.model, data, q)
            assert np.all(soles[:, :2].min(axis=0) <= com[:2]) and np.all(com[:2] <= soles[:, :2].max(axis=0))


def test_a_motion_from_the_reference_goes_through_the_graph_settled_and_every_frame_holds(planner, body):
    routes = []
    for goal in ([0.35, -0.2, 0.45], [0.1, 0.2, 0.9], [0.4, -0.3, 1.0], [0.5, -0.4, 0.8]):
        m = planner.plan("right_hand", goal)
        oracle = planner.body(m.strategy)
        assert not any(oracle.faults(m.postures)) and np.linalg.norm(hand(body, m.postures[-1]) - goal) <= TOL
        assert m.summary()["route"] == m.route
        if m.route == "graph":
            assert m.held == 0 and m.end == "settled"
        routes.append((m.strategy, m.route))
    assert ("whole", "graph") in routes, routes


def test_a_motion_from_another_posture_joins_the_graph_and_every_frame_holds(planner, body):
    """From a posture that is not the reference (the end of another reach), the motion joins the graph at a stored
    posture near it (a segment checked now) and follows the graph's shortest path; every frame holds."""
    first = planner.plan("right_hand", [0.4, -0.3, 1.0])
    start = dict(zip(first.names, first.postures[-1].tolist(), strict=True))
    routes = []
    for goal in ([0.45, -0.25, 1.2], [0.35, -0.35, 1.1], [0.5, -0.2, 1.0]):
        m = planner.plan("right_hand", goal, start)
        np.testing.assert_allclose(m.postures[0], first.postures[-1], atol=1e-9)
        assert not any(planner.body(m.strategy).faults(m.postures)) and m.end == "refined"
        assert np.linalg.norm(hand(body, m.postures[-1]) - goal) <= TOL
        routes.append((m.strategy, m.route))
    assert ("arm", "graph") in routes and ("whole", "graph") in routes, routes


def test_a_graph_not_made_for_its_tree_or_unreadable_is_not_used(planner, tmp_path):
    """A graph file that is not one (or was made for another tree) is passed over: every motion is planned as without
    one, and reading it says which file and what is wrong."""
    import shutil

    from reach.errors import StoreError
    from reach.maps.atlas import load_atlas
    from reach.maps.graph import load_graph

    folder = tmp_path / "atlas"
    shutil.copytree(planner.selector.atlas.path, folder)
    (folder / "whole.graph.npz").write_bytes(b"not a zip")
    with pytest.raises(StoreError, match=r"whole\.graph\.npz.*not a motion graph"):
        load_graph(folder / "whole.graph.npz")
    other = Planner(Selector(load_atlas(folder), policy="optimistic").warm_up(), budget=5.0)
    m = other.plan("right_hand", [0.35, -0.2, 0.45])
    assert m.route == "planned" and not any(other.body("whole").faults(m.postures))
    # `reach info` says which graphs an atlas has, and which it cannot use
    from reach.answers.audit import summary

    graphs = {n: s["motion_graph"] for n, s in summary(load_atlas(folder))["strategies"].items()}
    assert graphs["whole"]["state"] == "unreadable" and "whole.graph.npz" in graphs["whole"]["reason"]
    arm = other.selector.atlas.trees["arm"].stored()
    assert graphs["arm"]["state"] == "ok" and graphs["arm"]["stored"] == len(arm[0])
    (folder / "arm.graph.npz").unlink()
    assert summary(load_atlas(folder))["strategies"]["arm"]["motion_graph"] == {"state": "missing"}


def test_build_motion_graph_is_a_boolean_by_name():
    config = human_config(name="g")
    config["build"] = {"motion_graph": "yes"}
    from reach.errors import ConfigError

    with pytest.raises(ConfigError, match=r"build\.motion_graph.*expected true or false"):
        parse_config(config, "g", "g")
    config["build"] = {"motion_graph": False}
    assert parse_config(config, "g", "g").motion_graph is False


def test_a_goal_the_first_strategy_cannot_settle_is_settled_by_the_next_that_holds_it(planner, body, monkeypatch):
    """As a refinement hands over: when the arm's stored postures do not settle onto the goal, the next strategy by
    priority whose tree holds it answers, settled, without a solve."""
    arm = planner.body("arm")
    settle = type(arm).settle
    monkeypatch.setattr(type(arm), "settle", lambda self, q, g: None if self is arm else settle(self, q, g))
    goal = np.array([0.45, -0.25, 1.2])
    m = planner.plan("right_hand", goal)
    assert planner.selector.select("right_hand", goal, False).strategy == "arm"
    assert m.strategy == "whole" and m.end == "settled" and m.outcome == "reached"
    assert not any(planner.body("whole").faults(m.postures))
    assert np.linalg.norm(hand(body, m.postures[-1]) - goal) <= TOL


def test_a_graph_file_with_bad_fields_is_refused_naming_the_field(tmp_path):
    from reach.errors import StoreError
    from reach.maps.graph import MotionGraph, load_graph, save_graph

    good = MotionGraph(np.arange(3, dtype=np.int64), np.array([True, False, True]), np.array([[0, 1]], np.int32),
                       {"tree_digest": "x"})
    loaded = load_graph(save_graph(good, tmp_path / "g.graph.npz"))
    assert np.array_equal(loaded.edges, good.edges) and loaded.meta["tree_digest"] == "x"
    bad = MotionGraph(good.rows, good.home, np.array([[0, 7]], np.int32), {})
    with pytest.raises(StoreError, match=r"g\.graph\.npz.*edges: expected \(E, 2\) int32 indices into rows"):
        load_graph(save_graph(bad, tmp_path / "g.graph.npz"))


def test_the_graph_made_on_two_processes_is_the_one_made_inline(planner):
    """``reach build`` checks a graph's motions on its executor's workers (each its own oracle of the strategy's
    spec): the graph is the one this fixture's inline build made, motion for motion."""
    from oracles.protocol import OracleSpec
    from reach.building.executor import ProcessExecutor
    from reach.maps.graph import build_graph, load_graph

    tree = planner.selector.atlas.trees["whole"]
    pool = ProcessExecutor(OracleSpec.from_dict(tree.meta["oracle"]), workers=2, chunk_size=50)
    try:
        made = build_graph(tree, planner.body("whole"), apply=pool.apply)
    finally:
        pool.close()
    inline = load_graph(planner.selector.atlas.path / "whole.graph.npz")
    assert made is not None and made.meta["samples"] == inline.meta["samples"] > 0
    assert np.array_equal(made.home, inline.home) and np.array_equal(made.edges, inline.edges)


def test_the_least_shift_is_the_projection_onto_the_polygon_and_the_pelvis_bounds():
    """oracles.ik.balancing.least_shift against the answers worked by hand on a square (|x|, |y| <= 0.1 m): the
    shortest move of the root that puts the centre of mass (moved GAIN times as far) DEPTH inside."""
    from oracles.ik.balancing import DEPTH, GAIN, least_shift

    square = np.array([[1, 0, -0.1], [-1, 0, -0.1], [0, 1, -0.1], [0, -1, -0.1]], float)
    inside = 0.1 - DEPTH
    # beyond a corner: to the corner; beyond an edge: straight back to it; inside: no move
    np.testing.assert_allclose(least_shift(square, None, np.array([0.15, 0.12]), np.zeros(2)),
                               (np.array([inside, inside]) - [0.15, 0.12]) / GAIN, atol=1e-12)
    np.testing.assert_allclose(least_shift(square, None, np.array([0.0, -0.13]), np.zeros(2)),
                               [0.0, (0.13 - inside) / GAIN], atol=1e-12)
    assert not least_shift(square, None, np.array([0.05, -0.09]), np.zeros(2)).any()
    # the pelvis (the root) may not go past x = 0.02: the move to the edge's line is cut there, and y takes the rest
    pelvis = np.array([[1.0, 0.0, -0.02]])
    d = least_shift(square, pelvis, np.array([0.12, 0.0]), np.zeros(2))
    assert d[0] <= 0.02 - DEPTH + 1e-12
    np.testing.assert_allclose(d, [(inside - 0.12) / GAIN, 0.0], atol=1e-12)  # moving back is allowed
    d = least_shift(square, np.array([[-1.0, 0.0, -0.01]]), np.array([0.12, 0.0]), np.zeros(2))
    assert not d.any()  # the pelvis may not move back past x = -0.01: no move brings the centre of mass inside


def test_a_standing_path_is_kept_over_the_feet_by_moving_the_root_continuously(planner, body):
    """Between stored postures of a standing strategy, the oracle's interpolation moves the root aside where the plain
    path (Pinocchio's, the feet held) takes the centre of mass out of the soles' polygon: checked by our own forward
    kinematics and scipy's hull of the sole corners shrunk by the balance margin. Every moved posture whose feet stand
    where they stood is balanced; the path has no jump; and a posture's correction is the same whichever fractions of
    the path are asked, to the legs' holds' tolerance (a motion's frames are the graph's samples)."""
    from scipy.spatial import ConvexHull

    from oracles.bodies.posed import PosedBody

    oracle = planner.body("whole")
    rows, points, postures = planner.selector.atlas.trees["whole"].stored()
    data = body.model.createData()
    corners = [body.frame_id(f"{side}_{end}_{edge}") for side in ("right", "left") for end in ("heel", "toe")
               for edge in ("inner", "outer")]
    pin.framesForwardKinematics(body.model, data, np.asarray(oracle.reference_posture(), float))
    soles = np.array([data.oMf[f].translation for f in corners])
    hull = ConvexHull(soles[:, :2]).equations
    margin = oracle.strategy.task("balance").margin

    def outside(q):  # [m] past the shrunk polygon (> 0: out)
        pin.framesForwardKinematics(body.model, data, q)
        return float(np.max(hull[:, :2] @ pin.centerOfMass(body.model, data, q)[:2] + hull[:, 2] + margin))

    def standing(q):
        pin.framesForwardKinematics(body.model, data, q)
        return np.abs(np.array([data.oMf[f].translation for f in corners]) - soles).max() <= 2e-4

    s = np.linspace(0.0, 1.0, 41)
    plain_out = moved = balanced = mended = 0
    # stored postures paired at random: farther apart than neighbours, their plain paths leave the polygon more often
    for a, b in np.random.default_rng(0).choice(len(postures), (150, 2)):
        qa, qb = postures[a], postures[b]
        if outside(qa) > 1e-5 or outside(qb) > 1e-5:
            continue
        plain = oracle._held(qa, qb, PosedBody.interpolate(oracle, qa, qb, s))
        if max(outside(q) for q in plain) <= 1e-5:
            continue
        plain_out += 1
        path = oracle.interpolate(qa, qb, s)
        # (the legs' holds start from the previous posture's and stop within their tolerance: not to rounding)
        np.testing.assert_allclose(oracle.interpolate(qa, qb, s[3::7]), path[3::7], atol=2e-3)
        # no jump: the root's steps along the corrected path stay within the plain path's and a few millimetres
        step = np.linalg.norm(np.diff(path[:, :3], axis=0), axis=1).max()
        assert step <= np.linalg.norm(np.diff(plain[:, :3], axis=0), axis=1).max() + 0.005
        for q, p in zip(path, plain, strict=True):
            if np.abs(q[:2] - p[:2]).max() > 0 and standing(q):
                moved += 1
                balanced += outside(q) <= 1e-5
        mended += not any(oracle.faults(path))
    assert plain_out >= 3 and moved >= 10, (plain_out, moved)
    assert balanced == moved and mended >= 1, (balanced, moved, mended)
