"""A population (docs/population.md): members from ANSUR II, their atlases, and the share that reaches each target."""

from __future__ import annotations

import csv
import gzip
import json
import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM

from oracles.bodies.body import load_body
from oracles.bodies.population import boundary_manikins, members, parse_population
from oracles.errors import ModelError
from oracles.protocol import Goals, OracleSpec
from reach.answers.accommodation import direct, weighted_share, wilson
from reach.answers.evaluate import Target
from reach.building.config import parse_config
from reach.building.population import members_of
from reach.errors import ConfigError
from reach.serving import protocol as P
from reach.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]


def small(population: dict, **body: object) -> dict:
    """A population config with the right arm only, coarse: a member builds in about a second."""
    return {"name": "pop", "population": population, "body": {"human": dict(body)}, "box": "auto",
            "depth": {"min": 2, "max": 3}, "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "seed": 0}},
            "strategies": [{"name": "right_arm", "effector": "right_hand", "joints": ARM,
                            "tasks": [{"type": "reach"}, {"type": "self_collision"}, {"type": "coupling"}]}]}


# Targets about the right shoulder of an adult standing at the origin: some every member reaches, some none does, some
# only the long-armed.
TARGETS = [Target("chest", (0.45, -0.20, 1.25)), Target("far", (0.85, -0.20, 1.00)),
           Target("side", (0.05, -0.75, 1.20)), Target("high", (0.35, -0.15, 1.90)),
           Target("ahead", (0.55, -0.20, 1.35)), Target("low", (0.30, -0.25, 0.85))]


@pytest.mark.parametrize(("raw", "key"), [
    ({"ansur": {"n": 0}}, "population.ansur.n"),
    ({"ansur": {"n": 5, "sex": "x"}}, "population.ansur.sex"),
    ({"ansur": {"n": 5, "sex": "male", "female_share": 0.3}}, "population.ansur.female_share"),
    ({"ansur": {"all": True, "n": 3}}, "population.ansur.n"),
    ({"ansur": {"n": 5000, "sex": "female"}}, "population.ansur.n"),
    ({"boundary": {"coverage": 1.5}}, "population.boundary.coverage"),
    ({"boundary": {}, "ansur": {"n": 3}}, "population"),
    ({"people": 3}, "population.people"),
])
def test_a_bad_population_names_its_key(raw, key):
    with pytest.raises(ModelError) as err:
        members(parse_population(raw))
    assert err.value.key == key


def test_a_config_error_names_the_file_and_the_population_key():
    with pytest.raises(ConfigError, match=r"cfg\.yaml.*population\.ansur\.sex"):
        parse_config(small({"ansur": {"n": 2, "sex": "both"}}), "cfg.yaml")


def test_a_drawn_population_is_the_same_every_time_and_mixes_the_sexes_as_asked():
    spec = parse_population({"ansur": {"n": 10, "sex": "mixed", "female_share": 0.3, "seed": 7}})
    first, again = members(spec), members(spec)
    assert [m.name for m in first] == [m.name for m in again]
    assert sum(m.sex == "female" for m in first) == 3 and len({m.name for m in first}) == 10
    other = members(parse_population({"ansur": {"n": 10, "sex": "mixed", "female_share": 0.3, "seed": 8}}))
    assert [m.name for m in other] != [m.name for m in first]


def test_the_whole_survey_weighted_to_half_women():
    everyone = members(parse_population({"ansur": {"all": True, "female_share": 0.5}}))
    # the survey's own counts (Gordon et al. 2014), read from the carried file, not from the module
    with gzip.open(ROOT / "oracles/bodies/data/ansur2.csv.gz", "rt") as fh:
        sexes = [row["sex"] for row in csv.DictReader(fh)]
    assert len(everyone) == len(sexes) == 6068
    w = np.array([m.weight for m in everyone])
    women = np.array([m.sex == "female" for m in everyone])
    assert math.isclose(w[women].sum() / w.sum(), 0.5) and math.isclose(w.sum(), len(everyone))


def test_boundary_manikins_span_their_sex_thumbtip_reach():
    # at least 95 % of 500 sampled subjects' thumb-tip reaches lie within the range of their sex's manikins.
    # The subjects are read from the carried survey file here, independently of the module's sample.
    with gzip.open(ROOT / "oracles/bodies/data/ansur2.csv.gz", "rt") as fh:
        rows = list(csv.DictReader(fh))
    rng = np.random.default_rng(47)
    for sex in ("male", "female"):
        reach = np.array([float(r["thumbtipreach"]) / 1000 for r in rows if r["sex"] == sex])
        family = boundary_manikins(sex)
        assert len(family) == 15 and family[0].name == f"{sex}_centre"
        spanned = [m.human["thumbtipreach"] for m in family]
        picked = rng.choice(reach, size=500, replace=False)
        inside = np.mean((picked >= min(spanned)) & (picked <= max(spanned)))
        assert inside >= 0.95, (sex, inside)
        # the centre is the survey's mean
        assert abs(family[0].human["thumbtipreach"] - reach.mean()) < 1e-4


