"""Configuration validation: every error names the file and the key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from reach.building.config import load_config, parse_config
from reach.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
GOOD = {
    "name": "t", "box": {"min": [-1, -1, -1], "max": [1, 1, 1]},
    "depth": {"min": 1, "max": 4}, "oracle": {"name": "sphere", "params": {"radius": 0.5}},
    "strategies": [{"name": "a", "effector": "point"}],
}


def write(tmp_path, data, name="c.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


def mutate(**changes):
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    for dotted, value in changes.items():
        *parents, last = dotted.split("__")
        node = data
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        if value is ...:
            del node[last]
        else:
            node[last] = value
    return data


@pytest.mark.parametrize("name", ["sphere.yaml", "paper_figure2.yaml"])
def test_shipped_configs_load(name):
    config = load_config(ROOT / "configs" / name)
    assert config.strategies and config.d_min <= config.d_max


def test_good_config_and_priority_order(tmp_path):
    data = mutate(strategies=[{"name": "late", "priority": 5},
                              {"name": "early", "priority": 1, "oracle": {"params": {"radius": 0.2}}}])
    config = load_config(write(tmp_path, data))
    assert [s.name for s in config.strategies] == ["early", "late"]
    assert config.strategies[0].oracle.params == {"radius": 0.2}
    assert config.strategies[1].oracle.params == {"radius": 0.5}


@pytest.mark.parametrize(
    ("changes", "key", "message"),
    [
        ({"colour": "red"}, "colour", "unknown key"),
        ({"depth__max": "seven"}, "depth.max", "expected an integer"),
        ({"depth__min": 5, "depth__max": 3}, "depth.min", r"D_min \(5\) must not exceed D_max \(3\)"),
        ({"depth__max": 40}, "depth.max", r"in \[0, 20\]"),
        ({"box__max": [1, -1, 1]}, "box", "empty"),
        ({"box__max": [1, 1]}, "box", "2 or 3 coordinates"),
        ({"box__min": "low"}, "box.min", "list of numbers"),
        ({"oracle__name": "teapot"}, "strategies[0].oracle", "unknown oracle 'teapot'"),
        ({"oracle__params": {"radius": -1}}, "strategies[0].oracle", "radius must be a positive number"),
        ({"oracle__params": {"radius": "big"}}, "strategies[0].oracle", "radius must be a positive number \\[m\\], "
            "got 'big'"),
        ({"oracle__params": {"center": ["a", 0, 0]}}, "strategies[0].oracle", "center must be a list of finite "
            "numbers, got"),
        ({"oracle__name": "circle", "oracle__params": {}}, "box", "box is 3-D but strategy 'a' uses a 2-D oracle"),
        ({"strategies": []}, "strategies", "non-empty list"),
        ({"strategies": [{"name": "a"}, {"name": "a"}]}, "strategies[1].name", "duplicate"),
        ({"strategies": [{"name": "../x"}]}, "strategies[0].name", "names a file"),
        ({"name": "../../../escaped"}, "name", "names the folder out/<name>"),  # it wrote outside out/
        ({"name": "a/b"}, "name", "names the folder out/<name>"),
        ({"strategies": [{"name": "a", "speed": 3}]}, "strategies[0].speed", "unknown key"),
        ({"box": ...}, "box", "required key is missing"),
        ({"base": "missing.yaml"}, "base", "missing.yaml: no such config to extend"),  # named the file only
        ({"strategies": [{"name": "s" * 250}]}, "strategies[0].name", "at most 100 characters"),  # was a traceback
        ({"strategies": [{"name": "a", "ranges": {"x": [0, 1]}}]}, "strategies[0].ranges", "need a body strategy"),
    ],
)
def test_errors_name_file_and_key(tmp_path, changes, key, message):
    path = write(tmp_path, mutate(**changes))
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert info.value.key == key
    assert str(path) in str(info.value) and key in str(info.value)


def test_a_config_that_is_not_utf8_is_named(tmp_path):
    path = tmp_path / "latin.yaml"
    path.write_bytes("name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin\.yaml.*not UTF-8 text"):  # a traceback
        load_config(path)


def test_not_yaml_and_not_a_mapping(tmp_path):
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(write(tmp_path, "box: [unclosed"))
    with pytest.raises(ConfigError, match="expected a mapping, got list"):
        load_config(write(tmp_path, "- 1\n- 2\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.yaml")


def test_box_auto_is_derived_from_the_body():
    data = {
        "body": {"human": {"sex": "male", "percentile": 50}}, "box": {"auto": {"margin": 0.1}},
        "depth": {"min": 1, "max": 3}, "oracle": {"name": "casadi-ik"},
        "strategies": [{"name": "arm", "effector": "right_hand",
                        "joints": ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"]}],
    }
    config = parse_config(data, "auto", "auto")
    from oracles.bodies.body import human_body

    body = human_body()
    shoulder = body.frame_positions(names=["right_shoulder"])["right_shoulder"]
    arm = np.linalg.norm(body.frame_positions(names=["right_hand"])["right_hand"] - shoulder)
    bound = config.strategies[0].oracle.create().reach_bound()[1]
    assert arm <= bound <= arm + 0.03  # the chain's stretched length, about the shoulder
    # The ball (plus the margin) is the limit B0 may grow to; B0 itself holds what the probes reached, within it.
    limit = config.limit
    assert (np.allclose(limit.lo, shoulder - bound - 0.1, atol=1e-3)
            and np.allclose(limit.hi, shoulder + bound + 0.1, atol=1e-3))
    lo, hi = config.strategies[0].oracle.create().reach_extent()
    assert (np.all(limit.lo <= config.box.lo) and np.all(config.box.lo <= lo) and np.all(hi <= config.box.hi)
            and np.all(config.box.hi <= limit.hi))
    data["box"] = "auto"
    data["oracle"] = {"name": "sphere"}
    data["strategies"] = [{"name": "ball", "effector": "point"}]
    del data["body"]
    with pytest.raises(ConfigError, match="box: auto needs body strategies"):
        parse_config(data, "auto", "auto")


def test_a_duplicate_key_is_refused_with_its_line(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text("name: a\nbox: auto\nname: b\n")
    with pytest.raises(ConfigError, match=r"dup\.yaml: name: duplicate key \(line 3\); give each key once"):
        load_config(path)


def test_nested_aliases_and_deep_nesting_are_refused_before_they_expand(tmp_path):
    """796 bytes of nested YAML aliases in ``name`` ran 53-120 s to 2.7 GB and a MemoryError
    traceback. The aliases are counted expanded before anything is built: one line naming the file, at once (the
    count stops past the bound: no expansion is made)."""
    levels = ["a: &a [" + ", ".join(['"lol"'] * 9) + "]"]
    for prev, name in zip("abcdefgh", "bcdefghi", strict=True):
        levels.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join([*levels, "name: *i"]) + "\n")
    with pytest.raises(ConfigError, match=r"bomb\.yaml: holds over 200,000 values with its aliases"):
        load_config(bomb)
    deep = tmp_path / "deep.yaml"
    deep.write_text("[" * 5000 + "]" * 5000)
    with pytest.raises(ConfigError, match=r"deep\.yaml: nested too deeply"):
        load_config(deep)
    # A few aliases, as configs use them for shared task lists, still load.
    assert load_config(Path(__file__).parent.parent / "configs" / "demo.yaml").strategies


def test_a_human_dimension_that_is_not_a_number_names_its_key(tmp_path):
    """``stature: "1.7"`` named strategies[0].oracle."""
    path = tmp_path / "h.yaml"
    path.write_text('name: h\nbody: {human: {sex: male, stature: "1.7"}}\nbox: auto\ndepth: {min: 1, max: 2}\n'
                    'strategies: [{name: a, effector: right_hand, joints: ["right_elbow_*"]}]\n')
    with pytest.raises(ConfigError, match=r"body\.human\.stature: expected a number in m, got '1\.7'"):
        load_config(path)


def test_a_tab_gives_one_line_naming_the_place(tmp_path):
    path = tmp_path / "tab.yaml"
    path.write_text("name: a\nbox:\n\tmin: [0, 0, 0]\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    message = str(err.value)
    assert "\n" not in message and "at line 3, column 1 (YAML indents with spaces, not tabs)" in message


def test_a_bodys_oracle_defaults_to_casadi_ik():
    """A URDF config without `oracle:` was refused ("required key is missing")."""
    from reach.building.documents import read_yaml

    path = Path(__file__).resolve().parents[1] / "configs" / "examples" / "arm7_table.yaml"
    data = read_yaml(path)
    data.pop("oracle", None)
    config = parse_config(data, str(path), "arm7_table")
    assert {config.strategy(s.name).oracle.name for s in config.strategies} == {"casadi-ik"}
    analytic = {"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 2},
                "strategies": [{"name": "a"}]}
    with pytest.raises(ConfigError, match="required key is missing") as info:  # an analytic atlas names its shape
        parse_config(analytic, "x", "x")
    assert info.value.key == "oracle"


def _knee_config(ranges):
    arm = ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"]
    legs = [*arm, "root", "*_hip_*", "*_knee_*", "*_ankle_*"]
    return {
        "body": {"human": {"sex": "male", "percentile": 50}}, "box": {"min": [-1, -1, 0], "max": [1, 1, 2]},
        "depth": {"min": 1, "max": 3}, "oracle": {"name": "casadi-ik"},
        "strategies": [{"name": "arm", "effector": "right_hand", "joints": arm},
                       {"name": "squat", "effector": "right_hand", "joints": legs, "ranges": ranges,
                        "tasks": [{"type": "reach"}, {"type": "feet", "heels": "rise"}]}],
    }


def test_a_strategy_takes_its_own_joint_ranges_over_the_body_s():
    from oracles.bodies.body import human_body

    config = parse_config(_knee_config({"*_knee_flexion": [0.0, 2.74]}), "ranges", "ranges")
    arm, squat = (s.oracle.create() for s in config.strategies)
    body = human_body()
    for oracle, top in ((arm, body), (squat, None)):
        model = oracle.body.model
        for side in ("right", "left"):
            j = model.joints[model.getJointId(f"{side}_knee_flexion")].idx_q
            want = 2.74 if top is None else body.model.upperPositionLimit[j]
            assert model.upperPositionLimit[j] == pytest.approx(want)
    assert body.model.upperPositionLimit[body.model.joints[body.model.getJointId("right_knee_flexion")].idx_q] < 2.4
    assert squat.model_hash != arm.model_hash  # a tree built with other ranges is another body's
    assert squat.spec.params["ranges"] == {"*_knee_flexion": [0.0, 2.74]}  # a worker rebuilds it with them
    assert squat.spec.create().body.model.upperPositionLimit.tolist() == squat.body.model.upperPositionLimit.tolist()


@pytest.mark.parametrize(
    ("ranges", "key", "message"),
    [
        ([0, 2.74], "strategies[1].ranges", "expected joint name or pattern -> \\[lower, upper\\]"),
        ({"*_kneee": [0, 2.74]}, "strategies[1].ranges.*_kneee", "no joint matches"),
        ({"*_knee_flexion": [2.74, 0]}, "strategies[1].ranges.*_knee_flexion", "expected \\[lower, upper\\]"),
    ],
)
def test_a_strategy_s_bad_ranges_are_named(ranges, key, message):
    with pytest.raises(ConfigError, match=message) as info:
        parse_config(_knee_config(ranges), "ranges", "ranges")
    assert info.value.key == key


def test_box_auto_is_derived_when_first_asked_for_not_when_the_config_is_read(monkeypatch):
    """Reading a config with ``box: auto`` solves nothing (the probe of the reach extent is IK): ``reach evaluate
    --direct`` never draws in the box. The box is derived on first use, once, and a grown box keeps its limit."""
    from reach.building import config as module

    calls = []
    derive = module.derive_box
    monkeypatch.setattr(module, "derive_box", lambda *a, **k: calls.append(1) or derive(*a, **k))
    raw = {"name": "arm", "body": {"urdf": str(ROOT / "configs" / "urdf" / "ur5.urdf")}, "box": "auto",
           "depth": {"min": 1, "max": 2},
           "strategies": [{"name": "flange", "effector": "ee_link", "joints": ["*_joint"],
                           "tasks": [{"type": "reach"}]}]}
    config = module.parse_config(raw)
    assert calls == [] and config.given_box is None
    box, limit = config.box, config.limit
    assert calls == [1] and config.box is box and np.all(limit.lo <= box.lo) and np.all(box.hi <= limit.hi)
    grown = config.with_box(module.Box(box.lo - 0.01, box.hi))
    assert grown.limit == limit and np.allclose(grown.box.lo, box.lo - 0.01) and calls == [1]


@pytest.mark.parametrize("where, digits", [("depth: {min: 1, max: %s}", 4301), ("seed: %s", 400)])
def test_a_whole_number_too_long_for_any_key_is_refused_naming_its_line(tmp_path, where, digits):
    """A YAML integer of 4,301 digits (past Python's own limit for reading one) or a 400-digit number (which no float
    holds) anywhere in a config: a ConfigError naming the file and line, not a traceback."""
    from reach.errors import ConfigError

    path = tmp_path / "big.yaml"
    path.write_text("name: big\nbox: {min: [-1, -1, -1], max: [1, 1, 1]}\n" + (where % ("9" * digits)) + "\n"
                    "strategies: []\n")
    with pytest.raises(ConfigError, match=rf"big.yaml: line 3: a whole number of {digits} digits"):
        load_config(path)
