"""The reach command line, end to end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import reach
from reach.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_every_name_in_all_exists():
    for name in reach.__all__:
        assert getattr(reach, name) is not None


@pytest.mark.parametrize("command", [[], ["build"], ["info"], ["query"], ["model"], ["serve"]])
def test_help_on_every_command(command):
    out = subprocess.run([sys.executable, "-m", "reach.tools.cli", *command, "--help"], capture_output=True,
                         text=True, check=True)
    assert "usage: reach" in out.stdout


@pytest.fixture(scope="module")
def figure2_atlas(tmp_path_factory):
    out = tmp_path_factory.mktemp("atlas") / "fig2"
    assert main(["build", str(ROOT / "configs" / "paper_figure2.yaml"), "-o", str(out), "--quiet"]) == 0
    return out


def test_build_writes_trees_and_manifest(figure2_atlas):
    assert (figure2_atlas / "manifest.json").is_file()
    assert (figure2_atlas / "circle.npz").is_file()
    manifest = json.loads((figure2_atlas / "manifest.json").read_text())
    assert manifest["strategies"][0]["name"] == "circle" and "numpy" in manifest["versions"]


def test_info_json_has_the_documented_keys(figure2_atlas, capsys):
    assert main(["info", str(figure2_atlas), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    s = info["strategies"]["circle"]
    assert s["nodes"]["3"] == {"outer": 4, "inner": 16, "parent": 0, "final": 28}
    assert s["oracle_calls"] == 73
    assert s["lattice_vertices"] == 9**2
    assert s["volume"]["inner"] <= 3.141592653589793 <= s["volume"]["inner"] + s["volume"]["boundary"]
    assert s["extent"] == {"min": [-1.0, -1.0], "max": [1.0, 1.0]}
    assert s["reachable_extent"] == {"min": [-1.0, -1.0], "max": [1.0, 1.0]}
    # the inscribed circle touches each face at one lattice vertex
    assert s["on_faces"] == {"x-": 1, "x+": 1, "y-": 1, "y+": 1}


def test_info_warns_when_reachable_vertices_lie_on_the_box(tmp_path, capsys):
    raw = {"box": {"min": [-1, -1, 0], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 3},
           "oracle": {"name": "sphere", "params": {"radius": 0.9}},
           "strategies": [{"name": "ball", "effector": "point"}]}
    config = tmp_path / "cut.json"  # JSON is YAML
    config.write_text(json.dumps(raw))
    assert main(["build", str(config), "-o", str(tmp_path / "cut"), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp_path / "cut"), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["strategies"]["ball"]
    # At most the lattice vertices on z = 0 inside the ball (9 x 9 at depth 3, 0.25 m apart): the tree asks the oracle
    # of some only.
    g = np.linspace(-1, 1, 9)
    x, y = np.meshgrid(g, g)
    assert list(s["on_faces"]) == ["z-"] and 0 < s["on_faces"]["z-"] <= int(np.count_nonzero(x**2 + y**2 <= 0.81))
    assert s["reachable_extent"]["min"][2] == 0.0
    assert main(["info", str(tmp_path / "cut")]) == 0
    assert "warning: reachable vertices lie on faces of the box" in capsys.readouterr().out
    # The build said it, the manifest keeps it, the report flags it, and --strict fails (keeping the atlas).
    manifest = json.loads((tmp_path / "cut" / "manifest.json").read_text())
    assert manifest["warnings"]["faces"] == [{"strategy": "ball", "faces": s["on_faces"]}]
    assert main(["report", str(tmp_path / "cut"), "-o", str(tmp_path / "report"), "--level", "2"]) == 0
    out = capsys.readouterr()
    assert ("the box cuts these volumes" in (tmp_path / "report" / "report.md").read_text()
            and "warning: ball:" in out.err)
    assert json.loads((tmp_path / "report"
                       / "report.json").read_text())["strategies"]["ball"]["on_faces"] == s["on_faces"]
    assert main(["build", str(config), "-o", str(tmp_path / "strict"), "--quiet", "--strict"]) == 2
    out = capsys.readouterr()
    assert ("warning: ball: reachable vertices lie on faces of the box" in out.out
            and "--strict makes that an error" in out.err)
    assert (tmp_path / "strict" / "ball.npz").is_file()
    raw["box"] = {"min": [-1, -1, -1], "max": [1, 1, 1]}
    config.write_text(json.dumps(raw))
    assert main(["build", str(config), "-o", str(tmp_path / "whole"), "--quiet", "--strict"]) == 0


def test_query_json(figure2_atlas, capsys):
    assert main(["query", str(figure2_atlas), "0.1", "0.2", "--json"]) == 0
    answer = json.loads(capsys.readouterr().out)["answers"][0]
    assert answer["strategy"] == "circle" and answer["reachable"] is True
    assert main(["query", str(figure2_atlas), "0.99", "0.99", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["answers"][0]["reachable"] is False


def test_query_text(figure2_atlas, capsys):
    assert main(["query", str(figure2_atlas), "0", "0"]) == 0
    assert "reachable with strategy circle" in capsys.readouterr().out


def test_errors_exit_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("box: {min: [0, 0], max: [1, 1]}\ndepth: {min: 3, max: 1}\noracle: {name: circle}\nstrategies: "
                   "[{name: a}]\n")
    assert main(["build", str(bad), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("reach: error: ") and "bad.yaml: depth.min" in err
    assert main(["info", str(tmp_path / "absent")]) == 2
    assert "no such atlas folder" in capsys.readouterr().err
    assert main(["query", str(tmp_path / "absent"), "0", "0"]) == 2
    assert main(["query", str(tmp_path / "absent"), "zero", "0"]) == 2
    assert "goal: coordinates must be numbers" in capsys.readouterr().err


def test_unknown_effector_is_an_error(figure2_atlas, capsys):
    assert main(["query", str(figure2_atlas), "0", "0", "--effector", "left_hand"]) == 2
    assert "unknown effector 'left_hand'; this atlas has point" in capsys.readouterr().err


def test_query_from_must_be_a_json_object(figure2_atlas, capsys):
    assert main(["query", str(figure2_atlas), "0.1", "0.1", "--from", "[1, 2]"]) == 2
    assert "--from: expected a JSON object of joint name -> number" in capsys.readouterr().err
    assert main(["query", str(figure2_atlas), "0.1", "0.1", "--from", "{not json"]) == 2
    assert "--from: expected a JSON object" in capsys.readouterr().err


def test_json_output_never_holds_nan():
    import json as _json

    from reach.serving.protocol import finite

    data = {"a": float("nan"), "b": [1.0, float("inf"), {"c": -float("inf")}], "d": "x", "e": 2}
    text = _json.dumps(finite(data), allow_nan=False)  # raises on any NaN left
    assert _json.loads(text) == {"a": None, "b": [1.0, None, {"c": None}], "d": "x", "e": 2}


def test_serve_refuses_a_negative_worker_count(tmp_path, capsys):
    from reach.tools.cli import main

    assert main(["serve", str(tmp_path), "--workers", "-1"]) == 2
    assert "--workers: expected 0 or more worker processes, got -1" in capsys.readouterr().err


def test_an_error_naming_a_huge_path_stays_one_short_line(tmp_path, capsys):
    """A 40 KB mesh path was printed whole in the error (and a strategy name of 250 characters was a
    traceback: refused by its key now, tests/test_config.py)."""
    config = tmp_path / "c.yaml"
    config.write_text("name: t\nbody: {urdf: " + "a" * 40_000 + ".urdf}\nbox: auto\ndepth: {min: 1, max: 2}\n"
                      "strategies: [{name: a, effector: b, joints: [x]}]\n")
    assert main(["build", str(config), "-o", str(tmp_path / "out")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("reach: error: ")]
    assert len(err) == 1 and len(err[0]) < 1000 and "characters)..." in err[0]


@pytest.mark.slow
def test_the_wheel_is_named_reach_volumes_and_carries_the_command_and_the_survey(tmp_path):
    """PyPI's "reach" is a word-embedding library; the distribution is reach-volumes, the import and
    the command reach. The wheel built from the clone holds the command's entry point and the ANSUR II data."""
    import zipfile

    root = Path(__file__).resolve().parent.parent
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path),
                    str(root)], check=True, capture_output=True)
    wheel = next(tmp_path.glob("reach_volumes-*.whl"))
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        info = next(n for n in names if n.endswith(".dist-info/METADATA"))
        assert "Name: reach-volumes" in zf.read(info).decode()
        entry = zf.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "reach = reach.tools.cli:main" in entry
    assert "oracles/bodies/data/ansur2.csv.gz" in names and "reach/serving/cells.py" in names


