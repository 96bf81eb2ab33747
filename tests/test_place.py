"""Where to stand: placements ranked by the trees against analytic truths, verified by IK on the arm."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from reach.answers.evaluate import Target
from reach.answers.place import Space, rank, to_body, verify
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.errors import InputError
from reach.maps.atlas import load_atlas
from reach.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _atlas(tmp_path_factory, name: str, strategies: list[dict]) -> object:
    out = tmp_path_factory.mktemp(name) / name
    build_atlas(parse_config({"box": {"min": [-1.2, -1.2, -1.2], "max": [1.2, 1.2, 1.2]}, "depth": {"min": 2, "max": 5},
                              "oracle": {"name": "sphere", "params": {"radius": 1.0}}, "strategies": strategies},
                                  name, name), out)
    return load_atlas(out)


@pytest.fixture(scope="module")
def balls(tmp_path_factory):
    """An arm-only ball of 0.5 m (priority 1) inside a whole-body ball of 1 m, about the body's origin."""
    return _atlas(tmp_path_factory, "balls",
                  [{"name": "arm", "effector": "hand", "oracle": {"params": {"radius": 0.5}}},
                                              {"name": "body", "effector": "hand"}])


@pytest.fixture(scope="module")
def front(tmp_path_factory):
    """A volume in front of the body only: the box x in [0.3, 0.9], |y| <= 0.3, |z| <= 0.3 (a robot's reach over a
    table)."""
    return _atlas(tmp_path_factory, "front",
                  [{"name": "front", "effector": "hand",
                    "oracle": {"name": "box", "params": {"min": [0.3, -0.3, -0.3], "max": [0.9, 0.3, 0.3]}}}])


@pytest.fixture(scope="module")
def nothing(tmp_path_factory):
    return _atlas(tmp_path_factory, "nothing",
                  [{"name": "none", "effector": "hand",
                    "oracle": {"name": "box", "params": {"min": [5, 5, 5], "max": [6, 6, 6]}}}])


def test_to_body_moves_and_turns_the_targets():
    """A body at (1, 2, 0) facing +y sees the layout's point (1, 3, 0.5) 1 m straight ahead, 0.5 m up."""
    got = to_body(np.array([[1.0, 3.0, 0.5]]), np.array([[1.0, 2.0, 0.0, math.pi / 2]]))
    assert np.allclose(got, [[[1.0, 0.0, 0.5]]])


def test_a_ring_of_targets_puts_the_body_at_its_centre(balls):
    """Eight targets on a 0.4 m ring about (0.6, -0.3) at the body's height: every target within the arm's 0.5 m ball
    only within 0.1 m of the centre; the best placement is the centre (the middle of the tied ones), arm only."""
    angles = np.linspace(0, 2 * math.pi, 8, endpoint=False)
    targets = [Target(f"t{k}", (0.6 + 0.4 * math.cos(a), -0.3 + 0.4 * math.sin(a), 0.0), "hand")
               for k, a in enumerate(angles)]
    r = rank([balls], targets, Space((0.0, 1.2), (-0.9, 0.3), step=0.05, yaw=(0.0, 0.0)))
    assert np.allclose(r.placements[0, :2], [0.6, -0.3], atol=0.051)
    assert r.accommodated[0] == 1.0 and r.preference[0] == 1.0  # the arm reaches them all
    far = np.linalg.norm(r.placements[:, :2] - [0.6, -0.3], axis=1) > 0.2
    assert (r.preference[far] < 1.0).all()  # farther, the whole body is needed for some (weight 0.8), or none reaches


def test_a_robot_turns_to_face_targets_on_one_side(front):
    """Targets 0.6 m to the left of a base held near the origin: only a heading of +90 deg reaches them."""
    targets = [Target(f"t{k}", (dx, 0.6, dz), "hand")
               for k, (dx, dz) in enumerate([(-0.1, 0.0), (0.1, 0.0), (0.0, 0.1), (0.0, -0.1)])]
    r = rank([front], targets,
             Space((-0.1, 0.1), (-0.1, 0.1), step=0.05, yaw=(-math.pi, math.pi), yaw_step=math.radians(15)))
    assert r.reached[0] == 1.0 and abs(math.degrees(r.placements[0, 3]) - 90.0) < 16.0
    behind = np.abs(np.angle(np.exp(1j * (r.placements[:, 3] + math.pi / 2)))) < 0.3
    assert (r.reached[behind] == 0).all()


def test_a_population_counts_the_bodies_accommodated(balls, nothing):
    """Two bodies, one reaching nothing: at best half the population is accommodated and half the targets reached."""
    targets = [Target("a", (0.3, 0.0, 0.0), "hand"), Target("b", (0.0, 0.3, 0.0), "hand")]
    r = rank([balls, nothing], targets, Space((-0.2, 0.2), (-0.2, 0.2), step=0.1))
    assert r.accommodated[0] == 0.5 and r.reached[0] == 0.5 and r.preference[0] == 0.5
    assert r.row(0, targets)["strategies"][1] == {"a": None, "b": None}


