"""Seated bodies: the seat's geometry and reference posture, postures that never pass through the seat (coal),
the buttocks held on the pan, a locked belt, and the seated arm's volume as the standing arm's moved with the
shoulder."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM, browser_only, free_port

from oracles.bodies.body import load_body
from oracles.bodies.environment import parse_box
from oracles.errors import ModelError, TaskError
from oracles.ik.oracle import IKOracle
from oracles.ik.search import Search
from oracles.tasks.reach import TOLERANCE
from reach.answers.select import Selector

TRUNK = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "neck_*", "root", "*_hip_*", "*_knee_*", "*_ankle_*"]
SUPPORT = ["right_ischium", "left_ischium", "right_thigh_rest", "left_thigh_rest", "right_heel_inner",
           "right_heel_outer", "right_toe_inner",
           "right_toe_outer", "left_heel_inner", "left_heel_outer", "left_toe_inner", "left_toe_outer"]
LEAN = [{"type": "reach"},
        {"type": "contacts", "hinge": ["right_ischium", "left_ischium"], "fixed": ["right_foot", "left_foot"],
         "support": SUPPORT},
        {"type": "balance", "margin": 0.02}, {"type": "self_collision"}, {"type": "obstacles"}, {"type": "floor"},
        {"type": "coupling"}]
ANCHOR = [-0.25, 0.30, 0.85]
BELTED = [{"type": "reach"},
          {"type": "contacts", "fixed": ["right_ischium", "left_ischium", "right_foot", "left_foot"],
           "support": SUPPORT},
          {"type": "tether", "anchor": ANCHOR, "frames": ["sternum", "left_shoulder"], "slack": 0.02},
          {"type": "balance", "margin": 0.02}, {"type": "self_collision"}, {"type": "obstacles"}, {"type": "floor"},
          {"type": "coupling"}]


def seated(kind: str = "chair", sex: str = "male", percentile: float = 50, **seat) -> dict:
    return {"human": {"sex": sex, "percentile": percentile, "posture": "seated", "seat": {"kind": kind, **seat}}}


def _coal_gap(capsule: np.ndarray, box) -> float:
    """Coal's distance [m] between a world capsule (a, b, r) and a box, built here from the end points."""
    a, b, r = capsule[:3], capsule[3:6], float(capsule[6])
    axis = b - a
    n = float(np.linalg.norm(axis))
    z = axis / n if n > 1e-12 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    rot = np.column_stack([x, np.cross(z, x), z])
    return float(coal.distance(coal.Capsule(r, n), coal.Transform3s(rot, 0.5 * (a + b)), coal.Box(*(2 * box.half)),
                               coal.Transform3s(box.matrix, box.centre), coal.DistanceRequest(), coal.DistanceResult()))


@pytest.mark.parametrize("kind,sex,percentile",
                         [("chair", "female", 5), ("chair", "male", 95), ("wheelchair", "male", 50),
                          ("car", "female", 5)])
def test_the_seated_reference_rests_on_the_pan_against_the_backrest(kind, sex, percentile):
    """Coal: no capsule passes into the seat; the lowest of the pelvis's and thighs' capsules touches the pan, the trunk
    the backrest; the soles lie on their rest; the ischia lie on the pan."""
    body = load_body(seated(kind, sex, percentile))
    caps = body.capsules_at()
    names = [p.name for p in body.collision.placed]
    boxes = {b.name: b for b in body.furniture}
    gaps = {(n, b): _coal_gap(c, boxes[b]) for n, c in zip(names, caps, strict=True) for b in boxes}
    assert min(gaps.values()) > -0.005
    # The hips sit where the body's sitting height puts them over a hard seat (ANSUR II), or higher where the reclined
    # pelvis's capsule lifts them; the lowest capsule then rests on the pan, sunk by at most the soft tissue's 4 mm.
    place = body.anthropometry.place
    pan_top = boxes["seat_pan"].hi[2]
    assert body.q_ref[2] - pan_top >= place.hip_above_seat - 1e-9
    lowest = min(gaps[(n, "seat_pan")] for n in ("pelvis", "right_thigh", "left_thigh"))
    assert -0.0045 < lowest < 0.02
    if body.q_ref[2] - pan_top > place.hip_above_seat + 1e-6:
        assert lowest == pytest.approx(-0.004, abs=1e-3)
    assert min(gaps[(n, "backrest")] for n in ("pelvis", "abdomen", "thorax")) == pytest.approx(0.0, abs=0.003)
    frames = body.frame_positions()
    assert (frames["right_ischium"][2] == pytest.approx(pan_top, abs=1e-6)
            and frames["left_ischium"][2] == pytest.approx(pan_top, abs=1e-6))
    sole = 0.0 if kind != "wheelchair" else boxes["footrest"].hi[2]
    assert frames["right_heel"][2] == pytest.approx(sole, abs=1e-6)
    if kind != "car":  # the car's feet rest on the heel point, toes up on the pedal
        assert frames["right_toe"][2] == pytest.approx(sole, abs=1e-6)


