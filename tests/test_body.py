"""Bodies: the generated human against anthropometric truth, URDF loading and errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from oracles.bodies.anthropometry import ANSUR_STATURE, ANSUR_THUMBTIP_REACH, DE_LEVA, stature_at_percentile
from oracles.bodies.body import human_body, load_body, urdf_body
from reach.errors import ModelError
from reach.tools.cli import main

HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def man():
    return human_body("male")


@pytest.fixture(scope="module")
def woman():
    return human_body("female")


def _set(body, **angles):
    q = body.q_ref.copy()
    for name, value in angles.items():
        q[body.model.joints[body.joint_id(name)].idx_q] = value
    return q


@pytest.mark.parametrize("sex", ["male", "female"])
def test_thumbtip_reach_is_within_one_sd_of_ansur(sex):
    # Arm stretched forward at shoulder height (flexion 90 deg); horizontal
    # distance from a wall touching the back of the shoulders to the grip centre.
    body = human_body(sex)
    frames = body.frame_positions(_set(body, right_shoulder_flexion=np.pi / 2),
                                  ["right_hand", "back", "right_shoulder"])
    reach_mm = 1000 * (frames["right_hand"][0] - frames["back"][0])
    mean, sd = ANSUR_THUMBTIP_REACH[sex]
    assert abs(reach_mm - mean) <= sd
    assert abs(frames["right_hand"][2] - frames["right_shoulder"][2]) < 0.05  # at shoulder height


def test_mass_is_the_requested_one_and_segments_follow_de_leva():
    body = human_body("male", stature=1.80, mass=80.0)
    assert body.mass == pytest.approx(80.0, rel=1e-9)
    a = body.anthropometry
    for seg in ("upper_arm", "forearm", "hand", "thigh", "shank", "foot"):
        assert a.masses[seg] / 80.0 == pytest.approx(DE_LEVA["male"][seg][1] / 100.0, rel=1e-3)
    # The arm scales isometrically with stature from de Leva's 1741 mm subject.
    assert a.lengths["upper_arm"] == pytest.approx(0.2817 * 1.80 / 1.741, rel=1e-9)


def test_default_mass_is_ansur_mean(man, woman):
    assert man.mass == pytest.approx(85.5) and woman.mass == pytest.approx(67.8)


def test_stature_percentiles_follow_ansur():
    assert stature_at_percentile("male", 50) == pytest.approx(ANSUR_STATURE["male"][0] / 1000)
    assert stature_at_percentile("female", 5) < stature_at_percentile("female", 50) < stature_at_percentile("female",
        95)
    assert stature_at_percentile("male", 95) == pytest.approx((1756.3 + 1.6449 * 68.6) / 1000, abs=1e-4)


def test_world_frame_soles_on_floor_and_mirror_symmetry(man):
    f = man.frame_positions()
    H = man.anthropometry.stature
    for side in ("right", "left"):
        for part in ("foot", "heel", "toe", "heel_inner", "ball_outer", "toe_inner"):
            assert f[f"{side}_{part}"][2] == pytest.approx(0.0, abs=1e-8)  # the URDF holds 9 decimals
        assert f[f"{side}_foot"][0] > f[f"{side}_heel"][0]  # x forward
    assert f["left_hand"][1] > 0 > f["right_hand"][1]  # y to the left
    for name, pos in f.items():
        if name.startswith("left_"):
            mirror = f["right_" + name[5:]]
            assert np.allclose(pos, mirror * [1, -1, 1], atol=1e-8), name
    assert f["eyes"][2] == pytest.approx(0.936 * H)
    assert f["right_hand"][2] < f["right_shoulder"][2] - 0.5  # arms hanging


def test_proportions_and_centre_of_mass(man, woman):
    for body in (man, woman):
        H = body.anthropometry.stature
        com = body.center_of_mass()
        assert 0.53 * H < com[2] < 0.59 * H  # about 55-57 % of stature in standing adults
        assert abs(com[1]) < 1e-12
        f = body.frame_positions()
        shoulder_width = f["left_shoulder"][1] - f["right_shoulder"][1]
        assert 0.18 * H < shoulder_width < 0.24 * H
        hip = body.q_ref[2]
        assert 0.50 * H < hip < 0.56 * H  # hip joint height, Drillis & Contini 0.530 H


def test_joints_and_ranges_are_anatomical(man):
    names = man.joint_names
    for j in ("lumbar_flexion", "lumbar_lateral", "thoracic_rotation", "neck_flexion", "neck_rotation",
              "right_clavicle_elevation", "right_clavicle_protraction", "right_shoulder_flexion",
              "right_shoulder_abduction", "right_shoulder_rotation", "right_elbow_flexion", "right_forearm_pronation",
              "right_wrist_flexion", "right_wrist_deviation", "left_hip_flexion", "left_hip_abduction",
              "left_hip_rotation", "left_knee_flexion", "left_ankle_flexion", "left_ankle_inversion"):
        assert j in names
    limits = {n: (lo, hi) for n, lo, hi in man.limits()}
    assert limits["right_elbow_flexion"] == pytest.approx((0.0, np.radians(150)))
    # Flexing the elbow brings the hand forward: the sign convention is anatomical.
    hand = man.frame_positions(_set(man, right_elbow_flexion=np.pi / 2), ["right_hand"])["right_hand"]
    assert hand[0] > 0.2


def test_range_overrides_scale_or_replace(man):
    body = human_body("male", ranges={"right_elbow_*": {"scale": 0.5}, "left_knee_flexion": [0.0, 1.0]})
    limits = {n: (lo, hi) for n, lo, hi in body.limits()}
    assert limits["right_elbow_flexion"][1] == pytest.approx(np.radians(75))
    assert limits["left_knee_flexion"] == (0.0, 1.0)
    assert body.hash != man.hash


def test_range_override_errors_name_the_joint():
    with pytest.raises(ModelError, match=r"ranges.right_tail: no joint matches"):
        human_body(ranges={"right_tail": [0, 1]})
    with pytest.raises(ModelError, match=r"ranges\.right_elbow_flexion: expected \[lower, upper\]"):
        human_body(ranges={"right_elbow_flexion": {"scale": 3}})


def test_a_urdf_we_did_not_generate_loads_with_a_floating_root():
    body = urdf_body(HERE.parent / "configs" / "urdf" / "ur5.urdf")
    assert body.joint_names[:2] == ["shoulder_pan_joint", "shoulder_lift_joint"]
    assert body.mass == pytest.approx(4.0 + 3.7 + 8.393 + 2.275 + 1.219 * 2 + 0.1879)  # root link included
    assert body.model.names[1] == "root"
    tip = body.frame_positions(names=["ee_link"])["ee_link"]
    # UR5 zero pose, worked out by hand from the joint origins: the arm
    # stretched along x, the wrist offsets along y and down.
    assert tip == pytest.approx([0.425 + 0.39225, 0.13585 - 0.1197 + 0.093 + 0.0823, 0.089159 - 0.09465], abs=1e-6)


def test_malformed_urdf_and_unknown_names_are_named(tmp_path, man):
    bad = tmp_path / "broken.urdf"
    bad.write_text("<robot name='x'><link name='a'><joint></robot>")
    with pytest.raises(ModelError, match=r"broken\.urdf: not a valid URDF"):
        urdf_body(bad)
    with pytest.raises(ModelError, match=r"cannot read URDF"):
        urdf_body(tmp_path / "absent.urdf")
    # Issue 35: a negative mass and a zero joint axis were accepted.
    for fault, message in (("<mass value='-2'/>", r"link 'a': mass '-2'; expected a finite number >= 0"),):
        bad.write_text(f"<robot name='x'><link name='a'><inertial>{fault}<inertia ixx='1' iyy='1' izz='1' ixy='0' "
                       "ixz='0' iyz='0'/>"
                       "</inertial></link></robot>")
        with pytest.raises(ModelError, match=message):
            urdf_body(bad)
    bad.write_text("<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='revolute'><parent "
                   "link='a'/><child link='b'/><axis xyz='0 0 0'/><limit lower='-1' upper='1' effort='1' "
                   "velocity='1'/></joint></robot>")
    with pytest.raises(ModelError, match=r"joint 'j': axis '0 0 0'; expected three finite numbers, not all zero"):
        urdf_body(bad)
    # Issue 35: these gave tracebacks (or read for ever).
    with pytest.raises(ModelError, match=r"/dev/zero: not a regular file"):
        urdf_body("/dev/zero")
    latin = tmp_path / "latin.urdf"
    latin.write_bytes("<robot name='caf\xe9'/>".encode("latin-1"))
    with pytest.raises(ModelError, match=r"latin\.urdf: not UTF-8 text"):
        urdf_body(latin)
    with pytest.raises(ModelError, match=r"human: no frame 'right_paw'; frames are: .*right_hand"):
        man.frame_id("right_paw")
    with pytest.raises(ModelError, match=r"human: no joint 'tail'"):
        man.joint_id("tail")
    with pytest.raises(ModelError, match="exactly one of 'human' or 'urdf'"):
        load_body({})
    with pytest.raises(ModelError, match="percentile must be in"):
        load_body({"human": {"percentile": 120}})


def test_reach_model_json(capsys):
    assert main(["model", "human", "--sex", "female", "--percentile", "5", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["stature"] == pytest.approx(stature_at_percentile("female", 5))
    assert {"name", "lower", "upper"} == set(info["joints"][0])
    assert set(info["frames"]) >= {"right_hand", "left_hand", "right_foot", "eyes", "right_shoulder"}
    assert info["mass"] > 40
    assert main(["model", str(HERE.parent / "configs" / "urdf" / "ur5.urdf"), "--json"]) == 0
    assert "ee_link" in json.loads(capsys.readouterr().out)["frames"]


def test_reach_model_lists_the_capsules_and_each_strategys_pairs(capsys):
    assert main(["model", str(HERE.parent / "configs" / "demo.yaml"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert len(info["capsules"]) == 17 and {"name", "link", "radius", "length", "a", "b"} == set(info["capsules"][0])
    arm = next(t for t in info["strategies"]["right_arm"]["tasks"] if t["type"] == "self_collision")
    assert ["right_hand", "thorax"] in [sorted(p) for p in arm["pairs"]]
    assert any(c["pair"] == ["right_hand", "right_thigh"] for c in arm["at_reference"])
    assert main(["model", str(HERE.parent / "configs" / "demo.yaml")]) == 0
    text = capsys.readouterr().out
    assert "17 collision capsules" in text and "right_arm: 42 pairs checked" in text
    # The coupled limits each strategy applies (the arm: the shoulder's rule alone).
    coupling = next(t for t in info["strategies"]["right_arm"]["tasks"] if t["type"] == "coupling")
    assert coupling["rules"] == [{"joints": ["right_shoulder_abduction"], "by": "right_shoulder_flexion",
                                  "limit": pytest.approx(np.pi), "slope": 2.0}]
    coupled = "right_arm: coupled limits [rad]: right_shoulder_abduction <= 3.1416 + 2.0000 x right_shoulder_flexion"
    assert coupled in text


def test_a_urdf_joint_with_lower_above_upper_is_named(tmp_path):
    from pathlib import Path

    from oracles.bodies.body import urdf_body
    from reach.errors import ModelError

    text = (Path(__file__).parent / "data" / "all_joints.urdf").read_text()
    bad = tmp_path / "bad.urdf"
    bad.write_text(text.replace('<axis xyz="0 0 1"/><limit lower="-2" upper="2"', '<axis xyz="0 0 1"/><limit '
        'lower="2" upper="-2"', 1))
    with pytest.raises(ModelError, match=r"bad\.urdf: joint 'revolute_z' has limits lower 2\.0 > upper -2\.0; "
                                         r"expected lower <= upper") as err:
        urdf_body(bad)
    assert err.value.name == "revolute_z"