def test_bad_spaces_and_targets_are_refused_naming_the_field(balls):
    with pytest.raises(InputError, match="x: expected min <= max"):
        Space((1.0, 0.0), (0.0, 0.0))
    with pytest.raises(InputError, match="step: .* candidates; at most"):
        Space((-10, 10), (-10, 10), step=0.001)
    with pytest.raises(InputError, match="effector: .* no strategy for effector 'foot'"):
        rank([balls], [Target("a", (0.1, 0, 0), "foot")], Space((0, 0), (0, 0)))


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("arm")
    body = {"urdf": str(ROOT / "configs" / "urdf" / "arm7.urdf"),
            "frames": {"tcp": {"parent": "arm7_hand", "xyz": [0, 0, 0.1034]}},
            "reference": {"arm7_joint2": -0.785398, "arm7_joint4": -2.356194, "arm7_joint6": 1.570796,
                          "arm7_joint7": 0.785398}}
    build_atlas(parse_config({"name": "arm", "body": body, "box": {"min": [-1.0, -1.0, -0.4], "max": [1.0, 1.0, 1.3]},
                              "depth": {"min": 2, "max": 4},
                              "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "jit": False}},
                              "strategies": [{"name": "tcp", "effector": "tcp", "joints": ["arm7_joint*"]}]}, "arm",
                                  "arm"), folder / "atlas")
    return load_atlas(folder / "atlas")


