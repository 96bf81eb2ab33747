"""Robots as they come: URDFs turned, given frames and reference postures in the config, and checked at load."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml

from oracles.bodies.body import load_body
from oracles.errors import ModelError
from oracles.protocol import OracleSpec, body_params
from reach.building.config import load_config, parse_config
from reach.errors import ConfigError, InputError
from reach.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "configs" / "urdf"
EXAMPLES = ROOT / "configs" / "examples"


def _frames(model: pin.Model, q: np.ndarray) -> dict[str, np.ndarray]:
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return {str(f.name): data.oMf[i].translation.copy() for i, f in enumerate(model.frames)}


def test_up_and_forward_place_the_model_as_a_rotated_wrapper_urdf_does(tmp_path):
    """A y-up, z-forward character turned by the config stands where an independent wrapper URDF puts it:
    a new base link and a fixed joint with rpy (pi/2, 0, pi/2), i.e. Rz(90) Rx(90), which sends the model's
    x, y, z onto the world's y, z, x (worked by hand)."""
    text = (URDF / "yup_humanoid.urdf").read_text()
    wrapper = text.replace('<robot name="yup_humanoid">', '<robot name="wrapped"><link name="base"/>'
                           '<joint name="turn" type="fixed"><parent link="base"/><child link="pelvis"/>'
                           f'<origin xyz="0 0 1.0" rpy="{math.pi / 2} 0 {math.pi / 2}"/></joint>')
    (tmp_path / "wrapped.urdf").write_text(wrapper)
    turned = load_body({"urdf": str(URDF / "yup_humanoid.urdf"), "up": "y", "forward": "z",
                        "root_position": [0, 0, 1.0]})
    wrapped = load_body({"urdf": str(tmp_path / "wrapped.urdf")})
    a, b = turned.frame_positions(), wrapped.frame_positions()
    for name in ("head", "right_hand", "left_hand", "right_shoulder", "chest"):
        assert np.allclose(a[name], b[name], atol=1e-9), name
    assert a["head"][2] > a["chest"][2] > 1.0  # the head is up
    assert a["left_shoulder"][1] > 0 > a["right_shoulder"][1]  # the model's x (its left) is the world's y (left)
    # Moving a joint moves both alike: the root's turn is the reference, not a clipped coordinate.
    qa, qb = turned.q_ref.copy(), wrapped.q_ref.copy()
    for body, q in ((turned, qa), (wrapped, qb)):
        q[body.model.joints[body.joint_id("right_shoulder_flexion")].idx_q] = 1.2
    assert np.allclose(turned.frame_positions(qa)["right_hand"], wrapped.frame_positions(qb)["right_hand"], atol=1e-9)


def test_up_forward_and_root_rpy_errors_name_the_key():
    with pytest.raises(ModelError, match=r"ur5.urdf: up: expected one of x, -x, y, -y, z, -z"):
        load_body({"urdf": str(URDF / "ur5.urdf"), "up": "w"})
    with pytest.raises(ModelError, match=r"forward: expected one of x, -x, z, -z .*perpendicular to up y.*got 'y'"):
        load_body({"urdf": str(URDF / "ur5.urdf"), "up": "y", "forward": "y"})
    with pytest.raises(ModelError, match=r"root_rpy: expected 3 numbers \[rad\]"):
        load_body({"urdf": str(URDF / "ur5.urdf"), "root_rpy": [0, 1]})
    with pytest.raises(ModelError, match=r"^up: a URDF body's key"):
        load_body({"human": {}, "up": "y"})


def test_root_rpy_turns_the_root_about_the_world_axes():
    plain = load_body({"urdf": str(URDF / "ur5.urdf")})
    yawed = load_body({"urdf": str(URDF / "ur5.urdf"), "root_rpy": [0, 0, math.pi / 2]})
    p, y = plain.frame_positions()["ee_link"], yawed.frame_positions()["ee_link"]
    assert np.allclose(y, [-p[1], p[0], p[2]], atol=1e-9)  # a quarter turn about z: (x, y) -> (-y, x)
    assert plain.hash != yawed.hash