def test_wilson_interval_at_known_values():
    z2 = 1.959963984540054**2
    # no successes in n: the upper bound is z^2 / (n + z^2); all successes: the lower is n / (n + z^2)
    assert wilson(0.0, 4) == (0.0, pytest.approx(z2 / (4 + z2)))
    assert wilson(1.0, 40)[0] == pytest.approx(40 / (40 + z2))
    # equal weights are the plain interval; doubling every weight changes nothing
    hits = np.array([True, False, True, True])
    assert weighted_share(np.ones(4), hits) == weighted_share(2 * np.ones(4), hits)
    assert weighted_share(np.ones(4), hits)["share"] == 0.75


def test_a_member_keeps_the_config_body_posture_and_seat_and_a_size_given_there_is_refused():
    m = members(parse_population({"ansur": {"n": 1, "sex": "female", "seed": 1}}))[0]
    body = m.body({"human": {"posture": "seated", "seat": {"kind": "car"}}})
    assert body["human"] == {"posture": "seated", "seat": {"kind": "car"}, **m.human}
    # a size or sex given to every member would be dropped without a word: each member's comes from the survey
    with pytest.raises(ModelError, match=r"body\.human\.percentile: .*their own record: .* not percentile, sex"):
        m.body({"human": {"sex": "male", "percentile": 95, "posture": "seated"}})
    with pytest.raises(ConfigError, match=r"pop: body\.human\.acromialheight: .*not acromialheight"):
        parse_config(small({"ansur": {"n": 2, "sex": "mixed", "seed": 0}}, acromialheight=-1), "pop", "pop")
    with pytest.raises(ModelError, match="generated humans"):
        m.body({"urdf": "robot.urdf"})


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A population of four, each member's right arm built (depth 3), through the CLI."""
    folder = tmp_path_factory.mktemp("pop")
    config = folder / "pop.yaml"  # JSON is YAML
    config.write_text(json.dumps(small({"ansur": {"n": 4, "sex": "mixed", "seed": 3}})))
    targets = folder / "targets.csv"
    targets.write_text("name,x,y,z\n" + "".join(f"{t.name},{t.point[0]},{t.point[1]},{t.point[2]}\n"
                                                 for t in TARGETS))
    assert main(["build", str(config), "-o", str(folder / "out"), "--quiet", "-j", "1"]) == 0
    return config, folder / "out", targets


def test_a_population_builds_one_atlas_per_member_and_resumes(built, capsys):
    config, out, _ = built
    doc = json.loads((out / "population.json").read_text())  # read with json: our manifest, an independent parser
    names = [m["name"] for m in doc["members"]]
    assert len(names) == 4 and all((out / n / "manifest.json").is_file() for n in names)
    # a member's atlas answers shares and placements: no motion graph unless the config asks for one
    assert not list(out.glob("*/*.graph.npz"))
    raw = small({"ansur": {"n": 4, "sex": "mixed", "seed": 3}})
    assert not parse_config(raw, "pop.yaml").motion_graph
    assert parse_config({**raw, "build": {"motion_graph": True}}, "pop.yaml").motion_graph
    assert doc["population"] == {"ansur": {"n": 4, "sex": "mixed", "seed": 3}}
    capsys.readouterr()
    assert main(["build", str(config), "-o", str(out), "--quiet", "-j", "1"]) == 2
    assert "give --resume" in capsys.readouterr().err
    # an atlas built before its manifest kept landmarks: --resume records them, keeping its trees
    from reach.maps.atlas import read_manifest as read_atlas_manifest
    from reach.maps.atlas import write_manifest as write_atlas_manifest

    older = {k: v for k, v in read_atlas_manifest(out / names[0]).items() if k != "landmarks"}
    write_atlas_manifest(out / names[0], older)
    # a killed build: one member's folder lost; --resume builds it again and keeps the others
    lost = out / names[2]
    for f in lost.iterdir():
        f.unlink()
    lost.rmdir()
    capsys.readouterr()
    assert main(["build", str(config), "-o", str(out), "--quiet", "-j", "1", "--resume"]) == 0
    log = capsys.readouterr().out
    assert (lost / "manifest.json").is_file()
    assert log.count("kept the finished tree") == 3 and log.count("oracle calls") == 1
    assert "eyes" in read_atlas_manifest(out / names[0])["landmarks"]
    assert main(["model", str(config)]) == 0
    listing = capsys.readouterr().out
    assert "a population of 4" in listing and all(n in listing for n in names)


def test_prepare_takes_a_population_folder_and_its_first_member_serves_all(built, capsys, tmp_path):
    _, out, _ = built
    capsys.readouterr()
    assert main(["prepare", str(out)]) == 0
    first = json.loads((out / "population.json").read_text())["members"][0]["name"]
    assert f"its first member, {first}, for all 4" in capsys.readouterr().out
    # a member not built yet: one line naming the manifest and the fix
    broken = tmp_path / "pop"
    broken.mkdir()
    (broken / "population.json").write_text((out / "population.json").read_text())
    assert main(["prepare", str(broken)]) == 2
    err = capsys.readouterr().err.strip()
    assert "population.json" in err and "reach build --resume" in err and len(err.splitlines()) == 1