def test_our_turned_box_distance_agrees_with_coal():
    """Box.outside (the obstacles task's cuts) against coal's distance of a small sphere to the turned box."""
    box = parse_box({"min": [0.0, -0.2, 0.3], "max": [0.05, 0.2, 0.9], "rpy": [0.1, -0.4, 0.3]}, "box")
    rng = np.random.default_rng(3)
    for p in box.centre + rng.uniform(-0.5, 0.5, (200, 3)):
        ours, _ = box.outside(p)
        theirs = coal.distance(coal.Sphere(1e-9), coal.Transform3s(np.eye(3), p), coal.Box(*(2 * box.half)),
                               coal.Transform3s(box.matrix, box.centre), coal.DistanceRequest(), coal.DistanceResult())
        if ours > 0:
            assert ours == pytest.approx(theirs, abs=1e-6)
        else:
            assert theirs <= 1e-6


@pytest.mark.parametrize("spec,key,says", [
    (seated(height=0.9), "human.seat.height", "above this body's lower leg"),
    (seated("car", feet={"x": 1.4}), "human.seat.feet.x", "out of this body's reach"),
    (seated(kind="sofa"), "human.seat.kind", "chair, wheelchair, car"),
    (seated(back_angle=70), "human.seat.back_angle", r"\[0.0, 40.0\] deg"),
    ({"human": {"seat": {"kind": "chair"}}}, "human.seat", "posture: seated"),
    ({"human": {"posture": "kneeling"}}, "human.posture", "standing or seated"),
    (seated(depth=0.75), "human.seat", "passes .* into the seat's seat_pan"),
])
def test_seats_that_do_not_fit_are_named(spec, key, says):
    with pytest.raises(ModelError, match=rf"{key}.*{says}"):
        load_body(spec)


def test_the_seat_is_part_of_the_bodys_identity():
    """Another seat, another body: atlases built on one are not served for the other."""
    assert load_body(seated(back_angle=10)).hash != load_body(seated(back_angle=20)).hash
    assert load_body(seated()).hash != load_body({"human": {"sex": "male", "percentile": 50}}).hash


@pytest.fixture(scope="module")
def lean():
    return IKOracle(seated(), "right_hand", TRUNK, LEAN, search=Search(restarts=3, seed=0))


GOALS = np.array([[0.75, -0.2, 0.95], [0.6, -0.45, 0.45], [0.45, -0.35, 0.15], [0.9, -0.1, 0.7], [0.3, 0.25, 0.9],
                  [0.55, -0.2, 0.5]])