def test_frames_are_added_on_their_parent():
    body = load_body({"urdf": str(URDF / "arm7.urdf"), "frames": {"tcp": {"parent": "arm7_hand", "xyz": [0, 0, 0.1034]},
                                                                   "side": {"parent": "arm7_link3",
                                                                       "xyz": [0.1, 0, 0], "rpy": [0, 0, 1.0]}}})
    model = body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, body.q_ref)
    hand = data.oMf[model.getFrameId("arm7_hand")]
    assert np.allclose(data.oMf[model.getFrameId("tcp")].translation, hand.translation + hand.rotation[:, 2] * 0.1034)
    link3 = data.oMf[model.getFrameId("arm7_link3")]
    assert np.allclose(data.oMf[model.getFrameId("side")].translation, link3.translation + link3.rotation[:, 0] * 0.1)
    with pytest.raises(ModelError, match=r"frames.tcp.parent: no frame 'hand'; frames are: "):
        load_body({"urdf": str(URDF / "arm7.urdf"), "frames": {"tcp": {"parent": "hand"}}})
    with pytest.raises(ModelError, match=r"frames.arm7_hand: the model already has a frame 'arm7_hand'"):
        load_body({"urdf": str(URDF / "arm7.urdf"), "frames": {"arm7_hand": {"parent": "arm7_link7"}}})
    with pytest.raises(ModelError, match=r"arm7.urdf: frames: expected a mapping of name to \{parent, xyz, rpy\}"):
        load_body({"urdf": str(URDF / "arm7.urdf"), "frames": ["tcp"]})
    with pytest.raises(ModelError, match=r"frames.tcp: expected \{parent: FRAME"):
        load_body({"urdf": str(URDF / "arm7.urdf"), "frames": {"tcp": {"parent": "arm7_hand", "xzy": [0, 0, 1]}}})


def test_reference_posture_given_clipped_or_refused():
    clipped = load_body({"urdf": str(URDF / "arm7.urdf")})
    j4 = clipped.model.joints[clipped.joint_id("arm7_joint4")].idx_q
    assert clipped.q_ref[j4] == pytest.approx(-0.0698)
    assert clipped.notes == ("reference: joint 'arm7_joint4' at 0 is outside its range [-3.0718, -0.0698]; it stands "
                             "at -0.0698 (give body.reference to choose)",)
    ready = load_body({"urdf": str(URDF / "arm7.urdf"),
                       "reference": {"arm7_joint4": -2.356194, "arm7_joint6": 1.570796}})
    assert ready.q_ref[j4] == pytest.approx(-2.356194) and ready.notes == ()
    middle = load_body({"urdf": str(URDF / "arm7.urdf"), "reference": "middle"})
    assert middle.q_ref[j4] == pytest.approx(0.5 * (-3.0718 - 0.0698))
    with pytest.raises(ModelError, match=r"reference.arm7_joint4: -3.5 is outside the joint's range \[-3.0718, "
                                         r"-0.0698\]"):
        load_body({"urdf": str(URDF / "arm7.urdf"), "reference": {"arm7_joint4": -3.5}})
    with pytest.raises(ModelError, match=r"reference.elbow: no such joint; joints are: arm7_joint1"):
        load_body({"urdf": str(URDF / "arm7.urdf"), "reference": {"elbow": 0.1}})
    assert ready.hash != clipped.hash


def test_package_dirs_error_names_the_folder_to_give(tmp_path):
    pkg = tmp_path / "ws" / "my_robot"
    (pkg / "urdf").mkdir(parents=True)
    urdf = pkg / "urdf" / "r.urdf"
    urdf.write_text('<robot name="r"><link name="a"><collision><geometry><mesh '
                    'filename="package://my_robot/meshes/a.stl"/></geometry></collision></link></robot>')
    with pytest.raises(ModelError) as err:
        load_body({"urdf": str(urdf), "package_dirs": [str(pkg)]})
    assert err.value.key == "package_dirs"
    assert "give package_dirs the folder that holds the package folder 'my_robot'" in str(err.value)
    assert f"{tmp_path / 'ws'} holds a folder 'my_robot': give it" in str(err.value)


def _config(body: dict, strategies: list[dict], box: object = "auto") -> dict:
    return {"name": "t", "body": body, "box": box, "depth": {"min": 1, "max": 2}, "oracle": {"name": "casadi-ik"},
            "strategies": strategies}