def test_accommodation_from_atlases_agrees_with_direct_ik_checked_by_pinocchio(built, capsys):
    config_path, out, targets = built
    capsys.readouterr()
    assert main(["evaluate", str(out), "--targets", str(targets), "--json"]) == 0
    from_trees = json.loads(capsys.readouterr().out)
    config = parse_config(json.loads(config_path.read_text()), str(config_path))
    by_ik = direct(config, TARGETS)
    assert by_ik["refuted_by_check"] == 0
    # members solved in two processes: the same answers
    assert direct(config, TARGETS, workers=2)["by_member"] == by_ik["by_member"]
    # member x target: the atlases' verdict (refined at the target) against the members' own oracles, every
    # "reached" checked by forward kinematics on that member's own model, here with Pinocchio directly
    agree = 0
    strategy = config.strategies[0]
    for k, member in enumerate(members_of(config)):
        body = member.body(config.raw.get("body"))
        oracle = OracleSpec(strategy.oracle.name, {**strategy.oracle.params, "body": body}).create()
        points = np.array([t.point for t in TARGETS])
        verdict = oracle.evaluate(points)
        model = load_body(body).model
        data = model.createData()
        frame = model.getFrameId("right_hand")
        for i, (ok, q) in enumerate(zip(verdict.reachable, verdict.posture, strict=True)):
            if ok:
                pin.framesForwardKinematics(model, data, q)
                assert np.linalg.norm(data.oMf[frame].translation - points[i]) < 0.01
        assert by_ik["by_member"][k]["reached"] == list(verdict.reachable)
        assert from_trees["by_member"][k]["name"] == member.name
        agree += sum(a == b for a, b in zip(by_ik["by_member"][k]["reached"], from_trees["by_member"][k]["reached"],
                                            strict=True))
    assert agree == 4 * len(TARGETS)
    shares = {t["target"]: t["share"] for t in from_trees["targets"]}
    assert shares["chest"] == 1.0 and shares["high"] == 0.0  # the table holds both ends, not one answer for all
    # each member's row says every strategy that reaches a target: the strategies' shares counted from them again
    for result in (from_trees, by_ik):
        for t, row in enumerate(result["targets"]):
            for name, share in row["by_strategy"].items():
                hits = [m["reached"][t] and (m["strategy"][t] == name or name in m["also"][t])
                        for m in result["by_member"]]
                assert share["share"] == pytest.approx(np.mean(hits), abs=1e-4)


