"""Reports, mesh export and layout evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reach.answers.evaluate import evaluate, load_targets
from reach.building.atlas import build_atlas
from reach.building.config import load_config, parse_config
from reach.errors import ConfigError
from reach.tools.cli import main
from reach.tools.export import mesh

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def balls(tmp_path_factory):
    data = {
        "name": "balls", "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 2, "max": 5},
        "oracle": {"name": "sphere", "params": {"radius": 0.8}},
        "strategies": [
            {"name": "small", "effector": "point", "priority": 1,
             "oracle": {"params": {"radius": 0.4, "center": [0.2, 0, 0]}}},
            {"name": "large", "effector": "point", "priority": 2},
        ],
    }
    return build_atlas(parse_config(data, "balls", "balls"), tmp_path_factory.mktemp("r") / "balls")


def test_report_tables_and_figures(balls, tmp_path, capsys):
    assert main(["report", str(balls.path), "-o", str(tmp_path / "rep"), "--level", "3"]) == 0
    data = json.loads((tmp_path / "rep" / "report.json").read_text())
    small, large = data["strategies"]["small"], data["strategies"]["large"]
    assert small["volume_inner"] <= 4 / 3 * np.pi * 0.4**3 <= small["volume_inner"] + small["volume_boundary"]
    assert large["highest"] == pytest.approx(0.8, abs=0.07) and large["lowest"] == pytest.approx(-0.8, abs=0.07)
    assert small["forward"] == pytest.approx(0.6, abs=0.07)
    pair = data["pairs"][0]
    # The small ball lies inside the large one: nothing of it is outside.
    assert pair["a_minus_b"] == 0.0 and pair["intersection"] == pytest.approx(small["volume_inner"], rel=0.01)
    for name in ("figure8.png", "figure11.png", "slices.png", "strategy_small.png", "strategy_large.png"):
        png = tmp_path / "rep" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    assert "| small | point | 1 |" in capsys.readouterr().out


def test_exported_mesh_is_closed_and_has_the_sphere_volume(balls, tmp_path):
    assert main(["export", str(balls.path), "large", "-o", str(tmp_path / "large.stl")]) == 0
    m = trimesh.load(tmp_path / "large.stl")
    assert m.is_watertight
    assert m.volume == pytest.approx(4 / 3 * np.pi * 0.8**3, rel=0.03)
    verts, _ = mesh(balls.trees["large"])
    assert np.abs(np.linalg.norm(verts, axis=1) - 0.8).max() < 0.07  # within a cell of the sphere
    assert main(["export", str(balls.path), "large", "-o", str(tmp_path / "large.obj")]) == 2


def test_evaluate_population_table(balls, tmp_path, capsys):
    targets = tmp_path / "t.csv"
    targets.write_text("name,x,y,z\ncentre,0.2,0,0\nrim,0.7,0,0\noutside,0.95,0.9,0\n")
    assert main(["evaluate", str(balls.path), str(balls.path), "--targets", str(targets)]) == 0
    out = capsys.readouterr().out
    assert "centre" in out and "small" in out and "reachable" in out and "2/3" in out
    result = evaluate([balls], load_targets(targets))
    rows = {r["target"]: r for r in result["atlases"][0]["rows"]}
    assert rows["centre"]["strategy"] == "small" and rows["centre"]["also"] == ["large"]
    assert rows["rim"]["strategy"] == "large" and rows["outside"]["strategy"] is None
    assert result["atlases"][0]["summary"]["by_strategy"] == {"small": 1, "large": 1, "none": 1}


def test_bad_targets_are_named(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("name,x,y\na,1,2\n")
    with pytest.raises(ConfigError, match="expected the columns name, x, y, z"):
        load_targets(bad)
    bad.write_text("name,x,y,z\na,1,two,3\n")
    with pytest.raises(ConfigError, match="row 2: x, y and z must be numbers"):
        load_targets(bad)


def test_config_base_inheritance_and_relative_urdf():
    default = load_config(ROOT / "configs" / "default.yaml")
    demo = load_config(ROOT / "configs" / "demo.yaml")
    assert default.name == "default" and default.d_max == 7 and demo.d_max == 5
    assert [s.name for s in default.strategies] == [s.name for s in demo.strategies]
    female = load_config(ROOT / "configs" / "demo_female_p05.yaml")
    assert female.strategies[0].oracle.params["body"] == {"human": {"sex": "female", "percentile": 5}}
    ur5 = load_config(ROOT / "configs" / "ur5.yaml")
    assert Path(ur5.strategies[0].oracle.params["body"]["urdf"]).is_file()


def test_unknown_strategy_names_are_errors(balls, tmp_path, capsys):
    assert main(["report", str(balls.path), "-o", str(tmp_path / "r"), "--strategies", "small,tiny"]) == 2
    assert "unknown strategy 'tiny'; the atlas has" in capsys.readouterr().err
    assert main(["export", str(balls.path), "tiny", "-o", str(tmp_path / "t.stl")]) == 2
    assert "unknown strategy 'tiny'" in capsys.readouterr().err
    assert main(["audit", str(balls.path), "--strategies", "tiny"]) == 2
    assert "unknown strategy 'tiny'; the atlas has" in capsys.readouterr().err


def test_targets_without_an_effector_are_refused(tmp_path):
    from reach.maps.atlas import Atlas

    two = Atlas(Path("two"), {"strategies": [{"name": "a", "effector": "left", "priority": 1, "file": "a"},
                                              {"name": "b", "effector": "right", "priority": 1, "file": "b"}]}, {})
    targets = tmp_path / "t.csv"
    targets.write_text("name,x,y,z\nknob,0,0,0\n")
    with pytest.raises(ConfigError, match="no effector: give an effector column or --effector"):
        evaluate([two], load_targets(targets))


@pytest.mark.parametrize(
    ("doc", "key", "message"),
    [
        ("base: 3\n", "base", "expected the path of a config to extend"),
        ("base: loop.yaml\n", "base", "extends itself"),
    ],
)
def test_config_base_errors(tmp_path, doc, key, message):
    path = tmp_path / "loop.yaml"
    path.write_text(doc)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert info.value.key == key


def test_mirror_config_errors():
    base = {"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 2}, "oracle": {"name": "sphere"}}
    with pytest.raises(ConfigError, match=r"strategies\[0\]\.mirror_of: expected the name of another strategy"):
        parse_config({**base, "strategies": [{"name": "a", "mirror_of": "a"}]}, "m", "m")
    lopsided = {**base, "box": {"min": [-1, -0.5, -1], "max": [1, 1, 1]}}
    with pytest.raises(ConfigError, match="mirroring needs a box symmetric about y = 0"):
        parse_config({**lopsided, "strategies": [{"name": "a"}, {"name": "b", "mirror_of": "a"}]}, "m", "m")
    with pytest.raises(ConfigError, match=r"box\.auto\.margin: expected a number of metres"):
        parse_config({**base, "box": {"auto": {"margin": "wide"}}, "strategies": [{"name": "a"}]}, "m", "m")


def test_figure11_overlays_one_effectors_strategies_by_priority():
    from types import SimpleNamespace

    from reach.tools.report import overlay_names

    def tree(effector, priority):
        return SimpleNamespace(meta={"effector": effector, "priority": priority})

    # Atlas order is by priority, so the two arms come first; the overlay
    # nests one hand's arm, upper body and whole body, as the paper's Figure 11.
    trees = {"left_arm": tree("left_hand", 1), "right_arm": tree("right_hand", 1), "left_upper": tree("left_hand", 2),
             "right_upper": tree("right_hand", 2), "right_whole": tree("right_hand", 3),
             "left_whole": tree("left_hand", 3), "left_crouch": tree("left_hand", 4)}
    assert overlay_names(trees) == ["left_arm", "left_upper", "left_whole"]
    assert overlay_names({"a": tree("p", 1), "b": tree("p", 1)}) == ["a"]
