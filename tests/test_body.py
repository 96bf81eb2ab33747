"""Bodies: the generated human against anthropometric truth, URDF loading and errors."""

from __future__ import annotations

import csv
import gzip
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from oracles.bodies import ansur
from oracles.bodies.anthropometry import ANSUR_STATURE, DE_LEVA, stature_at_percentile
from oracles.bodies.body import human_body, load_body, urdf_body
from reach.errors import ModelError
from reach.tools.cli import main

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ansur2"


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


CARRIED = HERE.parent / "oracles" / "bodies" / "data" / "ansur2.csv.gz"


def _ansur_rows(sex):
    """The subjects of the public ANSUR II file itself (../shared/data/ansur2), read with csv alone: an independent
    reading of what the project carries. Where the public files are not beside the repository, the carried file
    (oracles/bodies/data/ansur2.csv.gz, the public files' columns the bodies use), read with gzip and csv alone."""
    name = {"male": ("ANSUR_II_MALE_Public.csv", "subjectid"), "female": ("ANSUR_II_FEMALE_Public.csv", "SubjectId")}
    path = SHARED / name[sex][0]
    if path.exists():
        with open(path, encoding="latin-1", newline="") as fh:
            return {int(r[name[sex][1]]): r for r in csv.DictReader(fh)}
    with gzip.open(CARRIED, "rt", encoding="utf-8", newline="") as fh:
        return {int(r["subject"]): r for r in csv.DictReader(fh) if r["sex"] == sex}


def _thumbtip(body):
    """Thumb-tip reach as ANSUR measures it: the arm forward at shoulder height, from the wall behind the shoulders
    (the ``back`` frame) to the thumb tip (``right_pinch``) [m], by Pinocchio's forward kinematics."""
    f = body.frame_positions(_set(body, right_shoulder_flexion=np.pi / 2), ["right_pinch", "back", "right_shoulder"])
    assert abs(f["right_pinch"][2] - f["right_shoulder"][2]) < 0.03  # at shoulder height
    return f["right_pinch"][0] - f["back"][0]


@pytest.mark.parametrize("sex", ["male", "female"])
def test_a_surveyed_persons_body_has_their_measures(sex):
    """A body built from an ANSUR II subject reproduces the subject's own measures, read from the survey's
    file by csv and checked on the model by Pinocchio's forward kinematics."""
    rows = _ansur_rows(sex)
    for subject in sorted(rows)[::400]:
        raw = {k: float(v) / 1000.0 for k, v in rows[subject].items() if k.islower() and k != "subjectid"
               and v.replace(".", "", 1).isdigit()}
        body = human_body(ansur={"sex": sex, "subject": subject})
        f = body.frame_positions()
        assert f["vertex"][2] == pytest.approx(raw["stature"], abs=1e-6)
        assert f["right_acromion"][2] == pytest.approx(raw["acromialheight"], abs=1e-6)
        assert _thumbtip(body) == pytest.approx(raw["thumbtipreach"], abs=2e-3)
        assert f["right_heel"][2] == pytest.approx(0.0, abs=1e-8)
        grip = raw["handlength"] - (raw["forearmhandlength"] - raw["forearmcenterofgriplength"])
        data = body.model.createData()
        pin.forwardKinematics(body.model, data, body.q_ref)
        wrist = data.oMi[body.joint_id("right_wrist_flexion")].translation
        assert abs(f["right_grip"][2] - wrist[2]) == pytest.approx(grip, abs=1e-6)
        assert abs(f["right_fingertip"][2] - wrist[2]) == pytest.approx(raw["handlength"], abs=1e-6)
        assert body.mass == pytest.approx(raw["weightkg"] * 100.0, rel=1e-6)
        # The landmarks where the survey puts them: the acromions' tips a biacromial breadth apart; with the elbow
        # flexed 90 deg, its underside (elbow_rest) a shoulder-elbow length below the acromion.
        assert f["left_acromion"][1] - f["right_acromion"][1] == pytest.approx(raw["biacromialbreadth"], abs=1e-6)
        bent = body.frame_positions(_set(body, right_elbow_flexion=np.pi / 2), ["right_acromion", "right_elbow_rest"])
        assert bent["right_acromion"][2] - bent["right_elbow_rest"][2] == pytest.approx(raw["shoulderelbowlength"],
                                                                                        abs=1e-6)
        # Sitting height: the vertex over a hard seat, the hips where the subject's sitting height puts them.
        place = body.anthropometry.place
        assert f["vertex"][2] - body.q_ref[2] + place.hip_above_seat == pytest.approx(raw["sittingheight"], abs=1e-6)


