"""The viewer (reach.tools.view): its answers against the selector's and a server's, and the page in a real browser.

The browser tests drive Debian's Chromium headless through Selenium and
assert on the screenshots' pixels. Without Chromium they skip, saying how to
install it; in CI (CI=true) a missing browser fails.
"""

from __future__ import annotations

import io
import os
import threading
import time

import numpy as np
import pytest
from helpers import ARM, BROWSER_MISSING, INSTALL, browser_only, free_port

from reach.answers.select import Selector
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.maps.atlas import load_atlas

viser = pytest.importorskip("viser", reason="the viewer needs viser: pip install 'reach-volumes[view]'")
pytestmark = pytest.mark.slow  # builds a body atlas, starts browsers
from reach.tools.view import BOUNDARY_SHADE, PALETTE, Viewer  # noqa: E402

CONFIG = {
    "body": {"human": {"sex": "male", "percentile": 50}},
    "box": {"min": [-0.5, -1.0, 0.6], "max": [0.9, 0.4, 2.1]}, "depth": {"min": 2, "max": 4},
    "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "secondary": False}},
    "strategies": [
        {"name": "right_arm", "effector": "right_hand", "priority": 1, "joints": ARM,
         "tasks": [{"type": "reach"}, {"type": "self_collision"}]},
        {"name": "right_upper_body", "effector": "right_hand", "priority": 2,
         "joints": [*ARM, "lumbar_*", "thoracic_*"],
         "tasks": [{"type": "reach"}, {"type": "self_collision"}]},
    ],
}
if BROWSER_MISSING and os.environ.get("CI") == "true":
    raise RuntimeError(f"Chromium is required in CI but {BROWSER_MISSING}; .ci/run must install it ({INSTALL})")
GOALS = np.array([[0.45, -0.25, 1.2], [0.3, -0.55, 0.9], [0.1, -0.9, 1.9], [0.85, 0.35, 0.65]])


@pytest.fixture(scope="module")
def atlas(tmp_path_factory):
    out = tmp_path_factory.mktemp("view") / "view"
    build_atlas(parse_config(CONFIG, "view", "view"), out)
    return load_atlas(out)


@pytest.fixture
def viewer(atlas):
    v = Viewer([atlas], port=free_port(), refine=False)
    yield v
    v.close()


def _same(a: dict, b: dict) -> bool:
    return {k: v for k, v in a.items() if k != "seconds"} == {k: v for k, v in b.items() if k != "seconds"}


def test_the_answer_shown_is_the_selectors(viewer, atlas):
    selector = Selector(atlas, refine=False)
    seen = set()
    for goal in GOALS:
        shown = viewer.set_goal(goal)[0]
        assert _same(shown, selector.select("right_hand", goal).to_dict())
        seen.add(shown["strategy"])
        assert (viewer.answer_box.content.count("unreachable") == 1) == (not shown["reachable"])
        if shown["reachable"]:
            assert f"**{shown['strategy']}**" in viewer.answer_box.content
    assert {"right_arm", "right_upper_body", None} <= seen  # the goals were chosen to show all three


def test_the_body_takes_the_answers_posture(viewer):
    """The drawn hand capsule ends where the answer's posture puts it: an independent forward kinematics."""
    import pinocchio as pin

    from oracles.bodies.body import human_body
    from reach.answers.answer import posture_vector

    answer = viewer.set_goal(GOALS[0])[0]
    scene = viewer.scenes[0]
    body = human_body()
    q = posture_vector(scene.shaper.posture_names, body.q_ref, answer["posture"], answer["root"])
    data = body.model.createData()
    pin.framesForwardKinematics(body.model, data, q)
    hand = scene.capsules[[p.name for p in body.collision.placed].index("right_hand")]
    a, b = body.collision.world(data, body.collision.index["right_hand"])
    assert np.allclose(hand.position, 0.5 * (a + b), atol=1e-6)
    w, x, y, z = hand.wxyz  # the mesh is built along +z: its rotation takes +z onto the capsule's axis
    assert np.allclose(pin.Quaternion(w, x, y, z).toRotationMatrix()[:, 2], (b - a) / np.linalg.norm(b - a), atol=1e-6)
    grip = data.oMf[body.frame_id("right_hand")].translation
    # the stored posture of a nearby vertex
    assert np.linalg.norm(grip - GOALS[0]) == pytest.approx(answer["residual"], abs=1e-6)