def test_config_errors_name_the_key_where_it_was_written():
    arm = {"name": "a", "effector": "ee_link", "joints": ["*_joint"],
           "tasks": [{"type": "reach"}, {"type": "self_collision", "margn": 1}]}
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.tasks\[1\]: unknown keys \['margn'\]"):
        parse_config(_config({"urdf": str(URDF / "ur5.urdf")}, [arm]))
    arm["tasks"] = [{"type": "reach"}]
    with pytest.raises(ConfigError, match=r"body\.frames\.tcp\.parent: .*ur5.urdf: no frame 'hand'"):
        parse_config(_config({"urdf": str(URDF / "ur5.urdf"), "frames": {"tcp": {"parent": "hand"}}}, [arm]))
    with pytest.raises(ConfigError, match=r"body\.colour: unknown key"):
        parse_config(_config({"urdf": str(URDF / "ur5.urdf"), "colour": "red"}, [arm]))
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.joints: no joint matches 'wrist'"):
        parse_config(_config({"urdf": str(URDF / "ur5.urdf")}, [{**arm, "joints": ["wrist"]}]))
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.effector: .*ur5.urdf: no frame 'tool0'"):
        parse_config(_config({"urdf": str(URDF / "ur5.urdf")}, [{**arm, "effector": "tool0"}]))
    with pytest.raises(ConfigError, match=r"ur5\.urdf: reference\.elbow_joint|body\.reference\.elbow_joint"):
        parse_config(_config({"urdf": str(URDF / "ur5.urdf"), "reference": {"elbow_joint": 9}}, [arm]))


def test_load_time_warnings_name_the_joint_pair_and_task():
    arm = {"name": "arm", "effector": "arm7_flange", "joints": ["arm7_joint*"],
           "tasks": [{"type": "reach"}, {"type": "self_collision"}]}
    # The Panda's zero posture folds its hand into its forearm once joint 4 is clipped: both are said.
    notes = parse_config(_config({"urdf": str(URDF / "arm7.urdf")}, [arm])).notes
    assert any("joint 'arm7_joint4' at 0 is outside its range" in n for n in notes)
    folded = [n for n in notes if "overlap by" in n]
    assert folded and all(n.startswith("strategy arm: capsules arm7_link") for n in folded)
    # The example's ready posture has none.
    assert load_config(EXAMPLES / "arm7_table.yaml").notes == ()
    # The biped's feet with no corners: the foot stands on its frame, and balance cannot be asked.
    raw = yaml.safe_load((EXAMPLES / "biped.yaml").read_text())
    raw["body"]["urdf"] = str(URDF / "biped.urdf")
    whole = raw["strategies"][1]
    bare = [t for t in whole["tasks"] if t["type"] != "balance"]
    bare[1] = {"type": "feet", "frames": ["r_sole", "l_sole"]}
    notes = parse_config({**raw, "strategies": [{**whole, "tasks": bare}]}).notes
    assert any("foot 'r_sole' has no sole corners" in n for n in notes)
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.tasks\[4\]: balance needs a support polygon of 3 frames "
                                          r"or more.*soles"):
        parse_config({**raw, "strategies": [{**whole, "tasks": [*bare, {"type": "balance"}]}]})
    # A floor that the planted feet's own capsules go through at the reference: no posture near it holds it.
    floored = [*(t for t in bare if t["type"] != "floor"), {"type": "floor", "exclude": []}]
    notes = parse_config({**raw, "strategies": [{**whole, "tasks": floored}]}).notes
    assert any("the reference posture breaks the hard tasks ['floor'] and no posture near it holds them" in n
               for n in notes)


def test_the_floor_stands_the_held_segments_of_any_robot():
    """Without exclude, the floor leaves out the capsules of the segments holding the feet, whatever their names."""
    raw = yaml.safe_load((EXAMPLES / "biped.yaml").read_text())
    raw["body"]["urdf"] = str(URDF / "biped.urdf")
    spec = raw["strategies"][1]
    oracle = OracleSpec("casadi-ik", body_params(raw["body"], spec["effector"], spec["joints"], spec["tasks"])).create()
    floor = oracle.strategy.task("floor")
    names = {oracle.body.collision.placed[i].name for i in floor.capsules}
    assert "r_foot_0" not in names and "l_foot_0" not in names and {"r_shank_0", "r_hand_0", "pelvis_0"} <= names
    assert oracle.diagnose() == []


def test_box_auto_cuts_the_floor_only_where_a_floor_task_holds_the_effector():
    arm7 = load_config(EXAMPLES / "arm7_table.yaml")  # no floor task: the arm reaches below its table top's plane
    assert arm7.box.lo[2] < -0.5
    biped = load_config(EXAMPLES / "biped.yaml")  # the whole body's floor task holds the hand above z = 0
    assert biped.box.lo[2] == 0.0
    raw = yaml.safe_load((EXAMPLES / "arm7_table.yaml").read_text())
    raw["body"]["urdf"] = str(URDF / "arm7.urdf")
    assert parse_config({**raw, "box": {"auto": {"floor": True}}}).box.lo[2] == 0.0
    with pytest.raises(ConfigError, match=r"box.auto.floor: expected auto, true or false"):
        parse_config({**raw, "box": {"auto": {"floor": "yes"}}})