def test_the_command_line_starts_without_the_scientific_stack():
    """`reach --help` took 0.4-1.2 s, importing the selector (and scipy, pinocchio, casadi) for
    three defaults. The parser's defaults come from reach.answers.defaults; a command imports what it needs when it
    runs. Counted in a fresh interpreter: no module of those packages is loaded by the parser."""
    heavy = "{'scipy', 'pinocchio', 'casadi', 'zmq', 'matplotlib'}"
    code = ("import sys; from reach.tools.cli import make_parser; make_parser(); "
            f"print(sorted({{m.split('.')[0] for m in sys.modules}} & {heavy}))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.strip()
    assert out == "[]"


def test_query_answers_a_file_of_goals_one_json_line_each(figure2_atlas, tmp_path, capsys, monkeypatch):
    """A script's hundred queries took a process each. ``--goals FILE`` (or ``-``) answers every
    line in one process, one JSON answer a line, in order; a header line is skipped, a bad line named."""
    import io

    goals = tmp_path / "goals.csv"
    goals.write_text("x,y\n0.1, 0.1\n# a comment\n5 5\n0.0,0.2\n")
    assert main(["query", "--goals", str(goals), str(figure2_atlas)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [a["goal"] for a in lines] == [[0.1, 0.1], [5.0, 5.0], [0.0, 0.2]]
    assert [a["reachable"] for a in lines] == [True, False, True]
    monkeypatch.setattr("sys.stdin", io.StringIO("0.1 0.1\n"))
    assert main(["query", "--goals", "-", str(figure2_atlas)]) == 0
    assert json.loads(capsys.readouterr().out)["goal"] == [0.1, 0.1]
    goals.write_text("0.1, 0.1\n0.2, oops\n")
    assert main(["query", "--goals", str(goals), str(figure2_atlas)]) == 2
    err = capsys.readouterr().err
    assert "--goals: " in err and "goals.csv line 2: expected X Y [Z] in metres, got '0.2, oops'" in err


def test_evaluate_of_a_config_without_direct_says_what_to_do(capsys):
    """A config given to ``reach evaluate`` where an atlas folder belongs: the error names --direct and the build."""
    config = str(Path(__file__).resolve().parents[1] / "configs" / "population.yaml")
    assert main(["evaluate", config, "--targets", "configs/targets/workstation_right.csv"]) == 2
    err = capsys.readouterr().err
    assert "is a config, not an atlas folder: give --direct" in err and f"reach build {config}" in err


def test_motion_usage_names_one_atlas_and_one_goal(capsys):
    with pytest.raises(SystemExit):
        main(["motion", "--help"])
    out = capsys.readouterr().out
    assert "ATLAS X Y Z\n" in out and "--connect ADDR X Y Z" in out and "[ATLAS X Y Z ...]" not in out


def test_a_mesh_path_too_long_for_the_system_is_a_one_line_error(tmp_path, capsys):
    """A URDF's mesh path of 40,000 characters raised OSError (File name too long) from the file system's lookup."""
    urdf = tmp_path / "long.urdf"
    urdf.write_text('<?xml version="1.0"?><robot name="r"><link name="base"><collision><geometry><mesh filename="'
                    + "m" * 40_000 + '.stl"/></geometry></collision></link></robot>')
    assert main(["model", str(urdf)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("reach: error: ")]
    assert len(err) == 1 and len(err[0]) < 1000 and "not found" in err[0]


def test_a_urdf_nested_too_deeply_is_a_one_line_error(tmp_path, capsys):
    """urdfdom's parser printed three lines of its own for 100,000 nested elements; refused before it sees them."""
    urdf = tmp_path / "deep.urdf"
    urdf.write_text('<robot name="r">' + "<a>" * 100_000 + "</a>" * 100_000 + "</robot>")
    assert main(["model", str(urdf)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "nested over 100 levels" in err[0] and str(urdf) in err[0]