def test_layers_slices_and_first_by_priority_choose_cells(viewer, atlas):
    arm = viewer.scenes[0].cells["right_arm"]
    viewer.cells_box.value = "both"
    assert len(viewer.visible_cells(0, "right_arm").centre) == len(arm.centre)
    viewer.cells_box.value = "inner"
    assert viewer.visible_cells(0, "right_arm").inner.all()
    viewer.first_box.value = True
    upper = viewer.visible_cells(0, "right_upper_body")
    assert 0 < len(upper.centre) < int(viewer.scenes[0].cells["right_upper_body"].inner.sum())
    assert not atlas.trees["right_arm"].contains(upper.centre, "vertex").any()
    viewer.first_box.value = False
    viewer.slice_axis.value, viewer.slice_at.value = "z", 1.2
    cut = viewer.visible_cells(0, "right_arm")
    assert len(cut.centre) and np.all(np.abs(cut.centre[:, 2] - 1.2) <= cut.size[:, 2] / 2)


def test_toggling_a_layer_sends_nothing_again(viewer):
    viewer.show_strategy("right_upper_body", True)
    handle = viewer._drawn[(0, "right_upper_body")][1]
    viewer.show_strategy("right_upper_body", False)
    assert viewer._drawn[(0, "right_upper_body")][1] is handle and handle.visible is False  # hidden, kept
    viewer.show_strategy("right_upper_body", True)
    assert viewer._drawn[(0, "right_upper_body")][1] is handle and handle.visible is True
    viewer.style_box.value = "dots"
    viewer.draw()
    assert viewer._drawn[(0, "right_upper_body")][1] is not handle  # other settings: drawn anew


def test_the_viewer_over_a_server_shows_the_servers_answers(atlas):
    from reach.serving.server import Server

    server = Server(atlas.path, "tcp://127.0.0.1:*", None, refine=False)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    v = Viewer([atlas], port=free_port(), connect=server.endpoint, refine=False)
    try:
        selector = Selector(atlas, refine=False)
        for goal in GOALS[:2]:
            assert _same(v.set_goal(goal)[0], selector.select("right_hand", goal).to_dict())
        v.effector = "nose"  # the server refuses the motion: the panel says why, the viewer lives on
        assert ("error" in v.plan_motion() and v.motion_box.content.startswith("no motion: ")
                and "nose" in v.motion_box.content)
    finally:
        v.close()
        server.stop()
        thread.join(timeout=5)


def test_two_atlases_stand_side_by_side(atlas):
    v = Viewer([atlas, atlas], port=free_port(), refine=False, spacing=1.5)
    try:
        answers = v.set_goal(GOALS[0])
        assert _same(answers[0], answers[1])
        a, b = (np.array(s.capsules[0].position) for s in v.scenes)
        assert np.allclose(b - a, [0.0, 1.5, 0.0])
        # the goal beside the second body too
        assert np.allclose(v.goal_markers[1].position, GOALS[0] + [0.0, 1.5, 0.0])
        assert not np.array_equal(v.scenes[0].colours, v.scenes[1].colours)
    finally:
        v.close()


# -- in a real browser --------------------------------------------------------
def _profile() -> str:
    import tempfile

    return tempfile.mkdtemp(prefix="reach-chromium-")


def _shot(driver, name: str, settle: float = 2.5) -> np.ndarray:
    """A screenshot as an (h, w, 3) array; kept as NAME.png in $REACH_SHOTS when set, to look at."""
    from PIL import Image

    time.sleep(settle)  # the page applies the scene's messages and renders
    png = driver.get_screenshot_as_png()
    if os.environ.get("REACH_SHOTS"):
        os.makedirs(os.environ["REACH_SHOTS"], exist_ok=True)
        with open(os.path.join(os.environ["REACH_SHOTS"], f"{name}.png"), "wb") as f:
            f.write(png)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def _shot_until(driver, name: str, done, timeout: float = 30.0) -> np.ndarray:
    """Screenshots until done(image) holds or timeout [s] passes (a loaded machine renders late); the last one."""
    t0 = time.monotonic()
    image = _shot(driver, name)
    while not done(image) and time.monotonic() - t0 < timeout:
        image = _shot(driver, name, settle=1.0)
    return image


def _pixels_near(image: np.ndarray, rgb, tol: int = 40) -> int:
    return int((np.abs(image[:, :, :760] - np.asarray(rgb)).max(axis=2) <= tol).sum())  # the scene, left of the panel


def _wait_for_page(driver, viewer, timeout: float = 30.0) -> None:
    driver.get(viewer.url)
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if "Volumes" in driver.find_element("tag name", "body").text:
            return
        time.sleep(0.3)
    raise AssertionError(f"the viewer's page did not load from {viewer.url}")