def test_ik_verifies_the_best_placement_of_a_robot_on_a_table(arm, tmp_path, capsys):
    """Targets on a shelf 1.2 m ahead of the layout's origin: the base moves towards them; IK at the best placement
    reaches what the trees claim; `reach place` prints the ranking and writes the heat map."""
    targets = [Target(f"t{k}", (1.2, y, z), "tcp")
               for k, (y, z) in enumerate([(-0.2, 0.3), (0.0, 0.3), (0.2, 0.3), (0.0, 0.5)])]
    r = rank([arm], targets,
             Space((0.0, 1.0), (-0.3, 0.3), step=0.1, yaw=(-math.pi / 2, math.pi / 2), yaw_step=math.radians(30)))
    assert r.reached[0] == 1.0 and r.placements[0, 0] > 0.3
    checked = verify(r, [arm], targets, best=2)
    assert checked[0]["reached"] == 1.0 and checked[0]["agree"]
    csv = tmp_path / "shelf.csv"
    csv.write_text("name,x,y,z,effector\n" + "".join(f"{t.name},{t.point[0]},{t.point[1]},{t.point[2]},tcp\n"
                                                     for t in targets))
    assert main(["place", str(arm.path), "--targets", str(csv), "--x", "0", "1", "--y", "-0.3", "0.3", "--step",
                 "0.1", "--yaw", "-90", "90",
                 "--yaw-step", "30", "--verify", "1", "--figure", str(tmp_path / "floor.png")]) == 0
    out = capsys.readouterr().out
    assert "rank 1 verified by IK: 100% of targets reached" in out and (tmp_path / "floor.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def table_arm(tmp_path_factory):
    """The arm on a table top (z = 0), clear of itself and of the table: it cannot reach among its own base."""
    folder = tmp_path_factory.mktemp("table_arm")
    body = {"urdf": str(ROOT / "configs" / "urdf" / "arm7.urdf"),
            "frames": {"tcp": {"parent": "arm7_hand", "xyz": [0, 0, 0.1034]}},
            "reference": {"arm7_joint2": -0.785398, "arm7_joint4": -2.356194, "arm7_joint6": 1.570796,
                          "arm7_joint7": 0.785398}}
    tasks = [{"type": "reach"}, {"type": "self_collision"},
             {"type": "obstacles", "boxes": [{"min": [-1.5, -1.5, -0.1], "max": [1.5, 1.5, 0.0]}]}]
    build_atlas(parse_config({"name": "table_arm", "body": body,
                              "box": {"min": [-1.0, -1.0, -0.4], "max": [1.0, 1.0, 1.3]},
                              # fatrop: the trap below (the trees hold all six targets at the tray, IK reaches some) is
                              # its tree's; the
                              # batched engine's tree holds two of six there, as IK does.
                              "depth": {"min": 2, "max": 4}, "oracle": {"name": "casadi-ik",
                                             "params": {"restarts": 1, "jit": False, "solver": "fatrop"}},
                              "strategies": [{"name": "tcp", "effector": "tcp", "joints": ["arm7_joint*"],
                                              "tasks": tasks}]}, "t", "t"),
                folder / "atlas")
    return load_atlas(folder / "atlas")


@pytest.mark.slow
def test_the_best_placement_has_margin_not_the_middle_of_the_tie_and_verifies(table_arm, monkeypatch):
    """Six tray targets 8 cm over the table on a 12 cm ring. Every placement of the base within
    about half a metre of the tray holds them all by the trees, and the middle of that tie is the tray itself, where
    the base stands among the targets and IK reaches only some (as a UR5's ranking did: 50 %). Ranked by margin the
    best placement keeps the targets deep inside the volume, and IK reaches them all; the IK-verified share re-ranks
    the verified candidates."""
    angles = np.linspace(0, 2 * math.pi, 6, endpoint=False)
    targets = [Target(f"t{k}", (0.12 * math.cos(a), 0.12 * math.sin(a), 0.08), "tcp") for k, a in enumerate(angles)]
    space = Space((-0.6, 0.6), (-0.6, 0.6), step=0.05, yaw=(0.0, 0.0))
    middle = rank([table_arm], targets, Space((0.0, 0.0), (0.0, 0.0)))
    # the trap is there
    assert middle.reached[0] == 1.0 and verify(middle, [table_arm], targets, best=1)[0]["reached"] < 1.0
    r = rank([table_arm], targets, space)
    tied = np.isfinite(r.margin)
    assert tied.sum() > 100 and r.reached[tied].min() == 1.0  # a wide tie, with the tray's middle inside it
    assert np.linalg.norm(r.placements[0, :2]) > 0.2 and r.margin[0] > middle.margin[0] + 0.05
    assert np.all(np.diff(r.margin[tied]) <= 1e-12)  # the tie ordered by margin, deepest first
    best = verify(r, [table_arm], targets, best=3)
    assert [v["reached"] for v in best] == [1.0, 1.0, 1.0] and best[0]["agree"]
    # Without the margin the middle of the tie came first; verifying re-ranks it below a placement that IK confirms.
    import reach.answers.place as place

    monkeypatch.setattr(place, "margins", lambda atlases, names, taken, points, *rest: np.zeros(len(points)))
    plain = rank([table_arm], targets, space)
    assert np.allclose(plain.placements[0, :2], [0.0, 0.0])
    again = verify(plain, [table_arm], targets, best=3)
    assert again[0]["trees_rank"] != 1  # the middle, which IK does not confirm, is no longer first
    assert [v["reached"] for v in again] == sorted((v["reached"] for v in again), reverse=True)
    assert np.allclose(plain.placements[again[0]["rank"] - 1], plain.placements[0])


@pytest.mark.parametrize("workers", [0, 1])
def test_the_server_places_the_body(balls, workers):
    """The `place` operation ranks as reach.answers.place does, in the loop or (with workers: seconds of work at its
    limit) in a worker; a grid over the limit is a bad_request naming the step, before anything is queued."""
    from reach.serving.client import Client, ServerError
    from tests.test_server import Running

    targets = [{"point": [0.6 + 0.4 * math.cos(a), -0.3 + 0.4 * math.sin(a), 0.0], "effector": "hand"}
               for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)]
    r = Running(balls.path, workers=workers)
    sent: list[str] = []
    if workers:
        submit = r.server.pool.submit
        r.server.pool.submit = lambda task: sent.append(task.op) or submit(task)  # type: ignore[union-attr]
    try:
        with Client(r.server.endpoint, retries=1, timeout=60_000) as c:  # a worker starts first
            got = c.call("place", targets=targets, x=[0.0, 1.2], y=[-0.9, 0.3], yaw=[0, 0], step=0.05, top=3)
            assert got["candidates"] == 25 * 25 and len(got["ranked"]) == 3
            best = got["ranked"][0]
            assert (np.allclose(best["position"][:2], [0.6, -0.3], atol=0.051) and best["reached"] == 1.0
                    and best["strategies"][0]["t0"] == "arm")
            with pytest.raises(ServerError, match="step"):
                c.call("place", targets=targets, x=[-10, 10], y=[-10, 10], step=0.01)
            assert c.call("health")["ok"]
        # the second refused before it is queued, naming the step (it waited for a busy worker, then timed out)
        assert sent == (["place"] if workers else [])
    finally:
        r.stop()


