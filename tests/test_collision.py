"""Collision geometry (oracles.bodies.collision) and the tasks built on it: our distances against coal's, the human's
URDF collision elements read back by an independent parser, URDF primitives and meshes, the pairs checked."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import coal
import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM

from oracles.bodies.body import human_body, urdf_body
from oracles.bodies.collision import Capsule, nearest_points
from oracles.ik.problem import ReachProblem
from oracles.ik.search import Search
from oracles.ik.strategy import parse_strategy
from reach.errors import ModelError


def coal_capsule_distance(a0, a1, ra, b0, b1, rb) -> float:
    """Coal's distance between two capsules given by their end points."""
    def placed(p, q, r):
        d = q - p
        n = np.linalg.norm(d)
        if n < 1e-12:
            return coal.Sphere(r), coal.Transform3s(np.eye(3), p)
        z = d / n
        x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        return coal.Capsule(r, n), coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), 0.5 * (p + q))

    (ga, ta), (gb, tb) = placed(a0, a1, ra), placed(b0, b1, rb)
    return float(coal.distance(ga, ta, gb, tb, coal.DistanceRequest(), coal.DistanceResult()))


def test_our_segment_distances_agree_with_coal():
    rng = np.random.default_rng(0)
    for _ in range(300):
        p = rng.uniform(-0.5, 0.5, (4, 3))
        if rng.random() < 0.2:  # parallel segments, the degenerate case
            p[3] = p[2] + (p[1] - p[0]) * rng.uniform(0.2, 2.0)
        elif rng.random() < 0.1:  # a sphere
            p[3] = p[2]
        ra, rb = rng.uniform(0.01, 0.1, 2)
        ours = nearest_points(p[0], p[1], p[2], p[3])[2]
        truth = coal_capsule_distance(p[0], p[1], ra, p[2], p[3], rb)
        assert ours - ra - rb == pytest.approx(truth, abs=1e-6)


def test_the_humans_urdf_collision_elements_are_its_capsules():
    body = human_body()
    root = ET.fromstring(body.urdf)  # an independent reading of the file we write
    found = {}
    for link in root.iter("link"):
        for col in link.findall("collision"):
            cyl = col.find("geometry/cylinder")
            found[col.get("name")] = (link.get("name"), float(cyl.get("radius")), float(cyl.get("length")))
    assert len(found) == len(body.capsules) == 17
    for c in body.capsules:
        link, radius, length = found[f"capsule_{c.name}"]
        assert (link == c.link and radius == pytest.approx(c.radius, abs=1e-9)
                and length == pytest.approx(c.length, abs=1e-9))
    # Sizes from the tables: the forearm thinner than the upper arm, the thorax the widest.
    r = {c.name: c.radius for c in body.capsules}
    assert r["right_hand"] < r["right_forearm"] < r["right_upper_arm"] < r["right_thigh"] < r["thorax"]


def test_coal_agrees_with_our_distances_on_the_human():
    body = human_body()
    model = body.collision
    rng = np.random.default_rng(1)
    pairs = [(i, j) for i in range(len(model.placed)) for j in range(i + 1, len(model.placed))]
    for _ in range(3):
        q = body.q_ref.copy()
        q[7:] = rng.uniform(body.model.lowerPositionLimit[7:], body.model.upperPositionLimit[7:])
        coal_d = model.distances(q, pairs)
        data = body.model.createData()
        import pinocchio as pin

        pin.forwardKinematics(body.model, data, q)
        for (i, j), d in zip(pairs, coal_d, strict=True):
            (a, b), (c, e) = model.world(data, i), model.world(data, j)
            ours = nearest_points(a, b, c, e)[2] - model.placed[i].radius - model.placed[j].radius
            assert ours == pytest.approx(d, abs=1e-6)