def test_reach_model_takes_a_urdfs_placement_and_prints_frames_and_warnings(capsys):
    assert main(["model", str(URDF / "yup_humanoid.urdf"), "--up", "y", "--forward", "z", "--root-position", "0", "0",
                 "1", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"]["head"][2] > 1.5 and info["warnings"] == []
    assert main(["model", str(URDF / "arm7.urdf")]) == 0
    out = capsys.readouterr()
    assert "frames at the reference posture [m]:" in out.out and "arm7_flange" in out.out
    assert "warning: reference: joint 'arm7_joint4'" in out.err
    assert main(["model", "human", "--up", "y"]) == 2
    assert "up: options for a URDF" in capsys.readouterr().err
    assert main(["model", str(URDF / "ur5.urdf"), "--up", "q"]) == 2
    assert "ur5.urdf: up: expected one of" in capsys.readouterr().err


def test_a_box_that_cuts_the_volume_grows_within_its_limit(tmp_path):
    """box: auto's B0 grows on the faces reachable vertices lie on, up to the provable bound, and the atlas is built
    again."""
    from reach.building.atlas import build_atlas
    from reach.building.autobox import grown
    from reach.maps.box import Box

    raw = {"box": {"min": [-1.2, -1.2, -1.2], "max": [1.2, 1.2, 1.2]}, "depth": {"min": 1, "max": 3},
           "oracle": {"name": "sphere", "params": {"radius": 1.0}},
           "strategies": [{"name": "ball", "effector": "point"}]}
    config = parse_config(raw)
    small = Box(np.array([-0.6, -1.2, -1.2]), np.array([1.2, 1.2, 1.2]))  # cuts the unit ball on x-
    assert grown(small, config.box, {"x-"}) == Box(np.array([-1.05, -1.2, -1.2]), np.array([1.2, 1.2, 1.2]))
    assert grown(config.box, config.box, {"x-", "z+"}) is None  # at the limit: nothing can move
    lines: list[str] = []
    atlas = build_atlas(config.with_box(small, limit=config.box), tmp_path / "a", log=lines.append)
    tree = atlas.tree("ball")
    assert tree.box.lo[0] == pytest.approx(-1.05) and tree.faces() == {}
    # stopped at the first depth whose reachable vertices met the face (the face's centre, depth 1), not after the
    # whole tree
    assert any("B0 grows to min [-1.05, -1.2, -1.2]" in line and "(found at depth 1 of ball)" in line
               for line in lines)
    assert atlas.manifest["warnings"]["faces"] == []
    # the same tree as a build of the grown box from the start
    direct = build_atlas(config.with_box(tree.box, limit=config.box), tmp_path / "b").tree("ball")
    assert direct.meta["digest"] == tree.meta["digest"] and len(direct) == len(tree)


def test_box_auto_probes_a_standing_body_instead_of_a_ball_about_its_foot():
    config = load_config(EXAMPLES / "biped.yaml")
    size, limit = config.box.hi - config.box.lo, config.limit.hi - config.limit.lo
    assert np.all(size[:2] < 0.7 * limit[:2])  # the 4.3 m ball about the foot, sized down to the body's reach
    assert config.box.hi[2] > 2.0  # the raised hand (2.05 m found) stays inside


def test_build_strict_refuses_a_config_with_warnings_before_building(tmp_path, capsys):
    raw = yaml.safe_load((EXAMPLES / "arm7_table.yaml").read_text())
    raw["body"] = {"urdf": str(URDF / "arm7.urdf"), "frames": raw["body"]["frames"]}  # no reference: joint 4 is clipped
    config = tmp_path / "clipped.yaml"
    config.write_text(yaml.safe_dump(raw))
    assert main(["build", str(config), "-o", str(tmp_path / "out"), "--strict"]) == 2
    err = capsys.readouterr().err
    assert "warning: " in err and "joint 'arm7_joint4' at 0 is outside its range" in err
    assert "--strict makes them errors" in err
    assert not (tmp_path / "out" / "tcp.npz").exists()


def _turntable_tool(joints: dict[str, float]) -> np.ndarray:
    """The turntable's tool [m] by its own geometry (tests/data/turntable.urdf), not Pinocchio's: the arm's length
    0.35 m plus the extension, raised by the shoulder about -y at 0.3 m, turned by the base about z."""
    length, s, t = 0.35 + joints["extend"], joints["shoulder"], joints["base_turn"]
    return np.array([length * math.cos(s) * math.cos(t), length * math.cos(s) * math.sin(t),
                     0.3 + length * math.sin(s)])


def test_a_continuous_joint_is_one_angle_in_answers_motions_configs_and_reach_model(tmp_path, capsys):
    """A continuous joint came back as NAME_0 and NAME_1 (its cosine and sine), which a user's
    own forward kinematics read as two joints. It is one angle in (-pi, pi] under the joint's own name, in answers,
    motion frames and a query's ``from``; ``reach model`` shows it as continuous."""
    from reach.answers.select import Selector
    from reach.building.atlas import build_atlas
    from reach.motion.planner import Planner

    urdf = Path(__file__).parent / "data" / "turntable.urdf"
    config = parse_config({
        "name": "turntable", "body": {"urdf": str(urdf), "reference": {"base_turn": 0.5, "extend": 0.1}},
        "box": {"min": [-0.7, -0.7, -0.2], "max": [0.7, 0.7, 0.9]}, "depth": {"min": 2, "max": 3},
        "strategies": [{"name": "arm", "effector": "tool", "joints": ["base_turn", "shoulder", "extend"],
                        "tasks": [{"type": "reach"}]}],
    }, "turntable", "turntable")
    atlas = build_atlas(config, tmp_path / "turntable")
    assert atlas.trees["arm"].vertices.posture_names[-4:] == ("base_turn.cos", "base_turn.sin", "shoulder", "extend")
    selector = Selector(atlas).warm_up()
    # Goals behind the arm, on both sides of the turn's +-pi seam.
    goals = np.array([_turntable_tool({"base_turn": t, "shoulder": 0.3, "extend": 0.1}) for t in (2.9, -3.0, 3.1, 0.4)])
    for goal, answer in zip(goals, selector.select_many("tool", goals), strict=True):
        assert answer.reachable and set(answer.posture) == {"base_turn", "shoulder", "extend"}
        assert -math.pi < answer.posture["base_turn"] <= math.pi
        assert np.linalg.norm(_turntable_tool(answer.posture) - goal) <= 0.005  # the user's own forward kinematics
    # A query's `from` gives the angle; the raw coordinates are not joints.
    start = selector.select("tool", goals[0], start={"base_turn": 3.0, "shoulder": 0.2, "extend": 0.05})
    assert start.reachable and np.linalg.norm(_turntable_tool(start.posture) - goals[0]) <= 0.005
    with pytest.raises(InputError, match=r"from: unknown joints \['base_turn.cos'\]; the posture's names are "
                                         r".*base_turn, extend"):
        selector.select("tool", goals[0], start={"base_turn.cos": 1.0})
    frames = Planner(selector).plan("tool", goals[1], start={"base_turn": 0.5}).frames()
    assert frames[0]["posture"]["base_turn"] == pytest.approx(0.5) and "base_turn.sin" not in frames[-1]["posture"]
    assert np.linalg.norm(_turntable_tool(frames[-1]["posture"]) - goals[1]) <= 0.005
    assert main(["model", str(urdf)]) == 0
    out = capsys.readouterr().out
    assert (re.search(r"base_turn\s+continuous \(-pi, pi\]", out)
            and re.search(r"extend\s+\[\+0\.0000, \+0\.2500\]", out))


def test_reference_auto_turns_a_ur5s_tool_down_where_projection_cannot():
    """For a UR5's tool-down strategy, damped least squares from the middle of the ranges found no
    posture holding the orientation (every joint stayed at zero, and the build warned). The engine's own search then
    finds one: Pinocchio puts the tool's axis within the cone, and nothing is diagnosed."""
    body = {"urdf": str(ROOT / "configs" / "urdf" / "ur5.urdf"), "reference": "auto"}
    down = [{"type": "reach"}, {"type": "orientation", "axis": "x", "direction": "-z", "cone": 5}]
    oracle = OracleSpec("casadi-ik", {**body_params(body, "ee_link", ["*_joint"], down), "restarts": 2}).create()
    q = oracle.body.q_ref  # type: ignore[attr-defined]
    assert oracle.faults(q[None])[0] == [] and oracle.diagnose() == []  # type: ignore[attr-defined]
    data = oracle.body.model.createData()  # type: ignore[attr-defined]
    pin.framesForwardKinematics(oracle.body.model, data, q)  # type: ignore[attr-defined]
    axis = data.oMf[oracle.body.model.getFrameId("ee_link")].rotation[:, 0]  # type: ignore[attr-defined]
    assert axis[2] <= -math.cos(math.radians(5))


def test_reference_auto_finds_a_posture_holding_each_strategys_hard_tasks(tmp_path, capsys):
    """A strategy holding the tool pointing down started from a reference that breaks it, and the
    user had to solve a posture by hand. ``reference: auto`` starts from the middle of the ranges and finds, per
    strategy, the nearest posture that holds its hard tasks; ``reach model`` prints it; Pinocchio agrees."""
    body = {"urdf": str(URDF / "arm7.urdf"), "frames": {"tcp": {"parent": "arm7_hand", "xyz": [0, 0, 0.1034]}},
            "reference": "auto"}
    down = [{"type": "reach"}, {"type": "orientation", "axis": "z", "direction": "-z", "cone": 5}]
    oracle = OracleSpec("casadi-ik", {**body_params(body, "tcp", ["arm7_joint*"], down), "restarts": 1}).create()
    middle = load_body({**body, "reference": "middle"}).q_ref
    q = oracle.body.q_ref  # type: ignore[attr-defined]
    assert (not np.allclose(q, middle) and oracle.faults(middle[None])[0] == ["orientation"]
            and oracle.faults(q[None])[0] == [])  # type: ignore[attr-defined]
    tool = _frames(oracle.body.model, q)["tcp"]  # type: ignore[attr-defined]
    assert np.allclose(tool, _frames(oracle.body.model, middle)["tcp"], atol=1e-3)  # the tool turned where it stood
    data = oracle.body.model.createData()  # type: ignore[attr-defined]
    pin.framesForwardKinematics(oracle.body.model, data, q)  # type: ignore[attr-defined]
    assert (data.oMf[oracle.body.model.getFrameId("tcp")].rotation @ [0, 0,
        1])[2] <= -math.cos(math.radians(5))  # type: ignore[attr-defined]
    assert oracle.diagnose() == [] and "reference" in oracle.describe()  # type: ignore[attr-defined]
    free = OracleSpec("casadi-ik",
                      {**body_params(body, "tcp", ["arm7_joint*"], [{"type": "reach"}]), "restarts": 1}).create()
    assert np.allclose(free.body.q_ref, middle)  # type: ignore[attr-defined]  # nothing to hold: the middle itself
    config = tmp_path / "auto.yaml"
    config.write_text(yaml.safe_dump({"name": "auto", "body": body, "box": {"min": [-1, -1, 0], "max": [1, 1, 1.2]},
                                      "depth": {"min": 1, "max": 2},
                                      "strategies": [{"name": "down", "effector": "tcp", "joints": ["arm7_joint*"],
                                                      "tasks": down}]}))
    assert main(["model", str(config)]) == 0
    assert re.search(r"down: reference \(auto\) arm7_joint1 [+-]\d\.\d{4}, arm7_joint2", capsys.readouterr().out)


def _ur5_twins_config(boxes: list[dict], twins: bool = True) -> dict:
    tasks = [{"type": "reach"}, {"type": "self_collision"}, {"type": "obstacles", "boxes": boxes}]
    return {"name": "twins", "body": {"urdf": str(URDF / "ur5.urdf")},
            "box": {"min": [-1.0, -1.0, -0.2], "max": [1.0, 1.0, 1.0]}, "depth": {"min": 2, "max": 3},
            "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "seed": 0}},
            "build": {"twins": twins},
            "strategies": [{"name": "guarded", "effector": "ee_link", "joints": ["*_joint"], "tasks": tasks}]}


def _turned_keys(tree, quarters: int) -> np.ndarray:  # noqa: ANN001
    """Each vertex's row turned by quarters x 90 deg about z through the origin (the UR5's base axis), or -1."""
    pts = tree.lattice.points(tree.lattice.coords(tree.vertices.keys))
    angle = quarters * math.pi / 2
    c, s = round(math.cos(angle)), round(math.sin(angle))
    turned = np.column_stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1], pts[:, 2]])
    steps = np.rint((turned - tree.box.lo) / tree.lattice.resolution).astype(np.int64)
    return tree.vertices.index(tree.lattice.keys(steps))


