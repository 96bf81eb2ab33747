"""Orientation goals and the reachability index, on the 7-DoF arm (configs/urdf/arm7.urdf), checked by
Pinocchio's forward kinematics independently of the solvers."""

from __future__ import annotations

import json
import math
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
import yaml
from helpers import CHROMIUM, DRIVER, browser_only, free_port

from oracles.bodies.kinematics import SymbolicKinematics
from oracles.errors import OracleError, TaskError
from oracles.protocol import Goals, OracleSpec, Oriented, body_params
from oracles.tasks import Symbolic
from reach.answers.answer import orientation_of
from reach.answers.select import Selector
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.building.index import vertex_levels
from reach.errors import ConfigError, InputError, ProtocolError, StoreError
from reach.maps.atlas import load_atlas
from reach.maps.index import ReachIndex, spiral
from reach.maps.store import load_indexed, load_tree, save_tree
from reach.serving.protocol import parse_request

ROOT = Path(__file__).resolve().parents[1]
ARM = {"urdf": str(ROOT / "configs" / "urdf" / "arm7.urdf"),
       "frames": {"tcp": {"parent": "arm7_hand", "xyz": [0, 0, 0.1034]}},
       "reference": {"arm7_joint2": -0.785398, "arm7_joint4": -2.356194, "arm7_joint6": 1.570796,
                     "arm7_joint7": 0.785398}}
TABLE = {"type": "obstacles", "boxes": [{"min": [-0.5, -1.0, -0.1], "max": [1.2, 1.0, 0.0]}]}


def _oracle(orientation: dict, engine: str = "casadi-ik") -> object:
    params = body_params(ARM, "tcp", ["arm7_joint*"], [{"type": "reach"}, TABLE, orientation])
    if engine == "casadi-ik":
        params["jit"] = False
    return OracleSpec(engine, {**params, "restarts": 2}).create()


def _pose(oracle: object, q: np.ndarray) -> pin.SE3:
    model = oracle.body.model  # type: ignore[attr-defined]
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[model.getFrameId("tcp")]


GOALS = np.array([[0.5, 0.0, 0.3], [0.5, 0.2, 0.1], [0.3, -0.3, 0.5], [0.0, 0.0, 1.2], [0.5, 0.2, 0.03]])


@pytest.mark.parametrize("engine", ["casadi-ik", "dls"])
def test_an_axis_within_its_cone_by_forward_kinematics(engine):
    """Every reachable verdict of 'the tool pointing down' puts the tool centre point at the goal (5 mm) and its
    z axis within 5 deg of -z (plus the verdict's 1 mrad), by Pinocchio; straight overhead it cannot point down
    (the hand would stand 0.1 m above the 1.2 m goal, past the reach the free arm has there)."""
    oracle = _oracle({"type": "orientation", "axis": "z", "direction": "-z", "cone": 5}, engine)
    v = oracle.evaluate(GOALS)  # type: ignore[attr-defined]
    assert v.reachable[:3].all() and not v.reachable[3]
    for g, q, ok in zip(GOALS, v.posture, v.reachable, strict=True):
        if ok:
            pose = _pose(oracle, q)
            assert np.linalg.norm(pose.translation - g) <= 0.005
            assert math.degrees(math.acos(np.clip(-(pose.rotation @ [0, 0, 1])[2], -1, 1))) <= 5.06