@pytest.mark.parametrize("sex", ["male", "female"])
def test_the_seated_measures_read_back_the_record_the_body_was_built_from(sex):
    """The measuring postures of the dimensions nobody gave a body (bench/validation.py's per-subject table) read the
    given ones back: knee height sitting, taken like popliteal height and the thigh clearance (hips and knees at 90
    deg, the sole under the heel frame), is the subject's own."""
    from oracles.bodies.measure import measure

    rows = _ansur_rows(sex)
    for subject in sorted(rows)[::500]:
        m = measure(human_body(ansur={"sex": sex, "subject": subject}))
        assert m["kneeheightsitting"] == pytest.approx(float(rows[subject]["kneeheightsitting"]) / 1000.0, abs=1e-6)
        assert m["lateralmalleolusheight"] < m["poplitealheight"] < m["kneeheightsitting"]
        assert m["elbowrestheight"] < m["sittingheight"] and m["shoulderelbowlength"] > m["acromionradialelength"]


@pytest.mark.parametrize("sex", ["male", "female"])
def test_the_carried_survey_is_the_file_its_readme_quotes(sex):
    """The carried file, read with gzip, hashlib and csv alone, is the one its README's digest names (which
    ``bench/ansur_extract.py --check`` compares, row by row, with the public files: CI runs it), and the survey module
    reads every subject of it, each value at its scale."""
    with gzip.open(CARRIED, "rb") as gz:
        raw = gz.read()
    quoted = re.search(r"sha256 is ([0-9a-f]{64})", (CARRIED.parent / "README.md").read_text()).group(1)
    assert hashlib.sha256(raw).hexdigest() == quoted
    rows = _ansur_rows(sex)
    carried = ansur.sample(sex)
    assert len(carried.ids) == len(rows) == {"male": 4082, "female": 1986}[sex]
    for i in (0, len(rows) // 2, len(rows) - 1):
        row = rows[int(carried.ids[i])]
        for name in ansur.COLUMNS:
            scale = 10.0 if name == ansur.MASS else 1000.0
            assert carried.values[i, ansur.COLUMNS.index(name)] == pytest.approx(float(row[name]) / scale, rel=1e-12)


def test_unknown_dimensions_are_regressed_on_the_given_ones_by_least_squares():
    """The conditional mean of a multivariate normal is the least-squares regression: checked against numpy's
    lstsq on the carried sample."""
    s = ansur.sample("female")
    given = {"stature": 1.60, "acromionradialelength": 0.30, "handlength": 0.175}
    values, sd = s.predict(given)
    x = np.column_stack([np.ones(len(s.ids))] + [s.column(k) for k in given])
    for name in ("thumbtipreach", "buttockkneelength", "sittingheight"):
        coef, res, *_ = np.linalg.lstsq(x, s.column(name), rcond=None)
        assert values[name] == pytest.approx(coef @ [1.0, *given.values()], abs=1e-9)
        assert sd[name] == pytest.approx(np.sqrt(res[0] / (len(s.ids) - 1)), rel=2e-3)
    assert values["stature"] == 1.60 and sd["stature"] == 0.0


def test_a_percentile_body_has_the_mean_proportions_at_its_stature():
    """A stature percentile is not a reach percentile: the 5th-percentile-stature woman's thumb-tip reach is the
    regression's at her stature (her 13th percentile or so of reach), not the 5th."""
    body = human_body("female", percentile=5)
    s = ansur.sample("female")
    values, _ = s.predict({"stature": stature_at_percentile("female", 5)})
    assert _thumbtip(body) == pytest.approx(values["thumbtipreach"], abs=2e-3)
    share = float(np.mean(s.column("thumbtipreach") < _thumbtip(body)))
    assert 0.08 < share < 0.2


def test_measured_dimensions_and_their_errors_name_the_key():
    body = load_body({"human": {"sex": "male", "stature": 1.80, "acromionradialelength": 0.36, "mass": 80}})
    assert body.mass == pytest.approx(80.0, rel=1e-9)
    a = body.anthropometry
    assert a.asked == {"stature": 1.80, "acromionradialelength": 0.36, "weightkg": 80.0}
    assert a.dims["acromionradialelength"] == 0.36 and a.spread["acromionradialelength"] == 0.0
    with pytest.raises(ModelError, match=r"human\.acromionradialelength: expected m near ANSUR II"):
        load_body({"human": {"sex": "male", "acromionradialelength": 360}})  # millimetres
    with pytest.raises(ModelError, match=r"human\.armlength: unknown key"):
        load_body({"human": {"sex": "male", "armlength": 0.6}})
    with pytest.raises(ModelError, match=r"human\.ansur\.subject: no female subject 1"):
        load_body({"human": {"ansur": {"sex": "female", "subject": 1}}})
    with pytest.raises(ModelError, match=r"human\.ansur\.sex"):
        load_body({"human": {"sex": "male", "ansur": {"sex": "female", "subject": 10037}}})


def test_de_leva_bodies_scale_stature_and_keep_their_urdf():
    body = human_body("male", stature=1.80, mass=80.0, proportions="de_leva")
    assert body.mass == pytest.approx(80.0, rel=1e-9)
    a = body.anthropometry
    for seg in ("upper_arm", "forearm", "hand", "thigh", "shank", "foot"):
        assert a.masses[seg] / 80.0 == pytest.approx(DE_LEVA["male"][seg][1] / 100.0, rel=1e-3)
    # The arm scales isometrically with stature from de Leva's 1741 mm subject.
    assert a.lengths["upper_arm"] == pytest.approx(0.2817 * 1.80 / 1.741, rel=1e-9)
    # The hash of the 50th-percentile man of the versions before ANSUR II bodies (its trees still refine).
    assert human_body("male", percentile=50, proportions="de_leva").hash == "82741ba5fad6f3e4"
    assert "right_grip" not in human_body("male", proportions="de_leva").frame_positions()


def test_default_mass_is_ansur_mean(man, woman):
    assert man.mass == pytest.approx(85.5, abs=0.1) and woman.mass == pytest.approx(67.8, abs=0.1)


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
    assert f["eyes"][2] == pytest.approx(man.anthropometry.place.eye_height)
    assert 0.92 * H < f["eyes"][2] < 0.95 * H  # Drillis & Contini: 0.936 H
    assert f["right_hand"][2] < f["right_shoulder"][2] - 0.5  # arms hanging


def test_proportions_and_centre_of_mass(man, woman):
    for body in (man, woman):
        H = body.anthropometry.stature
        com = body.center_of_mass()
        assert 0.53 * H < com[2] < 0.59 * H  # about 55-57 % of stature in standing adults
        assert abs(com[1]) < 1e-12
        f = body.frame_positions()
        shoulder_width = f["left_shoulder"][1] - f["right_shoulder"][1]
        # Shoulder centres from span and the arm (oracles.bodies.anthropometry): inside the acromions' tips.
        assert 0.16 * H < shoulder_width < body.anthropometry.dims["biacromialbreadth"]
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
    # a negative mass and a zero joint axis were accepted.
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
    # these gave tracebacks (or read for ever).
    with pytest.raises(ModelError, match=r"/dev/zero: not a regular file"):
        urdf_body("/dev/zero")
    latin = tmp_path / "latin.urdf"
    latin.write_bytes("<robot name='caf\xe9'/>".encode("latin-1"))
    with pytest.raises(ModelError, match=r"latin\.urdf: not UTF-8 text"):
        urdf_body(latin)
    # A document type declaration's entities could name local files: refused before any parser sees them.
    entity = tmp_path / "entity.urdf"
    entity.write_text('<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY host SYSTEM "file:///etc/hostname">]>\n'
                      "<robot name='x'><link name='&host;'/></robot>")
    with pytest.raises(ModelError, match=r"entity\.urdf: a document type declaration .* refused, never resolved"):
        urdf_body(entity)
    # A body's mass within half the survey's smallest and 1.5 times its span: 0 or negative masses built bodies whose
    # centre of mass was NaN.
    for mass in (0.0, -5.0, 19.0):
        with pytest.raises(ModelError, match=r"human\.mass: expected kg near ANSUR II's male range"):
            human_body("male", mass=mass)
    assert human_body("male", mass=25.0).mass == pytest.approx(25.0)
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


@pytest.mark.slow
def test_every_survey_body_stands_above_the_floor():
    """No capsule of any of ANSUR II's 6,068 subjects below the floor in the standing reference
    (the shank's lower sphere sank up to 6.2 mm under it in 37). Each body's URDF is parsed by Pinocchio here, its
    capsules placed by forward kinematics at the standing posture (every joint at 0, the root at the hips' height),
    apart from load_body's own reference posture."""
    from oracles.bodies.anthropometry import anthropometry
    from oracles.bodies.human import human_capsules, human_urdf, root_height

    lowest = []
    for sex in ("male", "female"):
        for subject in ansur.sample(sex).ids:
            body = anthropometry(sex, subject=int(subject))
            model = pin.buildModelFromXML(human_urdf(body), pin.JointModelFreeFlyer())
            data = model.createData()
            q = pin.neutral(model)
            q[2] = root_height(body)
            pin.framesForwardKinematics(model, data, q)
            low = min(min(data.oMf[model.getFrameId(c.link)].act(np.asarray(e, float))[2] for e in (c.a, c.b))
                      - c.radius for c in human_capsules(body))
            lowest.append((low, sex, int(subject)))
    assert len(lowest) == 6068
    worst = min(lowest)
    assert worst[0] >= -1e-9, worst  # (the soles lie on the floor itself)


@pytest.mark.slow
def test_every_survey_body_sits_on_the_seat():
    """Seated on the office chair, every one of ANSUR II's 6,068 subjects rests its thighs on the pan (the lowest point
    of each thigh capsule over the pan within 5 mm of its top; 31 of 50 floated more, up to 52 mm) and no capsule
    lies deeper in any part of the seat than the soft tissue a hard seat compresses (SEAT_SINK) and a millimetre.
    Capsules placed by this test's own forward kinematics of each body's model at its reference posture, their
    distance to the seat's boxes by coal."""
    import coal

    from oracles.bodies.human import SEAT_SINK

    thigh_gaps, deepest = [], []
    for sex in ("male", "female"):
        for subject in ansur.sample(sex).ids:
            body = load_body({"human": {"ansur": {"sex": sex, "subject": int(subject)}, "posture": "seated"}})
            model, data = body.model, body.model.createData()
            pin.framesForwardKinematics(model, data, body.q_ref)
            pan = next(b for b in body.furniture if b.name == "seat_pan")
            top, depth = pan.centre[2] + pan.half[2], pan.centre[0] + pan.half[0]
            boxes = [(coal.Box(*(2 * b.half)), coal.Transform3s(b.matrix, b.centre)) for b in body.furniture]
            inside = 0.0
            for c in body.capsules:
                frame = data.oMf[model.getFrameId(c.link)]
                a, b = frame.act(np.asarray(c.a, float)), frame.act(np.asarray(c.b, float))
                axis = b - a
                length = float(np.linalg.norm(axis))
                z = axis / length if length > 1e-12 else np.array([0.0, 0.0, 1.0])
                x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
                x /= np.linalg.norm(x)
                shape = coal.Capsule(c.radius, length) if length > 1e-12 else coal.Sphere(c.radius)
                place = coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), 0.5 * (a + b))
                for box, at in boxes:
                    gap = coal.distance(shape, place, box, at, coal.DistanceRequest(), coal.DistanceResult())
                    inside = min(inside, gap)
                if c.name.endswith("_thigh"):
                    p = a + np.linspace(0.0, 1.0, 201)[:, None] * axis
                    over = (p[:, 0] >= 0.0) & (p[:, 0] <= depth)
                    thigh_gaps.append((float(p[over, 2].min() - c.radius - top), sex, int(subject)))
            deepest.append((inside, sex, int(subject)))
    assert len(deepest) == 6068
    assert max(thigh_gaps)[0] <= 0.005, max(thigh_gaps)
    assert min(thigh_gaps)[0] >= -SEAT_SINK - 1e-3, min(thigh_gaps)
    assert min(deepest)[0] >= -SEAT_SINK - 1e-3, min(deepest)