def test_a_turning_base_on_a_square_floor_solves_one_of_each_four_twins_and_they_agree(tmp_path, capsys):
    """The UR5's base turns a full turn and its floor box is a square about the base: a quarter turn maps the volume
    onto itself. One vertex of each set of twins is solved and the others take its verdict, their postures turned:
    every twin pair agrees, each reachable posture puts the flange at its vertex by Pinocchio (computed here), and the
    oracle is asked about far fewer vertices than the tree holds. A floor box off centre turns nothing."""
    from reach.building.atlas import build_atlas

    floor = {"name": "floor", "min": [-2, -2, -0.3], "max": [2, 2, -0.02]}
    atlas = build_atlas(parse_config(_ur5_twins_config([floor]), str(tmp_path / "t.yaml")), tmp_path / "a")
    tree = atlas.trees["guarded"]
    v = tree.vertices
    build = tree.meta["build"]
    assert build["turned"] > 0 and build["oracle_calls"] + build["turned"] == len(v)
    assert build["oracle_calls"] < 0.4 * len(v)
    assert main(["info", str(tmp_path / "a")]) == 0
    assert f"{build['turned']} vertices given their twin's verdict a quarter turn away" in capsys.readouterr().out
    for quarters in (1, 2, 3):
        rows = _turned_keys(tree, quarters)
        pairs = rows >= 0
        assert pairs.sum() > 0.9 * len(v)
        assert np.array_equal(v.reachable[pairs], v.reachable[rows[pairs]])
    model = load_body({"urdf": str(URDF / "ur5.urdf")}).model
    data, fid = model.createData(), model.getFrameId("ee_link")
    pts = tree.lattice.points(tree.lattice.coords(v.keys))
    assert v.reachable.sum() > 20
    for p, q in zip(pts[v.reachable], v.posture[v.reachable], strict=True):
        pin.framesForwardKinematics(model, data, q)
        assert np.linalg.norm(data.oMf[fid].translation - p) <= 0.005
        assert np.all(q >= model.lowerPositionLimit - 1e-9) and np.all(q <= model.upperPositionLimit + 1e-9)
    off = {"name": "floor", "min": [-2, -1.5, -0.3], "max": [2, 2, -0.02]}
    lone = build_atlas(parse_config(_ur5_twins_config([off]), str(tmp_path / "u.yaml")), tmp_path / "b")
    assert lone.trees["guarded"].meta["build"]["turned"] == 0