def test_a_seat_track_ranks_positions_and_heights_and_draws_them(balls, tmp_path):
    """A seat slides on x and rises on z, no turn: three targets 0.4 m apart in z at x = 0.7 fit the arm's 0.5 m ball
    only
    from z = 0.2 and x >= 0.4; the heat map is drawn on the track's (x, z)."""
    from reach.tools.report import placement_map as heat_map

    targets = [Target("a", (0.7, 0.0, 0.2), "hand"), Target("b", (0.7, 0.0, 0.6), "hand"),
               Target("c", (0.7, 0.0, -0.2), "hand")]
    r = rank([balls], targets, Space((0.0, 0.6), (0.0, 0.0), (0.0, 0.4), step=0.05, yaw=(0.0, 0.0)))
    assert r.preference[0] == 1.0 and r.reached[0] == 1.0
    assert r.placements[0, 1] == 0.0 and r.placements[0, 3] == 0.0
    assert r.placements[0, 2] == pytest.approx(0.2, abs=0.051) and r.placements[0, 0] >= 0.4 - 0.051
    path = heat_map(r, targets, tmp_path / "track.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_absurd_steps_and_ranges_are_bad_input_not_an_overflow():
    """A step of 1e-320 or an x range of +-1e308 overflowed (an `internal` reply over the wire)."""
    from reach.answers.place import Space
    from reach.errors import InputError

    for kwargs in ({"x": (-1.0, 1.0), "y": (0.0, 0.0), "step": 1e-320}, {"x": (-1e308, 1e308), "y": (0.0, 0.0)}):
        with pytest.raises(InputError, match="values on one axis") as info:
            Space(**kwargs)
        assert info.value.field == "step"
    assert len(Space(x=(-1.0, 1.0), y=(0.0, 0.0)).candidates()) == 41


def counting_queries(monkeypatch) -> list[int]:
    """The points of each k-d tree query the margins make, counted from now on (the module's cKDTree wrapped)."""
    import reach.answers.place as place

    queried: list[int] = []
    real = place.cKDTree

    class Counting(real):  # type: ignore[misc, valid-type]
        def query(self, x, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202 - counts the margins' queries
            queried.append(len(x))
            return super().query(x, *args, **kwargs)

    monkeypatch.setattr(place, "cKDTree", Counting)
    return queried


def test_a_ranking_keeps_its_deadline_and_bounds_its_margins(balls, monkeypatch):
    """1,681 candidates x 1,000 targets near the centre of a ball (all tied) held a server's worker
    over 1,000 s: the margins' k-d tree queries were one per tied candidate and target, and no step read the deadline.
    Now the margins take at most MARGIN_QUERIES queries, and a deadline stops the ranking."""
    import time

    import reach.answers.place as place

    targets = [Target(f"t{k}", (0.01 * (k % 10), 0.01 * (k // 10 % 10), 0.001 * k), "hand") for k in range(1000)]
    space = Space((-0.2, 0.2), (-0.2, 0.2), step=0.01, yaw=(0.0, 0.0))  # 41 x 41 = 1,681 candidates
    queried = counting_queries(monkeypatch)
    r = rank([balls], targets, space)
    assert len(r.placements) == 1681 and r.accommodated[0] == 1.0
    assert 0 < sum(queried) <= place.MARGIN_QUERIES
    with pytest.raises(place.PastDeadline) as err:
        rank([balls], targets, space, deadline=time.perf_counter() - 1.0)
    assert err.value.code == "timeout"


def test_a_repeated_target_is_measured_once_and_a_late_deadline_stops_the_lookups(balls, monkeypatch):
    """1,000 identical targets held a server's worker in one k-d tree query; the trees' lookups of 1.68 M points
    read no deadline (a worker answered 1.1 s past it beside two CPU-bound processes). A layout's repeated point is
    queried once, the ranking is the one target's, and the lookups stop at a deadline between their chunks."""
    import reach.answers.place as place

    space = Space((-0.2, 0.2), (-0.2, 0.2), step=0.01, yaw=(0.0, 0.0))
    one = rank([balls], [Target("t", (0.05, 0.02, 0.0), "hand")], space)
    queried = counting_queries(monkeypatch)
    many = rank([balls], [Target(f"t{k}", (0.05, 0.02, 0.0), "hand") for k in range(1000)], space)
    assert np.array_equal(many.placements, one.placements) and np.array_equal(many.margin, one.margin, equal_nan=True)
    assert sum(queried) == np.count_nonzero(~np.isnan(one.margin))  # one point a tied candidate
    # a clock past the deadline from its third look: with chunks of 100 points, the ranking stops at its third chunk
    # of work (the targets moved into the body's frame, then the trees' lookups, each chunk looking at the deadline)
    looks = []

    def clock() -> float:
        looks.append(1)
        return 0.0 if len(looks) < 3 else 10.0

    monkeypatch.setattr(place.time, "perf_counter", clock)
    monkeypatch.setattr(place, "CONTAINS_CHUNK", 100)
    with pytest.raises(place.PastDeadline):
        rank([balls], [Target("t", (0.05, 0.02, 0.0), "hand")], space, deadline=5.0)
    assert len(looks) == 3