def test_a_collision_check_with_each_pairs_floor_as_margin_agrees_with_the_distances():
    """``CollisionModel.clear`` (coal's collision check, each pair's floor its security margin) against the pairs'
    distances (our own segment distances agree with those above): pair by pair, at postures near the reference and
    across the ranges, floors of both signs (a pair overlapping at the reference keeps that overlap)."""
    body = human_body()
    model = body.collision
    pairs = [(i, j) for i in range(len(model.placed)) for j in range(i + 1, len(model.placed))][::7]
    rng = np.random.default_rng(2)
    lo, hi = body.model.lowerPositionLimit[7:], body.model.upperPositionLimit[7:]
    checked = {True: 0, False: 0}
    for spread in (0.05, 0.3, 1.0):
        for _ in range(15):
            q = body.q_ref.copy()
            q[7:] += spread * (rng.uniform(lo, hi) - q[7:])
            d = model.distances(q, pairs)
            floors = d + rng.choice([-0.004, 0.004], len(d))  # each pair 4 mm on either side of its floor
            for k, pair in enumerate(pairs):
                apart = bool(model.clear(q, (pair,), floors[k : k + 1]))
                assert apart == (d[k] >= floors[k]), (pair, d[k], floors[k])
                checked[apart] += 1
            assert model.clear(q, tuple(pairs), floors) == bool(np.all(d >= floors))
            assert model.clear(q, tuple(pairs), d - 0.004)  # every pair just beyond its floor
    assert min(checked.values()) > 100  # both verdicts, many times
    assert model.clear(body.q_ref, (), np.zeros(0))


def test_the_floor_check_by_coal_agrees_with_the_capsules_end_points():
    """``CollisionModel.above_floor`` (coal's collision test against the floor's half-space) against our own reading:
    each capsule's end points at least its radius less the tolerance above z = 0, capsule by capsule, the body lowered
    and turned so that both verdicts come often, tolerances of both signs."""
    body = human_body()
    model = body.collision
    data = body.model.createData()
    rng = np.random.default_rng(3)
    lo, hi = body.model.lowerPositionLimit[7:], body.model.upperPositionLimit[7:]
    checked = {True: 0, False: 0}
    for _ in range(60):
        q = body.q_ref.copy()
        q[7:] += rng.uniform(0.0, 1.0) * (rng.uniform(lo, hi) - q[7:])
        q[2] -= rng.uniform(0.0, 0.6)
        pin.forwardKinematics(body.model, data, q)
        tol = float(rng.choice([1e-4, 0.0, -0.01, 0.02]))
        lowest = [min(a[2], b[2]) - p.radius for p, (a, b) in
                  ((p, model.world(data, i)) for i, p in enumerate(model.placed))]
        for i, z in enumerate(lowest):
            if abs(z + tol) > 1e-9:
                assert model.above_floor(q, (i,), tol) == (z >= -tol), (model.placed[i].name, z, tol)
                checked[z >= -tol] += 1
        every = tuple(range(len(lowest)))
        assert model.above_floor(q, every, tol) == (min(lowest) >= -tol)
    assert min(checked.values()) > 100
    assert model.above_floor(body.q_ref, (), 0.0)


def test_pairs_skip_adjacent_and_rigidly_joined_segments():
    body = human_body()
    s = parse_strategy(body, "right_hand", ARM, [{"type": "reach"}, {"type": "self_collision"}])
    task = s.task("self_collision")
    names = {frozenset((body.collision.placed[p.first].name, body.collision.placed[p.second].name)) for p in task.pairs}
    assert frozenset(("right_hand", "thorax")) in names and frozenset(("right_hand", "head")) in names
    assert frozenset(("right_upper_arm", "thorax")) not in names  # adjacent across the shoulder girdle
    assert frozenset(("right_forearm", "right_upper_arm")) not in names  # adjacent at the elbow
    assert frozenset(("left_thigh", "thorax")) not in names  # nothing the arm moves
    close = {frozenset(c[:2]) for c in task.at_reference}
    assert frozenset(("right_hand", "right_thigh")) in close  # the hanging hand touches the thigh: keeps its clearance
    pair = next(p for p in task.pairs
                if {body.collision.placed[p.first].name, body.collision.placed[p.second].name} == {"right_hand",
                    "right_thigh"})
    assert pair.clearance < 0