def test_a_free_task_holds_each_goals_own_direction_and_the_tree_stays_position_only():
    """Without a direction the task asks nothing (the tree is position-only); a goal's direction is held: the tool
    pointing up 3 cm above the table is not reachable (the hand would be under it), pointing down it is."""
    oracle = _oracle({"type": "orientation", "axis": "z"})
    assert isinstance(oracle, Oriented) and oracle.orientation_kinds() == ("direction", "rotation")
    free = oracle.evaluate(GOALS)  # type: ignore[attr-defined]
    assert free.reachable[[0, 1, 2, 4]].all()
    up = oracle.evaluate(Goals(GOALS[4:], {"orientation": np.array([[0.0, 0.0, 1.0]])}))
    down = oracle.evaluate(Goals(GOALS[4:], {"orientation": np.array([[0.0, 0.0, -1.0]])}))
    assert not up.reachable[0] and down.reachable[0]
    sideways = np.array([[1.0, 0.0, 0.0]] * 3)
    v = oracle.evaluate(Goals(GOALS[:3], {"orientation": sideways}))
    for g, q, ok in zip(GOALS[:3], v.posture, v.reachable, strict=True):
        if ok:
            pose = _pose(oracle, q)
            assert (np.linalg.norm(pose.translation - g) <= 0.005
                    and (pose.rotation @ [0, 0, 1])[0] >= math.cos(math.radians(5)) - 1e-3)
    with pytest.raises(OracleError, match="orientations have shape"):
        oracle.evaluate(Goals(GOALS[:2], {"orientation": np.zeros((3, 3))}))
    with pytest.raises(OracleError, match="not zero"):
        oracle.evaluate(Goals(GOALS[:1], {"orientation": np.zeros((1, 3))}))


def test_a_full_orientation_within_its_tolerance_by_forward_kinematics():
    """rpy (pi, 0, 0): the hand's x along the world's x, its z down; the angle of the rotation between the
    reached and the asked orientation is within the 5 deg tolerance. A direction is refused for the full form."""
    oracle = _oracle({"type": "orientation", "rpy": [math.pi, 0, 0], "tolerance": 5})
    target = pin.rpy.rpyToMatrix(math.pi, 0, 0)
    v = oracle.evaluate(GOALS[:3])  # type: ignore[attr-defined]
    assert v.reachable.all()
    for g, q in zip(GOALS[:3], v.posture, strict=True):
        pose = _pose(oracle, q)
        assert np.linalg.norm(pose.translation - g) <= 0.005
        assert math.degrees(np.linalg.norm(pin.log3(target.T @ pose.rotation))) <= 5.06
    assert oracle.orientation_kinds() == ("rotation",)
    with pytest.raises(OracleError, match="full orientation"):
        oracle.evaluate(Goals(GOALS[:1], {"orientation": np.array([[0.0, 0.0, -1.0]])}))


def test_the_casadi_row_is_the_cosine_pinocchio_gives():
    """The task's CasADi expression at random postures equals the cosine computed from Pinocchio's frame rotation."""
    oracle = _oracle({"type": "orientation", "axis": [0, 1, 0], "cone": 10})
    task = oracle.strategy.task("orientation")  # type: ignore[attr-defined]
    p = oracle.problem  # type: ignore[attr-defined]
    aim, on = ca.SX.sym("aim", 3, 3), ca.SX.sym("on")
    sym = Symbolic(SymbolicKinematics(oracle.body.model, p.q_sym), p.x_sym, ca.SX.sym("g", 3), p.x_ref,
                   p.upper - p.lower,  # type: ignore[attr-defined]
                   targets={"orientation": ca.vertcat(ca.vec(aim), on)})
    row = ca.Function("row", [p.x_sym, aim, on], [task.constraints(sym)[0].expr])
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = p.random_x(rng)
        target = pin.rpy.rpyToMatrix(*rng.uniform(-3, 3, 3))
        rot = _pose(oracle, p.q_of_x(x)).rotation
        expected = (rot @ [0, 1, 0]) @ (target @ [0, 1, 0]) - math.cos(math.radians(10))
        assert float(row(x, target, 1.0)) == pytest.approx(expected, abs=1e-9)
        assert float(row(x, target, 0.0)) >= 1.0  # off: always held