@browser_only
def test_the_page_draws_strategy_colours_and_layers_toggle(viewer, browser):
    viewer.style_box.value = "dots"  # opaque, unshaded: the strategy colours as they are
    viewer.show_strategy("right_upper_body", True)
    _wait_for_page(browser, viewer)
    arm, upper = PALETTE[0] * BOUNDARY_SHADE, PALETTE[1] * BOUNDARY_SHADE  # boundary cells, as drawn
    both = _shot_until(browser, "layers_both", lambda im: _pixels_near(im, arm) > 500 and _pixels_near(im, upper) > 500)
    assert _pixels_near(both, arm) > 500 and _pixels_near(both, upper) > 500
    viewer.show_strategy("right_upper_body", False)
    alone = _shot_until(browser, "layers_arm", lambda im: _pixels_near(im, upper) < 0.05 * _pixels_near(both, upper))
    assert _pixels_near(alone, upper) < 0.05 * _pixels_near(both, upper)
    assert _pixels_near(alone, arm) > 500


@browser_only
def test_moving_the_goal_moves_the_drawn_arm_and_names_the_strategy(viewer, browser):
    viewer.show_strategy("right_arm", False)  # the body alone
    viewer.set_goal(GOALS[0])
    _wait_for_page(browser, viewer)
    before = _shot(browser, "goal_before")
    text = browser.find_element("tag name", "body").text
    assert "right_arm" in text
    viewer.set_goal(GOALS[1])  # reached only by bending the trunk
    after = _shot_until(browser, "goal_after",
                        lambda im: (np.abs(im[:, :760] - before[:, :760]).max(axis=2) > 30).sum() > 300)
    assert "right_upper_body" in viewer.answer_box.content  # (the layers' checkboxes name every strategy on the page)
    changed = np.abs(after[:, :760] - before[:, :760]).max(axis=2) > 30
    assert changed.sum() > 300  # the body moved on screen
    ys, xs = np.nonzero(changed)
    assert xs.max() - xs.min() < 600  # where the body is, not the whole scene


def _hand_capsule(viewer) -> np.ndarray:
    scene = viewer.scenes[0]
    names = list(scene.shaper.shape(scene.shaper.reference_posture())[0])
    return np.array(scene.capsules[names.index("right_hand")].position)


def test_a_planned_motion_poses_the_body_frame_by_frame_and_ends_in_the_answer(viewer):
    from reach.motion.planner import Planner

    # a budget no machine runs out of: the same answer below
    viewer._planner = Planner(Selector(viewer.scenes[0].atlas), budget=5.0)
    viewer.set_goal(GOALS[0])
    summary = viewer.plan_motion()
    # The motion ends in the planner's answer: a stored posture settled onto the goal (the viewer's own answers here
    # are stored postures), found again here apart from the motion's frames.
    answer, end = viewer._planner._settled("right_hand", np.asarray(GOALS[0], float))
    assert summary["end"] == "settled" and end is not None
    shaper = viewer.scenes[0].shaper
    names, at_answer = shaper.shape(end)
    frames = len(viewer.motion["postures"])
    assert (summary["strategy"] == answer.strategy and summary["frame_count"] == frames
            and viewer.frame_slider.max == frames - 1)
    hand = names.index("right_hand")
    start = shaper.shape(shaper.reference_posture())[1][hand]
    assert np.allclose(_hand_capsule(viewer), 0.5 * (start[:3] + start[3:6]))  # the first frame: the reference posture
    viewer.show_frame(frames - 1)
    # the last: the answer's
    assert np.allclose(_hand_capsule(viewer), 0.5 * (at_answer[hand, :3] + at_answer[hand, 3:6]), atol=1e-6)
    np.testing.assert_allclose(viewer._path.points[-1, 1], viewer.motion["path"][-1])  # the path ends at the hand
    viewer.set_goal(GOALS[1])  # another goal: the motion shown was to the old one
    assert viewer.motion is None and viewer.play_button.disabled