def test_urdf_primitives_and_meshes_become_capsules(tmp_path):
    import trimesh

    mesh_dir = tmp_path / "pkg" / "meshes"
    mesh_dir.mkdir(parents=True)
    trimesh.creation.cylinder(radius=0.05, height=0.4).export(mesh_dir / "rod.stl")
    urdf = tmp_path / "robot.urdf"
    urdf.write_text("""<?xml version="1.0"?><robot name="r">
      <link name="base"><collision><geometry><box size="0.2 0.1 0.6"/></geometry></collision></link>
      <link name="arm"><collision><origin xyz="0 0 0.2"/>
        <geometry><cylinder radius="0.04" length="0.3"/></geometry></collision>
        <collision><geometry><sphere radius="0.07"/></geometry></collision>
        <collision><geometry><mesh filename="package://pkg/meshes/rod.stl"/></geometry></collision></link>
      <joint name="j" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>""")
    body = urdf_body(urdf, package_dirs=[str(tmp_path)])
    caps = {c.name: c for c in body.capsules}
    box = caps["base_0"]
    assert box.radius == pytest.approx(0.5 * np.hypot(0.2, 0.1)) and box.length == pytest.approx(0.6)
    assert (caps["arm_0"].radius == 0.04 and np.allclose(caps["arm_0"].a, [0, 0, 0.05])
            and np.allclose(caps["arm_0"].b, [0, 0, 0.35]))
    assert caps["arm_1"].length == 0.0 and caps["arm_1"].radius == 0.07
    rod = caps["arm_2"]
    # The rim of a cylinder needs the whole axis: the caps then enclose its flat ends.
    assert rod.radius == pytest.approx(0.05, rel=0.02) and rod.length == pytest.approx(0.4, abs=0.01)
    with pytest.raises(ModelError, match=r"package_dirs: mesh 'package://pkg/meshes/rod.stl' not found in \[\]: give "
                                         r"package_dirs the folder that holds the package folder 'pkg'"):
        urdf_body(urdf)


def test_a_collada_mesh_without_pycollada_names_the_extra(tmp_path, monkeypatch):
    """A .dae mesh needs pycollada, which trimesh only hints at; the error names the extra."""
    import sys

    (tmp_path / "part.dae").write_text("<COLLADA/>")
    urdf = tmp_path / "robot.urdf"
    urdf.write_text("""<?xml version="1.0"?><robot name="r">
      <link name="base"><collision><geometry><mesh filename="part.dae"/></geometry></collision></link></robot>""")
    monkeypatch.setitem(sys.modules, "collada", None)  # as if pycollada were not installed
    with pytest.raises(ModelError, match=r"part.dae is COLLADA \(.dae\), which needs pycollada: pip install "
                                         r"'reach-volumes\[meshes\]'"):
        urdf_body(urdf)


def test_a_capsule_on_an_unknown_link_is_named():
    from oracles.bodies.collision import CollisionModel

    body = human_body()
    with pytest.raises(ModelError, match="capsule 'tail' is on link 'tail_link'"):
        CollisionModel(body.model, [Capsule("tail", "tail_link", (0, 0, 0), (0, 0, 1), 0.1)])