def test_orientation_task_errors_name_the_key():
    def parse(raw: dict) -> None:
        OracleSpec("casadi-ik", body_params(ARM, "tcp", ["arm7_joint*"], [{"type": "reach"}, raw])).create()

    with pytest.raises(TaskError, match=r"tasks\[1\]\.axis: expected one of x, -x"):
        parse({"type": "orientation", "axis": "w"})
    with pytest.raises(TaskError, match=r"tasks\[1\]\.direction: direction and cone need axis"):
        parse({"type": "orientation", "direction": "z"})
    with pytest.raises(TaskError, match=r"tasks\[1\]\.rpy: an axis form takes"):
        parse({"type": "orientation", "axis": "z", "rpy": [0, 0, 0]})
    with pytest.raises(TaskError, match=r"tasks\[1\]\.cone: expected a number in \[0.5, 90"):
        parse({"type": "orientation", "axis": "z", "cone": 0})
    with pytest.raises(TaskError, match=r"tasks\[1\]\.axis: .*not zero"):
        parse({"type": "orientation", "axis": [0, 0, 0]})


def test_the_protocols_orientation_field():
    req = parse_request(json.dumps({"op": "query", "effector": "tcp", "goal": [0.5, 0, 0.3],
                                    "orientation": {"direction": [0, 0, -2]}}).encode())
    assert np.allclose(orientation_of(req["orientation"]), [0, 0, -1])
    req = parse_request(json.dumps({"op": "query", "effector": "tcp", "goal": [0.5, 0, 0.3],
                                    "orientation": {"quaternion": [1, 0, 0, 0]}}).encode())
    # 180 deg about x, [qx, qy, qz, qw]
    assert np.allclose(orientation_of(req["orientation"]), np.diag([1.0, -1.0, -1.0]))
    for bad, says in (({"direction": [0, 0, 0]}, "not zero"), ({"direction": [0, 1]}, "3 finite numbers"),
                      ({"direction": [0, 0, 1], "quaternion": [0, 0, 0, 1]}, "one of"), ({"rpy": [0, 0, 0]}, "one of")):
        with pytest.raises(ProtocolError, match=says):
            parse_request(json.dumps({"op": "query", "effector": "tcp", "goal": [0.5, 0, 0.3],
                                      "orientation": bad}).encode())


