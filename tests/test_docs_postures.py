"""docs/postures.py (the README's answer-posture figure): a malformed --goals is refused with a message, before any
atlas is read."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "docs" / "postures.py"


@pytest.mark.parametrize("goals", ["1,2", "0.4,-0.2,x", ";"])
def test_malformed_goals_are_refused_naming_the_format(tmp_path, goals):
    run = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "no-atlas"), "--goals", goals],
                         capture_output=True, text=True)
    assert run.returncode == 2
    assert "argument --goals: expected X,Y,Z;X,Y,Z... in metres" in run.stderr
