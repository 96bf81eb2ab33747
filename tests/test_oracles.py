"""Oracle registry and analytic shapes."""

from __future__ import annotations

from importlib.metadata import EntryPoint

import numpy as np
import pytest

import oracles.registry as registry
from oracles.protocol import OracleSpec, Verdicts
from oracles.shapes import BoxOracle, Torus
from reach.errors import OracleError


def ring_factory(radius: float = 1.0):
    """An entry-point oracle defined outside the built-in list."""
    return Torus(major=radius, minor=radius / 4)


def test_builtins_are_listed():
    names = registry.available()
    for n in ("circle", "sphere", "box", "torus", "union", "intersection", "difference"):
        assert n in names


def test_unknown_oracle_lists_the_known_ones():
    with pytest.raises(OracleError, match=r"unknown oracle 'nope'; available: .*sphere"):
        OracleSpec("nope").create()


def test_bad_params_are_named():
    with pytest.raises(OracleError, match=r"oracle 'sphere': bad parameters \['colour'\]"):
        OracleSpec("sphere", {"colour": "red"}).create()


def test_entry_points_extend_the_registry(monkeypatch):
    ep = EntryPoint(name="test-ring", value="tests.test_oracles:ring_factory", group=registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: [ep] if group == registry.ENTRY_POINT_GROUP else [])
    assert "test-ring" in registry.available()
    oracle = OracleSpec("test-ring", {"radius": 0.8}).create()
    assert isinstance(oracle, Torus) and oracle.major == 0.8


def test_box_oracle_verdicts_and_residuals():
    box = BoxOracle([0, 0, 0], [1, 2, 3])
    v = box.evaluate(np.array([[0.5, 1, 1], [2, 1, 1], [1, 2, 3], [-3, -4, 1]]))
    assert v.reachable.tolist() == [True, False, True, False]
    assert np.allclose(v.residual, [0, 1, 0, 5])


def test_combinations():
    spec = {"oracles": [{"name": "sphere", "params": {"radius": 1.0}}, {"name": "sphere", "params": {"radius": 0.5}}]}
    pts = np.array([[0.0, 0, 0], [0.75, 0, 0], [2.0, 0, 0]])
    assert OracleSpec("union", spec).create().evaluate(pts).reachable.tolist() == [True, True, False]
    assert OracleSpec("intersection", spec).create().evaluate(pts).reachable.tolist() == [True, False, False]
    shell = OracleSpec("difference", spec).create().evaluate(pts)
    assert shell.reachable.tolist() == [False, True, False]
    assert shell.residual[1] == 0.0


def test_combination_refuses_mixed_dimensions():
    spec = {"oracles": [{"name": "sphere"}, {"name": "circle"}]}
    with pytest.raises(OracleError, match="different dimensions"):
        OracleSpec("union", spec).create()


def test_torus_rejects_minor_above_major_and_points_of_wrong_shape():
    with pytest.raises(OracleError, match="minor radius"):
        Torus(major=0.2, minor=0.5)
    with pytest.raises(OracleError, match=r"shape \(N, 3\)"):
        Torus().evaluate(np.zeros((3, 2)))


def test_verdicts_concatenate():
    a = Verdicts(np.array([True]), np.array([0.0]), np.array([[1.0, 2.0]]))
    b = Verdicts(np.array([False]), np.array([0.5]), np.array([[3.0, 4.0]]))
    c = Verdicts.concatenate([a, b])
    assert c.reachable.tolist() == [True, False] and c.posture.shape == (2, 2)


def test_errors_live_in_oracles_carry_their_fields_and_reach_re_exports_them():
    import oracles.errors
    import reach.errors
    from oracles.bodies.body import human_body

    for name in ("ReachError", "OracleError", "ModelError", "TaskError"):
        assert getattr(reach.errors, name) is getattr(oracles.errors, name)
    with pytest.raises(reach.errors.ModelError, match="no frame 'wing'") as err:
        human_body().frame_id("wing")
    assert err.value.name == "wing" and err.value.source and err.value.reason.startswith("no frame 'wing'")
    with pytest.raises(reach.errors.OracleError) as bad:
        OracleSpec("casadi-ik",
                   {"body": {"human": {}}, "effector": "right_hand", "joints": ["right_elbow_flexion"],
                    "solver": "snopt"}).create()
    assert (bad.value.oracle, bad.value.key) == ("casadi-ik", "solver") and str(bad.value).startswith("casadi-ik: "
        "solver must be one of")


def test_nothing_in_oracles_imports_reach():
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "oracles"
    offenders = [str(p) for p in root.rglob("*.py")
                 if re.search(r"^\s*(from|import) reach\b", p.read_text(), flags=re.M)]
    assert offenders == []