def test_placement_of_a_population_weighs_its_members_and_the_share_of_targets(built, capsys):
    from reach.answers.place import Space, rank
    from reach.maps.atlas import load_atlas

    _, out, targets_csv = built
    doc = json.loads((out / "population.json").read_text())
    atlases = [load_atlas(out / m["atlas"]) for m in doc["members"]]
    space = Space((-0.2, 0.2), (-0.2, 0.2), (0.0, 0.0), (0.0, 0.0), 0.1, 1.0)
    alone = rank(atlases[:1], TARGETS, space, "right_hand")
    # a member of weight 0 does not count: the first member with weight 1 ranks as it does alone
    weighted = rank(atlases, TARGETS, space, "right_hand", body_weights=np.array([1.0, 0, 0, 0]))
    order = np.lexsort(alone.placements.T)
    again = np.lexsort(weighted.placements.T)
    assert np.allclose(alone.accommodated[order], weighted.accommodated[again])
    assert np.allclose(alone.reached[order], weighted.reached[again])
    # asking half of the targets accommodates at least as many as asking all, and per body it is a count
    half = rank(atlases, TARGETS, space, "right_hand", need=0.5)
    every = rank(atlases, TARGETS, space, "right_hand")
    by_place = np.lexsort(half.placements.T), np.lexsort(every.placements.T)
    assert np.all(half.accommodated[by_place[0]] >= every.accommodated[by_place[1]])
    assert set(np.round(half.accommodated * 4, 6)) <= {0.0, 1.0, 2.0, 3.0, 4.0}
    # the command takes the population folder, and --accommodate keeps only placements at or above the share
    capsys.readouterr()
    assert main(["place", str(out), "--targets", str(targets_csv), "--effector", "right_hand", "--x", "-0.2", "0.2",
                 "--y", "-0.2", "0.2",
                 "--yaw", "0", "0", "--step", "0.1", "--verify", "0", "--targets-share", "0.5", "--accommodate",
                 "0.5", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["accommodating"] == int(np.sum(half.accommodated >= 0.5))
    assert all(r["accommodated"] >= 0.5 for r in result["ranked"])


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A binary little-endian PLY of float vertices and uchar-counted int faces, read here without trimesh."""
    raw = path.read_bytes()
    head, _, body = raw.partition(b"end_header\n")
    lines = head.decode().splitlines()
    assert lines[0] == "ply" and "format binary_little_endian 1.0" in lines
    n_v = int(next(line.split()[2] for line in lines if line.startswith("element vertex")))
    n_f = int(next(line.split()[2] for line in lines if line.startswith("element face")))
    verts = np.frombuffer(body[:12 * n_v], "<f4").reshape(n_v, 3)
    faces = np.frombuffer(body[12 * n_v:], np.dtype([("n", "u1"), ("i", "<i4", (3,))]), count=n_f)
    assert np.all(faces["n"] == 3) and len(body) == 12 * n_v + 13 * n_f
    return verts, faces["i"]


def test_the_accommodation_volume_counts_members_whose_trees_hold_each_point(built, tmp_path, capsys):
    from reach.answers.accommodation import load_members, shares
    from reach.maps.atlas import load_atlas
    from reach.tools.accommodation_report import grid

    _, out, _ = built
    capsys.readouterr()
    assert main(["report", str(out), "-o", str(tmp_path / "rep"), "--level", "3"]) == 0
    table = json.loads((tmp_path / "rep" / "accommodation.json").read_text())
    atlases, weights, _ = load_members(out)
    axes, points = grid(atlases, 3)
    found = shares(atlases, weights, points)
    # each point's share, counted here member by member from the trees read again
    doc = json.loads((out / "population.json").read_text())
    pick = np.random.default_rng(0).choice(len(points), 300, replace=False)
    count = sum(load_atlas(out / m["atlas"]).trees["right_arm"].contains(points[pick], "vertex").astype(float)
                for m in doc["members"]) / len(doc["members"])
    assert np.allclose(found["right_arm"][pick], count) and np.allclose(found["any"], found["right_arm"])
    assert 0 < np.mean(count == 1.0) and np.mean(count == 0.0) > 0  # both ends occur: not one answer everywhere
    cell = float(np.prod([(a[-1] - a[0]) / (len(a) - 1) for a in axes]))
    v95 = table["strategies"]["right_arm"]["volume_m3"]
    assert v95["95%"] == pytest.approx(np.sum(found["right_arm"] >= 0.95 - 1e-9) * cell, abs=1e-4)
    assert v95["5%"] >= v95["50%"] >= v95["95%"] > 0
    # the 50 % isosurface lies where the share crosses a half: its vertices between grid points on either side
    verts, faces = read_ply(tmp_path / "rep" / "accommodation_right_arm_50.ply")
    assert len(faces) > 0 and faces.max() < len(verts)
    lo = np.array([a[0] for a in axes])
    step = np.array([(a[-1] - a[0]) / (len(a) - 1) for a in axes])
    assert np.all(verts >= lo - 1.01 * step) and np.all(verts <= np.array([a[-1] for a in axes]) + 1.01 * step)
    assert (tmp_path / "rep" / "accommodation_right_arm.png").stat().st_size > 10_000


def test_the_server_answers_accommodation_over_zeromq(built):
    import threading

    import zmq

    from reach.maps.atlas import load_atlas
    from reach.serving import protocol as P
    from reach.serving.server import Server

    _, out, _ = built
    doc = json.loads((out / "population.json").read_text())
    first = out / doc["members"][0]["atlas"]
    goals = [list(t.point) for t in TARGETS]
    plain = Server(first, "tcp://127.0.0.1:*", None)
    try:
        reply = json.loads(plain.respond(json.dumps({"op": "accommodation", "effector": "right_hand",
                                                     "goals": goals}).encode()))
        assert reply["error"]["code"] == P.FORBIDDEN and "--population" in reply["error"]["message"]
    finally:
        plain.close()
    server = Server(first, "tcp://127.0.0.1:*", None, population=out)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 20_000)
    sock.connect(server.endpoint)
    try:
        sock.send(json.dumps({"op": "accommodation", "id": 7, "effector": "right_hand", "goals": goals}).encode())
        reply = json.loads(sock.recv())
        # counted here from each member's tree, read again
        trees = [load_atlas(out / m["atlas"]).trees["right_arm"] for m in doc["members"]]
        count = np.mean([t.contains(np.array(goals), "vertex") for t in trees], axis=0)
        assert reply["ok"] and reply["id"] == 7 and reply["members"] == 4
        assert np.allclose(reply["share"], count) and np.allclose(reply["by_strategy"]["right_arm"], count)
        assert all(lo <= s <= hi for lo, s, hi in zip(reply["low"], reply["share"], reply["high"], strict=True))
        for bad, code in (({"effector": "left_foot", "goals": goals}, P.UNKNOWN_EFFECTOR),
                          ({"effector": "right_hand", "goals": [[0, 0, 0]] * 1001}, P.TOO_LARGE),
                          ({"effector": "right_hand"}, P.BAD_REQUEST)):
            sock.send(json.dumps({"op": "accommodation", **bad}).encode())
            assert json.loads(sock.recv())["error"]["code"] == code
        # goals on each member's own body: offsets from its right acromion, placed where Pinocchio puts that member's
        # frame on the body its manifest names (read here with json, the body built again)
        offsets = [[0.45, -0.05, 0.0], [0.6, -0.05, 0.0], [0.2, -0.1, -0.3], [0.05, -0.7, 0.0]]
        sock.send(json.dumps({"op": "accommodation", "effector": "right_hand", "goals": offsets,
                              "relative_to": "right_acromion"}).encode())
        reply = json.loads(sock.recv())
        held = []
        for m, tree in zip(doc["members"], trees, strict=True):
            at = load_body(m["body"]).frame_positions(names=["right_acromion"])["right_acromion"]
            held.append(tree.contains(np.array(offsets) + at, "vertex"))
        assert reply["ok"] and np.allclose(reply["share"], np.mean(held, axis=0))
        assert not np.allclose(np.mean(held, axis=0), np.mean([t.contains(np.array(offsets), "vertex")
                                                               for t in trees], axis=0))  # not the offsets as points
        sock.send(json.dumps({"op": "accommodation", "effector": "right_hand", "goals": offsets,
                              "relative_to": "third_eye"}).encode())
        error = json.loads(sock.recv())["error"]
        assert error["code"] == P.BAD_REQUEST
        assert "third_eye" in error["message"] and "right_acromion" in error["message"]
    finally:
        sock.close(linger=0)
        server.stop()
        thread.join(timeout=5)
        server.close()


def test_a_members_landmarks_are_its_bodys_frames_and_bad_ones_are_named(built):
    import dataclasses

    from reach.errors import StoreError
    from reach.maps.atlas import load_atlas

    _, out, _ = built
    member = json.loads((out / "population.json").read_text())["members"][1]
    atlas = load_atlas(out / member["atlas"])
    frames = load_body(member["body"]).frame_positions()  # every frame, by Pinocchio on the body built again
    assert set(atlas.manifest["landmarks"]) == set(frames)
    assert np.allclose(atlas.landmark("eyes"), frames["eyes"], atol=1e-12)
    for landmarks, match in ((None, "reach build --resume"), ([1, 2], "expected an object"),
                             ({"eyes": [0, "x", 1]}, r"landmarks\.eyes: expected \[x, y, z\]")):
        manifest = {k: v for k, v in atlas.manifest.items() if k != "landmarks"}
        if landmarks is not None:
            manifest["landmarks"] = landmarks
        with pytest.raises(StoreError, match=match):
            dataclasses.replace(atlas, manifest=manifest).landmark("eyes")


def test_seated_members_each_get_their_seat_fitted():
    family = boundary_manikins("female")
    small_body = load_body(family[2].body({"human": {"posture": "seated", "seat": {"kind": "car"}}}))
    large_body = load_body(family[1].body({"human": {"posture": "seated", "seat": {"kind": "car"}}}))
    assert family[1].human["buttockkneelength"] > family[2].human["buttockkneelength"] + 0.1
    # the heel point is fitted to each member's legs: the longer legs put it farther forward
    heel = [b.frame_positions(names=["right_heel"])["right_heel"][0] for b in (small_body, large_body)]
    assert heel[1] > heel[0] + 0.1
    # the short-thighed member's calf would press 10 mm into the cushion's front edge at the driver's 35 deg of knee
    # flexion: she sits closer, the knee flexed 40 deg; the long-legged member keeps 35
    knees = [b.describe()["seat"]["knee"] for b in (small_body, large_body)]
    assert knees == [40.0, 35.0]


def test_the_direct_command_prints_the_table_and_its_json(built, capsys):
    config_path, _, targets = built
    capsys.readouterr()
    assert main(["evaluate", str(config_path), "--direct", "--targets", str(targets), "-j", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    again = direct(parse_config(json.loads(config_path.read_text()), str(config_path)), TARGETS)
    assert result["by_member"] == again["by_member"] and result["way"] == "direct"
    assert main(["evaluate", str(config_path), "--direct", "--targets", str(targets), "-j", "1"]) == 0
    text = capsys.readouterr().out
    assert "reached % [95 % CI]" in text and "4 members" in text
    # a config without a population is refused by name
    plain = config_path.parent / "plain.yaml"
    plain.write_text(json.dumps({k: v for k, v in json.loads(config_path.read_text()).items() if k != "population"}))
    assert main(["evaluate", str(plain), "--direct", "--targets", str(targets)]) == 2
    assert "population" in capsys.readouterr().err


@pytest.mark.slow
def test_direct_answers_on_a_dask_cluster_are_the_ones_solved_here(built, capsys):
    """``reach evaluate --direct --scheduler ADDR``: the members are solved on a real Dask scheduler's two worker
    processes, and every member's answers are those solved in this process; without --direct, Dask is refused by
    name."""
    from distributed import Client, LocalCluster

    config_path, _, targets = built
    config = parse_config(json.loads(config_path.read_text()), str(config_path))
    here = direct(config, TARGETS)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            assert len(client.scheduler_info()["workers"]) == 2
            there = direct(config, TARGETS, client=client)
        capsys.readouterr()
        assert main(["evaluate", str(config_path), "--direct", "--targets", str(targets), "--scheduler",
                     cluster.scheduler_address, "--json"]) == 0
        cli = json.loads(capsys.readouterr().out)
    assert there["by_member"] == here["by_member"] == cli["by_member"] and there["way"] == "direct"
    assert main(["evaluate", str(config_path.parent / "out"), "--targets", str(targets), "--dask"]) == 2
    assert "--dask" in capsys.readouterr().err


def test_a_population_with_a_member_not_built_or_beside_other_atlases_is_refused_by_name(built, tmp_path, capsys):
    import shutil

    _, out, targets = built
    copy = tmp_path / "pop"
    shutil.copytree(out, copy)
    doc = json.loads((copy / "population.json").read_text())
    (copy / doc["members"][1]["atlas"] / "manifest.json").unlink()
    capsys.readouterr()
    assert main(["evaluate", str(copy), "--targets", str(targets), "--effector", "right_hand"]) == 2
    err = capsys.readouterr().err
    assert doc["members"][1]["name"] in err and "--resume" in err
    assert main(["place", str(out), str(out / doc["members"][0]["atlas"]), "--targets", str(targets),
                 "--effector", "right_hand", "--x", "0", "0", "--y", "0", "0", "--yaw", "0", "0"]) == 2
    assert "placed alone" in capsys.readouterr().err


def test_balance_pelvis_takes_true_false_or_a_distance():
    from oracles.bodies.body import human_body
    from oracles.errors import TaskError
    from oracles.ik.strategy import parse_strategy

    body = human_body()
    joints = [*ARM, "root", "*_hip_*", "*_ankle_*"]
    for bad in ("yes", -0.1, 2.0):
        with pytest.raises(TaskError, match=r"pelvis"):
            parse_strategy(body, "right_hand", joints, [{"type": "reach"}, {"type": "feet"},
                                                        {"type": "balance", "pelvis": bad}])
    task = parse_strategy(body, "right_hand", joints, [{"type": "reach"}, {"type": "feet"},
                                                       {"type": "balance", "pelvis": 0.05}]).task("balance")
    assert task.pelvis and task.aside == 0.05


@pytest.mark.slow
def test_a_strategy_with_more_freedom_reaches_what_its_sub_strategy_reaches_directly():
    """ANSUR II man 27150's whole body, asked cold, reached 1 of the workstation's targets that his upper body
    reaches (its searches flex the hips into the abdomen's clearance to the thigh). ``direct`` asks each strategy again
    from the posture the ones before it found, where its cold search missed: the whole body then reaches every target
    the upper body does, each posture passing the check by Pinocchio."""
    from reach.answers.accommodation import _member
    from reach.building.config import load_config

    config = load_config(Path(__file__).resolve().parents[1] / "configs" / "demo.yaml")
    body = {"human": {"ansur": {"sex": "male", "subject": 27150}}}
    rows = list(csv.DictReader(open(Path(__file__).resolve().parents[1] / "configs/targets/workstation_right.csv")))
    points = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    names = ("right_arm", "right_upper_body", "right_whole_body")
    oracles, strategies = {}, []
    for name in names:
        spec = config.strategy(name).oracle
        params = {**spec.params, "jit": False, "body": body}
        oracles[name] = OracleSpec(spec.name, params).create()
        strategies.append((name, "right_hand", spec.name, params))
    cold = oracles["right_whole_body"].evaluate(Goals(points)).reachable
    found, refuted = _member(oracles, strategies, points, ["right_hand"] * len(points), True)
    by = {n: np.array([r["strategy"] == n or n in r["also"] for r in found]) for n in names}
    assert refuted == 0
    assert by["right_upper_body"].sum() > cold.sum()  # the cold search's miss, as measured
    assert np.all(by["right_whole_body"][by["right_upper_body"] | by["right_arm"]])


def test_a_target_an_earlier_strategy_reached_costs_the_next_no_solve():
    """The upper body is asked only for the workstation targets the arm's postures do not hold by its own check: the
    others are its too (its joints a superset, its other joints at the reference), each posture passing the upper
    body's Pinocchio check, with no search (the whole body and the crouch of a population's direct answers then
    solve only what the arm and the upper body missed)."""
    from reach.answers.accommodation import _member
    from reach.building.config import load_config

    config = load_config(Path(__file__).resolve().parents[1] / "configs" / "demo.yaml")
    rows = list(csv.DictReader(open(Path(__file__).resolve().parents[1] / "configs/targets/workstation_right.csv")))
    points = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    oracles, strategies = {}, []
    for name in ("right_arm", "right_upper_body"):
        spec = config.strategy(name).oracle
        params = {**spec.params, "jit": False}
        oracles[name] = OracleSpec(spec.name, params).create()
        strategies.append((name, "right_hand", spec.name, params))
    found, refuted = _member(oracles, strategies, points, ["right_hand"] * len(points), True)
    arm = np.array([r["strategy"] == "right_arm" for r in found])
    upper = np.array([r["strategy"] == "right_upper_body" or "right_upper_body" in r["also"] for r in found])
    assert refuted == 0 and 0 < arm.sum() < len(points)
    assert np.all(upper[arm])  # what the arm reaches, the upper body reaches
    assert oracles["right_upper_body"].stats["points"] == len(points) - arm.sum()  # ... without being asked
    assert upper.sum() > arm.sum()  # and it reaches more by its own search


def test_a_population_manifest_that_is_not_one_is_refused_in_one_line(tmp_path):
    """population.json as an attacker writes it: deeply nested, a member without a name, a weight of 10**400, of
    Infinity or 1e999, a name of 5,000 characters, a FIFO, a link to /dev/zero. Each is a TreeError naming the file
    (a traceback, a hang, an `internal` answer or memory without bound before); a sound one still reads."""
    import os

    from reach.building.population import read_manifest
    from reach.errors import TreeError

    def member(**change):
        return {"name": "a", "sex": "male", "weight": 1.0, "body": {}, "atlas": "a", **change}

    cases = {
        "nested": "[" * 100_000 + "]" * 100_000,
        "no name": json.dumps({"format": 1, "members": [{k: v for k, v in member().items() if k != "name"}]}),
        "huge int": '{"format": 1, "members": [{"name": "a", "sex": "male", "atlas": "a", "weight": 1' + "0" * 400
                    + "}]}",
        "Infinity": json.dumps({"format": 1, "members": [member(weight=float("inf"))]}),
        "1e999": '{"format": 1, "members": [{"name": "a", "sex": "male", "atlas": "a", "weight": 1e999}]}',
        "long name": json.dumps({"format": 1, "members": [member(name="x" * 5000)]}),
    }
    for why, text in cases.items():
        folder = tmp_path / why.replace(" ", "_")
        folder.mkdir()
        (folder / "population.json").write_text(text)
        with pytest.raises(TreeError, match="population.json") as err:
            read_manifest(folder)
        assert "\n" not in str(err.value) and len(str(err.value)) < 500, why
    fifo = tmp_path / "fifo"
    fifo.mkdir()
    os.mkfifo(fifo / "population.json")
    with pytest.raises(TreeError, match="not a regular file"):
        read_manifest(fifo)
    zero = tmp_path / "zero"
    zero.mkdir()
    (zero / "population.json").symlink_to("/dev/zero")
    with pytest.raises(TreeError, match="not a regular file"):
        read_manifest(zero)
    good = tmp_path / "good"
    good.mkdir()
    (good / "population.json").write_text(json.dumps({"format": 1, "members": [member(weight=2.5)]}))
    assert read_manifest(good)["members"][0]["weight"] == 2.5


def test_an_atlas_manifest_that_is_a_fifo_is_refused_not_waited_on(tmp_path):
    import os

    from reach.errors import StoreError
    from reach.maps.atlas import load_atlas

    (tmp_path / "atlas").mkdir()
    os.mkfifo(tmp_path / "atlas" / "manifest.json")
    with pytest.raises(StoreError, match="not a regular file"):
        load_atlas(tmp_path / "atlas")


def _on_body_targets() -> list[Target]:
    """Targets on each person's body: 0.45 m ahead of the right acromion (every adult reaches it with the arm
    forward), and 1.5 m ahead of it (no one does)."""
    return [Target("ahead", (0.45, 0.0, 0.0), "right_hand", "right_acromion"),
            Target("beyond", (1.5, 0.0, 0.0), "right_hand", "right_acromion")]


def test_a_target_on_the_body_lies_where_each_members_landmark_puts_it():
    """``relative_to``: each member gets the target where their own frame lies (checked with Pinocchio on the
    member's model), and reaches it as the member's oracle says at that point."""
    from reach.answers.evaluate import on_body

    config = parse_config(small({"ansur": {"n": 3, "sex": "mixed", "seed": 2}}), "pop", "pop")
    targets = _on_body_targets()
    result = direct(config, targets)
    assert [m["reached"] for m in result["by_member"]] == [[True, False]] * 3 and result["refuted_by_check"] == 0
    placed = []
    strategy = config.strategies[0]
    for member in members_of(config):
        body = member.body(config.raw.get("body"))
        oracle = OracleSpec(strategy.oracle.name, {**strategy.oracle.params, "body": body}).create()
        model = load_body(body).model
        data = model.createData()
        pin.framesForwardKinematics(model, data, load_body(body).q_ref)
        acromion = data.oMf[model.getFrameId("right_acromion")].translation
        points = on_body(targets, oracle, np.zeros((2, 3)))
        assert np.allclose(points, acromion + np.array([t.point for t in targets]), atol=1e-12)
        assert list(oracle.evaluate(points).reachable) == [True, False]
        placed.append(points[0])
    assert np.ptp(np.array(placed)[:, 2]) > 0.02  # the members' acromions are not at one height


def test_a_target_on_the_body_names_an_unknown_frame_and_placement_refuses_it(tmp_path):
    from reach.answers.evaluate import load_targets
    from reach.answers.place import Space, rank
    from reach.errors import InputError

    csv_path = tmp_path / "targets.csv"
    csv_path.write_text("name,x,y,z,effector,relative_to\nahead,0.45,0,0,right_hand,right_elbw\nfixed,0.4,-0.2,1.2,,\n")
    targets = load_targets(csv_path)
    assert [t.relative_to for t in targets] == ["right_elbw", None] and targets[1].effector is None
    config = parse_config(small({"ansur": {"n": 1, "sex": "female", "seed": 0}}), "pop", "pop")
    with pytest.raises(ConfigError, match=r"ahead\.relative_to.*no frame 'right_elbw'; frames are: .*right_elbow_rest"):
        direct(config, targets[:1])
    with pytest.raises(InputError, match="ahead is given on the body"):
        rank([None], targets, Space((0.0, 0.0), (0.0, 0.0)))  # type: ignore[list-item]


@pytest.mark.slow
def test_a_target_on_the_body_from_a_built_populations_atlases(built, tmp_path, capsys):
    """``reach evaluate`` of a built population: each member's atlas answers the target placed on its own body,
    as the members' oracles do directly."""
    config_path, out, _ = built
    csv_path = tmp_path / "on_body.csv"
    csv_path.write_text("name,x,y,z,effector,relative_to\n" + "".join(
        f"{t.name},{t.point[0]},{t.point[1]},{t.point[2]},{t.effector},{t.relative_to}\n" for t in _on_body_targets()))
    capsys.readouterr()
    assert main(["evaluate", str(out), "--targets", str(csv_path), "--json"]) == 0
    from_trees = json.loads(capsys.readouterr().out)
    assert [m["reached"] for m in from_trees["by_member"]] == [[True, False]] * 4
    config = parse_config(json.loads(config_path.read_text()), str(config_path))
    assert [m["reached"] for m in direct(config, _on_body_targets())["by_member"]] == [[True, False]] * 4


# Values a client or a file might hold where something else is expected; "RAW:" ones are JSON text that json.dumps
# cannot write (numbers past a double, non-standard constants, deep nesting).
WEIRD = [None, True, -1, 0, 1.5, 1e308, -1e308, 10**30, "", "x" * 5000, [], {}, [[[]]], [1, 2], {"a": 1}, "NaN",
         "RAW:1e999", "RAW:-Infinity", "RAW:NaN", "RAW:1" + "0" * 400, "RAW:" + "[" * 5000 + "]" * 5000]
CODES = {P.BAD_FRAMES, P.TOO_LARGE, P.BAD_JSON, P.BAD_REQUEST, P.UNKNOWN_OP, P.UNKNOWN_EFFECTOR, P.UNKNOWN_STRATEGY,
         P.FORBIDDEN, P.UNREACHABLE, P.NO_MOTION, P.TIMEOUT, P.BUSY}


def _with(doc: dict, path: list, value: object) -> bytes:
    """``doc`` as JSON with the key at ``path`` set to ``value`` (a WEIRD one), or removed for the value ``...``."""
    doc = json.loads(json.dumps(doc))
    node = doc
    for key in path[:-1]:
        node = node[key]
    if value is ...:
        if isinstance(node, list):
            del node[path[-1]]
        else:
            node.pop(path[-1], None)
        return json.dumps(doc).encode()
    raw = isinstance(value, str) and value.startswith("RAW:")
    node[path[-1]] = "__RAW__" if raw else value
    text = json.dumps(doc)
    return (text.replace('"__RAW__"', value[4:]) if raw else text).encode()  # type: ignore[index]


def test_fuzzed_requests_to_a_population_server_get_a_documented_code_and_never_internal(built):
    from reach.serving.server import Server

    _, out, _ = built
    doc = json.loads((out / "population.json").read_text())
    point = [0.4, -0.3, 1.1]
    templates = {
        "query": {"op": "query", "effector": "right_hand", "goal": point},
        "motion": {"op": "motion", "effector": "right_hand", "goal": point},
        "place": {"op": "place", "targets": [{"point": point, "effector": "right_hand"}], "x": [0, 0.1],
                  "y": [0, 0.1], "yaw": [0, 0]},
        "accommodation": {"op": "accommodation", "effector": "right_hand", "goals": [point]},
    }
    rng = np.random.default_rng(63)
    server = Server(out / doc["members"][0]["atlas"], "tcp://127.0.0.1:*", None, population=out, budget=0.05)
    codes: dict[str, int] = {}
    try:
        for _ in range(400):
            op = str(rng.choice(P.OPS))
            template = templates.get(op, {"op": op})
            keys = ["id", "op", "unknown", *template, *(f.name for f in P.OPERATIONS[op].fields)]
            path: list = [str(rng.choice(keys))]
            if path[0] in ("goal", "goals", "targets", "x") and path[0] in template and rng.random() < 0.5:
                path.append(0)  # inside a list
            value = ... if rng.random() < 0.15 else WEIRD[int(rng.integers(len(WEIRD)))]
            reply = json.loads(server.respond(_with(template, path, value)))  # type: ignore[arg-type]
            code = "ok" if reply["ok"] else reply["error"]["code"]
            assert code == "ok" or code in CODES, (op, path, value, reply)
            codes[code] = codes.get(code, 0) + 1
        assert json.loads(server.respond(b'{"op": "health"}'))["ok"]  # type: ignore[arg-type]
    finally:
        server.close()
    assert codes.get(P.BAD_REQUEST, 0) > 100 and codes.get("ok", 0) > 10, codes  # both kinds drawn


def test_fuzzed_population_folders_are_refused_in_one_line_naming_the_file(built, tmp_path):
    from reach.answers.accommodation import load_members
    from reach.errors import ReachError

    _, out, _ = built
    doc = json.loads((out / "population.json").read_text())
    rng = np.random.default_rng(64)
    refused = 0
    for k in range(80):
        folder = tmp_path / f"p{k}"
        folder.mkdir()
        for m in doc["members"]:
            (folder / m["atlas"]).symlink_to(out / m["atlas"])
        where = rng.choice(["top", "member"])
        path: list = ([str(rng.choice(["format", "members", "name", "population"]))] if where == "top" else
                      ["members", int(rng.integers(len(doc["members"]))),
                       str(rng.choice(["name", "atlas", "weight", "sex"]))])
        value = ... if rng.random() < 0.2 else WEIRD[int(rng.integers(len(WEIRD)))]
        (folder / "population.json").write_bytes(_with(doc, path, value))
        try:
            atlases, weights, names = load_members(folder)
        except ReachError as exc:
            refused += 1
            message = str(exc)
            assert "\n" not in message and len(message) < 600 and "population.json" in message, (path, value, message)
            continue
        # taken: a valid manifest (a value that does not matter, or one that is valid)
        assert len(atlases) == len(doc["members"]) and np.isclose(weights.sum(), 1.0) and all(names), (path, value)
    assert refused > 40