def test_build_twins_false_solves_every_vertex_and_a_wrong_value_names_the_key(tmp_path):
    from reach.building.atlas import build_atlas

    floor = {"name": "floor", "min": [-2, -2, -0.3], "max": [2, 2, -0.02]}
    config = parse_config(_ur5_twins_config([floor], twins=False), str(tmp_path / "t.yaml"))
    tree = build_atlas(config, tmp_path / "a").trees["guarded"]
    assert tree.meta["build"]["turned"] == 0 and tree.meta["build"]["oracle_calls"] == len(tree.vertices)
    with pytest.raises(ConfigError, match=r"build\.twins: expected true or false, got 'yes'"):
        parse_config({**_ur5_twins_config([floor]), "build": {"twins": "yes"}}, str(tmp_path / "t.yaml"))


def test_blocked_starts_default_by_body_and_refuse_bad_values():
    """The batched engine's rescues of goals reached only through a collision: a URDF's body gets BLOCKED_STARTS by
    default, the generated human none (its capsules let the batched steps out; docs/results.md); a bad value names the
    key."""
    from oracles.errors import OracleError
    from oracles.ik.solvers.batched import BLOCKED_STARTS

    tasks = [{"type": "reach"}, {"type": "self_collision"}]
    robot = {"urdf": str(URDF / "ur5.urdf")}
    assert OracleSpec("casadi-ik", body_params(robot, "ee_link", ["*_joint"], tasks)).create() \
        .solver.blocked_starts == BLOCKED_STARTS  # type: ignore[attr-defined]
    human = OracleSpec("casadi-ik", body_params({"human": {"sex": "male"}}, "right_hand",
                                               ["right_shoulder*", "right_elbow*"], tasks)).create()
    assert human.solver.blocked_starts == 0  # type: ignore[attr-defined]
    params = body_params(robot, "ee_link", ["*_joint"], tasks)
    for bad in (-1, 300, True, "many"):
        with pytest.raises(OracleError, match="blocked_starts"):
            OracleSpec("casadi-ik", {**params, "blocked_starts": bad}).create()


