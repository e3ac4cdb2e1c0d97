"""``scripts/test.sh`` always ends with pytest's pass/fail line, whatever ``-q`` it is given."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "test.sh"


@pytest.mark.parametrize("quiet", [[], ["-q"], ["-qq"], ["--quiet", "-q"]])
def test_summary_line_survives_quiet(tmp_path, quiet):
    """The script in a stand-in repository (its setup a no-op, its .venv this Python)."""
    (tmp_path / "scripts").mkdir()
    shutil.copy(SCRIPT, tmp_path / "scripts" / "test.sh")
    (tmp_path / "scripts" / "setup.sh").write_text("#!/usr/bin/env bash\n")
    (tmp_path / ".venv" / "bin").mkdir(parents=True)
    (tmp_path / ".venv" / "bin" / "python").symlink_to(sys.executable)
    (tmp_path / "test_one.py").write_text("def test_ok():\n    pass\n\n"
                                          "def test_bad():\n    assert False\n")
    env = {k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"}
    run = subprocess.run(["bash", str(tmp_path / "scripts" / "test.sh"), *quiet, "test_one.py"],
                         cwd=tmp_path, capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 1
    assert "1 failed, 1 passed" in run.stdout.splitlines()[-1]