def test_lean_postures_never_pass_through_the_seat_and_keep_the_buttocks_on_it(lean):
    """Every reachable verdict: the hand on the goal (Pinocchio FK), no capsule into the seat (coal, margin given to the
    reference's contacts), the ischia where they sat, the centre of mass over the seated support."""
    v = lean.evaluate(GOALS)
    assert v.reachable.sum() >= 4
    body = lean.body
    boxes = body.furniture
    ref = body.frame_positions()
    for goal, ok, q in zip(GOALS, v.reachable, v.posture, strict=True):
        if not ok:
            continue
        frames = body.frame_positions(q)
        assert np.linalg.norm(frames["right_hand"] - goal) <= TOLERANCE + 1e-6
        for name in ("right_ischium", "left_ischium", "right_foot", "left_foot"):
            assert np.linalg.norm(frames[name] - ref[name]) < 1e-3
        for cap in body.capsules_at(q):
            assert min(_coal_gap(cap, b) for b in boxes) > -0.01
        com = body.center_of_mass(q)
        support = np.array([ref[f][:2] for f in SUPPORT])
        assert (support[:, 0].min() <= com[0] <= support[:, 0].max()
                and support[:, 1].min() <= com[1] <= support[:, 1].max())


def test_the_pelvis_turns_on_the_seat_and_the_lean_reaches_past_the_arm(lean):
    """A goal 0.2 m beyond the arm's reach straight ahead at shoulder height: the arm alone misses it, the lean reaches
    it with the pelvis pitched forward about the ischia (its orientation changes) and the trunk off the backrest."""
    arm = IKOracle(seated(), "right_hand", ARM, [{"type": "reach"}, {"type": "obstacles"}],
                   search=Search(restarts=3, seed=0))
    shoulder = lean.body.frame_positions()["right_shoulder"]
    far = shoulder + np.array([0.62 + 0.2, 0.0, 0.0])
    assert not arm.evaluate(far[None]).reachable[0]
    v = lean.evaluate(far[None])
    assert v.reachable[0]
    q = v.posture[0]
    pitch = pin.rpy.matrixToRpy(pin.Quaternion(q[6], *q[3:6]).toRotationMatrix())[1]
    assert pitch > -math.radians(15.0) + 0.05  # the pelvis pitched forward from its reclined 15 deg


def test_a_locked_belt_holds_the_chest_and_reaches_no_farther():
    """Belted: the sternum and the outboard shoulder within their webbing (+2 cm) of the anchor, by Pinocchio FK;
    straight
    ahead at shoulder height, the belted reach is no longer than the unbelted lean's."""
    body = seated("car")
    belted = IKOracle(body, "right_hand", TRUNK, BELTED, search=Search(restarts=2, seed=0))
    free = IKOracle(body, "right_hand", TRUNK, LEAN, search=Search(restarts=2, seed=0))
    ref = belted.body.frame_positions()
    shoulder = ref["right_shoulder"]
    line = shoulder + np.outer(np.arange(0.4, 1.2, 0.05), [1.0, 0.0, 0.0])
    vb, vf = belted.evaluate(line), free.evaluate(line)
    farthest = [float(line[v.reachable][:, 0].max() - shoulder[0]) if v.reachable.any() else 0.0 for v in (vb, vf)]
    assert 0.4 <= farthest[0] <= farthest[1]
    anchor = np.array(ANCHOR)
    for ok, q in zip(vb.reachable, vb.posture, strict=True):
        if ok:
            now = belted.body.frame_positions(q)
            for f in ("sternum", "left_shoulder"):
                assert np.linalg.norm(now[f] - anchor) <= np.linalg.norm(ref[f] - anchor) + 0.02 + 1e-4