@browser_only
def test_the_motion_plays_in_the_browser_and_ends_in_the_answers_posture(viewer, browser):
    from reach.motion.planner import Planner

    # a budget no machine runs out of: the same answer below
    viewer._planner = Planner(Selector(viewer.scenes[0].atlas), budget=5.0)
    viewer.show_strategy("right_arm", False)  # the body alone
    viewer.set_goal(GOALS[1])  # the trunk bends: a motion a screenshot sees
    _wait_for_page(browser, viewer)
    viewer.plan_motion()
    moved = lambda a, b: int((np.abs(a[:, :760] - b[:, :760]).max(axis=2) > 30).sum())  # noqa: E731
    start = _shot(browser, "motion_start")
    viewer.speed_slider.value = 0.1  # ten times slower: screenshots see the frames go by
    browser.find_element("xpath", "//button[contains(., 'play / pause')]").click()  # the page's own button
    seen, t0 = [], time.monotonic()
    while time.monotonic() - t0 < 30 and (not seen or viewer.playing or seen[-1][0] != viewer.frame):
        seen.append((viewer.frame, _shot(browser, f"motion_{len(seen)}", settle=0.15)))
    frames = [k for k, _ in seen]
    assert len(set(frames)) >= 3 and frames[-1] == len(viewer.motion["postures"]) - 1  # it played to the end
    assert any(moved(im, start) > 300 for _, im in seen[1:-1])  # the drawn body changed while playing
    end = _shot(browser, "motion_end")
    # The answer the motion ends in (a stored posture settled onto the goal), drawn from its own posture found again
    # (not from the motion's frames).
    answer, end_posture = viewer._planner._settled("right_hand", np.asarray(GOALS[1], float))
    assert answer.strategy == "right_upper_body" and viewer.motion["outcome"] == "reached"
    shaper = viewer.scenes[0].shaper
    viewer._pose(viewer.scenes[0], shaper.shape(end_posture)[1])
    posed = _shot(browser, "motion_answer")
    assert moved(start, posed) > 300 and moved(end, posed) < 0.05 * moved(start, posed)


def test_view_command_needs_an_atlas(tmp_path, capsys):
    from reach.tools.cli import main

    assert main(["view", str(tmp_path / "none")]) != 0
    assert "none" in capsys.readouterr().err



def test_an_analytic_atlas_is_viewed_without_a_body(tmp_path):
    raw = {"box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 1, "max": 3},
           "oracle": {"name": "sphere", "params": {"radius": 0.9}},
           "strategies": [{"name": "ball", "effector": "point"}]}
    build_atlas(parse_config(raw, "ball", "ball"), tmp_path / "ball")
    v = Viewer([load_atlas(tmp_path / "ball")], port=free_port())
    try:
        assert v.scenes[0].shaper is None and v.scenes[0].capsules == []
        inside, outside = v.set_goal(np.array([0.3, 0.0, 0.0]))[0], v.set_goal(np.array([0.99, 0.99, 0.0]))[0]
        assert inside["strategy"] == "ball" and inside["refined"] == "unavailable"
        assert not outside["reachable"] and "unreachable" in v.answer_box.content
    finally:
        v.close()


def viser_version() -> str:
    import viser

    return str(viser.__version__)


def _get(port: int, host_header: str, origin: str | None = None, upgrade: bool = False) -> tuple[int, bytes]:
    """One raw HTTP request to the viewer's port, with the Host (and Origin) a browser elsewhere could send."""
    import socket

    head = ["GET / HTTP/1.1", f"Host: {host_header}", "Connection: close"]
    if origin is not None:
        head.append(f"Origin: {origin}")
    if upgrade:
        head = [*head[:2], "Connection: Upgrade", "Upgrade: websocket", "Sec-WebSocket-Version: 13",
                "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
                f"Sec-WebSocket-Protocol: viser-v{viser_version()}", *head[3:]]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(("\r\n".join(head) + "\r\n\r\n").encode())
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
    return int(data.split(b" ", 2)[1]), data


def test_the_viewer_answers_only_its_own_origin(viewer):
    port = viewer.port
    assert _get(port, f"127.0.0.1:{port}")[0] == 200 and _get(port, f"localhost:{port}")[0] == 200  # its page
    status, text = _get(port, f"evil.example:{port}")  # DNS rebinding: another name for this address
    assert status == 403 and b"forbidden: Host 'evil.example:" in text
    assert _get(port, f"127.0.0.1:{port + 1}")[0] == 403  # another port's name
    status, text = _get(port, f"127.0.0.1:{port}", origin="http://evil.example", upgrade=True)  # a cross-site WebSocket
    assert status == 403 and b"forbidden: Origin 'http://evil.example' is not this server's" in text
    # its own page's WebSocket
    assert _get(port, f"127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", upgrade=True)[0] == 101