def test_self_collision_cuts_agree_with_coal_in_distance_and_gradient():
    """The cuts casadi-ik solves with: each pair's gap is coal's distance, and its gradient over x (a floating
    root's rpy included) predicts coal's distance at a nearby posture."""
    body = human_body()
    joints = ["root", "*_hip_*", "*_knee_*", "lumbar_*", "thoracic_*", *ARM, "left_shoulder_*", "left_elbow_*"]
    s = parse_strategy(body, "right_hand", joints, [{"type": "reach"}, {"type": "self_collision"}])
    problem = ReachProblem(body, s)
    task = s.task("self_collision")
    rng = np.random.default_rng(2)
    checked = 0
    for _ in range(5):
        x = problem.x_ref + rng.normal(size=problem.nx) * 0.3
        x = np.clip(x, problem.lower, problem.upper)
        q = problem.q_of_x(x)
        cuts = task.cuts(problem.numeric_x(q, body.model.createData()), np.inf)
        assert len(cuts) == len(task.pairs)
        coal_d = task.distances(q)
        step = rng.normal(size=problem.nx) * 1e-4
        coal_next = task.distances(problem.q_of_x(x + step))
        for cut, d, d_next in zip(cuts, coal_d, coal_next, strict=True):
            assert cut.gap == pytest.approx(d, abs=1e-6)
            if d > 1e-3:  # away from contact, where the distance is smooth
                assert cut.gap + cut.jacobian @ step == pytest.approx(d_next, abs=2e-7)
                checked += 1
    assert checked > 100


def test_a_robot_on_a_table_no_longer_reaches_through_it():
    from pathlib import Path

    from oracles.ik.oracle import IKOracle

    ur5 = {"urdf": str(Path(__file__).resolve().parents[1] / "configs" / "urdf" / "ur5.urdf")}
    table = {"type": "obstacles", "boxes": [{"min": [-1.0, -1.0, -0.8], "max": [1.0, 1.0, -0.001]}]}
    free = IKOracle(ur5, "ee_link", ["*_joint"], [{"type": "reach"}], search=Search(restarts=2))
    guarded = IKOracle(ur5, "ee_link", ["*_joint"], [{"type": "reach"}, table], search=Search(restarts=2))
    below, above = np.array([[0.4, 0.2, -0.3]]), np.array([[0.4, 0.2, 0.3]])
    assert free.evaluate(below).reachable[0]  # through the table top
    assert not guarded.evaluate(below).reachable[0]
    v = guarded.evaluate(above)
    assert v.reachable[0]
    task = guarded.strategy.task("obstacles")
    for g in task.guards:  # coal: every link clears the table top (or keeps its mounting clearance)
        assert task.distance(guarded.body.collision, v.posture[0], g.capsule, g.box) >= g.floor


def test_obstacle_errors_name_the_key():
    from reach.errors import TaskError

    body = human_body()
    with pytest.raises(TaskError, match=r"tasks\[1\]\.boxes\[0\]: min must be below max"):
        parse_strategy(body, "right_hand", ARM,
                       [{"type": "reach"}, {"type": "obstacles", "boxes": [{"min": [0, 0, 1], "max": [1, 1, 0]}]}])
    with pytest.raises(TaskError, match=r"tasks\[1\]\.boxes: expected a non-empty list"):
        parse_strategy(body, "right_hand", ARM, [{"type": "reach"}, {"type": "obstacles"}])


def test_reachable_arm_verdicts_are_collision_free_by_an_independent_coal_check():
    """Capsules read from the URDF text with ElementTree, placed with Pinocchio's frames, measured by coal."""
    import pinocchio as pin

    from oracles.ik.oracle import IKOracle

    oracle = IKOracle({"human": {"sex": "male", "percentile": 50}}, "right_hand", ARM,
                      [{"type": "reach"}, {"type": "self_collision"}], search=Search(restarts=2))
    body, task = oracle.body, oracle.strategy.task("self_collision")
    shapes = {}
    for link in ET.fromstring(body.urdf).iter("link"):
        for col in link.findall("collision"):
            origin, cyl = col.find("origin"), col.find("geometry/cylinder")
            rpy = [float(v) for v in origin.get("rpy").split()]
            local = pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.array([float(v) for v in origin.get("xyz").split()]))
            shapes[col.get("name").removeprefix("capsule_")] = (link.get("name"), local,
                                                                coal.Capsule(float(cyl.get("radius")),
                                                                    float(cyl.get("length"))))
    goals = np.random.default_rng(4).uniform([-0.3, -0.6, 0.7], [0.5, 0.4, 1.6], (30, 3))
    v = oracle.evaluate(goals)
    assert 8 <= v.reachable.sum()
    names = [p.name for p in body.collision.placed]
    for q, ok in zip(v.posture, v.reachable, strict=True):
        if not ok:
            continue
        data = body.model.createData()
        pin.framesForwardKinematics(body.model, data, q)

        def placed(name, data=data):
            link, local, shape = shapes[name]
            m = data.oMf[body.model.getFrameId(link)] * local
            return shape, coal.Transform3s(m.rotation, m.translation)

        for pair in task.pairs:
            (ga, ta), (gb, tb) = placed(names[pair.first]), placed(names[pair.second])
            d = coal.distance(ga, ta, gb, tb, coal.DistanceRequest(), coal.DistanceResult())
            assert d >= pair.floor, (names[pair.first], names[pair.second], d)