def test_the_seated_arm_volume_is_the_standing_arm_volume_moved_with_the_shoulder():
    """The same arm on another trunk posture: goals around the shoulder, moved by the clavicle's rigid motion from
    standing to seated, get the same verdicts (reach and the arm's coupling only, no seat or legs in the way)."""
    tasks = [{"type": "reach"}, {"type": "coupling"}]
    stand = IKOracle({"human": {"sex": "male", "percentile": 50}}, "right_hand", ARM, tasks,
                     search=Search(restarts=3, seed=0))
    sit = IKOracle(seated("car"), "right_hand", ARM, tasks, search=Search(restarts=3, seed=0))

    def clavicle(oracle):
        data = oracle.body.model.createData()
        pin.framesForwardKinematics(oracle.body.model, data, oracle.body.q_ref)
        return data.oMf[oracle.body.model.getFrameId("right_clavicle")]

    move = clavicle(sit) * clavicle(stand).inverse()
    rng = np.random.default_rng(7)
    shoulder = stand.body.frame_positions()["right_shoulder"]
    directions = rng.normal(size=(40, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # Radii away from the boundary by 5 cm either way (the arm reaches about 0.62 m from the shoulder).
    goals = shoulder + directions * rng.choice([0.3, 0.45, 0.75, 0.85], size=(40, 1))
    a = stand.evaluate(goals).reachable
    b = sit.evaluate(np.array([move.act(g) for g in goals])).reachable
    assert a.any() and (~a).any()
    assert np.mean(a == b) >= 0.95


def test_the_tether_row_and_its_casadi_constraint_agree_with_pinocchio_and_finite_differences():
    """The CasADi constraint is the squared distance to the anchor (Pinocchio FK) less the squared length; the dls
    row's Jacobian is the distance's gradient (finite differences), and it appears only near or past the webbing's
    length."""
    import casadi as ca

    from oracles.bodies.kinematics import SymbolicKinematics
    from oracles.ik.problem import ReachProblem
    from oracles.ik.strategy import parse_strategy
    from oracles.tasks import Symbolic
    from tests.test_tasks import numeric, random_x

    body = load_body(seated("car"))
    problem = ReachProblem(body, parse_strategy(body, "right_hand", TRUNK, BELTED))
    tether = problem.strategy.task("tether")
    x = random_x(problem, 5)
    q = problem.q_of_x(x)
    num = numeric(problem, q, np.zeros(3))
    anchor = np.array(ANCHOR)
    for f in ("sternum", "left_shoulder"):
        d = body.frame_positions(q)[f] - anchor
        tether._length[f] = float(np.linalg.norm(d)) - 0.001  # just past: the row is active
    sym = Symbolic(SymbolicKinematics(body.model, problem.q_sym), problem.x_sym, ca.SX.sym("g", 3), problem.x_ref,
                   problem.upper - problem.lower)
    values = ca.Function("c", [sym.x], [ca.vertcat(*[c.expr for c in tether.constraints(sym)])])(x)
    # the squared distance less the squared length (the row's bound is 0 for every body: oracles.ik.parameters)
    assert np.allclose(np.array(values).ravel(),
                       [np.sum((body.frame_positions(q)[f] - anchor) ** 2) - tether._length[f] ** 2
                        for f in ("sternum", "left_shoulder")], atol=1e-9)
    rows = tether.rows(num)
    assert len(rows) == 2
    eps = 1e-6
    model = body.model
    for row, f in zip(rows, ("sternum", "left_shoulder"), strict=True):
        fd = []
        for k in range(num.columns.size):
            v = np.zeros(model.nv)
            v[num.columns[k]] = eps
            moved = body.frame_positions(pin.integrate(model, q, v))[f]
            fd.append((np.linalg.norm(moved - anchor) - np.linalg.norm(body.frame_positions(q)[f] - anchor)) / eps)
        assert np.allclose(row.jacobian.ravel(), fd, atol=1e-4)
        assert row.error[0] < 0  # pulled back inside


@pytest.fixture(scope="module")
def seated_atlas(tmp_path_factory):
    """A coarse arm-only atlas of a seated 50th-percentile man at an office chair, right hand."""
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config

    out = tmp_path_factory.mktemp("seated") / "atlas"
    config = {"body": seated(), "box": {"min": [-0.4, -1.0, 0.2], "max": [1.2, 0.6, 1.8]},
              "depth": {"min": 2, "max": 3}, "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "seed": 0}},
              "strategies": [{"name": "arm", "effector": "right_hand", "joints": ARM,
                              "tasks": [{"type": "reach"},
                                        {"type": "obstacles",
                                         "boxes": [{"name": "desk", "min": [0.55, -0.8, 0.69],
                                                    "max": [1.3, 0.8, 0.72]}]}]}]}
    build_atlas(parse_config(config, "seated", "seated"), out)
    return out


def test_the_viewer_shows_the_seat_and_the_desk(seated_atlas):
    """The viewer adds the body's furniture and the strategy's obstacles as boxes where the body says they are."""
    from reach.maps.atlas import load_atlas
    from reach.tools.view import Viewer

    atlas = load_atlas(seated_atlas)
    v = Viewer([atlas], port=free_port(), refine=False)
    try:
        boxes = {h.name.rsplit("/", 1)[-1]: h for h in v.scenes[0].furniture}
        assert set(boxes) == {"seat_pan", "backrest", "desk"}
        body = load_body(seated())
        pan = next(b for b in body.furniture if b.name == "seat_pan")
        assert (np.allclose(boxes["seat_pan"].position, pan.centre)
                and np.allclose(boxes["desk"].position, [0.925, 0.0, 0.705]))
    finally:
        v.close()


def test_evaluate_at_moves_the_targets_into_the_body_and_draws_them(seated_atlas, tmp_path, capsys):
    """--at X Y Z YAW gives the verdicts of the targets moved into the body's frame by hand; --figure writes a PNG;
    reach model --figure draws the seated reference."""
    import json

    from reach.tools.cli import main

    layout = tmp_path / "layout.csv"
    # The body's frame stands at (2, 1, 0) facing +y in the layout: the layout's (1.3, 1.6, 0.9) is 0.6 ahead, 0.7
    # right.
    layout.write_text("name,x,y,z,effector\nahead,1.3,1.6,0.9,right_hand\nbehind,2.0,0.0,0.9,right_hand\n")
    body_frame = tmp_path / "body.csv"
    body_frame.write_text("name,x,y,z,effector\nahead,0.6,0.7,0.9,right_hand\nbehind,-1.0,0.0,0.9,right_hand\n")
    assert main(["evaluate", str(seated_atlas), "--targets", str(layout), "--at", "2", "1", "0", "90", "--json",
                 "--figure", str(tmp_path / "f.png")]) == 0
    moved = json.loads(capsys.readouterr().out)
    assert main(["evaluate", str(seated_atlas), "--targets", str(body_frame), "--json"]) == 0
    direct = json.loads(capsys.readouterr().out)
    assert [r["reachable"] for r in moved["atlases"][0]["rows"]] == [r["reachable"]
        for r in direct["atlases"][0]["rows"]]
    assert [r["strategy"] for r in moved["atlases"][0]["rows"]] == [r["strategy"] for r in direct["atlases"][0]["rows"]]
    assert not moved["atlases"][0]["rows"][1]["reachable"]  # 1 m behind the backrest
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_reach_model_prints_and_draws_the_fitted_seat(tmp_path, capsys):
    import json

    from reach.tools.cli import main

    config = Path(__file__).resolve().parents[1] / "configs" / "examples" / "office_seated_female_p05.yaml"
    assert main(["model", str(config), "--figure", str(tmp_path / "m.png"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["seat"]["kind"] == "chair" and info["seat"]["back_angle"] == pytest.approx(15.0)
    assert 0.3 < info["seat"]["height"] < 0.45  # fitted to her lower leg
    assert {b["name"] for b in info["furniture"]} == {"seat_pan", "backrest"}
    assert (tmp_path / "m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
@browser_only
def test_the_page_draws_the_seat(seated_atlas, browser, tmp_path):
    """In a real browser: with the volumes hidden, the page differs where the seat and the desk are drawn (hidden, then
    shown); the screenshot with them is kept in $REACH_SHOTS to look at."""
    from reach.maps.atlas import load_atlas
    from reach.tools.view import Viewer
    from tests.test_view import _shot, _wait_for_page

    v = Viewer([load_atlas(seated_atlas)], port=free_port(), refine=False)
    try:
        _wait_for_page(browser, v)
        v.show_strategy("arm", False)
        for h in v.scenes[0].furniture:
            h.visible = False
        without = _shot(browser, "seated_without")
        for h in v.scenes[0].furniture:
            h.visible = True
        with_seat = _shot(browser, "seated_with_seat")
        changed = int((np.abs(with_seat.astype(int) - without.astype(int)).max(axis=2) > 30)[:, :760].sum())
        assert changed > 2000
    finally:
        v.close()


def test_the_seated_arm_tree_is_the_standing_arm_tree_moved_with_the_shoulder(tmp_path):
    """Trees (D_max 4, reach and the arm's coupling only): every point whose standing verdict holds a cell around it
    (an interior point), moved by the clavicle's rigid motion from standing to seated, gets the same verdict from the
    seated tree: the volumes agree within a cell."""
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config
    from reach.maps.atlas import load_atlas

    tasks = [{"type": "reach"}, {"type": "coupling"}]
    trees, moves = {}, {}
    for name, body in (("stand", {"human": {"sex": "male", "percentile": 50}}), ("sit", seated("car"))):
        oracle = IKOracle(body, "right_hand", ARM, tasks)
        shoulder = oracle.body.frame_positions()["right_shoulder"]
        config = {"body": body, "box": {"min": (shoulder - 0.8).tolist(), "max": (shoulder + 0.8).tolist()},
                  "depth": {"min": 2, "max": 4}, "oracle": {"name": "casadi-ik", "params": {"restarts": 2, "seed": 0}},
                  "strategies": [{"name": "arm", "effector": "right_hand", "joints": ARM, "tasks": tasks}]}
        build_atlas(parse_config(config, name, name), tmp_path / name)
        trees[name] = load_atlas(tmp_path / name).trees["arm"]
        data = oracle.body.model.createData()
        pin.framesForwardKinematics(oracle.body.model, data, oracle.body.q_ref)
        moves[name] = data.oMf[oracle.body.model.getFrameId("right_clavicle")]
    move = moves["sit"] * moves["stand"].inverse()
    cell = float(np.max(trees["stand"].box.hi - trees["stand"].box.lo)) / 2**4
    rng = np.random.default_rng(11)
    points = rng.uniform(trees["stand"].box.lo, trees["stand"].box.hi, (3000, 3))
    inside = trees["stand"].contains(points, "vertex")
    offsets = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * cell
    interior = np.all([trees["stand"].contains(points + o, "vertex") == inside for o in offsets], axis=0)
    moved = np.array([move.act(p) for p in points[interior]])
    agree = trees["sit"].contains(moved, "vertex") == inside[interior]
    assert interior.sum() > 1000 and inside[interior].any()
    assert agree.mean() >= 0.98


def test_evaluate_probes_targets_a_coarse_tree_misses_beside_the_desk(seated_atlas, tmp_path):
    """Over the lap and the desk, where the coarse tree's cells (D_max 3, 20 cm) meet the body and the desk: targets no
    tree holds are solved thoroughly by IK, marked beyond the trees, and every such verdict puts the hand on the target
    (Pinocchio FK)."""
    from reach.answers.evaluate import Target, evaluate
    from reach.maps.atlas import load_atlas

    atlas = load_atlas(seated_atlas)
    tree = atlas.trees["arm"]
    grid = np.array([[x, y, z] for x in np.arange(0.2, 0.66, 0.05) for y in (-0.5, -0.3, -0.1) for z in (0.76, 0.9)])
    missed = grid[~tree.contains(grid, "vertex")]
    assert len(missed) >= 3
    result = evaluate([atlas], [Target(f"t{k}", tuple(p), "right_hand") for k, p in enumerate(missed)])
    rows = result["atlases"][0]["rows"]
    probed = [r for r in rows if r["beyond_trees"]]
    assert probed and all(r["reachable"] and r["strategy"] == "arm" for r in probed)
    body = load_body(seated())
    for r in probed:
        a = Selector(atlas).probe("right_hand", np.array(r["point"]))
        q = body.configuration(a.posture, a.root)
        assert np.linalg.norm(body.frame_positions(q)["right_hand"] - np.array(r["point"])) <= TOLERANCE + 1e-6


def test_the_shoulder_belts_line_agrees_with_pinocchio_and_finite_differences():
    """With a buckle the belt is the webbing's length from the D-ring over the shoulder and the sternum to the buckle:
    the CasADi constraint is that length (Pinocchio FK), the dls row its gradient (finite differences)."""
    import casadi as ca

    from oracles.bodies.kinematics import SymbolicKinematics
    from oracles.ik.problem import ReachProblem
    from oracles.ik.strategy import parse_strategy
    from oracles.tasks import Symbolic
    from tests.test_tasks import numeric, random_x

    buckle = [0.05, -0.22, 0.30]
    tasks = [t if t["type"] != "tether" else {**t, "frames": ["left_shoulder", "sternum"], "buckle": buckle}
             for t in BELTED]
    body = load_body(seated("car"))
    problem = ReachProblem(body, parse_strategy(body, "right_hand", TRUNK, tasks))
    tether = problem.strategy.task("tether")

    def length(q: np.ndarray) -> float:
        p = body.frame_positions(q)
        path = [np.array(ANCHOR), p["left_shoulder"], p["sternum"], np.array(buckle)]
        return float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(path)))

    # at the reference the webbing is its length less the slack: the belt holds
    assert tether._length["path"] == pytest.approx(length(body.q_ref) + 0.02)
    x = random_x(problem, 5)
    q = problem.q_of_x(x)
    tether._length["path"] = length(q) - 0.001  # just past: the row is active
    sym = Symbolic(SymbolicKinematics(body.model, problem.q_sym), problem.x_sym, ca.SX.sym("g", 3), problem.x_ref,
                   problem.upper - problem.lower)
    value = ca.Function("c", [sym.x], [ca.vertcat(*[c.expr for c in tether.constraints(sym)])])(x)
    assert float(value) == pytest.approx(length(q) - tether._length["path"], abs=1e-9)  # the row: past the length
    (row,) = tether.rows(numeric(problem, q, np.zeros(3)))
    num = numeric(problem, q, np.zeros(3))
    eps, fd = 1e-6, []
    for k in range(num.columns.size):
        v = np.zeros(body.model.nv)
        v[num.columns[k]] = eps
        fd.append((length(pin.integrate(body.model, q, v)) - length(q)) / eps)
    assert np.allclose(row.jacobian.ravel(), fd, atol=1e-4)
    assert row.error[0] < 0
    with pytest.raises(TaskError, match="buckle"):
        parse_strategy(body, "right_hand", TRUNK, [{"type": "tether", "anchor": ANCHOR, "frames": ["sternum"],
                                                    "buckle": [0, 0]}])


def test_a_seated_body_is_measured_as_its_standing_person():
    """`reach model` of a driver printed a stature of 1.08 m: the survey's measures were taken from the seated
    reference. They are the standing person's now, whatever the seat."""
    from oracles.bodies.body import load_body
    from oracles.bodies.measure import measure

    standing = measure(load_body({"human": {"sex": "female", "percentile": 5}}))
    seated = measure(load_body({"human": {"sex": "female", "percentile": 5, "posture": "seated",
                                          "seat": {"kind": "car"}}}))
    from oracles.bodies.anthropometry import stature_at_percentile

    assert seated == standing
    assert seated["stature"] == pytest.approx(stature_at_percentile("female", 5), abs=1e-4)


def test_the_95th_percentile_driver_sits_on_sae_j1517s_95th_percentile_line():
    """The drivers sat about 10 cm too close. The car seat's heel point is fitted where the knee flexes 35
    deg, which puts the 95th-percentile man's hip joint (the H-point) within 25 mm of J1517's 95th-percentile line at
    his H30, measured here by Pinocchio's frames; the line's transcription gives 857 mm at H30 = 271 mm, as a
    secondary source does."""
    from oracles.bodies.body import load_body
    from oracles.bodies.seat import j1517_x95

    assert j1517_x95(0.271) == pytest.approx(0.857, abs=0.001)
    body = load_body({"human": {"sex": "male", "percentile": 95, "posture": "seated", "seat": {"kind": "car"}}})
    f = body.frame_positions(body.q_ref, ["right_hip_flexion", "right_heel"])
    behind, h30 = f["right_heel"][0] - f["right_hip_flexion"][0], f["right_hip_flexion"][2] - f["right_heel"][2]
    assert abs(behind - j1517_x95(h30)) <= 0.025
    i = body.q_names.index("right_knee_flexion")
    assert body.q_ref[i] == pytest.approx(math.radians(35.0), abs=math.radians(0.5))