def test_spiral_points_cover_the_sphere_evenly():
    """Unit vectors; consecutive points are neighbours (within 2.5 times the mean spacing sqrt(4 pi / N)) and no two
    points are closer than a third of it: the spiral of Saff & Kuijlaars (1997)."""
    for n in (26, 50, 200):
        d = spiral(n)
        assert d.shape == (n, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
        spacing = math.sqrt(4 * math.pi / n)
        assert np.linalg.norm(np.diff(d, axis=0), axis=1).max() < 2.5 * spacing
        gaps = np.linalg.norm(d[:, None] - d[None], axis=2) + 10 * np.eye(n)
        assert gaps.min() > spacing / 3
        assert np.linalg.norm(d.mean(axis=0)) < 0.05  # no side favoured
    assert np.array_equal(vertex_levels(np.array([[0, 0, 0], [4, 0, 8], [2, 4, 0], [1, 0, 0]]), 3), [0, 1, 2, 3])


@pytest.fixture(scope="module")
def arm_atlas(tmp_path_factory):
    """A small atlas of the arm: position-only with a 12-direction index, and the tool pointing down."""
    folder = tmp_path_factory.mktemp("arm")
    config = {
        "name": "arm_small", "body": ARM, "box": {"min": [-0.9, -0.9, 0.0], "max": [0.9, 0.9, 1.3]},
        "depth": {"min": 2, "max": 3}, "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "jit": False}},
        "strategies": [
            {"name": "tcp", "effector": "tcp", "joints": ["arm7_joint*"], "directions": 12,
             "tasks": [{"type": "reach"}, TABLE, {"type": "orientation", "axis": "z"}]},
            {"name": "plain", "effector": "tcp", "joints": ["arm7_joint*"], "priority": 5,
             "tasks": [{"type": "reach"}, TABLE]},
        ],
    }
    (folder / "arm.yaml").write_text(yaml.safe_dump(config))
    from reach.building.config import load_config

    build_atlas(load_config(folder / "arm.yaml"), folder / "atlas")
    return folder


@pytest.mark.slow
def test_the_index_is_stored_and_each_reached_direction_holds(arm_atlas):
    """The index's bits are only at reachable vertices, survive the round trip, and a sample of the directions it
    says are reached is reached again by the audit's thorough referee, and of those it says are not, the referee
    reaches few (the quick search's misses)."""
    atlas = load_atlas(arm_atlas / "atlas")
    tree, index = atlas.trees["tcp"], atlas.indexes["tcp"]
    assert index.reached.shape == (len(tree.vertices), 12)
    assert not index.reached[~tree.vertices.reachable].any()
    share = index.share[tree.vertices.reachable]
    assert 0.05 < share.mean() < 0.95 and share.max() > share.min()
    assert tree.meta["index"]["goals"] <= 12 * int(tree.vertices.reachable.sum())
    assert "plain" not in atlas.indexes and np.isnan(atlas.map("plain").index_at(np.zeros((1, 3)), held=False)).all()
    referee = OracleSpec.from_dict(tree.meta["oracle"]).create().variant("referee", restarts=2)
    rows = np.nonzero(tree.vertices.reachable)[0][::7][:12]
    points = tree.lattice.points(tree.lattice.coords(tree.vertices.keys[rows]))
    yes = no = miss = 0
    for r, p in zip(rows, points, strict=True):
        for j in (0, 5, 11):
            v = referee.evaluate(Goals(p[None], {"orientation": index.directions[j][None]},
                                       seeds=tree.vertices.posture[r][None]))
            if index.reached[r, j]:
                yes += 1
                assert v.reachable[0], (r, j)
            else:
                no += 1
                miss += int(v.reachable[0])
    assert yes and no and miss <= max(2, no // 5)


@pytest.mark.slow  # builds the arm's atlas with an index (8 s)
def test_a_damaged_index_is_refused(arm_atlas, tmp_path):
    tree, index = load_indexed(arm_atlas / "atlas" / "tcp.npz")
    assert index is not None
    bad = ReachIndex(index.directions, np.ones_like(index.reached))
    with pytest.raises(StoreError, match="unreachable vertices"):
        load_tree(save_tree(tree, tmp_path / "bad.npz", bad))
    arrays = dict(np.load(arm_atlas / "atlas" / "tcp.npz"))
    arrays["index_bits"] = arrays["index_bits"][:-1]
    with pytest.raises(StoreError, match="bits .* do not match"):
        ReachIndex.from_arrays(arrays, len(tree.vertices), "tcp.npz")


def test_queries_hold_the_goals_orientation(arm_atlas):
    """Only strategies with an orientation task answer, by refinement; the posture holds it by forward kinematics;
    refine off and an atlas without such a strategy are refused naming the field; the answer carries the index."""
    atlas = load_atlas(arm_atlas / "atlas")
    selector = Selector(atlas, budget=1.0)
    down = np.array([0.0, 0.0, -1.0])
    a = selector.select("tcp", np.array([0.45, 0.1, 0.25]), orientation=down)
    assert a.reachable and a.strategy == "tcp" and a.refined == "ok"
    oracle = selector.oracle("tcp")
    q = np.array([a.posture.get(n, 0.0) for n in atlas.trees["tcp"].vertices.posture_names])
    q[:7] = [*a.root["position"], *a.root["quaternion"]]
    pose = _pose(oracle, q)
    assert (np.linalg.norm(pose.translation - [0.45, 0.1, 0.25]) <= 0.005
            and -(pose.rotation @ [0, 0, 1])[2] >= math.cos(math.radians(5)) - 1e-3)
    assert a.index is not None and 0.0 <= a.index <= 1.0
    up = selector.select("tcp", np.array([0.5, 0.2, 0.03]), orientation=np.array([0.0, 0.0, 1.0]))
    assert not up.reachable and up.posture is None
    with pytest.raises(InputError, match="refine: a goal with an orientation is always refined"):
        selector.select("tcp", np.array([0.45, 0.1, 0.25]), refine=False, orientation=down)
    plain = Selector(atlas, budget=1.0)
    plain.order = [o for o in plain.order if o[0] == "plain"]
    plain._by_effector = {"tcp": ["plain"]}
    with pytest.raises(InputError, match="orientation: no strategy of 'tcp' holds a goal's direction"):
        plain.select("tcp", np.array([0.45, 0.1, 0.25]), orientation=down)


def test_directions_need_an_orientation_task_with_an_axis():
    config = {"name": "x", "body": ARM, "box": {"min": [-1, -1, 0], "max": [1, 1, 1.3]}, "depth": {"min": 1, "max": 2},
              "oracle": {"name": "casadi-ik"},
              "strategies": [{"name": "tcp", "effector": "tcp", "joints": ["arm7_joint*"], "directions": 20}]}
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.directions: the reachability index needs an orientation "
                                          r"task with an axis"):
        parse_config(config, "x.yaml")
    config["strategies"][0]["directions"] = -1
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.directions"):
        parse_config(config, "x.yaml")


@pytest.mark.parametrize("workers", [0, 1])
def test_the_server_answers_an_oriented_query(arm_atlas, workers):
    """Over ZeroMQ, in the loop and in a worker process: the answer holds the direction (forward kinematics), and
    refine false with an orientation is a bad_request naming the field; the server keeps serving."""
    from reach.serving.client import Client, ServerError
    from tests.test_server import Running

    r = Running(arm_atlas / "atlas", budget=2.0, workers=workers)
    try:
        with Client(r.server.endpoint, timeout=20000, retries=1) as client:
            a = client.query("tcp", [0.45, 0.1, 0.25], orientation={"direction": [1.0, 0.0, 0.0]})
            assert a["reachable"] and a["strategy"] == "tcp" and a["refined"] == "ok"
            names = load_atlas(arm_atlas / "atlas").trees["tcp"].vertices.posture_names
            q = np.array([a["posture"].get(n, 0.0) for n in names])
            q[:7] = [*a["root"]["position"], *a["root"]["quaternion"]]
            pose = _pose(_oracle({"type": "orientation", "axis": "z"}), q)
            assert (np.linalg.norm(pose.translation - [0.45, 0.1, 0.25]) <= 0.005
                    and (pose.rotation @ [0, 0, 1])[0] >= math.cos(math.radians(5)) - 1e-3)
            with pytest.raises(ServerError, match="refine"):
                client.query("tcp", [0.45, 0.1, 0.25], refine=False, orientation={"direction": [1.0, 0.0, 0.0]})
            assert client.call("health")["ok"]
    finally:
        r.stop()


def test_the_report_draws_the_index_as_a_heat_map(arm_atlas, tmp_path):
    """index_tcp.png (none for the strategy without an index) shows the viridis range; report.md has the index's
    table."""
    from PIL import Image

    from reach.tools.report import report

    t = report(load_atlas(arm_atlas / "atlas"), tmp_path, level=3)
    assert (tmp_path / "index_tcp.png").is_file() and not (tmp_path / "index_plain.png").exists()
    assert t["strategies"]["tcp"]["index"]["directions"] == 12 and t["strategies"]["plain"]["index"] is None
    assert "| tcp | 12 |" in (tmp_path / "report.md").read_text()
    image = np.asarray(Image.open(tmp_path / "index_tcp.png").convert("RGB")).astype(int)
    purple, yellow = np.array([68, 1, 84]), np.array([253, 231, 37])  # viridis at 0 and 1 (in the colour bar at least)
    assert (np.abs(image - purple).max(axis=2) < 30).sum() > 50 and (np.abs(image - yellow).max(axis=2) < 30).sum() > 50
    # Greens and blues in between: the slices hold more than the two ends.
    assert len({tuple(p) for p in image.reshape(-1, 3)[::7]}) > 60


def test_the_viewer_colours_cells_by_the_index(arm_atlas):
    from reach.tools.view import Viewer, index_colours

    assert np.array_equal(index_colours(np.array([0.0, 1.0, np.nan])), [[68, 1, 84], [253, 231, 36], [128, 128, 128]])
    atlas = load_atlas(arm_atlas / "atlas")
    viewer = Viewer([atlas], port=free_port(), refine=False)
    try:
        viewer.cells_box.value = "both"
        viewer.index_box.value = True
        viewer.show_strategy("tcp", True)
        cells = viewer.visible_cells(0, "tcp")
        shown = atlas.map("tcp").index_at(cells.centre, held=False)
        assert np.isfinite(shown).all() and shown.max() > shown.min()
        assert viewer._drawn[(0, "tcp")][0][3] is True  # drawn with the index's colours
    finally:
        viewer.close()


def test_the_audit_covers_the_index(arm_atlas):
    """The audit asks the referee about seeded (vertex, direction) pairs; directions the index calls reached are reached
    (its bits come from verdicts checked by forward kinematics, or from agreeing corners), and the shares are close."""
    from reach.answers.audit import audit

    result = audit(load_atlas(arm_atlas / "atlas"), samples=30, restarts=1, names=["tcp", "plain"])
    i = result["strategies"]["tcp"]["index"]
    assert i["pairs"] == 30 and i["false_reached"]["of"] + i["false_missed"]["of"] == 30
    assert i["false_reached"]["rate"] <= 0.2 and abs(i["share_by_index"] - i["share_by_referee"]) <= 0.25
    assert "index" not in result["strategies"]["plain"]


@pytest.mark.slow
@browser_only
def test_the_page_shows_the_index_colours(arm_atlas):
    """In a real browser: a slice of the arm's cells as dots in the index's colours, the dark violet of the edge
    (index near 0) and the greens of the ring within; without the index, the strategy's own colour instead."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    from reach.tools.view import Viewer
    from tests.test_view import _profile, _shot_until, _wait_for_page

    viewer = Viewer([load_atlas(arm_atlas / "atlas")], port=free_port(), refine=False)
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1200,800", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", f"--user-data-dir={_profile()}"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service(DRIVER), options=opts)
    try:
        viewer.style_box.value, viewer.cells_box.value, viewer.index_box.value = "dots", "both", True
        viewer.show_strategy("tcp", True)
        _wait_for_page(driver, viewer)

        def count(image: np.ndarray, rgb: tuple[int, int, int], tol: int = 45) -> int:
            return int((np.abs(image[:, :760] - np.asarray(rgb)).max(axis=2) <= tol).sum())

        violet, green = (68, 1, 84), (53, 183, 121)  # viridis near 0 and near 0.75
        image = _shot_until(driver, "index_dots", lambda im: count(im, violet) > 200 and count(im, green) > 100)
        assert count(image, violet) > 200 and count(image, green) > 100
        viewer.index_box.value = False
        viewer.draw()
        plain = _shot_until(driver, "index_off", lambda im: count(im, green) < 0.2 * count(image, green))
        assert count(plain, green) < 0.2 * count(image, green)
    finally:
        driver.quit()
        viewer.close()


def test_a_batch_carries_one_orientation_per_goal(arm_atlas):
    """Per goal: the same goal asked pointing down and pointing up (3 cm above the table) answers each as asked;
    the protocol refuses a list of the wrong length or of two kinds, naming the field."""
    goals = [[0.5, 0.2, 0.03], [0.5, 0.2, 0.03]]
    selector = Selector(load_atlas(arm_atlas / "atlas"), budget=1.0)
    down, up = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])
    a, b = selector.select_many("tcp", np.array(goals), orientation=[down, up])
    assert a.reachable and not b.reachable
    with pytest.raises(InputError, match="orientation: expected one direction"):
        selector.select_many("tcp", np.array(goals), orientation=[down])
    ok = parse_request(json.dumps({"op": "query", "effector": "tcp", "goals": goals,
                                   "orientation": [{"direction": [0, 0, -1]}, {"direction": [0, 0, 1]}]}).encode())
    assert [np.asarray(o).tolist() for o in orientation_of(ok["orientation"])] == [[0, 0, -1], [0, 0, 1]]
    for bad, says in (([{"direction": [0, 0, -1]}], "one per goal: 1 for 2 goals"),
                      ([{"direction": [0, 0, -1]}, {"quaternion": [0, 0, 0, 1]}], "of one kind"),
                      ([{"direction": [0, 0, -1]}, {"direction": [0, 0]}], r"\[1\] direction: a list of 3")):
        with pytest.raises(ProtocolError, match=says):
            parse_request(json.dumps({"op": "query", "effector": "tcp", "goals": goals, "orientation": bad}).encode())



@pytest.fixture(scope="module")
def arm7_table(tmp_path_factory):
    """The arm7_table example's position-only strategy (free orientation, clear of itself and of the table), D_max 4."""
    data = yaml.safe_load((ROOT / "configs" / "examples" / "arm7_table.yaml").read_text())
    data["body"]["urdf"] = str(ROOT / "configs" / "urdf" / "arm7.urdf")
    data.update(box={"min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 1.3]}, depth={"min": 2, "max": 4})
    data["strategies"] = [{k: v for k, v in data["strategies"][0].items() if k != "directions"}]
    folder = tmp_path_factory.mktemp("arm7_table")
    (folder / "arm7_table.yaml").write_text(yaml.safe_dump(data))
    from reach.building.config import load_config

    build_atlas(load_config(folder / "arm7_table.yaml"), folder / "atlas")
    return load_atlas(folder / "atlas")


@pytest.mark.slow
def test_oriented_refinement_tries_hard_enough_where_the_referee_reaches(arm7_table):
    """An oriented goal is refined from its stored postures, which hold no orientation, within the
    server's 20 ms budget: on arm7_table it timed out on 5 of the 72 goals of these three seeds that the referee
    (IPOPT, 8 random restarts) reaches. With random starts for a goal that carries a target and a budget of at least
    0.5 s (the batched engine's K starts and K random ones; 0.2 s timed out under load), 1 of 75 was still missed
    (above the base, a posture on a joint's limit that IPOPT finds from the reference): fatrop now also polishes from
    the starts of a cold oriented goal no start reached. At most one is missed: the goals are those the tree holds,
    and a tree built with the rescues of goals reached only through a collision (blocked_starts) holds a
    goal, (-0.2675, 0.1206, 0.6318) m with its approach axis (-0.711, -0.136, 0.690), that no refinement reaches from
    either tree (it lay outside the sample before). Every goal called reachable holds its orientation by forward
    kinematics."""
    selector = Selector(arm7_table)  # the default 20 ms budget: oriented goals get ORIENTED_BUDGET
    tree = arm7_table.trees["tcp"]
    referee = OracleSpec.from_dict(tree.meta["oracle"]).create().variant("referee", restarts=8)
    oracle = selector.oracle("tcp")
    reached = missed = 0
    for seed in range(3):
        rng = np.random.default_rng(seed)
        points = rng.uniform([-0.7, -0.7, 0.05], [0.8, 0.7, 1.1], (400, 3))
        points = points[tree.contains(points, "vertex")][:40]
        directions = rng.normal(size=(len(points), 3))
        directions /= np.linalg.norm(directions, axis=1)[:, None]
        truth = referee.evaluate(Goals(points, {"orientation": directions})).reachable
        for p, d, ok in zip(points, directions, truth, strict=True):
            a = selector.select("tcp", p, orientation=d)
            reached += int(ok)
            missed += int(ok and not a.reachable)
            if a.reachable:
                q = np.array([a.posture.get(n, 0.0) for n in tree.vertices.posture_names])
                q[:7] = [*a.root["position"], *a.root["quaternion"]]
                pose = _pose(oracle, q)
                assert (np.linalg.norm(pose.translation - p) <= 0.005
                        and (pose.rotation @ [0, 0, 1]) @ d >= math.cos(math.radians(5)) - 1e-3)
    assert reached >= 60 and missed <= 1, (reached, missed)