def test_the_arms_keep_out_is_the_static_body_and_unreachable():
    from oracles.ik.oracle import IKOracle

    oracle = IKOracle({"human": {}}, "right_hand", ARM, [{"type": "reach"}, {"type": "self_collision"}],
                      search=Search(restarts=3, give_up=None))
    task = oracle.strategy.task("self_collision")
    names = {oracle.body.collision.placed[i].name for i in task.static}
    assert {"thorax", "abdomen", "pelvis", "head", "left_upper_arm"} <= names
    assert "right_thigh" not in names  # the hanging hand touches it at the reference posture
    capsules = oracle.keep_out()
    assert capsules.shape == (len(names), 7)
    centres = 0.5 * (capsules[:, :3] + capsules[:, 3:6])
    assert not oracle.evaluate(centres).reachable.any()


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    s = np.clip((p - a) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)


def test_a_mesh_gets_capsules_along_its_long_axis_as_its_shape_asks(tmp_path):
    """A torso-like mesh (a slim column on a wide base) becomes several capsules, slimmer where the
    mesh is, whose union still covers every point of its surface (sampled here by trimesh, not the fit's points); a
    plain rod stays one capsule."""
    import trimesh

    base = trimesh.creation.box((0.5, 0.5, 0.2))
    column = trimesh.creation.box((0.15, 0.15, 0.9))
    column.apply_translation([0, 0, 0.55])
    trimesh.util.concatenate([base, column]).export(tmp_path / "torso.stl")
    trimesh.creation.cylinder(radius=0.05, height=0.4).export(tmp_path / "rod.stl")
    urdf = tmp_path / "robot.urdf"
    urdf.write_text("""<?xml version="1.0"?><robot name="r">
      <link name="torso"><collision><geometry><mesh filename="torso.stl"/></geometry></collision></link>
      <link name="arm"><collision><geometry><mesh filename="rod.stl"/></geometry></collision></link>
      <joint name="j" type="revolute"><parent link="torso"/><child link="arm"/>
        <origin xyz="0.4 0 0.8"/><axis xyz="0 1 0"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>""")
    caps = urdf_body(urdf).capsules
    torso = [c for c in caps if c.link == "torso"]
    assert [c.name for c in torso][0] == "torso_0" and len(torso) >= 2
    assert [c.name for c in caps if c.link == "arm"] == ["arm_0"]
    # One capsule over the whole torso is as thick as the base's half diagonal (0.35 m); the column's pieces are not.
    assert min(c.radius for c in torso) < 0.15
    points = trimesh.load(tmp_path / "torso.stl").sample(3000, seed=1)
    gap = np.min([_point_segment_distance(points, np.array(c.a), np.array(c.b)) - c.radius for c in torso], axis=0)
    assert gap.max() <= 1e-9
    volume = sum(np.pi * c.radius**2 * (c.length + 4 * c.radius / 3) for c in torso)
    one = np.pi * 0.36**2 * (1.0 + 4 * 0.36 / 3)  # about the single capsule's (base half diagonal 0.354, 1.1 m tall)
    assert volume < 0.6 * one
