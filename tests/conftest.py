"""Shared fixtures: small analytic trees, built once per session."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.protocol import Goals, OracleSpec, Verdicts
from reach.building.tree import build_tree
from reach.maps.box import Box
from reach.maps.tree import VATree


class CountingOracle:
    """Wraps an oracle and records every point it is asked about."""

    def __init__(self, inner):  # noqa: ANN001
        self.inner = inner
        self.dim = inner.dim
        self.posture_names = tuple(inner.posture_names)
        self.asked: list[np.ndarray] = []
        self.hints: list[np.ndarray | None] = []

    def evaluate(self, goals: Goals | np.ndarray) -> Verdicts:
        g = Goals.of(goals, self.dim)
        self.asked.append(np.array(g.points))
        self.hints.append(None if g.seeds is None else np.array(g.seeds))
        return self.inner.evaluate(g)

    @property
    def calls(self) -> int:
        return sum(len(a) for a in self.asked)


@pytest.fixture
def counting():
    return CountingOracle


@pytest.fixture(scope="session")
def unit_sphere_tree() -> VATree:
    return build_tree(OracleSpec("sphere", {"radius": 1.0}), Box([-1, -1, -1], [1, 1, 1]), 2, 6)


@pytest.fixture(scope="session")
def nested_balls(tmp_path_factory):
    """An atlas folder of two balls about the origin for the effector "point": ``near`` (0.4 m, priority 1) inside
    ``far`` (0.9 m, priority 2), D_max 5 (the selector's and the server's tests)."""
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config

    out = tmp_path_factory.mktemp("balls") / "balls"
    build_atlas(parse_config({
        "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 2, "max": 5},
        "oracle": {"name": "sphere", "params": {"radius": 0.9}},
        "strategies": [
            {"name": "near", "effector": "point", "priority": 1, "oracle": {"params": {"radius": 0.4}}},
            {"name": "far", "effector": "point", "priority": 2},
        ],
    }, "balls", "balls"), out)
    return out


@pytest.fixture
def browser():
    """Headless Chromium (Debian's) driven by Selenium, for the viewer's page (tests/test_view.py's constants)."""
    from helpers import CHROMIUM, DRIVER
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    from tests.test_view import _profile

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    # As the machine's notes say: no background networking (the network is closed), software WebGL.
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--window-size=1200,800", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", f"--user-data-dir={_profile()}"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service(DRIVER), options=opts)
    yield driver
    driver.quit()
