"""The README's commands and code, run: every `reach` command parses, the light ones run, and every Python block runs.

Commands that build the demo or default atlas, serve or view run elsewhere
(`make run`, the server, viewer and ROS tests); here they are parsed by the
CLI's own parser, so that a renamed command or option fails a test.
"""

from __future__ import annotations

import re
import shlex
import threading
from pathlib import Path

import pytest
from helpers import ARM, human_config

from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.tools.cli import main, make_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def reach_commands() -> list[list[str]]:
    out = []
    for block in blocks("sh"):
        for line in block.splitlines():
            line = line.split("  #")[0].strip().rstrip("&").strip()
            if line.startswith("reach "):
                out.append(shlex.split(line)[1:])
    return out


def test_the_readme_shows_commands_and_code():
    assert len(reach_commands()) >= 18 and len(blocks("python")) >= 2


@pytest.mark.parametrize("argv", reach_commands(), ids=lambda a: " ".join(a)[:60])
def test_every_reach_command_of_the_readme_parses(argv):
    args = make_parser().parse_args(argv)
    assert callable(args.func)


def test_the_quick_look_at_the_sphere_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    light = [a for a in reach_commands() if "sphere" in " ".join(a)]
    assert [a[0] for a in light] == ["build", "info", "query"]
    for argv in light:
        assert main(argv) == 0, argv
    assert '"inner"' in capsys.readouterr().out


@pytest.mark.slow
def test_every_python_block_of_the_readme_runs(tmp_path, monkeypatch):
    # A small arm atlas stands for the demo's (out/demo), and a server on a random port for the one at 5555.
    from reach.serving.server import Server

    monkeypatch.chdir(tmp_path)
    strategies = [{"name": "right_arm", "effector": "right_hand", "joints": ARM, "tasks": [{"type": "reach"}]}]
    build_atlas(parse_config(human_config(d_max=3, strategies=strategies, name="demo"), "demo", "demo"),
                tmp_path / "out" / "demo")
    server = Server(tmp_path / "out" / "demo", "tcp://127.0.0.1:*", None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        for code in blocks("python"):
            exec(compile(code.replace("tcp://127.0.0.1:5555", server.endpoint), "README.md", "exec"), {})  # noqa: S102
    finally:
        server.stop()
        thread.join(timeout=5)
    assert (tmp_path / "ball.npz").is_file()