def test_goals_reached_only_through_a_collision_are_rescued_and_every_rescue_holds(monkeypatch):
    """The UR5 guarded against itself and a floor box, asked cold about goals low beside its base, where starts reach
    through the floor or the base: with its rescues it tries more (fatrop from fresh random starts), never calls
    reachable a goal it called unreachable without them, and every posture it calls reachable passes the independent
    check (Pinocchio FK, coal on the capsules, the box). The near misses' last wave is kept at its smallest: at its
    size now it reaches the two goals the rescues add here as well."""
    import sys

    from oracles.ik import waves

    sys.path.insert(0, str(ROOT / "tests"))
    from truth_suite import independent_check

    monkeypatch.setattr(waves, "NEAR_WAVE", 1)

    boxes = [{"min": [-1.5, -1.5, -0.1], "max": [1.5, 1.5, -0.02]}]
    tasks = [{"type": "reach"}, {"type": "self_collision"}, {"type": "obstacles", "boxes": boxes}]
    params = {**body_params({"urdf": str(URDF / "ur5.urdf")}, "ee_link", ["*_joint"], tasks), "seed": 0}
    rng = np.random.default_rng(5)
    goals = np.column_stack([rng.uniform(-0.35, 0.35, (2, 40)).T, rng.uniform(0.0, 0.12, 40)])
    without = OracleSpec("casadi-ik", {**params, "blocked_starts": 0}).create()
    rescued = OracleSpec("casadi-ik", params).create()
    a, b = without.evaluate(goals), rescued.evaluate(goals)
    assert rescued.stats["polished"] > without.stats["polished"]  # the rescues ran
    assert np.all(b.reachable[a.reachable]) and b.reachable.sum() > a.reachable.sum() >= 10  # 34 against 32 here
    for i in np.nonzero(b.reachable)[0]:
        assert independent_check(rescued, b.posture[i], goals[i]) == [], i