def test_vipers_own_port_refuses_what_the_gate_did_not_pass_on(viewer):
    """DNS rebinding to viser's own loopback port: the page, a WebSocket of a foreign origin and
    even this machine's own name for that port are refused there; only what came through the gate gets in."""
    inner = viewer.server.get_port()
    assert inner != viewer.port
    for host, origin in ((f"evil.example:{inner}", None), (f"127.0.0.1:{inner}", None),
                         (f"127.0.0.1:{inner}", "http://evil.example")):
        for upgrade in (False, True):
            status, text = _get(inner, host, origin=origin, upgrade=upgrade)
            assert status == 403 and b"forbidden:" in text, (host, origin, upgrade, text[:200])
    # The gate's own names, as the gate passes them on, still reach viser.
    assert _get(viewer.port, f"127.0.0.1:{viewer.port}", origin=f"http://127.0.0.1:{viewer.port}",
                upgrade=True)[0] == 101


@browser_only
def test_a_page_of_another_origin_reaches_no_port_of_the_viewer(viewer, browser, tmp_path):
    """A real browser on a page served from another loopback port tries a WebSocket to every port the viewer
    opens (the gate's and viser's): none opens."""
    import http.server
    import threading

    page = tmp_path / "index.html"
    page.write_text("<html><body><script>window.results = {};</script></body></html>")
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=str(tmp_path), **k)  # noqa: E731
    other = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=other.serve_forever, daemon=True).start()
    try:
        browser.get(f"http://127.0.0.1:{other.server_address[1]}/index.html")
        script = """
            const done = arguments[arguments.length - 1];
            const ports = arguments[0], out = {};
            let left = ports.length;
            for (const p of ports) {
                const ws = new WebSocket(`ws://127.0.0.1:${p}`, [arguments[1]]);
                ws.onopen = () => { out[p] = 'open'; ws.close(); if (--left === 0) done(out); };
                ws.onerror = () => { out[p] = 'refused'; if (--left === 0) done(out); };
            }"""
        browser.set_script_timeout(20)
        ports = [viewer.port, viewer.server.get_port()]
        out = browser.execute_async_script(script, ports, f"viser-v{viser_version()}")
        assert out == {str(p): "refused" for p in ports}, out
        # The same browser on the viewer's own page opens its WebSocket (the check can fail).
        browser.get(viewer.url)
        out = browser.execute_async_script(script, [viewer.port], f"viser-v{viser_version()}")
        assert out == {str(viewer.port): "open"}, out
    finally:
        other.shutdown()


@pytest.fixture
def population_viewer(atlas):
    """The viewer with an accommodation volume: a slab in front of the chest, half of it reached by every member
    (share 1, yellow), half by a fifth of them (share 0.2, viridis's blue-purple)."""
    xs, ys, zs = np.meshgrid(np.linspace(0.3, 0.7, 9), np.linspace(-0.6, 0.2, 17), np.linspace(1.0, 1.4, 9),
                             indexing="ij")
    points = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], axis=1)
    share = np.where(points[:, 1] < -0.2, 1.0, 0.2)
    v = Viewer([atlas], port=free_port(), refine=False, accommodation=(points, share))
    v.show_strategy("right_arm", False)
    yield v
    v.close()


def test_the_accommodation_dots_are_those_at_or_above_the_threshold(population_viewer):
    from reach.tools.view import index_colours

    points, share = population_viewer.accommodation
    drawn = population_viewer.draw_accommodation()
    assert len(drawn.points) == len(points)  # 5 %: every point
    assert np.array_equal(np.asarray(drawn.colors), index_colours(share))
    population_viewer.accommodation_at.value = 50
    drawn = population_viewer.draw_accommodation()
    assert len(drawn.points) == int(np.sum(share >= 0.5)) and np.all(np.asarray(drawn.points)[:, 1] < -0.2)
    population_viewer.accommodation_box.value = False
    assert population_viewer.draw_accommodation() is None


@browser_only
def test_the_page_colours_the_accommodation_by_its_share(population_viewer, browser):
    from reach.tools.view import index_colours

    everyone, few = index_colours(np.array([1.0, 0.2]))
    _wait_for_page(browser, population_viewer)
    both = _shot_until(browser, "accommodation", lambda im: _pixels_near(im, everyone) > 300
                       and _pixels_near(im, few) > 300)
    assert _pixels_near(both, everyone) > 300 and _pixels_near(both, few) > 300
    population_viewer.accommodation_at.value = 50  # the panel's slider, as a user moves it
    most = _shot_until(browser, "accommodation_50", lambda im: _pixels_near(im, few) < 0.05 * _pixels_near(both, few))
    assert _pixels_near(most, few) < 0.05 * _pixels_near(both, few) and _pixels_near(most, everyone) > 300