def test_an_srdf_leaves_its_disabled_link_pairs_out_of_self_collision(tmp_path):
    """body.srdf (MoveIt's convention): the pairs of links its disable_collisions elements name are left out of the
    self_collision task, and no others; given relative to the config, it is found beside it; a link the URDF lacks,
    malformed XML and a folder are errors naming the key."""
    import shutil

    srdf = tmp_path / "ur5.srdf"
    srdf.write_text("""<?xml version="1.0"?><robot name="ur5">
      <disable_collisions link1="base_link" link2="upper_arm_link" reason="Never"/>
      <disable_collisions link1="forearm_link" link2="wrist_2_link" reason="Never"/></robot>""")
    shutil.copy(URDF / "ur5.urdf", tmp_path / "ur5.urdf")
    tasks = [{"type": "reach"}, {"type": "self_collision"}]
    config = {"name": "srdf", "body": {"urdf": "ur5.urdf"}, "box": {"min": [-1, -1, -1], "max": [1, 1, 1]},
              "depth": {"min": 1, "max": 2},
              "strategies": [{"name": "s", "effector": "ee_link", "joints": ["*_joint"], "tasks": tasks}]}
    (tmp_path / "plain.yaml").write_text(yaml.safe_dump(config))
    config["body"]["srdf"] = "ur5.srdf"
    (tmp_path / "srdf.yaml").write_text(yaml.safe_dump(config))

    def pairs(path: Path) -> set[frozenset[str]]:
        oracle = load_config(path).strategy("s").oracle.create()
        placed = oracle.body.collision.placed  # type: ignore[attr-defined]
        return {frozenset((placed[p.first].capsule.link, placed[p.second].capsule.link))
                for p in oracle.strategy.task("self_collision").pairs}  # type: ignore[attr-defined]

    plain, guarded = pairs(tmp_path / "plain.yaml"), pairs(tmp_path / "srdf.yaml")
    disabled = {frozenset(("base_link", "upper_arm_link")), frozenset(("forearm_link", "wrist_2_link"))}
    assert disabled <= plain and plain - guarded == disabled
    body = load_body({"urdf": str(tmp_path / "ur5.urdf"), "srdf": str(srdf)})
    assert body.disabled == disabled and body.spec["srdf"] == str(srdf)
    for text, match in (('<robot><disable_collisions link1="base_link" link2="gripper"/></robot>',
                         "names link 'gripper', which the URDF does not have"),
                        ("<robot><disable_collisions", "not an SRDF")):
        srdf.write_text(text)
        with pytest.raises(ModelError, match=match) as err:
            load_body({"urdf": str(tmp_path / "ur5.urdf"), "srdf": str(srdf)})
        assert err.value.key == "srdf"
    with pytest.raises(ModelError, match="not a regular file"):
        load_body({"urdf": str(tmp_path / "ur5.urdf"), "srdf": str(tmp_path)})
    with pytest.raises(ModelError, match="the path of the robot's SRDF"):
        load_body({"urdf": str(tmp_path / "ur5.urdf"), "srdf": 3})
